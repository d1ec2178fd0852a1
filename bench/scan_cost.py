"""Scan cost of a device block: instructions per scan under callgrind.

    .venv/bin/python bench/scan_cost.py                                  # the working tree, shims -O0 and -O2
    .venv/bin/python bench/scan_cost.py --variant before=140d186 --variant now=worktree
    .venv/bin/python bench/scan_cost.py --help

Not a test: it prints figures (st_src/README.md, "Scan cost"). For each variant (a commit
exported with `git archive`, or the working tree: bench/wire_pace.py's Variant) and each
build of the shims (--shims: O0 = CMAKE_BUILD_TYPE Debug, as OpenPLC compiles them with the
program; O2 = RelWithDebInfo), for Counter_MTS9 (MT-S9, 115200 8N1), TempCtrl_MVD94,
FDC_Controller and MB_Poll (19200 8N2; MB_Poll reads coils, holding registers, discrete inputs
and input registers of the simulator's generic device bench/poll_device.json, 5 words), each
in wire_pace's `device_program` (one block, task 20 ms)
with `Period := T#30s` ("steady": no new snapshot after the first refresh), `T#1s`
("published": a snapshot every second, so `Age` and `SettingsAge` are computed in the scans
between, the steady scan of a block whose data are published) and `T#0s` ("pick-up"): the program is built as OpenPLC builds it (iec2c -f -l -p -r -R -a, g++ -O0,
bench/wirepace/wp_host.cpp as the runtime) and run in real time under
`valgrind --tool=callgrind --dump-after=config_run__*` against the simulator on a pty, so
callgrind writes one profile per scan. The simulator answers at once (a pty is not paced):
with `T#0s` nearly every scan then takes a new snapshot, the worst case; --pace paces its
replies at the line's baud rate (fewer scans pick up, as on a wire). The first --skip-scans scans (the
bus opened, the plan set, the first refreshes) are left out; of the next --scans scans it
reports, per scan:

* block: the inclusive instructions (Ir) of the calls to the block's body function
  (`<BLOCK>_body__`, everything it calls included);
* shim calls: the inclusive Ir of every call the ST code makes to a `mbfb_*` function (a
  call from the program's generated code, not from the shims themselves or their worker
  thread), summed per scan; also per function (calls per scan, Ir per call);
* published: the median of the block's Ir over the scans that took no new snapshot (Period
  T#1s);
* pick-up: the share of scans in which the program saw `Valid AND Age = T#0s` (it calls
  `wp_pub`): a new snapshot taken, judged and published in that scan.

Everything listens on ptys only; every process is stopped by pid; the temp dir is removed.
Needs what wire_pace.py needs (cmake, ninja, gcc/g++, OpenPLC v3's iec2c, the venv) and
valgrind (Debian package).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wire_pace as wp  # noqa: E402

# (block, simulator device, baud, format)
POLL_DEVICE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "poll_device.json")
BLOCKS = (("Counter_MTS9", "mts9:1", 115200, "8N1"),
          ("TempCtrl_MVD94", "mvd94:1", 19200, "8N2"),
          ("FDC_Controller", "fdc100:1", 19200, "8N2"),
          ("MB_Poll", f"generic:1:file={POLL_DEVICE}", 19200, "8N2"))
# a block's inputs besides Enable, Port, SlaveId, Line, Period: MB_Poll's four ranges, mixed
INPUTS = {"MB_Poll": ", Fc1 := 1, Addr1 := 0, Count1 := 20, Fc2 := 3, Addr2 := 0, Count2 := 10, "
                     "Fc3 := 2, Addr3 := 10, Count3 := 40, Fc4 := 4, Addr4 := 100, Count4 := 5"}
MODES = (("steady", "T#30s"), ("published", "T#1s"), ("pick-up", "T#0s"))
SHIMS = {"O0": "Debug", "O2": "RelWithDebInfo"}


# ---- callgrind's output format (one file per dump, names compressed across the dumps) ----------

class Names:
    """callgrind's name compression: '(id) name' defines, '(id)' refers; ids hold across dumps."""

    def __init__(self):
        self.map: dict[str, str] = {}

    def get(self, value: str) -> str:
        m = re.match(r"\((\d+)\)(?: (.*))?$", value)
        if not m:
            return value
        if m.group(2) is not None:
            self.map[m.group(1)] = m.group(2)
        return self.map.get(m.group(1), "?")


