#!/usr/bin/env python3
"""The recipe round trip: what `mbcommission backup --st` prints compiles in a PLC program and,
downloaded by the blocks, reproduces the backup.

    test_recipe_roundtrip.py --build BUILD_DIR --target T --exe EXE --program OUT.st [--strucpp]
    test_recipe_roundtrip.py --skip REASON      (toolchain missing: exit 77, or 1 in CI)

One simulated line (9600 8N2 RTU) holds instrument A of each model, tuned away from the
defaults, and instrument B at the defaults (MV-D94 at 1 and 2, FDC-100 at 3 and 4, MT-S9 at 5
and 6). For each model: `backup --st` of A; its output pasted unedited into roundtrip.st's
VAR CONSTANT block (the marker); the program built (cmake --build of T: matiec, or STruC++
with --strucpp), run against the line: it downloads each recipe to B (WriteSettings, Done).
Then: a backup of B holds every field of the settings structure as A's backup does; the wire
carried a write to B of exactly the fields that differed (each once, A's value, the scaling
ones before the others), the lock or access level only as the recipe needs it, nothing to
anyone else; the block's SettingsWritten is that number of fields.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
sys.path.insert(0, os.path.join(ROOT, "maps"))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tests", "strucpp"))
import settings  # noqa: E402  maps/settings.py
from run_fb_test import skip  # noqa: E402  exit 77, or 1 under MBFB_REQUIRE_TOOLCHAIN=1
from run_strucpp import build  # noqa: E402  cmake --build of one target, one build at a time

TOOL = os.path.join(ROOT, "tools", "commission", "mbcommission.py")
TEMPLATE = os.path.join(HERE, "roundtrip.st")
MARKER = "(*@RECIPES*)"

# kind, the program's recipe name, its block's note name, A (tuned) and B (defaults)
MODELS = [
    ("mvd94", "RecipeMVD94", "MV-D94",
     "mvd94:1:SV=120.0,DP=1,TYPE=J,HILT=300.0,LOLT=-50.0,A1SP=5.0,SPOF=-1.5,PB=12.5,TD=45,CT=15,"
     "HYST=0.5,A2HY=0.3,LOCK=0101", "mvd94:2"),
    ("fdc100", "RecipeFDC", "FDC",
     "fdc100:3:INPT=12,DP=2,SP1H=400.0,SP1=150.0,SP2=20.0,PB=20.0,TI=200,ALHY=2.0,RR=5.0,"
     "CYC1=10.0", "fdc100:4"),
    ("mts9", "RecipeMTS9", "MT-S9", "mts9:5:Decimal Set=2", "mts9:6"),
]
MIN_DIFFER = {"mvd94": 8, "fdc100": 8, "mts9": 1}   # A really is another product than B


def tool(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, TOOL, *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def backup(port: str, addr: int, out: str, *extra) -> tuple[dict, str]:
    r = tool("backup", port, addr, "-o", out, *extra)
    if r.returncode != 0:
        raise AssertionError(f"backup of {addr} failed ({r.returncode}): {r.stderr.strip()}")
    with open(out, encoding="utf-8") as fh:
        return json.load(fh), r.stdout


def recipe_raw(kind: str, data: dict) -> dict:
    """field -> raw word(s) of a backup's recipe fields."""
    return {s.field: data["registers"][s.reg.name]["raw"] for s in settings.fields(kind)}


def writes(frames: list) -> list:
    """(slave, register, value) of every register a FC06 / FC16 request wrote, in wire order."""
    out = []
    for f in frames:
        b = [int(x, 16) for x in f["hex"].split()]
        if f["dir"] != "rx" or len(b) < 6:
            continue
        if b[1] == 6:
            out.append((b[0], b[2] << 8 | b[3], b[4] << 8 | b[5]))
        elif b[1] == 16:
            start, count = b[2] << 8 | b[3], b[4] << 8 | b[5]
            out += [(b[0], start + i, b[7 + 2 * i] << 8 | b[8 + 2 * i]) for i in range(count)]
    return out


