# The tests' serial lines between processes (tests/shims/testline.c): the simulator offers its
# pty as a line whose bytes go through a Unix socket in MBFB_TESTLINE_DIR, and the masters'
# processes, with mbfb_testline preloaded, take it (tools/sim/modsim/lineoffer.py). A pty's
# bytes pass through a kernel worker thread that a loaded machine held for seconds.
# mbfb_testlines(): every test of the calling directory gets the two variables (its own
# LD_PRELOAD, where a test sets one, wins for the process it starts: a pty as before).
set(MBFB_TESTLINE_ENV "LD_PRELOAD=$<TARGET_FILE:mbfb_testline>"
    "MBFB_TESTLINE_DIR=${CMAKE_BINARY_DIR}/tmp")
function(mbfb_testlines)
  get_directory_property(_tests TESTS)
  foreach(_t ${_tests})
    set_property(TEST ${_t} APPEND PROPERTY ENVIRONMENT ${MBFB_TESTLINE_ENV})
  endforeach()
endfunction()
