"""The ladder example in the real OpenPLC v3 runtime: plc_lib installed into a scratch copy, the ST
the OpenPLC Editor generated from examples/heat_treat_ld/plc.xml compiled by compile_program.sh,
the runtime's Modbus TCP server on loopback (private namespace), the simulator on a pty, pymodbus
as the SCADA. Register map: examples/heat_treat_ld/README.md."""
import os
import sys

import pytest

import oplc
from oplc import s16, wait

sys.path.insert(0, os.path.join(oplc.ROOT, "tests", "sim"))
from simctl import Simulator  # noqa: E402

EXAMPLE = os.path.join(oplc.ROOT, "examples", "heat_treat_ld", "heat_treat_ld.st")
PORT = 5502
Z2PV, Z2SV, Z2ERR, COUNT, COUNTERR, BEAT = 3, 4, 5, 6, 7, 8
Z2SPREQ = 1025
C_Z2VALID, C_Z2QUIET, C_PARTSVALID, C_PARTSQUIET, C_ANY, C_RESET = 3, 5, 6, 7, 8, 9


@pytest.fixture(scope="module")
def plant(tmp_path_factory, dist):
    tmp = tmp_path_factory.mktemp("ld")
    bus = str(tmp / "bus")
    with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=30.0, seed=2) as sim, \
            oplc.Scratch() as plc:
        plc.install(dist)
        plc.compile(oplc.retarget(EXAMPLE, str(tmp / "heat_treat_ld.st"), bus))
        plc.start(modbus_port=PORT)
        client = oplc.PlcClient(PORT)
        try:
            yield sim, client
        finally:
            client.close()
            print(plc.runtime_log()[-3000:])


def test_ld_program_publishes_the_instruments(plant):
    sim, client = plant
    wait(lambda: all(client.coils(10)[i] for i in (C_Z2VALID, C_PARTSVALID)), 30, "both devices valid")
    b0 = client.hr(BEAT)[0]
    wait(lambda: client.hr(BEAT)[0] != b0, 5, "the scan heartbeat to move")
    assert client.hr(Z2SV)[0] == sim.ctl("get", addr=2, reg="SV")["raw"]  # DP=1: raw = x10
    lo = sim.ctl("get", addr=2, reg="PV")["raw"]
    mid = s16(client.hr(Z2PV)[0])
    hi = sim.ctl("get", addr=2, reg="PV")["raw"]
    assert min(lo, hi) - 50 <= mid <= max(lo, hi) + 50, (lo, mid, hi)
    assert 0 < client.hr(COUNT)[0] <= sim.ctl("get", addr=3, reg="VALUE")["raw"] & 0xFFFF
    assert client.hr(Z2ERR)[0] == client.hr(COUNTERR)[0] == 0
    assert not any(client.coils(10)[i] for i in (C_Z2QUIET, C_PARTSQUIET, C_ANY))


def test_ld_set_point_request_reaches_the_mvd94(plant):
    sim, client = plant
    wait(lambda: client.coils(10)[C_Z2VALID], 30, "zone 2 valid")
    new = 1300 if sim.ctl("get", addr=2, reg="SV")["raw"] != 1300 else 1400
    client.write(Z2SPREQ, new)
    wait(lambda: sim.ctl("get", addr=2, reg="SV")["raw"] == new, 10, "SV to reach the MV-D94")
    wait(lambda: client.hr(Z2SV)[0] == new, 10, "the PLC to read back the new SV")


def test_ld_reset_coil_resets_the_count_once(plant):
    sim, client = plant
    wait(lambda: client.coils(10)[C_PARTSVALID], 30, "counter valid")
    sim.ctl("set", addr=3, reg="REAL", raw=50000)
    wait(lambda: client.hr(COUNT)[0] >= 50000, 10, "the PLC to show the preset count")
    client.write_coil(C_RESET, True)
    wait(lambda: not client.coils(10)[C_RESET], 10, "the program to clear the reset request")
    assert sim.ctl("get", addr=3, reg="VALUE")["raw"] < 50000, "the MT-S9 was not reset"
    wait(lambda: client.hr(COUNT)[0] < 50000, 10, "the PLC to show the reset count")
    assert client.hr(COUNTERR)[0] == 0


def test_ld_quiet_alarm_when_the_counter_goes_offline(plant):
    sim, client = plant
    wait(lambda: client.coils(10)[C_PARTSVALID], 30, "counter valid")
    sim.ctl("offline", addr=3, on=True)
    try:
        wait(lambda: client.coils(10)[C_PARTSQUIET] and client.coils(10)[C_ANY], 30,
             "the PLC to report the counter quiet")
        assert client.hr(COUNTERR)[0] != 0
        assert client.coils(10)[C_Z2VALID], "zone 2 on the same bus keeps working"
    finally:
        sim.ctl("offline", addr=3, on=False)
    wait(lambda: client.coils(10)[C_PARTSVALID] and not client.coils(10)[C_PARTSQUIET], 60,
         "the counter to recover")
