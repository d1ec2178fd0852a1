# tools/matiec/matiec.cmake - which IEC 61131-3 compiler (matiec's iec2c) the build uses;
# included by the top CMakeLists.txt. Sets MBFB_IEC2C (empty when there is none),
# MBFB_TOOLCHAIN (what it is, in words) and MBFB_TOOLCHAIN_REASON (why there is none).
#
# In this order, the first that applies:
#   1. MATIEC_HOME: a matiec build (iec2c, lib/ieclib.txt, lib/C/*.h). Set but without iec2c is
#      an error that the tests report as their skip reason; nothing else is tried then.
#   2. OPENPLC_HOME (default /opt/OpenPLC_v3): OpenPLC v3's webserver/iec2c.
#   3. iec2c on PATH.
#   4. The embedded default: matiec built from source into this build tree (_matiec/), once:
#      from MATIEC_SOURCE_DIR (a matiec source tree: a clone, a release, or OpenPLC's own
#      utils/matiec_src; copied, never written to), else fetched with git from MATIEC_GIT_URL
#      (default: beremiz's public repository) at MATIEC_GIT_COMMIT (pinned below), unless
#      MBFB_FETCH_MATIEC is OFF. Needs flex, bison, autoconf, automake, libtool, make, g++.
# Each of these may be given in the environment (read at every configure, never cached) or with
# -D (cached); the environment wins, and where a cached value is used the summary says so.

set(MBFB_MATIEC_GIT_URL_DEFAULT "https://github.com/beremiz/matiec.git")
# The commit every fb test and the runner were verified with (beremiz matiec, 2024-04-26): the
# last before 8a06b3b, from which FOR i := a TO a runs zero times (tools/matiec/README.md).
set(MBFB_MATIEC_GIT_COMMIT_DEFAULT "d3196244bf50b2d6d512a0240e10dfa75edbeb7b")

# _mbfb_setting(VAR DEFAULT DOC): VAR from the environment (wins; not cached, so the next run
# without it does not inherit it), else from the cache (cmake -DVAR=...), else DEFAULT;
# _mbfb_origin_VAR says which, for the summary.
macro(_mbfb_setting var default doc)
  if(DEFINED ENV{${var}})
    set(${var} "$ENV{${var}}")
    set(_mbfb_origin_${var} "environment")
  elseif(NOT "$CACHE{${var}}" STREQUAL "")
    set(${var} "$CACHE{${var}}")
    set(_mbfb_origin_${var} "cached in ${CMAKE_BINARY_DIR}: cmake -U${var} or set ${var} in the environment to change it")
  else()
    set(${var} "${default}")
    set(_mbfb_origin_${var} "default")
  endif()
endmacro()

_mbfb_setting(MATIEC_HOME "" "A matiec build: iec2c, lib/ieclib.txt, lib/C (wins over everything else)")
_mbfb_setting(OPENPLC_HOME "" "OpenPLC v3 checkout (webserver/iec2c, webserver/lib); empty: /opt/OpenPLC_v3")
_mbfb_setting(MATIEC_SOURCE_DIR "" "A matiec source tree to build iec2c from (offline machines)")
_mbfb_setting(MATIEC_GIT_URL "${MBFB_MATIEC_GIT_URL_DEFAULT}" "Where to fetch matiec's source from")
_mbfb_setting(MATIEC_GIT_COMMIT "${MBFB_MATIEC_GIT_COMMIT_DEFAULT}" "The matiec commit to fetch")
_mbfb_setting(MBFB_FETCH_MATIEC "ON" "Fetch and build matiec when no toolchain is found (needs network)")
set(_openplc "${OPENPLC_HOME}")
if(_openplc STREQUAL "")
  set(_openplc "/opt/OpenPLC_v3")
endif()

set(MBFB_IEC2C "")
set(MBFB_TOOLCHAIN "")
set(MBFB_TOOLCHAIN_REASON "")
set(MBFB_MATIEC_BUILT_FROM "")

# _mbfb_run(WHAT LOG DIR CMD...): one step of the matiec build; on failure sets
# MBFB_TOOLCHAIN_REASON and prints the log's tail.
function(_mbfb_run what log dir)
  execute_process(COMMAND ${ARGN} WORKING_DIRECTORY "${dir}" RESULT_VARIABLE rc
                  OUTPUT_FILE "${log}" ERROR_FILE "${log}.err")
  if(NOT rc EQUAL 0)
    file(READ "${log}.err" err)
    string(LENGTH "${err}" n)
    if(n GREATER 2000)
      math(EXPR start "${n} - 2000")
      string(SUBSTRING "${err}" ${start} -1 err)
    endif()
    message(STATUS "matiec: ${what} failed (${rc}); the end of ${log}.err:\n${err}")
    set(MBFB_TOOLCHAIN_REASON "building matiec failed at '${what}' (log: ${log}.err)" PARENT_SCOPE)
  endif()
