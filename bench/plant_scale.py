"""Scale, measured: a plant of 4 lines x 16 instruments in one program, in the project's runner.

    .venv/bin/python bench/plant_scale.py                    # wire run + scan cost: ~10 min here
    .venv/bin/python bench/plant_scale.py --skip cost        # the wire run only: ~3 min
    .venv/bin/python bench/plant_scale.py --skip cost --variant before=e75bb47 --variant now=worktree --rounds 3
                                                             # two versions side by side, wire runs interleaved
    .venv/bin/python bench/plant_scale.py --help             # --lines 4 --per-line 16 --baud 19200 ...

Not a test: it prints figures (bench/README.md, "Scale: a plant of 4 lines x 16 instruments").
One generated ST program holds --lines x --per-line device blocks, a mix of TempCtrl_MVD94,
FDC_Controller and Counter_MTS9 on every line (device k of line L is kind (k + L) mod 3, so
each line has 6 / 5 / 5 of them in a different order; slave ids 1..64 across the plant, all
distinct), every block with the same MB_LINE (--baud, 8N2: the MV-D94's only format) and the
same Period. Each block counts its refreshes (a scan with `Valid AND Age = T#0s`) in its own
located %QW variable. The program is compiled as OpenPLC builds it (iec2c -f -l -p -r -R -a,
g++ -O0, the shims at -O0: CMake Debug) and linked with the project's runner (tools/runner:
fb_host.cpp, plc_vars.cpp, plc_control.cpp, plc_host.cpp; task 20 ms in real time, as
OpenPLC's runtime). Every line is the simulator (its 16 devices) behind ptyline (paced at the
baud rate, 1..10 ms device turnaround, seeded), as in bench/rig.py's Line.

The wire run (Period T#0s: every block refreshes back to back), in a window of --seconds after
--warmup:
* share of each line's wire: bench/rig.py's Line.figures from ptyline's frame log,
  sum over the requests of (t3.5 + request + measured turnaround + reply) / window (log
  entries of one direction back to back on the wire joined into one frame: PlantLine); the
  silence before each request; requests after less than t3.5, requests with no reply next,
  and log entries ptyline marks as collided;
* refreshes per device from the runner's snapshot (the %QW counters at the window's ends),
  against the fair share: the line's refreshes / its devices (every block asks for the same
  Period, so the worker owes each the same number of refreshes); also each device's requests
  on the wire;
* CPU of each line's bus worker: /proc/PID/task/TID/stat (utime + stime, clock ticks) and
  /proc/PID/task/TID/schedstat (ns on a CPU), over the window. The shims start one worker per
  port, from the scan thread, in the first scan, in the program's order (line 0 first), so the
  workers' tids in increasing order are lines 0, 1, 2, 3 (checked: exactly --lines threads
  besides the scan thread).

The scan cost (--skip cost leaves it out): the same program under
`valgrind --tool=callgrind --dump-after=config_run__*` (one profile per scan), Period T#30s
(steady: no refresh due after the first ones) and T#0s (refreshes back to back), against
each block alone in bench/scan_cost.py's measure() (bench/rig.py's device_program, one
block, same line settings) with the same periods. Per scan: the program body's inclusive Ir
(MAIN_body__), each block type's bodies (calls, Ir) and which blocks published (calls of
scale_pub_<kind>, an empty C function the program calls on a refresh). Steady: the mean over
the scans in which no block published, against sum over the blocks of their cost alone.
Refreshes back to back: each scan against its prediction from the blocks alone with Period
T#0s (per kind: n x the cost of a scan without a refresh + the scan's refreshes x (the cost of
a scan with one - that)).

Versions side by side (--variant NAME=REF, repeatable; REF a commit, exported with `git archive`
and built as rig.py's Variant does, or `worktree`; NAME=REF@N runs that arm's program at
nice N, NAME=REF@/M its lines (ptyline and the simulator) at nice M, NAME=REF@N/M both: what
the machine's load costs, and whose CPU the share waits for): the wire runs of the versions interleaved,
--rounds of each (A B A B ...), and one table of the shares and gaps of every run at the end.
Every version runs on the same simulator (this tree's) and on the line model (ptyline) of the
last version given.

Everything is on ptys, every process is stopped by pid, the temp dir (under $TMPDIR) is removed.
Needs what bench/wire_pace.py needs (cmake, ninja, gcc/g++, OpenPLC v3's iec2c, the venv) and
valgrind for the scan cost.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import pickle
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import types

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "tools", "runner"))
import scan_cost as sc  # noqa: E402
import rig as wp  # noqa: E402
from runner import Runner  # noqa: E402

# (block, simulator kind, short name)
KINDS = (("TempCtrl_MVD94", "mvd94", "mv"), ("FDC_Controller", "fdc100", "fdc"),
         ("Counter_MTS9", "mts9", "mts"))
RUNNER_SRC = ("fb_host.cpp", "plc_vars.cpp", "plc_control.cpp", "plc_host.cpp")
PUB_C = "".join(f'extern "C" void scale_pub_{s}(void) {{ __asm__ volatile(""); }}\n' for *_, s in KINDS)
PUB_H = "".join(f'extern "C" void scale_pub_{s}(void);\n' for *_, s in KINDS)


def plant(lines: int, per_line: int) -> list[tuple[int, int, int]]:
    """[(line, kind index, slave id)] in program order."""
    return [(L, (k + L) % len(KINDS), L * per_line + k + 1) for L in range(lines) for k in range(per_line)]


def plant_program(ports: list[str], devs, baud: int, period: str, task_ms: int) -> str:
    decl, located, body = [], [], []
    for n, (L, kind, slave) in enumerate(devs):
        block, _, short = KINDS[kind]
        decl.append(f"    d{n} : {block};")
        located.append(f"    c{n} AT %QW{n} : UINT;")
        body.append(f"  d{n}(Enable := TRUE, Port := '{ports[L]}', SlaveId := {slave}, Line := l, "
                    f"Period := {period});\n"
                    f"  IF d{n}.Valid AND d{n}.Age = T#0s THEN c{n} := c{n} + 1; {{{{ scale_pub_{short}(); }}}} END_IF;")
    return (f"\nPROGRAM main\n  VAR\n    l : MB_LINE := (Baud := {baud}, Parity := 'N', StopBits := 2);\n"
            + "\n".join(decl) + "\n  END_VAR\n  VAR\n" + "\n".join(located) + "\n  END_VAR\n" + "\n".join(body) + "\nEND_PROGRAM\n"
            + wp.CONFIG.replace("T#1ms", f"T#{task_ms}ms"))


def compile_runner(v: wp.Variant, key: str, program: str) -> str:
    """The program with the project's runner host, built as OpenPLC builds it; the executable."""
    work = os.path.join(v.dir, "run-" + key)
    os.makedirs(work)
    with open(os.path.join(work, "program.st"), "w", encoding="utf-8") as fh:
        fh.write("".join(open(f, encoding="utf-8").read() + "\n" for f in v.st) + program)
    wp.run([v.iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "-I", os.path.join(v.home, "webserver", "lib"),
            "program.st"], cwd=work)
    wp.run([sys.executable, os.path.join(v.src, "tools", "runner", "mkglue.py"), work], cwd=work)
    for name, text in (("scale_pub.h", PUB_H), ("scale_pub.cpp", PUB_C)):
        with open(os.path.join(work, name), "w", encoding="utf-8") as fh:
            fh.write(text)
    rdir = os.path.join(v.src, "tools", "runner")
    exe = os.path.join(work, "plant")
    wp.run(["g++", "-std=gnu++11", "-O0", "-w", "-I", os.path.join(v.home, "webserver", "core", "lib"),
            "-I", rdir, "-I", os.path.join(v.src, "c_shims", "include"), "-I", work,
            "-include", v.pragma_header, "-include", "scale_pub.h", "-o", exe, "Config0.c", "Res0.c", "glue.c",
            "scale_pub.cpp"] + [os.path.join(rdir, f) for f in RUNNER_SRC]
           + [v.lib, v.lm, "-lpthread", f"-Wl,-rpath,{os.path.dirname(v.lm)}"], cwd=work)
    return exe


