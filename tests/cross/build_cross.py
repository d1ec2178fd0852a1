"""The project built for the Raspberry Pi's architectures by Debian's cross compilers
(tests/cross/project, README.md here): one target per run.

    build_cross.py ARCH BUILD_DIR [--matiec IEC2C IEC_LIB IEC_CINC LANG PYTHON | --no-programs WHY
                                   | --v4 PACKAGE_DIR | --no-v4 WHY]
(in BUILD_DIR/cross/ARCH[-programs][-v4]).
ARCH arm64 or armhf: the shims (C and C++), the kernel guest program, the hosts, both
examples and the fb test program of each device block (every fb test program with
MBFB_CROSS_ALL=1), linked with Debian's multiarch libmodbus-dev:ARCH, -Werror on our
own code; with --v4 the v4 package's sources as one shared library. ARCH armv6 (Raspberry Pi
OS's 32-bit baseline: Pi Zero, Pi 1): the shims compiled with -march=armv6 -marm -mfpu=vfp;
it fails on any call to libatomic (an __atomic_* symbol the objects need).
Exit 0 when all was built and checked, 1 on a failure, 77 (skipped, with the reason) when the
cross compilers or the multiarch libmodbus are missing; MBFB_REQUIRE_TOOLCHAIN=1 makes a
missing one a failure.
"""
import argparse
import glob
import os
import re
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
# ARCH -> (compilers' triple, Debian architecture of libmodbus-dev, extra flags, ELF machine)
TARGETS = {
    "arm64": ("aarch64-linux-gnu", "arm64", "", "AArch64"),
    "armhf": ("arm-linux-gnueabihf", "armhf", "", "ARM"),
    "armv6": ("arm-linux-gnueabihf", None, "-march=armv6 -marm -mfpu=vfp", "ARM"),
}
# the fb test programs built: one per device block (what the ARM guests run); every one with
# MBFB_CROSS_ALL=1 (they differ from these in their test code only: each holds every block)
FB_PROGRAMS = ["mvd94", "vd", "fdc", "mts9"]
PACKAGES = {"aarch64-linux-gnu": "gcc-aarch64-linux-gnu g++-aarch64-linux-gnu",
            "arm-linux-gnueabihf": "gcc-arm-linux-gnueabihf g++-arm-linux-gnueabihf"}


def skip_or_fail(reason):
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        print(f"FAIL: {reason} (MBFB_REQUIRE_TOOLCHAIN=1)")
        sys.exit(1)
    print(f"SKIP: {reason}")
    sys.exit(77)


def fail(what):
    print(f"FAIL: {what}")
    sys.exit(1)


def run(cmd, log):
    """Run a command, its output appended to log; fail with the log's tail on an error."""
    with open(log, "a") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        tail = open(log, errors="replace").read().splitlines()[-40:]
        print("\n".join(tail))
        fail(f"{' '.join(cmd[:3])} ... exited {r.returncode} (whole log: {log})")


def elf_machine(path, triple):
    out = subprocess.run([f"{triple}-readelf", "-h", path], capture_output=True,
                         text=True).stdout
    m = re.search(r"Machine:\s+(.*)", out)
    return m.group(1).strip() if m else "?"