class Profile:
    """Parses callgrind dumps in order; each dump -> {'arcs': {(caller, callee): [calls, Ir]}}."""

    def __init__(self):
        self.fns, self.files, self.objs = Names(), Names(), Names()

    def parse(self, path: str) -> dict:
        arcs: dict[tuple, list] = {}
        fn = fn_file = fn_obj = ob = fl = None
        callee = None
        pending = None
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                c = line[:1]
                if c.isdigit() or c in "+-*":
                    if pending is not None:
                        parts = line.split()
                        a = arcs.setdefault((fn, fn_file, fn_obj, pending[0]), [0, 0])
                        a[0] += pending[1]
                        a[1] += int(parts[1]) if len(parts) > 1 else 0
                        pending = None
                    continue
                key, _, value = line.rstrip("\n").partition("=")
                if key == "fn":
                    fn, fn_file, fn_obj = self.fns.get(value), fl, ob
                elif key == "fl":
                    fl = self.files.get(value)
                elif key in ("fi", "fe", "cfi", "cfl"):
                    self.files.get(value)
                elif key == "ob":
                    ob = self.objs.get(value)
                elif key == "cob":
                    self.objs.get(value)
                elif key == "cfn":
                    callee = self.fns.get(value)
                elif key == "calls":
                    pending = (callee, int(value.split()[0]))
        return arcs


def scan_figures(arcs: dict, block: str, exe: str) -> dict:
    body = re.compile(re.escape(block.upper()) + r"_body__\(")
    out = {"body": 0, "shims": 0, "per_fn": {}, "pub": False}
    for (caller, cfile, cobj, callee), (calls, ir) in arcs.items():
        if body.match(callee or "") and caller and caller.startswith("MAIN_body__"):
            out["body"] += ir
        elif callee and callee.startswith("wp_pub") and caller and caller.startswith("MAIN_body__"):
            out["pub"] = True
        elif (callee and callee.startswith("mbfb_") and caller and not caller.startswith("mbfb_")
              and cobj == exe and "c_shims" not in (cfile or "") and not caller.startswith("main")):
            out["shims"] += ir
            f = out["per_fn"].setdefault(callee.split("(")[0], [0, 0])
            f[0] += calls
            f[1] += ir
    return out


def callgrind_scans(cmd: list, tmp: str, log_name: str, timeout_s: float, skip: int,
                    n: int) -> list:
    """Runs cmd, a program that scans, under callgrind with a dump after each scan
    (config_run__*), its output in tmp/log_name; returns the call arcs (Profile.parse) of scans
    skip + 1 .. skip + n. Exits with the output's tail when the program fails, or when it
    scanned fewer times. Used by plant_scale.py too."""
    cg = tempfile.mkdtemp(prefix="cg-", dir=tmp)
    out = os.path.join(tmp, log_name)
    with open(out, "w") as fh:
        proc = subprocess.Popen(["valgrind", "--tool=callgrind", f"--callgrind-out-file={cg}/cg.out",
                                 "--dump-after=config_run__*", *cmd], stdout=fh, stderr=subprocess.STDOUT)
        try:
            rc = proc.wait(timeout_s)
        finally:
            wp.stop(proc)
    if rc != 0:
        raise SystemExit(f"{cmd[0]} under callgrind exited {rc}:\n{open(out).read()[-2000:]}")
    parts = sorted((int(f.rsplit(".", 1)[1]), f) for f in os.listdir(cg) if re.fullmatch(r"cg\.out\.\d+", f))
    if len(parts) < skip + n:
        raise SystemExit(f"{cmd[0]}: {len(parts)} scans under callgrind, fewer than --skip-scans + --scans")
    prof = Profile()
    scans = []
    for k, f in parts:                          # dump k is written after scan k-1 (dump 1: init + scan 0)
        arcs = prof.parse(os.path.join(cg, f))
        if skip < k <= skip + n:
            scans.append(arcs)
    shutil.rmtree(cg)
    return scans


