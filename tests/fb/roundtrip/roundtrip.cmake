# The recipe round trip's test registration, one for both toolchains: tests/fb
# (fb_recipe_roundtrip, matiec) and tests/strucpp (strucpp_recipe_roundtrip, STruC++) build
# the same roundtrip.st and run it with the same driver (test_recipe_roundtrip.py).
include_guard(GLOBAL)

# mbfb_roundtrip_reason(OUT REASON): why the round trip cannot be built: REASON (the
# toolchain's), or that the shims' shared library is missing; empty when it can.
function(mbfb_roundtrip_reason out reason)
  if(NOT reason AND NOT TARGET mbfb_shared)
    set(reason "the shims' shared library (mbfb_shared) is not built")
  endif()
  set(${out} "${reason}" PARENT_SCOPE)
endfunction()

# mbfb_roundtrip_test(NAME REASON TARGET PROGRAM_ST [ARGS driver args...] [ENV k=v...]): the
# test NAME, skipped with REASON when it is not empty, else building TARGET at test time
# (outside ALL: PROGRAM_ST exists only once the test has written it) and running it, with
# the shims' shared library in MBFB_LIB.
function(mbfb_roundtrip_test name reason target program_st)
  cmake_parse_arguments(RT "" "" "ARGS;ENV" ${ARGN})
  set(py ${CMAKE_CURRENT_FUNCTION_LIST_DIR}/test_recipe_roundtrip.py)
  if(reason)
    add_test(NAME ${name} COMMAND ${MBFB_PYTHON} ${py} --skip "${reason}")
    return()
  endif()
  add_test(NAME ${name}
           COMMAND ${MBFB_PYTHON} ${py} ${RT_ARGS} --build ${CMAKE_BINARY_DIR}
                   --target ${target} --exe $<TARGET_FILE:${target}> --program ${program_st})
  list(APPEND RT_ENV "MBFB_LIB=$<TARGET_FILE:mbfb_shared>")
  set_tests_properties(${name} PROPERTIES ENVIRONMENT "${RT_ENV}")
endfunction()
