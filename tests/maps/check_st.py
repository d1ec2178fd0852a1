#!/usr/bin/env python3
"""Checks the ST blocks' named constants against the register maps (rule: maps/README.md,
"Constants in ST").

    python3 tests/maps/check_st.py [FILE_OR_DIR ...]   # default: st_src/ of this checkout

Every `VAR CONSTANT` / `VAR_GLOBAL CONSTANT` entry whose name starts with MVD_, MTS_ or FDC_
must equal what its device's map says: a number, or an array <P>_<TABLE>_BY_CODE whose
elements are the table's (numeric) labels by code. So must every field of a structure type
named <P>_REGISTERS (TYPE ... STRUCT): field X is the address of register X (checked as the
constant <P>_REG_X; INPUT_TYPE names TYPE, an ST keyword). So must every label of a CASE table
that names its codes: a label line `22, 56: ... (* MVD_AFU_NONE, MVD_AFU_NONE38 ... *)` gives
its labels (decimal literals: matiec takes no named constant there) the names in the comment
that ends the line, one name per label, checked as those constants would be; in a FUNCTION
named <P>_DECODE_<X> every label line must name its codes. Exit 0 when all agree; 1 on any
difference, on a prefixed constant the rule does not know, on a decoder's label without a name,
or when no prefixed constant is found at all (so the check cannot pass empty); 2 on bad
arguments or an unreadable map.
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))  # tests/maps -> the checkout
MAPS = os.path.join(ROOT, "maps")
sys.path.insert(0, MAPS)
import mbmap  # noqa: E402

PREFIXES = {"MVD": "mvd94", "MTS": "mts9", "FDC": "fdc100"}
COMMENT = re.compile(r"\(\*.*?\*\)|//[^\n]*", re.S)
BLOCK = re.compile(r"\bVAR(?:_GLOBAL)?\s+CONSTANT\b(.*?)\bEND_VAR\b", re.S | re.I)
ENTRY = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*:\s*([A-Za-z_][A-Za-z0-9_]*)\s*:=\s*([^;]+);")
ARRAY = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*:\s*ARRAY\s*\[\s*([^\].]+?)\s*\.\.\s*([^\]]+?)\s*\]"
                   r"\s*OF\s*[A-Za-z_][A-Za-z0-9_]*\s*:=\s*\[([^\]]*)\]\s*;", re.I)
BY_CODE = "_BY_CODE"     # <P>_<TABLE>_BY_CODE: an array, element [code] = the code's label
CODE_ALIAS = "CODE_"     # <P>_<TABLE>_CODE_<LABEL>: <P>_<TABLE>_<LABEL> when an enum value has that name
FC_MAX = re.compile(r"FC0?(\d+)_MAX_WORDS$")
TYPE_BLOCK = re.compile(r"\bTYPE\b(.*?)\bEND_TYPE\b", re.S)
REGISTERS = re.compile(r"\b([A-Za-z]+)_REGISTERS\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b", re.S | re.I)
FIELD_ALIASES = {"INPUT_TYPE": "TYPE"}   # a register named by an ST keyword
CASE_BLOCK = re.compile(r"\bCASE\b.*?\bOF\b(.*?)\bEND_CASE\b", re.S)
CASE_LABELS = re.compile(r"^[ \t]*(-?\d+(?:[ \t]*,[ \t]*-?\d+)*)[ \t]*:(?!=)", re.M)
CASE_NAMES = re.compile(r"\(\*\s*([A-Za-z]+_\w+(?:\s*,\s*[A-Za-z]+_\w+)*)")
FUNCTION = re.compile(r"\bFUNCTION\s+([A-Za-z_]\w*)\b(.*?)\bEND_FUNCTION\b", re.S)
DECODER = re.compile(r"([A-Za-z]+)_DECODE_\w+$")


def st_int(text: str) -> int:
    """An IEC integer literal: 123, -5, 16#FF, 2#1010, 8#17, UINT#16#10, 1_000."""
    t = text.strip().replace("_", "")
    neg = t.startswith("-")
    t = t.lstrip("+-")
    parts = t.split("#")
    if len(parts) == 3:                     # TYPE#BASE#DIGITS
        parts = parts[1:]
    if len(parts) == 2 and not parts[0].isdigit():   # TYPE#DIGITS
        parts = [parts[1]]
    value = int(parts[1], int(parts[0])) if len(parts) == 2 else int(parts[0], 10)
    return -value if neg else value


