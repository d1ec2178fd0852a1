#!/usr/bin/env python3
"""The settings of each instrument, described once from maps/<device>.json: what a recipe holds
(the ST types MVD94_SETTINGS, FDC_SETTINGS, MTS9_SETTINGS), how each field is scaled and checked,
and the order the instrument needs them written in.

    import settings
    for s in settings.fields("fdc100"):            # in write order
        s.field, s.st_type, s.raw_range, s.part     # 'SP1', 'REAL', (0, 65535), ''
    raw = settings.to_raw("mvd94", {"SV": 120.0, "DP": 0x11, ...})   # field -> raw, checked
    text = settings.st_initial("mvd94", values)     # '(A1FU := 48, ...)': a recipe to paste

    python3 maps/settings.py --out st_src/MB_Settings.st     # write the ST types
    python3 maps/settings.py --check st_src/MB_Settings.st   # exit 1 when stale (ctest settings.types)

Which registers (the rule, from the map's grades; the facts it needs are keys of each register
in the JSON, maps/README.md "Fields"):
- in a recipe: access exactly RW, read by FC03 and written by FC06 or FC16, confidence H or M
  (M-H), and `recipe` none of line (the unit would leave its line), no (a count, a command,
  factory data), author (the MT-S9's access level, raised and put back by whoever writes);
- left out: confidence L (the encoding is a guess: a recipe would write a wrong value with
  confidence), RW only under a condition (FDC MV1/MV2 in manual mode, calibration after CMND),
  and the line / no / author registers. left_out() lists each with its reason.
ST type: REAL where the map's scale has decimals or an offset (set points, hysteresis, PB...),
UINT / INT (DINT for two words) by the register's sign for plain numbers and index codes (the
raw code: a structure initialiser cannot hold an enumeration value in matiec).
Write order: `first` (input type, unit, decimal point, FDC ALFN: what scales the others), then
`limit` (the limits the set points lie within), then the others, all by address; the lock
(`lock`) is opened (`unlocked`) before all of them and written last.
Python standard library only.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
from dataclasses import dataclass

HERE = os.path.dirname(os.path.abspath(__file__))
STREF = os.path.join(os.path.dirname(HERE), "tools", "stref")  # generated.py
sys.path.insert(0, HERE)
import mbmap  # noqa: E402

ORDER = {"first": 0, "limit": 1, "": 2, "lock": 3}
NOT_IN_RECIPE = {"line": "set the line, the unit would leave it", "no": "no settings (a count, "
                 "a command, factory data)", "author": "the access level, raised and put back "
                 "by the writer"}
# IEC 61131-3 keywords a field may not be named (st_field in the map gives another name).
KEYWORDS = {"TYPE", "END_TYPE", "STRUCT", "VAR", "AT", "BY", "DO", "IF", "OF", "ON", "OR", "TO",
            "AND", "MOD", "NOT", "XOR", "FOR", "END", "CASE", "ELSE", "EXIT", "THEN", "TRUE",
            "FALSE", "WHILE", "REPEAT", "UNTIL", "RETURN", "ARRAY", "STEP", "TASK", "TIME",
            "DATE", "STRING", "REAL", "INT", "UINT", "DINT", "WORD", "BOOL", "BYTE", "CONSTANT"}


class SettingError(ValueError):
    """A recipe value that cannot be written: .field names it (ErrorID 202 in the blocks)."""

    def __init__(self, field: str, text: str):
        super().__init__(f"{field}: {text}")
        self.field = field


@dataclass(frozen=True)
class Setting:
    """One field of a device's settings structure."""
    field: str                     # ST field name
    reg: mbmap.Register
    st_type: str                   # REAL, UINT, INT, DINT
    part: str                      # "first", "limit", "" (an ordinary one), "lock"
    raw_range: tuple               # raw (lo, hi) accepted on a write
    codes: tuple | None            # the raw codes allowed (index-code registers)
    within: tuple                  # fields (limits) a set point must lie within

    @property
    def scaled(self) -> bool:
        return self.st_type == "REAL"


def _type_range(r) -> tuple:
    bits = 16 * r.words
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if r.signed else (0, (1 << bits) - 1)


def field_name(r) -> str:
    return r.st_field or mbmap.st_name(r.name)


