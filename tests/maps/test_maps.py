"""The register maps against the manuals' worked frames, byte for byte (ctest maps.frames).

The frames are in each map's "frames" (copied from the manuals, see maps/README.md). For each:
the checksum (CRC-16/MODBUS low byte first, LRC for ASCII, 00 00 in RTU-without-CRC requests),
the function code and addresses against the map's function windows, and every value the manual
names, decoded from the frame's words at the map's address with the map's encoding and scale.
The checker is also run on deliberately wrong maps, so it is shown to catch a wrong address,
scale, word order or code.
"""
from __future__ import annotations

import copy
import json
import os
import struct
import subprocess
import sys
import tempfile

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
MAPS = os.path.join(os.path.dirname(os.path.dirname(HERE)), "maps")  # the product: maps/
sys.path.insert(0, MAPS)
import mbmap  # noqa: E402

PY = sys.executable


def crc16(data: bytes) -> int:
    c = 0xFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return c


def lrc(data: bytes) -> int:
    return (-sum(data)) & 0xFF


def unframe(text: str, framing: str, request: bool):
    """(address, PDU) of a frame written as in the map; asserts its checksum."""
    if framing == "ascii":
        assert text.startswith(":") and text.endswith("\r\n"), text
        raw = bytes.fromhex(text[1:-2])
        assert lrc(raw[:-1]) == raw[-1], f"LRC of {text!r}: {lrc(raw[:-1]):02X}"
        return raw[0], raw[1:-1]
    raw = bytes.fromhex(text)
    body, check = raw[:-2], raw[-2:]
    if framing == "nocrc" and request:
        assert check == b"\0\0", f"RTU without CRC sends 00 00: {text}"
    else:
        assert check == struct.pack("<H", crc16(body)), \
            f"CRC of {text}: {struct.pack('<H', crc16(body)).hex(' ').upper()}"
    return body[0], body[1:]


def words_of(fc: int, req: bytes, rep: bytes | None):
    """{address: word} a frame carries: read replies, FC06 value, FC16 data."""
    if fc in (3, 4):
        start, count = struct.unpack(">HH", req[1:5])
        if rep is None:
            return start, count, {}
        assert rep[0] == fc and rep[1] == 2 * count and len(rep) == 2 + 2 * count
        return start, count, dict(zip(range(start, start + count),
                                      struct.unpack(f">{count}H", rep[2:])))
    if fc == 6:
        addr, value = struct.unpack(">HH", req[1:5])
        if rep is not None:
            assert rep == req, "FC06 reply echoes the request"
        return addr, 1, {addr: value}
    if fc == 16:
        start, count, nbytes = struct.unpack(">HHB", req[1:6])
        assert nbytes == 2 * count and len(req) == 6 + nbytes
        if rep is not None:
            assert rep == req[:5], "FC16 reply echoes address and count"
        return start, count, dict(zip(range(start, start + count),
                                      struct.unpack(f">{count}H", req[6:])))
    raise AssertionError(f"function {fc} in a worked frame")


def check_frame(m: mbmap.Map, f: dict):
    framing = f.get("framing", "rtu")
    addr, req = unframe(f["request"], framing, True)
    rep = None
    if f.get("reply"):
        raddr, rep = unframe(f["reply"], framing, False)
        assert raddr == addr
    fc = req[0]
    assert fc in m.function_codes, f"FC{fc:02d} not in the map"
    start, count, words = words_of(fc, req, rep)
    fn = m.function(fc)
    windows = [fn["window"]] + ([fn["alias_window"]] if "alias_window" in fn else [])
    assert any(lo <= start and start + count - 1 <= hi for lo, hi in windows), \
        f"{start}+{count} outside the FC{fc:02d} windows {windows}"
    assert count <= fn.get("max_words", 1)
    aliases = {a: r.addr for r in m.registers for a in r.aliases_at}
    state = {}                              # registers the frame itself sets (INPT, DP...)
    for a, w in words.items():
        r = m.by_addr.get(aliases.get(a, a))
        if r is not None and r.words == 1:
            state[r.name] = w
    for name in f.get("reads", []):
        r = m.reg(name)
        at = [r.addr, *r.aliases_at]
        assert any(start <= a < start + count for a in at), f"{name} ({at}) not in {start}+{count}"
        assert fc in r.fc
    for key, want in f["values"].items():
        name, _, part = key.partition(":")
        r = m.reg(name)
        assert fc in r.fc, f"{r.name} is not reached by FC{fc:02d}"
        base = next((a for a in [r.addr, *r.aliases_at] if a in words), None)
        assert base is not None, f"{r.name} at {r.addr} is not in the frame ({start}+{count})"
        if part == "low":                   # FC06 to the low word of a 32-bit register
            raw = words[base]
        else:
            ws = [words.get(base + i) for i in range(r.words)]
            assert None not in ws, f"{r.name}: {r.words} words, frame has {ws}"
            raw = m.decode_words(r, ws)
        if isinstance(want, str):           # a code of the register's table (or its name's)
            assert raw == m.code(r.codes or r.name, want), f"{r.name} = {raw:#06x}, not {want}"
        elif isinstance(want, float):
            got = m.to_eng(r, raw, state)
            assert round(got, 6) == want, f"{r.name} = {got} (raw {raw}), manual {want}"
        else:
            assert raw == want, f"{r.name} = {raw}, manual {want}"