endfunction()

# _mbfb_build_matiec(KIND WHERE): iec2c built in ${CMAKE_BINARY_DIR}/_matiec/src from a
# source directory (KIND dir) or a git URL at MATIEC_GIT_COMMIT (KIND git). Done once: the
# stamp names what was built; a different source or commit builds again.
function(_mbfb_build_matiec kind where)
  set(top "${CMAKE_BINARY_DIR}/_matiec")
  set(src "${top}/src")
  if(kind STREQUAL "git")
    set(identity "git ${where} ${MATIEC_GIT_COMMIT}")
  else()
    get_filename_component(where "${where}" ABSOLUTE)
    set(identity "dir ${where}")
  endif()
  set(MBFB_MATIEC_BUILT_FROM "${identity}" PARENT_SCOPE)
  if(EXISTS "${top}/stamp" AND EXISTS "${src}/iec2c")
    file(READ "${top}/stamp" old)
    if(old STREQUAL identity)
      set(MBFB_IEC2C "${src}/iec2c" PARENT_SCOPE)
      return()
    endif()
  endif()
  foreach(tool flex bison autoreconf aclocal automake libtoolize make)
    find_program(_t_${tool} ${tool} NO_CACHE)
    if(NOT _t_${tool})
      set(MBFB_TOOLCHAIN_REASON "building matiec needs ${tool} (Debian packages flex bison autoconf automake libtool make: .ci/apt-packages.txt)" PARENT_SCOPE)
      return()
    endif()
  endforeach()
  file(REMOVE_RECURSE "${top}")
  file(MAKE_DIRECTORY "${top}")
  set(MBFB_TOOLCHAIN_REASON "")
  if(kind STREQUAL "git")
    find_package(Git QUIET)
    if(NOT GIT_EXECUTABLE)
      set(MBFB_TOOLCHAIN_REASON "fetching matiec needs git" PARENT_SCOPE)
      return()
    endif()
    message(STATUS "matiec: fetching ${where} at ${MATIEC_GIT_COMMIT} ...")
    file(MAKE_DIRECTORY "${src}")
    _mbfb_run("git init" "${top}/fetch.log" "${src}" ${GIT_EXECUTABLE} init -q)
    # One commit by its hash (GitHub allows it); a server that does not gets a full fetch.
    execute_process(COMMAND ${GIT_EXECUTABLE} fetch -q --depth 1 "${where}" "${MATIEC_GIT_COMMIT}"
                    WORKING_DIRECTORY "${src}" RESULT_VARIABLE rc OUTPUT_QUIET ERROR_QUIET)
    if(NOT rc EQUAL 0)
      _mbfb_run("git fetch ${where}" "${top}/fetch.log" "${src}" ${GIT_EXECUTABLE} fetch -q "${where}")
      if(MBFB_TOOLCHAIN_REASON)
        set(MBFB_TOOLCHAIN_REASON "could not fetch matiec from ${where} (offline? give a local source tree with MATIEC_SOURCE_DIR, see README Prerequisites)" PARENT_SCOPE)
        return()
      endif()
    endif()
    _mbfb_run("git checkout ${MATIEC_GIT_COMMIT}" "${top}/fetch.log" "${src}"
              ${GIT_EXECUTABLE} -c advice.detachedHead=false checkout -q "${MATIEC_GIT_COMMIT}")
    if(MBFB_TOOLCHAIN_REASON)
      set(MBFB_TOOLCHAIN_REASON "${MATIEC_GIT_URL} has no commit ${MATIEC_GIT_COMMIT}" PARENT_SCOPE)
      return()
    endif()
  else()
    if(NOT EXISTS "${where}/configure.ac" OR NOT EXISTS "${where}/lib/ieclib.txt")
      set(MBFB_TOOLCHAIN_REASON "MATIEC_SOURCE_DIR=${where} is not a matiec source tree (no configure.ac, lib/ieclib.txt)" PARENT_SCOPE)
      return()
    endif()
    message(STATUS "matiec: copying the source tree ${where} ...")
    file(COPY "${where}/" DESTINATION "${src}" PATTERN ".git" EXCLUDE)
    if(EXISTS "${src}/Makefile")  # an in-place build (OpenPLC's utils/matiec_src): start clean
      execute_process(COMMAND make distclean WORKING_DIRECTORY "${src}" OUTPUT_QUIET ERROR_QUIET)
    endif()
  endif()
  cmake_host_system_information(RESULT jobs QUERY NUMBER_OF_LOGICAL_CORES)
  message(STATUS "matiec: building iec2c in ${src} (autoreconf, configure, make -j${jobs}; a few minutes, once) ...")
  set(_cmd_autoreconf autoreconf -fi)
  set(_cmd_configure ./configure)
  set(_cmd_make make -j${jobs})
  if(CMAKE_C_COMPILER_LAUNCHER AND CMAKE_CXX_COMPILER_LAUNCHER)   # test.sh: ccache
    list(APPEND _cmd_configure "CC=${CMAKE_C_COMPILER_LAUNCHER} ${CMAKE_C_COMPILER}"
                               "CXX=${CMAKE_CXX_COMPILER_LAUNCHER} ${CMAKE_CXX_COMPILER}")
  endif()
  foreach(name autoreconf configure make)
    _mbfb_run("${name}" "${top}/${name}.log" "${src}" ${_cmd_${name}})
    if(MBFB_TOOLCHAIN_REASON)
      set(MBFB_TOOLCHAIN_REASON "${MBFB_TOOLCHAIN_REASON}" PARENT_SCOPE)
      return()
    endif()
  endforeach()
  if(NOT EXISTS "${src}/iec2c")
    set(MBFB_TOOLCHAIN_REASON "building matiec in ${src} made no iec2c" PARENT_SCOPE)
    return()
  endif()
  file(WRITE "${top}/stamp" "${identity}")
  set(MBFB_IEC2C "${src}/iec2c" PARENT_SCOPE)
