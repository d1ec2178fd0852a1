"""Blind time of TempCtrl_MVD94 after ONE late reply, BEFORE and AFTER side by side in one run.

    .venv/bin/python bench/block_blind.py [REPEATS] [--before REF] [--delays 100,200,...]
                                          [--trace] [--from OUTPUT]

Not a test (no ctest registration): it prints figures (bench/README.md, "Blind time after
one late reply, block level"). The block level of bench/late_blind.sh: bench/block_blind.st (its
header says what it measures) is compiled twice, with st_src/ and c_shims/ of BEFORE (REF,
default 99d66d9^: the last commit before the back-in-step work, taken with `git archive` into a
temp dir) and of the work tree (AFTER), each with iec2c (OPENPLC_HOME's, -f -l -p -r -R -a as
tests/fb), the work tree's fbtest.st, glue (mkglue.py) and runner host (tools/runner: scans in
real time at the task period, as OpenPLC's runtime), and libmodbus from pkg-config; both
c_shims compiled alike (cc -O2). Each run gets its own simulator (tools/sim, one MV-D94 on a
pty, 9600 8N2); the two versions run alternately, delay by delay and repeat by repeat, so both
see the same machine load. Printed: the raw result lines, then a markdown table of medians
(and the worst repeat where it is 20 ms or more above the median): the largest age of the published data after the fault minus (delay + Period), whether Valid
was lost (in how many of the repeats, and for how long), the ErrorIDs shown, wrong values.
--trace prints each run's block events and the simulator's frames after the fault; --from
prints the table again from a saved output.
Everything temporary is in one mktemp directory, removed at the end; the simulators are
stopped by pid (simctl.Simulator), the runners by pid too.
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import shlex
import signal
import statistics as st
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rig as wp  # noqa: E402

PERIOD_MS = 500
DEFAULT_BEFORE = "99d66d9^"


CLOCK_CPP = """#include <time.h>
extern "C" double blind_wall_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1000.0 + (double)ts.tv_nsec / 1.0e6;
}
"""


def sh(cmd, cwd=None):
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"failed ({p.returncode}): {' '.join(map(shlex.quote, cmd))}\n"
                         f"{p.stdout[-3000:]}{p.stderr[-3000:]}")
    return p.stdout


def build(src: str, work: str, home: str) -> str:
    """st_src/ and c_shims/ of `src` with the work tree's test support, program and host."""
    os.makedirs(work)
    sources = sorted(glob.glob(os.path.join(src, "st_src", "*.st")))
    sources += [os.path.join(ROOT, "tests", "fb", "fbtest.st"),
                os.path.join(ROOT, "bench", "block_blind.st")]
    with open(os.path.join(work, "program.st"), "w", encoding="utf-8") as out:
        for f in sources:
            with open(f, encoding="utf-8") as fh:
                out.write(fh.read() + "\n")
    sh([os.path.join(home, "webserver", "iec2c"), "-f", "-l", "-p", "-r", "-R", "-a", "-I",
        os.path.join(home, "webserver", "lib"), "program.st"], cwd=work)
    sh([sys.executable, os.path.join(ROOT, "tools", "runner", "mkglue.py"), work], cwd=work)
    lm_cflags = sh(["pkg-config", "--cflags", "libmodbus"]).split()
    lm_libs = sh(["pkg-config", "--libs", "libmodbus"]).split()
    lm_dir = sh(["pkg-config", "--variable=libdir", "libmodbus"]).strip()
    inc = os.path.join(src, "c_shims", "include")
    objs = os.path.join(work, "shims")
    os.makedirs(objs)
    sh(["cc", "-O2", "-std=gnu11", "-c", "-I", inc, "-I", os.path.join(src, "c_shims", "src")]
       + lm_cflags + sorted(glob.glob(os.path.join(src, "c_shims", "src", "*.c"))), cwd=objs)
    # the wall clock for the program's pragma (its own file: iec_std_lib.h's struct tm clashes
    # with <time.h>)
    with open(os.path.join(work, "blind_clock.cpp"), "w", encoding="utf-8") as fh:
        fh.write(CLOCK_CPP)
    with open(os.path.join(work, "blind_clock.h"), "w", encoding="utf-8") as fh:
        fh.write('extern "C" double blind_wall_ms(void);\n')
    runner = os.path.join(ROOT, "tools", "runner")
    exe = os.path.join(work, "block_blind")
    sh(["g++", "-std=gnu++11", "-O2", "-w", "-I", os.path.join(home, "webserver", "core", "lib"),
        "-I", runner, "-I", os.path.join(ROOT, "tests", "fb"), "-I", inc, "-I", work,
        "-include", "mbfb_st.h" if os.path.exists(os.path.join(inc, "mbfb_st.h")) else "mbfb.h",
        "-include", "fbtest.h", "-include", "blind_clock.h", "-o", exe, "Config0.c", "Res0.c", "glue.c", "blind_clock.cpp"]
       + [os.path.join(runner, f) for f in ("fb_host.cpp", "plc_vars.cpp", "plc_control.cpp",
                                             "plc_host.cpp")]
       + [os.path.join(ROOT, "tests", "fb", "fbtest_hooks.cpp")]
       + sorted(glob.glob(os.path.join(objs, "*.o"))) + lm_libs
       + ["-lpthread", "-ldl", "-lm", f"-Wl,-rpath,{lm_dir}"], cwd=work)
    return exe


