#!/usr/bin/env python3
"""Scan time of mbcommission against the physical minimum, in one run.

    .venv/bin/python bench/scan_time.py [--lib build/lib/libmbfb.so]

Cases: the factory-settings pass (3 settings x 247 addresses) on the demo's line, and a sweep of
one setting (8N2 RTU) over 247 addresses at 9600 and at 115200, each against the simulator with
the demo's three instruments (at 115200: the MT-S9 alone). The physical minimum of a case is addresses x (request on the wire + the
shims' shortest reply timeout for it), the time a line with no device at all costs; the ratio
measured / minimum is printed (bench/README.md, "Scan time").
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


def minimum(settings, n_addr):
    """Request + the shims' shortest timeout for each probe (lineops.probe_seconds less the gap
    the shims keep before a request)."""
    total = 0.0
    for baud, fmt, framing in settings:
        bits = 1 + int(fmt[0]) + (fmt[1] != "N") + int(fmt[2])
        total += (lineops.probe_seconds(baud, fmt, framing) - 3.5 * bits / baud) * n_addr
    return total


def run(port, baud, extra):
    t = time.monotonic()
    r = subprocess.run([sys.executable, TOOL, "scan", port, "--no-progress", *extra],
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scan failed: {r.stderr.strip()}")
    return time.monotonic() - t


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lib", default=os.path.join(ROOT, "build", "lib", "libmbfb.so"))
    a = p.parse_args()
    os.environ["MBFB_LIB"] = a.lib
    cases = [("factory pass, 3 settings", 9600, [], lineops.FACTORY),
             ("one setting at 9600", 9600, ["--baud", "9600", "--format", "8N2", "--framing", "rtu"],
              [(9600, "8N2", "rtu")]),
             ("one setting at 115200", 115200,
              ["--baud", "115200", "--format", "8N2", "--framing", "rtu"],
              [(115200, "8N2", "rtu")])]
    print(f"| case | measured s | physical minimum s | ratio |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory(dir=os.path.join(ROOT, "build")) as tmp:
        for name, baud, extra, settings in cases:
            devices = DEVICES if baud <= 19200 else ["mts9:3"]   # the SetPro stops at 19200
            with Simulator(devices, baud=baud, fmt="8N2", link=os.path.join(tmp, "line")) as sim:
                took = run(sim.port, baud, extra)
            low = minimum(settings, 247)
            print(f"| {name} | {took:.1f} | {low:.1f} | {took / low:.2f} |", flush=True)


if __name__ == "__main__":
    main()