def _st_type(m, r) -> str:
    sc = m.data["scales"][r.scale]
    dec, off = sc.get("decimals"), sc.get("offset", 0)
    if dec not in (None, 0) or off:
        return "REAL"
    if r.words == 2:
        return "DINT"
    return "INT" if r.signed else "UINT"


def _why_not(r) -> str | None:
    """Why a register is no recipe field (None: it is one)."""
    if "W" not in r.access:
        return "read only"
    if r.access != "RW":
        return f"writable only {r.access[3:]}"
    if r.recipe in NOT_IN_RECIPE:
        return NOT_IN_RECIPE[r.recipe]
    if r.confidence.startswith("L"):
        return "confidence L, its encoding a guess"
    if 3 not in r.fc or not ({6, 16} & set(r.fc)):
        return "not read by FC03 and written by FC06/FC16"
    return None


def fields(device: str) -> list:
    """The settings of a device ('mvd94', 'vd', 'fdc100', 'mts9'), in write order."""
    m = mbmap.load(device)
    out = []
    for r in m.registers:
        if _why_not(r) is not None:
            continue
        name = field_name(r)
        if name in KEYWORDS or not re.fullmatch(r"[A-Z][A-Z0-9_]*", name) or "__" in name:
            raise mbmap.MapError(f"{m.device}: {r.name} gives the field {name!r}, no ST "
                                 "identifier: give the register an st_field")
        codes = tuple(sorted(m.table(r.codes).values())) if r.codes else None
        span = r.range or ((codes[0], codes[-1]) if codes else _type_range(r))
        out.append(Setting(name, r, _st_type(m, r), r.recipe, span, codes,
                           tuple(field_name(m.reg(w)) for w in r.within)))
    out.sort(key=lambda s: (ORDER[s.part], s.reg.addr))
    names = [s.field for s in out]
    if sorted(names) != sorted(names, key=str.lower):
        raise mbmap.MapError(f"{m.device}: field names sort differently with and without case")
    return out


def left_out(device: str) -> list:
    """[(register name, why)] of the writable registers that are no recipe field."""
    m = mbmap.load(device)
    return [(r.name, _why_not(r)) for r in m.registers if "W" in r.access and _why_not(r)]


def left_out_text(device: str) -> str:
    """left_out() grouped by reason: 'FILT, CH01: confidence L, ...; ADDR, BAUD: ...'."""
    why = {}
    for n, w in left_out(device):
        why.setdefault(w, []).append(n)
    return "; ".join(f"{', '.join(ns)}: {w}" for w, ns in why.items())


def restorable(device: str) -> list:
    """The registers a raw restore (mbcommission) writes, in write order: every plain RW
    register but the line, no-setting, lock and author ones (confidence L included: a raw copy
    from a unit of the same model needs no encoding)."""
    m = mbmap.load(device)
    regs = [r for r in m.registers if r.access == "RW" and r.recipe in ("", "first", "limit")
            and 3 in r.fc]
    return sorted(regs, key=lambda r: (ORDER[r.recipe], r.addr))


def access_register(device: str):
    """(register, unlocked code, kind) of the lock ('lock') or access level ('author'), or None."""
    for r in mbmap.load(device).registers:
        if r.recipe in ("lock", "author"):
            return r, r.unlocked, r.recipe
    return None


def type_name(device: str) -> str:
    return mbmap.load(device).data["settings_type"]


def by_field(device: str) -> dict:
    return {s.field: s for s in fields(device)}


# ----- values: engineering (REAL) or raw (codes, numbers) <-> raw words -----
def _state(device: str, raw: dict) -> dict:
    """The registers the others scale with (the 'first' part), raw, by register name."""
    return {s.reg.name: raw[s.field] for s in fields(device) if s.part == "first" and s.field in raw}


def from_raw(device: str, raw_by_reg: dict) -> dict:
    """field -> value from raw register values by register name (a backup's)."""
    m = mbmap.load(device)
    state = {s.reg.name: raw_by_reg[s.reg.name] for s in fields(device)
             if s.part == "first" and s.reg.name in raw_by_reg}
    out = {}
    for s in fields(device):
        raw = raw_by_reg[s.reg.name]
        if s.scaled:
            dec, _ = m.scaling(s.reg, state)
            out[s.field] = round(m.to_eng(s.reg, raw, state), dec)
        else:
            out[s.field] = int(raw)
    return out


