"""Wire pace: how much of a paced RS-485 line each kind of master uses.

    .venv/bin/python bench/wire_pace.py                      # before (pinned commit) and after (working tree)
    .venv/bin/python bench/wire_pace.py --variant now=worktree --runs 1 --seconds 3   # quick look

Not a test: it prints figures (bench/README.md, "Wire pace", "Three devices on one line",
"MB_Poll beside a device block on one line", "Scale: 8 lines x 32 MT-S9"); what the other
benches share is rig.py. In ONE run, on lines paced by ptyline (tools/sim/ptyline, 1..10 ms
device turnaround, seeded), for each variant (a commit exported with `git archive` and built in
a temp dir, or the working tree) it measures, side by side and interleaved (run 1 of every
cell, then run 2, ...):

* one MV-D94 at 9600 8N2 (the simulated MV-D94 stops at 19200) and one MT-S9 at 115200 8N1:
  the shims polling back to back through their public API (bench/wirepace/wp_shims.c, `post`;
  also `plan` when mbfb.h has plans), the device block (TempCtrl_MVD94 / Counter_MTS9,
  Period T#0s) in an ST program run in real time at task intervals 1, 20, 50 and 100 ms
  (bench/wirepace/wp_host.cpp, compiled as OpenPLC does: iec2c, g++ -O0), mbpoll at its
  fastest (-l 10), and a plain libmodbus loop (bench/wirepace/wp_lm.c, Debian's libmodbus);
* the three-device line: MV-D94, FDC-100 and MT-S9 on one 9600 8N2 line, each block with
  Period T#0s in one program: refreshes per second per device;
* the shared line (--skip lines,three,scale to run it alone): TempCtrl_MVD94 (Period T#0s) and
  MB_Poll (coils + holding registers of the simulator's generic device bench/poll_device.json,
  Period T#1ms) on one 9600 8N2 line, one program per task interval: the line's share and each
  device's refreshes per second (both must refresh);
* the scale run: 8 buses x 32 MT-S9 at 115200 (8 simulator processes on ptys, pacing their
  own replies), one Counter_MTS9 each in one generated program, against the same program
  with one device: scan time and its jitter, refreshes per device, worker CPU.

Figures from ptyline's frame log (wire times), in a window of --seconds after --warmup:
tx/s = requests sent; share = sum over those requests of (t3.5 + request bytes + the reply's
measured turnaround + reply bytes) / window, i.e. tx/s x the shortest compliant transaction
(1.00 = the wire's limit for that device; over 1 only when a master skips the t3.5 silence);
"< t3.5" = requests sent after less silence than t3.5 (3.5 characters; the spec's fixed
1.75 ms above 19200 baud, also in the share); gap = median silence
before a request. Three runs (--runs), medians. Everything listens on ptys only, every
process is stopped by pid, the temp dir is removed.
"""
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

from rig import (CONFIG, HERE, ROOT, Line, Simulator, Variant, cache_value, device_program,  # noqa: E402,F401
                 host_json, log, run, stop, temp_root)

BEFORE = "12e63ec"   # before the plan-based device blocks: shims with plans, st_src blocks on post/poll/take
INTERVALS = (1, 20, 50, 100)
# (key, title, baud, format, simulator device, block, FC, address, count for the C masters)
LINES = (("mv", "MV-D94 9600 8N2", 9600, "8N2", "mvd94:1", "TempCtrl_MVD94", 3, 0, 17),
         ("mt", "MT-S9 115200 8N1", 115200, "8N1", "mts9:1", "Counter_MTS9", 3, 0, 10))