def undefined(path, triple):
    out = subprocess.run([f"{triple}-nm", "-u", path], capture_output=True, text=True).stdout
    return {ln.split()[-1] for ln in out.splitlines() if ln.strip()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("arch", choices=sorted(TARGETS))
    ap.add_argument("build")
    ap.add_argument("--matiec", nargs=5, metavar=("IEC2C", "IEC_LIB", "IEC_CINC", "LANG", "PY"))
    ap.add_argument("--no-programs", metavar="WHY")
    ap.add_argument("--v4", metavar="PACKAGE_DIR")
    ap.add_argument("--no-v4", metavar="WHY")
    a = ap.parse_args()
    triple, debarch, flags, machine = TARGETS[a.arch]
    for tool in (f"{triple}-gcc", f"{triple}-g++"):
        if shutil.which(tool) is None:
            skip_or_fail(f"{tool} not found (Debian packages {PACKAGES[triple]}, "
                         f".ci/apt-packages.txt)")
    if debarch and not glob.glob(f"/usr/lib/{triple}/libmodbus.so"):
        skip_or_fail(f"no libmodbus for {debarch} in /usr/lib/{triple} (Debian package "
                     f"libmodbus-dev:{debarch}, .ci/apt-packages.txt; scripts/deps.sh enables "
                     f"the architecture)")
    if a.no_programs:
        skip_or_fail(f"the programs need matiec: {a.no_programs}")
    if a.no_v4:
        skip_or_fail(f"the v4 package needs STruC++: {a.no_v4}")
    parts = []
    if debarch and a.matiec:
        parts.append("programs")
    if debarch and a.v4:
        gen = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(a.v4))), "gen",
                           "mbfb_v4.cpp")
        if not os.path.isfile(os.path.join(a.v4, "library.properties")) or \
                not os.path.isfile(gen):
            skip_or_fail(f"the v4 package is not built ({a.v4}, {gen}: target mbfb_v4, "
                         f"test strucpp_build)")
        parts.append("v4")
    out = os.path.join(os.path.abspath(a.build), "cross", "-".join([a.arch] + parts))
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    log = os.path.join(out, "build.log")
    cmd = ["cmake", "-S", os.path.join(HERE, "project"), "-B", out, "-G", "Ninja",
           "-DCMAKE_SYSTEM_NAME=Linux", f"-DCMAKE_SYSTEM_PROCESSOR={triple.split('-')[0]}",
           f"-DCMAKE_C_COMPILER={triple}-gcc", f"-DCMAKE_CXX_COMPILER={triple}-g++",
           f"-DCMAKE_LIBRARY_ARCHITECTURE={triple}", f"-DMBFB_ROOT={ROOT}",
           f"-DMBFB_ARCH_FLAGS={flags}", f"-DMBFB_PARTS={';'.join(parts)}"]
    if a.matiec:
        iec2c, lib, cinc, lang, py = a.matiec
        cmd.append("-DMBFB_FB_PROGRAMS=" + ("all" if os.environ.get("MBFB_CROSS_ALL") == "1"
                                            else ";".join(FB_PROGRAMS)))
        cmd += [f"-DMBFB_IEC2C={iec2c}", f"-DMBFB_IEC_LIB={lib}", f"-DMBFB_IEC_CINC={cinc}",
                f"-DMBFB_PROGRAM_LANG={lang}", f"-DMBFB_PYTHON={py}"]
    if "v4" in parts:
        pkg = os.path.abspath(a.v4)
        v4 = os.path.dirname(os.path.dirname(pkg))  # BUILD/v4 (v4/CMakeLists.txt)
        cmd += [f"-DMBFB_V4_PACKAGE={pkg}", f"-DMBFB_V4_GEN={v4}/gen",
                f"-DMBFB_STRUCPP_INC={v4}/strucpp/src/runtime/include"]
    t0 = time.monotonic()
    run(cmd, log)
    run(["cmake", "--build", out, "-j", os.environ.get("MBFB_CROSS_JOBS", "2")], log)
    print(f"{a.arch}: built {' + '.join(['shims'] + parts)} with {triple}-gcc {flags} in "
          f"{time.monotonic() - t0:.0f} s")
    with open(log) as f:
        warnings = [ln for ln in f if "warning:" in ln]
    print(f"{a.arch}: {len(warnings)} warning lines (generated code: matiec's with -w, STruC++'s "
          f"with -Wall; ours with -Werror)")
    for w in warnings[:10]:
        print("   " + w.rstrip())

    failures = []
    # every object of the shims: the target's machine, and no libatomic call (inline atomics)
    libs = [os.path.join(out, "libmbfb.a"), os.path.join(out, "libmbfb_cxx.a")]
    for lib in libs:
        atomics = sorted(s for s in undefined(lib, triple) if s.startswith("__atomic_"))
        print(f"{a.arch}: {os.path.basename(lib)}: libatomic calls: {atomics or 'none'}")
        if atomics:
            failures.append(f"{os.path.basename(lib)} calls libatomic: {atomics}")
    if a.arch == "armv6":
        attrs = subprocess.run([f"{triple}-readelf", "-A", libs[0]], capture_output=True,
                               text=True).stdout
        archs = sorted(set(re.findall(r"Tag_CPU_arch: (\S+)", attrs)))
        print(f"armv6: the objects' Tag_CPU_arch: {archs}")
        if archs != ["v6"]:
            failures.append(f"the armv6 objects say Tag_CPU_arch {archs}, not v6")
    built = []
    if "programs" in parts:
        tests = sorted(os.path.basename(t)[2:-3] for t in glob.glob(
            os.path.join(ROOT, "tests", "fb", "t_*.st"))) \
            if os.environ.get("MBFB_CROSS_ALL") == "1" else FB_PROGRAMS
        names = ["kernel_guest_serial", "heat_treat_st", "heat_treat_ld"] + \
            ["fb_" + t for t in tests]
        built += [os.path.join(out, n) for n in names]
    if "v4" in parts:
        built.append(os.path.join(out, "libmbfb_v4_package.so"))
    for path in built:
        if not os.path.exists(path):
            failures.append(f"{os.path.basename(path)} was not built")
            continue
        m = elf_machine(path, triple)
        if m != machine:
            failures.append(f"{os.path.basename(path)} is for {m}, not {machine}")
    if built:
        print(f"{a.arch}: {len(built)} binaries for {machine}: " +
              " ".join(os.path.basename(p) for p in built))
    for f in failures:
        print(f"FAIL: {f}")
    if failures:
        sys.exit(1)
    print("all checks passed")


if __name__ == "__main__":
    main()
