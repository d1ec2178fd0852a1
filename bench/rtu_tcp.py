"""RTU over TCP beside plain serial: how much of the paced line the shims use through a
transparent gateway, against the same device on a paced serial line, side by side in one run.

    .venv/bin/python bench/rtu_tcp.py                    # build/ (cmake targets mbfb, mbfb-ptyline)
    .venv/bin/python bench/rtu_tcp.py --build build --runs 3 --seconds 5

Not a test: it prints figures (bench/README.md, "RTU over TCP beside serial"). The master is
bench/wirepace/wp_shims.c (`post`: one FC03 after the other, as fast as the worker runs them)
linked with the shims of --build. The device is one MV-D94 at 9600 8N2 (reading 17 registers):
* serial: the simulator on a pty paced by ptyline (1..10 ms turnaround, seeded);
* gateway: the simulator as an RTU-over-TCP gateway on 127.0.0.1 (`--rtu-tcp --pace`: its
  line timed at the same baud, the same turnaround model), the shims on
  'tcp://127.0.0.1:PORT' with Framing RTU.
Runs alternate (serial, gateway, serial, ...); medians of --runs. tx/s = good transactions
per second of the master's run; share = tx/s x the shortest compliant transaction (t3.5 +
request + mean turnaround 5.5 ms + reply, as wire_pace.py's share), 1.00 = the line's limit. Everything listens on a
pty or 127.0.0.1; every process is stopped by pid; the temp dir is removed.
"""
from __future__ import annotations

import argparse
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
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
sys.path.insert(0, os.path.join(ROOT, "bench"))
from simctl import Simulator  # noqa: E402
from rig import cache_value, run, stop  # noqa: E402

BAUD, FMT, DEVICE, FC, ADDR, COUNT = 9600, "8N2", "mvd94:1", 3, 0, 17


def master(exe: str, port: str, seconds: float, env: dict | None = None) -> tuple[float, int]:
    """wp_shims post on port for `seconds`; (good transactions per second, failed)."""
    out = tempfile.TemporaryFile(mode="w+")
    t0 = time.monotonic()
    proc = subprocess.Popen([exe, "post", port, str(BAUD), FMT, "1", str(FC), str(ADDR),
                             str(COUNT)], stdout=out, stderr=subprocess.STDOUT, text=True,
                            env=env)
    try:
        time.sleep(seconds)
    finally:
        stop(proc, signal.SIGINT)
    elapsed = time.monotonic() - t0
    out.seek(0)
    text = out.read()
    out.close()
    m = re.search(r"^ok (\d+) err (\d+)$", text, re.M)
    if not m:
        raise SystemExit(f"wp_shims on {port} printed no result:\n{text[-2000:]}")
    return int(m.group(1)) / elapsed, int(m.group(2))


def shortest_transaction() -> float:
    """The line's shortest compliant FC03 transaction in seconds: t3.5, request, mean
    turnaround 5.5 ms, reply (as wire_pace.py's share)."""
    bits = 1 + int(FMT[0]) + (FMT[1] != "N") + int(FMT[2])
    return (3.5 + 6 + 2 + 3 + 2 * COUNT + 2) * bits / BAUD + 0.0055


def build_master(build: str, tmp: str, need=()) -> str:
    """bench/wirepace/wp_shims.c linked with the shims of `build` into tmp; the executable.
    `need`: more build outputs that must exist."""
    lib = os.path.join(build, "c_shims", "libmbfb.a")
    lm = cache_value(build, "MBFB_LM_OPENPLC_LIB") or cache_value(build, "MBFB_LM_DEBIAN_LIB")
    missing = [p for p in (lib, *need) if not os.path.exists(p)]
    if missing or not lm:
        raise SystemExit(f"build {', '.join(missing) or 'libmodbus'} first (cmake --build {build})")
    exe = os.path.join(tmp, "wp_shims")
    run(["gcc", "-O2", "-I", os.path.join(ROOT, "c_shims", "include"), "-o", exe,
         os.path.join(ROOT, "bench", "wirepace", "wp_shims.c"), lib, lm, "-lpthread", "-ldl",
         f"-Wl,-rpath,{os.path.dirname(lm)}"])
    return exe


def bench_args(doc: str):
    """The options of a side-by-side wire-share bench: --build, --runs, --seconds."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"), help="cmake build dir")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=5.0, help="each master run")
    return ap.parse_args()


def main() -> int:
    args = bench_args(__doc__)
    ptyline = os.path.join(args.build, "tools", "sim", "ptyline", "mbfb-ptyline")
    tmp = tempfile.mkdtemp(prefix="rtutcp-bench-")
    try:
        exe = build_master(args.build, tmp, [ptyline])
        res = {"serial": [], "gateway": []}
        fails = {"serial": 0, "gateway": 0}
        for r in range(args.runs):
            for kind in ("serial", "gateway"):
                if kind == "serial":
                    sim = Simulator([DEVICE], baud=BAUD, fmt=FMT, pace=True, seed=r + 1,
                                    extra=["--ptyline", ptyline])
                else:
                    sim = Simulator([DEVICE], transport="rtu-tcp", baud=BAUD, fmt=FMT,
                                    pace=True, seed=r + 1)
                with sim:
                    port = sim.port if kind == "serial" else f"tcp://{sim.tcp[0]}:{sim.tcp[1]}"
                    rate, failed = master(exe, port, args.seconds)
                res[kind].append(rate)
                fails[kind] += failed
                print(f"run {r + 1} {kind:7s} {rate:6.2f} tx/s  failed {failed}",
                      file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    shortest = shortest_transaction()
    print(f"MV-D94 {BAUD} {FMT}, FC03 of {COUNT} registers; shortest transaction "
          f"{shortest * 1000:.1f} ms; {args.runs} runs of {args.seconds:g} s, medians")
    print("| path | tx/s | share | failed |")
    print("|---|---|---|---|")
    for kind in ("serial", "gateway"):
        rate = statistics.median(res[kind])
        print(f"| {kind} | {rate:.2f} | {rate * shortest:.2f} | {fails[kind]} |")
    ratio = statistics.median(res["gateway"]) / statistics.median(res["serial"])
    print(f"gateway / serial: {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
