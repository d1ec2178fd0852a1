#!/usr/bin/env python3
"""CPU time of the shims with one dead device, two builds of them side by side in one run.

    .venv/bin/python bench/listen_cpu.py LIB_BEFORE LIB_AFTER [SECONDS] [RUNS]

Each LIB is the shims as a shared library (bench/soak's mbfb_soak_lib, or c_shims of a commit
built the same way). A pty whose far end never answers stands for a dead device at 19200 8N2;
one read of it is posted every 100 ms, as a block would, for SECONDS (15); the process's CPU
time (user + system, the worker thread included) is printed per run, and the worker
thread's own (its schedstat). Then nothing is posted for IDLE_SECONDS (5) while the device
is still out of step, and the worker's CPU time over that idle spell is printed: what
waiting costs when nothing arrives. The runs alternate between the two builds so both see
the same machine load. It shows what listening to the port while a device is out of step
(c_shims/README.md, "Late replies") costs in CPU.
"""
import ctypes
import os
import resource
import subprocess
import sys
import time

IDLE_SECONDS = 5.0


def threads_cpu():
    """CPU time (s) of each thread of this process but the main one, by thread id."""
    out, main = {}, os.getpid()
    for tid in os.listdir("/proc/self/task"):
        if int(tid) == main:
            continue
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                out[tid] = int(f.read().split()[0]) / 1e9
        except OSError:
            pass                             # the thread ended meanwhile
    return out


def delta(before, after):
    return sum(t - before.get(tid, 0.0) for tid, t in after.items())


def one(lib_path, seconds):
    lib = ctypes.CDLL(lib_path)
    master, slave = os.openpty()
    os.set_blocking(master, False)
    path = os.ttyname(slave).encode()
    bus = lib.mbfb_bus_open_args(path, len(path), 19200, ord("N"), 8, 2, 0, 0, -1)
    dev = lib.mbfb_dev_open(bus, 1)
    buf = (ctypes.c_uint16 * 4)()
    r0, t0, n = resource.getrusage(resource.RUSAGE_SELF), time.monotonic(), 0
    w0 = threads_cpu()
    while time.monotonic() - t0 < seconds:
        h = lib.mbfb_post(dev, 3, 0, 1, None)
        while lib.mbfb_poll(h) < 3:          # MBFB_REQ_DONE / MBFB_REQ_FAILED
            time.sleep(0.01)
        lib.mbfb_take(h, buf, 1)
        n += 1
        time.sleep(0.1)
        try:
            os.read(master, 4096)            # the requests, so the pty never fills
        except OSError:
            pass
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    wall, w1 = time.monotonic() - t0, threads_cpu()
    time.sleep(IDLE_SECONDS)                 # nothing posted; the device still out of step
    w2 = threads_cpu()
    lib.mbfb_shutdown()
    os.close(master)
    os.close(slave)
    return cpu, wall, n, delta(w0, w1), delta(w1, w2)


def main(argv):
    if len(argv) >= 2 and argv[0] == "--one":
        cpu, wall, n, worker, idle = one(argv[1], float(argv[2]))
        print(f"{cpu:.4f} {wall:.2f} {n} {worker:.6f} {idle:.6f}")
        return 0
    if len(argv) < 2:
        print("usage: listen_cpu.py LIB_BEFORE LIB_AFTER [SECONDS] [RUNS]", file=sys.stderr)
        return 2
    seconds = float(argv[2]) if len(argv) > 2 else 15.0
    runs = int(argv[3]) if len(argv) > 3 else 2
    for lib in argv[:2]:
        if not os.path.isfile(lib):
            print(f"listen_cpu: no such library: {lib}", file=sys.stderr)
            return 2
    print("| run | build | CPU time | wall | requests | CPU per second of wall |"
          f" worker thread | worker, {IDLE_SECONDS:.0f} s idle |")
    print("|---|---|---|---|---|---|---|---|")
    for r in range(runs):
        for name, lib in (("before", argv[0]), ("after", argv[1])):
            out = subprocess.run([sys.executable, __file__, "--one", lib, str(seconds)],
                                 capture_output=True, text=True, check=True).stdout.split()
            cpu, wall, n = float(out[0]), float(out[1]), int(out[2])
            worker, idle = float(out[3]), float(out[4])
            print(f"| {r + 1} | {name} | {cpu * 1000:.0f} ms | {wall:.1f} s | {n} |"
                  f" {cpu * 1000 / wall:.1f} ms/s | {worker * 1000 / wall:.2f} ms/s |"
                  f" {idle * 1000:.2f} ms |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