class PlantLine(wp.Line):
    """rig.py's Line, whose frames() joins entries of one direction that are back to back on
    the wire (less than 1.5 characters apart): ptyline, delayed under load, may log one frame
    in pieces (a request as 8 one-byte entries), which a receiver hears as one frame."""

    def frames(self) -> list[tuple[float, str, int, int]]:
        out: list[tuple[float, str, int, int]] = []
        for t, d, nb, a in super().frames():
            if out and out[-1][1] == d and t - (out[-1][0] + out[-1][2] * self.char_us) < 1.5 * self.char_us:
                out[-1] = (out[-1][0], d, out[-1][2] + nb, out[-1][3])
            else:
                out.append((t, d, nb, a))
        return out

    def collisions(self, t0: float, t1: float) -> int:
        """Log entries in [t0, t1) that ptyline marks as collided ('M>S*', 'S>M*')."""
        with open(self.logf, encoding="utf-8") as fh:
            return sum(1 for ln in fh if len(p := ln.split()) >= 2 and p[1].endswith("*")
                       and t0 <= float(p[0]) < t1)


def open_lines(ptyline: str, tmp: str, devs, nlines: int, baud: int) -> list:
    lines = []
    try:
        for L in range(nlines):
            lines.append(PlantLine(ptyline, tmp, f"line{L}", baud, "8N2",
                                 [f"{KINDS[k][1]}:{s}" for l2, k, s in devs if l2 == L]))
    except BaseException:
        for line in lines:
            line.close()
        raise
    return lines