def to_raw(device: str, values: dict) -> dict:
    """field -> raw of a whole recipe, each checked against its range (and a set point against
    the recipe's own limits), scaled with the recipe's own input type and decimal point.
    SettingError names the first field that fails (in write order)."""
    m = mbmap.load(device)
    fs = fields(device)
    missing = [s.field for s in fs if s.field not in values]
    if missing:
        raise SettingError(missing[0], f"missing (a recipe gives every field: {', '.join(missing)})")
    unknown = sorted(set(values) - {s.field for s in fs})
    if unknown:
        raise SettingError(unknown[0], f"no field of {type_name(device)}")
    raw = {}
    for s in fs:
        v = values[s.field]
        if s.scaled:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise SettingError(s.field, f"{v!r} is no number")
            r = m.from_eng(s.reg, float(v), _state(device, raw))
        else:
            if isinstance(v, bool) or not isinstance(v, int):
                raise SettingError(s.field, f"{v!r} is no whole number ({s.st_type})")
            r = v
        lo, hi = s.raw_range
        if s.codes is not None and r not in s.codes:
            raise SettingError(s.field, f"{r} is no code of table {s.reg.codes}")
        if not lo <= r <= hi:
            dec, off = m.scaling(s.reg, _state(device, raw))
            span = f"{(lo - off) / 10 ** dec:g}..{(hi - off) / 10 ** dec:g}" if s.scaled else f"{lo}..{hi}"
            raise SettingError(s.field, f"{v} outside {span}")
        for_lim = [raw.get(w) for w in s.within]
        if len(for_lim) == 2 and None not in for_lim and not for_lim[0] <= r <= for_lim[1]:
            raise SettingError(s.field, f"{v} outside {s.within[0]}..{s.within[1]}")
        raw[s.field] = r
    return raw


# ----- ST text: a recipe as the structure's initial value, and back -----
def st_literal(s: Setting, value, decimals: int = 1) -> str:
    if s.scaled:
        return f"{float(value):.{max(1, decimals)}f}"
    if s.codes is not None:
        return f"16#{int(value):02X}"
    return str(int(value))


def st_initial(device: str, values: dict, width: int = 96) -> str:
    """The structure's initial value, fields in alphabetical order: '(A1FU := 16#30, ...)'.
    Not checked (a backup may hold what the map calls out of range: to_raw says so on restore)."""
    m = mbmap.load(device)
    fs = by_field(device)
    state = {s.reg.name: int(values[f]) for f, s in fs.items() if s.part == "first"}
    parts = [f"{f} := {st_literal(fs[f], values[f], m.scaling(fs[f].reg, state)[0])}"
             for f in sorted(fs)]
    lines, cur = [], "("
    for i, p in enumerate(parts):
        p += ", " if i < len(parts) - 1 else ")"
        if len(cur) + len(p) > width and cur.strip("( "):
            lines.append(cur.rstrip())
            cur = " "
        cur += p
    return "\n".join(lines + [cur])


NUMBER = re.compile(r"^[+-]?(?:(?:2|8|16)#[0-9A-Fa-f_]+|\d[\d_]*(?:\.\d[\d_]*)?(?:[eE][+-]?\d+)?)$")


