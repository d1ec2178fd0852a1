"""Wire share through the real serial drivers beside a pty, in one run: N one-register reads
(FC03, 9600 8N2, an MV-D94 on a line paced by tools/sim/ptyline) by the same shims program
(tests/kernel/guest_serial.c, step bench) through
  - the 8250 (QEMU's 16550, /dev/ttyS1) and ftdi_sio (QEMU's FT232 behind xHCI, /dev/ttyUSB0)
    in the kernel test bed's guest (tests/kernel/bed.py, TCG), and
  - a pty on the host (the simulator's paced line served directly), at the same time.
Wire share = the frames' own time on the wire (request 8 + reply 7 bytes, 11 bits each) times N
over the elapsed time of the N reads. QEMU does not pace its UARTs: the paced line (ptyline)
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
import threading

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "kernel"))
from bed import Bed, Port, Skip, SIM  # noqa: E402
from test_serial import USB_MODULES  # noqa: E402

LINE = "--baud 9600 --format 8N2 --device mvd94:1:SV=100.0,DP=1"
WIRE_US = (8 + 7) * 11 * 1e6 / 9600


def share(line):
    m = re.search(r"n=(\d+) good=(\d+) elapsed_us=(\d+)", line)
    n, good, us = map(int, m.groups())
    return good, n, us / n / 1000, WIRE_US * good / us


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
    t = threading.Thread(target=host_pty, args=(build, program, a.n, host))
    t.start()  # the pty on the host while the guest runs
    try:
        run = Bed(build).boot(program, args=[f"bench:/dev/ttyS1:0:{a.n}",
                                             f"bench:/dev/ttyUSB0:1:{a.n}"],
                              modules=USB_MODULES,
                              ports=[Port("8250", LINE, "paced"), Port("ftdi", LINE, "paced")])
    except Skip as e:
        print(f"skipped: {e}")
        return
    t.join()
    print(f"| path | reads good | ms per read | wire share |")
    print(f"|---|---|---|---|")
    for name, text in (("pty (host)", "".join(host)), ("8250 (guest)", run.output),
                       ("ftdi_sio (guest)", run.output)):
        for line in text.splitlines():
            if line.startswith("RESULT bench") and (
                    ("ttyS1" in line) == (name.startswith("8250")) and
                    ("ttyUSB0" in line) == (name.startswith("ftdi"))):
                good, n, ms, w = share(line)
                print(f"| {name} | {good}/{n} | {ms:.1f} | {w:.2f} |")
    print(f"(frames' own wire time per read: {WIRE_US / 1000:.1f} ms; guest boot and run "
          f"{run.seconds:.0f} s)")


if __name__ == "__main__":
    main()
