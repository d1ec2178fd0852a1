#!/usr/bin/env python3
"""mkeditorlib.py OUT.xml ST_FILE... - the OpenPLC Editor palette library of our blocks.

Writes a PLCopen TC6 XML v2.01 library (the format of the Editor's own
editor/plcopen/Standard_Function_Blocks.xml) listing the public function blocks of the given
ST files: their VAR_INPUT / VAR_IN_OUT / VAR_OUTPUT pins with types, initial values and the
comment of each declaration, and the block's header comment as its documentation. The Editor
reads only interfaces from such a library: the code comes from mbfb.txt in its matiec library
(plc_lib/README.md, "The OpenPLC Editor's block palette").

A block is public when no other POU of the library instantiates it (MB_Link, MB_Txn, ... are
the device blocks' internals). Functions and types are not listed: the Editor's palette takes
function blocks from here, and it never looks up data types in a palette library.

Hand-written parsing (stdlib only): no maintained Python ST parser reads declaration comments,
and the ST subset of declarations is small (matiec checks the same files when plc_lib is built).
"""
import re
import sys
import xml.etree.ElementTree as ET

NS = "http://www.plcopen.org/xml/tc6_0201"
XHTML = "http://www.w3.org/1999/xhtml"
ELEMENTARY = {"BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT", "ULINT", "REAL",
              "LREAL", "TIME", "DATE", "TOD", "DT", "BYTE", "WORD", "DWORD", "LWORD"}
SECTIONS = {"VAR_INPUT": "inputVars", "VAR_IN_OUT": "inOutVars", "VAR_OUTPUT": "outputVars"}
POU_RE = re.compile(r"^\s*(FUNCTION_BLOCK|FUNCTION|PROGRAM)\s+(\w+)", re.I | re.M)
COMMENT_RE = re.compile(r"\(\*(.*?)\*\)", re.S)
SECTION_RE = re.compile(r"\b(VAR(?:_INPUT|_OUTPUT|_IN_OUT|_TEMP|_EXTERNAL)?)\b(?:\s+(?:CONSTANT|RETAIN)\b)?"
                        r"(.*?)\bEND_VAR\b", re.S | re.I)
SKIP_RE = re.compile(r"(?:\s|\(\*.*?\*\))*", re.S)  # blanks and comments between declarations
# "a, b : TYPE := init;" and the comment that follows it on the same line
DECL_RE = re.compile(r"(\w+(?:\s*,\s*\w+)*)\s*:\s*([^;]+?)\s*;[ \t]*(?:\(\*(.*?)\*\))?", re.S)


class Pou:
    def __init__(self, kind, name, doc, text):
        self.kind, self.name, self.doc, self.text = kind.upper(), name, doc, text
        self.pins = {s: [] for s in SECTIONS}  # section -> [(name, type, initial, comment)]
        self.local_types = set()


def _clean(comment):
    return " ".join(comment.split())


def parse(path):
    """The POUs of one ST file, with their interface pins."""
    with open(path, encoding="utf-8") as f:
        src = f.read()
    first = COMMENT_RE.match(src.lstrip())
    file_doc = _clean(first.group(1)) if first else ""
    pous = []
    starts = list(POU_RE.finditer(src))
    for i, m in enumerate(starts):
        end_kw = "END_" + m.group(1).upper()
        end = src.upper().find(end_kw, m.end())
        if end < 0:
            raise SystemExit(f"{path}: {m.group(2)} has no {end_kw}")
        before = src[starts[i - 1].end() if i else 0:m.start()].rstrip()
        doc = COMMENT_RE.findall(before)
        own = _clean(doc[-1]) if doc and before.endswith("*)") else ""
        pou = Pou(m.group(1), m.group(2), own or file_doc, src[m.end():end])
        _parse_vars(pou, path)
        pous.append(pou)
    return pous


def _parse_vars(pou, path):
    for sec in SECTION_RE.finditer(pou.text):
        section = sec.group(1).upper()
        body = sec.group(2)
        pos = 0
        while True:
            pos = SKIP_RE.match(body, pos).end()
            if pos >= len(body):
                break
            m = DECL_RE.match(body, pos)
            if not m:
                raise SystemExit(f"{path}: {pou.name}: cannot read declaration "
                                 f"{body[pos:].splitlines()[0]!r}")
            pos = m.end()
            names, decl, comment = m.group(1), m.group(2), _clean(m.group(3) or "")
            vtype, _, init = (s.strip() for s in decl.partition(":="))
            for name in (n.strip() for n in names.split(",")):
                if section in SECTIONS:
                    pou.pins[section].append((name, vtype, init, comment))
                else:
                    pou.local_types.add(vtype.upper())


