"""plc_lib/install.sh and uninstall.sh on a scratch copy of OpenPLC v3: they change exactly
what they say (files named mbfb*, one marker block in standard_FB.txt and c_blocks.h), are
idempotent, and uninstall restores the tree byte for byte."""
import hashlib
import os

import pytest

EDITED = {"webserver/lib/standard_FB.txt", "webserver/core/c_blocks.h"}


def snapshot(root):
    snap = {}
    for d, _, files in os.walk(root):
        for f in files:
            p = os.path.join(d, f)
            rel = os.path.relpath(p, root)
            with open(p, "rb") as fh:
                snap[rel] = (hashlib.sha256(fh.read()).hexdigest(), os.stat(p).st_mode)
    return snap


def changes(a, b):
    return {k for k in a.keys() | b.keys() if a.get(k) != b.get(k)}


def without_block(path):
    """The file's lines outside our marker block, and the block itself."""
    outside, block, inside = [], [], False
    with open(path) as f:
        for line in f:
            if "mbfb BEGIN" in line:
                inside = True
            (block if inside else outside).append(line)
            if inside and "mbfb END" in line:
                inside = False
    return "".join(outside), block


def test_install_changes_only_ours_and_uninstall_restores(scratch, dist):
    root = scratch.dir
    before = snapshot(root)
    originals = {f: open(os.path.join(root, f)).read() for f in EDITED}
    scratch.install(dist)
    after = snapshot(root)
    with open(os.path.join(dist, "MANIFEST")) as f:
        ours = {line.strip() for line in f if line.strip()} | {"webserver/lib/mbfb.manifest"}
    assert changes(before, after) == ours | EDITED
    assert all(os.path.basename(p).startswith("mbfb") for p in ours)
    for f in EDITED:
        rest, block = without_block(os.path.join(root, f))
        assert rest == originals[f], f"{f}: changed outside the marker block"
        assert len(block) == 3, f"{f}: marker block is {block}"
    std = open(os.path.join(root, "webserver/lib/standard_FB.txt")).read()
    # After "enable code generation": matiec generates our blocks' C into each program.
    assert std.index("{enable code generation}") < std.index('{#include "mbfb.txt" }')
    for f in ours - {"webserver/lib/mbfb.manifest"}:
        assert open(os.path.join(root, f), "rb").read() == open(os.path.join(dist, f), "rb").read()

    assert "nothing changed" in scratch.install(dist)
    assert snapshot(root) == after, "second install changed the tree"
    scratch.uninstall()
    assert snapshot(root) == before, "uninstall did not restore the tree"
    assert "nothing changed" in scratch.uninstall()
    assert snapshot(root) == before


def test_install_without_dist_generates_with_targets_iec2c(scratch, dist):
    """install.sh alone runs mkdist.sh with that OpenPLC's iec2c: same files as the build's."""
    scratch.install()
    with open(os.path.join(dist, "MANIFEST")) as f:
        for rel in (line.strip() for line in f):
            assert open(os.path.join(scratch.dir, rel), "rb").read() == \
                open(os.path.join(dist, rel), "rb").read(), rel


def test_install_refuses_to_overwrite_a_foreign_file(scratch, dist):
    foreign = os.path.join(scratch.web, "core", "mbfb.h")
    with open(foreign, "w") as f:
        f.write("/* someone else's mbfb.h */\n")
    before = snapshot(scratch.dir)
    with pytest.raises(RuntimeError, match="not installed by us"):
        scratch.install(dist)
    assert snapshot(scratch.dir) == before


def test_c_blocks_without_final_newline_is_restored_exactly(scratch, dist):
    path = os.path.join(scratch.web, "core", "c_blocks.h")
    with open(path, "w") as f:
        f.write("// my own C block\nint mine(void);")  # no final newline
    before = snapshot(scratch.dir)
    scratch.install(dist)
    assert open(path).read().startswith("// my own C block\nint mine(void);\n/* mbfb BEGIN")
    scratch.uninstall()
    assert snapshot(scratch.dir) == before


def test_bad_target_is_refused_and_untouched(tmp_path):
    import subprocess
    (tmp_path / "webserver").mkdir()
    r = subprocess.run([os.path.join(os.path.dirname(__file__), "..", "..", "plc_lib", "install.sh"),
                        str(tmp_path)], capture_output=True, text=True)
    assert r.returncode != 0 and "not an OpenPLC v3 installation" in r.stderr
    assert os.listdir(tmp_path) == ["webserver"] and os.listdir(tmp_path / "webserver") == []