def measure(v: wp.Variant, exe: str, block: str, dev: str, baud: int, fmt: str, port: str,
            tmp: str, args) -> dict:
    """One callgrind run of one program; returns the figures over the measured scans."""
    seconds = (args.skip_scans + args.scans) * args.task_ms / 1000.0 + 1.0
    sim = wp.Simulator([dev], baud=baud, fmt=fmt, pace=args.pace, seed=1, link=port,
                       extra=["--ptyline", "none"] if args.pace else [])
    sim.start()
    try:
        arcs = callgrind_scans([exe, "0", f"{seconds:g}", str(args.task_ms)], tmp, "host.txt",
                               seconds * 10 + 120, args.skip_scans, args.scans)
    finally:
        sim.stop()
    scans = [scan_figures(a, block, exe) for a in arcs]
    n = len(scans)
    per_fn: dict[str, list] = {}
    for s in scans:
        for name, (c, ir) in s["per_fn"].items():
            f = per_fn.setdefault(name, [0, 0])
            f[0] += c
            f[1] += ir
    picked = [s["shims"] for s in scans if s["pub"]]
    other = [s["shims"] for s in scans if not s["pub"]]
    return {"n": n, "pub": sum(s["pub"] for s in scans) / n,
            "body": sum(s["body"] for s in scans) / n,
            "body_pub": statistics.mean(s["body"] for s in scans if s["pub"]) if picked else None,
            "body_other_median": statistics.median(s["body"] for s in scans if not s["pub"]) if other else None,
            "shims": sum(s["shims"] for s in scans) / n,
            "shims_pub": statistics.mean(picked) if picked else None,
            "shims_other": statistics.mean(other) if other else None,
            "shims_max": max(s["shims"] for s in scans),
            "per_fn": {k: (c / n, ir / c) for k, (c, ir) in sorted(per_fn.items())}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variant", action="append", metavar="NAME=REF",
                    help="a commit or 'worktree' (repeatable; default now=worktree)")
    ap.add_argument("--shims", default="O0,O2", help="builds of the shims: O0 (Debug), O2 (RelWithDebInfo)")
    ap.add_argument("--scans", type=int, default=450, help="scans measured per run")
    ap.add_argument("--skip-scans", type=int, default=50, help="first scans left out (open, plan, first refreshes)")
    ap.add_argument("--task-ms", type=int, default=20)
    ap.add_argument("--pace", action="store_true",
                    help="the simulator paces its replies at the baud rate (default: answers at once)")
    ap.add_argument("--blocks", default=",".join(b for b, *_ in BLOCKS))
    args = ap.parse_args()
    variants = [v.split("=", 1) for v in (args.variant or ["now=worktree"])]
    if any(len(v) != 2 or not v[0].isidentifier() for v in variants):
        raise SystemExit("--variant wants NAME=REF (REF: a commit or 'worktree')")
    opts = [o for o in args.shims.split(",") if o]
    blocks = [b for b in BLOCKS if b[0] in args.blocks.split(",")]
    if not opts or set(opts) - set(SHIMS) or not blocks or len(blocks) != len(set(args.blocks.split(","))) \
            or args.scans <= 0 or args.skip_scans < 0 or args.task_ms <= 0:
        raise SystemExit("bad arguments: see --help (--shims from O0,O2; --blocks from "
                         + ",".join(b for b, *_ in BLOCKS) + "; --scans, --task-ms > 0)")
    if not shutil.which("valgrind"):
        raise SystemExit("valgrind not found (Debian package valgrind)")
    tmp = tempfile.mkdtemp(prefix="scancost-")
    started = time.monotonic()
    res = {}
    try:
        for name, ref in variants:
            for o in opts:
                v = wp.Variant(f"{name}-{o}", ref, tmp, SHIMS[o])
                for block, dev, baud, fmt in blocks:
                    for mode, period in MODES:
                        key = f"{block}-{mode}"
                        port = os.path.join(tmp, f"{v.name}-{key}")
                        exe = v.compile(key, wp.device_program(block, port, baud, fmt, period,
                                                               INPUTS.get(block, "")))
                        wp.log(f"[{v.name}] {block} {mode}: {args.skip_scans} + {args.scans} scans under callgrind ...")
                        res[(name, o, block, mode)] = measure(v, exe, block, dev, baud, fmt, port, tmp, args)
                shutil.rmtree(v.dir)
        report(res, variants, opts, blocks, args)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    wp.log(f"total {time.monotonic() - started:.0f} s")
    return 0


