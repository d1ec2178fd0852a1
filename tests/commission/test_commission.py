"""mbcommission (tools/commission) against the simulator and a pymodbus peer: scan finds exactly
the instruments on a line, backup/restore/diff round trips, dry runs put no write on the wire, a
device lost mid-restore is reported and a second run finishes, another model is refused."""
import contextlib
import json
import os
import subprocess
import sys
import threading
import time

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402

TOOL = os.path.join(ROOT, "tools", "commission", "mbcommission.py")
PEER = os.path.join(ROOT, "tests", "shims", "pymodbus_peer.py")


def tool(*args):
    return subprocess.run([sys.executable, TOOL, *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def writes(sim):
    """Requests with FC06/FC16 the simulator received since the log was cleared."""
    log = sim.control({"op": "log"})["frames"]
    return [f for f in log if f["dir"] == "rx" and f["hex"].split()[1] in ("06", "10")]


def test_scan_finds_exactly_the_instruments(tmp_path):
    """Non-factory addresses and bauds on one line, an MT-S9 on ASCII among the RTU
    instruments, and one answer that fits no map."""
    devices = ["mvd94:7:SV=120.0,DP=1,BAUD=19.2K", "fdc100:12:SP1=150.0",
               "mts9:21:Baud Rate Set=4,framing=rtu", "fdc100:5", "mts9:3:framing=ascii"]
    with Simulator(devices, baud=9600, fmt="8N2") as sim:
        sim.control({"op": "set", "addr": 5, "reg": "PROG", "raw": 9901})  # no such model
        r = tool("scan", sim.port, "--address", "1-25", "--baud", 9600, "--baud", 19200,
                 "--format", "8N2", "--framing", "rtu", "--framing", "ascii", "--no-progress")
    assert r.returncode == 0, r.stderr
    rows = [line.split() for line in r.stdout.splitlines() if line[:7].strip().isdigit()]
    got = sorted((int(x[0]), x[1], x[2], x[3]) for x in rows)
    assert got == [(3, "MT-S9", "ASCII", "9600"), (5, "unknown", "RTU", "9600"),
                   (7, "MV-D94/VD", "RTU", "19200"), (12, "FDC-100", "RTU", "9600"),
                   (21, "MT-S9", "RTU", "19200")], r.stdout
    assert "unknown Modbus device at 5, 9600 8N2 RTU" in r.stdout + r.stderr
    assert "PROG(71)=610 -> BTC-9100" in r.stdout          # the registers that made it
    # one line for the port: the one most of them speak (19200 RTU), what the others need
    assert r.stdout.count("MB_LINE :=") == 1 and "Baud := 19200" in r.stdout, r.stdout
    assert "mvd94_7 : TempCtrl_MVD94;" in r.stdout and "mts9_21 : Counter_MTS9;" in r.stdout
    assert "Framing := 'ASCII'" not in r.stdout and "mts9_3 :" not in r.stdout
    assert "MT-S9 at 3: Baud Rate Set (7) := 4 (19200) (with Author (9) >= 3 first); " \
        "Type (8) := 1 (RTU) (with Author (9) >= 4 first)" in r.stdout, r.stdout
    assert "FDC-100 at 12: BAUD (40) := 4 (19200)" in r.stdout, r.stdout


def test_scan_tries_the_factory_addresses_first():
    """The factory settings at the factory address (1 for all three models) before the other
    addresses: a factory-new unit is found within seconds, the rest of the sweep after it."""
    with Simulator(["mvd94:1:SV=80", "mvd94:4"], baud=9600, fmt="8N2") as sim:
        r = tool("scan", sim.port, "--address", "1-6", "--no-progress")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "pass 1: factory settings at the factory address: 3 probe(s)" in out, out
    assert "pass 2: factory settings at the other addresses: 15 probe(s)" in out, out
    done = [line for line in out.splitlines() if line.startswith("pass 1 done")]
    assert done and "1 instrument(s) found so far" in done[0], out
    assert float(done[0].split(" after ")[1].split()[0]) < 5.0, done[0]
    assert out.index("pass 1 done") < out.index("pass 2 done")
    rows = [line.split() for line in out.splitlines() if line[:7].strip().isdigit()]
    assert [(int(x[0]), x[1]) for x in rows] == [(1, "MV-D94/VD"), (4, "MV-D94/VD")], out


def test_scan_stopped_after_the_factory_address_lists_what_it_found():
    """Ctrl-C once pass 1 is done: the instruments found so far are listed, exit 130."""
    import signal
    with Simulator(["mvd94:1:SV=80"], baud=9600, fmt="8N2") as sim:
        proc = subprocess.Popen([sys.executable, TOOL, "scan", sim.port, "--no-progress"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            head = []
            for line in proc.stdout:
                head.append(line)
                if line.startswith("pass 1 done"):
                    break
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 130, "".join(head) + out + err
    assert any(x.split()[:2] == ["1", "MV-D94/VD"] for x in out.splitlines()), out
    assert "pass 2 done" not in out
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("source,target,first", [
    ("mvd94:1:SV=120.0,DP=1,TYPE=J,HILT=300.0,A1SP=5.0", "mvd94:2", "TYPE"),
    ("mts9:1:Decimal Set=2", "mts9:2", "Decimal Set")])
def test_backup_restore_then_diff_is_empty(tmp_path, source, target, first):
    a = tmp_path / "a.json"
    with Simulator([source, target], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "-o", a).returncode == 0
        data = json.loads(a.read_text())
        assert data["registers"][first]["raw"] != 0 or first == "TYPE"
        before = tool("diff", a, "--port", sim.port, "--address", 2)
        assert before.returncode == 1 and first in before.stdout, before.stdout
        sim.control({"op": "log", "clear": True})
        dry = tool("restore", a, sim.port, 2)                  # default: a dry run
        assert dry.returncode == 1 and "dry run" in dry.stdout
        assert writes(sim) == []                               # nothing on the wire
        done = tool("restore", a, sim.port, 2, "--yes")
        assert done.returncode == 0, done.stdout + done.stderr
        after = tool("diff", a, "--port", sim.port, "--address", 2)
        assert after.returncode == 0 and "0 setting(s) differ" in after.stdout, after.stdout


def test_device_lost_mid_restore_then_a_second_run_finishes(tmp_path):
    a = tmp_path / "a.json"
    src = "mvd94:1:SV=120.0,SPOF=1.0,PVOF=2.0,A1SP=3.0,A2SP=4.0,A3SP=5.0,PB=7.0,TD=40,CT=30"
    with Simulator([src, "mvd94:2"], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "-o", a).returncode == 0
        sim.control({"op": "log", "clear": True})
        stop = threading.Event()

        def pull_the_plug():             # offline once the second write is on the wire
            while not stop.is_set() and len(writes(sim)) < 2:
                time.sleep(0.002)
            sim.control({"op": "offline", "addr": 2, "on": True})
        t = threading.Thread(target=pull_the_plug)
        t.start()
        r = tool("restore", a, sim.port, 2, "--yes")
        stop.set()
        t.join()
        assert r.returncode == 5, r.stdout + r.stderr
        line = r.stderr.strip().splitlines()[-1]
        assert "written: " in line and "not written: " in line and "run again" in line
        assert "written: none" not in line, line               # it stopped mid-way
        sim.control({"op": "offline", "addr": 2, "on": False})
        again = tool("restore", a, sim.port, 2, "--yes")
        assert again.returncode == 0, again.stdout + again.stderr
        assert tool("diff", a, "--port", sim.port, "--address", 2).returncode == 0


def test_another_models_backup_is_refused_before_any_write(tmp_path):
    a = tmp_path / "fdc.json"
    with Simulator(["fdc100:1:SP1=150.0", "mvd94:2"], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "--format", "8N2", "-o", a).returncode == 0
        sim.control({"op": "log", "clear": True})
        r = tool("restore", a, sim.port, 2, "--yes")
        assert r.returncode == 4 and "nothing written" in r.stderr, r.stderr
        assert writes(sim) == []


def test_fdc_download_one_block_read_back(tmp_path):
    """restore --download (FDC manual Example 1): a dry run first, then one FC16 of the 0x34
    words at 0, the lock opened before and set as in the backup after; the unit stays at its
    address; diff empty. Another model's backup is refused before the port is opened."""
    a, mv = tmp_path / "fdc.json", tmp_path / "mv.json"
    with Simulator(["fdc100:1:SP1H=400.0,SP1=300.0,PB=20.0,ALHY=2.0",
                    "fdc100:2:SP1H=160.0,LOCK=1", "mvd94:3"], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "--format", "8N2", "-o", a).returncode == 0
        assert tool("backup", sim.port, 3, "-o", mv).returncode == 0
        sim.control({"op": "log", "clear": True})
        dry = tool("restore", a, sim.port, 2, "--format", "8N2", "--download")
        assert dry.returncode == 1 and "dry run" in dry.stdout and "FC16 of 52 words" in dry.stdout
        assert writes(sim) == []
        r = tool("restore", a, sim.port, 2, "--format", "8N2", "--download", "--yes")
        assert r.returncode == 0, r.stdout + r.stderr
        sent = [f["hex"].split() for f in writes(sim)]
        blocks = [f for f in sent if f[1] == "10"]
        assert len(blocks) == 1 and blocks[0][:7] == ["02", "10", "00", "00", "00", "34", "68"]
        assert [f[2:4] for f in sent if f[1] == "06"] == [["00", "03"]]   # LOCK opened only
        assert sim.control({"op": "get", "addr": 2, "reg": "ADDR"})["raw"] == 2
        assert sim.control({"op": "get", "addr": 2, "reg": "SP1"})["eng"] == 300.0
        after = tool("diff", a, "--port", sim.port, "--address", 2, "--format", "8N2")
        assert after.returncode == 0 and "0 setting(s) differ" in after.stdout, after.stdout
        sim.control({"op": "log", "clear": True})
        refused = tool("restore", mv, sim.port, 3, "--download", "--yes")
        assert refused.returncode == 2 and "nothing written" in refused.stderr, refused.stderr
        assert len(refused.stderr.strip().splitlines()) == 1
        other = tool("restore", a, sim.port, 3, "--download", "--yes")
        assert other.returncode == 4 and "nothing written" in other.stderr, other.stderr
        assert writes(sim) == []


def test_fdc_download_refused_block_is_reported_and_a_rerun_finishes(tmp_path):
    """The unit refuses the FC16 (exception 4, once): one line naming the step and what was
    done (the lock opened), exit 5; the second run downloads the block."""
    a = tmp_path / "fdc.json"
    with Simulator(["fdc100:1:SP1=80.0,PB=25.0", "fdc100:2:LOCK=1"], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "--format", "8N2", "-o", a).returncode == 0
        sim.control({"op": "fault", "addr": 2, "kind": "exception", "code": 4, "fc": 16,
                     "count": 1})
        r = tool("restore", a, sim.port, 2, "--format", "8N2", "--download", "--yes")
        assert r.returncode == 5, r.stdout + r.stderr
        line = r.stderr.strip()
        assert len(line.splitlines()) == 1 and "FC16 of 52 words at 0 failed" in line, line
        assert "done: LOCK opened" in line and "run again" in line, line
        assert sim.control({"op": "get", "addr": 2, "reg": "PB"})["eng"] != 25.0
        again = tool("restore", a, sim.port, 2, "--format", "8N2", "--download", "--yes")
        assert again.returncode == 0, again.stdout + again.stderr
        assert sim.control({"op": "get", "addr": 2, "reg": "PB"})["eng"] == 25.0
        assert tool("diff", a, "--port", sim.port, "--address", 2,
                    "--format", "8N2").returncode == 0


def test_bad_input_gets_one_line_and_its_status(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    r = tool("diff", bad, bad)
    assert r.returncode == 6 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = tool("backup", tmp_path / "no-such-port", 1, "-o", tmp_path / "x.json")
    assert r.returncode == 3 and "no such port" in r.stderr
    r = tool("scan", tmp_path, "--address", "0-3")
    assert r.returncode == 2 and "1..247" in r.stderr and "Traceback" not in r.stderr
    with Simulator(["mvd94:1"], baud=9600, fmt="8N2") as sim:
        r = tool("backup", sim.port, 9, "-o", tmp_path / "x.json")
    assert r.returncode == 4 and "answers at 9" in r.stderr


@contextlib.contextmanager
def pymodbus_mvd94():
    """pymodbus holding an MV-D94's map (RTU over TCP): (its tcp:// port, read(addr) of one
    holding register through a pymodbus client)."""
    from pymodbus import FramerType
    from pymodbus.client import ModbusTcpClient
    peer = subprocess.Popen([sys.executable, PEER, "rtu-tcp", "mvd94"], stdout=subprocess.PIPE,
                            text=True)
    client = None
    try:
        port = int(peer.stdout.readline().split()[1])
        client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU)

        def read(addr):
            assert client.connected or client.connect()
            got = client.read_holding_registers(addr, count=1, slave=1)
            assert not got.isError(), addr
            return got.registers[0]
        yield f"tcp://127.0.0.1:{port}", read
    finally:
        if client is not None:
            client.close()
        peer.terminate()
        peer.wait(timeout=10)


def test_restore_onto_pymodbus_read_back_by_pymodbus(tmp_path):
    """An independent peer: pymodbus holding an MV-D94's map (RTU over TCP), read back with a
    pymodbus client register by register."""
    a = tmp_path / "a.json"
    with Simulator(["mvd94:1:SV=150.0,DP=1,A1SP=2.5,PB=12.0"], baud=9600, fmt="8N2") as sim:
        assert tool("backup", sim.port, 1, "-o", a).returncode == 0
    with pymodbus_mvd94() as (port, read):
        r = tool("restore", a, port, 1, "--yes")
        assert r.returncode == 0, r.stdout + r.stderr
        want = json.loads(a.read_text())["registers"]
        for name in ("SV", "DP", "A1SP", "PB", "LOLT", "HILT"):
            assert read(want[name]["addr"]) == want[name]["raw"] & 0xFFFF, name


sys.path.insert(0, os.path.join(ROOT, "maps"))
import settings  # noqa: E402  (the settings description: maps/settings.py)


def recipe_fields(data):
    """field -> raw of a backup's recipe fields (maps/settings.py)."""
    kind = data["kind"]
    raw = {n: e["raw"] for n, e in data["registers"].items()}
    return {s.field: raw[s.reg.name] for s in settings.fields(kind)}


@pytest.mark.parametrize("source,target,opts", [
    ("mvd94:1:SV=120.0,DP=1,TYPE=J,HILT=300.0,A1SP=5.0,SPOF=-1.5,PB=12.5,LOCK=0101", "mvd94:2", ()),
    ("fdc100:1:INPT=12,DP=2,SP1H=400.0,SP1=150.0,PB=20.0,ALHY=2.0", "fdc100:2", ("--format", "8N2")),
    ("mts9:1:Decimal Set=2", "mts9:2", ())])
def test_backup_st_is_a_recipe_that_restores_the_backup(tmp_path, source, target, opts):
    """backup --st prints the settings structure's initial value (a declaration, fields in
    alphabetical order, every field of the type); restore of it makes the target hold every
    recipe field of the source, each read back; the scaling (DP, INPT) written before the
    values it scales; a second restore writes nothing."""
    rec, src, dst = tmp_path / "r.st", tmp_path / "src.json", tmp_path / "dst.json"
    with Simulator([source, target], baud=9600, fmt="8N2") as sim:
        r = tool("backup", sim.port, 1, *opts, "--st", "-o", src)
        assert r.returncode == 0, r.stderr
        rec.write_text(r.stdout)
        data = json.loads(src.read_text())
        kind = data["kind"]
        decl = r.stdout[r.stdout.index("*)") + 2:].strip()
        assert decl.startswith(f"{kind}_1_recipe : {settings.type_name(kind)} :=") and \
            decl.endswith(");"), decl
        body = decl.split(":=", 1)[1]
        names = [p.split(":=")[0].strip(" (\n") for p in body.split(",")]
        assert names == sorted(names) == sorted(s.field for s in settings.fields(kind)), names
        parsed = settings.parse_initial(kind, r.stdout)
        assert settings.to_raw(kind, parsed) == recipe_fields(data)
        assert tool("backup", sim.port, 2, *opts, "-o", dst).returncode == 0
        assert recipe_fields(json.loads(dst.read_text())) != recipe_fields(data)
        sim.control({"op": "log", "clear": True})
        dry = tool("restore", rec, sim.port, 2, *opts)
        assert dry.returncode == 1 and "dry run" in dry.stdout and writes(sim) == []
        done = tool("restore", rec, sim.port, 2, *opts, "--yes")
        assert done.returncode == 0, done.stdout + done.stderr
        order = [int(f["hex"].split()[3], 16) for f in writes(sim)]
        first = [s.reg.addr for s in settings.fields(kind) if s.part == "first"]
        access = settings.access_register(kind)[0].addr
        scaling = [i for i, a in enumerate(order) if a in first]
        values = [i for i, a in enumerate(order) if a not in first and a != access]
        assert scaling and (not values or max(scaling) < min(values)), order
        assert tool("backup", sim.port, 2, *opts, "-o", dst).returncode == 0
        assert recipe_fields(json.loads(dst.read_text())) == recipe_fields(data)
        again = tool("restore", rec, sim.port, 2, *opts, "--yes")
        assert again.returncode == 0 and "0 setting(s) differ" in again.stdout, again.stdout


def test_st_recipe_refused_with_one_line_before_any_write(tmp_path):
    """A field out of its range (named), a field the type does not have, another model's
    settings: one line, nothing written; a bare initial value takes the device's model."""
    with Simulator(["mvd94:1:SV=80.0,DP=1,HILT=300.0", "fdc100:2"], baud=9600, fmt="8N2") as sim:
        r = tool("backup", sim.port, 1, "--st", "--st-name", "zone1")
        assert r.returncode == 0 and "\nzone1 : MVD94_SETTINGS :=" in r.stdout, r.stdout
        text = r.stdout
        bad = tool("backup", sim.port, 1, "--st", "--st-name", "1zone")
        assert bad.returncode == 2 and "not an ST identifier" in bad.stderr
        sim.control({"op": "log", "clear": True})
        cases = [(text.replace("SV := 80.0", "SV := 400.0"), 6, "SV: 400.0 outside LOLT..HILT"),
                 (text.replace("SV := 80.0", "SV := 1000.0"), 6, "SV: 1000.0 outside -199.9..999.9"),
                 (text.replace("CT := 20", "CT := 101"), 6, "CT: 101 outside 0..100"),
                 (text.replace("CT := 20", "CYCLE := 20"), 6, "CYCLE: no field of MVD94_SETTINGS"),
                 (text.replace("SV := 80.0", "SV := hot"), 6, "SV: hot is no number")]
        for i, (bad, status, why) in enumerate(cases):
            f = tmp_path / f"bad{i}.st"
            f.write_text(bad)
            r = tool("restore", f, sim.port, 1, "--yes")
            assert r.returncode == status and why in r.stderr, (why, r.stderr)
            assert len(r.stderr.strip().splitlines()) == 1 and "nothing written" in r.stderr
        good = tmp_path / "good.st"
        good.write_text(text)
        r = tool("restore", good, sim.port, 2, "--yes", "--format", "8N2")
        assert r.returncode == 4 and "MVD94_SETTINGS" in r.stderr, r.stderr
        bare = tmp_path / "bare.st"                      # only the initial value: the device's
        bare.write_text(text.split(":=", 1)[1].replace("SV := 80.0", "SV := 90.0"))
        assert writes(sim) == []
        r = tool("restore", bare, sim.port, 1, "--yes")
        assert r.returncode == 0 and "1 setting(s) differ" in r.stdout, r.stdout + r.stderr
        assert sim.control({"op": "get", "addr": 1, "reg": "SV"})["eng"] == 90.0


def test_st_recipe_onto_pymodbus_read_back_by_pymodbus(tmp_path):
    """backup --st from the simulator, restored onto pymodbus holding an MV-D94's map (RTU over
    TCP), every recipe field read back with a pymodbus client."""
    rec, src = tmp_path / "r.st", tmp_path / "src.json"
    with Simulator(["mvd94:1:SV=150.0,DP=1,A1SP=2.5,PB=12.0,HYST=0.5"], baud=9600, fmt="8N2") as sim:
        r = tool("backup", sim.port, 1, "--st", "-o", src)
        assert r.returncode == 0, r.stderr
        rec.write_text(r.stdout)
    want = recipe_fields(json.loads(src.read_text()))
    with pymodbus_mvd94() as (port, read):
        r = tool("restore", rec, port, 1, "--yes")
        assert r.returncode == 0, r.stdout + r.stderr
        for s in settings.fields("mvd94"):
            assert read(s.reg.addr) == want[s.field] & 0xFFFF, s.field


def declared(out):
    """(MB_LINE names declared, the Line := of each block call, the block instances)."""
    lines = [x.split(":")[0].strip() for x in out.splitlines() if "MB_LINE :=" in x]
    calls = [x.split("Line := ")[1].rstrip(");") for x in out.splitlines() if "Line := " in x]
    blocks = [x.split(":")[0].strip() for x in out.splitlines()
              if x.rstrip().endswith(("TempCtrl_MVD94;", "FDC_Controller;", "Counter_MTS9;"))]
    return lines, calls, blocks


def test_mixed_line_gives_one_working_declaration_set_or_a_clear_message():
    """The issue's line: an FDC-100 at 5, two MV-D94 at 17 and 18, an MT-S9 at 200 in ASCII.
    The scan says they cannot share one line and what to set (the MT-S9's Type, with Author),
    declares one MB_LINE for the three that share it and nothing that would give ErrorID 9.
    With the MT-S9 moved to RTU: one MB_LINE for all four, every block on it, each instrument
    answering with those settings."""
    with Simulator(["fdc100:5", "mvd94:17", "mvd94:18", "mts9:200:framing=ascii"], baud=9600,
                   fmt="8N2") as sim:
        r = tool("scan", sim.port, "--address", "5,17,18,200", "--no-progress")
        assert r.returncode == 0, r.stderr
        assert "do not share one line setting" in r.stdout, r.stdout
        assert "MT-S9 at 200: Type (8) := 1 (RTU) (with Author (9) >= 4 first)" in r.stdout
        lines, calls, blocks = declared(r.stdout)
        assert len(lines) == 1 and set(calls) == set(lines), r.stdout
        assert sorted(blocks) == ["fdc100_5", "mvd94_17", "mvd94_18"], r.stdout
        assert "Framing := 'ASCII'" not in r.stdout
        sim.control({"op": "set", "addr": 200, "reg": "Type", "raw": 1})    # the fix: RTU
        r = tool("scan", sim.port, "--address", "5,17,18,200", "--no-progress")
        assert r.returncode == 0, r.stderr
        assert "do not share" not in r.stdout, r.stdout
        lines, calls, blocks = declared(r.stdout)
        assert len(lines) == 1 and calls == lines * 4, r.stdout
        assert sorted(blocks) == ["fdc100_5", "mts9_200", "mvd94_17", "mvd94_18"], r.stdout
        decl = next(x for x in r.stdout.splitlines() if "MB_LINE :=" in x)
        fields = dict(f.split(" := ") for f in decl.split("(", 1)[1].rstrip(");").split(", "))
        assert "Framing" not in fields and fields["Parity"] == "'N'", decl
        fmt = f"8{fields['Parity'].strip(chr(39))}{fields['StopBits']}"
        for a in (5, 17, 18, 200):                      # every instrument on that one line
            b = tool("backup", sim.port, a, "--baud", fields["Baud"], "--format", fmt, "--st")
            assert b.returncode == 0 and "_SETTINGS :=" in b.stdout, (a, b.stderr)


def test_scan_finds_a_device_whose_reply_comes_late():
    """A probe goes on a fresh line (no settle after a silent address). A device whose reply
    comes after the reply timeout garbles the next address's probe: both are probed again with
    the settle, and the device is found."""
    with Simulator(["mvd94:4"], baud=9600, fmt="8N2") as sim:
        sim.control({"op": "fault", "addr": 4, "kind": "late", "delay_ms": 85, "count": 1})
        r = tool("scan", sim.port, "--address", "3-6", "--baud", 9600, "--format", "8N2",
                 "--framing", "rtu", "--no-progress")
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [line.split() for line in r.stdout.splitlines() if line[:7].strip().isdigit()]
    assert [(int(x[0]), x[1]) for x in rows] == [(4, "MV-D94/VD")], r.stdout


def test_scan_takes_no_late_or_foreign_reply_for_another_address():
    """A reply two probes late (it lands in the probe of the address after next) and a reply
    carrying another address (8 answers as 9): the scan probes again with the line settled and
    reports each device at its own address, nothing at the addresses whose probes heard them."""
    with Simulator(["mvd94:4", "mvd94:8"], baud=9600, fmt="8N2") as sim:
        sim.control({"op": "fault", "addr": 4, "kind": "late", "delay_ms": 150, "count": 1})
        sim.control({"op": "fault", "addr": 8, "kind": "wrong_slave", "slave": 9, "count": 1})
        r = tool("scan", sim.port, "--address", "3-10", "--baud", 9600, "--format", "8N2",
                 "--framing", "rtu", "--no-progress")
        log = sim.control({"op": "log"})["frames"]
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [line.split() for line in r.stdout.splitlines() if line[:7].strip().isdigit()]
    assert [(int(x[0]), x[1]) for x in rows] == [(4, "MV-D94/VD"), (8, "MV-D94/VD")], r.stdout
    assert any(f["dir"] == "tx" and f["hex"].split()[0] == "09" for f in log), \
        "the foreign reply was not sent: the test tests nothing"
