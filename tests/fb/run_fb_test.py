"""Run one ST function-block test program against the device simulator.

    run_fb_test.py --exe BUILD/fb_<name> --st tests/fb/t_<name>.st
    run_fb_test.py --skip "reason"      (toolchain missing: exit 77, or 1 in CI)

The test program's header says which simulator it needs, in one comment line:
    (*@SIM format=8N2 baud=9600 time-scale=0.001 device=mvd94:1:SV=100.0,DP=1 device=... *)
The simulator runs on a pty reached through a stable --symlink path (reopen_port keeps it),
or with transport=rtu-tcp as an RTU-over-TCP gateway on 127.0.0.1 (the port is then
'tcp://127.0.0.1:PORT'); the program gets it in MBFB_TEST_PORT and the control socket in
MBFB_SIM_CONTROL. transport=pymodbus-mvd94 serves the program no simulator but pymodbus's RTU
framer on a TCP server at 127.0.0.1 with an MV-D94's registers (tests/shims/pymodbus_peer.py,
a peer we did not write; no control socket); transport=pymodbus-mvd94+poll adds its generic
slave 2 (coils, discrete inputs, registers). The
simulator is stopped by pid whatever happens (simctl.Simulator context manager).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(HERE)), "tools", "sim"))
sys.path.insert(0, os.path.dirname(HERE))
import timed  # noqa: E402  (tests/timed.py)

SKIP = 77


def sim_spec(st_path: str) -> dict:
    with open(st_path, encoding="utf-8") as fh:
        text = fh.read()
    m = re.search(r"\(\*@SIM(.*?)\*\)", text, re.S)
    if not m:
        raise SystemExit(f"{st_path}: no (*@SIM ... *) header")
    spec = {"devices": [], "format": "8N2", "baud": 9600, "time-scale": 1.0, "transport": "pty",
            "pace": "0"}
    for item in m.group(1).split():
        key, _, value = item.partition("=")
        if key == "device":   # a generic device's file=NAME: a file beside the test
            spec["devices"].append(re.sub(r"(?<=[:,])file=(?!/)([^,]+)",
                                          lambda m: "file=" + os.path.join(HERE, m.group(1)), value))
        elif key in ("format", "baud", "time-scale", "transport", "pace"):
            spec[key] = value
        else:
            raise SystemExit(f"{st_path}: unknown @SIM key {key!r}")
    return spec


def skip(reason: str) -> int:
    """A missing toolchain: the exit code, 77 (skipped), or 1 under MBFB_REQUIRE_TOOLCHAIN=1."""
    print(f"SKIP: {reason}")
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        print("MBFB_REQUIRE_TOOLCHAIN=1: a missing toolchain is a failure")
        return 1
    return SKIP


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--exe")
    ap.add_argument("--st")
    ap.add_argument("--skip")
    ap.add_argument("--baud", type=int, help="the line's baud instead of the @SIM header's "
                    "(the program reads it as MBFB_TEST_BAUD: T_BAUD)")
    ap.add_argument("--direction", help="RS-485 direction mode under test (rts, gpio, kernel): "
                    "the program runs under the test double (--double) and reads the mode as "
                    "MBFB_TEST_DIRECTION (T_DIRECTION); its edges are checked afterwards")
    ap.add_argument("--framing", default="", help="the framing under test (rtu, ascii, nocrc): "
                    "MBFB_TEST_FRAMING (T_FRAMING), and framing=... of the @SIM MT-S9 devices")
    ap.add_argument("--double", help="the test double's library (tests/shims/linedouble.c)")
    ap.add_argument("--timeout", type=float, default=400.0)
    args = ap.parse_args()
    if args.skip is not None:
        return skip(args.skip)
    # the program's worker and the simulated devices hold reply timeouts: before other load
    timed.raise_priority(os.path.basename(args.st or args.exe or "fb test"))
    from simctl import Simulator  # tools/sim/simctl.py

    spec = sim_spec(args.st)
    if args.baud:
        spec["baud"] = args.baud
    if args.framing:
        spec["devices"] = [d + (",framing=" if d.count(":") > 1 else ":framing=") + args.framing
                           if d.startswith("mts9:") else d for d in spec["devices"]]
    if spec["transport"].startswith("pymodbus-"):
        return run_pymodbus(args, spec["transport"][len("pymodbus-"):].split("+"))
    tmp = tempfile.mkdtemp(prefix="fbtest-")
    try:
        link = os.path.join(tmp, "ttySIM")
        pty = spec["transport"] == "pty"
        with Simulator(spec["devices"], baud=int(spec["baud"]), fmt=spec["format"],
                       time_scale=float(spec["time-scale"]), transport=spec["transport"],
                       pace=spec["pace"] == "1", link=link if pty else None) as sim:
            port = link if pty else f"tcp://{sim.tcp[0]}:{sim.tcp[1]}"
            env = dict(os.environ, MBFB_TEST_PORT=port, MBFB_SIM_CONTROL=sim.control_path,
                       MBFB_TEST_BAUD=str(spec["baud"]), MBFB_TEST_FRAMING=args.framing)
            edges = os.path.join(tmp, "line.log")
            if args.direction:
                env.update(MBFB_TEST_DIRECTION=args.direction, LD_PRELOAD=args.double,
                           LINEDOUBLE_PORT=link, LINEDOUBLE_LOG=edges,
                           LINEDOUBLE_GPIOCHIP=DOUBLE_GPIOCHIP)
            try:
                proc = subprocess.run([args.exe], env=env, timeout=args.timeout)
                rc = proc.returncode
            except subprocess.TimeoutExpired:
                print(f"FAIL: {args.exe} still running after {args.timeout} s (killed)")
                rc = 1
            if rc == 0 and args.direction:
                rc = check_edges(edges, args.direction, spec["format"], int(spec["baud"]))
            if rc != 0:
                print("--- simulator stderr (tail) ---")
                print(sim.stderr()[-3000:])
                print_log_tail(sim)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if rc == 0 else 1


LOG_TAIL = 40   # frames of the simulator's log shown after a failure


def print_log_tail(sim) -> None:
    """The simulator's frames since the program last cleared its log (the last LOG_TAIL), with
    their times: what was on the line when a check failed."""
    try:
        log = sim.log(clear=False)
    except Exception as err:  # noqa: BLE001 - a dead simulator: say so, the failure stands
        print(f"--- simulator log: not read ({err}) ---")
        return
    print(f"--- simulator log (last {min(LOG_TAIL, len(log))} of {len(log)} frames, s) ---")
    for e in log[-LOG_TAIL:]:
        print(f"{e.get('t', 0):10.3f} {e.get('dir', '?'):2} {e.get('hex', '')} {e.get('info', '')}")


DOUBLE_GPIOCHIP = "gpiochip-double"   # the chip the test double has (a program asks for it)


def check_edges(path: str, mode: str, fmt: str, baud: int) -> int:
    """The double's record of the run: every request framed by the line (line_edges.py)."""
    sys.path.insert(0, os.path.join(os.path.dirname(HERE), "shims"))
    import line_edges
    bits = 1 + int(fmt[0]) + (fmt[1] != "N") + int(fmt[2])
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    try:
        got = line_edges.check(text, mode, 1e6 * bits / baud, T_DIR_BEFORE_US, T_DIR_AFTER_US)
    except AssertionError as err:
        print(f"FAIL: direction {mode}: {err}")
        return 1
    print(f"direction {mode}: {got['requests']} requests, each framed by the line "
          f"(reply at least {got.get('min_margin_us', 0)} us after the line went down)")
    return 0


T_DIR_BEFORE_US, T_DIR_AFTER_US = 200, 100   # the delays t_direction.st sets


def run_pymodbus(args, kinds) -> int:
    """The program against pymodbus's RTU-over-TCP server with the slaves `kinds` (mvd94, or
    mvd94+poll: pymodbus_peer.py), stopped by pid whatever happens."""
    peer = os.path.join(os.path.dirname(HERE), "shims", "pymodbus_peer.py")
    proc = subprocess.Popen([sys.executable, peer, "rtu-tcp"] + kinds, stdout=subprocess.PIPE,
                            text=True)
    try:
        ready = proc.stdout.readline().split()
        if len(ready) != 2 or ready[0] != "READY":
            print(f"FAIL: pymodbus peer did not start ({ready})")
            return 1
        env = dict(os.environ, MBFB_TEST_PORT=f"tcp://127.0.0.1:{ready[1]}")
        env.pop("MBFB_SIM_CONTROL", None)
        try:
            rc = subprocess.run([args.exe], env=env, timeout=args.timeout).returncode
        except subprocess.TimeoutExpired:
            print(f"FAIL: {args.exe} still running after {args.timeout} s (killed)")
            rc = 1
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stdout.close()
    return 0 if rc == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
