"""RS-485 direction switched by the shims beside plain serial: how much of the paced line the
shims use when the bus worker toggles RTS around every request, with and without delays, side
by side with no direction control in one run.

    .venv/bin/python bench/direction.py                  # build/ (targets mbfb, mbfb-ptyline,
                                                         #  mbfb_linedouble)
    .venv/bin/python bench/direction.py --build build --runs 3 --seconds 5

Not a test: it prints figures (bench/README.md, "Direction control on the wire"). The master is
bench/wirepace/wp_shims.c (`post`: one FC03 after the other, as fast as the worker runs them),
the device one MV-D94 at 9600 8N2 (17 registers) on a pty paced by ptyline (1..10 ms
turnaround, seeded), as in bench/rtu_tcp.py. A pty has no RTS, so the RTS runs go through the
test double (tests/shims/linedouble.c, LD_PRELOAD), which passes the ioctls by; the plain runs
go through the same double too, so both pay its bookkeeping. Runs alternate; medians of --runs.
The predicted ratio is what the delays alone would cost: shortest / (shortest + before + after),
shortest the line's shortest compliant transaction (bench/rtu_tcp.py). Everything listens on a
pty; every process is stopped by pid; the temp dir is removed.
"""
from __future__ import annotations

import os
import shutil
import statistics
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
sys.path.insert(0, os.path.join(ROOT, "bench"))
from rtu_tcp import (BAUD, COUNT, DEVICE, FMT, bench_args, build_master, master,  # noqa: E402
                     shortest_transaction)
from simctl import Simulator  # noqa: E402

DIR_RTS = 2                                     # MBFB_DIR_RTS
CASES = [("none", None, 0, 0), ("rts", DIR_RTS, 0, 0), ("rts +1 ms before", DIR_RTS, 1000, 0),
         ("rts +0.5 ms both", DIR_RTS, 500, 500)]


def main() -> int:
    args = bench_args(__doc__)
    ptyline = os.path.join(args.build, "tools", "sim", "ptyline", "mbfb-ptyline")
    double = os.path.join(args.build, "tests", "shims", "libmbfb_linedouble.so")
    tmp = tempfile.mkdtemp(prefix="direction-bench-")
    res = {name: [] for name, *_ in CASES}
    fails = {name: 0 for name, *_ in CASES}
    try:
        exe = build_master(args.build, tmp, [ptyline, double])
        for r in range(args.runs):
            for name, mode, before, after in CASES:
                with Simulator([DEVICE], baud=BAUD, fmt=FMT, pace=True, seed=r + 1,
                               extra=["--ptyline", ptyline]) as sim:
                    env = dict(os.environ, LD_PRELOAD=double, LINEDOUBLE_PORT=sim.port)
                    if mode is not None:
                        env.update(MBFB_WP_DIRECTION=str(mode), MBFB_WP_DIR_BEFORE_US=str(before),
                                   MBFB_WP_DIR_AFTER_US=str(after))
                    rate, failed = master(exe, sim.port, args.seconds, env)
                res[name].append(rate)
                fails[name] += failed
                print(f"run {r + 1} {name:18s} {rate:6.2f} tx/s  failed {failed}",
                      file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    shortest = shortest_transaction()
    base = statistics.median(res["none"])
    print(f"MV-D94 {BAUD} {FMT}, FC03 of {COUNT} registers; shortest transaction "
          f"{shortest * 1000:.1f} ms; {args.runs} runs of {args.seconds:g} s, medians")
    print("| direction | tx/s | share | / none | predicted from the delays | failed |")
    print("|---|---|---|---|---|---|")
    for name, _mode, before, after in CASES:
        rate = statistics.median(res[name])
        predicted = shortest / (shortest + (before + after) / 1e6)
        print(f"| {name} | {rate:.2f} | {rate * shortest:.2f} | {rate / base:.2f} | "
              f"{predicted:.2f} | {fails[name]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
