# mbfb_st_program(): how an ST program becomes a target, for tools/runner (the native build) and
# tests/cross (the same programs for ARM, built by the cross compilers). Needs: MBFB_RUNNER_DIR
# (tools/runner), MBFB_IEC2C, MBFB_IEC_LIB, MBFB_IEC_CINC, MBFB_PROGRAM_LANG, MBFB_PYTHON, the
# host library targets and mbfb_set_rpath(<target> <flavour>).
# mbfb_st_program(<target> <dir> [SHARED] [HOST <library>] [INCLUDE <header>] <st files...>):
# the ST files (concatenated in order) compiled by iec2c in <dir> (its output kept by content:
# scripts/gencache.py), glued (mkglue.py), compiled
# as MBFB_PROGRAM_LANG with mbfb_st.h (the shims and the pragmas' macros; and <header>) force-included, and linked with the host
# (default: the runner's) into <target>: an executable, or with SHARED a shared object (a
# program a host dlopens, compiled with -fno-gnu-unique as Runtime v4's programs are, so that
# dlclose unmaps it). (A CMake function is global: tests/fb calls it too.)
function(mbfb_st_program target dir)
  cmake_parse_arguments(PARSE_ARGV 2 _arg "SHARED" "HOST;INCLUDE" "")
  set(_host mbfb_runner_host)
  if(_arg_HOST)
    set(_host ${_arg_HOST})
  endif()
  set(_incl "SHELL:-include mbfb_st.h")
  if(_arg_INCLUDE)   # a path, or a name on the host library's include path
    list(APPEND _incl "SHELL:-include ${_arg_INCLUDE}")
  endif()
  set(_st ${_arg_UNPARSED_ARGUMENTS})
  set(_here ${MBFB_RUNNER_DIR})
  string(REPLACE ";" "|" _in "${_st}")
  add_custom_command(
    OUTPUT ${dir}/Config0.c ${dir}/Res0.c ${dir}/glue.c
    COMMAND ${CMAKE_COMMAND} -E make_directory ${dir}
    COMMAND ${CMAKE_COMMAND} -DOUT=${dir}/program.st -DIN=${_in} -P ${_here}/concat.cmake
    COMMAND ${MBFB_PYTHON} ${_here}/../../scripts/gencache.py iec2c --in ${MBFB_IEC2C}
            --in-dir ${MBFB_IEC_LIB} --in program.st --out Config0.c --out Config0.h
            --out LOCATED_VARIABLES.h --out POUS.c --out POUS.h --out Res0.c --out VARIABLES.csv
            -- ${MBFB_IEC2C} -f -l -p -r -R -a -I ${MBFB_IEC_LIB} program.st
    COMMAND ${MBFB_PYTHON} ${_here}/mkglue.py ${dir}
    WORKING_DIRECTORY ${dir}
    DEPENDS ${_st} ${_here}/concat.cmake ${_here}/mkglue.py
    COMMENT "iec2c: ${target}" VERBATIM)
  set_source_files_properties(${dir}/Config0.c ${dir}/Res0.c ${dir}/glue.c PROPERTIES
                              LANGUAGE ${MBFB_PROGRAM_LANG} GENERATED TRUE)
  if(_arg_SHARED)
    add_library(${target} MODULE ${dir}/Config0.c ${dir}/Res0.c ${dir}/glue.c)
    target_compile_options(${target} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:-fno-gnu-unique>)
  else()
    add_executable(${target} ${dir}/Config0.c ${dir}/Res0.c ${dir}/glue.c)
  endif()
  # As OpenPLC's compile_program.sh: g++ -std=gnu++11 -I core/lib -w, no -O and no -g (the
  # build type's flags do not apply: -O0 -g0 after them); c_blocks.h reaches the shims header
  # there (plc_lib), here it is force-included. matiec's code at -O2 -g took 4 times the
  # compile time of -O0 for nothing a test needs.
  target_include_directories(${target} PRIVATE ${MBFB_IEC_CINC} ${_here} ${dir})
  target_compile_options(${target} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:-std=gnu++11> -w -O0 -g0
                         ${_incl})
  target_link_libraries(${target} PRIVATE ${_host})
  mbfb_set_rpath(${target} default)
endfunction()
