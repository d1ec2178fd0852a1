"""A recipe download's cost on a paced line, beside another block's refresh, in one run.

    .venv/bin/python bench/recipe_pace.py [--build build] [-k 6] [--period-ms 200] [--before REF]

Not a test: it prints figures (bench/README.md, "Recipe downloads"). It compiles
bench/recipe_pace.st with the working tree's st_src (as bench/bus_economy.py does: iec2c, g++)
and runs it against the simulator (an MV-D94 at 1, a VD at 2) on a line paced by ptyline at
9600 8N2 (1..10 ms device turnaround). Two windows, marked by the program: idle (both blocks
refreshing) and K downloads back to back of a 10-field recipe into the MV-D94. From the
simulator's log: the download's requests per recipe (FC06 writes, one-word FC03 read-backs,
and the MV-D94's refresh reads in between), the wire time they take (gap + bytes + turnaround,
as bus_economy), how long a download takes (from its Execute edge to SettingsDone, and the
window over K, which adds the wait for the settings' re-read before the next one), and the
VD's refreshes per second in each window. --before REF adds an arm with the st_src of commit
REF (for instance the one before the downloads ran as chains in the worker), built and run
the same way in the same invocation, side by side.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
from bus_economy import CHAR_S, GAP_S, build, run_paced, st_sources  # noqa: E402  (bench/ on the path)

FIELDS = 10                      # bench/recipe_pace.st: writes per download (9 fields + LOCK)


def run(exe: str, ptyline: str) -> tuple[str, list, dict]:
    return run_paced(exe, ptyline, ["mvd94:1:SV=100.0,DP=1", "vd:2:SV=50.0,DP=1"],
                     "bench-recipe-", "-k")


def window(out: str, frames: list, name: str, scan_s: float, turn: float) -> dict:
    m = {w: re.search(rf"note scan (\d+): {name} {w} (\d+) (\d+)", out) for w in ("start", "end")}
    (s0, f0, r0), (s1, f1, r1) = ((int(x) for x in m[w].groups()) for w in ("start", "end"))
    secs = (s1 - s0) * scan_s
    rx = [f["hex"].split() for f in frames[f0:f1] if f["dir"] == "rx" and f["hex"]]
    whole = [r for r in rx if len(r) >= 6]   # a frame cut short by noise is not a request
    tx = {i: f["hex"].split() for i, f in enumerate(frames[f0:f1]) if f["dir"] == "tx" and f["hex"]}

    def bus(reqs):
        return sum(GAP_S + turn + (len(r) + 8) * CHAR_S for r in reqs)   # + a reply of ~8 bytes
    mv = [r for r in whole if r[0] == "01"]
    writes = [r for r in mv if r[1] == "06"]
    backs = [r for r in mv if r[1] == "03" and r[4:6] == ["00", "01"]]
    line_bytes = sum(len(r) for r in rx) + sum(len(t) for t in tx.values())
    return {"secs": secs, "vd_rate": (r1 - r0) / secs, "writes": writes, "backs": backs,
            "mv_other": len(mv) - len(writes) - len(backs), "bus_dl": bus(writes + backs),
            "line_util": (len(rx) * (GAP_S + turn) + line_bytes * CHAR_S) / secs}


def arm(args, ptyline: str, program: str, before: str | None) -> dict:
    """Build the bench program with the working tree's st_src (before None) or REF's, run it,
    and take the figures of both windows."""
    work = tempfile.mkdtemp(prefix="bench-recipe-build-")
    try:
        exe = build(args.build, work, st_sources(before, work), program)
        out, frames, stats = run(exe, ptyline)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    turn = (stats["reply_latency"]["avg_us"] or 0) / 1e6
    busy = re.search(r"note scan \d+: dl busy (\d+)", out)
    return {"turn": turn, "idle": window(out, frames, "idle", args.scan_ms / 1000, turn),
            "dl": window(out, frames, "dl", args.scan_ms / 1000, turn),
            "busy_s": int(busy.group(1)) * args.scan_ms / 1000}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("-k", type=int, default=6, help="downloads in the window")
    ap.add_argument("--period-ms", type=int, default=200)
    ap.add_argument("--scan-ms", type=int, default=10)
    ap.add_argument("--before", metavar="REF", help="also run the st_src of commit REF")
    args = ap.parse_args()
    ptyline = os.path.join(args.build, "tools", "sim", "ptyline", "mbfb-ptyline")
    if not os.path.exists(ptyline):
        raise SystemExit(f"missing {ptyline}: configure and build --build first")
    with open(os.path.join(ROOT, "bench", "recipe_pace.st"), encoding="utf-8") as fh:
        program = (fh.read().replace("@PERIOD@", f"T#{args.period_ms}ms")
                   .replace("@SCAN_MS@", str(args.scan_ms)).replace("@K@", str(args.k))
                   .replace("@SCANS@", str(int(3000 / args.scan_ms))))
    arms = [("this tree", arm(args, ptyline, program, None))]
    if args.before:
        arms.append((args.before, arm(args, ptyline, program, args.before)))
    k = args.k
    turns = " / ".join(f"{a['turn'] * 1000:.1f}" for _, a in arms)
    print(f"one line 9600 8N2 (ptyline), reply latency {turns} ms, scans of {args.scan_ms} ms, "
          f"Period {args.period_ms} ms; {k} downloads of a {FIELDS}-field recipe (MV-D94) beside a VD\n")
    print("| figure | " + " | ".join(f"{name}: idle | downloads" for name, _ in arms) + " |")
    print("|---|" + "---|---|" * len(arms))

    def row(label, idle, dl):
        print(f"| {label} | " + " | ".join(f"{idle(a)} | {dl(a)}" for _, a in arms) + " |")
    row("FC06 writes per download", lambda a: "", lambda a: f"{len(a['dl']['writes']) / k:.2f}")
    row("one-word read-backs per download", lambda a: "", lambda a: f"{len(a['dl']['backs']) / k:.2f}")
    row("MV-D94 refresh reads per download", lambda a: "", lambda a: f"{a['dl']['mv_other'] / k:.2f}")
    row("time per download, Execute to Done", lambda a: "",
        lambda a: f"{a['busy_s'] / k * 1000:.0f} ms")
    row("wire time of its writes and read-backs", lambda a: "",
        lambda a: f"{a['dl']['bus_dl'] / k * 1000:.0f} ms ({a['dl']['bus_dl'] / a['busy_s']:.0%} of Execute to Done)")
    row("window per download (with the wait for the settings' re-read)", lambda a: "",
        lambda a: f"{a['dl']['secs'] / k * 1000:.0f} ms ({a['dl']['bus_dl'] / a['dl']['secs']:.0%})")
    row("line in use (all requests and replies)", lambda a: f"{a['idle']['line_util']:.0%}",
        lambda a: f"{a['dl']['line_util']:.0%}")
    row("VD refreshes per second", lambda a: f"{a['idle']['vd_rate']:.2f}",
        lambda a: f"{a['dl']['vd_rate']:.2f} (x{a['dl']['vd_rate'] / a['idle']['vd_rate']:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
