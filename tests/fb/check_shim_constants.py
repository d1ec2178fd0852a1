#!/usr/bin/env python3
"""Checks the shim constants the ST blocks mirror against c_shims/include/mbfb.h.

    python3 tests/fb/check_shim_constants.py [--src st_src] [--header c_shims/include/mbfb.h]

A `VAR CONSTANT` entry named SHIM_<X> must equal `#define MBFB_<X>`, one named MB_E_<X> or E_<X>
must equal `#define MBFB_E_<X>`. An entry with such a name and no #define of that name fails too
(a constant renamed on one side only), and so does finding none at all. The matiec and STruC++
C code holds an ST constant as a variable set when the block starts, so the C compiler cannot
compare it (it does compare the sizes of the structures handed to the shims: MB_SHIM_DIAG,
MB_SNAP, the plan items, MB_REGS). Exit 0 when all agree, 1 otherwise (a line per difference).
"""
import argparse
import glob
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
COMMENT = re.compile(r"\(\*.*?\*\)", re.S)
BLOCK = re.compile(r"\bVAR\s+CONSTANT\b(.*?)\bEND_VAR\b", re.S)
ENTRY = re.compile(r"\b(SHIM_\w+|MB_E_\w+|E_\w+)\s*:\s*\w+\s*:=\s*([^;]+);")
DEFINE = re.compile(r"^#define\s+(MBFB_\w+)\s+(-?\d+)\b", re.M)


def st_int(text):
    t = text.strip().replace("_", "")
    if "#" in t:
        base, digits = t.split("#")[-2:]
        return int(digits, int(base)) if base.isdigit() else int(digits)
    return int(t)


def c_name(st_name):
    if st_name.startswith("SHIM_"):
        return "MBFB_" + st_name[len("SHIM_"):]
    if st_name.startswith("MB_E_"):
        return "MBFB_E_" + st_name[len("MB_E_"):]
    return "MBFB_" + st_name           # E_<X>


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default=os.path.join(ROOT, "st_src"))
    ap.add_argument("--header", default=os.path.join(ROOT, "c_shims", "include", "mbfb.h"))
    a = ap.parse_args()
    with open(a.header, encoding="utf-8") as fh:
        defines = {m.group(1): int(m.group(2)) for m in DEFINE.finditer(fh.read())}
    bad, n = [], 0
    for path in sorted(glob.glob(os.path.join(a.src, "*.st"))):
        with open(path, encoding="utf-8") as fh:
            src = COMMENT.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), fh.read())
        for block in BLOCK.finditer(src):
            for e in ENTRY.finditer(block.group(1)):
                n += 1
                line = src.count("\n", 0, block.start(1) + e.start()) + 1
                name, value, c = e.group(1), st_int(e.group(2)), c_name(e.group(1))
                where = f"{os.path.relpath(path, ROOT)}:{line}: {name} = {value}"
                if c not in defines:
                    bad.append(f"{where}: mbfb.h has no {c}")
                elif defines[c] != value:
                    bad.append(f"{where}: mbfb.h has {c} = {defines[c]}")
    if n == 0:
        bad.append(f"{a.src}: no SHIM_*, MB_E_* or E_* constant found")
    for b in bad:
        print(b)
    if not bad:
        print(f"{n} shim constants agree with {os.path.relpath(a.header, ROOT)}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
