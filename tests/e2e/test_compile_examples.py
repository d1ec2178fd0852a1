"""The examples compile with OpenPLC's own compile_program.sh once plc_lib is installed, and the
library survives OpenPLC recompiling programs (several programs in a row, blank one included)."""
import os

import oplc

EXAMPLES = [os.path.join(oplc.ROOT, "examples", d, d + ".st") for d in ("heat_treat_st", "heat_treat_ld")]


def test_examples_compile_and_library_survives_recompiles(scratch, dist):
    scratch.install(dist)
    progs = [p for p in EXAMPLES if os.path.exists(p)]
    assert len(progs) == 2, f"the two example programs, found: {progs}"
    blank = os.path.join(scratch.web, "st_files", "blank_program.st")
    # one example, the blank program, the other example: each compile after the first is a
    # recompile over the library as the first left it
    st, ld = progs
    for p in (st, blank, ld):
        out = scratch.compile(p, name=os.path.basename(p))
        assert "Compilation finished successfully" in out
        assert os.path.exists(os.path.join(scratch.web, "core", "openplc"))
    # Still installed exactly as before: a new install has nothing to do.
    assert "nothing changed" in scratch.install(dist)
