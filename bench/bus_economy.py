"""Bus time of the device blocks on ONE paced RS-485 line, BEFORE and AFTER, in one run.

    .venv/bin/python bench/bus_economy.py [--build build-economy] [--before COMMIT] [-n 30]

Not a test: it prints figures (bench/README.md, "Bus economy"). For each variant (BEFORE:
st_src/*.st as of COMMIT, taken with `git show` into a temp dir; AFTER: the working tree)
and each load (a realistic Period, and Period 0 = as fast as the line allows) it compiles
bench/bus_economy.st with OpenPLC's iec2c and g++ like tests/fb does, runs it against the
simulator with one MV-D94, one FDC-100 and one MT-S9 on a line paced by ptyline at
9600 8N2 (1..10 ms device turnaround), and counts each device's frames in the simulator's
log over exactly N refreshes (window marks printed by the program).

Bus time of one transaction = gap the master keeps before it (max(3.5 characters, 44 bits)
= 4.58 ms at 9600 8N2, as the shims do) + request and reply bytes x 1.146 ms + the reply
latency ptyline measured (turnaround). The line could sustain 1 / (bus time per refresh)
refreshes per second of that device alone, 1 / sum over the three for all three.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402
from rig import cache_value  # noqa: E402  (bench/ is on the path: this script's folder)

DEFAULT_BEFORE = "e3d8370"        # last commit before the tiered polling (st_src)
DEVICES = (("mv", 1, "MV-D94", "mvd94:1"), ("fdc", 2, "FDC-100", "fdc100:2"),
           ("ct", 3, "MT-S9", "mts9:3"))
BAUD, CHAR_BITS = 9600, 11        # 8N2: start + 8 + 2 stop
CHAR_S = CHAR_BITS / BAUD
GAP_S = max(3.5 * CHAR_S, 44 / BAUD)


def st_sources(before: str | None, into: str) -> list[str]:
    """st_src/*.st of the working tree (before None) or of commit `before`, sorted."""
    if before is None:
        src = os.path.join(ROOT, "st_src")
        return sorted(os.path.join(src, f) for f in os.listdir(src) if f.endswith(".st"))
    names = subprocess.run(["git", "-C", ROOT, "ls-tree", "--name-only", before, "st_src/"],
                           check=True, capture_output=True, text=True).stdout.split()
    out = []
    for name in sorted(n for n in names if n.endswith(".st")):
        path = os.path.join(into, os.path.basename(name))
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(subprocess.run(["git", "-C", ROOT, "show", f"{before}:{name}"], check=True,
                                    capture_output=True, text=True).stdout)
        out.append(path)
    return out


def build(build_dir: str, work: str, sources: list[str], program: str) -> str:
    """iec2c + g++ as tests/fb/CMakeLists.txt does; returns the executable."""
    build_dir = os.path.abspath(build_dir)
    home = (cache_value(build_dir, "OPENPLC_HOME") or os.environ.get("OPENPLC_HOME")
            or "/opt/OpenPLC_v3")    # OpenPLC's documented default
    iec2c = cache_value(build_dir, "MBFB_IEC2C") or os.path.join(home, "webserver", "iec2c")
    lm = cache_value(build_dir, "MBFB_LM_OPENPLC_LIB") or cache_value(build_dir, "MBFB_LM_DEBIAN_LIB")
    text = "".join(open(f, encoding="utf-8").read() + "\n"
                   for f in sources + [os.path.join(ROOT, "tests", "fb", "fbtest.st")])
    with open(os.path.join(work, "program.st"), "w", encoding="utf-8") as fh:
        fh.write(text + program)
    subprocess.run([iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "-I",
                    os.path.join(home, "webserver", "lib"), "program.st"], cwd=work, check=True,
                   capture_output=True)
    # the located-variable glue and the ST test host library, as tests/fb's mbfb_st_program
    subprocess.run([sys.executable, os.path.join(ROOT, "tools", "runner", "mkglue.py"), work],
                   cwd=work, check=True)
    exe = os.path.join(work, "bench")
    subprocess.run(["g++", "-std=gnu++11", "-O2", "-w", "-I", os.path.join(home, "webserver", "core", "lib"),
                    "-I", os.path.join(ROOT, "tests", "fb"), "-I", os.path.join(ROOT, "c_shims", "include"),
                    "-I", os.path.join(ROOT, "tools", "runner"),
                    "-I", work, "-include", "mbfb_st.h", "-include", "fbtest.h", "-o", exe,
                    "Config0.c", "Res0.c", "glue.c",
                    os.path.join(build_dir, "tests", "fb", "libmbfb_test_host.a"),
                    os.path.join(build_dir, "c_shims", "libmbfb.a"), lm, "-lpthread",
                    f"-Wl,-rpath,{os.path.dirname(lm)}"], cwd=work, check=True)
    return exe


def run_paced(exe: str, ptyline: str, devices: list, prefix: str,
              smaller: str) -> tuple[str, list, dict]:
    """Runs bench program exe against the simulator (devices, as simctl takes them) on a line
    paced by ptyline at 9600 8N2; returns its output, the simulator's log and the line's stats.
    Exits with the reason when the program fails a check, the line is not paced, or the log
    overflowed (`smaller`: the option that makes a run smaller). Used by recipe_pace.py too."""
    tmp = tempfile.mkdtemp(prefix=prefix)
    try:
        link = os.path.join(tmp, "ttyBENCH")
        os.environ["MBFB_PTYLINE"] = ptyline
        with Simulator(devices, fmt="8N2", pace=True, link=link, seed=1) as sim:
            env = dict(os.environ, MBFB_TEST_PORT=link, MBFB_SIM_CONTROL=sim.control_path,
                       MBFB_MAX_SCANS="100000")
            out = subprocess.run([exe], env=env, capture_output=True, text=True, timeout=900).stdout
            if "checks passed, 0 failed" not in out:
                raise SystemExit(f"bench program failed:\n{out[-2000:]}")
            frames = sim.log()
            line = sim.ctl("line_stats")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if not line.get("available"):
        raise SystemExit(f"line not paced by ptyline: {line}")
    if len(frames) >= 4000:
        raise SystemExit(f"the simulator's log overflowed (4000 frames): use a smaller {smaller}")
    return out, frames, line["stats"]


def run(exe: str, ptyline: str, scan_ms: int) -> dict:
    """Runs the program on a paced line; returns the log, line stats and window marks."""
    out, frames, line = run_paced(exe, ptyline, [d[3] for d in DEVICES], "bench-eco-", "-n")
    marks = {}
    for scan, name, what, n in re.findall(r"note scan (\d+): (\w+) (start|end) (\d+)", out):
        marks[(name, what)] = (int(scan), int(n))
    return {"frames": frames, "line": line, "marks": marks, "scan_s": scan_ms / 1000.0}


def figures(res: dict, n: int) -> dict:
    """Per device: transactions, bytes, bus time per refresh, utilisation, sustainable rate."""
    turn = (res["line"]["reply_latency"]["avg_us"] or 0) / 1e6
    per = {}
    for name, addr, _, _ in DEVICES:
        (s0, f0), (s1, f1) = res["marks"][(name, "start")], res["marks"][(name, "end")]
        mine = [f for f in res["frames"][f0:f1] if f["hex"] and int(f["hex"][:2], 16) == addr]
        req = [len(f["hex"].split()) for f in mine if f["dir"] == "rx"]
        rep = [len(f["hex"].split()) for f in mine if f["dir"] == "tx"]
        busy = len(req) * (GAP_S + turn) + (sum(req) + sum(rep)) * CHAR_S
        window = (s1 - s0) * res["scan_s"]
        per[name] = {"txn": len(req) / n, "bytes": (sum(req) + sum(rep)) / n,
                     "bus_ms": busy / n * 1000, "util": busy / window if window else 0.0,
                     "rate": n / window if window else 0.0}
    logged = sum(len(f["hex"].split()) for f in res["frames"])
    wire = res["line"]["m2s"]["bytes"] + res["line"]["s2m"]["bytes"]
    if logged != wire:             # the per-device figures would miss traffic
        raise SystemExit(f"simulator log has {logged} bytes, the line carried {wire}")
    return {"dev": per, "turn_ms": turn * 1000, "line": res["line"], "bytes": wire}


def report(results: dict, n: int, loads: list) -> None:
    for load, label in loads:
        print(f"\n### {label}: {n} refreshes per device, one line 9600 8N2 (ptyline), "
              f"reply latency {results[('before', load)]['turn_ms']:.1f} / "
              f"{results[('after', load)]['turn_ms']:.1f} ms (before / after)\n")
        print("| device | txn/refresh | bytes/refresh | bus ms/refresh | utilisation | "
              "refreshes/s measured | line could sustain (alone) |")
        print("|---|---|---|---|---|---|---|")
        for name, _, title, _ in DEVICES:
            b, a = results[("before", load)]["dev"][name], results[("after", load)]["dev"][name]
            print(f"| {title} | {b['txn']:.2f} -> {a['txn']:.2f} | {b['bytes']:.1f} -> {a['bytes']:.1f} | "
                  f"{b['bus_ms']:.1f} -> {a['bus_ms']:.1f} | {b['util']:.1%} -> {a['util']:.1%} | "
                  f"{b['rate']:.2f} -> {a['rate']:.2f} | "
                  f"{1000 / b['bus_ms']:.1f}/s -> {1000 / a['bus_ms']:.1f}/s |")
        tb = sum(results[("before", load)]["dev"][d[0]]["bus_ms"] for d in DEVICES)
        ta = sum(results[("after", load)]["dev"][d[0]]["bus_ms"] for d in DEVICES)
        lb, la = results[("before", load)]["line"], results[("after", load)]["line"]
        print(f"| all three | | | {tb:.1f} -> {ta:.1f} | line (ptyline, bytes only, whole run) "
              f"{lb['total']['utilisation']:.1%} -> {la['total']['utilisation']:.1%} | | "
              f"{1000 / tb:.2f}/s -> {1000 / ta:.2f}/s (x{tb / ta:.2f}) |")
        print(f"\nEvery byte ptyline carried is in the simulator's log "
              f"({results[('before', load)]['bytes']} / {results[('after', load)]['bytes']} bytes).")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--before", default=DEFAULT_BEFORE, help="commit of the BEFORE st_src")
    ap.add_argument("-n", type=int, default=30, help="refreshes per device in the window")
    ap.add_argument("--period-ms", type=int, default=500)
    ap.add_argument("--settings-ms", type=int, default=5000)
    ap.add_argument("--scan-ms", type=int, default=5)
    args = ap.parse_args()
    ptyline = os.path.join(args.build, "tools", "sim", "ptyline", "mbfb-ptyline")
    for need in (os.path.join(args.build, "CMakeCache.txt"), ptyline,
                 os.path.join(args.build, "c_shims", "libmbfb.a")):
        if not os.path.exists(need):
            raise SystemExit(f"missing {need}: configure and build --build first")
    with open(os.path.join(ROOT, "bench", "bus_economy.st"), encoding="utf-8") as fh:
        template = fh.read()
    loads = [(args.period_ms, f"Period {args.period_ms} ms, SettingsPeriod {args.settings_ms} ms"),
             (0, f"Period 0 (saturated line), SettingsPeriod {args.settings_ms} ms")]
    results = {}
    work = tempfile.mkdtemp(prefix="bench-eco-build-")
    try:
        for variant, commit in (("before", args.before), ("after", None)):
            vdir = os.path.join(work, variant)
            os.makedirs(vdir)
            sources = st_sources(commit, vdir)
            # MB_LINE.Parity: an enumeration in older st_src, a string since
            parity_none = ("MB_PARITY_NONE" if any("MB_PARITY_NONE" in open(f, encoding="utf-8").read()
                                                   for f in sources) else "'N'")
            for period, _ in loads:
                program = (template.replace("@PERIOD@", f"T#{period}ms")
                           .replace("@SETTINGS@", f"T#{args.settings_ms}ms")
                           .replace("@N@", str(args.n)).replace("@SCAN_MS@", str(args.scan_ms))
                           .replace("@MV_EXTRA@", "" if commit else
                                    f", SettingsPeriod := T#{args.settings_ms}ms")
                           .replace("@PARITY_NONE@", parity_none))
                bdir = os.path.join(vdir, f"p{period}")
                os.makedirs(bdir)
                exe = build(args.build, bdir, sources, program)
                print(f"running {variant} ({commit or 'working tree'}), Period {period} ms ...",
                      file=sys.stderr)
                results[(variant, period)] = figures(run(exe, ptyline, args.scan_ms), args.n)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"BEFORE = st_src at {args.before}, AFTER = working tree; "
          f"gap {GAP_S * 1000:.2f} ms, character {CHAR_S * 1000:.3f} ms")
    report(results, args.n, loads)
    return 0


if __name__ == "__main__":
    sys.exit(main())