def report(res, variants, opts, blocks, args) -> None:
    names = [n for n, _ in variants]
    print(f"# Scan cost: {', '.join(f'{n} = {r}' for n, r in variants)}; shims {', '.join(opts)}; "
          f"task {args.task_ms} ms; {args.scans} scans after {args.skip_scans}; "
          f"simulator {'paced' if args.pace else 'answering at once'}; "
          f"instructions (Ir) per scan, means\n")
    o0 = opts[0]

    def worst(r, what):                 # pick-up: the scans that took a snapshot (all scans if none did)
        return r[what + "_pub"] if r[what + "_pub"] is not None else r[what]

    head = "| block | " + " | ".join(f"{m}, {n}" for m, _ in MODES for n in names)
    head += " | " + " | ".join(f"shim calls -{o} {n} (steady / pick-up)" for o in opts for n in names) + " |"
    print(head)
    print("|---" * (1 + len(MODES) * len(names) + len(opts) * len(names)) + "|")
    for block, *_ in blocks:
        cells = [f"{res[(n, o0, block, 'steady')]['body']:,.0f}".replace(",", " ") for n in names]
        cells += [f"{res[(n, o0, block, 'published')]['body_other_median'] or 0:,.0f}".replace(",", " ")
                  for n in names]
        cells += [f"{worst(res[(n, o0, block, 'pick-up')], 'body'):,.0f}".replace(",", " ") for n in names]
        cells += [f"{res[(n, o, block, 'steady')]['shims']:.0f} / {worst(res[(n, o, block, 'pick-up')], 'shims'):.0f}"
                  for o in opts for n in names]
        print(f"| `{block}` | " + " | ".join(cells) + " |")
    print(f"\nMeans per scan; steady: over all scans; published (Period T#1s): the median over the scans "
          f"that took no new snapshot; pick-up: over the scans that took a new snapshot. "
          f"Block columns: the body's inclusive Ir with the shims at -{o0} (the ST code is -O0 in every run).")
    print("\n| variant | shims | block | case | scans | pick-ups | block Ir | in pick-up scans | shim calls Ir | "
          "in pick-up scans | in other scans | max | per function: calls/scan x Ir/call |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (n, o, block, mode), r in res.items():
        fmt = lambda x: "-" if x is None else f"{x:.0f}"  # noqa: E731
        fns = ", ".join(f"{k} {c:.2f} x {ir:.0f}" for k, (c, ir) in r["per_fn"].items())
        print(f"| {n} | -{o} | {block} | {mode} | {r['n']} | {r['pub']:.1%} | {r['body']:.0f} | {fmt(r['body_pub'])} | "
              f"{r['shims']:.0f} | "
              f"{fmt(r['shims_pub'])} | {fmt(r['shims_other'])} | {r['shims_max']} | {fns} |")
    over = [(k, r) for k, r in res.items() if r["shims_max"] > 300]
    print("\nShim calls over 300 Ir per block in a scan (mean over the pick-up scans; the most in one scan): "
          + ("; ".join(f"{k[2]} {k[3]} ({k[0]}, shims -{k[1]}): {worst(r, 'shims'):.0f}; {r['shims_max']}"
                       for k, r in over) if over else "none") + ".")


if __name__ == "__main__":
    sys.exit(main())
