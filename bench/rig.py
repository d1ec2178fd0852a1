"""What the Python benches share (no bench itself): a variant of the tree built in a temp dir
(`Variant`: a commit exported with `git archive`, or the working tree; the shims, ptyline and
ST programs compiled as OpenPLC builds them), a line paced by ptyline with its frame log
(`Line`), the one-device ST program (`device_program`), the scan host's JSON, and the process
helpers (run, stop by pid, a temp root removed afterwards). Used by wire_pace.py, scan_cost.py,
write_done.py, plant_scale.py, gap_trace.py, block_blind.py and bus_economy.py."""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.join(ROOT, "bench", "wirepace")
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402

def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(cmd, **kw):
    kw.setdefault("check", True)
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    try:
        return subprocess.run(cmd, **kw)
    except subprocess.CalledProcessError as e:
        raise SystemExit(f"failed: {' '.join(map(str, cmd))}\n{(e.stdout or '')[-1500:]}{(e.stderr or '')[-3000:]}")


def stop(proc: subprocess.Popen, sig=signal.SIGTERM, timeout=10.0) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def temp_root(prefix: str):
    """A temp dir that is TMPDIR too while it lives (the simulators', programs' and runner's temp
    dirs go in it), removed at the end, TMPDIR as it was."""
    tmp = tempfile.mkdtemp(prefix=prefix)
    old_tmpdir = os.environ.get("TMPDIR")
    os.environ["TMPDIR"] = tmp
    tempfile.tempdir = tmp
    try:
        yield tmp
    finally:
        tempfile.tempdir = None
        if old_tmpdir is None:
            os.environ.pop("TMPDIR", None)
        else:
            os.environ["TMPDIR"] = old_tmpdir
        shutil.rmtree(tmp, ignore_errors=True)


def cache_value(build: str, key: str) -> str | None:
    with open(os.path.join(build, "CMakeCache.txt"), encoding="utf-8") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return line.split("=", 1)[1].strip()
    return None


class Variant:
    """One version of the code: its sources (a commit's or the working tree), built in work."""

    def __init__(self, name: str, ref: str, work: str, build_type: str = "RelWithDebInfo"):
        """build_type: the shims' CMAKE_BUILD_TYPE (bench/scan_cost.py: Debug, i.e. -O0, as OpenPLC)."""
        self.name, self.ref = name, ref
        self.dir = os.path.join(work, name)
        os.makedirs(self.dir)
        if ref == "worktree":
            self.src = ROOT
        else:
            self.src = os.path.join(self.dir, "src")
            os.makedirs(self.src)
            arch = subprocess.Popen(["git", "-C", ROOT, "archive", ref], stdout=subprocess.PIPE)
            run(["tar", "-x", "-C", self.src], stdin=arch.stdout)
            if arch.wait() != 0:
                raise SystemExit(f"git archive {ref} failed")
        self.build = os.path.join(self.dir, "build")
        log(f"[{name}] building {ref} (shims, ptyline) ...")
        run(["cmake", "-S", self.src, "-B", self.build, "-G", "Ninja",
             f"-DCMAKE_BUILD_TYPE={build_type}"])
        run(["cmake", "--build", self.build, "-j2", "--target", "mbfb", "mbfb-ptyline"])
        # OpenPLC's iec2c, its ST library and its C headers: programs are built as OpenPLC does
        self.home = (cache_value(self.build, "OPENPLC_HOME") or os.environ.get("OPENPLC_HOME")
                     or "/opt/OpenPLC_v3")
        self.iec2c = os.path.join(self.home, "webserver", "iec2c")
        if not os.path.exists(self.iec2c):
            raise SystemExit(f"no iec2c at {self.iec2c}: set OPENPLC_HOME (OpenPLC v3 with matiec)")
        self.lm = cache_value(self.build, "MBFB_LM_OPENPLC_LIB") or cache_value(self.build, "MBFB_LM_DEBIAN_LIB")
        self.lm_debian = cache_value(self.build, "MBFB_LM_DEBIAN_LIB")
        self.lib = os.path.join(self.build, "c_shims", "libmbfb.a")
        self.ptyline = os.path.join(self.build, "tools", "sim", "ptyline", "mbfb-ptyline")
        self.header = open(os.path.join(self.src, "c_shims", "include", "mbfb.h"), encoding="utf-8").read()
        self.has_plans = "mbfb_plan_take" in self.header
        # the header a program's pragmas need: mbfb_st.h (the API and the pragmas' macros) where
        # the variant has one, else mbfb.h (older trees held the macros there)
        self.pragma_header = ("mbfb_st.h" if os.path.exists(os.path.join(self.src, "c_shims", "include", "mbfb_st.h"))
                              else "mbfb.h")
        self.shims = os.path.join(self.dir, "wp_shims")
        run(["gcc", "-O2", "-I", os.path.join(self.src, "c_shims", "include"), "-o", self.shims,
             os.path.join(HERE, "wp_shims.c"), self.lib, self.lm, "-lpthread",
             f"-Wl,-rpath,{os.path.dirname(self.lm)}"])
        self.st = sorted(os.path.join(self.src, "st_src", f)
                         for f in os.listdir(os.path.join(self.src, "st_src")) if f.endswith(".st"))
        self.programs: dict[str, str] = {}

    def compile(self, key: str, program: str) -> str:
        """iec2c + g++ -O0 (as OpenPLC builds a program) with wp_host.cpp; returns the executable."""
        work = os.path.join(self.dir, "st-" + key)
        os.makedirs(work)
        text = "".join(open(f, encoding="utf-8").read() + "\n" for f in self.st)
        with open(os.path.join(work, "program.st"), "w", encoding="utf-8") as fh:
            fh.write(text + program)
        run([self.iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "-I",
             os.path.join(self.home, "webserver", "lib"), "program.st"], cwd=work)
        exe = os.path.join(work, "prog")
        run(["g++", "-std=gnu++11", "-O0", "-w", "-I", os.path.join(self.home, "webserver", "core", "lib"),
             "-I", os.path.join(self.src, "c_shims", "include"), "-I", HERE, "-I", work,
             "-include", self.pragma_header, "-include", "wp_host.h", "-o", exe, "Config0.c", "Res0.c",
             os.path.join(HERE, "wp_host.cpp"), self.lib, self.lm, "-lpthread",
             f"-Wl,-rpath,{os.path.dirname(self.lm)}"], cwd=work)
        self.programs[key] = exe
        return exe


