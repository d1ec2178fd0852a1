"""Drive the project's own runner: an ST program built with fb_host.cpp
(CMake target heat_treat_st_runner), the stand-in for OpenPLC's runtime where it is missing.

    with Runner(exe, sets={"CONFIG0.RES0.HEATTREAT.BUSPORT": bus}) as plc:
        plc.snapshot()["QW"]["0"]      # located variables, as the runner last wrote them
        plc.command("set %MW0 1500")   # between two scans; RunnerError if refused

Runner also answers like OpenPLC's Modbus TCP server (hr, coils, write: the interface of
tools/openplc/oplc.PlcClient), so a display reads either back end the same way. The runner process
is stopped by pid on close(); its temp directory (snapshot, socket) is removed.
"""
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time



def _die_with_parent():
    """In the child: SIGKILL it if the process that started it dies without cleaning up."""
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG

# OpenPLC's Modbus map (core/modbus.cpp): holding registers 0..1023 = %QW, 1024..2047 = %MW,
# coil n = %QX(n/8).(n%8). A register OpenPLC has not bound to a variable reads 0 (here too);
# a write to one is refused here (RunnerError) where OpenPLC drops it silently.
MW_BASE = 1024


class RunnerError(RuntimeError):
    pass


class Runner:
    def __init__(self, exe, sets=None, start_timeout=10.0):
        self.tmp = tempfile.mkdtemp(prefix="mbfb-runner-")
        self.snapshot_path = os.path.join(self.tmp, "snapshot.json")
        self.control_path = os.path.join(self.tmp, "control.sock")
        self.log_path = os.path.join(self.tmp, "runner.log")
        args = [exe, "--run", "--snapshot", self.snapshot_path, "--control", self.control_path]
        for name, value in (sets or {}).items():
            args += ["--set", f"{name}={value}"]
        self._sock = self._file = None
        with open(self.log_path, "w") as log:
            self.proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True,
                                         preexec_fn=_die_with_parent)
        try:
            deadline = time.monotonic() + start_timeout
            while not (os.path.exists(self.snapshot_path) and os.path.exists(self.control_path)):
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RunnerError(f"runner did not start:\n{self.log()}")
                time.sleep(0.05)
        except BaseException:
            self.close()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def log(self):
        with open(self.log_path, errors="replace") as f:
            return f.read()

    def snapshot(self):
        """The located variables as last written ({"scan": N, "QW": {"0": ...}, ...})."""
        if self.proc.poll() is not None:
            raise RunnerError(f"runner exited ({self.proc.returncode}):\n{self.log()}")
        with open(self.snapshot_path) as f:  # replaced atomically by the runner
            return json.load(f)

    def command(self, line):
        """One control command ("set %MW0 1500", "get %QW0"); returns what follows "ok"."""
        if self._sock is None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self._sock.settimeout(5)
            self._sock.connect(self.control_path)
            self._file = self._sock.makefile("rw")
        self._file.write(line + "\n")
        self._file.flush()
        reply = self._file.readline().strip()
        if not reply.startswith("ok"):
            raise RunnerError(f"{line!r}: {reply or 'no answer'}")
        return reply[2:].strip()

    # ---- the interface of oplc.PlcClient (OpenPLC's Modbus TCP server) ----
    def hr(self, addr, count=1):
        snap = self.snapshot()
        out = []
        for a in range(addr, addr + count):
            area, n = ("MW", a - MW_BASE) if a >= MW_BASE else ("QW", a)
            out.append(snap.get(area, {}).get(str(n), 0) & 0xFFFF)
        return out

    def coils(self, count=9):
        qx = self.snapshot().get("QX", {})
        return [bool(qx.get(f"{i // 8}.{i % 8}", False)) for i in range(count)]

    def write(self, addr, value):
        if not 0 <= addr < 2 * MW_BASE:
            raise RunnerError(f"holding register {addr}: only %QW (0..1023) and %MW (1024..2047)")
        self.command(f"set %MW{addr - MW_BASE} {value}" if addr >= MW_BASE else f"set %QW{addr} {value}")

    def close(self):
        if self._sock is not None:
            self._file.close()
            self._sock.close()
            self._sock = self._file = None
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.kill(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        shutil.rmtree(self.tmp, ignore_errors=True)
