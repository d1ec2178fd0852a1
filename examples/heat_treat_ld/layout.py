#!/usr/bin/env python3
"""layout.py --editor DIR --palette MBFB_Blocks.xml [--out DIR] - write examples/heat_treat_ld:
lay out the LD rungs of plc.xml and add the two ST function blocks they call (Recipe_Request
and Line_Products, read from the ST example), then let the OpenPLC Editor's own code (a checkout of
github.com/thiagoralves/editor, run headless by plc_lib/editor/editor_tool.py) load the project,
save plc.xml with its serializer and write heat_treat_ld.st with its PLCGenerator.

Development aid, not run in CI (the Editor is not a build dependency); needs a Python with lxml.
The Editor's loader gives every block's pins (its standard library and our palette; the ST
function blocks' from their declarations), so each block is written with all its pins in the
Editor's order, as the Editor saves them.
"""
import argparse
import os
import re
import shutil
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "plc_lib", "editor"))
import editor_tool  # noqa: E402

RAIL_X, RIGHT_X = 40, 2000


class El:
    """A placed element: its localId and the absolute points of its outputs (None = the only one)."""

    def __init__(self, lid, pins):
        self.id = lid
        self.pins = pins


class Ladder:
    def __init__(self, pins):
        self.pins = pins            # block type -> ([inputs], [outputs])
        self.out = []               # XML of the body's elements
        self.ids = iter(range(1, 100000))
        self.rail = El(next(self.ids), {})
        self.right = El(next(self.ids), {})
        self.rail_points = []
        self.coils = []

    # ---- connections
    def _src(self, s):
        """s: ('rail', y), (El, pin), or El with a single output -> (El, point, pin)."""
        if isinstance(s, tuple) and s[0] == "rail":
            self.rail_points.append(s[1])
            return self.rail, (RAIL_X + 10, s[1]), None
        if isinstance(s, tuple):
            return s[0], s[0].pins[s[1]], s[1]
        return s, s.pins[None], None

    def _pin_in(self, rel, dst, srcs):
        conns = ""
        for s in srcs:
            el, (sx, sy), param = self._src(s)
            dx, dy = dst
            if dy == sy:
                pts = [dst, (sx, sy)]
            else:
                mx = sx + max(10, (dx - sx) // 2)
                mx -= mx % 10
                pts = [dst, (mx, dy), (mx, sy), (sx, sy)]
            fp = f' formalParameter="{param}"' if param else ""
            p = "".join(f'<position x="{x}" y="{y}"/>' for x, y in pts)
            conns += f'<connection refLocalId="{el.id}"{fp}>{p}</connection>'
        return f'<connectionPointIn><relPosition x="{rel[0]}" y="{rel[1]}"/>{conns}</connectionPointIn>'

    # ---- elements
    def invar(self, x, y, expr):
        w = max(60, 10 * len(expr) + 20)
        lid = next(self.ids)
        self.out.append(f'<inVariable localId="{lid}" height="30" width="{w}" negated="false">'
                        f'<position x="{x}" y="{y}"/><connectionPointOut><relPosition x="{w}" y="15"/>'
                        f'</connectionPointOut><expression>{expr}</expression></inVariable>')
        return El(lid, {None: (x + w, y + 15)})

    def outvar(self, x, y, expr, src):
        w = max(60, 10 * len(expr) + 20)
        lid = next(self.ids)
        self.out.append(f'<outVariable localId="{lid}" height="30" width="{w}" negated="false">'
                        f'<position x="{x}" y="{y}"/>{self._pin_in((0, 15), (x, y + 15), [src])}'
                        f'<expression>{expr}</expression></outVariable>')

    def contact(self, x, y, var, srcs, negated=False, tag="contact", storage=None):
        lid = next(self.ids)
        st = f' storage="{storage}"' if storage else ""
        self.out.append(f'<{tag} localId="{lid}" height="20" width="30" negated="{str(negated).lower()}"{st}>'
                        f'<position x="{x}" y="{y}"/>{self._pin_in((0, 10), (x, y + 10), srcs)}'
                        f'<connectionPointOut><relPosition x="30" y="10"/></connectionPointOut>'
                        f'<variable>{var}</variable></{tag}>')
        return El(lid, {None: (x + 30, y + 10)})

    def coil(self, x, y, var, srcs, storage=None):
        el = self.contact(x, y, var, srcs, tag="coil", storage=storage)
        self.coils.append(el)
        return el

    def block(self, x, y, typ, inputs, instance=None, w=160):
        """inputs: {pin: source}; a str source is a variable or literal placed level with its pin.
        Every pin of the type is written, as the Editor saves a block."""
        ins, outs = self.pins[typ]
        if "EN" in inputs:  # execution control: the Editor adds EN/ENO as first pins
            ins, outs = ["EN"] + ins, ["ENO"] + outs
        assert not set(inputs) - set(ins), (typ, set(inputs) - set(ins))
        lid = next(self.ids)
        inst = f' instanceName="{instance}"' if instance else ""
        xml = [f'<block localId="{lid}" typeName="{typ}"{inst} height="{40 * max(len(ins), len(outs)) + 20}" '
               f'width="{w}"><position x="{x}" y="{y}"/><inputVariables>']
        for k, p in enumerate(ins):
            ry = 40 * (k + 1)
            src = inputs.get(p)
            if isinstance(src, str):
                src = self.invar(x - 40 - max(60, 10 * len(src) + 20), y + ry - 15, src)
            if src is not None:
                xml.append(f'<variable formalParameter="{p}">{self._pin_in((0, ry), (x, y + ry), [src])}</variable>')
            else:
                xml.append(f'<variable formalParameter="{p}"><connectionPointIn>'
                           f'<relPosition x="0" y="{ry}"/></connectionPointIn></variable>')
        xml.append("</inputVariables><inOutVariables/><outputVariables>")
        el = El(lid, {})
        for k, p in enumerate(outs):
            ry = 40 * (k + 1)
            el.pins[p] = (x + w, y + ry)
            xml.append(f'<variable formalParameter="{p}"><connectionPointOut>'
                       f'<relPosition x="{w}" y="{ry}"/></connectionPointOut></variable>')
        xml.append("</outputVariables></block>")
        self.out.append("".join(xml))
        if len(outs) == 1:
            el.pins[None] = el.pins[outs[0]]
        return el

    def height(self, typ):
        ins, outs = self.pins[typ]
        return 40 * max(len(ins), len(outs)) + 20

    def comment(self, x, y, w, h, text):
        lid = next(self.ids)
        self.out.append(f'<comment localId="{lid}" height="{h}" width="{w}"><position x="{x}" y="{y}"/>'
                        f'<content><xhtml:p><![CDATA[{text}]]></xhtml:p></content></comment>')

    def body(self, height):
        rail = [f'<leftPowerRail localId="{self.rail.id}" height="{height}" width="10"><position x="{RAIL_X}" y="0"/>']
        for y in sorted(set(self.rail_points)):
            rail.append(f'<connectionPointOut formalParameter=""><relPosition x="10" y="{y}"/></connectionPointOut>')
        rail.append("</leftPowerRail>")
        right = [f'<rightPowerRail localId="{self.right.id}" height="{height}" width="10"><position x="{RIGHT_X}" y="0"/>']
        for el in self.coils:
            x, y = el.pins[None]
            right.append(self._pin_in((0, y), (RIGHT_X, y), [el]))
        right.append("</rightPowerRail>")
        return "".join(rail) + "".join(right) + "".join(self.out)


# ---------------------------------------------------------------- ST helpers
# The project's two ST function blocks, called from the ladder: Recipe_Request (the handshake)
# and Line_Products (the line's recipes), both the ST example's, read from
# examples/heat_treat_st/heat_treat_st.st so that each is written once. plc.xml holds each with
# its interface in XML and its body as ST, as the Editor saves an ST POU.
ST_EXAMPLE = os.path.join(HERE, "..", "heat_treat_st", "heat_treat_st.st")
ELEMENTARY = {"BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT", "ULINT", "BYTE", "WORD",
              "DWORD", "LWORD", "REAL", "LREAL", "TIME", "DATE", "TOD", "DT"}
SECTIONS = {"VAR_INPUT": "inputVars", "VAR_OUTPUT": "outputVars", "VAR": "localVars"}


def st_block(text, name):
    """FUNCTION_BLOCK `name` of an ST text: (its leading comment, [(section, constant,
    [(var, type, initial, comment)])], body). Declarations one per line, as ours are."""
    start = text.index(f"FUNCTION_BLOCK {name}\n")
    doc = text[text.rindex("(*", 0, start) + 2:text.rindex("*)", 0, start)]
    doc = " ".join(doc.split())
    block = text[start:text.index("END_FUNCTION_BLOCK", start)]
    lines = block.split("\n")[1:]
    sections, cur, k = [], None, 0
    while k < len(lines):
        ln = lines[k].strip()
        if ln in ("VAR_INPUT", "VAR_OUTPUT", "VAR", "VAR CONSTANT"):
            cur = (SECTIONS[ln.split()[0]], ln.endswith("CONSTANT"), [])
            sections.append(cur)
        elif ln == "END_VAR":
            cur = None
        elif cur is not None and ln:
            m = re.fullmatch(r"(\w+) : (\w+)(?: := ([^;]+))?;\s*(?:\(\*\s*(.*?)\s*\*\))?", ln)
            assert m, f"{name}: declaration not understood: {ln!r}"
            cur[2].append(m.groups())
        elif cur is None and ln:
            break
        k += 1
    body = "\n".join(x[2:] if x.startswith("  ") else x for x in lines[k:]).strip() + "\n"
    return doc, sections, body


def type_xml(t):
    return f"<{t}/>" if t in ELEMENTARY else "<string/>" if t == "STRING" else f'<derived name="{t}"/>'


def var_xml(name, typ, init=None, doc=None, addr=None):
    a = f' address="{addr}"' if addr else ""
    v = f'<variable name="{name}"{a}><type>{type_xml(typ) if not typ.startswith("<") else typ}</type>'
    if init:
        v += f'<initialValue><simpleValue value="{init}"/></initialValue>'
    if doc:
        v += f'<documentation><xhtml:p><![CDATA[{doc}]]></xhtml:p></documentation>'
    return v + "</variable>"


def helpers():
    """[(name, doc, sections, body)] of the project's ST function blocks."""
    with open(ST_EXAMPLE, encoding="utf-8") as f:
        example = f.read()
    return [(name, *st_block(example, name)) for name in ("Recipe_Request", "Line_Products")]


def helper_pins(blocks):
    """block type -> ([inputs], [outputs]) of the helpers, for Ladder.block."""
    out = {}
    for name, _, sections, _ in blocks:
        ins = [v[0] for s, _, vs in sections if s == "inputVars" for v in vs]
        outs = [v[0] for s, _, vs in sections if s == "outputVars" for v in vs]
        out[name] = (ins, outs)
    return out


CONSTANT = ' constant="true"'


def helper_pou(name, doc, sections, body):
    iface = "".join(f"<{s}{CONSTANT if const else ''}>"
                    + "".join(var_xml(n, t, i, d) for n, t, i, d in vs) + f"</{s}>"
                    for s, const, vs in sections)
    return (f'<pou name="{name}" pouType="functionBlock"><interface>{iface}</interface>'
            f'<body><ST><xhtml:p><![CDATA[{body}]]></xhtml:p></ST></body>'
            f'<documentation><xhtml:p><![CDATA[{doc}]]></xhtml:p></documentation></pou>')


# ---------------------------------------------------------------- the rungs
ZONES = [  # n, block type, slave, instance, what, set point request register, its status register
    (1, "FDC_Controller", 1, "Zone1", "FDC-100", 1024, 9),
    (2, "TempCtrl_MVD94", 2, "Zone2", "MV-D94", 1025, 10),
]


def zone_rungs(ld, y, n, typ, slave, inst, what, hr, status_hr):
    z = f"Z{n}"
    ld.comment(40, y, 1400, 60, f"Zone {n} set point request (HR {hr}, x10): a new value is taken while no "
               f"write runs, and sent once the zone is Valid (its limits known). HR {status_hr} ({z}SPStatus) "
               f"shows the result: 0 sent, else the ErrorID.")
    y += 80
    ne = ld.block(260, y, "NE", {"IN1": f"{z}SPReq", "IN2": f"{z}Req"}, w=80)
    ld.outvar(420, y + 25, f"{z}New", ne)
    y += 120
    c1 = ld.contact(120, y + 30, f"{z}Write", [("rail", y + 40)], negated=True)
    c2 = ld.contact(200, y + 30, f"{z}New", [c1])
    mv = ld.block(320, y, "MOVE", {"EN": c2, "IN": f"{z}SPReq"}, w=80)
    ld.outvar(480, y + 65, f"{z}Req", (mv, "OUT"))
    ld.coil(900, y + 30, f"{z}Wait", [(mv, "ENO")], storage="reset")
    y += 140
    ne1 = ld.block(260, y, "NE", {"IN1": f"{z}Req", "IN2": "0"}, w=80)
    ne2 = ld.block(260, y + 120, "NE", {"IN1": f"{z}Req", "IN2": f"{z}Settled"}, w=80)
    and1 = ld.block(420, y + 20, "AND", {"IN1": ne1, "IN2": ne2}, w=80)
    ld.outvar(580, y + 45, f"{z}Open", and1)
    i2r = ld.block(260, y + 200, "INT_TO_REAL", {"IN": f"{z}Req"}, w=120)
    ten = ld.invar(260, y + 285, "10.0")
    div = ld.block(460, y + 200, "DIV", {"IN1": i2r, "IN2": ten}, w=80)
    ld.outvar(620, y + 225, f"{z}SVSet", div)
    y += 340
    ld.comment(40, y, 1400, 30, f"Zone {n}: start an attempt when a request is open, no retry wait runs, the zone "
               f"is Valid and the last attempt's result is gone.")
    y += 50
    src = ("rail", y + 40)
    for k, (var, neg) in enumerate(((f"{z}Open", False), (f"{z}Wait", True), (f"{inst}.Valid", False),
                                    (f"{inst}.SVDone", True), (f"{inst}.SVError", True))):
        src = ld.contact(120 + 100 * k, y + 30, var, [src], negated=neg)
    ld.coil(900, y + 30, f"{z}Write", [src], storage="set")
    y += 80

    ld.comment(40, y, 1400, 30, f"Zone {n}: {typ} ({what}, slave {slave}) polls every 500 ms; "
               f"WriteSV sends {z}SVSet on a rising edge, WriteSettings the product's recipe "
               f"(Products.Recipe{n}); SettingsField goes to HR {13 + n}.")
    y += 50
    blk = ld.block(320, y, typ, {"Enable": ("rail", y + 40), "Port": "BusPort", "SlaveId": str(slave),
                                 "Line": "BusLine", "Period": "T#500ms", "WriteSV": f"{z}Write",
                                 "SVSet": f"{z}SVSet", "WriteSettings": f"{z}RWrite",
                                 "Settings": f"Products.Recipe{n}"}, instance=inst, w=200)
    ld.coil(900, y + 30, f"{z}Valid", [(blk, "Valid")])
    ld.outvar(940, y + 145, f"{z}Err", (blk, "ErrorID"))
    px, py = blk.pins["SettingsField"]
    ld.outvar(px + 100, py - 15, f"{z}RecipeField", (blk, "SettingsField"))
    for k, (pin, var) in enumerate((("PV", f"{z}PV"), ("SV", f"{z}SV"))):
        yy = y + 220 + 140 * k
        m = ld.block(620, yy, "MUL", {"IN1": (blk, pin), "IN2": ld.invar(460, yy + 110, "10.0")}, w=80)
        r = ld.block(760, yy, "REAL_TO_INT", {"IN": m}, w=120)
        ld.outvar(940, yy + 25, var, r)
    y += ld.height(typ) + 40

    ld.comment(40, y, 1400, 60, f"Zone {n}: the attempt ended (SVDone or SVError): publish SVErrorID, drop WriteSV. "
               f"A transient error (a bus error below 128, 205 limits not read yet) waits 2 s and tries again; "
               f"otherwise the request is settled: sent, or refused for good (202 out of range, ...).")
    y += 80
    c1 = ld.contact(120, y + 30, f"{z}Write", [("rail", y + 40)])
    d = ld.contact(200, y + 30, f"{inst}.SVDone", [c1])
    e = ld.contact(200, y + 70, f"{inst}.SVError", [c1])
    ld.coil(900, y + 30, f"{z}End", [d, e])
    y += 120
    lt = ld.block(260, y, "LT", {"IN1": f"{inst}.SVErrorID", "IN2": "128"}, w=80)
    eq = ld.block(260, y + 120, "EQ", {"IN1": f"{inst}.SVErrorID", "IN2": "205"}, w=80)
    orb = ld.block(420, y + 20, "OR", {"IN1": lt, "IN2": eq}, w=80)
    ld.outvar(580, y + 45, f"{z}Transient", orb)
    y += 240
    c1 = ld.contact(200, y + 30, f"{z}End", [("rail", y + 40)])
    mv = ld.block(320, y, "MOVE", {"EN": c1, "IN": f"{inst}.SVErrorID"}, w=80)
    ld.outvar(480, y + 65, f"{z}SPStatus", (mv, "OUT"))
    ld.coil(900, y + 30, f"{z}Write", [(mv, "ENO")], storage="reset")
    y += 140
    c1 = ld.contact(120, y + 30, f"{z}End", [("rail", y + 40)])
    c2 = ld.contact(200, y + 30, f"{inst}.SVError", [c1])
    c3 = ld.contact(280, y + 30, f"{z}Transient", [c2])
    ld.coil(900, y + 30, f"{z}Wait", [c3], storage="set")
    y += 60
    c1 = ld.contact(120, y + 30, f"{z}End", [("rail", y + 40)])
    c2 = ld.contact(200, y + 30, f"{z}Wait", [c1], negated=True)
    mv = ld.block(320, y, "MOVE", {"EN": c2, "IN": f"{z}Req"}, w=80)
    ld.outvar(480, y + 65, f"{z}Settled", (mv, "OUT"))
    y += 140
    c1 = ld.contact(200, y + 30, f"{z}Wait", [("rail", y + 40)])
    t = ld.block(320, y, "TON", {"IN": c1, "PT": "T#2s"}, instance=f"{z}RetryTmr", w=80)
    ld.coil(900, y + 30, f"{z}Wait", [(t, "Q")], storage="reset")
    return y + 140


def alarm_rungs(ld, y, n):
    z = f"Z{n}"
    sub = ld.block(320, y, "SUB", {"IN1": f"Zone{n}.PV", "IN2": f"Zone{n}.SV"}, w=80)
    ab = ld.block(460, y, "ABS", {"IN": sub}, w=80)
    gt = ld.block(600, y, "GT", {"IN1": ab, "IN2": ld.invar(460, y + 65, "Band")}, w=80)
    ld.outvar(740, y + 25, f"{z}Far", gt)
    y += 120
    c1 = ld.contact(120, y + 30, f"{z}Valid", [("rail", y + 40)])
    c2 = ld.contact(200, y + 30, f"{z}Far", [c1])
    t1 = ld.block(320, y, "TON", {"IN": c2, "PT": "T#5s"}, instance=f"{z}BandTmr", w=80)
    ld.coil(900, y + 30, f"{z}OutOfBand", [(t1, "Q")])
    y += 120
    c3 = ld.contact(200, y + 30, f"{z}Valid", [("rail", y + 40)], negated=True)
    t2 = ld.block(320, y, "TON", {"IN": c3, "PT": "T#3s"}, instance=f"{z}QuietTmr", w=80)
    ld.coil(900, y + 30, f"{z}Quiet", [(t2, "Q")])
    return y + 120


def recipe_rungs(ld, y):
    """The product request (HR 1026): each zone's Recipe_Request, then Line_Products, before the
    zones' blocks (which take WriteSettings and Settings from them in the same scan)."""
    ld.comment(40, y, 1400, 60, "Products: HR 1026 (ProductReq) asks for product 1 (A, the line as tuned) or 2 (B). "
               "Each zone's Recipe_Request starts its download (WriteSettings) once the recipes are known, "
               "shows its status in HR 12 / 13 (0 held, 65535 downloading, else the ErrorID) and retries a "
               "transient error after 2 s; Line_Products holds the recipes and the product held (HR 11).")
    y += 80
    for n, _, _, inst, *_ in ZONES:
        z = f"Z{n}"
        blk = ld.block(460, y, "Recipe_Request", {"Request": "ProductReq", "Ready": "Products.Ready",
                                                  "Done": f"{inst}.SettingsDone", "Error": f"{inst}.SettingsError",
                                                  "ErrorID": f"{inst}.SettingsErrorID"},
                       instance=f"{z}Recipe", w=200)
        for pin, var in (("Write", f"{z}RWrite"), ("Status", f"{z}RecipeStatus")):
            px, py = blk.pins[pin]
            ld.outvar(px + 100, py - 15, var, (blk, pin))
        y += ld.height("Recipe_Request") + 40
    inputs = {}
    for n, _, _, inst, *_ in ZONES:
        inputs.update({f"Valid{n}": f"{inst}.Valid", f"Age{n}": f"{inst}.SettingsAge",
                       f"Current{n}": f"{inst}.Current", f"Product{n}": f"Z{n}Recipe.Product",
                       f"Held{n}": f"Z{n}Recipe.Held"})
    blk = ld.block(460, y, "Line_Products", inputs, instance="Products", w=200)
    px, py = blk.pins["Holding"]
    ld.outvar(px + 100, py - 15, "ProductHeld", (blk, "Holding"))
    return y + ld.height("Line_Products") + 40


def rungs(ld):
    ld.comment(40, 20, 1400, 60,
               "heat_treat_ld: zone 1 (FDC-100, slave 1) and zone 2 (SetPro MV-D94, slave 2) held at their "
               "set points and the parts counter (MT-S9, slave 3) on one RS-485 line (BusLine: 9600 8N2 RTU); "
               "alarms when a zone leaves its band or a device goes quiet. Modbus map: examples/heat_treat_ld/README.md.")
    y = recipe_rungs(ld, 100)
    for zone in ZONES:
        y = zone_rungs(ld, y, *zone)

    ld.comment(40, y, 1400, 30, "Parts: Counter_MTS9 counts; writing coil 9 (ResetReq) resets the count, "
               "the coil clears when the reset is done or failed.")
    y += 50
    parts = ld.block(320, y, "Counter_MTS9", {"Enable": ("rail", y + 40), "Port": "BusPort", "SlaveId": "3",
                                              "Line": "BusLine", "Period": "T#500ms", "ResetCount": "ResetReq"},
                     instance="Parts", w=200)
    ld.coil(900, y + 30, "PartsValid", [(parts, "Valid")])
    ld.outvar(940, y + 145, "CountErr", (parts, "ErrorID"))
    d2u = ld.block(620, y + 220, "DINT_TO_UINT", {"IN": (parts, "RealData")}, w=120)
    ld.outvar(820, y + 245, "PartCount", d2u)
    ld.coil(900, y + 590, "ResetReq", [(parts, "ResetDone"), (parts, "ResetError")], storage="reset")
    y += ld.height("Counter_MTS9") + 40

    ld.comment(40, y, 1400, 30, "Alarms: out of band = valid data more than Band from the set point for 5 s; "
               "quiet = no valid data for 3 s.")
    y += 50
    for n, *_ in ZONES:
        y = alarm_rungs(ld, y, n)
    c4 = ld.contact(200, y + 30, "PartsValid", [("rail", y + 40)], negated=True)
    t3 = ld.block(320, y, "TON", {"IN": c4, "PT": "T#3s"}, instance="PartsQuietTmr", w=80)
    ld.coil(900, y + 30, "PartsQuiet", [(t3, "Q")])
    y += 120
    alarms = [f"Z{n}{a}" for n, *_ in ZONES for a in ("OutOfBand", "Quiet")] + ["PartsQuiet"]
    srcs = [ld.contact(200, y + 30 + 40 * k, a, [("rail", y + 40 + 40 * k)]) for k, a in enumerate(alarms)]
    ld.coil(900, y + 30, "AnyAlarm", srcs)
    y += 40 * len(alarms) + 50

    ld.comment(40, y, 1400, 30, "Heartbeat: counts PLC scans (HR 8).")
    y += 50
    add = ld.block(320, y, "ADD", {"IN1": "Heartbeat", "IN2": "1"}, w=80)
    ld.outvar(480, y + 25, "Heartbeat", add)
    return y + 120


VARS = [  # name, type, address, initial value, documentation
    ("BusPort", "<string/>", None, "'/tmp/heat_treat_bus'",
     "The bus. Against the simulator: the --symlink path of mbsim.py; on a PLC: '/dev/ttyUSB0'."),
    ("BusLine", '<derived name="MB_LINE"/>', None,
     "(Baud := 9600, DataBits := 8, Framing := 'RTU', Parity := 'N', StopBits := 2)",
     "One line, one setting for all three instruments: 9600 8N2 Modbus RTU (the MV-D94's default; "
     "the FDC-100 set to no parity, the MT-S9 to 2 stop bits)."),
    ("Band", "<REAL/>", None, "10.0", "allowed |PV - SV| before the band alarm, degrees"),
    ("Zone1", '<derived name="FDC_Controller"/>', None, None, None),
    ("Zone2", '<derived name="TempCtrl_MVD94"/>', None, None, None),
    ("Parts", '<derived name="Counter_MTS9"/>', None, None, None),
    ("Z1BandTmr", '<derived name="TON"/>', None, None, None),
    ("Z1QuietTmr", '<derived name="TON"/>', None, None, None),
    ("Z2BandTmr", '<derived name="TON"/>', None, None, None),
    ("Z2QuietTmr", '<derived name="TON"/>', None, None, None),
    ("PartsQuietTmr", '<derived name="TON"/>', None, None, None),
    ("Z1RetryTmr", '<derived name="TON"/>', None, None, None),
    ("Z2RetryTmr", '<derived name="TON"/>', None, None, None),
    ("Z1Recipe", '<derived name="Recipe_Request"/>', None, None, "zone 1's recipe download"),
    ("Z2Recipe", '<derived name="Recipe_Request"/>', None, None, "zone 2's recipe download"),
    ("Products", '<derived name="Line_Products"/>', None, None, "the line's products: a recipe per zone each"),
    ("Z1RWrite", "<BOOL/>", None, None, "zone 1's WriteSettings: TRUE from the start of a download to its end"),
    ("Z2RWrite", "<BOOL/>", None, None, "zone 2's WriteSettings"),
]
for _n in (1, 2):
    VARS += [
        (f"Z{_n}Req", "<INT/>", None, None, "the set point request being handled, x10"),
        (f"Z{_n}New", "<BOOL/>", None, None, "a new request value in HR 102{_n - 1}"),
        (f"Z{_n}Open", "<BOOL/>", None, None, "a request not settled yet"),
        (f"Z{_n}Settled", "<INT/>", None, None, "the last request that ended: sent, or refused for good"),
        (f"Z{_n}Write", "<BOOL/>", None, None, "WriteSV: TRUE from the start of an attempt to its end"),
        (f"Z{_n}End", "<BOOL/>", None, None, "the attempt ended this scan (SVDone or SVError)"),
        (f"Z{_n}Transient", "<BOOL/>", None, None, "SVErrorID is worth another try"),
        (f"Z{_n}Wait", "<BOOL/>", None, None, "after a transient error: wait 2 s before trying again"),
        (f"Z{_n}SVSet", "<REAL/>", None, None, None),
        (f"Z{_n}Far", "<BOOL/>", None, None, "|PV - SV| > Band"),
    ]
VARS += [
    ("Z1PV", "<INT/>", "%QW0", None, "HR 0: zone 1 PV x10"),
    ("Z1SV", "<INT/>", "%QW1", None, "HR 1: zone 1 SV x10"),
    ("Z1Err", "<WORD/>", "%QW2", None, "HR 2: zone 1 ErrorID"),
    ("Z2PV", "<INT/>", "%QW3", None, "HR 3: zone 2 PV x10"),
    ("Z2SV", "<INT/>", "%QW4", None, "HR 4: zone 2 SV x10"),
    ("Z2Err", "<WORD/>", "%QW5", None, "HR 5: zone 2 ErrorID"),
    ("PartCount", "<UINT/>", "%QW6", None, "HR 6: part count (low 16 bits)"),
    ("CountErr", "<WORD/>", "%QW7", None, "HR 7: counter ErrorID"),
    ("Heartbeat", "<UINT/>", "%QW8", None, "HR 8: scan heartbeat"),
    ("Z1SPStatus", "<WORD/>", "%QW9", None, "HR 9: zone 1 set point status: 0 sent (or none yet), else SVErrorID"),
    ("Z2SPStatus", "<WORD/>", "%QW10", None, "HR 10: zone 2 set point status"),
    ("ProductHeld", "<INT/>", "%QW11", None, "HR 11: the product the line holds: 1 = A, 2 = B, 0 = none yet or changing"),
    ("Z1RecipeStatus", "<WORD/>", "%QW12", None,
     "HR 12: zone 1 recipe status: 0 held (or none yet), 65535 downloading, else SettingsErrorID"),
    ("Z2RecipeStatus", "<WORD/>", "%QW13", None, "HR 13: zone 2 recipe status"),
    ("Z1RecipeField", "<INT/>", "%QW14", None, "HR 14: zone 1 recipe field refused or failed (SettingsField), 0 = none"),
    ("Z2RecipeField", "<INT/>", "%QW15", None, "HR 15: zone 2 recipe field"),
    ("Z1SPReq", "<INT/>", "%MW0", None, "HR 1024: zone 1 set point request x10 (0 = none)"),
    ("Z2SPReq", "<INT/>", "%MW1", None, "HR 1025: zone 2 set point request x10 (0 = none)"),
    ("ProductReq", "<INT/>", "%MW2", None, "HR 1026: product request: 1 = A, 2 = B (0 = keep what the line holds)"),
    ("Z1Valid", "<BOOL/>", "%QX0.0", None, "coil 0"),
    ("Z1OutOfBand", "<BOOL/>", "%QX0.1", None, "coil 1"),
    ("Z1Quiet", "<BOOL/>", "%QX0.2", None, "coil 2"),
    ("Z2Valid", "<BOOL/>", "%QX0.3", None, "coil 3"),
    ("Z2OutOfBand", "<BOOL/>", "%QX0.4", None, "coil 4"),
    ("Z2Quiet", "<BOOL/>", "%QX0.5", None, "coil 5"),
    ("PartsValid", "<BOOL/>", "%QX0.6", None, "coil 6"),
    ("PartsQuiet", "<BOOL/>", "%QX0.7", None, "coil 7"),
    ("AnyAlarm", "<BOOL/>", "%QX1.0", None, "coil 8"),
    ("ResetReq", "<BOOL/>", "%QX1.1", None, "coil 9: write TRUE to reset the part count"),
]


def project(body, blocks):
    vx = [var_xml(name, typ, init, doc, addr) for name, typ, addr, init, doc in VARS]
    fbs = "".join(helper_pou(*b) for b in blocks)
    return f"""<?xml version='1.0' encoding='utf-8'?>
<project xmlns:ns1="http://www.plcopen.org/xml/tc6.xsd" xmlns:xhtml="http://www.w3.org/1999/xhtml" xmlns:xsd="http://www.w3.org/2001/XMLSchema" xmlns="http://www.plcopen.org/xml/tc6_0201">
<fileHeader companyName="modbus-fb" productName="heat_treat_ld" productVersion="1" creationDateTime="2024-01-01T00:00:00"/>
<contentHeader name="heat_treat_ld" modificationDateTime="2024-01-01T00:00:00"><coordinateInfo>
<fbd><scaling x="10" y="10"/></fbd><ld><scaling x="10" y="10"/></ld><sfc><scaling x="10" y="10"/></sfc>
</coordinateInfo></contentHeader>
<types><dataTypes/><pous>{fbs}<pou name="heat_treat_ld" pouType="program"><interface><localVars>{"".join(vx)}</localVars></interface>
<body><LD>{body}</LD></body></pou></pous></types>
<instances><configurations><configuration name="Config0"><resource name="Res0">
<task name="MainTask" priority="0" interval="T#50ms"><pouInstance name="HeatTreatLD" typeName="heat_treat_ld"/></task>
</resource></configuration></configurations></instances>
</project>
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--editor", required=True, help="checkout of thiagoralves/editor")
    ap.add_argument("--palette", required=True, help="build/plc_lib/editor/MBFB_Blocks.xml")
    ap.add_argument("--out", default=HERE, help="where plc.xml and heat_treat_ld.st go")
    args = ap.parse_args()
    structures = editor_tool.load_editor(args.editor, args.palette)
    pins = {}
    for cat in structures.StdBlckLst:
        for b in cat["list"]:
            pins.setdefault(b["name"], ([i[0] for i in b["inputs"]], [o[0] for o in b["outputs"]]))
    blocks = helpers()
    pins.update(helper_pins(blocks))
    ld = Ladder(pins)
    height = rungs(ld)
    with tempfile.TemporaryDirectory() as tmp:
        raw = os.path.join(tmp, "plc.xml")
        with open(raw, "w", encoding="utf-8") as f:
            f.write(project(ld.body(height), blocks))
        # the Editor's serializer writes plc.xml; its generator writes the ST from that file
        editor_tool.generate_st(raw, os.path.join(args.out, "heat_treat_ld.st"), resave=True)
        shutil.move(raw, os.path.join(args.out, "plc.xml"))


if __name__ == "__main__":
    main()