def public_blocks(pous):
    """Function blocks no other POU of the library instantiates, in file order."""
    used = set().union(*(p.local_types for p in pous)) | {
        t.upper() for p in pous for s in p.pins.values() for _, t, _, _ in s}
    return [p for p in pous if p.kind == "FUNCTION_BLOCK" and p.name.upper() not in used]


def _type_element(parent, vtype):
    t = ET.SubElement(parent, f"{{{NS}}}type")
    up = vtype.upper()
    if up in ELEMENTARY:
        ET.SubElement(t, f"{{{NS}}}{up}")
    elif up == "STRING":
        ET.SubElement(t, f"{{{NS}}}string")
    elif re.fullmatch(r"\w+", vtype):
        ET.SubElement(t, f"{{{NS}}}derived", name=vtype)
    else:
        raise SystemExit(f"unsupported pin type {vtype!r} (arrays/strings with length)")


def _xhtml(parent, tag, text):
    el = ET.SubElement(parent, f"{{{NS}}}{tag}")
    ET.SubElement(el, f"{{{XHTML}}}p").text = text
    return el


def library_xml(blocks, name="Modbus instrument blocks (mbfb)"):
    ET.register_namespace("", NS)
    ET.register_namespace("xhtml", XHTML)
    stamp = "2024-01-01T00:00:00"  # fixed: the file must not change when st_src/ does not
    proj = ET.Element(f"{{{NS}}}project")
    ET.SubElement(proj, f"{{{NS}}}fileHeader", companyName="modbus-fb", productName="mbfb",
                  productVersion="1.0", creationDateTime=stamp)
    ch = ET.SubElement(proj, f"{{{NS}}}contentHeader", name=name, modificationDateTime=stamp)
    ci = ET.SubElement(ch, f"{{{NS}}}coordinateInfo")
    for lang in ("fbd", "ld", "sfc"):
        ET.SubElement(ET.SubElement(ci, f"{{{NS}}}{lang}"), f"{{{NS}}}scaling", x="0", y="0")
    types = ET.SubElement(proj, f"{{{NS}}}types")
    ET.SubElement(types, f"{{{NS}}}dataTypes")
    pous = ET.SubElement(types, f"{{{NS}}}pous")
    for b in blocks:
        pou = ET.SubElement(pous, f"{{{NS}}}pou", name=b.name, pouType="functionBlock")
        iface = ET.SubElement(pou, f"{{{NS}}}interface")
        for section, tag in SECTIONS.items():
            if not b.pins[section]:
                continue
            vars_el = ET.SubElement(iface, f"{{{NS}}}{tag}")
            for pname, vtype, init, comment in b.pins[section]:
                v = ET.SubElement(vars_el, f"{{{NS}}}variable", name=pname)
                _type_element(v, vtype)
                if init:
                    iv = ET.SubElement(v, f"{{{NS}}}initialValue")
                    ET.SubElement(iv, f"{{{NS}}}simpleValue", value=init)
                if comment:
                    _xhtml(v, "documentation", comment)
        # The Editor's own library blocks carry a placeholder body: the code is in matiec's lib.
        body = ET.SubElement(pou, f"{{{NS}}}body")
        _xhtml(body, "ST", "(* implemented in mbfb.txt, plc_lib *)")
        _xhtml(pou, "documentation", b.doc + " Reference: st_src/README.md.")
    ET.SubElement(ET.SubElement(proj, f"{{{NS}}}instances"), f"{{{NS}}}configurations")
    ET.indent(proj, space="  ")
    return ET.tostring(proj, encoding="unicode", xml_declaration=False)


def main(argv):
    if len(argv) < 3:
        raise SystemExit(__doc__.split("\n")[0])
    pous = [p for path in sorted(argv[2:]) for p in parse(path)]
    blocks = public_blocks(pous)
    if not blocks:
        raise SystemExit("no public function block found")
    with open(argv[1], "w", encoding="utf-8") as f:
        f.write("<?xml version='1.0' encoding='utf-8'?>\n")
        f.write("<!-- GENERATED by plc_lib/editor/mkeditorlib.py from st_src/: do not edit. -->\n")
        f.write(library_xml(blocks) + "\n")


if __name__ == "__main__":
    main(sys.argv)
