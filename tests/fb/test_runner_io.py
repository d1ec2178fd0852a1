"""The runner (fb_host.cpp --run) on the example program, without a simulator
(its blocks just report no port): the snapshot of located variables, the control socket's
set/get with every kind of bad input, --set, and a clean stop. Run by ctest (fb_runner_io) as
    RUNNER_EXE=build/tools/runner/heat_treat_st_runner python -m pytest tests/fb/test_runner_io.py
"""
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tools", "runner"))
from runner import Runner, RunnerError  # noqa: E402

EXE = os.environ.get("RUNNER_EXE", "")
P = "CONFIG0.RES0.HEATTREAT."   # the example's program instance (its CONFIGURATION)


@pytest.fixture(scope="module")
def plc():
    assert os.access(EXE, os.X_OK), f"RUNNER_EXE={EXE!r} is not the runner"
    with Runner(EXE, sets={P + "BUSPORT": "/nonexistent/mbfb-no-port"}) as r:
        yield r


def test_snapshot_lists_the_located_variables_consistently(plc):
    snap = plc.snapshot()
    # Exactly the example's located variables (heat_treat_st.st), by IEC address.
    assert set(snap) == {"scan", "QW", "MW", "QX"}
    # %QW0..8 values and status, %QW9/%QW10 the set point requests' status (0 = none yet),
    # %QW11..15 the product held and the zones' recipe status and field, %QW16..23 the energy
    # meter's four REALs as read, %QW24 its ErrorID
    assert sorted(snap["QW"], key=int) == [str(i) for i in range(25)]
    assert sorted(snap["MW"]) == ["0", "1", "2"]
    assert sorted(snap["QX"]) == [f"0.{i}" for i in range(8)] + ["1.0", "1.1"]
    # Written between two scans: the heartbeat (%QW8, +1 per scan) equals the scan count.
    assert snap["QW"]["8"] == snap["scan"] & 0xFFFF
    # No port: nothing valid, and the blocks say why (ErrorID != 0 in %QW2/%QW5/%QW7), once
    # each block has tried to open it (a wait for that, not a speed check).
    deadline = time.monotonic() + 30
    while not all((snap := plc.snapshot())["QW"][k] != 0 for k in ("2", "5", "7")):
        assert time.monotonic() < deadline, f"no ErrorID for the missing port: {snap['QW']}"
        time.sleep(0.05)
    assert not any(snap["QX"][k] for k in ("0.0", "0.3", "0.6"))
    assert all(snap["QW"][k] != 0 for k in ("2", "5", "7"))
    assert snap["QW"]["9"] == 0 and snap["QW"]["10"] == 0  # no request: nothing to report


def test_runs_at_its_task_period_not_faster(plc):
    # Until 20 more scans are seen (a wait for them, however slow the machine): a T#50ms task
    # never runs more scans than real time allows (+ snapshot age, 200 ms each end).
    s0, t0 = plc.snapshot()["scan"], time.monotonic()
    deadline = t0 + 60
    while (s1 := plc.snapshot()["scan"]) < s0 + 20:
        assert time.monotonic() < deadline, f"the runner scanned {s1 - s0} times in 60 s"
        time.sleep(0.05)
    t1 = time.monotonic()
    assert s1 - s0 <= (t1 - t0 + 0.4) / 0.050 + 1


@pytest.mark.parametrize("name, text, back", [
    ("%MW0", "-5", "-5"), ("MW0", "32767", "32767"), ("mw1", "-32768", "-32768"),
    ("%MW0", "0x10", "16"),
    ("%QW2", "65535", "65535"),                           # WORD (the program overwrites it)
    ("%QX0.0", "TRUE", "true"), ("%QX0.0", "0", "false"),  # BOOL
    (P + "BAND", "12.5", "12.5"),                          # REAL
    (P + "ZONE1.STALETIME", "1500", "1500"),               # TIME, in ms
    (P + "BUSPORT", "'/dev/ttyUSB1'", '"/dev/ttyUSB1"'),   # STRING, quotes optional
    (P + "BUSPORT", 'a "b" c', '"a \\"b\\" c"'),
])
def test_set_then_get(plc, name, text, back):
    assert plc.command(f"set {name} {text}") == ""
    if not name.startswith("%Q"):  # the program writes its outputs every scan
        assert plc.command(f"get {name}") == back


