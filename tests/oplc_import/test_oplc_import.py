"""tools/oplc_import: the readers on OpenPLC's own files (fixtures/*.cfg written by OpenPLC v3's
generate_mbconfig(), mkfixture.py; v4_plant.json accepted by Runtime v4's own config model), the
located addresses modbus_master.cpp assigns, the generated ST (MB_Poll ranges, writes on change,
status), bad entries (one line each with its id, nothing written), the user's program mode
(--into), and a compile check of every output with matiec as OpenPLC runs it, compiled as C++."""
import os
import re
import shutil
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
TOOL = os.path.join(ROOT, "tools", "oplc_import")
FIX = os.path.join(HERE, "fixtures")
sys.path[:0] = [TOOL, HERE]
import readers  # noqa: E402
import gen  # noqa: E402
import line_plant  # noqa: E402

REQUIRE = os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1"


def fixture(name):
    with open(os.path.join(FIX, name), encoding="utf-8") as fh:
        return fh.read()


def run(*args):
    return subprocess.run([sys.executable, os.path.join(TOOL, "oplc_import.py"), *args],
                          capture_output=True, text=True, timeout=60, check=False)


def need(path, what):
    if not os.path.exists(path):
        if REQUIRE:
            pytest.fail(f"{what} is not at {path}")
        pytest.skip(f"{what} is not at {path}")


# ----- the fixtures are OpenPLC's own -----
def test_v3_fixtures_are_what_openplc_writes():
    import mkfixture
    home = os.environ.get("OPENPLC_HOME") or "/opt/OpenPLC_v3"
    need(os.path.join(home, "webserver", "webserver.py"), "OpenPLC v3's webserver.py")
    for plant, rows in mkfixture.PLANTS.items():
        assert mkfixture.make(home, plant, rows) == fixture(f"{plant}.cfg"), plant


def test_v4_fixture_is_accepted_by_the_plugins_model():
    home = os.environ.get("OPENPLC_V4_HOME") or "/opt/openplc-runtime"
    model = os.path.join(home, "core", "src", "drivers", "plugins", "python", "shared",
                         "plugin_config_decode")
    need(os.path.join(model, "modbus_master_config_model.py"), "Runtime v4's config model")
    code = ("import sys; sys.path.insert(0, sys.argv[1]);"
            "from modbus_master_config_model import ModbusMasterConfig as M;"
            "c = M(); c.import_config_from_file(sys.argv[2]); c.validate();"
            "print([(d.name, d.transport, d.slave_id, len(d.io_points)) for d in c.devices])")
    out = subprocess.run([sys.executable, "-c", code, model, os.path.join(FIX, "v4_plant.json")],
                         capture_output=True, text=True, timeout=60, check=True)
    assert "[('relays', 'rtu', 2, 3), ('meter', 'rtu', 5, 4), ('gateway', 'tcp', 3, 2)]" \
        in out.stdout


# ----- v3: what modbus_master.cpp polls, and where it puts it -----
def test_v3_devices_and_located_addresses():
    devices, period, problems = readers.read_v3(fixture("plant.cfg"), "plant.cfg")
    assert problems == [] and period == 100
    relays, meter, esp, vfd = devices
    assert (relays.port, relays.slave, relays.baud, relays.parity, relays.data_bits,
            relays.stop_bits, relays.timeout_ms) == ("/dev/ttyUSB0", 2, 9600, "N", 8, 2, 1000)
    assert (esp.port, esp.slave, vfd.port, vfd.slave) == \
        ("tcp://127.0.0.1:5020", 1, "tcp://127.0.0.1:5021", 7)
    got = {d.name: [(r.fc, r.addr, r.count, r.located[0], r.located[-1]) for r in d.reads + d.writes]
           for d in devices}
    # modbus_master.cpp: per device DI, coils, IR, HR read, HR write; each area's index runs
    # on from device to device (bool_input_index, bool_output_index, int_input_index for IR
    # and HR read, int_output_index), %IX100.0 / %QX100.0 / %IW100 / %QW100 first.
    assert got == {
        "relays": [(2, 0, 8, "%IX100.0", "%IX100.7"), (15, 0, 4, "%QX100.0", "%QX100.3")],
        "meter": [(4, 0, 8, "%IW100", "%IW107"), (3, 20, 4, "%IW108", "%IW111"),
                  (16, 10, 2, "%QW100", "%QW101")],
        "esp io": [(2, 0, 8, "%IX101.0", "%IX101.7"), (4, 0, 1, "%IW112", "%IW112"),
                   (15, 0, 8, "%QX100.4", "%QX101.3"), (16, 0, 1, "%QW102", "%QW102")],
        "vfd": [(3, 8192, 3, "%IW113", "%IW115"), (16, 8192, 2, "%QW103", "%QW104")],
    }


