"""tools/oplc_import end to end in the real OpenPLC v3 runtime. One plant: a relay module (slave
2) and a meter (slave 5) on one RTU line, the simulator's generic devices
(tests/oplc_import/line_*.json). One user program using %IX100.0.., %IW100.., %QX100.0..,
%QW100... Run A: OpenPLC's own Slave Devices (tests/oplc_import/fixtures/line.cfg, written by
OpenPLC's generate_mbconfig(), its port set to the simulator's). Run B: no Slave Devices, the
same program converted with `oplc_import --into`. pymodbus reads both through OpenPLC's Modbus
server: the same values at the same addresses, and the outputs written through it reach the
devices in both; OpenPLC writes its outputs at every poll, the converted program only when they
change; with the meter silent both hold its last values, and only the converted program says
so (its status, published by the test's one added line)."""
import os
import subprocess
import sys

import pytest

import oplc
from oplc import wait

sys.path.insert(0, os.path.join(oplc.ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402

HERE = os.path.join(oplc.ROOT, "tests", "oplc_import")
sys.path.insert(0, HERE)
from line_plant import METER_WORDS, RELAY_INPUTS, user_program  # noqa: E402
PORT = 5502
DI0, COIL0, IR0, HR0 = 800, 800, 100, 100      # %IX100.0, %QX100.0, %IW100, %QW100 on the server
STATUS_COIL = 0                                # %QX0.0: run B publishes dev1_Valid there

USER = user_program()


def reads(client):
    c = client.client
    di = client._call(c.read_discrete_inputs, DI0, count=8).bits[:8]
    ir = client._call(c.read_input_registers, IR0, count=12).registers
    return list(di), list(ir)


def writes(sim, head):
    return sum(1 for f in sim.log(clear=False) if f["dir"] == "rx" and f["hex"].startswith(head))


def run_plant(tmp, dist, sim, program, mbconfig):
    """The plant in a scratch OpenPLC, the same steps in both runs: (the values seen, the coil
    writes (FC15) during ten polls of unchanged outputs, the meter's status as published or
    None, the values while the meter is silent)."""
    with oplc.Scratch() as plc:
        plc.install(dist)
        cfg = os.path.join(plc.web, "mbconfig.cfg")
        if mbconfig is None:
            if os.path.exists(cfg):
                os.remove(cfg)
        else:
            with open(cfg, "w", encoding="utf-8") as fh:
                fh.write(mbconfig)
        plc.compile(program, name="main.st")
        for reg in ("co:0", "co:1", "co:2", "co:3", "out1", "out2"):
            sim.ctl("set", addr=2 if reg.startswith("co") else 5, reg=reg, raw=1)
        sim.log(clear=True)
        plc.start(modbus_port=PORT)
        client = oplc.PlcClient(PORT)
        try:
            seen = wait(lambda: (lambda r: r if r == (RELAY_INPUTS, METER_WORDS) else None)(
                reads(client)), 60, "the devices' values at %IX100.0.. and %IW100..")
            client.write_coil(COIL0 + 2, True)
            client.write(HR0 + 1, 1234)
            wait(lambda: sim.ctl("get", addr=2, reg="co:2")["raw"] == 1 and
                 [sim.ctl("get", addr=2, reg=f"co:{i}")["raw"] for i in (0, 1, 3)] == [0, 0, 0],
                 60, "the relays as the outputs say")
            wait(lambda: sim.ctl("get", addr=5, reg="out2")["raw"] == 1234, 60, "out2 written")
            wait(lambda: writes(sim, "05 10") and writes(sim, "02 0F"), 60, "the writes logged")
            polls0, writes0 = writes(sim, "02 02"), writes(sim, "02 0F")
            wait(lambda: writes(sim, "02 02") >= polls0 + 10, 60, "ten more polls of the relays")
            rewrites = writes(sim, "02 0F") - writes0     # with the outputs unchanged
            sim.ctl("offline", addr=5, on=True)
            polls0 = writes(sim, "02 02")
            wait(lambda: writes(sim, "02 02") >= polls0 + 5, 60, "polls with the meter silent")
            status = None
            if mbconfig is None:
                status = wait(lambda: not client.coils(1)[STATUS_COIL] and "silent", 60,
                              "the converted program's meter status to fall")
            held = reads(client)
            sim.ctl("offline", addr=5, on=False)
            return seen, rewrites, status, held
        finally:
            client.close()
            print(plc.runtime_log()[-2000:])


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    bus = str(tmp_path_factory.mktemp("line") / "bus")
    with Simulator([f"generic:2:file={os.path.join(HERE, 'line_relays.json')}",
                    f"generic:5:file={os.path.join(HERE, 'line_meter.json')}"], link=bus) as sim:
        yield sim, bus


def test_slave_devices_and_converted_program_agree(line, dist, tmp_path):
    sim, bus = line
    with open(os.path.join(HERE, "fixtures", "line.cfg"), encoding="utf-8") as fh:
        mbconfig = fh.read().replace('"/dev/ttyUSB0"', f'"{bus}"')
    user = tmp_path / "main.st"
    user.write_text(USER)
    a = run_plant(tmp_path, dist, sim, str(user), mbconfig)
    conv = subprocess.run([sys.executable, os.path.join(oplc.ROOT, "tools", "oplc_import",
                                                        "oplc_import.py"),
                           os.path.join(HERE, "fixtures", "line.cfg"), "--port",
                           f"/dev/ttyUSB0={bus}", "--into", str(user), "-o", "-"],
                          capture_output=True, text=True, check=True)
    converted = conv.stdout.replace("(* end of the converted part *)",
                                    "(* end of the converted part *)\n  meter_ok := dev1_Valid;")
    (tmp_path / "main_mb.st").write_text(converted)
    b = run_plant(tmp_path, dist, sim, str(tmp_path / "main_mb.st"), None)
    assert a[0] == b[0] == (RELAY_INPUTS, METER_WORDS)       # same values, same addresses
    assert a[3] == b[3] == (RELAY_INPUTS, METER_WORDS)       # last values held while silent
    assert a[1] >= 5                                          # OpenPLC: a write at every poll
    assert b[1] == 0                                          # converted: on change only
    assert a[2] is None and b[2] == "silent"
