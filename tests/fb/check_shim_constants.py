#!/usr/bin/env python3
"""Checks the shim constants the ST blocks mirror against c_shims/include/mbfb.h.

    python3 tests/fb/check_shim_constants.py [--src st_src] [--header c_shims/include/mbfb.h]

A `VAR CONSTANT` entry named SHIM_<X> must equal `#define MBFB_<X>`, one named MB_E_<X> or E_<X>
must equal `#define MBFB_E_<X>`; so must the fields of the shared constant structures of
MB_Types.st: MB_FUNCTION_CODES.<X> = MBFB_FC_<X>, MB_ERROR_IDS.<X> = MBFB_E_<X> (both must be
there). A VAR CONSTANT entry named after one of their fields (MB_FC_<X>, E_<X>) fails: those
are declared once, in the structure. An entry with such a name and no #define of that name fails too
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
TYPE_BLOCK = re.compile(r"\bTYPE\b(.*?)\bEND_TYPE\b", re.S)
STRUCT = re.compile(r"\b(\w+)\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b", re.S)
FIELD = re.compile(r"\b(\w+)\s*:\s*\w+\s*:=\s*([^;]+);")
SHARED = {"MB_FUNCTION_CODES": ("MBFB_FC_", "MB_FC_"), "MB_ERROR_IDS": ("MBFB_E_", "E_")}


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
    sources = {}
    for path in sorted(glob.glob(os.path.join(a.src, "*.st"))):
        with open(path, encoding="utf-8") as fh:
            sources[path] = COMMENT.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), fh.read())
    shared = {}                        # st constant name a field stands for -> its struct
    for path, src in sources.items():
        for tb in TYPE_BLOCK.finditer(src):
            for st in STRUCT.finditer(tb.group(1)):
                if st.group(1) not in SHARED:
                    continue
                prefix, st_prefix = SHARED[st.group(1)]
                for f in FIELD.finditer(st.group(2)):
                    n += 1
                    shared[st_prefix + f.group(1)] = st.group(1)
                    line = src.count("\n", 0, tb.start(1) + st.start(2) + f.start()) + 1
                    name, value, c = f"{st.group(1)}.{f.group(1)}", st_int(f.group(2)), prefix + f.group(1)
                    where = f"{os.path.relpath(path, ROOT)}:{line}: {name} = {value}"
                    if c not in defines:
                        bad.append(f"{where}: mbfb.h has no {c}")
                    elif defines[c] != value:
                        bad.append(f"{where}: mbfb.h has {c} = {defines[c]}")
    for struct in sorted(set(SHARED) - set(shared.values())):
        bad.append(f"{a.src}: no TYPE {struct} : STRUCT with initialised fields found")
    for path, src in sources.items():
        for block in BLOCK.finditer(src):
            for e in re.finditer(r"\b(\w+)\s*:\s*\w+\s*:=", block.group(1)):
                if e.group(1) in shared:
                    line = src.count("\n", 0, block.start(1) + e.start()) + 1
                    bad.append(f"{os.path.relpath(path, ROOT)}:{line}: {e.group(1)} declared again: "
                               f"use the field of {shared[e.group(1)]} (MB_Types.st)")
    for path, src in sources.items():
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