endfunction()

if(NOT MATIEC_HOME STREQUAL "")
  if(EXISTS "${MATIEC_HOME}/iec2c" AND NOT IS_DIRECTORY "${MATIEC_HOME}/iec2c")
    set(MBFB_IEC2C "${MATIEC_HOME}/iec2c")
    set(MBFB_TOOLCHAIN "matiec in MATIEC_HOME=${MATIEC_HOME} (${_mbfb_origin_MATIEC_HOME})")
  else()
    set(MBFB_TOOLCHAIN_REASON "MATIEC_HOME=${MATIEC_HOME} (${_mbfb_origin_MATIEC_HOME}) has no iec2c; unset it to use OpenPLC's, PATH's or the embedded matiec")
  endif()
elseif(EXISTS "${_openplc}/webserver/iec2c")
  set(MBFB_IEC2C "${_openplc}/webserver/iec2c")
  set(MBFB_TOOLCHAIN "OpenPLC v3 at ${_openplc} (OPENPLC_HOME: ${_mbfb_origin_OPENPLC_HOME})")
else()
  find_program(_mbfb_path_iec2c iec2c NO_CACHE)
  if(_mbfb_path_iec2c)
    set(MBFB_IEC2C "${_mbfb_path_iec2c}")
    set(MBFB_TOOLCHAIN "iec2c on PATH (${_mbfb_path_iec2c})")
  elseif(NOT MATIEC_SOURCE_DIR STREQUAL "")
    _mbfb_build_matiec(dir "${MATIEC_SOURCE_DIR}")
    set(MBFB_TOOLCHAIN "matiec built from MATIEC_SOURCE_DIR=${MATIEC_SOURCE_DIR} (${_mbfb_origin_MATIEC_SOURCE_DIR}) in ${CMAKE_BINARY_DIR}/_matiec")
  elseif(MBFB_FETCH_MATIEC)
    _mbfb_build_matiec(git "${MATIEC_GIT_URL}")
    set(MBFB_TOOLCHAIN "matiec ${MATIEC_GIT_COMMIT} from ${MATIEC_GIT_URL}, built in ${CMAKE_BINARY_DIR}/_matiec")
  else()
    set(MBFB_TOOLCHAIN_REASON "no matiec: no OpenPLC v3 at ${_openplc}, no MATIEC_HOME, no iec2c on PATH, no MATIEC_SOURCE_DIR, and MBFB_FETCH_MATIEC is OFF")
  endif()
endif()
if(MBFB_TOOLCHAIN_REASON)
  set(MBFB_IEC2C "")
  set(MBFB_TOOLCHAIN "none: ${MBFB_TOOLCHAIN_REASON}")
endif()
# OpenPLC's runtime (the e2e tests, demo.sh --openplc) is found apart from the compiler.
if(EXISTS "${_openplc}/webserver/core/glue_generator")
  set(MBFB_OPENPLC_RUNTIME "${_openplc}")
else()
  set(MBFB_OPENPLC_RUNTIME "")
endif()
message(STATUS "toolchain: ${MBFB_TOOLCHAIN}")
if(MBFB_OPENPLC_RUNTIME)
  message(STATUS "OpenPLC v3 runtime: ${MBFB_OPENPLC_RUNTIME} (OPENPLC_HOME: ${_mbfb_origin_OPENPLC_HOME})")
else()
  message(STATUS "OpenPLC v3 runtime: not at ${_openplc} (OPENPLC_HOME: ${_mbfb_origin_OPENPLC_HOME}); e2e tests report skipped")
endif()