# ---- ST programs (task INTERVAL 1 ms; wp_host sets the real interval at run time) -------------

CONFIG = """
CONFIGURATION Config0
  RESOURCE Res0 ON PLC
    TASK task0(INTERVAL := T#1ms, PRIORITY := 0);
    PROGRAM instance0 WITH task0 : main;
  END_RESOURCE
END_CONFIGURATION
"""


def device_program(block: str, port: str, baud: int, fmt: str, period: str = "T#0s",
                   inputs: str = "") -> str:
    """One block on `port`; `inputs`: more of its inputs (", Fc1 := 3, ...": MB_Poll's ranges)."""
    return f"""
PROGRAM main
  VAR
    l : MB_LINE := (Baud := {baud}, Parity := 'N', StopBits := {fmt[2]});
    dev : {block};
  END_VAR
  dev(Enable := TRUE, Port := '{port}', SlaveId := 1, Line := l, Period := {period}{inputs});
  IF dev.Valid AND dev.Age = T#0s THEN {{{{ wp_pub(0); }}}} END_IF;
END_PROGRAM
""" + CONFIG


class Line:
    """ptyline (frame log) + the simulator on its S side; masters open self.m (a symlink)."""

    def __init__(self, ptyline: str, tmp: str, name: str, baud: int, fmt: str, devices: list[str]):
        self.baud, self.fmt = baud, fmt
        bits = 1 + int(fmt[0]) + (fmt[1] != "N") + int(fmt[2])
        self.char_us = bits * 1e6 / baud
        # t3.5 as the Modbus serial line spec has it: 3.5 characters, fixed 1750 us above 19200
        self.t35_us = 3.5 * self.char_us if baud <= 19200 else 1750.0
        self.m = os.path.join(tmp, name)
        self.logf = os.path.join(tmp, name + ".log")
        self.statsf = os.path.join(tmp, name + ".json")
        self.proc = subprocess.Popen([ptyline, "--baud", str(baud), "--format", fmt,
                                      "--turnaround-ms", "1:10", "--seed", "1", "--log", self.logf,
                                      "--stats", self.statsf, "--link-m", self.m],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        ports = {}
        for _ in range(2):
            k, v = self.proc.stdout.readline().split()
            ports[k] = v
        self.ready = time.monotonic()
        self.sim = Simulator(devices, transport="serial", serial=ports["S"], baud=baud, fmt=fmt, seed=1)
        try:
            self.sim.start()
        except BaseException:
            stop(self.proc)
            raise

    def now_us(self) -> float:
        return (time.monotonic() - self.ready) * 1e6

    def close(self) -> None:
        self.sim.stop()
        stop(self.proc)

    def frames(self) -> list[tuple[float, str, int, int]]:
        """[(start_us, 'M>S'|'S>M', nbytes, first byte)]"""
        out = []
        with open(self.logf, encoding="utf-8") as fh:
            for line in fh:
                p = line.split()
                if len(p) >= 3:
                    out.append((float(p[0]), p[1].rstrip("*"), len(p) - 2, int(p[2], 16)))
        return out

    def figures(self, t0: float, t1: float) -> dict:
        """Requests starting in [t0, t1) (line time, us): see the module's docstring."""
        fr = self.frames()
        n, short, busy, gaps, turns = 0, 0, 0.0, [], []
        per_addr: dict[int, int] = {}
        for i, (t, d, nb, a) in enumerate(fr):
            if d != "M>S" or not t0 <= t < t1:
                continue
            n += 1
            per_addr[a] = per_addr.get(a, 0) + 1
            if i > 0:
                pt, _, pn, _ = fr[i - 1]
                gap = t - (pt + pn * self.char_us)
                gaps.append(gap)
                short += gap < self.t35_us
            cost = self.t35_us + nb * self.char_us
            if i + 1 < len(fr) and fr[i + 1][1] == "S>M":
                turn = fr[i + 1][0] - (t + nb * self.char_us)
                turns.append(turn)
                cost += turn + fr[i + 1][2] * self.char_us
            busy += cost
        win = (t1 - t0) / 1e6
        return {"tx": n / win, "share": busy / 1e6 / win, "short": short / n if n else 0.0,
                "gap_ms": statistics.median(gaps) / 1000 if gaps else float("nan"),
                "turn_ms": statistics.mean(turns) / 1000 if turns else float("nan"),
                "per_addr": {a: c / win for a, c in per_addr.items()}}


def host_json(text: str) -> dict:
    for ln in text.splitlines():
        if ln.startswith("{"):
            return json.loads(ln)
    raise SystemExit(f"program printed no result:\n{text[-2000:]}")


# ---- the benchmark ----------------------------------------------------------------------------