# ---- the wire run ------------------------------------------------------------------------------

def thread_cpu(pid: int) -> dict[int, tuple[int, int]]:
    """{tid: (utime + stime in clock ticks, ns on a CPU)} of every thread of pid."""
    out = {}
    for d in glob.glob(f"/proc/{pid}/task/*"):
        tid = int(os.path.basename(d))
        try:
            with open(os.path.join(d, "stat")) as fh:
                f = fh.read().rsplit(")", 1)[1].split()      # fields from 3 (state) on
            with open(os.path.join(d, "schedstat")) as fh:
                ns = int(fh.read().split()[0])
        except OSError:
            continue
        out[tid] = (int(f[11]) + int(f[12]), ns)             # fields 14, 15: utime, stime
    return out


def per_device_wire(line: PlantLine, t0: float, t1: float) -> dict[int, tuple[int, float]]:
    """{slave: (requests, bus us)} in [t0, t1): Line.figures' cost of a transaction, per address."""
    fr = line.frames()
    out: dict[int, list] = {}
    for i, (t, d, nb, a) in enumerate(fr):
        if d != "M>S" or not t0 <= t < t1:
            continue
        cost = line.t35_us + nb * line.char_us
        if i + 1 < len(fr) and fr[i + 1][1] == "S>M":
            cost += fr[i + 1][0] - (t + nb * line.char_us) + fr[i + 1][2] * line.char_us
        e = out.setdefault(a, [0, 0.0])
        e[0] += 1
        e[1] += cost
    return {a: (n, us) for a, (n, us) in out.items()}


def line_gaps(line: PlantLine, t0: float, t1: float) -> dict:
    """Silence before each request in [t0, t1): ms min, mean, p99, max; requests with no reply next, after < t3.5."""
    fr = line.frames()
    gaps = [t - (fr[i - 1][0] + fr[i - 1][2] * line.char_us)
            for i, (t, d, _, _) in enumerate(fr) if i and d == "M>S" and t0 <= t < t1]
    gaps.sort()
    ask = [i for i, (t, d, _, _) in enumerate(fr) if d == "M>S" and t0 <= t < t1]
    unanswered = sum(1 for i in ask if i + 1 >= len(fr) or fr[i + 1][1] != "S>M")
    short = sum(1 for g in gaps if g < line.t35_us)
    return {"unanswered": unanswered, "short": short, "requests": len(ask), "mean_ms": statistics.mean(gaps) / 1000, "p99_ms": gaps[int(0.99 * (len(gaps) - 1))] / 1000,
            "max_ms": gaps[-1] / 1000, "min_ms": gaps[0] / 1000} if gaps else {}


def renice(pid: int, nice: int) -> None:
    """Every thread of pid at nice `nice` (the bus workers start in the first scan: call after)."""
    for d in glob.glob(f"/proc/{pid}/task/*"):
        try:
            os.setpriority(os.PRIO_PROCESS, int(os.path.basename(d)), nice)
        except OSError:
            pass