def test_v3_windows_port_and_parity():
    devices, _, problems = readers.read_v3(fixture("com_port.cfg"), "com_port.cfg")
    assert problems == []
    (uno,) = devices
    assert (uno.port, uno.baud, uno.parity, uno.data_bits, uno.stop_bits) == \
        ("/dev/ttyS2", 115200, "E", 8, 1)


def test_v3_bad_entries_one_line_each_nothing_written(tmp_path):
    out = tmp_path / "out.st"
    res = run(os.path.join(FIX, "bad.cfg"), "-o", str(out))
    assert res.returncode == 2 and res.stdout == "" and not out.exists()
    assert "Traceback" not in res.stderr
    lines = res.stderr.splitlines()
    assert [re.match(r"oplc_import: error (OI-\d\d): ", x).group(1) for x in lines] == \
        ["OI-03", "OI-07", "OI-05", "OI-11"]
    assert "device0 'big' Input_Registers 0+130: 130 registers for FC04" in lines[0]
    assert "device1 'paused': RTU_TX_Pause 50 ms" in lines[1]
    assert "device3 'broadcast': slave id 0" in lines[2]
    assert "device2 'other line': /dev/ttyUSB0 at 19200 8N1" in lines[3]


def test_v3_malformed_files():
    assert readers.read_v3('Num_Devices = "1"\nPolling_Period = "100"\nTimeout = "1000"\n'
                           'device0.name = "x"\n', "m.cfg")[2][0].pid == "OI-02"
    with pytest.raises(readers.Problem) as err:
        readers.read_v3("hello\n", "m.cfg")
    assert err.value.pid == "OI-01"
    problems = readers.read_v3(fixture("plant.cfg").replace('device1.slave_id = "5"',
                                                            'device1.slave_id = "five"'), "p")[2]
    assert [p.pid for p in problems] == ["OI-02"] and "'five' is not a number" in problems[0].what


def test_v3_past_openplcs_400_words():
    text = fixture("plant.cfg").replace('device1.Input_Registers_Size = "8"',
                                        'device1.Input_Registers_Size = "120"')
    for i in range(3):      # four devices of 120 input registers: the fourth is past %IW499
        text = text.replace(f'device{i}.Input_Registers_Size = "{0 if i != 2 else 1}"',
                            f'device{i}.Input_Registers_Size = "120"')
    text = text.replace('device3.Holding_Registers_Read_Size = "3"',
                        'device3.Holding_Registers_Read_Size = "125"')
    problems = readers.read_v3(text, "p")[2]
    assert [p.pid for p in problems] == ["OI-08"] and "Holding_Registers_Read" in problems[0].where


# ----- v4 -----
def test_v4_devices_and_located_addresses():
    devices, _, problems = readers.read_v4(fixture("v4_plant.json"), "v4.json")
    assert problems == []
    relays, meter, gw = devices
    assert (meter.port, meter.slave, meter.timeout_ms, gw.port, gw.slave) == \
        ("/dev/ttyUSB0", 5, 500, "tcp://127.0.0.1:5024", 3)
    assert [(r.fc, r.addr, r.count, r.period_ms) for r in relays.reads + relays.writes] == \
        [(2, 0, 8, 100), (15, 0, 4, 100), (5, 4, 1, 100)]
    # the plugin: bits from the located bit on, across bytes; one WORD per register
    assert gw.reads[0].located == ["%IX2.4", "%IX2.5", "%IX2.6", "%IX2.7", "%IX3.0", "%IX3.1"]
    assert (gw.reads[0].addr, gw.reads[1].addr) == (0x0C00, 0x0100)
    assert meter.writes[1].located == ["%QW101", "%QW102"]


def test_v4_bad_entries(tmp_path):
    res = run(os.path.join(FIX, "v4_bad.json"), "-o", str(tmp_path / "o.st"))
    assert res.returncode == 2 and not (tmp_path / "o.st").exists()
    ids = [re.match(r"oplc_import: error (OI-\d\d): ", x).group(1) for x in res.stderr.splitlines()]
    assert ids == ["OI-08", "OI-09", "OI-09", "OI-03", "OI-10"]
    assert "io_points[5]: %IX1.2 is also" in res.stderr
    res = run(os.path.join(FIX, "plant.cfg"), "--v4", "-o", str(tmp_path / "o.st"))
    assert res.returncode == 2 and res.stderr.startswith("oplc_import: error OI-01: plant.cfg: not JSON")
    assert len(res.stderr.splitlines()) == 1