def three_program(port: str) -> str:
    return f"""
PROGRAM main
  VAR
    l : MB_LINE := (Baud := 9600, Parity := 'N', StopBits := 2);
    mv : TempCtrl_MVD94;
    fdc : FDC_Controller;
    ct : Counter_MTS9;
  END_VAR
  mv(Enable := TRUE, Port := '{port}', SlaveId := 1, Line := l, Period := T#0s);
  fdc(Enable := TRUE, Port := '{port}', SlaveId := 2, Line := l, Period := T#0s);
  ct(Enable := TRUE, Port := '{port}', SlaveId := 3, Line := l, Period := T#0s);
  IF mv.Valid AND mv.Age = T#0s THEN {{{{ wp_pub(0); }}}} END_IF;
  IF fdc.Valid AND fdc.Age = T#0s THEN {{{{ wp_pub(1); }}}} END_IF;
  IF ct.Valid AND ct.Age = T#0s THEN {{{{ wp_pub(2); }}}} END_IF;
END_PROGRAM
""" + CONFIG


POLL_DEVICE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "poll_device.json")
POLL_RANGES = "Fc1 := 1, Addr1 := 0, Count1 := 20, Fc2 := 3, Addr2 := 0, Count2 := 10"


def poll_program(port: str) -> str:
    """TempCtrl_MVD94 (slave 1) and MB_Poll (slave 2, coils + holding registers) on one line."""
    return f"""
PROGRAM main
  VAR
    l : MB_LINE := (Baud := 9600, Parity := 'N', StopBits := 2);
    mv : TempCtrl_MVD94;
    gp : MB_Poll;
  END_VAR
  mv(Enable := TRUE, Port := '{port}', SlaveId := 1, Line := l, Period := T#0s);
  gp(Enable := TRUE, Port := '{port}', SlaveId := 2, Line := l, Period := T#1ms, {POLL_RANGES});
  IF mv.Valid AND mv.Age = T#0s THEN {{{{ wp_pub(0); }}}} END_IF;
  IF gp.Valid AND gp.Age = T#0s THEN {{{{ wp_pub(1); }}}} END_IF;
END_PROGRAM
""" + CONFIG


def scale_program(ports: list[str], per_bus: int, period: str = "T#0s") -> str:
    decl, body = [], []
    for b, port in enumerate(ports):
        for s in range(per_bus):
            n = b * per_bus + s
            decl.append(f"    d{n} : Counter_MTS9;")
            body.append(f"  d{n}(Enable := TRUE, Port := '{port}', SlaveId := {s + 1}, Line := l, "
                        f"Period := {period});\n"
                        f"  IF d{n}.Valid AND d{n}.Age = T#0s THEN {{{{ wp_pub({n}); }}}} END_IF;")
    return ("\nPROGRAM main\n  VAR\n    l : MB_LINE := (Baud := 115200);\n" + "\n".join(decl)
            + "\n  END_VAR\n" + "\n".join(body) + "\nEND_PROGRAM\n" + CONFIG)


# ---- a paced line ------------------------------------------------------------------------------

