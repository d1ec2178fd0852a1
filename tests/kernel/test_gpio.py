"""GPIO direction control on a kernel GPIO chip: the kernel's gpio-sim in the QEMU guest
(tests/kernel/bed.py), driven by the shims through the real libgpiod 2 and 1 around requests to
the simulator on the 8250 port; the line's level read back from gpio-sim's sysfs.

    test_gpio.py BUILD_DIR GUEST_PROGRAM LIBGPIOD1 LIBGPIOD2
Debian's kernel has no gpio-sim: tests/kernel/gpio_sim.sh builds it for the guest's kernel from
Debian's headers and source packages of that kernel. LIBGPIOD1 is Debian's libgpiod 1
(libgpiod.so.2), LIBGPIOD2 libgpiod 2 built in the build tree (tests/shims/libgpiod2.cmake); each
case runs on one of them (guest_gpio.c preloads it). In the guest, for each library and polarity:
  - the line reads the pull's level (0) before the bus opens, and the idle level once it is
    open (0; 1 with DirActiveLow), requested by consumer "mbfb" (debugfs);
  - every read answered, and one pulse to the sending level per request (sampled in sysfs);
  - after mbfb_shutdown the line is released: no consumer, back at the pull's level.
Exit 0 when every check holds, 1 on a failed check, 77 (skipped) without QEMU, the kernel, the
module or a library (1 under MBFB_REQUIRE_TOOLCHAIN=1).
"""
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bed import Bed, Port, Skip, skip_or_fail, tool_cache  # noqa: E402

SIMDIR = "/sys/kernel/config/gpio-sim/mbfb"
LABEL = "mbfb-sim"     # the bus names the chip by its label (as on a Pi 5: pinctrl-rp1)
LINE = 17
N_READS = 6            # guest_gpio.c
LIB_DIR = "/usr/lib/x86_64-linux-gnu"
SETUP = [
    "insmod /lib/modules/gpio-sim.ko",
    "mount -t configfs none /sys/kernel/config",
    "mount -t debugfs none /sys/kernel/debug",
    f"mkdir {SIMDIR} {SIMDIR}/bank0",
    f"echo 32 > {SIMDIR}/bank0/num_lines",
    f"echo {LABEL} > {SIMDIR}/bank0/label",
    f"echo 1 > {SIMDIR}/live",
]

failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what)
    if not ok:
        failures.append(what)


def results(output):
    out = []
    for line in output.splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[:2] == ["RESULT", "gpio"]:
            d = {"lib": os.path.basename(parts[2])}
            for kv in parts[3:]:
                k, _, v = kv.partition("=")
                d[k] = int(v) if v.lstrip("-").isdigit() else v
            out.append(d)
    return out


def main():
    build, program, lib1, lib2 = sys.argv[1:5]
    bed = Bed(build)
    try:
        _, moddir = bed.kernel()
        for lib, what in ((lib1, "Debian's libgpiod 1 (package libgpiod2)"),
                          (lib2, "libgpiod 2 (built by tests/shims/libgpiod2.cmake)")):
            if not os.path.isfile(lib):
                raise Skip(f"{what} not found: '{lib}'")
        r = subprocess.run([os.path.join(HERE, "gpio_sim.sh"),
                            tool_cache(build, "kernel-gpio-sim"), os.path.basename(moddir)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            raise Skip("no gpio-sim module for the guest: " +
                       (r.stderr.strip().splitlines() or ["?"])[-1])
        ko = r.stdout.strip()
    except Skip as e:
        skip_or_fail(str(e))
    libs = {"libgpiod.so.2": lib1, "libgpiod.so.3": lib2}
    files = [(ko, "/lib/modules/gpio-sim.ko")]
    files += [(os.path.realpath(src), f"{LIB_DIR}/{name}") for name, src in libs.items()]
    run = bed.boot(program, modules=["configfs"], setup=SETUP, files=files,
                   args=["/dev/ttyS1", SIMDIR, LABEL, str(LINE)] +
                        [f"{LIB_DIR}/{name}" for name in libs],
                   ports=[Port("8250", "--baud 9600 --format 8N2 --device mvd94:1:SV=100.0,DP=1")],
                   trace_events=())
    print(run.output)
    check(run.rc == 0, f"the guest program ran (exit {run.rc}, {run.seconds:.1f} s)")
    got = results(run.output)
    check(len(got) == 4, f"{len(got)} of 4 cases reported (2 libraries x 2 polarities)")
    for d in got:
        low = d.get("active_low")
        name = f"{d['lib']} active_low={low}"
        check(d.get("mapped") == d["lib"], f"{name}: the only libgpiod loaded ({d.get('mapped')})")
        check(d.get("opened") == 0, f"{name}: the bus opened with Direction GPIO (ErrorID {d.get('opened')})")
        check(d.get("reads") == N_READS, f"{name}: {d.get('reads')} of {N_READS} reads answered")
        check(d.get("before") == 0, f"{name}: the line at the pull's level 0 before (read {d.get('before')})")
        check(d.get("idle") == low, f"{name}: the line idle at {low} once open (read {d.get('idle')})")
        check(d.get("consumer") == "mbfb", f"{name}: requested by 'mbfb' (debugfs: {d.get('consumer')})")
        check(d.get("pulses") == N_READS,
              f"{name}: one pulse to {1 - low} per request ({d.get('pulses')} for {N_READS})")
        check(d.get("released") == 0 and d.get("consumer_after") == "none",
              f"{name}: released at shutdown (level {d.get('released')}, consumer {d.get('consumer_after')})")
    print(f"{len(failures)} failed" if failures else "all checks passed")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
