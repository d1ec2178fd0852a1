"""The OpenPLC Editor files (ctest label editor): the palette library plc_lib/editor generates, and
the ladder example examples/heat_treat_ld (plc.xml, the project as the Editor saves it, and the
ST the Editor's generator made from it).

Checked without the Editor (it is not a build dependency): the TC6 structure the Editor's loader
reads, every public block of the library with exactly the pins matiec compiles (names, types,
directions: a program that wires every pin is compiled by OpenPLC's iec2c), and the LD project's
wiring and its agreement with the ST. The ST compiles in OpenPLC (e2e_compile_examples) and runs
against the simulator (e2e_runtime_ld).
"""
import os
import re
import subprocess
import xml.etree.ElementTree as ET

import pytest

import oplc

NS = {"p": "http://www.plcopen.org/xml/tc6_0201"}
LD_DIR = os.path.join(oplc.ROOT, "examples", "heat_treat_ld")
PALETTE = os.path.join(os.environ.get("MBFB_BUILD", os.path.join(oplc.ROOT, "build")),
                       "plc_lib", "editor", "MBFB_Blocks.xml")


def need_toolchain(why):
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        pytest.fail(why)
    pytest.skip(why)


def q(path):
    return "/".join(f"p:{s}" for s in path.split("/"))


def type_name(var):
    t = var.find("p:type", NS)[0]
    return t.get("name") if t.tag.endswith("derived") else t.tag.split("}")[1].upper()


@pytest.fixture(scope="module")
def palette():
    """{block: {"in": [(name, TYPE)], "out": [...], "inout": [...]}} from the palette XML."""
    assert os.path.isfile(PALETTE), f"{PALETTE} missing: build the mbfb_editor_lib target"
    root = ET.parse(PALETTE).getroot()
    assert root.tag == "{%s}project" % NS["p"]
    for part in ("fileHeader", "contentHeader/coordinateInfo", "types/dataTypes", "types/pous",
                 "instances/configurations"):
        assert root.find(q(part), NS) is not None, f"palette XML lacks {part}"
    blocks = {}
    for pou in root.findall(q("types/pous/pou"), NS):
        assert pou.get("pouType") == "functionBlock"
        iface = pou.find("p:interface", NS)
        blocks[pou.get("name")] = {
            d: [(v.get("name"), type_name(v)) for v in iface.findall(f"p:{tag}/p:variable", NS)]
            for d, tag in (("in", "inputVars"), ("out", "outputVars"), ("inout", "inOutVars"))}
        assert pou.find("p:documentation", NS) is not None
    return blocks


