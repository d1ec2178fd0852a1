"""The web-upload route: plc_lib/mkbundle.sh makes one .st carrying the blocks, the program and
the shims as (*FILE:...*) lines; OpenPLC's own upload handler (webserver/openplc.py
compile_program, run from the scratch copy) must write the shims into core/ and compile it,
with the library NOT installed."""
import os
import subprocess
import sys
import time

import oplc

EXAMPLE = os.path.join(oplc.ROOT, "examples", "heat_treat_st", "heat_treat_st.st")


def test_bundle_compiles_through_openplc_upload_handler(scratch, dist, tmp_path):
    bundle = tmp_path / "bundle.st"
    with open(bundle, "w") as f:
        subprocess.run([os.path.join(oplc.ROOT, "plc_lib", "mkbundle.sh"), "--dist", dist, EXAMPLE],
                       stdout=f, check=True)
    text = bundle.read_text()
    assert "(*FILE:mbfb.h " in text and "(*FILE:mbfb_st.h " in text \
        and "(*FILE:c_blocks.h #include \"mbfb_st.h\"*)" in text
    assert "(*DBG:" in text
    name = "bundle.st"
    os.replace(bundle, os.path.join(scratch.web, "st_files", name))
    # OpenPLC's handler, imported from the scratch copy (it only uses the standard library).
    code = ("import sys, time; sys.path.insert(0, '.'); import openplc\n"
            "r = openplc.runtime(); r.compile_program(%r)\n"

            "end = time.time() + 600; s = ''\n"
            "while 'finished' not in s and time.time() < end:\n"
            "    s = r.compilation_status(); time.sleep(0.2)\n"
            "print(s)\n") % name
    r = subprocess.run([sys.executable, "-c", code], cwd=scratch.web, capture_output=True, text=True)
    assert "Compilation finished successfully" in r.stdout, r.stdout + r.stderr
    core = os.path.join(scratch.web, "core")
    with open(os.path.join(dist, "MANIFEST")) as f:
        shims = [os.path.basename(p.strip()) for p in f if p.startswith("webserver/core/")]
    for s in shims:
        assert os.path.exists(os.path.join(core, s)), f"upload did not write core/{s}"
    assert open(os.path.join(core, "c_blocks.h")).read().strip() == '#include "mbfb_st.h"'
    # The program file OpenPLC kept is plain ST again (FILE/DBG lines stripped by openplc.py).
    kept = open(os.path.join(scratch.web, "st_files", name)).read()
    assert "(*FILE:" not in kept and "(*DBG:" not in kept and "FUNCTION_BLOCK TempCtrl_MVD94" in kept