def parse_initial(device: str, text: str) -> dict:
    """field -> value of an initial value ('(F := v, ...)', alone or in a declaration
    'X : MVD94_SETTINGS := (...);'); comments allowed. SettingError on anything else."""
    body = re.sub(r"\(\*.*?\*\)", " ", text, flags=re.S)
    lo, hi = body.find("("), body.rfind(")")
    if lo < 0 or hi < lo:
        raise SettingError("(", f"no '( FIELD := value, ... )' of {type_name(device)}")
    head = body[:lo].strip()
    if head and not re.fullmatch(rf"(?:\w+\s*:\s*)?{type_name(device)}\s*:=", head, re.I):
        raise SettingError(head.split()[0], f"expected a {type_name(device)} initial value")
    fs, out = by_field(device), {}
    for item in filter(None, (x.strip() for x in body[lo + 1:hi].split(","))):
        mm = re.fullmatch(r"(\w+)\s*:=\s*(\S+)", item)
        if not mm:
            raise SettingError(item, "expected FIELD := value")
        name, lit = mm.group(1).upper(), mm.group(2).replace("_", "")
        lit = re.sub(r"^([+-]?)[A-Za-z]+#", r"\1", lit)     # a typed literal: REAL#1.5, UINT#16#30
        if name not in fs:
            raise SettingError(name, f"no field of {type_name(device)}")
        if name in out:
            raise SettingError(name, "given twice")
        if not NUMBER.match(lit):
            raise SettingError(name, f"{mm.group(2)} is no number")
        sign = -1 if lit.startswith("-") else 1
        lit = lit.lstrip("+-")
        if "#" in lit:
            base, digits = lit.split("#")
            v = sign * int(digits, int(base))
        elif "." in lit or "e" in lit.lower():
            v = sign * float(lit)
        else:
            v = sign * int(lit)
        if fs[name].scaled:
            v = float(v)
        elif isinstance(v, float):
            raise SettingError(name, f"{mm.group(2)}: {fs[name].st_type} takes a whole number")
        out[name] = v
    return out


# ----- the ST types -----
def _describe(m, s: Setting, rank: int) -> str:
    r = s.reg
    bits = [f"0x{r.addr:04X}"]
    if s.scaled:
        bits.append(f"{r.unit or 'eng'}, scale {r.scale}")
    elif s.codes is not None:
        bits.append(f"code, table {r.codes}")
    elif r.unit:
        bits.append(r.unit)
    bits.append(f"raw {s.raw_range[0]}..{s.raw_range[1]}")
    if s.within:
        bits.append(f"within {s.within[0]}..{s.within[1]}")
    bits.append(f"written {rank}" if s.part != "lock" else "opened first, written last")
    return "; ".join(bits)


def render() -> str:
    out = ["(* MB_Settings.st - the settings of each instrument in engineering units, one structure",
           "   per device: what a recipe holds, what the device blocks publish and download.",
           "   Generated by maps/settings.py from maps/*.json: do not edit (ctest settings.types fails",
           "   when it is stale). Fields in alphabetical order ON PURPOSE (matiec, see MB_LINE).",
           "   REAL: engineering units, scaled as the map's scale with the device's own decimal point",
           "   and input type; UINT/INT: the raw number or index code. Each field's comment: address;",
           "   unit and scale or code table; raw range a write must lie in; its place in the write",
           "   order. *)",
           "TYPE"]
    for dev in ("mvd94", "fdc100", "mts9"):
        m = mbmap.load(dev)
        fs = fields(dev)
        rank = {s.field: i + 1 for i, s in enumerate(fs)}
        order = ", ".join(s.field for s in fs)
        left = left_out_text(dev)
        out.append(f"  (* {m.data['title']} ({dev}.json).")
        out += wrap(f"Write order: {order}.", "     ")
        out += wrap(f"Left out: {left}. *)", "     ")
        out.append(f"  {type_name(dev)} : STRUCT")
        width = max(len(s.field) + len(s.st_type) for s in fs) + 3
        for s in sorted(fs, key=lambda s: s.field):
            decl = f"{s.field} : {s.st_type};"
            out.append(f"    {decl:<{width + 1}} (* {_describe(m, s, rank[s.field])} *)")
        out.append("  END_STRUCT;")
    out.append("END_TYPE")
    return "\n".join(out) + "\n"


def wrap(text: str, indent: str, width: int = 98) -> list:
    lines, cur = [], indent
    for word in text.split(" "):
        if len(cur) + len(word) + 1 > width and cur.strip():
            lines.append(cur.rstrip())
            cur = indent
        cur += word + " "
    return lines + [cur.rstrip()]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="write the ST types here (default: standard output)")
    ap.add_argument("--check", metavar="FILE", help="exit 1 if FILE differs from what would be written")
    args = ap.parse_args(argv)
    sys.path.insert(0, STREF)
    from generated import generate  # the command line of every generated file
    return generate("settings", render, mbmap.MapError, out=args.out, check=args.check,
                    hint="python3 maps/settings.py --out it")


if __name__ == "__main__":
    sys.exit(main())
