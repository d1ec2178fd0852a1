"""The web-upload bundle in OpenPLC's own upload handler, then a shell: plc_lib/mkbundle.sh makes
one .st carrying the blocks, the program and the shims as (*FILE:...*) lines; OpenPLC's handler
(webserver/openplc.py compile_program, run from the scratch copy) writes the shims into core/ and
compiles it, with the library NOT installed. Then plc_lib/install.sh takes over what the bundle
wrote (and nothing foreign), the plain example compiles, and uninstall.sh gives back the OpenPLC
as it was before either. (The same bundle through the web page, started and read over Modbus:
test_web.py.)"""
import os
import subprocess
import sys

import pytest

import oplc
from test_install import changes, snapshot

EXAMPLE = os.path.join(oplc.ROOT, "examples", "heat_treat_st", "heat_treat_st.st")
SUMS = "webserver/core/mbfb_bundle.sha256"
C_BLOCKS = "webserver/core/c_blocks.h"


def library_part(snap):
    """The paths of a snapshot that are the library's or that the library edits; the rest is
    OpenPLC's and the uploaded programs'."""
    def ours(p):
        name = os.path.basename(p)
        return name.startswith("mbfb") or p in (C_BLOCKS, "webserver/lib/standard_FB.txt")
    return {p: v for p, v in snap.items() if ours(p)}


def rest(snap):
    lib = library_part(snap)
    return {p: v for p, v in snap.items() if p not in lib}


def upload_through_handler(scratch, bundle, name):
    """OpenPLC's handler, imported from the scratch copy (it only uses the standard library),
    on st_files/name; returns its compilation log."""
    os.replace(bundle, os.path.join(scratch.web, "st_files", name))
    code = ("import sys, time; sys.path.insert(0, '.'); import openplc\n"
            "r = openplc.runtime(); r.compile_program(%r)\n"
            "end = time.time() + 600; s = ''\n"
            "while 'finished' not in s and time.time() < end:\n"
            "    s = r.compilation_status(); time.sleep(0.2)\n"
            "print(s)\n") % name
    r = subprocess.run([sys.executable, "-c", code], cwd=scratch.web, capture_output=True, text=True)
    assert "Compilation finished successfully" in r.stdout, r.stdout + r.stderr
    return r.stdout


def test_bundle_then_install_then_uninstall(scratch, dist, tmp_path):
    root = scratch.dir
    s0 = snapshot(root)
    bundle = tmp_path / "bundle.st"
    with open(bundle, "w") as f:
        subprocess.run([os.path.join(oplc.ROOT, "plc_lib", "mkbundle.sh"), "--dist", dist, EXAMPLE],
                       stdout=f, check=True)
    text = bundle.read_text()
    assert "(*FILE:mbfb.h " in text and "(*FILE:mbfb_bundle.sha256 " in text and "(*DBG:" in text
    upload_through_handler(scratch, bundle, "bundle.st")

    # What the handler wrote: every shim, c_blocks.h as install.sh writes it into a fresh
    # OpenPLC but for the final newline, and the sums of all of them, which match.
    core = os.path.join(scratch.web, "core")
    with open(os.path.join(dist, "MANIFEST")) as f:
        shims = [p.strip() for p in f if p.startswith("webserver/core/")]
    for s in shims:
        assert os.path.exists(os.path.join(root, s)), f"upload did not write {s}"
    cb = open(os.path.join(root, C_BLOCKS)).read()
    assert cb.startswith("// Empty file\n/* mbfb BEGIN") and cb.endswith('#include "mbfb.h"\n/* mbfb END */')
    r = subprocess.run(["sha256sum", "-c", "--quiet", SUMS], cwd=root, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert len(open(os.path.join(root, SUMS)).read().splitlines()) == len(shims) + 1
    # The program file OpenPLC kept is plain ST again (FILE/DBG lines stripped by openplc.py).
    kept = open(os.path.join(scratch.web, "st_files", "bundle.st")).read()
    assert "(*FILE:" not in kept and "(*DBG:" not in kept and "FUNCTION_BLOCK TempCtrl_MVD94" in kept
    s1 = snapshot(root)
    bundled = {p: open(os.path.join(root, p), "rb").read() for p in library_part(s1)}

    # A file the bundle wrote and someone changed since is foreign: install.sh refuses, untouched.
    edited = os.path.join(root, shims[1])
    original = open(edited, "rb").read()
    with open(edited, "ab") as f:
        f.write(b"\n// changed on the PLC\n")
    s_edit = snapshot(root)
    with pytest.raises(RuntimeError, match="not installed by us"):
        scratch.install(dist)
    assert snapshot(root) == s_edit
    with open(edited, "wb") as f:
        f.write(original)

    out = scratch.install(dist)
    assert "took over the %d files a web-upload bundle wrote" % (len(shims) + 1) in out, out
    s_inst = snapshot(root)
    assert rest(s_inst) == rest(s1), "install.sh changed files that are not the library's"
    assert SUMS not in s_inst
    assert "nothing changed" in scratch.install(dist)
    # The library works: the plain example (not its bundle) compiles with OpenPLC's script.
    scratch.compile(EXAMPLE, "plain.st")
    s3 = snapshot(root)
    assert library_part(s3) == library_part(s_inst)

    scratch.uninstall()
    s2 = snapshot(root)
    assert library_part(s2) == library_part(s0), \
        f"not as before the bundle: {sorted(changes(library_part(s2), library_part(s0)))}"
    assert rest(s2) == rest(s3), "uninstall.sh changed files that are not the library's"
    # What install.sh left after the bundle is what it writes into a fresh OpenPLC.
    scratch.install(dist)
    assert library_part(snapshot(root)) == library_part(s_inst)
    scratch.uninstall()

    # uninstall.sh straight after a bundle (no install.sh) gives back the same tree.
    for p, data in bundled.items():
        with open(os.path.join(root, p), "wb") as f:
            f.write(data)
    assert library_part(snapshot(root)) == library_part(s1)
    scratch.uninstall()
    assert library_part(snapshot(root)) == library_part(s0)


def test_foreign_bundle_sums_are_refused(scratch, dist):
    """A file at the bundle's sums path that is not in its format is not ours: nothing changes."""
    with open(os.path.join(scratch.dir, SUMS), "w") as f:
        f.write("my own notes\n")
    before = snapshot(scratch.dir)
    for script in ("install.sh", "uninstall.sh"):
        with pytest.raises(RuntimeError, match="was not written by a bundle"):
            scratch.run_script(script, *(["--dist", dist] if script == "install.sh" else []))
        assert snapshot(scratch.dir) == before