@pytest.mark.parametrize("line, why", [
    ("set %MW0 32768", "out of range 32768 for INT %MW0"),
    ("set %MW0 -32769", "out of range"),
    ("set %QW2 -1", "out of range -1 for WORD"),
    ("set %QW2 65536", "out of range"),
    ("set %MW0 12abc", "not a value 12abc for INT"),
    ("set %MW0 1.5", "not a value"),
    ("set %QX0.0 yes", "not a value yes for BOOL"),
    (f"set {P}BAND 1e39", "out of range"),
    (f"set {P}BAND nan", "not a value"),
    (f"set {P}BUSPORT {'x' * 127}", "out of range"),
    ("set %MW9 1", "no variable %MW9"),
    ("get %IX0.0", "no variable"),
    ("set %MW0", "expected 'set NAME VALUE' or 'get NAME'"),
    ("get %MW0 1", "expected"),
    ("poke %MW0 1", "expected"),
    ("", "expected"),
])
def test_bad_commands_are_refused_and_change_nothing(plc, line, why):
    plc.command("set %MW0 7")
    plc.command(f"set {P}BAND 3.5")
    plc.command(f"set {P}BUSPORT /nonexistent/mbfb-no-port")
    with pytest.raises(RunnerError, match=re.escape(why)):
        plc.command(line)
    assert plc.command("get %MW0") == "7"
    assert plc.command(f"get {P}BAND") == "3.5"
    assert plc.command(f"get {P}BUSPORT") == '"/nonexistent/mbfb-no-port"'


def test_write_lands_in_the_snapshot_and_the_modbus_view(plc):
    plc.write(1025, 1234)  # OpenPLC's holding register 1025 = %MW1
    deadline = time.monotonic() + 5
    while plc.snapshot()["MW"]["1"] != 1234:
        assert time.monotonic() < deadline, "the snapshot never showed %MW1 = 1234"
        time.sleep(0.05)
    assert plc.hr(1024, 2)[1] == 1234
    assert plc.hr(1030, 1) == [0]  # not bound to a variable: reads 0, as on OpenPLC
    with pytest.raises(RunnerError, match="no variable %MW6"):
        plc.write(1030, 1)             # ... but a write to it is refused, not dropped
    with pytest.raises(RunnerError, match="holding register 2048"):
        plc.write(2048, 1)


def test_several_clients_and_split_lines(plc):
    a = socket.socket(socket.AF_UNIX)
    b = socket.socket(socket.AF_UNIX)
    for s in (a, b):
        s.settimeout(5)
        s.connect(plc.control_path)
    a.sendall(b"get %M")
    b.sendall(b"set %MW0 42\n")
    assert b.recv(100) == b"ok\n"
    a.sendall(b"W0\nget %MW0\r\n")
    got = b""
    while got.count(b"\n") < 2:
        got += a.recv(100)
    assert got == b"ok 42\nok 42\n"
    a.close()
    b.close()


def run(*args, timeout=10):
    return subprocess.run([EXE, *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args, why", [
    (["--set", P + "NOSUCH=1"], "no variable"),
    (["--set", P + "BAND=abc"], "not a value abc for REAL"),
    (["--set", P + "BAND"], "expected NAME=VALUE"),
    (["--control", "/nonexistent/dir/sock"], "control socket"),
    (["--seconds", "-5"], "--seconds wants a number of seconds >= 0, not '-5'"),
    (["--seconds", "abc"], "--seconds wants a number of seconds >= 0, not 'abc'"),
    (["--seconds", "nan"], "--seconds wants a number of seconds >= 0, not 'nan'"),
    (["--seconds", "1e999"], "--seconds wants a number of seconds >= 0, not '1e999'"),
    (["--seconds"], "--seconds needs a value"),
    (["--snapshot"], "--snapshot needs a value"),
    (["--snapshot", ""], "--snapshot needs a non-empty value"),
    (["--bogus"], "unknown option '--bogus'"),
])
def test_bad_arguments_exit_2_before_any_scan(args, why):
    """Every command-line error: exit 2, one line on stderr naming it, no scan run."""
    r = run("--run", *args)
    assert r.returncode == 2
    assert r.stderr.startswith("runner: ") and r.stderr.count("\n") == 1, r.stderr
    assert why in r.stderr
    assert "stopped after" not in r.stderr and r.stdout == ""


def test_usage_without_run():
    r = run("--snapshot", "x")
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "--run missing (usage: " in r.stderr


def test_help_prints_the_usage_and_exits_0():
    r = run("--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: ") and "--run [--snapshot FILE]" in r.stdout


def test_sigterm_stops_cleanly_and_removes_the_socket():
    with tempfile.TemporaryDirectory() as d:
        sock, snap = os.path.join(d, "c.sock"), os.path.join(d, "s.json")
        p = subprocess.Popen([EXE, "--run", "--control", sock, "--snapshot", snap,
                              "--set", P + "BUSPORT=/nonexistent/x"],
                             stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 10
            while not os.path.exists(snap):
                assert time.monotonic() < deadline and p.poll() is None
                time.sleep(0.05)
            os.kill(p.pid, signal.SIGTERM)
            _, err = p.communicate(timeout=10)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
        assert p.returncode == 0, err
        assert re.search(r"stopped after \d+ scans", err)
        assert not os.path.exists(sock)
        assert not os.path.exists(snap + ".tmp")


def test_seconds_limit():
    r = run("--run", "--seconds", "0.5", "--set", P + "BUSPORT=/nonexistent/x")
    assert r.returncode == 0
    scans = int(re.search(r"stopped after (\d+) scans", r.stderr).group(1))
    assert scans == 10  # 0.5 s of a T#50ms task