def wire_run(exe: str, ptyline: str, tmp: str, devs, args, nice: tuple = (None, None),
             keep: str | None = None) -> dict:
    """nice: (the program's, the lines' (ptyline and the simulator)) nice values, None: as started."""
    lines = open_lines(ptyline, tmp, devs, args.lines, args.baud)
    try:
        if nice[1] is not None:
            for x in lines:
                renice(x.proc.pid, nice[1])
                renice(x.sim.proc.pid, nice[1])
        with Runner(exe) as plc:
            pid = plc.proc.pid
            if nice[0] is not None:
                time.sleep(1.0)                      # the workers are started
                renice(pid, nice[0])
            time.sleep(args.warmup)
            s0, t0, c0, w0 = plc.snapshot(), [x.now_us() for x in lines], thread_cpu(pid), time.monotonic()
            time.sleep(args.seconds)
            s1, t1, c1, w1 = plc.snapshot(), [x.now_us() for x in lines], thread_cpu(pid), time.monotonic()
        figs = [x.figures(a, b) for x, a, b in zip(lines, t0, t1)]
        wire = [per_device_wire(x, a, b) for x, a, b in zip(lines, t0, t1)]
        gaps = [dict(line_gaps(x, a, b), collisions=x.collisions(a, b)) for x, a, b in zip(lines, t0, t1)]
        if keep:
            os.makedirs(keep, exist_ok=True)
            for L, x in enumerate(lines):
                with open(os.path.join(keep, f"line{L}.frames"), "w", encoding="utf-8") as fh:
                    fh.write(f"# window {t0[L]:.0f} .. {t1[L]:.0f} us (line time)\n")
                    fh.write(open(x.logf, encoding="utf-8").read())
    finally:
        for x in lines:
            x.close()
    workers = sorted(t for t in c1 if t != pid and t in c0)
    if len(workers) != args.lines:
        raise SystemExit(f"expected {args.lines} bus workers besides the scan thread, found {len(workers)}: "
                         f"{sorted(c1)} (pid {pid})")
    tck = os.sysconf("SC_CLK_TCK")
    wall = w1 - w0
    scans = s1["scan"] - s0["scan"]
    counts = [(s1["QW"][str(n)] - s0["QW"][str(n)]) & 0xFFFF for n in range(len(devs))]
    return {"wall": wall, "scans": scans, "window": scans * args.task_ms / 1000.0, "counts": counts,
            "lines": figs, "wire": wire, "gaps": gaps,
            "cpu_stat": [(c1[t][0] - c0[t][0]) / tck / wall for t in workers],
            "cpu_ns": [(c1[t][1] - c0[t][1]) / 1e9 / wall for t in workers],
            "scan_cpu_ns": (c1[pid][1] - c0[pid][1]) / 1e9 / wall,
            "load": os.getloadavg(), "nice": nice, "at": time.strftime("%H:%M:%S", time.gmtime())}


# ---- the scan cost -----------------------------------------------------------------------------

def plant_cost(exe: str, ptyline: str, tmp: str, devs, args) -> list[dict]:
    """Per measured scan: {'prog': Ir, 'ir': {short: Ir}, 'calls': {short: n}, 'pub': {short: n}}."""
    seconds = (args.skip_scans + args.scans) * args.task_ms / 1000.0 + 1.0
    lines = open_lines(ptyline, tmp, devs, args.lines, args.baud)
    try:
        measured = sc.callgrind_scans([exe, "--run", "--seconds", f"{seconds:g}"], tmp, "plant-cg.txt",
                                      seconds * 20 + 300, args.skip_scans, args.scans)
    finally:
        for x in lines:
            x.close()
    bodies = {re.compile(re.escape(b.upper()) + r"_body__\("): s for b, _, s in KINDS}
    scans = []
    for arcs in measured:
        s = {"prog": 0, "ir": {x: 0 for *_, x in KINDS}, "calls": {x: 0 for *_, x in KINDS},
             "pub": {x: 0 for *_, x in KINDS}}
        for (caller, _, _, callee), (calls, ir) in arcs.items():
            callee = callee or ""
            if callee.startswith("MAIN_body__("):
                s["prog"] += ir
            elif caller and caller.startswith("MAIN_body__("):
                for rx, short in bodies.items():
                    if rx.match(callee):
                        s["ir"][short] += ir
                        s["calls"][short] += calls
                if callee.startswith("scale_pub_"):
                    s["pub"][callee[len("scale_pub_"):].split("(")[0]] += calls
        scans.append(s)
    return scans


def alone_cost(v: wp.Variant, tmp: str, args, period: str) -> dict:
    """scan_cost.measure of each block alone (rig.py's device_program) on the plant's line settings."""
    out = {}
    for block, dev, short in KINDS:
        port = os.path.join(tmp, f"alone-{short}-{period.replace('#', '')}")
        exe = v.compile(f"alone-{short}-{period.replace('#', '')}",
                        wp.device_program(block, port, args.baud, "8N2", period))
        wp.log(f"{block} alone, Period {period}: {args.alone_skip_scans} + {args.scans} scans under callgrind ...")
        ns = types.SimpleNamespace(skip_scans=args.alone_skip_scans, scans=args.scans, task_ms=args.task_ms,
                                   pace=True)
        out[short] = sc.measure(v, exe, block, f"{dev}:1", args.baud, "8N2", port, tmp, ns)
    return out


