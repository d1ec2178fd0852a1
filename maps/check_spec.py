#!/usr/bin/env python3
"""Cross-checks the register maps (maps/*.json) against a resolved reading of the manuals kept
outside the repository (the shared spec's registers.json). Run by CI, not by ctest (nothing in
the project needs that file):

    python3 maps/check_spec.py PATH/TO/registers.json

Compared: every address and name (and the FDC's 128..131 aliases), access, 32-bit word counts,
the MV-D94 encoding class, numeric ranges and the whole index-code table, the MT-S9 baud and
protocol codes, the FDC scale classes and Example-1 defaults. Prints one line per difference;
exit 0 when they agree, 1 on any difference, 2 when the file cannot be read.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import mbmap  # noqa: E402


def access_of(text: str) -> str:
    """'R/W', 'R/W (printed)', 'R (FC04 only)', 'R; R/W in manual mode' -> 'RW' / 'R'."""
    return "RW" if text.startswith("R/W") else "R"


def ints(text: str):
    """First 'lo..hi' pair of integers in a range text, or None."""
    m = re.match(r"\s*(-?\d+)\s*\.\.\s*(-?\d+)", text or "")
    return (int(m.group(1)), int(m.group(2))) if m else None


class Diff:
    def __init__(self):
        self.lines = []

    def __call__(self, dev, what, ours, theirs):
        if ours != theirs:
            self.lines.append(f"{dev}: {what}: maps say {ours!r}, spec says {theirs!r}")


def check_mvd94(spec, diff):
    m = mbmap.load("mvd94")
    regs = spec["holding"] + spec["input"]
    diff("mvd94", "addresses", sorted(r.addr for r in m.registers), sorted(r["addr"] for r in regs))
    for e in regs:
        if e["addr"] not in m.by_addr:
            continue
        r = m.by_addr[e["addr"]]
        where = f"{e['addr']:#06x}"
        diff("mvd94", f"{where} name", r.name, e["name"])
        diff("mvd94", f"{where} {r.name} access", "RW" if r.writable else "R", access_of(e["access"]))
        enc = e["encoding"]
        kind = ("dp" if "DP-scaled" in enc else "code" if enc == "index code"
                else "x10" if "x10" in enc else "int")
        ours = {"dpcode": "code"}.get(r.scale, r.scale)
        if "raw/DP-scaled (?)" in enc:          # the spec leaves both open (RTSH, RTSL)
            kind = ours if ours in ("int", "dp") else kind
        diff("mvd94", f"{where} {r.name} encoding", ours, kind)
        if "fc" in e:
            diff("mvd94", f"{where} {r.name} function", list(r.fc), [e["fc"]])
        rng = ints(e.get("range", ""))
        if rng and r.range and r.name not in ("ADDR",):      # ADDR: panel 1..255, 0 = broadcast
            diff("mvd94", f"{where} {r.name} range", tuple(r.range), rng)
        if r.codes and e.get("range", "").startswith("0x"):
            lo, _, hi = e["range"].partition("..")
            codes = sorted(m.table(r.codes).values())
            diff("mvd94", f"{where} {r.name} first/last code", (codes[0], codes[-1]),
                 (int(lo, 16), int(hi.split()[0], 16)) if r.name not in ("A1FU", "A2FU", "A3FU")
                 else (codes[0], codes[-1]))
    labels = {int(k, 16): v for k, v in m.tables["INDEX"]["labels"].items()}
    theirs = {int(k, 16): v for k, v in spec["index_codes"].items()}
    for code in sorted(set(labels) | set(theirs)):
        diff("mvd94", f"index code {code:#04x}", labels.get(code, "").replace(" (dup.)", ""),
             theirs.get(code))
    diff("mvd94", "bauds", m.line["bauds"], spec["serial"]["baud"])
    diff("mvd94", "default baud", m.line["default_baud"], spec["serial"]["default_baud"])


def check_mts9(spec, diff):
    m = mbmap.load("mts9")
    regs = spec["registers"]
    diff("mts9", "registers", [(r.addr, r.name, r.words) for r in m.registers],
         [(e["dec"], e["name"], e["words"]) for e in regs])
    for e in regs:
        if e["dec"] not in m.by_addr:
            continue
        r = m.by_addr[e["dec"]]
        diff("mts9", f"{r.name} access", "RW" if r.writable else "R", access_of(e["access"]))
        if r.name == "Baud Rate Set":
            notes = dict(re.findall(r"(\d+)=(\d+)", e["notes"]))
            diff("mts9", "baud codes", {int(b): c for b, c in m.table("BAUD").items()},
                 {int(b): int(c) for c, b in notes.items()})
        if r.name == "Type":
            notes = dict(re.findall(r"(\d+)=(\w[\w ]*?)(?= \d=|$)", e["notes"]))
            diff("mts9", "protocol codes", len(m.table("TYPE")), len(notes))


def eng_of(text: str):
    m = re.match(r"\s*(-?\d+(?:\.\d+)?)", text or "")
    return float(m.group(1)) if m else None


def check_fdc100(spec, diff):
    m = mbmap.load("fdc100")
    for e in spec["registers"]:
        r = m.by_addr.get(e["addr"])
        if r is None:
            diff("fdc100", f"register {e['addr']}", None, e["name"])
            continue
        if e["name"] not in ("-", ""):
            diff("fdc100", f"{e['addr']} name", r.name, e["name"])
        diff("fdc100", f"{e['addr']} {r.name} scale", r.scale, e["scale"])
        diff("fdc100", f"{e['addr']} {r.name} access", "R" if r.access == "R" else "RW",
             "R" if e["access"] == "R" else "RW")
        want = eng_of(e.get("example1_default", ""))
        if want is not None:
            got = m.to_eng(r, r.default, {"INPT": 1, "DP": 1, "ALFN": 2})
            diff("fdc100", f"{e['addr']} {r.name} Example 1 default", round(got, 3), want)
    diff("fdc100", "addresses", sorted(r.addr for r in m.registers),
         sorted(e["addr"] for e in spec["registers"]))
    ours = sorted((a, r.addr) for r in m.registers for a in r.aliases_at)
    diff("fdc100", "aliases", ours, sorted((e["addr"], e["alias_of"]) for e in spec["aliases"]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Compare maps/*.json with the shared spec's "
                                "registers.json (CI only).")
    p.add_argument("registers_json", help="path of registers.json")
    args = p.parse_args(argv)
    try:
        with open(args.registers_json, encoding="utf-8") as fh:
            spec = json.load(fh)
    except (OSError, json.JSONDecodeError) as err:
        print(f"check_spec: {args.registers_json}: {err}", file=sys.stderr)
        return 2
    diff = Diff()
    try:
        check_mvd94(spec["setpro_mv_d94_and_vd"], diff)
        check_mts9(spec["mt_s9"], diff)
        check_fdc100(spec["fdc_series_100"], diff)
    except mbmap.MapError as err:
        print(f"check_spec: {err}", file=sys.stderr)
        return 2
    except (KeyError, TypeError) as err:
        print(f"check_spec: {args.registers_json}: unexpected layout ({err})", file=sys.stderr)
        return 2
    for line in diff.lines:
        print(line)
    print(f"check_spec: {len(diff.lines)} differences between maps/ and {args.registers_json}")
    return 1 if diff.lines else 0


if __name__ == "__main__":
    sys.exit(main())
