"""Where the silence before a request goes, in bench/plant_scale.py's plant: the bus worker or the line.

    .venv/bin/python bench/gap_trace.py                       # 4 lines x 16 devices, a 12 s window: ~1.5 min
    .venv/bin/python bench/gap_trace.py --help                # --lines 4 --per-line 16 --seconds 12 --ref worktree

Not a test: it prints figures (bench/README.md, "Scale: a plant of 4 lines x 16 instruments").
The plant program of plant_scale.py (Period T#0s: refreshes back to back) runs in the runner on
its paced lines (ptyline and the simulator), while `perf trace -e read,write` follows the
runner's threads and the ptyline processes. For each request of a line it takes four times:

    P  ptyline writes the reply's last byte to the master's pty
    R  the bus worker's read() that got it returns (the worker takes the line as quiet from here)
    W  the worker writes the next request (after the gap it keeps: t3.5 or 44 bit times)
    Q  ptyline's read() of that request returns (ptyline's log starts the request here)

and prints, per line, the means (medians) of: the worker's own silence W - R; the delivery
through the ptys and the two wake-ups on them, (R - P) + (Q - W); P to Q; and, from ptyline's
frame log over the same window, the logged silence before a request, whose excess over P to Q
is ptyline delivering the reply's last byte after its scheduled time. The share of the wire
counts from the log, so on a loaded machine the line model's own waits for a CPU show there as
silence the master left. perf's tracing adds load of its own: compare within one run.

The workers are told apart from the runner's other threads by their requests: a thread whose
writes ptyline reads (the first ptyline read after each write, median under 5 ms). Needs what
plant_scale.py's wire run needs, and perf (Debian package linux-perf) with the right to trace
the processes (root, or kernel.perf_event_paranoid <= 1).
"""
from __future__ import annotations

import argparse
import bisect
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import plant_scale as ps  # noqa: E402
import rig as wp  # noqa: E402
from runner import Runner  # noqa: E402

# "  12.345 ( 0.012 ms): comm/1234 write(fd: 5, buf: 0x..., count: 8)   = 8"
EVENT = re.compile(r"\s*([\d.]+) \(\s*([\d.]+) ms\): .*?/(\d+) (read|write)\(.*\)\s+= (-?\d+)")


def trace_events(path: str) -> dict[int, list[tuple[str, float, float, int]]]:
    """{tid: [(name, entry ms, return ms, result)]} of the successful calls, in order."""
    out: dict[int, list] = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        for ln in fh:
            m = EVENT.match(ln)
            if m and int(m.group(5)) > 0:
                t, d = float(m.group(1)), float(m.group(2))
                out.setdefault(int(m.group(3)), []).append((m.group(4), t, t + d, int(m.group(5))))
    return out


def returns(events, name: str) -> list[float]:
    return sorted(e[2] for e in events if e[0] == name)


def after(sorted_times: list[float], t: float) -> float | None:
    i = bisect.bisect_left(sorted_times, t)
    return sorted_times[i] if i < len(sorted_times) else None


def before(sorted_times: list[float], t: float) -> float | None:
    i = bisect.bisect_right(sorted_times, t)
    return sorted_times[i - 1] if i else None


def worker_of(ev, worker_tids, ptyline_pid: int) -> int | None:
    """The runner thread whose writes this ptyline reads first (median delay under 5 ms)."""
    reads = returns(ev.get(ptyline_pid, []), "read")
    best = None
    for tid in worker_tids:
        writes = [e[1] for e in ev[tid] if e[0] == "write"]
        d = [q - w for w in writes[:100] if (q := after(reads, w)) is not None]
        if len(d) >= 20 and statistics.median(d) < 5.0 and (best is None or statistics.median(d) < best[0]):
            best = (statistics.median(d), tid)
    return best[1] if best else None


def split(ev, tid: int, ptyline_pid: int) -> dict[str, list[float]]:
    """Per request of the worker: W - R, (R - P) + (Q - W), Q - P (ms)."""
    preads, pwrites = returns(ev[ptyline_pid], "read"), returns(ev[ptyline_pid], "write")
    wreads = returns(ev[tid], "read")
    out: dict[str, list[float]] = {"worker": [], "delivery": [], "p_to_q": []}
    for name, w, _, _ in ev[tid]:
        if name != "write":
            continue
        r = before(wreads, w)
        p = before(pwrites, r) if r is not None else None
        q = after(preads, w)
        if None in (r, p, q) or r - p > 50 or q - w > 50:  # the window's edges, a lost event
            continue
        out["worker"].append(w - r)
        out["delivery"].append((r - p) + (q - w))
        out["p_to_q"].append(q - p)
    return out