@pytest.fixture(scope="module")
def matiec_pous(tmp_path_factory):
    """matiec's own view of the library: {FB: (interface [(NAME, TYPE)], private types)}."""
    home = oplc.openplc_home()
    dist = os.environ.get("MBFB_DIST", "")
    if not home or not os.path.isfile(os.path.join(dist, "MANIFEST")):
        need_toolchain("OpenPLC's iec2c or the generated library (MBFB_DIST) not found")
    out = tmp_path_factory.mktemp("iec")
    lib = os.path.join(dist, "webserver", "lib", "mbfb.txt")
    r = subprocess.run([os.path.join(home, "webserver", "iec2c"), "-f", "-l", "-p", "-r", "-R", "-a",
                        "-I", os.path.join(home, "webserver", "lib"), lib],
                       cwd=out, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    with open(out / "POUS.h") as f:
        text = f.read()
    pous = {}
    for m in re.finditer(r"// FUNCTION_BLOCK (\w+)\n// Data part\ntypedef struct \{(.*?)\} \1;", text, re.S):
        iface, _, private = m.group(2).partition("// FB private variables")
        decl = re.compile(r"__DECLARE_VAR\((\w+),(\w+)\)|^\s*(\w+) (\w+);", re.M)
        pins = [(g[1], g[0]) for g in decl.findall(iface) if g[0]]
        local_types = {g[0] or g[2] for g in decl.findall(private)}
        pous[m.group(1)] = (pins, local_types)
    assert pous, "no FUNCTION_BLOCK in matiec's POUS.h"
    return pous, lib, home


def test_palette_lists_every_public_block_with_matiecs_pins(palette, matiec_pous):
    pous, _, _ = matiec_pous
    used = set().union(*(types for _, types in pous.values()))
    public = {name for name in pous if name not in used}
    assert {b.upper() for b in palette} == public, "palette blocks != FBs no other FB instantiates"
    assert {"TEMPCTRL_MVD94", "COUNTER_MTS9", "FDC_CONTROLLER"} <= public
    for block, pins in palette.items():
        xml = {n.upper(): t.upper() for d in pins.values() for n, t in d}
        xml.update(EN="BOOL", ENO="BOOL")
        c = dict(pous[block.upper()][0])
        assert set(xml) == set(c), f"{block}: pin names differ from matiec's"
        # matiec names array types anonymously (__ARRAY_OF_WORD_125 for MB_REGS): the
        # compile test below checks those.
        assert {n: t for n, t in xml.items() if not c[n].startswith("__")} == \
            {n: t for n, t in c.items() if not t.startswith("__")}, f"{block}: pin types differ"


def test_palette_pins_compile_with_their_directions_and_types(palette, matiec_pous, tmp_path):
    """A program that passes every input with := and takes every output with =>, each from a
    variable of the palette's type: matiec rejects a wrong direction or type."""
    _, lib, home = matiec_pous
    decls, calls = [], []
    for k, (block, pins) in enumerate(sorted(palette.items())):
        decls.append(f"    b{k} : {block};")
        args = []
        for d, op in (("in", ":="), ("inout", ":="), ("out", "=>")):
            for name, typ in pins[d]:
                decls.append(f"    v{k}_{name} : {typ};")
                args.append(f"{name} {op} v{k}_{name}")
        calls.append(f"  b{k}({', '.join(args)});")
    prog = tmp_path / "pins.st"
    with open(lib) as f:
        body = f.read()
    prog.write_text(body + "\nPROGRAM pins_check\n  VAR\n" + "\n".join(decls) + "\n  END_VAR\n"
                    + "\n".join(calls) + "\nEND_PROGRAM\n")
    r = subprocess.run([os.path.join(home, "webserver", "iec2c"), "-f", "-l", "-p", "-r", "-R", "-a",
                        "-I", os.path.join(home, "webserver", "lib"), str(prog)],
                       cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


# ---------------------------------------------------------------- the ladder example

@pytest.fixture(scope="module")
def ld():
    root = ET.parse(os.path.join(LD_DIR, "plc.xml")).getroot()
    ET.parse(os.path.join(LD_DIR, "beremiz.xml"))  # the Editor opens a folder with both
    pous = root.findall(q("types/pous/pou"), NS)
    # the program in LD, and the two ST function blocks it calls (the product recipes)
    assert [(p.get("name"), p.get("pouType")) for p in pous] == [
        ("Recipe_Request", "functionBlock"), ("Line_Products", "functionBlock"),
        ("heat_treat_ld", "program")]
    for fb in pous[:2]:
        assert fb.find(q("body/ST"), NS) is not None, f"{fb.get('name')}'s body is not ST"
    body = pous[2].find(q("body/LD"), NS)
    assert body is not None, "the program's body is not LD"
    return root, pous[2], body


def st_text():
    with open(os.path.join(LD_DIR, "heat_treat_ld.st")) as f:
        return f.read()


def test_ld_is_a_ladder_with_our_blocks_wired(ld, palette):
    _, _, body = ld
    kinds = [el.tag.split("}")[1] for el in body]
    for k in ("leftPowerRail", "rightPowerRail", "contact", "coil", "block"):
        assert k in kinds, f"no {k} in the LD body"
    ids = {el.get("localId") for el in body}
    for conn in body.iter("{%s}connection" % NS["p"]):
        assert conn.get("refLocalId") in ids, f"dangling connection to {conn.get('refLocalId')}"
    ours = [b for b in body.findall("p:block", NS) if b.get("typeName") in palette]
    assert {"FDC_Controller", "TempCtrl_MVD94", "Counter_MTS9"} <= {b.get("typeName") for b in ours}
    for b in ours:
        pins = palette[b.get("typeName")]
        for d, tag in (("in", "inputVariables"), ("out", "outputVariables")):
            got = [v.get("formalParameter") for v in b.findall(f"p:{tag}/p:variable", NS)]
            assert got == [n for n, _ in pins[d]], f"{b.get('instanceName')}: {tag} differ from the palette"
    # the counter's ResetCount is wired, and a coil clears the request when the reset ends
    parts = next(b for b in ours if b.get("typeName") == "Counter_MTS9")
    reset_in = parts.find("p:inputVariables/p:variable[@formalParameter='ResetCount']/p:connectionPointIn/p:connection", NS)
    assert reset_in is not None
    coils = {c.find("p:variable", NS).text: c for c in body.findall("p:coil", NS)}
    srcs = {(c.get("refLocalId"), c.get("formalParameter")) for c in coils["ResetReq"].iter("{%s}connection" % NS["p"])}
    assert srcs == {(parts.get("localId"), "ResetDone"), (parts.get("localId"), "ResetError")}
    assert coils["ResetReq"].get("storage") == "reset"


def st_vars(st):
    """{name: (address, type, initial)} of the ST program's declarations."""
    prog = st.split("END_PROGRAM")[0].split("\nPROGRAM ")[1]
    out = {}
    for m in re.finditer(r"^\s*(\w+)(?: AT (%\S+))? : ([^:;]+?)(?: := ([^;]+))?;$", prog, re.M):
        out[m.group(1)] = (m.group(2), m.group(3).strip(), m.group(4))
    return out


def test_st_is_the_ld_compiled(ld):
    root, pou, body = ld
    st = st_text()
    vars_st = st_vars(st)
    xml_vars = {}
    for v in pou.findall(q("interface/localVars/variable"), NS):
        init = v.find(q("initialValue/simpleValue"), NS)
        xml_vars[v.get("name")] = (v.get("address"), type_name(v), init.get("value") if init is not None else None)
    assert {k: v for k, v in vars_st.items() if not k.startswith("_TMP_")} == xml_vars
    assert vars_st["BusPort"][2] == f"'{oplc.EXAMPLE_BUS}'"
    # the line, with the FDC-100's parity, comes from the declaration alone (no code sets it)
    assert vars_st["BusLine"][1:] == ("MB_LINE", "(Baud := 9600, DataBits := 8, Framing := 'RTU', "
                                                 "Parity := 'N', StopBits := 2)")
    assert not re.search(r"\bBusLine\.", st)
    for b in body.findall("p:block", NS):
        name = b.get("instanceName") or b.get("typeName")
        assert re.search(rf"\b{name}\(", st), f"block {name} is not called in the ST"
    for c in body.findall("p:coil", NS):
        var = c.find("p:variable", NS).text
        assert re.search(rf"^\s*{var} := ", st, re.M), f"coil {var} is not assigned in the ST"
    for c in body.findall("p:contact", NS):
        assert re.search(rf"\b{c.find('p:variable', NS).text}\b", st.split("END_VAR")[-1])
    task = root.find(q("instances/configurations/configuration/resource/task"), NS)
    inst = task.find("p:pouInstance", NS)
    assert (f"TASK {task.get('name')}(INTERVAL := {task.get('interval')},PRIORITY := {task.get('priority')});"
            in st)
    assert f"PROGRAM {inst.get('name')} WITH {task.get('name')} : {inst.get('typeName')};" in st


def test_ld_set_point_request_is_sent_only_when_valid_and_settled_on_the_result(ld):
    """Each zone's WriteSV (ZnWrite) is set only through Valid and no pending SVDone/SVError, and
    reset when the attempt ended; the status register takes SVErrorID."""
    _, _, body = ld
    els = {el.get("localId"): el for el in body}
    st = st_text()
    for n in (1, 2):
        writes = [c for c in body.findall("p:coil", NS) if c.find("p:variable", NS).text == f"Z{n}Write"]
        assert sorted(c.get("storage") for c in writes) == ["reset", "set"]
        chain, el = [], next(c for c in writes if c.get("storage") == "set")
        while True:  # walk the series contacts back to the rail
            conns = el.findall("p:connectionPointIn/p:connection", NS)
            assert len(conns) == 1
            el = els[conns[0].get("refLocalId")]
            if not el.tag.endswith("contact"):
                break
            chain.append((el.find("p:variable", NS).text, el.get("negated") == "true"))
        assert el.tag.endswith("leftPowerRail")
        assert set(chain) == {(f"Z{n}Open", False), (f"Z{n}Wait", True), (f"Zone{n}.Valid", False),
                              (f"Zone{n}.SVDone", True), (f"Zone{n}.SVError", True)}
        assert st_vars(st)[f"Z{n}SPStatus"] == (f"%QW{8 + n}", "WORD", None)
        assert re.search(rf"MOVE\(EN := Z{n}End, IN := Zone{n}\.SVErrorID", st)
        assert re.search(rf"WriteSV := Z{n}Write, SVSet := Z{n}SVSet[,)]", st)


def test_ld_product_request_downloads_each_zones_recipe(ld):
    """HR 1026 (ProductReq) drives each zone's Recipe_Request, whose Write is the zone's
    WriteSettings and whose product selects the recipe Line_Products gives the zone's Settings
    (both blocks the ST example's, the same text), in that order in the scan; the status
    registers of the ST example's map (HR 11..15)."""
    root, _, body = ld
    st = st_text()
    with open(os.path.join(oplc.ROOT, "examples", "heat_treat_st", "heat_treat_st.st")) as f:
        example = f.read()
    code = lambda t: [x.strip() for x in t.split("END_VAR")[-1].strip().splitlines()]  # noqa: E731
    for name in ("Recipe_Request", "Line_Products"):
        fb = st.split(f"FUNCTION_BLOCK {name}\n")[1].split("END_FUNCTION_BLOCK")[0]
        want = example.split(f"FUNCTION_BLOCK {name}\n")[1].split("END_FUNCTION_BLOCK")[0]
        assert code(fb) == code(want), f"{name} is not the ST example's"
    v = st_vars(st)
    assert v["ProductReq"] == ("%MW2", "INT", None)
    assert v["ProductHeld"] == ("%QW11", "INT", None)
    calls = [st.index(f"{c}(") for c in ("Z1Recipe", "Z2Recipe", "Products", "Zone1", "Zone2")]
    assert calls == sorted(calls), "the requests, then the recipes, then the zones"
    for n in (1, 2):
        assert v[f"Z{n}RecipeStatus"] == (f"%QW{11 + n}", "WORD", None)
        assert v[f"Z{n}RecipeField"] == (f"%QW{13 + n}", "INT", None)
        assert re.search(rf"Z{n}Recipe\(Request := ProductReq, Ready := Products\.Ready, "
                         rf"Done := Zone{n}\.SettingsDone, Error := Zone{n}\.SettingsError, "
                         rf"ErrorID := Zone{n}\.SettingsErrorID\);", st)
        assert re.search(rf"Z{n}RWrite := Z{n}Recipe\.Write;", st)
        assert re.search(rf"Product{n} := Z{n}Recipe\.Product, Held{n} := Z{n}Recipe\.Held", st)
        assert re.search(rf"WriteSettings := Z{n}RWrite, Settings := Products\.Recipe{n}\)", st)
        assert re.search(rf"Z{n}RecipeField := Zone{n}\.SettingsField;", st)
    assert "ProductHeld := Products.Holding;" in st
