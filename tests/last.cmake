# The tests that run last, together: test_late's flavours (shims_late_*, tests/shims). Included
# at the end of the top CMakeLists.txt, where every other test exists: CMake 3.25 sets a test's
# properties only in the directory that made it, so these are made here.
#
# test_late holds late replies against reply timeouts of 200 to 400 ms. Beside ctest -j's other
# tests (8 at once on 2 cores, the burst of STruC++ tests after strucpp_build) three CI runs in a
# row failed one of its scenarios in two to five flavours at once; alone every flavour passed.
# Alone one after another they took 4.4 minutes of a CI run, mostly waiting. So they wait for
# every other test of the run (DEPENDS: an order only, ctest ignores a name that is not in the
# run) and then run beside each other only, in the time of the longest.

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
get_property(_last GLOBAL PROPERTY MBFB_LAST_SHIMS_TESTS)
foreach(_e ${_last})
  string(REPLACE ":" ";" _e ${_e})
  list(GET _e 0 _name)
  list(GET _e 1 _flavour)
  mbfb_shims_test(${_name} ${_flavour})
  set_tests_properties(${_name} PROPERTIES DEPENDS "${_others}")
endforeach()