# ----- the generated ST -----
def generated(name, *args):
    res = run(os.path.join(FIX, name), "-o", "-", *args)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_generated_polls_writes_and_status():
    st = generated("plant.cfg")
    # one MB_Poll per device here (every range fits one), with its ranges in order
    assert "dev1_poll0(Enable := TRUE,\n    Port := oplc_port0, SlaveId := 5, Line := dev1_line,\n" \
           "    Period := T#100ms,\n    Fc1 := 4, Addr1 := 0, Count1 := 8,\n" \
           "    Fc2 := 3, Addr2 := 20, Count2 := 4);" in st
    # range 2's words follow range 1's; bits and words count apart
    assert "oplc_IW108 := dev1_poll0.Words[8];" in st
    assert "oplc_IW112 := dev2_poll0.Words[0];" in st and "oplc_IX101_0 := dev2_poll0.Bits[0];" in st
    # outputs: the located output bits/words into the write blocks, FC15/FC16 (as v3 does)
    assert "dev2_write0.Values[7] := oplc_QX101_3;" in st
    assert "dev3_write0(Port := oplc_port2, SlaveId := 7, Line := dev3_line, Addr := 8192, " \
           "Count := 2, Single := FALSE" in st
    # each located address declared once, each device's status
    decls = re.findall(r"AT (%\S+) :", st)
    assert len(decls) == len(set(decls)) == 8 + 8 + 4 + 8 + 16 + 5
    for i in range(4):
        assert f"dev{i}_Valid : BOOL;" in st and f"dev{i}_ErrorID : WORD;" in st
    assert "dev1_line : MB_LINE := (Baud := 9600, DataBits := 8, Parity := 'N', StopBits := 2, " \
           "TimeoutMs := 1000);" in st


def test_generated_single_writes_and_periods():
    st = generated("v4_plant.json")
    assert "Addr := 4, Count := 1, Single := TRUE" in st          # FC05 stays FC05
    assert "Addr := 10, Count := 1, Single := TRUE" in st         # FC06 stays FC06
    # a 200 ms and a 1000 ms range of one device: two MB_Poll instances
    assert "Period := T#200ms,\n    Fc1 := 4" in st and "Period := T#1000ms,\n    Fc1 := 3" in st


def test_v4_standalone_notes_that_runtime_v4_keeps_i_per_program(tmp_path):
    """Runtime v4 never passes a program's %I writes on (strucpp_v4_import shows the image's
    %IW100 at 0 with the blocks): a v4 PROGRAM of its own gets one note, --into none, v3 none."""
    res = run(os.path.join(FIX, "v4_plant.json"), "-o", "-")
    assert res.returncode == 0 and res.stdout
    assert res.stderr.splitlines() == [
        "oplc_import: note: Runtime v4 passes no program's writes to %I on to other programs or "
        "plugins: put this into the program that uses the addresses (--into FILE)"]
    user = tmp_path / "main.st"
    user.write_text(USER)
    res = run(os.path.join(FIX, "v4_plant.json"), "--into", str(user), "-o", "-")
    assert res.returncode == 0 and res.stderr == ""
    res = run(os.path.join(FIX, "plant.cfg"), "-o", "-")
    assert res.returncode == 0 and res.stderr == ""


def test_packing_over_125_words():
    d = readers.Device("x", "/dev/ttyUSB0", 1, 9600, "N", 8, 1)
    for fc, n in ((4, 100), (3, 100), (2, 2000), (1, 16)):
        d.reads.append(readers.Range(fc, 0, n, ["%IW0"] * n, 100, "w"))
    polls = gen.pack_polls(d)
    assert [[(r.fc, r.count) for r in p] for p in polls] == [[(4, 100), (1, 16)], [(3, 100)],
                                                              [(2, 2000)]]
    assert all(sum(r.words for r in p) <= 125 for p in polls)


USER = """(* the user's program, as OpenPLC compiles it *)
PROGRAM main
  VAR
    level AT %IW100 : INT;
    pump AT %QX100.0 : BOOL;
    alarm AT %IX100.3 : BOOL;
    speed AT %QW103 : UINT;
  END_VAR
  VAR
    t : TON;
  END_VAR
  pump := level > 100 AND NOT alarm;
  speed := 1500;
END_PROGRAM

""" + line_plant.CONFIGURATION


