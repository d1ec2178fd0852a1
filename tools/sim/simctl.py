"""Client of the device simulator for tests and tools (docs/contracts.md sections 2 and 3).

    from simctl import Simulator
    with Simulator(["mvd94:1:SV=100.0,DP=1"]) as sim:     # starts mbsim.py on a new pty
        sim.port                                          # '/dev/pts/N' (or the --symlink path)
        sim.control({"op": "get", "addr": 1, "reg": "SV"})  # -> {"ok": True, "raw": 1000, ...}
    # leaving the block stops it by pid

The tests' pytest fixture of it is tests/sim/conftest.py's sim_fixture().
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))  # tools/sim -> the checkout
MBSIM = os.path.join(HERE, "mbsim.py")
VENV_PYTHON = os.path.join(ROOT, ".venv", "bin", "python")


class SimulatorError(RuntimeError):
    """The simulator did not start, or a control request failed."""


class Simulator:
    """One simulator process. Arguments mirror mbsim.py's options.

    devices: list of 'KIND:ADDR[:NAME=VALUE,...]'. transport: 'pty' (default), 'tcp',
    'rtu-tcp' or 'serial' (then serial=DEVICE). fmt is --format. faults: list of dicts (written to a
    temporary --faults file). extra: more raw arguments.
    """

    def __init__(self, devices, transport: str = "pty", baud: int = 9600, fmt: str = "8N2",
                 time_scale: float = 1.0, pace: bool = False, seed: int = 0, faults=None,
                 link: str | None = None, serial: str | None = None, tcp_port: int = 0,
                 extra=(), python: str | None = None, start_timeout: float = 15.0):
        self.tmp = tempfile.mkdtemp(prefix="mbsim-")
        self.control_path = os.path.join(self.tmp, "control.sock")
        args = []
        if transport == "pty":
            args.append("--pty")
            if link:
                args += ["--symlink", link]
        elif transport in ("tcp", "rtu-tcp"):
            args += [f"--{transport}", f"127.0.0.1:{tcp_port}"]
        elif transport == "serial":
            args += ["--serial", serial]
        else:
            raise ValueError(f"transport {transport!r}")
        args += ["--baud", str(baud), "--format", fmt, "--time-scale", str(time_scale),
                 "--seed", str(seed), "--control", self.control_path]
        if pace:
            args.append("--pace")
        for dev in devices:
            args += ["--device", dev]
        if faults:
            path = os.path.join(self.tmp, "faults.json")
            with open(path, "w", encoding="utf-8") as fh:
                json.dump(list(faults), fh)
            args += ["--faults", path]
        self.args = args + list(extra)
        self.python = python or (VENV_PYTHON if os.path.exists(VENV_PYTHON) else sys.executable)
        self.start_timeout = start_timeout
        self.proc = None
        self.port = None            # pty path / link / serial device / '127.0.0.1:PORT'
        self.tcp = None             # (host, port) with transport 'tcp' or 'rtu-tcp'
        self.ready_line = None
        self._sock = None
        self._file = None
        self._lock = threading.Lock()
        self._stderr = os.path.join(self.tmp, "stderr.txt")

    # ----- lifecycle -----
    def start(self) -> "Simulator":
        """Start mbsim.py and wait for its ready line."""
        err = open(self._stderr, "wb")
        self.proc = subprocess.Popen([self.python, MBSIM, *self.args], stdout=subprocess.PIPE,
                                     stderr=err, stdin=subprocess.DEVNULL)
        err.close()
        line = self._read_ready()
        self.ready_line = line
        kind, _, where = line.partition(" ")
        self.port = where
        if kind in ("TCP", "RTU-TCP"):
            host, _, port = where.rpartition(":")
            self.tcp = (host, int(port))
        return self

    def _read_ready(self) -> str:
        result = {}

        def reader():
            result["line"] = self.proc.stdout.readline().decode().strip()

        thread = threading.Thread(target=reader, daemon=True)
        thread.start()
        thread.join(self.start_timeout)
        line = result.get("line", "")
        if not line.split(" ")[0] in ("PTY", "SERIAL", "TCP", "RTU-TCP"):
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()
            err = self.stderr()
            self.stop()
            raise SimulatorError(f"simulator did not start: {line!r}\n{err}")
        return line

    def stderr(self) -> str:
        try:
            with open(self._stderr, encoding="utf-8", errors="replace") as fh:
                return fh.read()
        except OSError:
            return ""

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGTERM by pid, wait; SIGKILL if it does not exit. Returns the exit status."""
        if self._sock:
            self._sock.close()
            self._sock = self._file = None
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.kill(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()
        shutil.rmtree(self.tmp, ignore_errors=True)
        return self.proc.returncode

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # ----- control protocol -----
    def control(self, request: dict, timeout: float = 30.0) -> dict:
        """Send one request, return the reply dict (ok true or false)."""
        with self._lock:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                self._sock.settimeout(timeout)
                self._sock.connect(self.control_path)
                self._file = self._sock.makefile("rwb")
            self._file.write((json.dumps(request) + "\n").encode())
            self._file.flush()
            line = self._file.readline()
        if not line:
            raise SimulatorError("control socket closed")
        return json.loads(line)

    def ctl(self, op: str, **kw) -> dict:
        """control() that raises SimulatorError unless ok: sim.ctl('get', addr=1, reg='SV')."""
        reply = self.control({"op": op, **kw})
        if not reply.get("ok"):
            raise SimulatorError(f"{op} {kw}: {reply.get('error')}")
        return reply

    def log(self, clear: bool = True) -> list:
        """Frames on the line since the last clear: [{'t', 'dir', 'hex'[, 'info']}]."""
        return self.ctl("log", clear=clear)["frames"]

    def wait_for(self, predicate, timeout: float = 10.0, interval: float = 0.05):
        """Poll predicate() until true (returns its value) or raise TimeoutError."""
        end = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() > end:
                raise TimeoutError("condition not reached")
            time.sleep(interval)