def fig(xs: list[float]) -> str:
    return f"{statistics.mean(xs):.2f} ({statistics.median(xs):.2f})" if xs else "-"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lines", type=int, default=4)
    ap.add_argument("--per-line", type=int, default=16)
    ap.add_argument("--baud", type=int, default=19200, help="every line, 8N2")
    ap.add_argument("--task-ms", type=int, default=20)
    ap.add_argument("--warmup", type=float, default=4.0)
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--ref", default="worktree", help="a commit, or 'worktree'")
    args = ap.parse_args()
    if not (1 <= args.lines <= 16 and 1 <= args.per_line and args.lines * args.per_line <= 247) \
            or args.baud not in (2400, 4800, 9600, 19200) or min(args.task_ms, args.seconds) <= 0 or args.warmup < 0:
        raise SystemExit("bad arguments: see --help (at most 247 devices; baud 2400..19200; times > 0)")
    if not shutil.which("perf"):
        raise SystemExit("perf not found (Debian package linux-perf)")
    with wp.temp_root("gaptrace-") as tmp:      # the simulators' temp dirs too
        devs = ps.plant(args.lines, args.per_line)
        ports = [os.path.join(tmp, f"line{L}") for L in range(args.lines)]
        v = wp.Variant("v", args.ref, tmp, "Debug")
        wp.log("compiling the plant program (iec2c, g++ -O0, the runner) ...")
        exe = ps.compile_runner(v, "t0", ps.plant_program(ports, devs, args.baud, "T#0s", args.task_ms))
        lines = ps.open_lines(v.ptyline, tmp, devs, args.lines, args.baud)
        try:
            with Runner(exe) as plc:
                time.sleep(args.warmup)
                out = os.path.join(tmp, "perf.txt")
                pids = [plc.proc.pid] + [x.proc.pid for x in lines]
                wp.log(f"perf trace over {args.seconds:g} s ...")
                perf = subprocess.Popen(["perf", "trace", "-o", out, "-e", "read,write", "-p",
                                         ",".join(map(str, pids))], stderr=subprocess.PIPE, text=True)
                time.sleep(1.0)                              # perf attached
                t0 = [x.now_us() for x in lines]
                time.sleep(args.seconds)
                t1 = [x.now_us() for x in lines]
                wp.stop(perf, sig=signal.SIGINT)
                if perf.returncode not in (0, -2, 130):
                    raise SystemExit(f"perf trace exited {perf.returncode}: {perf.stderr.read()[-1000:]}")
                runner_tids = {int(t) for t in os.listdir(f"/proc/{plc.proc.pid}/task")}
            logged = [(ps.line_gaps(x, a, b), x.figures(a, b)) for x, a, b in zip(lines, t0, t1)]
        finally:
            for x in lines:
                x.close()
        ev = trace_events(out)
        load = os.getloadavg()
        print(f"# Silence before a request, {args.lines} lines x {args.per_line} devices at {args.baud} 8N2, "
              f"{args.ref} ({ps.revision() if args.ref == 'worktree' else args.ref}); "
              f"{time.strftime('%H:%M', time.gmtime())} UTC, load average {' '.join(f'{x:.2f}' for x in load)}; "
              f"ms, mean (median)\n")
        print("| line | requests traced | worker W - R | delivery (R - P) + (Q - W) | P to Q | logged silence | "
              "ptyline late with the reply's end | share (log) |")
        print("|---" * 8 + "|")
        for L, x in enumerate(lines):
            tid = worker_of(ev, [t for t in runner_tids if t in ev], x.proc.pid)
            g, f = logged[L]
            s = split(ev, tid, x.proc.pid) if tid else {"worker": [], "delivery": [], "p_to_q": []}
            late = g["mean_ms"] - statistics.mean(s["p_to_q"]) if s["p_to_q"] and g else float("nan")
            print(f"| {L} | {len(s['worker'])} | {fig(s['worker'])} | {fig(s['delivery'])} | {fig(s['p_to_q'])} | "
                  f"{g['mean_ms']:.2f} ({f['gap_ms']:.2f}) | {late:.2f} | {f['share']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
