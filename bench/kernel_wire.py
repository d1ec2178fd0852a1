"""Wire share through the real serial drivers beside a pty, in one run: N one-register reads
(FC03, 9600 8N2, an MV-D94 on a line paced by tools/sim/ptyline) by the same shims program
(tests/kernel/guest_serial.c, step bench) through
  - the 8250 (QEMU's 16550, /dev/ttyS1) and ftdi_sio (QEMU's FT232 behind xHCI, /dev/ttyUSB0)
    in the kernel test bed's guest (tests/kernel/bed.py, TCG),
  - amba-pl011, the Raspberry Pi's UART driver (QEMU's PL011, /dev/ttyAMA0) in the bed's
    aarch64 guest (QEMU's virt machine), the program cross-built by tests/cross (cross_arm64:
    BUILD/cross/arm64-programs), a second boot, and
  - a pty on the host (the simulator's paced line served directly), just before the boot
    (at the same time, QEMU's TCG and the host program share the 2 cores and the host
    program's reads time out).
Wire share = the reads per second times the shortest compliant transaction, as in README
"Wire pace": the gap before a request (t3.5, at least 44 bit times: 4.58 ms), the request (8
bytes), the simulator's mean turnaround (5.5 ms) and the reply (7 bytes), 11 bits a byte:
27.3 ms. QEMU does not pace its UARTs: the paced line (ptyline)
is what makes the time; what the figures show is each driver path's overhead per transaction
(latency timer, tcdrain, interrupts under TCG), not a real UART's timing.

    .venv/bin/python bench/kernel_wire.py [--build build] [--n 40]
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "kernel"))
from bed import Bed, Port, Skip, SIM  # noqa: E402
from test_serial import USB_MODULES  # noqa: E402

LINE = "--baud 9600 --format 8N2 --device mvd94:1:SV=100.0,DP=1"
RX_TRIG = "/sys/class/tty/ttyS1/rx_trig_bytes"  # the 16550's receive FIFO trigger level
CHAR_US = 11 * 1e6 / 9600
SHORTEST_US = max(3.5 * CHAR_US, 44e6 / 9600) + 8 * CHAR_US + 5500 + 7 * CHAR_US


def share(line):
    m = re.search(r"n=(\d+) good=(\d+) elapsed_us=(\d+)", line)
    n, good, us = map(int, m.groups())
    return good, n, us / n / 1000, SHORTEST_US * good / us


def host_pty(build, program, n, out):
    with tempfile.TemporaryDirectory() as d:
        link = os.path.join(d, "line")
        env = dict(os.environ, MBFB_PTYLINE=os.path.join(build, "tools/sim/ptyline/mbfb-ptyline"))
        sim = subprocess.Popen([sys.executable, SIM, "--pty", "--pace", "--symlink", link,
                                *LINE.split()], stdout=subprocess.PIPE, text=True, env=env)
        sim.stdout.readline()
        try:
            r = subprocess.run([program, f"bench:{link}:0:{n}"], capture_output=True, text=True)
            out.append(r.stdout)
        finally:
            sim.terminate()
            sim.wait()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--n", type=int, default=40)
    a = ap.parse_args()
    build = os.path.abspath(a.build)
    program = os.path.join(build, "tests/kernel/kernel_guest_serial")
    host = []
    host_pty(build, program, a.n, host)
    pl011, arm_prog = [], os.path.join(build, "cross", "arm64-programs", "kernel_guest_serial")
    try:
        if not os.path.exists(arm_prog):
            raise Skip(f"{arm_prog} not built (ctest -R cross_arm64)")
        arm = Bed(build, "arm64").boot(arm_prog, args=[f"bench:/dev/ttyAMA0:0:{a.n}"],
                                       ports=[Port("pl011", LINE, "paced")])
        pl011 = [ln for ln in arm.output.splitlines() if ln.startswith("RESULT bench")]
        print(f"(aarch64 guest boot and run {arm.seconds:.0f} s, program exit {arm.rc})")
        if not pl011:
            print("PL011: no result; the program said:\n" + arm.output[-600:])
    except Skip as e:
        print(f"PL011 skipped: {e}")
    try:
        run = Bed(build).boot(program, args=[f"bench:/dev/ttyS1:0:{a.n}",
                                             f"bench:/dev/ttyUSB0:1:{a.n}",
                                             f"write:{RX_TRIG}:1",
                                             f"bench:/dev/ttyS1:0:{a.n}"],
                              modules=USB_MODULES,
                              ports=[Port("8250", LINE, "paced"), Port("ftdi", LINE, "paced")])
    except Skip as e:
        print(f"skipped: {e}")
        return
    print("| path | reads good | ms per read | wire share |")
    print("|---|---|---|---|")
    guest = [ln for ln in run.output.splitlines() if ln.startswith("RESULT bench")]
    rows = [("pty (host)", "".join(host).strip())]
    if len(guest) == 3:
        rows += [("8250 (guest)", guest[0]), ("ftdi_sio (guest)", guest[1]),
                 ("8250, rx_trig_bytes 1 (guest)", guest[2])]
    if pl011:
        rows.append(("amba-pl011 (aarch64 guest)", pl011[0]))
    for name, line in rows:
        good, n, ms, w = share(line)
        print(f"| {name} | {good}/{n} | {ms:.1f} | {w:.2f} |")
    print(next((ln for ln in run.output.splitlines() if ln.startswith("RESULT write")), ""))
    print(f"(shortest compliant read: {SHORTEST_US / 1000:.1f} ms; guest boot and run "
          f"{run.seconds:.0f} s)")


if __name__ == "__main__":
    main()
