#!/usr/bin/env python3
"""Writes the block reference of the ST library from its declarations.

    python3 tools/stref/stref.py [--src st_src] [--header c_shims/include/mbfb.h] [--out FILE]
    python3 tools/stref/stref.py --check st_src/REFERENCE.md      # exit 1 if it is stale

For every FUNCTION_BLOCK and FUNCTION in the ST files: every input and output with its type,
default and comment, and every ErrorID the block can give: the error constants it declares
(`VAR CONSTANT` entries named E_* or MB_E_*, with their comments; the fields of MB_ERROR_IDS,
MB_Types.st, it uses through an instance: ERR.RANGE) and those of the blocks it
instantiates, and, for a block that reaches the bus (it instantiates MB_Device, or is
MB_Device), the shims' codes (#define MBFB_E_* in mbfb.h, and 128+x for exception x).
A block no other POU instantiates is public (as the OpenPLC Editor palette, plc_lib/editor).
Exit codes: 0 written / up to date, 1 stale (--check), 2 bad input (one line on stderr).
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import sys

from generated import generate  # the command line of every generated file

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORE = "MB_Device"

POU = re.compile(r"^\s*(FUNCTION_BLOCK|FUNCTION)\s+(\w+)(?:\s*:\s*(\w+))?(.*?)^\s*END_\1\b",
                 re.S | re.M)
SECTION = re.compile(r"\b(VAR_INPUT|VAR_OUTPUT|VAR_IN_OUT|VAR\s+CONSTANT|VAR)\b(.*?)\bEND_VAR\b", re.S)
ENTRY = re.compile(r"^\s*(\w+)\s*:\s*([^;:=]+?)\s*(?::=\s*(.+?))?\s*;\s*(?:\(\*(.*?)\*\))?\s*$")
CONST = re.compile(r"(\w+)\s*:\s*\w+\s*:=\s*([^;]+);\s*(?:\(\*(.*?)\*\))?")
LEAD_COMMENT = re.compile(r"\A\s*\(\*(.*?)\*\)", re.S)
SHARED_IDS = "MB_ERROR_IDS"     # the shared error ids: a STRUCT type with initialised fields
SHIM_CODES = "MB_SHIM_CODES"    # the shims' codes the blocks test: its E_* fields are remapped
STRUCT = re.compile(r"\b(\w+)\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b", re.S)
INSTANCE = re.compile(r"(\w+)\s*:\s*(\w+)\s*;")
SHIM_DEFINE = re.compile(r"^#define\s+MBFB_E_(\w+)\s+(\d+)[ \t]*(?:/\*(.*?)\*/)?", re.M | re.S)


class InputError(Exception):
    pass


def st_int(text):
    t = text.strip().replace("_", "")
    neg = t.startswith("-")
    t = t.lstrip("+-")
    parts = t.split("#")
    if len(parts) == 3:
        parts = parts[1:]
    if len(parts) == 2 and not parts[0].isdigit():
        parts = [parts[1]]
    value = int(parts[1], int(parts[0])) if len(parts) == 2 else int(parts[0], 10)
    return -value if neg else value


def oneline(text):
    return " ".join((text or "").split())


def parse_pous(paths):
    """{name: dict(kind, file, doc, inputs, outputs, errors, uses)} for every POU."""
    pous = {}
    shared = {}                   # field of MB_ERROR_IDS -> its id
    shim = {}                     # E_* field of MB_SHIM_CODES -> its code
    sources = []
    for path in paths:
        with open(path, encoding="utf-8") as fh:
            sources.append((path, fh.read()))
        for st in STRUCT.finditer(re.sub(r"\(\*.*?\*\)", " ", sources[-1][1], flags=re.S)):
            if st.group(1) == SHARED_IDS:
                shared.update((c.group(1), st_int(c.group(2))) for c in CONST.finditer(st.group(2)))
            elif st.group(1) == SHIM_CODES:
                shim.update((c.group(1), st_int(c.group(2))) for c in CONST.finditer(st.group(2))
                            if c.group(1).startswith("E_"))
    for path, src in sources:
        last_end = 0
        for m in POU.finditer(src):
            kind, name, rtype, body = m.group(1), m.group(2), m.group(3), m.group(4)
            # the comment just before the POU (after the previous one) documents it
            before = src[last_end:m.start()]
            last_end = m.end()
            docs = re.findall(r"\(\*(.*?)\*\)", before, re.S)
            doc = oneline(docs[-1]) if docs else ""
            pou = {"kind": kind, "file": os.path.basename(path), "doc": doc, "type": rtype,
                   "inputs": [], "outputs": [], "errors": {}, "uses": set(), "remapped": set()}
            for sec in SECTION.finditer(body):
                which = " ".join(sec.group(1).split())
                text = sec.group(2)
                for i in INSTANCE.finditer(text if which in ("VAR", "VAR CONSTANT") else ""):
                    if i.group(2) == SHIM_CODES:   # a shim code the block reports as another
                        pou["remapped"] |= {shim[f.group(1)] for f in
                                            re.finditer(rf"\b{i.group(1)}\.(\w+)", body) if f.group(1) in shim}
                    if i.group(2) != SHARED_IDS:
                        continue
                    for f in re.finditer(rf"\b{i.group(1)}\.(\w+)", body):
                        if f.group(1) not in shared:
                            raise InputError(f"{path}: {name}: {SHARED_IDS} has no {f.group(1)}")
                        pou["errors"][shared[f.group(1)]] = (f"{SHARED_IDS}.{f.group(1)}", "")
                if which == "VAR CONSTANT":
                    for c in CONST.finditer(text):
                        cname = c.group(1)
                        if cname.startswith("SHIM_E_"):   # a shim code the block reports as another
                            pou["remapped"].add(st_int(c.group(2)))
                        elif re.fullmatch(r"(MB_)?E_\w+", cname):
                            try:
                                code = st_int(c.group(2))
                            except ValueError:
                                raise InputError(f"{path}: {name}.{cname}: {c.group(2)!r} is not a number")
                            pou["errors"][code] = (cname, oneline(c.group(3)))
                    continue
                for line in text.splitlines():
                    e = ENTRY.match(line)
                    if not e:
                        continue
                    vname, vtype, default, comment = e.groups()
                    vtype = oneline(vtype)
                    if which == "VAR":
                        if re.fullmatch(r"\w+", vtype):
                            pou["uses"].add(vtype)
                        continue
                    entry = (vname, vtype, oneline(default) if default else "", oneline(comment))
                    pou["inputs" if which in ("VAR_INPUT", "VAR_IN_OUT") else "outputs"].append(entry)
            if name in pous:
                raise InputError(f"{path}: {name} is declared twice")
            pous[name] = pou
    return pous


def shim_errors(header):
    try:
        with open(header, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as err:
        raise InputError(f"{header}: {err.strerror}")
    out = {}
    for m in SHIM_DEFINE.finditer(text):
        name, code, comment = m.group(1), int(m.group(2)), oneline(m.group(3))
        if name == "EXCEPTION_BASE":
            continue                  # 128+x: a row of its own
        out[code] = ("MBFB_E_" + name, comment)
    if not out:
        raise InputError(f"{header}: no #define MBFB_E_* found")
    return out


def errors_of(name, pous, seen=None):
    """Error constants of a block and of the blocks it instantiates; whether it reaches the
    bus; the shim codes it reports as others."""
    seen = set() if seen is None else seen
    if name in seen or name not in pous:
        return {}, False, set()
    seen.add(name)
    pou = pous[name]
    errs = dict(pou["errors"])
    bus = name == CORE
    remapped = set(pou["remapped"])
    for used in sorted(pou["uses"]):
        sub, sub_bus, sub_re = errors_of(used, pous, seen)
        for code, val in sub.items():
            errs.setdefault(code, val)
        bus = bus or sub_bus
        remapped |= sub_re
    return errs, bus, remapped


def cell(text):
    return (text or "").replace("|", "\\|")


def render(pous, shims):
    used = set()
    for pou in pous.values():
        used |= pou["uses"]
    out = ["# Block reference (generated)", "",
           "Written by `tools/stref/stref.py` from the declarations in `st_src/*.st` and the error",
           "codes in `c_shims/include/mbfb.h`; do not edit: change the ST (its comments) and run the",
           "build (target `st_reference`), or `python3 tools/stref/stref.py --out st_src/REFERENCE.md`.",
           "The test `st_reference` fails when this file is stale. Behaviour: `st_src/README.md`.", ""]
    blocks = sorted((n for n, p in pous.items() if p["kind"] == "FUNCTION_BLOCK"),
                    key=lambda n: (n in used, n.lower()))
    funcs = sorted((n for n, p in pous.items() if p["kind"] == "FUNCTION"), key=str.lower)
    out.append("| block | file | use |")
    out.append("|---|---|---|")
    for n in blocks:
        out.append(f"| [`{n}`](#{n.lower()}) | `{pous[n]['file']}` | "
                   f"{'internal (used by other blocks)' if n in used else 'public'} |")
    out.append("")
    for n in blocks:
        pou = pous[n]
        out += [f"## {n}", "", f"`{pou['file']}`" + (" (internal)" if n in used else ""), ""]
        if pou["doc"]:
            out += [cell(pou["doc"]), ""]
        for title, rows in (("Inputs", pou["inputs"]), ("Outputs", pou["outputs"])):
            out += [f"**{title}**", "", "| name | type | default | comment |", "|---|---|---|---|"]
            for vname, vtype, default, comment in rows:
                out.append(f"| `{vname}` | `{cell(vtype)}` | {('`' + cell(default) + '`') if default else ''} "
                           f"| {cell(comment)} |")
            if not rows:
                out.append("| (none) | | | |")
            out.append("")
        errs, bus, remapped = errors_of(n, pous)
        if bus:
            for code, val in shims.items():
                if code < 200 and code not in remapped:
                    errs.setdefault(code, val)
        out += ["**ErrorID**", "", "| id | name | meaning |", "|---|---|---|", "| 0 | | no error |"]
        for code in sorted(errs):
            cname, comment = errs[code]
            if not comment and code in shims:
                comment = shims[code][1]      # the meaning mbfb.h gives that id
            out.append(f"| {code} | `{cname}` | {cell(comment)} |")
        if bus:
            out.append("| 128+x | | the device answered Modbus exception x (129 illegal function, "
                       "130 illegal address, 131 illegal value, 132 device failure) |")
        out.append("")
    out += ["## Functions", "", "| function | returns | inputs | file |", "|---|---|---|---|"]
    for n in funcs:
        pou = pous[n]
        ins = ", ".join(f"`{v}`: `{cell(t)}`" + (f" := `{cell(d)}`" if d else "")
                        for v, t, d, _ in pou["inputs"])
        out.append(f"| `{n}` | `{pou['type']}` | {ins} | `{pou['file']}` |")
    out.append("")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--src", default=os.path.join(ROOT, "st_src"), help="folder of the ST files")
    ap.add_argument("--header", default=os.path.join(ROOT, "c_shims", "include", "mbfb.h"))
    ap.add_argument("--out", help="write here (default: standard output)")
    ap.add_argument("--check", metavar="FILE", help="exit 1 if FILE differs from what would be written")
    args = ap.parse_args(argv)

    def text():
        paths = sorted(glob.glob(os.path.join(args.src, "*.st")))
        if not paths:
            raise InputError(f"{args.src}: no .st files")
        return render(parse_pous(paths), shim_errors(args.header))
    return generate("stref", text, InputError, out=args.out, check=args.check,
                    hint="the build target st_reference (or tools/stref/stref.py --out it)")


if __name__ == "__main__":
    sys.exit(main())