def timed_master(line: Line, cmd: list[str], warmup: float, seconds: float, self_timed=False):
    """Runs a master on the line; returns (figures in the window, its stdout)."""
    start = line.now_us()
    out = tempfile.TemporaryFile(mode="w+")
    proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, text=True)
    died = None
    try:
        if self_timed:
            proc.wait(warmup + seconds + 60)
            died = proc.returncode != 0 and proc.returncode
        else:
            time.sleep(warmup + seconds + 0.3)
            died = proc.poll()            # a master that ended before it was stopped
    finally:
        stop(proc, signal.SIGINT)
    out.seek(0)
    text = out.read()
    out.close()
    if died is not None and died is not False:
        raise SystemExit(f"{' '.join(cmd)} exited {died}:\n{text[-2000:]}")
    t0 = start + warmup * 1e6
    fig = line.figures(t0, t0 + seconds * 1e6)
    m = (re.search(r"^ok (\d+) err (\d+)$", text, re.M)   # wp_shims / wp_lm: whole run
         or re.search(r"transmitted, \d+ received, (\d+) errors", text))   # mbpoll (exits 1 then)
    fig["failed"] = int(m.group(m.lastindex)) if m else None
    return fig, text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variant", action="append", metavar="NAME=REF",
                    help=f"a commit or 'worktree' (repeatable; default before={BEFORE} after=worktree)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring window per cell")
    ap.add_argument("--warmup", type=float, default=1.0)
    ap.add_argument("--intervals", default=",".join(map(str, INTERVALS)))
    ap.add_argument("--three-task-ms", type=int, default=20)
    ap.add_argument("--three-seconds", type=float, default=6.0)
    ap.add_argument("--scale", default="8x32", help="BUSESxDEVICES, or 0 to skip the scale run")
    ap.add_argument("--scale-task-ms", type=int, default=20)
    ap.add_argument("--scale-seconds", type=float, default=6.0)
    ap.add_argument("--scale-period", default="T#0s",
                    help="the blocks' Period in the scale run (T#0s: refresh back to back; e.g. T#1h: "
                         "one refresh, then steady scans with nothing new)")
    ap.add_argument("--poll-seconds", type=float, default=6.0)
    ap.add_argument("--skip", default="", help="comma list of: lines,three,poll,scale")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    try:
        intervals = [int(x) for x in args.intervals.split(",") if x]
    except ValueError:
        raise SystemExit(f"--intervals wants milliseconds like 1,20,50,100, not '{args.intervals}'") from None
    variants = [v.split("=", 1) for v in (args.variant or [f"before={BEFORE}", "after=worktree"])]
    if any(len(v) != 2 or not v[0].isidentifier() for v in variants):
        raise SystemExit("--variant wants NAME=REF (REF: a commit or 'worktree')")
    if not shutil.which("mbpoll"):
        raise SystemExit("mbpoll not found (Debian package mbpoll)")
    try:
        buses, per_bus = (0, 0) if args.scale == "0" else map(int, args.scale.split("x"))
    except ValueError:
        raise SystemExit(f"--scale wants BUSESxDEVICES (e.g. 8x32) or 0, not '{args.scale}'") from None
    if not (0 <= buses <= 64 and 0 <= per_bus <= 247) or min(args.runs, args.seconds, args.warmup + 1) <= 0 \
            or not intervals or min(intervals) <= 0 or skip - {"lines", "three", "poll", "scale"}:
        raise SystemExit("bad arguments: see --help (runs, seconds > 0; intervals > 0; "
                         "skip from lines,three,poll,scale; at most 64 buses x 247 devices)")
    if not re.fullmatch(r"T#[0-9]+(ms|s|m|h)", args.scale_period):
        raise SystemExit(f"--scale-period wants an IEC TIME such as T#0s, T#500ms or T#1h, not "
                         f"'{args.scale_period}'")
    tmp = tempfile.mkdtemp(prefix="wirepace-")
    procs_started = time.monotonic()
    try:
        V = [Variant(name, ref, tmp) for name, ref in variants]
        ptyline = V[-1].ptyline                       # one line model for every variant
        lm_exe = os.path.join(tmp, "wp_lm")
        deb = V[-1].lm_debian
        run(["gcc", "-O2", "-I", cache_value(V[-1].build, "MBFB_LM_DEBIAN_INC"), "-o", lm_exe, os.path.join(HERE, "wp_lm.c"),
             deb, f"-Wl,-rpath,{os.path.dirname(deb)}"])
        ports = {k: os.path.join(tmp, k) for k, *_ in LINES}
        ports["three"] = os.path.join(tmp, "three")
        ports["poll"] = os.path.join(tmp, "poll")
        scale_ports = [os.path.join(tmp, f"bus{b}") for b in range(buses)]
        for v in V:
            log(f"[{v.name}] compiling the ST programs (iec2c, g++ -O0) ...")
            if "lines" not in skip:
                for key, _, baud, fmt, _, block, *_ in LINES:
                    v.compile(key, device_program(block, ports[key], baud, fmt))
            if "three" not in skip:
                v.compile("three", three_program(ports["three"]))
            if "poll" not in skip:
                v.compile("poll", poll_program(ports["poll"]))
            if "scale" not in skip and buses:
                v.compile("scale", scale_program(scale_ports, per_bus, args.scale_period))
                v.compile("scale1", scale_program(scale_ports[:1], 1, args.scale_period))
        res: dict = {}

        def add(key, value):
            res.setdefault(key, []).append(value)

        for r in range(args.runs):
            if "lines" not in skip:
                for key, title, baud, fmt, dev, block, fc, addr, count in LINES:
                    log(f"run {r + 1}/{args.runs}: {title}")
                    line = Line(ptyline, tmp, key, baud, fmt, [dev])
                    try:
                        cargs = [line.m, str(baud), fmt, "1", str(fc), str(addr), str(count)]
                        for v in V:
                            add((key, v.name, "shims"), timed_master(line, [v.shims, "post"] + cargs,
                                                                      args.warmup, args.seconds)[0])
                            if v.has_plans:
                                add((key, v.name, "plan"), timed_master(line, [v.shims, "plan"] + cargs,
                                                                         args.warmup, args.seconds)[0])
                            for ms in intervals:
                                f, _ = timed_master(line, [v.programs[key], str(args.warmup), str(args.seconds),
                                                           str(ms)], args.warmup, args.seconds, True)
                                add((key, v.name, f"block{ms}"), f)
                        add((key, "", "mbpoll"), timed_master(line, [
                            "mbpoll", "-m", "rtu", "-b", str(baud), "-d", "8", "-P", "none", "-s", fmt[2],
                            "-a", "1", "-t", "4" if fc == 3 else "3", "-0", "-r", str(addr), "-c", str(count),
                            "-l", "10", "-q", line.m], args.warmup, args.seconds)[0])
                        add((key, "", "lm"), timed_master(line, [lm_exe] + cargs, args.warmup, args.seconds)[0])
                    finally:
                        line.close()
            if "three" not in skip:
                log(f"run {r + 1}/{args.runs}: three devices")
                line = Line(ptyline, tmp, "three", 9600, "8N2", ["mvd94:1", "fdc100:2", "mts9:3"])
                try:
                    for v in V:
                        f, out = timed_master(line, [v.programs["three"], str(args.warmup),
                                                     str(args.three_seconds), str(args.three_task_ms)],
                                              args.warmup, args.three_seconds, True)
                        h = host_json(out)
                        pubs = (h["pubs"] + [0, 0, 0])[:3]
                        add(("three", v.name), {"pubs": [p / h["window_s"] for p in pubs],
                                                "tx": [f["per_addr"].get(a, 0.0) for a in (1, 2, 3)],
                                                "share": f["share"], "short": f["short"]})
                finally:
                    line.close()
            if "poll" not in skip:
                log(f"run {r + 1}/{args.runs}: MB_Poll beside TempCtrl_MVD94")
                line = Line(ptyline, tmp, "poll", 9600, "8N2", ["mvd94:1", f"generic:2:file={POLL_DEVICE}"])
                try:
                    for v in V:
                        for ms in intervals:
                            f, out = timed_master(line, [v.programs["poll"], str(args.warmup),
                                                         str(args.poll_seconds), str(ms)],
                                                  args.warmup, args.poll_seconds, True)
                            h = host_json(out)
                            pubs = (h["pubs"] + [0, 0])[:2]
                            add(("poll", f"{v.name}/{ms}"), {"pubs": [p / h["window_s"] for p in pubs],
                                                       "tx": [f["per_addr"].get(a, 0.0) for a in (1, 2)],
                                                       "share": f["share"], "short": f["short"]})
                finally:
                    line.close()
            if "scale" not in skip and buses:
                log(f"run {r + 1}/{args.runs}: scale {buses} x {per_bus}")
                sims = []
                try:
                    for b in range(buses):
                        s = Simulator([f"mts9:{a}" for a in range(1, per_bus + 1)], baud=115200, fmt="8N1",
                                      pace=True, seed=b + 1, link=scale_ports[b], extra=["--ptyline", "none"])
                        sims.append(s)
                        s.start()
                    for v in V:
                        for key, ndev in (("scale1", 1), ("scale", buses * per_bus)):
                            p = subprocess.run([v.programs[key], str(args.warmup), str(args.scale_seconds),
                                                str(args.scale_task_ms)], capture_output=True, text=True,
                                               timeout=args.warmup + args.scale_seconds + 120)
                            h = host_json(p.stdout)
                            pubs = (h["pubs"] + [0] * ndev)[:ndev]
                            h["rates"] = [x / h["window_s"] for x in pubs]
                            add((key, v.name), h)
                finally:
                    for s in sims:
                        s.stop()
        report(res, V, intervals, args, buses, per_bus)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log(f"total {time.monotonic() - procs_started:.0f} s")
    return 0


