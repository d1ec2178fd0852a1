#!/usr/bin/env python3
"""Writes the error table (docs/errors.md) from the one place the ids are defined: the
MBFB_OK / MBFB_E_* #defines of c_shims/include/mbfb.h and their comments.

    python3 tools/stref/errors.py [--header c_shims/include/mbfb.h] [--out docs/errors.md]
    python3 tools/stref/errors.py --check docs/errors.md        # exit 1 if it is stale

Exit codes: 0 written / up to date, 1 stale (--check), 2 bad input (one line on stderr).
"""
from __future__ import annotations

import argparse
import os
import re
import sys

from generated import generate  # the command line of every generated file

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFINE = re.compile(r"^#define\s+(MBFB_OK|MBFB_E_\w+)\s+(\d+)[ \t]*(?:/\*(.*?)\*/)?", re.M | re.S)
HEAD = """# Error ids

One table for the C shims (negative return values, request results) and every function block's
`ErrorID`: 1..63 communication and shim errors, 128 + x when the device answered with Modbus
exception x, 200..255 block input errors, found before anything is sent (nothing goes on the
wire). Which ids each block can give: [st_src/REFERENCE.md](../st_src/REFERENCE.md).

Generated from `c_shims/include/mbfb.h` by `tools/stref/errors.py` (ctest `error_table` fails
when this file is stale); edit the header, not this file.

| id | name | meaning |
|---|---|---|
"""


def rows(header_text: str) -> list:
    out = []
    for name, value, comment in DEFINE.findall(header_text):
        meaning = " ".join((comment or "").split())
        if name == "MBFB_E_EXCEPTION_BASE":
            out.append(("128+x", "exception x", "the device answered with Modbus exception x: 129 "
                        "illegal function, 130 illegal data address, 131 illegal data value, "
                        "132 device failure"))
        else:
            out.append((value, name, meaning or ("no error" if name == "MBFB_OK" else "")))
    if len(out) < 10:
        raise ValueError("fewer than 10 MBFB_E_* ids found in the header")
    return out


def render(header_text: str) -> str:
    return HEAD + "".join(f"| {i} | {n} | {m} |\n" for i, n, m in rows(header_text))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--header", default=os.path.join(ROOT, "c_shims", "include", "mbfb.h"))
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "errors.md"))
    p.add_argument("--check", metavar="FILE")
    a = p.parse_args(argv)

    def text():
        with open(a.header, encoding="utf-8") as fh:
            return render(fh.read())
    return generate("errors.py", text, (OSError, ValueError), out=a.out, check=a.check,
                    hint="tools/stref/errors.py")


if __name__ == "__main__":
    sys.exit(main())
