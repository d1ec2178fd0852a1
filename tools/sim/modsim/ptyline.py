"""The ptyline program (tools/sim/ptyline, C) run by the simulator as its paced RS-485 line."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time


def _die_with_parent():
    """In the ptyline child: SIGTERM when the simulator dies, even by SIGKILL (Linux prctl)."""
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG


class PtyLine:
    """The ptyline program (tools/sim/ptyline) as the simulator's paced RS-485 line."""

    def __init__(self, binary: str, line, seed: int):
        self.binary, self.line, self.seed = binary, line, seed
        self.proc = None
        self.stats_path = os.path.join(tempfile.mkdtemp(prefix="mbsim-line-"), "line.json")

    def start(self) -> tuple[str, str]:
        """Start it; returns (master side path, simulator side path)."""
        fmt = f"{self.line.data_bits}{self.line.parity}{self.line.stop_bits}"
        self.proc = subprocess.Popen(
            [self.binary, "--baud", str(self.line.baud), "--format", fmt,
             "--turnaround-ms", "1:10", "--seed", str(self.seed), "--stats", self.stats_path],
            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)
        sides = {}
        while len(sides) < 2:
            text = self.proc.stdout.readline().decode().split()
            if len(text) != 2:
                self.stop()
                raise OSError("ptyline did not start")
            sides[text[0]] = text[1]
        return sides["M"], sides["S"]

    def stop(self, final: bool = True):
        """Stop the line program; final: also remove its statistics directory."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            self.proc.stdout.close()
        self.proc = None
        if final:
            shutil.rmtree(os.path.dirname(self.stats_path), ignore_errors=True)

    def stats(self) -> dict:
        """Fresh statistics: SIGUSR1 makes ptyline rewrite its stats file."""
        if self.proc is None:
            raise OSError("the line is down")
        before = os.stat(self.stats_path).st_mtime_ns if os.path.exists(self.stats_path) else 0
        self.proc.send_signal(signal.SIGUSR1)
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            if os.path.exists(self.stats_path) and os.stat(self.stats_path).st_mtime_ns != before:
                with open(self.stats_path, encoding="utf-8") as fh:
                    return json.load(fh)
            time.sleep(0.005)
        raise OSError("ptyline did not write its statistics")
