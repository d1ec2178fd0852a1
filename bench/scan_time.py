#!/usr/bin/env python3
"""Scan time of mbcommission against the physical minimum, in one run.

    .venv/bin/python bench/scan_time.py [--lib build/lib/libmbfb.so]

Cases: the factory settings at the factory address alone (`--address 1`: the first pass, 3
probes, as a whole command); the default scan of the demo's line (the factory settings: first
at the factory addresses, then at the other 246 addresses), with the time of its first pass as
the tool reports it ("pass 1 done ... after X s") and the whole command's time; and a sweep of one
setting (8N2 RTU) over 247 addresses at 9600 and at 115200, each against the simulator with the
demo's three instruments (at 115200: the MT-S9 alone). The physical minimum of a case is
probes x (request on the wire + the shims' shortest reply timeout for it), the time a line with
no device at all costs; the ratio measured / minimum is printed (bench/README.md, "Scan time"),
for the scan as it is (a fresh line for each probe: no settle) and with --settle (the shims'
settle after each silent address, as before), side by side.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [os.path.join(ROOT, "tools", "sim"), os.path.join(ROOT, "tools", "commission")]
from simctl import Simulator  # noqa: E402
import lineops  # noqa: E402

TOOL = os.path.join(ROOT, "tools", "commission", "mbcommission.py")
DEVICES = ["fdc100:1:PARI=2,SP1=120.0", "mvd94:2:SV=100.0,DP=1", "mts9:3"]


def minimum(plan):
    """Request + the shims' shortest timeout for each probe of [(setting, addresses)]
    (lineops.probe_seconds less the gap the shims keep before a request)."""
    total = 0.0
    for (baud, fmt, framing), addrs in plan:
        bits = 1 + int(fmt[0]) + (fmt[1] != "N") + int(fmt[2])
        total += (lineops.probe_seconds(baud, fmt, framing) - 3.5 * bits / baud) * len(addrs)
    return total


def run(port, extra, settle=False):
    """(seconds of the whole command, {pass number: seconds after the probing began})."""
    t = time.monotonic()
    r = subprocess.run([sys.executable, TOOL, "scan", port, "--no-progress", *extra,
                        *(["--settle"] if settle else [])],
                       capture_output=True, text=True)
    took = time.monotonic() - t
    if r.returncode != 0:
        sys.exit(f"scan failed: {r.stderr.strip()}")
    passes = {}
    for line in r.stdout.splitlines():       # "pass 1 done (...) after 0.6 s: ..."
        if line.startswith("pass ") and " done " in line:
            passes[int(line.split()[1])] = float(line.split(" after ")[1].split()[0])
    return took, passes


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lib", default=os.path.join(ROOT, "build", "lib", "libmbfb.so"))
    a = p.parse_args()
    os.environ["MBFB_LIB"] = a.lib
    addrs = list(range(1, 248))
    factory = lineops.passes(lineops.FACTORY, addrs)
    one = [(9600, "8N2", "rtu")]
    cases = [("factory settings at the factory address only (`--address 1`)", 9600,
              ["--address", "1"], lineops.passes(lineops.FACTORY, [1])),
             ("default scan: factory settings at all 247 addresses", 9600, [], factory),
             ("one setting at 9600", 9600, ["--baud", "9600", "--format", "8N2", "--framing", "rtu"],
              lineops.passes(one, addrs)),
             ("one setting at 115200", 115200,
              ["--baud", "115200", "--format", "8N2", "--framing", "rtu"],
              lineops.passes([(115200, "8N2", "rtu")], addrs))]
    print("| case | measured s | with --settle s | physical minimum s | ratio | ratio --settle |\n"
          "|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(dir=os.path.join(ROOT, "build")) as tmp:
        for name, baud, extra, plan in cases:
            devices = DEVICES if baud <= 19200 else ["mts9:3"]   # the SetPro stops at 19200
            took, passes = {}, {}
            for settle in (False, True):    # side by side: the same simulator, one after the other
                with Simulator(devices, baud=baud, fmt="8N2", link=os.path.join(tmp, "line")) as sim:
                    took[settle], passes[settle] = run(sim.port, extra, settle)
            if not extra:                   # the default scan: its first pass on its own
                low = minimum(plan[0][1])
                print(f"| pass 1: factory settings at the factory address "
                      f"({sum(len(a) for _, a in plan[0][1])} probes; time the tool reports) "
                      f"| {passes[False][1]:.2f} | {passes[True][1]:.2f} | {low:.2f} "
                      f"| {passes[False][1] / low:.2f} | {passes[True][1] / low:.2f} |", flush=True)
            low = sum(minimum(p) for _, p in plan)
            print(f"| {name} (whole command) | {took[False]:.1f} | {took[True]:.1f} | {low:.1f} "
                  f"| {took[False] / low:.2f} | {took[True] / low:.2f} |", flush=True)


if __name__ == "__main__":
    main()