CASES = [(dev, i) for dev in mbmap.DEVICES for i in range(len(mbmap.load(dev).frames))]


@pytest.mark.parametrize("dev,i", CASES, ids=[f"{d}-{i}" for d, i in CASES])
def test_worked_frame(dev, i):
    m = mbmap.load(dev)
    check_frame(m, m.frames[i])


def test_every_device_has_frames_and_sources():
    for dev in mbmap.DEVICES:
        m = mbmap.load(dev)
        assert len(m.frames) >= 3, dev
        assert all(r.source and r.confidence in ("H", "M", "M-H", "L", "H (order) / M (signed)")
                   or r.confidence for r in m.registers)
        assert not mbmap.validate(m)


def mutated(dev, change):
    """The device's map changed by change(data), loaded from a temporary folder."""
    with open(mbmap.path_of(dev), encoding="utf-8") as fh:
        data = json.load(fh)
    data = copy.deepcopy(data)
    change(data)
    with tempfile.TemporaryDirectory(prefix="mbfb-maps-") as tmp:
        with open(os.path.join(tmp, f"{dev}.json"), "w", encoding="utf-8") as fh:
            json.dump(data, fh)
        return mbmap.load(dev, tmp)


def reg_entry(data, name):
    return next(r for r in data["registers"] if r["name"] == name)


@pytest.mark.parametrize("dev,change,frame", [
    ("mvd94", lambda d: reg_entry(d, "SV").update(addr=0x22), 0),          # wrong address
    ("mvd94", lambda d: d["functions"]["4"].update(window=[0x2000, 0x2002]), 1),   # window
    ("mts9", lambda d: reg_entry(d, "Real Data").update(type="uint16", words=1), 2),
    ("fdc100", lambda d: reg_entry(d, "SP1").update(scale="S5"), 0),       # wrong scale
    ("fdc100", lambda d: d["tables"]["CMND"]["codes"].update(RESET=0x6826), 3),   # wrong code
    ("fdc100", lambda d: reg_entry(d, "CMND").update(addr=73), 3),
])
def test_the_check_catches_a_wrong_map(dev, change, frame):
    with pytest.raises((AssertionError, KeyError, mbmap.MapError)):
        m = mutated(dev, change)        # (a clash of addresses is refused at load)
        check_frame(m, m.frames[frame])


def test_a_wrong_checksum_is_caught():
    m = mbmap.load("mvd94")
    f = dict(m.frames[0], request="01 03 00 00 00 01 84 0B")
    with pytest.raises(AssertionError):
        check_frame(m, f)


# ----- check_st.py on ST written here -----
def run_check_st(text: str):
    with tempfile.TemporaryDirectory(prefix="mbfb-maps-") as tmp:
        path = os.path.join(tmp, "t.st")
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
        r = subprocess.run([PY, os.path.join(HERE, "check_st.py"), path], capture_output=True,
                           text=True, timeout=60, check=False)
    return r.returncode, r.stdout + r.stderr


GOOD = """FUNCTION_BLOCK X
  VAR CONSTANT
    MVD_REG_SV : UINT := 16#0000;  (* comment *) MVD_REG_PV : UINT := 16#1000;
    MVD_DP_00_00 : UINT := 16#12;
    MTS_REG_REAL_DATA : UINT := 0; MTS_TYPE_ASCII : UINT := 0;
    FDC_CMND_AUTOTUNE : UINT := 26664; FDC_FC03_MAX_WORDS : INT := 80;
    FDC_OFFSET_N1 : UINT := 19999; FDC_REG_MV1 : UINT := 66;
  END_VAR
  VAR x : INT; END_VAR
END_FUNCTION_BLOCK
"""


def test_check_st_accepts_constants_equal_to_the_maps():
    rc, out = run_check_st(GOOD)
    assert rc == 0, out
    assert "9 constants, 0 differ" in out


@pytest.mark.parametrize("line,why", [
    ("MVD_REG_SV : UINT := 16#0001;", "says 0"),
    ("FDC_CMND_RESET : UINT := 16#6826;", "says 26661"),
    ("FDC_REG_SPX : UINT := 0;", "no register named"),
    ("MTS_FOO_BAR : UINT := 0;", "unknown to mts9.json"),
    ("FDC_REG_PV : UINT := 16#ZZ;", "not an integer"),
])
def test_check_st_fails_on_any_difference(line, why):
    rc, out = run_check_st(GOOD.replace("  END_VAR\n  VAR x", f"    {line}\n  END_VAR\n  VAR x"))
    assert rc == 1 and why in out, out


