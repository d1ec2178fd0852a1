"""The command line (docs/contracts.md section 2), the receive rules (t3.5 / frame length),
--pace with and without ptyline, --serial, and the control protocol's error replies."""
import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from conftest import RawPort, crc, instrument
import simctl

MBSIM = simctl.MBSIM
PY = simctl.VENV_PYTHON if os.path.exists(simctl.VENV_PYTHON) else sys.executable
READ = crc("01 03 00 00 00 01")
GOOD = "01 03 02 03 E8 B8 FA"


def hexu(data):
    return data.hex(" ").upper()


def run_bad(*args):
    res = subprocess.run([PY, MBSIM, *args], capture_output=True, text=True, timeout=20)
    return res.returncode, res.stdout, res.stderr


@pytest.mark.parametrize("args,message", [
    (["--pty", "--device", "plc9:1"], "KIND"),
    (["--pty", "--device", "mvd94:1", "--device", "fdc100:1"], "share an address"),
    (["--pty", "--format", "9X1", "--device", "mvd94:1"], "format"),
    (["--pty", "--device", "mts9:1:framing=ascii", "--device", "mts9:2:framing=rtu"],
     "one framing"),
    (["--pty", "--device", "mts9:1:framing=nocrc", "--device", "mvd94:2"], "only mts9"),
    (["--pty", "--device", "mvd94:1:SPOF=5000"], "out of range"),
    (["--pty", "--device", "mvd94:1:FOO=1"], "no register"),
    (["--tcp", "0.0.0.0:0", "--device", "mvd94:1"], "127.0.0.1"),
    (["--pty"], "--device"),
    (["--device", "mvd94:1"], "required"),
])
def test_bad_command_lines(args, message):
    code, out, err = run_bad(*args)
    assert code == 2 and out == "" and message in err


def test_ready_line_sigterm_sigint_and_cleanup(tmp_path):
    link, ctl = str(tmp_path / "port"), str(tmp_path / "ctl.sock")
    for sig in (signal.SIGTERM, signal.SIGINT):
        proc = subprocess.Popen([PY, MBSIM, "--pty", "--link", link, "--control", ctl,
                                 "--device", "mvd94:1:SV=1000"], stdout=subprocess.PIPE,
                                text=True)
        try:
            line = proc.stdout.readline()
            assert line == f"PTY {link}\n"
            assert os.path.realpath(link).startswith("/dev/pts/") and os.path.exists(ctl)
            raw = RawPort(link)
            assert hexu(raw.xfer(READ)) == GOOD        # served as soon as it is printed
            raw.close()
        finally:
            os.kill(proc.pid, sig)
            assert proc.wait(10) == 0
            assert proc.stdout.read() == ""            # exactly one line
            proc.stdout.close()
        assert not os.path.lexists(link) and not os.path.exists(ctl)


def test_serial_device_mode():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        with simctl.Simulator(["mvd94:1:SV=1000"], transport="serial", serial=path) as sim:
            assert sim.ready_line == f"SERIAL {path}"
            os.write(master, bytes.fromhex(READ))
            got, end = b"", time.monotonic() + 2
            os.set_blocking(master, False)
            while len(got) < 7 and time.monotonic() < end:
                try:
                    got += os.read(master, 64)
                except BlockingIOError:
                    time.sleep(0.01)
            assert hexu(got) == GOOD
    finally:
        os.close(master)
        os.close(slave)


def test_frame_end_rules(raw_factory):
    with simctl.Simulator(["mvd94:1:SV=1000"]) as sim:
        raw = raw_factory(sim.port)
        req = bytes.fromhex(READ)
        # a request written in two pieces 1 ms apart is still one request (length-aware)
        raw.ser.write(req[:3])
        time.sleep(0.001)
        assert hexu(raw.xfer(req[3:])) == GOOD
        # ... but 150 ms of silence in the middle splits it: both pieces are garbage
        raw.ser.write(req[:3])
        time.sleep(0.15)
        assert raw.xfer(req[3:]) == b""
        log = sim.log()
        assert [f.get("info") for f in log if f["dir"] == "rx"][-2:] == ["garbage", "bad CRC"]
        # an unknown function (no known length) ends by t3.5 silence: exception 01
        assert hexu(raw.xfer(crc("01 41 00 00"))) == crc("01 C1 01")


def test_pace_inside_the_simulator(raw_factory):
    """--ptyline none: replies leave at the character time (+ 1..10 ms turnaround)."""
    with simctl.Simulator(["mvd94:1:SV=1000"], pace=True, baud=2400,
                          extra=["--ptyline", "none"]) as sim:
        raw = raw_factory(sim.port, 2400)
        char = 11 / 2400
        t0 = time.monotonic()
        raw.ser.write(bytes.fromhex(READ))
        got = b""
        while len(got) < 7 and time.monotonic() - t0 < 2:
            got += raw.ser.read(16)
        elapsed = time.monotonic() - t0
        assert hexu(got) == GOOD
        assert elapsed >= 3.5 * char + 0.001 + 6 * char     # lower bound only
        assert not sim.ctl("line_stats")["available"]


def test_pace_with_ptyline_counts_the_line():
    binary = os_ptyline()
    with simctl.Simulator(["mvd94:1:SV=1000"], pace=True, extra=["--ptyline", binary]) as sim:
        inst = instrument(sim.port, 1)
        for _ in range(5):
            assert inst.read_register(0) == 1000
        stats = sim.ctl("line_stats")["stats"]
        assert stats["m2s"]["frames"] == 5 and stats["m2s"]["bytes"] == 40
        assert stats["s2m"]["frames"] == 5 and stats["s2m"]["bytes"] == 35
        assert stats["total"]["utilisation"] > 0
        assert stats["reply_latency"]["min_us"] >= 1000      # the 1..10 ms turnaround
        # a master that fires the next request right after the reply: short gaps counted
        raw = RawPort(sim.port)
        try:
            for _ in range(5):
                raw.ser.write(bytes.fromhex(READ))
                got, t0 = b"", time.monotonic()
                while len(got) < 7 and time.monotonic() - t0 < 1:
                    got += raw.ser.read(16)
            time.sleep(0.1)
        finally:
            raw.close()
        stats = sim.ctl("line_stats")["stats"]
        assert stats["requests"]["short_3_5"] >= 1


def os_ptyline():
    from modsim.app import find_ptyline
    binary = find_ptyline(None)
    if binary is None:
        if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1" or os.environ.get("MBFB_PTYLINE"):
            pytest.fail("mbfb-ptyline not built")
        pytest.skip("mbfb-ptyline not built (tools/sim/ptyline)")
    return binary


def test_control_protocol_errors():
    with simctl.Simulator(["mvd94:1"]) as sim:
        s = socket.socket(socket.AF_UNIX)
        s.connect(sim.control_path)
        f = s.makefile("rwb")
        for req in (b"not json\n", b"[1]\n", b'{"op":"nope"}\n', b'{"op":"get","addr":1}\n',
                    b'{"op":"get","addr":1,"reg":"XYZ"}\n', b'{"op":"get","addr":4,"reg":"SV"}\n'):
            f.write(req)
            f.flush()
            reply = json.loads(f.readline())
            assert reply["ok"] is False and reply["error"]
        f.write(b'{"op":"devices"}\n')
        f.flush()
        assert json.loads(f.readline())["devices"] == [{"kind": "mvd94", "addr": 1}]
        s.close()