def constants(paths):
    """(file, line, name, value text) of every constant in the VAR CONSTANT blocks; the value
    text of an array is (low bound, high bound, [element texts])."""
    out = []
    for path in paths:
        with open(path, encoding="utf-8", errors="replace") as fh:
            src = fh.read()
        clean = COMMENT.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), src)
        for block in BLOCK.finditer(clean):
            for e in ENTRY.finditer(block.group(1)):
                line = clean.count("\n", 0, block.start(1) + e.start()) + 1
                out.append((path, line, e.group(1), e.group(3).strip()))
            for a in ARRAY.finditer(block.group(1)):
                line = clean.count("\n", 0, block.start(1) + a.start()) + 1
                out.append((path, line, a.group(1),
                            (a.group(2), a.group(3), [x.strip() for x in a.group(4).split(",")])))
        for tb in TYPE_BLOCK.finditer(clean):
            for st in REGISTERS.finditer(tb.group(1)):
                for e in ENTRY.finditer(st.group(2)):
                    line = clean.count("\n", 0, tb.start(1) + st.start(2) + e.start()) + 1
                    field = FIELD_ALIASES.get(e.group(1).upper(), e.group(1))
                    out.append((path, line, f"{st.group(1)}_REG_{field}", e.group(3).strip()))
    return out


def case_labels(paths):
    """The named labels of the CASE tables: ([(file, line, name, label text)], [(file, line,
    problem)]): a label line whose comment names a different number of codes than it has
    labels, or a label line of a <P>_DECODE_ function that names none."""
    out, problems = [], []
    for path in paths:
        with open(path, encoding="utf-8", errors="replace") as fh:
            src = fh.read()
        clean = COMMENT.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), src)
        decoders = [(f.start(2), f.end(2)) for f in FUNCTION.finditer(clean)
                    if DECODER.match(f.group(1)) and DECODER.match(f.group(1)).group(1).upper() in PREFIXES]
        for block in CASE_BLOCK.finditer(clean):
            for lab in CASE_LABELS.finditer(block.group(1)):
                at = block.start(1) + lab.start()
                line = clean.count("\n", 0, at) + 1
                eol = src.find("\n", at)
                names = CASE_NAMES.search(src[at:len(src) if eol < 0 else eol])
                labels = [x.strip() for x in lab.group(1).split(",")]
                if names is None:
                    if any(a <= at < b for a, b in decoders):
                        problems.append((path, line, f"CASE label {lab.group(1)} of a decoder names no "
                                         "code: end its line with (* <P>_<TABLE>_<LABEL> *)"))
                    continue
                named = [x.strip() for x in names.group(1).split(",")]
                if len(named) != len(labels):
                    problems.append((path, line, f"CASE labels {labels} named {named}: one name per label"))
                    continue
                out += [(path, line, n, v) for n, v in zip(named, labels)]
    return out, problems


def expected(m, rest: str):
    """What the map says for a constant name without its prefix: (value, what) or KeyError."""
    if rest.startswith("REG_"):
        name = rest[4:]
        for r in m.registers:
            if name in (mbmap.st_name(n) for n in (r.name, *r.aliases)):
                return r.addr, f"address of {r.name}"
        raise KeyError(f"{m.device} has no register named {name} (names as in the map, "
                       "'_' for other characters)")
    fc = FC_MAX.match(rest)
    if fc:
        f = m.function(int(fc.group(1)))
        if "max_words" not in f:
            raise KeyError(f"FC{int(fc.group(1)):02d} has no max_words in {m.device}.json")
        return f["max_words"], f"FC{int(fc.group(1)):02d} max_words"
    for kind, key in (("OFFSET_", "offset"), ("DEC_", "decimals")):
        if rest.startswith(kind):
            sc = m.data["scales"].get(rest[len(kind):])
            if sc is None or not isinstance(sc.get(key, 0), int):
                raise KeyError(f"no scale {rest[len(kind):]} with a fixed {key} in {m.device}.json")
            return sc.get(key, 0), f"{key} of scale {rest[len(kind):]}"
    for table in sorted(m.tables, key=len, reverse=True):
        if rest == table + BY_CODE and "codes" in m.tables[table]:
            return by_code(m, table)
        if rest.startswith(table + "_") and "codes" in m.tables[table]:
            label = rest[len(table) + 1:]
            exact = [v for k, v in m.table(table).items() if mbmap.st_name(k) == label]
            if not exact and label.startswith(CODE_ALIAS):
                label = label[len(CODE_ALIAS):]
                exact = [v for k, v in m.table(table).items() if mbmap.st_name(k) == label]
            if not exact:
                raise KeyError(f"table {table} has no label {label} (labels as in the map, "
                               "'_' for other characters)")
            value = exact[0]
            if not isinstance(value, int):
                raise KeyError(f"table {table} entry {label} is not a number")
            return value, f"{table} code {m.label(table, value)}"
    raise KeyError("not a register (REG_), table code, <TABLE>_BY_CODE, FCnn_MAX_WORDS, "
                   "OFFSET_ or DEC_ name")