# ---- main --------------------------------------------------------------------------------------

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lines", type=int, default=4)
    ap.add_argument("--per-line", type=int, default=16)
    ap.add_argument("--baud", type=int, default=19200, help="every line, 8N2 (the MV-D94 goes to 19200)")
    ap.add_argument("--task-ms", type=int, default=20)
    ap.add_argument("--warmup", type=float, default=5.0)
    ap.add_argument("--seconds", type=float, default=30.0, help="the wire run's window")
    ap.add_argument("--scans", type=int, default=300, help="scans measured under callgrind")
    ap.add_argument("--skip-scans", type=int, default=250, help="the plant's first scans left out")
    ap.add_argument("--alone-skip-scans", type=int, default=50, help="a block alone: first scans left out")
    ap.add_argument("--skip", default="", help="comma list of: wire,cost")
    ap.add_argument("--keep", metavar="DIR", help="keep the wire run's frame logs (ptyline's, per line) in DIR "
                    "(DIR/NAME-ROUND with --variant)")
    ap.add_argument("--variant", action="append", metavar="NAME=REF[@PLC_NICE[/LINES_NICE]]",
                    help="a version side by side: a commit or 'worktree' (repeatable; default now=worktree); "
                         "@N runs its program at nice N, @/M its lines (ptyline, simulator) at nice M")
    ap.add_argument("--rounds", type=int, default=1, help="wire runs of each version, interleaved")
    ap.add_argument("--save", metavar="FILE", help="also keep the raw results (pickle) in FILE")
    ap.add_argument("--from", dest="saved", metavar="FILE", help="only the report again, from a --save FILE")
    args = ap.parse_args()
    if args.saved:
        with open(args.saved, "rb") as fh:
            res, saved_args = pickle.load(fh)
        report(res, plant(saved_args.lines, saved_args.per_line), saved_args)
        return 0
    skip = set(filter(None, args.skip.split(",")))
    variants = parse_variants(args.variant or ["now=worktree"])
    if skip - {"wire", "cost"} or not (1 <= args.lines <= 16 and 1 <= args.per_line
                                       and args.lines * args.per_line <= 247) \
            or args.baud not in (2400, 4800, 9600, 19200) or min(args.task_ms, args.seconds, args.scans) <= 0 \
            or args.warmup < 0 or args.skip_scans < 0 or args.alone_skip_scans < 0 or args.rounds < 1:
        raise SystemExit("bad arguments: see --help (at most 247 devices; baud 2400..19200; "
                         "--skip from wire,cost; times and counts > 0)")
    if "cost" not in skip and not shutil.which("valgrind"):
        raise SystemExit("valgrind not found (Debian package valgrind), or --skip cost")
    started = time.monotonic()
    with wp.temp_root("plantscale-") as tmp:      # the simulators' temp dirs too
        devs = plant(args.lines, args.per_line)
        ports = [os.path.join(tmp, f"line{L}") for L in range(args.lines)]
        built, exes = {}, {}
        for name, ref, _ in variants:
            if ref not in built:
                built[ref] = wp.Variant(f"v{len(built)}", ref, tmp, "Debug")
                wp.log(f"[{ref}] compiling the plant program (iec2c, g++ -O0, the runner) ...")
                exes[ref] = compile_runner(built[ref], "t0", plant_program(ports, devs, args.baud, "T#0s",
                                                                           args.task_ms))
        ptyline = built[variants[-1][1]].ptyline          # one line model for every version
        v, exe0 = built[variants[0][1]], exes[variants[0][1]]
        res = {"load0": os.getloadavg(), "start": time.strftime("%H:%M", time.gmtime()),
               "variants": variants, "runs": []}
        if "wire" not in skip:
            for r in range(args.rounds):
                for name, ref, nice in variants:
                    wp.log(f"wire run {r + 1}/{args.rounds}, {name} ({ref}{nice_text(nice)}): "
                           f"{args.warmup:g} s + {args.seconds:g} s ...")
                    keep = os.path.join(args.keep, f"{name}-{r + 1}") if args.keep and len(variants) * args.rounds > 1 \
                        else args.keep
                    w = wire_run(exes[ref], ptyline, tmp, devs, args, nice, keep)
                    res["runs"].append((name, r + 1, w))
            res["wire"] = res["runs"][-1][2] if len(res["runs"]) == 1 else None
        if "cost" not in skip:
            exe30 = compile_runner(v, "t30", plant_program(ports, devs, args.baud, "T#30s", args.task_ms))
            for mode, period, exe in (("steady", "T#30s", exe30), ("back to back", "T#0s", exe0)):
                wp.log(f"plant under callgrind, Period {period}: {args.skip_scans} + {args.scans} scans ...")
                res[("plant", mode)] = plant_cost(exe, v.ptyline, tmp, devs, args)
                res[("alone", mode)] = alone_cost(v, tmp, args, period)
        res["load1"] = os.getloadavg()
        res["end"] = time.strftime("%H:%M", time.gmtime())
        res["rev"] = revision()
        if args.save:
            with open(args.save, "wb") as fh:
                pickle.dump((res, args), fh)
        report(res, devs, args)
    wp.log(f"total {time.monotonic() - started:.0f} s")
    return 0


