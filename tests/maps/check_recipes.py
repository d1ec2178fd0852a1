#!/usr/bin/env python3
"""Checks the recipe parts of the ST blocks against maps/settings.py, the one description of
each instrument's settings.

    python3 tests/maps/check_recipes.py [--src st_src]

A block makes its download with MB_Recipe (st_src/MB_Sequence.st), one call per field in the
instrument's write order; MB_Recipe numbers the fields by that order (the number SettingsField
shows), so the order of the calls is the order of the numbers. For each recipe part below:
- the calls name, in order, the registers of settings.fields() (`Reg := REG.X`), every field
  once, and the last call (Close) the lock (or the MT-S9's Author level, access_register());
- each field's range (Lo, Hi; MB_Recipe's defaults 0..65535) is the map's raw range, its
  bounds evaluated from the block's VAR CONSTANTs and the fields of the shared constant
  structures it declares an instance of (`SC : FDC_SCALES`: `SC.DP_MAX`); a bound given as the recipe's own limits
  (lo, hi) is allowed only to a limit or a field the map puts within them; a field with a code
  table gives Known (and no other bound), and only such a field does;
- `Signed := TRUE` exactly on the fields whose register is signed;
- MB_LAST (MB_Types.st) gives the last index of MB_BITS, MB_REGS and MB_STEPS, and every
  recipe fits.
Exit 0 when all agree; 1 on any difference (a line each), or when a part is not found.
"""
from __future__ import annotations

import argparse
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "maps"))
import settings  # noqa: E402

# device -> (file, POU that makes the download, MB_Recipe instance, register prefix)
PARTS = {
    "mvd94": ("MVD_Recipe.st", "MVD_Recipe", "r", r"REG\."),
    "fdc100": ("FDC_Recipe.st", "FDC_Recipe", "r", r"REG\."),
    "mts9": ("Counter_MTS9.st", "Counter_MTS9", "recipe", r"MTS_REG_"),
}
OWN_LIMITS = {"lo", "hi"}          # the recipe's own limits, raw (a variable of the block)
COMMENT = re.compile(r"\(\*.*?\*\)", re.S)


def pou(src: str, name: str) -> str:
    m = re.search(rf"\bFUNCTION_BLOCK\s+{name}\b(.*?)\bEND_FUNCTION_BLOCK\b", src, re.S)
    return m.group(1) if m else ""


def constants(body: str) -> dict:
    out = {}
    for block in re.findall(r"\bVAR\s+CONSTANT\b(.*?)\bEND_VAR\b", body, re.S):
        for name, value in re.findall(r"(\w+)\s*:\s*\w+\s*:=\s*([^;]+);", block):
            out[name.upper()] = value.strip()
    return out


def struct_constants(src_dir: str, body: str) -> dict:
    """`INST.FIELD` -> initialiser, for each instance the block declares of a structure of
    st_src (`SC : FDC_SCALES;` gives SC.DP_MAX, SC.OFFSET, ...)."""
    text = " ".join(COMMENT.sub(" ", open(os.path.join(src_dir, f), encoding="utf-8").read())
                    for f in sorted(os.listdir(src_dir)) if f.endswith(".st"))
    structs = {n.upper(): b for n, b in re.findall(r"\b(\w+)\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b",
                                                   text, re.S)}
    out = {}
    for inst, typ in re.findall(r"\b(\w+)\s*:\s*(\w+)\s*;", body):
        fields = structs.get(typ.upper(), "")
        for name, value in re.findall(r"(\w+)\s*:\s*\w+\s*:=\s*([^;]+);", fields):
            out[f"{inst}.{name}".upper()] = value.strip()
    return out


def split_args(text: str) -> dict:
    args, depth, cur = [], 0, ""
    for ch in text:
        if ch == "," and depth == 0:
            args.append(cur)
            cur = ""
            continue
        depth += ch == "("
        depth -= ch == ")"
        cur += ch
    args.append(cur)
    out = {}
    for a in filter(str.strip, args):
        k, _, v = a.partition(":=")
        out[k.strip().upper()] = " ".join(v.split())
    return out


def calls(body: str, inst: str) -> list:
    """The arguments of each call `inst(...)` in order (a call may span lines)."""
    out = []
    for m in re.finditer(rf"(?<![\w.]){inst}\s*\(", body):
        depth, i = 1, m.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(body[i], 0)
            i += 1
        out.append(split_args(body[m.end():i - 1]))
    return out


def value(expr: str, consts: dict, seen=()):
    """An integer bound from a literal, a constant, -X or INT_TO_DINT(X); None for lo/hi; raise
    ValueError otherwise."""
    e = expr.strip()
    if e.lower() in OWN_LIMITS:
        return None
    m = re.fullmatch(r"\w+_TO_\w+\((.*)\)", e)
    if m:
        return value(m.group(1), consts, seen)
    if e.startswith("-"):
        v = value(e[1:], consts, seen)
        return None if v is None else -v
    if re.fullmatch(r"\d+", e):
        return int(e)
    m = re.fullmatch(r"16#([0-9A-Fa-f_]+)", e)
    if m:
        return int(m.group(1).replace("_", ""), 16)
    if e.upper() in consts and e.upper() not in seen:
        return value(consts[e.upper()], consts, seen + (e.upper(),))
    raise ValueError(f"bound {expr!r} is no number, constant or the recipe's lo/hi")