def by_code(m, table: str):
    """What an array <P>_<TABLE>_BY_CODE must hold: (low code, [label of each code from low
    to high]); the table's codes must be consecutive numbers, its labels numbers."""
    codes = m.table(table)
    by = {v: k for k, v in codes.items()}
    if not all(isinstance(v, int) for v in by) or sorted(by) != list(range(min(by), max(by) + 1)):
        raise KeyError(f"table {table}'s codes are not consecutive numbers")
    try:
        labels = [int(by[c]) for c in sorted(by)]
    except ValueError:
        raise KeyError(f"table {table}'s labels are not numbers") from None
    return (min(by), labels), f"{table} labels by code {min(by)}..{max(by)}"


def array_value(text):
    """(low bound, [elements]) of an array's (low, high, [element texts]); ValueError if the
    bounds do not match the number of elements."""
    low, high, items = text
    low, high, values = st_int(low), st_int(high), [st_int(x) for x in items]
    if high - low + 1 != len(values):
        raise ValueError(f"{len(values)} elements for [{low}..{high}]")
    return low, values


def check(paths, maps_dir=MAPS, out=sys.stdout) -> int:
    found = bad = 0
    labels, problems = case_labels(paths)
    for path, line, why in problems:
        print(f"{os.path.relpath(path)}:{line}: {why}", file=out)
        bad += 1
    for path, line, name, text in constants(paths) + labels:
        prefix, _, rest = name.partition("_")
        if prefix.upper() not in PREFIXES:
            continue
        found += 1
        where = f"{os.path.relpath(path)}:{line}: {name}"
        m = mbmap.load(PREFIXES[prefix.upper()], maps_dir)
        try:
            want, what = expected(m, rest.upper())
        except KeyError as err:
            print(f"{where}: unknown to {m.device}.json: {str(err).strip(chr(34))}", file=out)
            bad += 1
            continue
        if isinstance(text, tuple) != isinstance(want, tuple):
            print(f"{where}: {'an array' if isinstance(text, tuple) else 'a number'}, but "
                  f"{m.device}.json has {'an array' if isinstance(want, tuple) else 'a number'} "
                  f"for it ({what})", file=out)
            bad += 1
            continue
        try:
            value = array_value(text) if isinstance(text, tuple) else st_int(text)
        except ValueError as err:
            print(f"{where}: value {text!r} is not an integer literal ({err})", file=out)
            bad += 1
            continue
        if isinstance(value, tuple):          # an array: [first..] the values
            shown, ok = (lambda v: f"[{v[0]}..] {v[1]}"), f"{where}: ok ({what})"
        else:
            shown, ok = (lambda v: f"{v} (0x{v & 0xFFFF:04X})"), f"{where} = {value}: ok ({what})"
        if value != want:
            print(f"{where} = {shown(value)}, but {m.device}.json says {shown(want)} ({what})",
                  file=out)
            bad += 1
        else:
            print(ok, file=out)
    if found == 0:
        print("check_st: no MVD_/MTS_/FDC_ constant found in VAR CONSTANT blocks of "
              + ", ".join(os.path.relpath(p) for p in paths), file=out)
        return 1
    print(f"check_st: {found} constants, {bad} differ from the maps", file=out)
    return 1 if bad else 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("paths", nargs="*", help="ST files or folders (default: st_src/)")
    p.add_argument("--maps", default=MAPS, help="folder of the map files (default: maps/)")
    args = p.parse_args(argv)
    paths = []
    for item in args.paths or [os.path.join(ROOT, "st_src")]:
        if os.path.isdir(item):
            paths += sorted(glob.glob(os.path.join(item, "*.st")))
        elif os.path.isfile(item):
            paths.append(item)
        else:
            print(f"check_st: {item}: no such file or folder", file=sys.stderr)
            return 2
    try:
        return check(paths, args.maps)
    except mbmap.MapError as err:
        print(f"check_st: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
