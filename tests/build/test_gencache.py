"""scripts/gencache.py: the generators' outputs kept by content.

A stand-in generator (this file run as a script) counts its runs, so each test sees whether the
command ran or the cache answered. Then the two real generators the build keeps, iec2c and
STruC++, are each run twice on the same input in folders of different names: a cache is only
sound for a generator whose output holds nothing but what the key has (no path, no time).
"""
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
GENCACHE = os.path.join(ROOT, "scripts", "gencache.py")
PROGRAM = """PROGRAM main
  VAR
    n : INT;
    t : TON;
  END_VAR
  t(IN := n < 10, PT := T#50ms);
  IF t.Q THEN n := n + 1; END_IF;
END_PROGRAM
CONFIGURATION Config0
  RESOURCE Res0 ON PLC
    TASK tk (INTERVAL := T#20ms, PRIORITY := 0);
    PROGRAM inst WITH tk : main;
  END_RESOURCE
END_CONFIGURATION
"""


def require(what):
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        pytest.fail(f"{what} (MBFB_REQUIRE_TOOLCHAIN=1)")
    pytest.skip(what)


@pytest.fixture
def env(tmp_path):
    e = dict(os.environ, MBFB_TOOL_CACHE=str(tmp_path / "cache"))
    e.pop("MBFB_GENCACHE", None)
    return e


def gen(cwd, env, *opts, fail=False, skip_out=False, inp="in.txt"):
    """The stand-in generator through gencache: reads inp, writes out.a and out.b, counts."""
    cmd = [sys.executable, GENCACHE, "fake", *opts, "--in", inp, "--out", "out.a", "--out", "out.b",
           "--", sys.executable, os.path.abspath(__file__), inp, str(cwd.parent / "runs"),
           "fail" if fail else ("one" if skip_out else "ok")]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)


def runs(tmp_path):
    p = tmp_path / "runs"
    return int(p.read_text()) if p.exists() else 0


def folder(tmp_path, name, text="x = 1\n"):
    d = tmp_path / name
    d.mkdir()
    (d / "in.txt").write_text(text)
    return d


def test_a_second_folder_with_the_same_input_is_answered_from_the_cache(tmp_path, env):
    a, b = folder(tmp_path, "clone-a"), folder(tmp_path, "clone-b")
    assert gen(a, env).returncode == 0 and runs(tmp_path) == 1
    assert gen(b, env).returncode == 0 and runs(tmp_path) == 1, "the cache did not answer"
    for f in ("out.a", "out.b"):
        assert (a / f).read_bytes() == (b / f).read_bytes()
    assert (b / "out.a").read_text() == "A x = 1\n"


def test_a_changed_input_or_key_runs_the_generator(tmp_path, env):
    a = folder(tmp_path, "a")
    gen(a, env)
    (a / "in.txt").write_text("x = 2\n")
    assert gen(a, env).returncode == 0 and runs(tmp_path) == 2
    assert (a / "out.a").read_text() == "A x = 2\n"
    assert gen(a, env, "--key", "tool-2").returncode == 0 and runs(tmp_path) == 3
    assert gen(a, env, "--key", "tool-2").returncode == 0 and runs(tmp_path) == 3


def test_a_failed_or_incomplete_run_is_not_kept(tmp_path, env):
    a = folder(tmp_path, "a")
    r = gen(a, env, fail=True)
    assert r.returncode == 3 and runs(tmp_path) == 1
    assert gen(a, env, skip_out=True).returncode == 0 and runs(tmp_path) == 2
    assert gen(a, env).returncode == 0 and runs(tmp_path) == 3, "an incomplete run was kept"


def test_no_cache_when_turned_off(tmp_path, env):
    a = folder(tmp_path, "a")
    env["MBFB_GENCACHE"] = "0"
    gen(a, env)
    gen(a, env)
    assert runs(tmp_path) == 2
    assert not (tmp_path / "cache").exists()


def twice(tmp_path, name, run):
    """run(folder) in two folders of different names; their outputs, file by file."""
    outs = []
    for d in (tmp_path / f"{name}-one", tmp_path / "second" / f"{name}-two"):
        d.mkdir(parents=True)
        (d / "program.st").write_text(PROGRAM)
        r = run(d)
        assert r.returncode == 0, r.stdout + r.stderr
        outs.append({f: (d / f).read_bytes() for f in sorted(os.listdir(d)) if f != "program.st"})
    assert outs[0].keys() == outs[1].keys()
    for f in outs[0]:
        assert outs[0][f] == outs[1][f], f"{name}: {f} differs between two runs on the same input"
    return outs[0]


def test_iec2c_output_depends_on_its_input_alone(tmp_path):
    iec2c, lib = os.environ.get("MBFB_IEC2C", ""), os.environ.get("MBFB_IEC_LIB", "")
    if not (iec2c and os.path.isfile(iec2c)):
        require("no iec2c in this build (MBFB_IEC2C)")
    out = twice(tmp_path, "iec2c", lambda d: subprocess.run(
        [iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "-I", lib, "program.st"], cwd=d,
        capture_output=True, text=True))
    # what tools/runner/st_program.cmake keeps
    assert {"Config0.c", "Config0.h", "LOCATED_VARIABLES.h", "POUS.c", "POUS.h", "Res0.c",
            "VARIABLES.csv"} == set(out)


def test_strucpp_output_depends_on_its_input_alone(tmp_path):
    node, cli = shutil.which("node"), os.environ.get("MBFB_STRUCPP_CLI", "")
    if not (node and cli and os.path.isfile(cli)):
        require(f"STruC++ is not built ({cli or 'MBFB_STRUCPP_CLI unset'})")
    # by absolute paths from elsewhere, as the build runs it
    out = twice(tmp_path, "strucpp", lambda d: subprocess.run(
        [node, cli, str(d / "program.st"), "-o", str(d / "program.cpp")], cwd=tmp_path,
        capture_output=True, text=True))
    assert set(out) == {"program.cpp", "program.hpp"}   # what v4/CMakeLists.txt keeps


if __name__ == "__main__":   # the stand-in generator: IN RUNS MODE
    src, counter, mode = sys.argv[1:4]
    n = int(open(counter).read()) if os.path.exists(counter) else 0
    open(counter, "w").write(str(n + 1))
    if mode == "fail":
        sys.exit(3)
    text = open(src).read()
    open("out.a", "w").write("A " + text)
    if mode == "ok":
        open("out.b", "w").write("B " + text)
