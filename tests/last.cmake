# The tests that run last, together: test_late's flavours (shims_late_*, tests/shims) and the
# soak's smoke run (soak_smoke, tests/soak). Included
# at the end of the top CMakeLists.txt, where every other test exists: CMake 3.25 sets a test's
# properties only in the directory that made it, so these are made here.
#
# test_late holds late replies against reply timeouts of 200 to 400 ms. Beside ctest -j's other
# tests (8 at once on 2 cores, the burst of STruC++ tests after strucpp_build) three CI runs in a
# row failed one of its scenarios in two to five flavours at once; alone every flavour passed.
# Alone one after another they took 4.4 minutes of a CI run, mostly waiting. So they wait for
# every other test of the run (DEPENDS: an order only, ctest ignores a name that is not in the
# run) and then run beside each other only, in the time of the longest. soak_smoke, timed
# against the same reply timeouts, ran alone before (13 s).

# _mbfb_tests_under(<dir> <var>): the names of the tests of <dir> and the folders below it
function(_mbfb_tests_under dir var)
  get_property(_tests DIRECTORY ${dir} PROPERTY TESTS)
  get_property(_subs DIRECTORY ${dir} PROPERTY SUBDIRECTORIES)
  foreach(s ${_subs})
    _mbfb_tests_under(${s} _more)
    list(APPEND _tests ${_more})
  endforeach()
  set(${var} ${_tests} PARENT_SCOPE)
endfunction()

_mbfb_tests_under(${CMAKE_SOURCE_DIR} _others)
# each folder's part: a function that makes its tests here and appends their names to the
# global property MBFB_RUN_LAST_TESTS (registered in MBFB_RUN_LAST by tests/shims, tests/soak)
get_property(_makers GLOBAL PROPERTY MBFB_RUN_LAST)
foreach(_f ${_makers})
  cmake_language(CALL ${_f})
endforeach()
get_property(_last GLOBAL PROPERTY MBFB_RUN_LAST_TESTS)
foreach(_t ${_last})
  set_tests_properties(${_t} PROPERTIES DEPENDS "${_others}")
endforeach()