def run(exe: str, delay: int, tmp: str, trace: bool) -> dict:
    """One run against a fresh simulator: the RESULT line's fields (+ the trace)."""
    link = os.path.join(tmp, "ttyBLIND")
    with Simulator(["mvd94:1:SV=100.0,DP=1"], baud=9600, fmt="8N2", time_scale=0.001,
                   link=link) as sim:
        env = dict(os.environ, MBFB_TEST_PORT=link, MBFB_SIM_CONTROL=sim.control_path,
                   BLIND_DELAY_MS=str(delay))
        proc = subprocess.Popen([exe, "--run", "--seconds", str(40 + delay / 1000)], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        lines, result = [], None
        try:
            for line in proc.stdout:
                lines.append(line.rstrip())
                if "RESULT " in line or "ERROR " in line:
                    result = line
                    break
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()
        frames = sim.log() if trace else []
    if result is None or "RESULT " not in result:
        raise SystemExit(f"no result (delay {delay}):\n" + "\n".join(lines[-20:]))
    kv = dict(x.split("=", 1) for x in result.split("RESULT ", 1)[1].split())
    if trace:
        kv["trace"] = [l.split(": ", 1)[1] for l in lines if ": EV " in l]
        t0 = frames[0]["t"] if frames else 0.0
        kv["frames"] = ["%8.1f ms %s %s%s" % ((f["t"] - t0) * 1000, f["dir"], f.get("hex", ""),
                                              "  (" + f["info"] + ")" if f.get("info") else "")
                        for f in frames]
    return kv


def error_id(text: str) -> int:
    """WORD_TO_STRING's '16#84' -> 132 (docs/errors.md's numbers are decimal)."""
    return int(text[3:], 16) if text.startswith("16#") else int(text)


def table(raw: list) -> None:
    rows = {}
    for ver, kv in raw:
        rows.setdefault((int(kv["delay"]), ver), []).append(kv)
    print("\n| late by | before: data at most (beyond delay + Period), median | after: data "
          "at most (beyond delay + Period), median | before: Valid lost / ErrorIDs | after: Valid lost / "
          "ErrorIDs | wrong |")
    print("|---|---|---|---|---|---|")
    for d in sorted({k[0] for k in rows}):
        cells, extra, wrong = [], [], 0
        for ver in ("before", "after"):
            r = rows[(d, ver)]
            age = st.median(float(x["maxage"]) for x in r)
            worst = max(float(x["maxage"]) for x in r)
            cells.append("%.2f s (%+.0f ms)%s" % (age / 1000, age - d - PERIOD_MS,
                                                 ", worst %.2f s (%+.0f ms)" % (
                                                     worst / 1000, worst - d - PERIOD_MS)
                                                 if worst - age >= 20 else ""))
            lost = [x for x in r if x["lost"] == "TRUE"]
            ids = sorted({error_id(i) for x in r for i in x["errs"].split("/")
                          if i and i != "-"})
            extra.append("%s%s / %s" % (
                "%d of %d" % (len(lost), len(r)) if lost else "no",
                " (median %.2f s)" % (st.median(float(x["invalid"]) for x in lost) / 1000)
                if lost else "", ", ".join(map(str, ids)) if ids else "none"))
            wrong += sum(int(x["wrong"]) for x in r)
            if any(x["back"] != "TRUE" for x in r):
                cells[-1] += " (not back within 30 s)"
        print("| %d ms | %s | %s | %s | %s | %d |" % (d, cells[0], cells[1], extra[0], extra[1],
                                                     wrong))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("repeats", nargs="?", type=int, default=3)
    ap.add_argument("--before", default=DEFAULT_BEFORE, help="commit of the BEFORE st_src, c_shims")
    ap.add_argument("--delays", default="100,200,500,1000,2000")
    ap.add_argument("--trace", action="store_true", help="print every run's events and frames")
    ap.add_argument("--from", dest="raw", metavar="OUTPUT",
                    help="only the table again, from the raw lines of an earlier run's output")
    args = ap.parse_args()
    if args.raw:
        with open(args.raw, encoding="utf-8") as fh:
            table([(line.split()[0], dict(x.split("=", 1) for x in line.split()[1:]))
                   for line in fh if re.match(r"(before|after) +delay=", line)])
        return 0
    home = os.environ.get("OPENPLC_HOME", "/opt/OpenPLC_v3")
    if not os.path.exists(os.path.join(home, "webserver", "iec2c")):
        raise SystemExit(f"no iec2c in {home}/webserver (set OPENPLC_HOME)")
    delays = [int(d) for d in args.delays.split(",")]
    with wp.temp_root("block-blind-") as tmp:      # the simulators' temp dirs too
        before_src = os.path.join(tmp, "before-src")
        os.makedirs(before_src)
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.before, "st_src", "c_shims"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", before_src], input=archive, check=True)
        t = time.monotonic()
        exes = {"before": build(before_src, os.path.join(tmp, "before"), home),
                "after": build(ROOT, os.path.join(tmp, "after"), home)}
        dirty = subprocess.run(["git", "-C", ROOT, "diff", "--quiet", "HEAD", "--", "st_src",
                                "c_shims"]).returncode != 0
        rev = lambda r: sh(["git", "-C", ROOT, "rev-parse", "--short", r]).strip()
        print(f"before: st_src, c_shims at {rev(args.before)}; after: work tree at {rev('HEAD')}"
              f"{' + changes' if dirty else ''} (built in {time.monotonic() - t:.0f} s); "
              f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
              f"{os.getloadavg()[2]:.2f}, {os.cpu_count()} CPUs", flush=True)
        raw = []
        for d in delays:
            for k in range(args.repeats):
                for ver in ("before", "after"):
                    kv = run(exes[ver], d, tmp, args.trace)
                    raw.append((ver, kv))
                    print(f"{ver:6s} " + " ".join(f"{a}={b}" for a, b in kv.items()
                                                  if a not in ("trace", "frames")), flush=True)
                    if args.trace:
                        print("  block (ms after the fault was set; the late request is the "
                              "first frame, about one Period later):")
                        print("\n".join("    " + e for e in kv["trace"]))
                        print("  line (ms after the first frame after the fault):")
                        print("\n".join("    " + f for f in kv["frames"]))
        print(f"load average at the end {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
              f"{os.getloadavg()[2]:.2f}")
        table(raw)
    return 0


if __name__ == "__main__":
    sys.exit(main())