def check_wire(kind: str, b_addr: int, a: dict, b0: dict, before: dict, after: dict,
               wire: list) -> list:
    """What went to B (`wire`) against what differed between the recipe fields `a` (A's) and
    `b0` (B's before); `before` and `after` are B's backups. Returns the failures."""
    bad = []
    acc = settings.access_register(kind)
    acc_reg, unlocked, acc_kind = acc if acc else (None, None, None)
    fields = {s.field: s for s in settings.fields(kind)}
    differ = [f for f in fields if a[f] != b0[f]]
    by_addr = {}
    for f, s in fields.items():
        for i in range(s.reg.words):
            by_addr[s.reg.addr + i] = (f, i)
    mine = [(reg, val) for slave, reg, val in wire if slave == b_addr]
    setting_writes = [(reg, val) for reg, val in mine if acc_reg is None or reg != acc_reg.addr]
    written = []
    for reg, val in setting_writes:
        if reg not in by_addr:
            bad.append(f"{kind}: register {reg} written, no recipe field")
            continue
        f, i = by_addr[reg]
        s = fields[f]
        want = (a[f] >> (16 * (s.reg.words - 1 - i))) & 0xFFFF
        if val != want:
            bad.append(f"{kind}: {f} written as {val}, A holds {want}")
        if i == 0:
            written.append(f)
    want = sorted(f for f in differ if acc_reg is None or fields[f].reg.addr != acc_reg.addr)
    if sorted(written) != want:
        bad.append(f"{kind}: fields written {sorted(written)}, differing {want}")
    first = [k for k, f in enumerate(written) if fields[f].part == "first"]
    rest = [k for k, f in enumerate(written) if fields[f].part != "first"]
    if first and rest and max(first) > min(rest):
        bad.append(f"{kind}: a value written before the scaling it needs: {written}")
    lock = [val for reg, val in mine if acc_reg is not None and reg == acc_reg.addr]
    if acc_kind == "lock":
        lock_field = by_addr[acc_reg.addr][0]
        opened = b0[lock_field] != unlocked
        if not opened and lock_field not in differ and lock:
            bad.append(f"{kind}: lock written {lock} though neither locked nor changed")
        if lock and lock[-1] != a[lock_field]:
            bad.append(f"{kind}: lock left at {lock[-1]}, the recipe has {a[lock_field]}")
        if len(lock) > 2:
            bad.append(f"{kind}: lock written {len(lock)} times")
    elif acc_kind == "author":
        name = acc_reg.name
        if not differ and lock:
            bad.append(f"{kind}: access level written {lock} with nothing to write")
        if after["registers"][name]["raw"] != before["registers"][name]["raw"]:
            bad.append(f"{kind}: access level left at {after['registers'][name]['raw']}, "
                       f"was {before['registers'][name]['raw']}")
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip")
    ap.add_argument("--build")
    ap.add_argument("--target")
    ap.add_argument("--exe")
    ap.add_argument("--program", help="where the program with the pasted recipes is written "
                    "(the target's source)")
    ap.add_argument("--strucpp", action="store_true", help="the target is built by STruC++ "
                    "(skips with MBFB_STRUCPP_REASON)")
    args = ap.parse_args()
    if args.skip is not None:
        return skip(args.skip)
    if args.strucpp and os.environ.get("MBFB_STRUCPP_REASON"):
        return skip(os.environ["MBFB_STRUCPP_REASON"])
    from simctl import Simulator  # tools/sim/simctl.py

    with open(TEMPLATE, encoding="utf-8") as fh:
        template = fh.read()
    assert template.count(MARKER) == 1, f"{TEMPLATE}: no single {MARKER}"
    tmp = tempfile.mkdtemp(prefix="roundtrip-")
    failures = []
    try:
        link = os.path.join(tmp, "ttySIM")
        devices = [m[3] for m in MODELS] + [m[4] for m in MODELS]
        with Simulator(devices, baud=9600, fmt="8N2", link=link) as sim:
            a, b0, texts = {}, {}, []
            for kind, name, _, spec_a, spec_b in MODELS:
                addr_a, addr_b = int(spec_a.split(":")[1]), int(spec_b.split(":")[1])
                data, st = backup(link, addr_a, os.path.join(tmp, f"{kind}_a.json"), "--st",
                                  "--st-name", name)
                a[kind] = data
                b0[kind], _ = backup(link, addr_b, os.path.join(tmp, f"{kind}_b0.json"))
                differ = [f for f, v in recipe_raw(kind, data).items()
                          if v != recipe_raw(kind, b0[kind])[f]]
                print(f"{kind}: A at {addr_a} and B at {addr_b} differ in {len(differ)} of "
                      f"{len(settings.fields(kind))} fields: {', '.join(differ)}")
                assert len(differ) >= MIN_DIFFER[kind], f"{kind}: A is too like B to test anything"
                texts.append(st)
            # the printed text, unedited, in the program's VAR CONSTANT block
            pasted = "\n".join(texts).rstrip("\n")
            program = template.replace(MARKER, "    " + pasted.replace("\n", "\n    "))
            os.makedirs(os.path.dirname(os.path.abspath(args.program)), exist_ok=True)
            with open(args.program, "w", encoding="utf-8") as fh:
                fh.write(program)
            rc, out = build(args.build, args.target)
            if rc:
                print(out[-6000:])
                print(f"FAIL: the program with the pasted recipes ({args.program}) does not build")
                return 1
            sim.control({"op": "log", "clear": True})
            env = dict(os.environ, MBFB_TEST_PORT=link, MBFB_SIM_CONTROL=sim.control_path)
            try:
                p = subprocess.run([args.exe], env=env, capture_output=True, text=True,
                                   timeout=300)
            except subprocess.TimeoutExpired:
                print(f"FAIL: {args.exe} still running after 300 s (killed)")
                return 1
            print(p.stdout[-4000:], p.stderr[-2000:])
            if p.returncode != 0:
                print(f"FAIL: the program's downloads did not all end Done (exit {p.returncode})")
                return 1
            wire = writes(sim.control({"op": "log"})["frames"])
            for kind, name, note, spec_a, spec_b in MODELS:
                addr_b = int(spec_b.split(":")[1])
                b1, _ = backup(link, addr_b, os.path.join(tmp, f"{kind}_b1.json"))
                ra, rb0, rb1 = (recipe_raw(kind, d) for d in (a[kind], b0[kind], b1))
                text_raw = settings.to_raw(kind, settings.parse_initial(
                    kind, [t for t in texts if name in t][0]))
                if text_raw != ra:
                    failures.append(f"{kind}: the printed recipe is not A's backup")
                lost = {f: (rb1[f], ra[f]) for f in ra if rb1[f] != ra[f]}
                if lost:
                    failures.append(f"{kind}: B after the download differs from A in "
                                    f"{len(lost)} field(s) (B, A): {lost}")
                failures += check_wire(kind, addr_b, ra, rb0, b0[kind], b1, wire)
                differ = sum(1 for f in ra if ra[f] != rb0[f])
                said = f": {note} written {differ}\n" in p.stdout
                if not said:
                    failures.append(f"{kind}: the block did not report {differ} field(s) written")
                mine = [(r, v) for sl, r, v in wire if sl == addr_b]
                print(f"{kind}: B holds A's {len(ra)} fields; {differ} differed; the wire to B: "
                      f"{len(mine)} register writes {mine}")
            others = sorted({s for s, _, _ in wire} - {int(m[4].split(":")[1]) for m in MODELS})
            if others:
                failures.append(f"writes to other slaves than the B instruments: {others}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for f in failures:
        print(f"FAIL: {f}")
    if not failures:
        print("PASS: backup --st pasted, compiled, downloaded: B's backup equals A's, only the "
              "differing fields written")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