def check_part(device: str, src_dir: str) -> list:
    fname, name, inst, prefix = PARTS[device]
    path = os.path.join(src_dir, fname)
    body = pou(COMMENT.sub(" ", open(path, encoding="utf-8").read()), name)
    where = f"{os.path.relpath(path, ROOT)} {name}"
    if not body:
        return [f"{where}: FUNCTION_BLOCK not found"]
    consts = {**struct_constants(src_dir, body), **constants(body)}
    cs = [c for c in calls(body, inst) if "CLEAR" not in c]
    fields = [s for s in settings.fields(device) if s.part != "lock"]
    lock = settings.access_register(device)
    bad = []
    if not cs or "CLOSE" not in cs[-1]:
        return bad + [f"{where}: no MB_Recipe call with Close (the lock) last"]
    close, cs = cs[-1], cs[:-1]
    if len(cs) != len(fields):
        bad.append(f"{where}: {len(cs)} fields, maps/settings.py has {len(fields)}")
    for n, (c, s) in enumerate(zip(cs, fields), start=1):
        at = f"{where}: field {n}"
        reg = re.fullmatch(prefix + r"(\w+)", c.get("REG", ""))
        if not reg or reg.group(1) != s.field:
            bad.append(f"{at}: Reg := {c.get('REG')}, the write order has {s.field} "
                       f"(maps/settings.py: {', '.join(f.field for f in fields)})")
            break                  # the rest follows from it
        bad += check_field(f"{at} ({s.field})", c, s.raw_range, s.codes, s.reg.signed,
                           bool(s.within) or s.part == "limit", consts)
    want = lock[0] if lock else None
    reg = re.fullmatch(prefix + r"(\w+)", close.get("REG", ""))
    if want is None or not reg or reg.group(1) != settings.field_name(want):
        bad.append(f"{where}: the lock (Close) is {close.get('REG')}, the map's is "
                   f"{want.name if want else 'none'}")
    elif lock[2] == "lock":
        s = settings.by_field(device)[settings.field_name(want)]
        bad += check_field(f"{where}: the lock ({s.field})", close, s.raw_range, s.codes,
                           s.reg.signed, False, consts)
    return bad


def check_field(at, c, raw_range, codes, signed, own_ok, consts) -> list:
    bad = []
    if ("KNOWN" in c) != (codes is not None):
        bad.append(f"{at}: Known {'missing: a code table' if codes else 'given without a code table'}")
    if ("SIGNED" in c and c["SIGNED"].upper() == "TRUE") != signed:
        bad.append(f"{at}: Signed := TRUE {'missing: the register is signed' if signed else 'on an unsigned register'}")
    try:
        lo, hi = (value(c.get(k, d), consts) for k, d in (("LO", "0"), ("HI", "65535")))
    except ValueError as err:
        return bad + [f"{at}: {err}"]
    if (lo is None or hi is None) and not own_ok:
        bad.append(f"{at}: bounded by the recipe's lo/hi, but the map puts it within no limits")
    if codes is not None:
        if ("LO" in c or "HI" in c) and (lo, hi) != (0, 65535):
            bad.append(f"{at}: a code field bounded by Lo/Hi as well as Known")
        return bad
    for got, want, what in ((lo, raw_range[0], "Lo"), (hi, raw_range[1], "Hi")):
        if got is not None and got != want:
            bad.append(f"{at}: {what} {got}, the map's raw range is {raw_range[0]}..{raw_range[1]}")
    return bad


def check_last(src_dir: str) -> list:
    types = COMMENT.sub(" ", open(os.path.join(src_dir, "MB_Types.st"), encoding="utf-8").read())
    bad = []
    last = re.search(r"\bMB_LAST\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b", types, re.S)
    got = dict(re.findall(r"(\w+)\s*:\s*INT\s*:=\s*(\d+)\s*;", last.group(1))) if last else {}
    for field, arr in (("BITS", "MB_BITS"), ("REGS", "MB_REGS"), ("STEPS", "MB_STEPS")):
        m = re.search(rf"\b{arr}\s*:\s*ARRAY\s*\[\s*0\s*\.\.\s*(\d+)\s*\]", types)
        if not m or got.get(field) != m.group(1):
            bad.append(f"st_src/MB_Types.st: MB_LAST.{field} = {got.get(field)}, {arr} ends at "
                       f"{m.group(1) if m else '?'}")
    longest = max(len([s for s in settings.fields(d) if s.part != "lock"]) for d in PARTS)
    if got.get("STEPS") and longest > int(got["STEPS"]) + 1:
        bad.append(f"st_src/MB_Types.st: MB_STEPS holds {int(got['STEPS']) + 1} steps, a recipe "
                   f"has {longest} fields")
    return bad


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default=os.path.join(ROOT, "st_src"))
    a = ap.parse_args(argv)
    bad = check_last(a.src)
    for dev in PARTS:
        bad += check_part(dev, a.src)
    for b in bad:
        print(b)
    if not bad:
        n = sum(len(settings.fields(d)) for d in PARTS)
        print(f"{len(PARTS)} recipe parts ({n} fields) agree with maps/settings.py")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
