"""A PLC program with the blocks loaded and unloaded again and again in one process, against
the simulator: what OpenPLC Runtime v4 does on every Start and Stop (c_shims/README.md,
"Lifetime").

    test_unload_program.py --host BUILD/unload_host --so PROGRAM.so --st unload.st [--cycles 20]
    test_unload_program.py --skip "reason"   (toolchain missing: exit 77, or 1 in CI)

The program (unload.st, built as a shared object by matiec or STruC++) runs a live MV-D94 and a
dead one, each with its plan, and ends with a write on the wire (the simulator drops its echo). The host
(unload_host.cpp) dlopens it, scans it until it is done, dlcloses it, checks that it is unmapped
and that the thread and descriptor counts are back, and says UNLOADED. Then this script checks
the simulator: in the cycle it heard the live device's reads (the port opened again), the dead
one's and the write; after dlclose returned, nothing (500 ms). A host that dies (SIGSEGV:
a worker left running in the unmapped program, as before the shims' destructor) fails the test.
"""
from __future__ import annotations

import argparse
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
sys.path.insert(0, os.path.dirname(HERE))  # tests/fb
from run_fb_test import sim_spec, skip  # noqa: E402  (the @SIM header, a skip's exit code)

QUIET_S = 0.5       # after dlclose: the simulator must hear nothing for this long
LINE_TIMEOUT_S = 90  # one cycle's scans (the program's budget is 250 scans) and its unload


def requests(frames, slave: int, fc: int | None = None) -> int:
    """Requests (simulator rx) to `slave` (with function fc) in a frame log."""
    n = 0
    for f in frames:
        b = f["hex"].split()
        if f["dir"] == "rx" and len(b) > 1 and int(b[0], 16) == slave and \
                (fc is None or int(b[1], 16) == fc):
            n += 1
    return n


def read_line(proc) -> str:
    """The host's next line, or '' when it ended or was silent too long."""
    ready, _, _ = select.select([proc.stdout], [], [], LINE_TIMEOUT_S)
    return proc.stdout.readline() if ready else ""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--host")
    ap.add_argument("--so")
    ap.add_argument("--st")
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--skip")
    args = ap.parse_args()
    if args.skip is not None:
        return skip(args.skip)
    from simctl import Simulator  # tools/sim/simctl.py

    spec = sim_spec(args.st)
    tmp = tempfile.mkdtemp(prefix="unload-")
    failures = []
    worst_ms = 0
    try:
        link = os.path.join(tmp, "ttySIM")
        with Simulator(spec["devices"], baud=int(spec["baud"]), fmt=spec["format"],
                       time_scale=float(spec["time-scale"]), link=link) as sim:
            env = dict(os.environ, MBFB_TEST_PORT=link, MBFB_SIM_CONTROL=sim.control_path)
            proc = subprocess.Popen([args.host, args.so, str(args.cycles)], env=env,
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            try:
                cycle = 0
                while cycle < args.cycles:
                    line = read_line(proc)
                    if not line:
                        break
                    print(line.rstrip())
                    if not line.startswith("UNLOADED "):
                        continue
                    _, c, ms = line.split()
                    worst_ms = max(worst_ms, int(ms))
                    heard = sim.log(clear=True)    # the cycle, up to now (after dlclose)
                    time.sleep(QUIET_S)
                    after = sim.log(clear=True)
                    live, dead = requests(heard, 1, 3), requests(heard, 7, 3)
                    write = requests(heard, 1, 6)
                    if live == 0 or dead == 0 or write == 0:
                        failures.append(f"cycle {c}: the simulator heard {live} reads of the "
                                        f"live device, {dead} of the dead one and {write} writes "
                                        "(each must be > 0)")
                    if requests(after, 1) + requests(after, 7):
                        failures.append(f"cycle {c}: {len(after)} frames after dlclose returned: "
                                        + " | ".join(f["hex"] for f in after[:4]))
                    cycle += 1
                    try:
                        proc.stdin.write("next\n")
                        proc.stdin.flush()
                    except BrokenPipeError:
                        break  # the host died: its exit status says how
                try:
                    proc.stdin.close()
                except BrokenPipeError:
                    pass
                print(proc.stdout.read(), end="")
                proc.wait(timeout=LINE_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                failures.append("the host did not end")
            proc.stdout.close()
            rc = proc.returncode
            if rc is not None and rc < 0:
                failures.append(f"the host died with signal {-rc} after {cycle} unloads")
            elif rc != 0:
                failures.append(f"the host failed (exit {rc}) after {cycle} unloads")
            elif cycle != args.cycles:
                failures.append(f"{cycle} of {args.cycles} cycles")
            if failures:
                print("--- simulator stderr (tail) ---")
                print(sim.stderr()[-3000:])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for f in failures:
        print(f"FAIL: {f}")
    if failures:
        return 1
    print(f"PASS: {args.cycles} load/unload cycles, each with two plans, a dead device and a "
          f"write in flight; longest dlclose {worst_ms} ms; nothing heard after any dlclose")
    return 0


if __name__ == "__main__":
    sys.exit(main())