def parse_variants(specs: list[str]) -> list[tuple[str, str, tuple]]:
    """--variant NAME=REF[@PLC_NICE[/LINES_NICE]] -> [(name, ref, (plc nice, lines' nice))], None: as started."""
    out = []
    for spec in specs:
        name, _, rest = spec.partition("=")
        ref, _, nice = rest.partition("@")
        m = re.fullmatch(r"(-?\d+)?(?:/(-?\d+))?", nice)
        if not name.isidentifier() or not ref or not m or name in (n for n, *_ in out):
            raise SystemExit(f"--variant wants NAME=REF, NAME=REF@PLC_NICE, NAME=REF@PLC_NICE/LINES_NICE or "
                             f"NAME=REF@/LINES_NICE (distinct names), not '{spec}'")
        out.append((name, ref, tuple(None if g is None else int(g) for g in m.groups())))
    return out


def nice_text(nice) -> str:
    if not isinstance(nice, tuple):
        nice = (nice, None)                  # a --save file of the first form (@N only)
    parts = [f"{what} at nice {n}" for what, n in zip(("program", "lines"), nice) if n is not None]
    return ", " + ", ".join(parts) if parts else ""


def num(x: float) -> str:
    """12 345 (the README's thousands)."""
    return f"{x:,.0f}".replace(",", " ")


def revision() -> str:
    rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True,
                         text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", ROOT, "diff", "--quiet", "HEAD", "--", "st_src", "c_shims",
                            "tools/runner"]).returncode != 0
    return rev + (" + changes" if dirty else "")


def report(res, devs, args) -> None:
    print(f"# Plant: {args.lines} lines x {args.per_line} devices at {args.baud} 8N2, task {args.task_ms} ms, "
          f"working tree at {res['rev']}; {res['start']} to {res['end']} UTC; "
          f"load average {' '.join(f'{x:.2f}' for x in res['load0'])} at the start, "
          f"{' '.join(f'{x:.2f}' for x in res['load1'])} at the end; {os.cpu_count()} CPUs\n")
    kinds = {s: b for b, _, s in KINDS}
    if res.get("wire"):
        report_wire(res["wire"], devs, args)
    elif res.get("runs"):
        report_runs(res, devs, args)
    if ("plant", "steady") in res:
        report_cost(res, devs, args, kinds)


