#!/usr/bin/env python3
"""Every FOR loop in st_src/*.st has literal or named-constant bounds.

A named constant: a VAR CONSTANT of the file, or a field of one of MB_Types.st's shared
constant structures (MB_LAST: LAST.STEPS) read through an instance the file declares
(`LAST : MB_LAST;`), the fields initialised and only read ("Shared constants").

Upstream matiec since commit 8a06b3b (2024-06) compiles `FOR i := a TO b` so that it runs zero
times when b = a (tools/matiec/README.md); OpenPLC's matiec does not. A bound computed at run
time (`NRef - 1`) can equal the start, so the blocks keep such loops out: constant bounds and an
IF inside. Exit 0 when every loop qualifies (and at least one loop was found), 1 otherwise.
"""
import glob
import os
import re
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, os.path.join(ROOT, "v4"))
from translate import st_spans  # noqa: E402  (the project's ST lexer: comments, pragmas, strings)

FOR = re.compile(r"\bFOR\s+\w+\s*:=\s*(.+?)\s+TO\s+(.+?)(?:\s+BY\s+(.+?))?\s+DO\b", re.S | re.I)
CONSTANTS = re.compile(r"\bVAR(?:_GLOBAL)?\s+CONSTANT\b(.*?)\bEND_VAR\b", re.S | re.I)
LITERAL = re.compile(r"-?\d+")
SHARED = ("MB_LAST", "MB_SHIM_CODES", "MB_ERROR_IDS", "MB_FUNCTION_CODES")


def shared_fields():
    """{struct: {field}} of the shared constant structures in MB_Types.st (initialised fields)."""
    src = open(os.path.join(ROOT, "st_src", "MB_Types.st"), encoding="utf-8").read()
    out = {}
    for m in re.finditer(r"\b(\w+)\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b", src, re.S):
        if m.group(1) in SHARED:
            out[m.group(1)] = {f.upper() for f in re.findall(r"(\w+)\s*:\s*\w+\s*:=", m.group(2))}
    return out


def main() -> int:
    bad, loops = [], 0
    fields = shared_fields()
    for path in sorted(glob.glob(os.path.join(ROOT, "st_src", "*.st"))):
        src = open(path, encoding="utf-8").read()
        text = "".join(src[i:j] if kind in ("code", "string") else "\n" * src.count("\n", i, j)
                       for kind, i, j in st_spans(src))  # comments and pragmas out, lines kept
        names = {m.group(1).upper() for block in CONSTANTS.findall(text)
                 for m in re.finditer(r"(\w+)\s*:", block)}
        for inst, typ in re.findall(r"\b(\w+)\s*:\s*(\w+)\s*;", text):
            if typ in fields:
                names |= {f"{inst.upper()}.{f}" for f in fields[typ]}
        for m in FOR.finditer(text):
            loops += 1
            line = text.count("\n", 0, m.start()) + 1
            for bound in filter(None, m.groups()):
                b = bound.strip()
                if not (LITERAL.fullmatch(b) or b.upper() in names):
                    bad.append(f"{os.path.relpath(path, ROOT)}:{line}: FOR bound '{b}' is not a constant")
    for b in bad:
        print(b)
    if loops == 0:
        print("no FOR loop found in st_src/*.st: the check would pass empty")
        return 1
    print(f"{loops} FOR loops, {len(bad)} with a bound that is not a constant")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