def test_into_the_users_program(tmp_path):
    user = tmp_path / "main.st"
    user.write_text(USER)
    out = tmp_path / "main_mb.st"
    res = run(os.path.join(FIX, "plant.cfg"), "--into", str(user), "-o", str(out))
    assert res.returncode == 0, res.stderr
    st = out.read_text()
    # the user's names, converted to and from their types; their declarations not repeated
    assert "level := WORD_TO_INT(dev1_poll0.Words[0]);" in st
    assert "alarm := dev0_poll0.Bits[3];" in st
    assert "dev0_write0.Values[0] := pump;" in st
    assert "dev3_write0.Values[0] := UINT_TO_WORD(speed);" in st
    assert re.findall(r"AT %IW100\b", st) == ["AT %IW100"] and "oplc_IW101 AT %IW101" in st
    # inside PROGRAM main, before its own statements; the helpers before it
    body = st[st.index("PROGRAM main"):st.index("END_PROGRAM")]
    assert body.index("end of the converted part") < body.index("pump := level > 100")
    assert st.index("FUNCTION_BLOCK OPLC_WriteBits") < st.index("PROGRAM main")
    # a served address of another type: one line
    user.write_text(USER.replace("level AT %IW100 : INT", "level AT %IW100 : REAL"))
    res = run(os.path.join(FIX, "plant.cfg"), "--into", str(user), "-o", str(out) + "2")
    assert res.returncode == 2 and "OI-12" in res.stderr and "level AT %IW100 : REAL" in res.stderr
    # declared as a global of the configuration: not in a program, one line
    user.write_text(USER.replace("    level AT %IW100 : INT;\n", "").replace(
        "  RESOURCE Res0 ON PLC", "  VAR_GLOBAL\n    level AT %IW100 : INT;\n  END_VAR\n"
        "  RESOURCE Res0 ON PLC"))
    res = run(os.path.join(FIX, "plant.cfg"), "--into", str(user), "-o", str(out) + "3")
    assert res.returncode == 2 and "level AT %IW100 is declared outside a PROGRAM" in res.stderr
    assert len(res.stderr.splitlines()) == 1


# ----- compile check: matiec as OpenPLC runs it, then the C as C++ -----
def compile_st(text, tmp):
    iec2c = os.environ.get("MBFB_IEC2C")
    lib = os.environ.get("MBFB_IEC_LIB")
    cinc = os.environ.get("MBFB_IEC_CINC")
    if not (iec2c and lib and cinc and os.path.exists(iec2c)):
        reason = "no matiec (MBFB_IEC2C, MBFB_IEC_LIB, MBFB_IEC_CINC: run through ctest)"
        if REQUIRE:
            pytest.fail(reason)
        pytest.skip(reason)
    srcs = sorted(f for f in os.listdir(os.path.join(ROOT, "st_src")) if f.endswith(".st"))
    parts = []
    for f in srcs:
        with open(os.path.join(ROOT, "st_src", f), encoding="utf-8") as fh:
            parts.append(fh.read())
    with open(os.path.join(tmp, "program.st"), "w", encoding="utf-8") as fh:
        fh.write("\n".join(parts) + "\n" + text)
    res = subprocess.run([iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "-I", lib, "program.st"],
                         cwd=tmp, capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stdout + res.stderr
    cxx = shutil.which("g++") or shutil.which("c++")
    res = subprocess.run([cxx, "-std=gnu++11", "-fsyntax-only", "-w", "-I", cinc, "-I",
                          os.path.join(ROOT, "c_shims", "include"), "-include", "mbfb_st.h",
                          "Res0.c"], cwd=tmp, capture_output=True, text=True, timeout=600,
                         check=False)
    assert res.returncode == 0, res.stderr[-3000:]


CONFIG = """
CONFIGURATION Config0
  RESOURCE Res0 ON PLC
    TASK task0(INTERVAL := T#20ms,PRIORITY := 0);
    PROGRAM inst0 WITH task0 : oplc_slaves;
  END_RESOURCE
END_CONFIGURATION
"""


def test_outputs_compile_with_matiec(tmp_path):
    """A v3 conversion as a program of its own, a v4 one into the user's program."""
    os.mkdir(tmp_path / "v3")
    compile_st(generated("plant.cfg") + CONFIG, str(tmp_path / "v3"))
    user = tmp_path / "main.st"
    user.write_text(USER)
    res = run(os.path.join(FIX, "v4_plant.json"), "--into", str(user), "-o", "-")
    assert res.returncode == 0, res.stderr
    os.mkdir(tmp_path / "v4")
    compile_st(res.stdout, str(tmp_path / "v4"))