# the tables held as named constants in st_src: each shown to fail when one value is wrong
TABLES = """    MVD_UNIT_CODE_DEGC : INT := 16#0C; MVD_UNIT_CODE_DEGF : INT := 16#0D;
    MVD_UNIT_CODE_ENG : INT := 16#0E;
    MVD_BAUD_BPS_BY_CODE : ARRAY[28..31] OF DINT := [2400, 4800, 9600, 19200];
    MTS_BAUD_BY_CODE : ARRAY[0..9] OF DINT := [2400, 4800, 9600, 14400, 19200, 28800, 38400, 57600,
                                               76800, 115200];
"""


def with_tables(text: str) -> str:
    return GOOD.replace("  END_VAR\n  VAR x", text + "  END_VAR\n  VAR x")


def test_check_st_accepts_the_code_alias_and_tables_by_code():
    rc, out = run_check_st(with_tables(TABLES))
    assert rc == 0, out
    assert "14 constants, 0 differ" in out
    assert "MVD_UNIT_CODE_ENG = 14: ok (UNIT code ENG)" in out
    assert "MTS_BAUD_BY_CODE: ok (BAUD labels by code 0..9)" in out


@pytest.mark.parametrize("old,new,why", [
    ("MVD_UNIT_CODE_ENG : INT := 16#0E", "MVD_UNIT_CODE_ENG : INT := 16#0F", "says 14"),
    ("MVD_UNIT_CODE_DEGF : INT := 16#0D", "MVD_UNIT_CODE_DEGK : INT := 16#0D", "has no label DEGK"),
    ("[2400, 4800, 9600, 19200]", "[2400, 4800, 9600, 38400]", "says [28..] [2400, 4800, 9600, 19200]"),
    ("ARRAY[28..31]", "ARRAY[27..30]", "says [28..]"),
    ("14400, 19200, 28800", "19200, 14400, 28800", "says [0..] [2400, 4800, 9600, 14400"),
    ("76800, 115200]", "76800]", "elements for [0..9]"),
])
def test_check_st_fails_on_a_wrong_table_constant(old, new, why):
    assert old in TABLES
    rc, out = run_check_st(with_tables(TABLES.replace(old, new)))
    assert rc == 1 and why in out, out


# a decoder's CASE table: literal labels (matiec takes no named constant there), named by the
# comment that ends each label line
DECODER = """FUNCTION MVD_DECODE_X : INT
  VAR_INPUT
    Code : WORD;
  END_VAR
  CASE WORD_TO_INT(Code) OF
    22, 56: MVD_DECODE_X := 0;     (* MVD_AFU_NONE, MVD_AFU_NONE38: either code *)
    48: MVD_DECODE_X := 1;         (* MVD_AFU_HI *)
    -1: MVD_DECODE_X := 2;         (* MVD_AFU_LO *)
  ELSE
    MVD_DECODE_X := 3;
  END_CASE;
END_FUNCTION
"""


def test_check_st_checks_the_named_case_labels():
    rc, out = run_check_st(DECODER.replace("-1:", "49:"))
    assert rc == 0, out
    assert "MVD_AFU_NONE38 = 56: ok (AFU code NONE38)" in out
    assert "4 constants, 0 differ" in out


@pytest.mark.parametrize("old,new,why", [
    ("-1:", "-1:", "MVD_AFU_LO = -1"),                                  # a wrong code
    ("-1:", "50:", "MVD_AFU_LO = 50"),
    ("22, 56:", "22, 57:", "MVD_AFU_NONE38 = 57"),
    ("(* MVD_AFU_HI *)", "(* MVD_AFU_HIGH *)", "has no label HIGH"),     # a misspelt name
    ("(* MVD_AFU_HI *)", "(* the high alarm *)", "of a decoder names no code"),
    ("(* MVD_AFU_HI *)", "", "of a decoder names no code"),
    ("MVD_AFU_NONE, MVD_AFU_NONE38", "MVD_AFU_NONE", "one name per label"),
])
def test_check_st_fails_on_a_wrong_case_label(old, new, why):
    assert old in DECODER
    rc, out = run_check_st(DECODER.replace(old, new, 1))
    assert rc == 1 and why in out, out


def test_check_st_fails_when_it_finds_no_constant():
    text = GOOD.replace("VAR CONSTANT", "VAR").replace("MVD_", "X_").replace("MTS_", "Y_")
    rc, out = run_check_st(text.replace("FDC_", "Z_"))
    assert rc == 1 and "no MVD_/MTS_/FDC_ constant" in out, out


def test_check_st_ignores_commented_constants():
    rc, out = run_check_st(GOOD.replace("  END_VAR\n  VAR x",
                                        "    (* MVD_REG_SV : UINT := 5; *)\n  END_VAR\n  VAR x"))
    assert rc == 0, out


def test_readme_is_generated_from_the_maps():
    import mkdoc
    with open(os.path.join(MAPS, "README.md"), encoding="utf-8") as fh:
        assert fh.read() == mkdoc.render(), "run python3 maps/mkdoc.py"