def report_runs(res, devs, args) -> None:
    """Versions side by side: one line per run, then each run's line table."""
    refs = {n: (r, nice) for n, r, nice in res["variants"]}
    print("## Wire runs side by side (Period T#0s; in the order run)\n")
    print("| version | round | at (UTC) | load at the end | share of the wire, lines 0..3 | gap ms median | "
          "gap ms mean | gap ms p99 | tx/s per line | worker CPU % (schedstat) | worst device vs fair share |")
    print("|---" * 11 + "|")
    for name, r, w in res["runs"]:
        ref, nice = refs[name]
        worst = 0.0
        for L in range(args.lines):
            c = [w["counts"][n] for n, d in enumerate(devs) if d[0] == L]
            fair = sum(c) / len(c)
            worst = max(worst, max(abs(x / fair - 1) for x in c) if fair else float("inf"))
        rng = lambda xs, f: f"{f(min(xs))} to {f(max(xs))}"  # noqa: E731
        shares = " / ".join(f"{x['share']:.3f}" for x in w["lines"])
        print(f"| {name} ({ref}{nice_text(nice)}) | {r} | {w.get('at', '')} | "
              f"{w['load'][0]:.1f} | {shares} | "
              f"{rng([x['gap_ms'] for x in w['lines']], lambda v: f'{v:.2f}')} | "
              f"{rng([g['mean_ms'] for g in w['gaps']], lambda v: f'{v:.2f}')} | "
              f"{rng([g['p99_ms'] for g in w['gaps']], lambda v: f'{v:.1f}')} | "
              f"{rng([x['tx'] for x in w['lines']], lambda v: f'{v:.1f}')} | "
              f"{rng([100 * x for x in w['cpu_ns']], lambda v: f'{v:.2f}')} | ±{worst:.1%} |")
    print()
    for name, (ref, nice) in refs.items():
        runs = [w for n, _, w in res["runs"] if n == name]
        share = [statistics.mean(x["share"] for x in w["lines"]) for w in runs]
        excess = [statistics.mean(g["mean_ms"] for g in w["gaps"]) for w in runs]
        print(f"* {name}: share of the wire, mean of the lines, median over {len(runs)} runs "
              f"**{statistics.median(share):.3f}** (runs {min(share):.3f} to {max(share):.3f}); mean gap "
              f"{statistics.median(excess):.2f} ms (runs {min(excess):.2f} to {max(excess):.2f})")
    print()
    for name, r, w in res["runs"]:
        print(f"### {name}, round {r}\n")
        report_wire(w, devs, args, per_device=False)


def report_wire(w, devs, args, per_device: bool = True) -> None:
    win = w["window"]
    print(f"## Wire run: Period T#0s, window {w['wall']:.1f} s wall = {w['scans']} scans "
          f"({win:.1f} s of task time) after {args.warmup:g} s; wire load average at the end "
          f"{' '.join(f'{x:.2f}' for x in w['load'])}\n")
    print("| line | devices MV-D94 / FDC / MT-S9 | share of the wire | tx/s | requests < t3.5 / unanswered / collided entries | gap ms min / median / mean / p99 / max | "
          "refreshes/s (line) | per device min / median / max | worst device vs fair share | "
          "never refreshed | worker CPU % (stat) | worker CPU % (schedstat) |")
    print("|---" * 12 + "|")
    worst_all = 0.0
    for L in range(args.lines):
        idx = [n for n, d in enumerate(devs) if d[0] == L]
        c = [w["counts"][n] for n in idx]
        fair = sum(c) / len(c)
        dev = max(abs(x / fair - 1) for x in c) if fair else float("inf")
        worst_all = max(worst_all, dev)
        mix = [sum(1 for n in idx if devs[n][1] == k) for k in range(len(KINDS))]
        f, g = w["lines"][L], w["gaps"][L]
        print(f"| {L} | {' / '.join(map(str, mix))} | **{f['share']:.3f}** | {f['tx']:.1f} | {g['short']} / {g['unanswered']} of {g['requests']} / {g['collisions']} | "
              f"{g['min_ms']:.2f} / {f['gap_ms']:.2f} / {g['mean_ms']:.2f} / {g['p99_ms']:.1f} / {g['max_ms']:.1f} | "
              f"{sum(c) / win:.2f} | {min(c) / win:.3f} / {statistics.median(c) / win:.3f} / "
              f"{max(c) / win:.3f} | **±{dev:.1%}** | {sum(1 for x in c if x == 0)} | "
              f"{100 * w['cpu_stat'][L]:.2f} | {100 * w['cpu_ns'][L]:.2f} |")
    print(f"\nScan thread CPU (schedstat): {100 * w['scan_cpu_ns']:.1f} % of a core. Worst device of the "
          f"plant against its line's fair share: ±{worst_all:.1%}.\n")
    if not per_device:
        return
    print("| line | slave | block | refreshes | refreshes/s | vs fair share | requests/s | bus share |")
    print("|---|---|---|---|---|---|---|---|")
    for L in range(args.lines):
        idx = [n for n, d in enumerate(devs) if d[0] == L]
        fair = sum(w["counts"][n] for n in idx) / len(idx)
        for n in idx:
            _, k, slave = devs[n]
            req, us = w["wire"][L].get(slave & 0xFF, (0, 0.0))
            print(f"| {L} | {slave} | {KINDS[k][0]} | {w['counts'][n]} | {w['counts'][n] / win:.3f} | "
                  f"{w['counts'][n] / fair - 1:+.1%} | {req / w['wall']:.2f} | {us / 1e6 / w['wall']:.3f} |")