def med(values):
    values = [v for v in values if v == v]          # a window without requests has no gap (nan)
    return statistics.median(values) if values else float("nan")


def report(res, V, intervals, args, buses, per_bus) -> None:
    names = [v.name for v in V]
    print(f"# Wire pace: {', '.join(f'{v.name} = {v.ref}' for v in V)}; {args.runs} runs, medians; "
          f"window {args.seconds:g} s after {args.warmup:g} s\n")
    if "lines" not in args.skip:
        rows = [("shims", "c_shims polling back to back (post/poll/take)")]
        if any(v.has_plans for v in V):
            rows.append(("plan", "c_shims plan, period 0 (plan_take every 1 ms)"))
        rows += [(f"block{ms}", f"device block, task {ms} ms") for ms in intervals]
        head = ("| master | " + " | ".join(f"{t.split()[0]} tx/s | share | < t3.5 | gap ms" for _, t, *_ in LINES)
                + " |")
        print(head)
        print("|---" * (1 + 4 * len(LINES)) + "|")

        def cells(key, vname, row):
            fs = res.get((key, vname, row))
            if not fs:
                return "- | - | - | -"
            return (f"{med([f['tx'] for f in fs]):.1f} | {med([f['share'] for f in fs]):.2f} | "
                    f"{med([f['short'] for f in fs]):.0%} | {med([f['gap_ms'] for f in fs]):.1f}")

        for row, label in rows:
            for n in names:
                tag = f" ({n})" if len(names) > 1 else ""
                print(f"| {label}{tag} | " + " | ".join(cells(k, n, row) for k, *_ in LINES) + " |")
        print("| mbpoll -l 10 (its fastest) | " + " | ".join(cells(k, "", "mbpoll") for k, *_ in LINES) + " |")
        print("| plain libmodbus loop | " + " | ".join(cells(k, "", "lm") for k, *_ in LINES) + " |")
        failed = [f"{k[0]} {k[2]}{' (' + k[1] + ')' if k[1] and len(names) > 1 else ''}: "
                  f"{', '.join(str(f['failed']) for f in fs)}"
                  for k, fs in res.items() if len(k) == 3 and any(f.get("failed") for f in fs)]
        print("\nFailed transactions (whole run of each C master and mbpoll, per run): "
              + ("; ".join(failed) if failed else "none") + ".")
        empty = [f"{k[0]} {k[2]}{' (' + k[1] + ')' if k[1] and len(names) > 1 else ''}"
                 for k, fs in res.items() if len(k) == 3 and any(f["tx"] == 0 for f in fs)]
        if empty:
            print("Runs without any request in the window (counted as 0 tx/s in the medians): "
                  + "; ".join(empty) + ".")
        turns = [f["turn_ms"] for k in res if len(k) == 3 for f in res[k]]
        print(f"\nDevice turnaround measured on the wire (request end to reply start): median "
              f"{med(turns):.2f} ms. C masters read FC03 " + ", ".join(
                  f"{t.split()[0]} {c} registers at {a}" for _, t, _, _, _, _, _, a, c in LINES) + ".")
    if "three" not in args.skip:
        print(f"\n## Three devices on one 9600 8N2 line (Period T#0s each, task {args.three_task_ms} ms)\n")
        print("| variant | MV-D94 refreshes/s | FDC-100 | MT-S9 | MV-D94 tx/s | FDC tx/s | MT-S9 tx/s | "
              "line share | < t3.5 |")
        print("|---|---|---|---|---|---|---|---|---|")
        for n in names:
            fs = res.get(("three", n), [])
            if fs:
                p = [med([f["pubs"][i] for f in fs]) for i in range(3)]
                t = [med([f["tx"][i] for f in fs]) for i in range(3)]
                print(f"| {n} | {p[0]:.2f} | {p[1]:.2f} | {p[2]:.2f} | {t[0]:.1f} | {t[1]:.1f} | {t[2]:.1f} | "
                      f"{med([f['share'] for f in fs]):.2f} | {med([f['short'] for f in fs]):.0%} |")
    if "poll" not in args.skip:
        print(f"\n## MB_Poll beside TempCtrl_MVD94 on one 9600 8N2 line (MV-D94 Period T#0s; MB_Poll "
              f"Period T#1ms: {POLL_RANGES}; window {args.poll_seconds:g} s)\n")
        print("| variant | task ms | MV-D94 refreshes/s | MB_Poll refreshes/s | MV-D94 tx/s | MB_Poll tx/s | "
              "line share | < t3.5 |")
        print("|---|---|---|---|---|---|---|---|")
        for n in names:
            for ms in intervals:
                fs = res.get(("poll", f"{n}/{ms}"), [])
                if fs:
                    p = [med([f["pubs"][i] for f in fs]) for i in range(2)]
                    t = [med([f["tx"][i] for f in fs]) for i in range(2)]
                    print(f"| {n} | {ms} | {p[0]:.2f} | {p[1]:.2f} | {t[0]:.1f} | {t[1]:.1f} | "
                          f"{med([f['share'] for f in fs]):.2f} | {med([f['short'] for f in fs]):.0%} |")
    if "scale" not in args.skip and buses:
        print(f"\n## Scale: {buses} buses x {per_bus} MT-S9 at 115200 (simulators pace their replies), "
              f"one Counter_MTS9 each (Period := {args.scale_period}) in one program, task {args.scale_task_ms} ms; "
              f"against 1 device\n")
        print("| variant | devices | scan us median | p99 | max | sd | start jitter us median | p99 | max | "
              "refreshes/s per device min / median / max | devices never refreshed | worker CPU % | "
              "scan thread CPU % | scan thread SCHED_FIFO |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for n in names:
            for key, nd in (("scale1", 1), ("scale", buses * per_bus)):
                hs = res.get((key, n), [])
                if not hs:
                    continue
                g = lambda f: med([f(h) for h in hs])  # noqa: E731
                print(f"| {n} | {nd} | {g(lambda h: h['scan_us']['median']):.1f} | "
                      f"{g(lambda h: h['scan_us']['p99']):.1f} | {g(lambda h: h['scan_us']['max']):.0f} | "
                      f"{g(lambda h: h['scan_us']['sd']):.1f} | {g(lambda h: h['start_jitter_us']['median']):.0f} | "
                      f"{g(lambda h: h['start_jitter_us']['p99']):.0f} | {g(lambda h: h['start_jitter_us']['max']):.0f} | "
                      f"{g(lambda h: min(h['rates'])):.2f} / {g(lambda h: statistics.median(h['rates'])):.2f} / "
                      f"{g(lambda h: max(h['rates'])):.2f} | {g(lambda h: sum(1 for x in h['rates'] if x == 0)):.0f} | "
                      f"{g(lambda h: h['cpu']['others_pct']):.1f} | {g(lambda h: h['cpu']['main_pct']):.1f} | "
                      f"{sum(1 for h in hs if h.get('rt'))} of {len(hs)} runs |")


if __name__ == "__main__":
    sys.exit(main())
