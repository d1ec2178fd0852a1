"""The demo's command lines: demo.sh, examples/heat_treat_st/live.py and
tools/openplc/install-openplc.sh. Every bad input ends in one line on stderr naming it and exit
2, before anything is built, installed or started; --help describes each program's own options.
install-openplc.sh is run against a local stand-in repository (a git repo whose install.sh
records how it was called), never against OpenPLC's. Run by ctest (fb_demo_cli)."""
import os
import subprocess
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEMO = os.path.join(ROOT, "demo.sh")
LIVE = os.path.join(ROOT, "examples", "heat_treat_st", "live.py")
INSTALL = os.path.join(ROOT, "tools", "openplc", "install-openplc.sh")


def run(cmd, env=None, timeout=60):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
                          env=dict(os.environ, **(env or {})))


def one_line_error(r, prefix, why):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(prefix), r.stderr
    assert why in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("args, why", [
    (["--time-scale", "-5"], "--time-scale wants a number > 0 (up to 10000), not '-5'"),
    (["--time-scale", "0"], "not '0'"),
    (["--time-scale", "abc"], "not 'abc'"),
    (["--time-scale", "1e3"], "not '1e3'"),
    (["--time-scale=-5"], "not '-5'"),
    (["--time-scale"], "--time-scale needs a value"),
    (["--seconds", "-1"], "--seconds wants a number of seconds >= 0, not '-1'"),
    (["--seconds", "soon"], "not 'soon'"),
    (["--seconds", ""], "--seconds needs a non-empty value"),
    (["--build-dir"], "--build-dir needs a value"),
    (["--build-dir", ""], "--build-dir needs a non-empty value"),
    (["--runner", "--openplc"], "--runner and --openplc exclude each other"),
    (["--bogus"], "unknown option '--bogus'"),
    (["extra"], "unknown option 'extra'"),
    (["--runner=yes"], "unknown option 'yes'"),
    (["--install-openplc", "a", "b"], "--install-openplc takes at most one directory"),
])
def test_demo_bad_command_line(args, why):
    one_line_error(run([DEMO, *args]), "demo.sh: ", why)


def test_demo_help_describes_its_own_options():
    r = run([DEMO, "--help"])
    assert r.returncode == 0 and r.stderr == ""
    for opt in ("--runner", "--openplc", "--build-dir DIR", "--time-scale F", "--seconds N",
                "--install-openplc [DIR]", "MATIEC_SOURCE_DIR", "OPENPLC_HOME"):
        assert opt in r.stdout, opt
    assert "--backend" not in r.stdout  # live.py's, not demo's


@pytest.mark.parametrize("args, why", [
    (["--time-scale", "-5"], "must be a number > 0: '-5'"),
    (["--time-scale", "nan"], "must be a number > 0: 'nan'"),
    (["--seconds", "x"], "not a number: 'x'"),
    (["--seconds", "-2"], "must be a number >= 0: '-2'"),
    (["--backend", "plc"], "invalid choice: 'plc'"),
    (["--backend", "runner"], "--backend runner needs --runner-exe"),
    (["--nope"], "unrecognized arguments: --nope"),
])
def test_live_bad_command_line(args, why):
    one_line_error(run([sys.executable, LIVE, *args]), "live.py: ", why)


@pytest.mark.parametrize("args, why", [
    (["--force"], "unknown option '--force'"),
    (["a", "b"], "one directory at most"),
])
def test_install_openplc_bad_command_line(args, why):
    one_line_error(run([INSTALL, *args]), "install-openplc.sh: ", why)


def test_install_openplc_refuses_a_non_empty_directory():
    with tempfile.TemporaryDirectory(prefix="mbfb-oplc-") as d:
        open(os.path.join(d, "mine.txt"), "w").close()
        one_line_error(run([INSTALL, d]), "install-openplc.sh: ", f"{d} exists and is not empty")
        assert os.listdir(d) == ["mine.txt"]


def test_install_openplc_clones_and_runs_the_installer_of_the_repository():
    """A stand-in for OpenPLC's repository: its install.sh records its arguments and cwd."""
    with tempfile.TemporaryDirectory(prefix="mbfb-oplc-") as d:
        repo, dest = os.path.join(d, "repo"), os.path.join(d, "OpenPLC_v3")
        os.makedirs(repo)
        with open(os.path.join(repo, "install.sh"), "w") as f:
            f.write('#!/bin/sh\necho "$(pwd) $*" > installed.txt\n')
        os.chmod(os.path.join(repo, "install.sh"), 0o755)
        git = ["git", "-C", repo, "-c", "user.name=t", "-c", "user.email=t@example.invalid"]
        subprocess.run(["git", "init", "-q", repo], check=True)
        subprocess.run(git + ["add", "install.sh"], check=True)
        subprocess.run(git + ["commit", "-q", "-m", "stand-in"], check=True)
        r = run([INSTALL, dest], env={"OPENPLC_GIT_URL": repo})
        assert r.returncode == 0, r.stderr
        with open(os.path.join(dest, "installed.txt")) as f:
            assert f.read().split() == [os.path.realpath(dest), "linux"]
        assert f"export OPENPLC_HOME={dest}" in r.stdout
        # a second run: a directory that is not OpenPLC (no webserver/iec2c) is refused
        one_line_error(run([INSTALL, dest], env={"OPENPLC_GIT_URL": repo}), "install-openplc.sh: ",
                       "exists and is not empty")
        # an installed OpenPLC is left alone
        os.makedirs(os.path.join(dest, "webserver"))
        iec2c = os.path.join(dest, "webserver", "iec2c")
        open(iec2c, "w").close()
        os.chmod(iec2c, 0o755)
        r = run([INSTALL, dest], env={"OPENPLC_GIT_URL": repo})
        assert r.returncode == 0 and "already installed" in r.stdout