def report_cost(res, devs, args, kinds) -> None:
    print(f"\n## Scan cost (callgrind, Ir per scan; program and shims at -O0; {args.scans} scans after "
          f"{args.skip_scans}; blocks alone: {args.scans} after {args.alone_skip_scans})\n")
    n_of = {s: sum(1 for d in devs if KINDS[d[1]][2] == s) for s in kinds}
    scans = res[("plant", "steady")]
    quiet = [s for s in scans if not any(s["pub"].values())]
    alone = res[("alone", "steady")]
    print(f"Steady (Period T#30s): {len(quiet)} of {len(scans)} measured scans without a refresh; means "
          f"over those.\n")
    print("| block | in the program | Ir per call in the program | alone (scan_cost.measure) | "
          "program / alone |")
    print("|---|---|---|---|---|")
    tot_in, tot_alone = 0.0, 0.0
    for s, b in kinds.items():
        ir = statistics.mean(q["ir"][s] for q in quiet) if quiet else float("nan")
        calls = statistics.mean(q["calls"][s] for q in quiet) if quiet else float("nan")
        a = alone[s]["body"]
        tot_in += ir
        tot_alone += n_of[s] * a
        print(f"| `{b}` x {n_of[s]} ({calls:.0f} calls/scan) | {num(ir)} | {num(ir / calls)} | {num(a)} | "
              f"{ir / calls / a:.3f} |")
    prog = statistics.mean(q["prog"] for q in quiet) if quiet else float("nan")
    print(f"| all blocks | {num(tot_in)} | | {num(tot_alone)} (sum) | {tot_in / tot_alone:.3f} |")
    print(f"| whole program (`MAIN_body__`: blocks + counters) | {num(prog)} | | | {prog / tot_alone:.3f} |")
    shares = ", ".join(f"{s} {alone[s]['pub']:.1%}" for s in kinds)
    print(f"\nAlone, steady: pick-up share {shares}; most in one program scan "
          f"{num(max(q['prog'] for q in quiet) if quiet else 0)} Ir.")
    scans = res[("plant", "back to back")]
    ab = res[("alone", "back to back")]
    print(f"\nRefreshes back to back (Period T#0s): {len(scans)} scans; a block's cost per call in the "
          f"program against two predictions from the same block alone with Period T#0s (A: steady + the "
          f"refreshes x the alone mean's extra per refresh; B: the alone scans without a refresh + the "
          f"refreshes x (a pick-up scan - those))\n")
    print("| block | refreshes per block per scan | in the program, Ir per call | alone: mean per scan | "
          "pick-up scans | Ir in them | in the others | prediction A | prediction B |")
    print("|---|---|---|---|---|---|---|---|---|")
    tot = {"m": 0.0, "a": 0.0, "b": 0.0}
    waits = []
    for s, b in kinds.items():
        r = ab[s]
        pick = r["body_pub"] if r["body_pub"] is not None else r["body"]
        other = (r["body"] - r["pub"] * pick) / (1 - r["pub"]) if r["pub"] < 1 else alone[s]["body"]
        per = statistics.mean(q["pub"][s] for q in scans) / n_of[s]          # refreshes per block per scan
        m = statistics.mean(q["ir"][s] for q in scans) / n_of[s]
        idle = [q["ir"][s] / n_of[s] for q in scans if not q["pub"][s]]
        waits.append(f"{s} {num(statistics.mean(idle)) if idle else '-'} ({len(idle)} scans)")
        a = alone[s]["body"] + per * ((r["body"] - alone[s]["body"]) / r["pub"] if r["pub"] else 0.0)
        bb = other + per * (pick - other)
        for k, x in (("m", m), ("a", a), ("b", bb)):
            tot[k] += n_of[s] * x
        print(f"| `{b}` | {per:.4f} | {num(m)} | {num(r['body'])} | {r['pub']:.0%} | {num(pick)} | {num(other)} | "
              f"{num(a)} | {num(bb)} |")
    print(f"| all blocks, per scan | | {num(tot['m'])} | | | | | {num(tot['a'])} ({tot['m'] / tot['a']:.3f}) | "
          f"{num(tot['b'])} ({tot['m'] / tot['b']:.3f}) |")
    print(f"\nIn the program's scans in which no block of that kind refreshed, Ir per call: {', '.join(waits)}.")
    print(f"Whole program (`MAIN_body__`) per scan: mean {num(statistics.mean(q['prog'] for q in scans))}, "
          f"max {num(max(q['prog'] for q in scans))}.")

if __name__ == "__main__":
    sys.exit(main())
