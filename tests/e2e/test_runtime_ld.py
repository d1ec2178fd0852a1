"""The ladder example in the real OpenPLC v3 runtime: plc_lib installed into a scratch copy, the ST
the OpenPLC Editor generated from examples/heat_treat_ld/plc.xml compiled by compile_program.sh,
the runtime's Modbus TCP server on loopback (private namespace), the simulator on a pty, pymodbus
as the SCADA. Register map: examples/heat_treat_ld/README.md."""
import os

import pytest

import oplc
from oplc import s16, wait

from test_runtime import fc06, product_switch, program_time, request_while_offline, running_example  # noqa: E402

EXAMPLE = os.path.join(oplc.ROOT, "examples", "heat_treat_ld", "heat_treat_ld.st")
PORT = 5502
Z1PV, Z1SV, Z1ERR, Z2PV, Z2SV, Z2ERR, COUNT, COUNTERR, BEAT, Z1SPSTATUS, Z2SPSTATUS = range(11)
PRODUCTHELD, Z1RSTATUS, Z2RSTATUS, Z1RFIELD, Z2RFIELD = range(11, 16)
Z1SPREQ, Z2SPREQ, PRODUCTREQ = 1024, 1025, 1026
(C_Z1VALID, C_Z1BAND, C_Z1QUIET, C_Z2VALID, C_Z2BAND, C_Z2QUIET, C_PARTSVALID, C_PARTSQUIET, C_ANY,
 C_RESET) = range(10)
VALID = (C_Z1VALID, C_Z2VALID, C_PARTSVALID)
ALARMS = (C_Z1BAND, C_Z1QUIET, C_Z2BAND, C_Z2QUIET, C_PARTSQUIET, C_ANY)


@pytest.fixture(scope="module")
def plant(tmp_path_factory, dist):
    with running_example(tmp_path_factory.mktemp("ld"), dist, EXAMPLE, seed=2) as (sim, _plc, client):
        yield sim, client


def between(client, sim, reg, addr, sim_reg):
    """The PLC's value x10 lies between two simulator readings (engineering units) around it."""
    lo = sim.ctl("get", addr=addr, reg=sim_reg)["eng"]
    mid = s16(client.hr(reg)[0])
    hi = sim.ctl("get", addr=addr, reg=sim_reg)["eng"]
    assert 10 * min(lo, hi) - 50 <= mid <= 10 * max(lo, hi) + 50, (lo, mid, hi)


def test_ld_program_publishes_the_instruments(plant):
    sim, client = plant
    wait(lambda: all(client.coils(10)[i] for i in VALID), 30, "all three devices valid")
    b0 = client.hr(BEAT)[0]
    wait(lambda: client.hr(BEAT)[0] != b0, 5, "the scan heartbeat to move")
    # the FDC-100 shares the 8N2 line only because BusLine's declaration set Parity := 'N'
    assert s16(client.hr(Z1SV)[0]) == round(10 * sim.ctl("get", addr=1, reg="SP1")["eng"])
    assert client.hr(Z2SV)[0] == sim.ctl("get", addr=2, reg="SV")["raw"]  # DP=1: raw = x10
    between(client, sim, Z1PV, 1, "PV")
    between(client, sim, Z2PV, 2, "PV")
    assert 0 < client.hr(COUNT)[0] <= sim.ctl("get", addr=3, reg="VALUE")["raw"] & 0xFFFF
    assert client.hr(Z1ERR)[0] == client.hr(Z2ERR)[0] == client.hr(COUNTERR)[0] == 0
    assert not any(client.coils(10)[i] for i in ALARMS)


ZONES = [(C_Z1VALID, Z1SPREQ, Z1SV, Z1SPSTATUS, 1, "SP1", "SP1H"),
         (C_Z2VALID, Z2SPREQ, Z2SV, Z2SPSTATUS, 2, "SV", "HILT")]


@pytest.mark.parametrize("valid, req, sv, status, addr, reg, hi", ZONES)
def test_ld_set_point_request_reaches_the_controller(plant, valid, req, sv, status, addr, reg, hi):
    sim, client = plant
    wait(lambda: client.coils(10)[valid], 30, "the zone valid")
    new = 1300 if round(10 * sim.ctl("get", addr=addr, reg=reg)["eng"]) != 1300 else 1400
    sim.log(clear=True)
    client.write(req, new)
    wait(lambda: round(10 * sim.ctl("get", addr=addr, reg=reg)["eng"]) == new, 10,
         "the set point to reach the controller")
    wait(lambda: s16(client.hr(sv)[0]) == new, 10, "the PLC to read back the new SV")
    assert len(fc06(sim.log(clear=True), addr)) == 1, "the request must be written exactly once"
    assert client.hr(status)[0] == 0


@pytest.mark.parametrize("valid, req, sv, status, addr, reg, hi", ZONES)
def test_ld_out_of_range_request_is_refused_not_sent_and_not_retried(plant, valid, req, sv, status, addr,
                                                                     reg, hi):
    """202 in the status register, no FC06 on the wire (so no retry loop); the next request works."""
    sim, client = plant
    wait(lambda: client.coils(10)[valid], 30, "the zone valid")
    before = sim.ctl("get", addr=addr, reg=reg)["eng"]
    bad = round(10 * sim.ctl("get", addr=addr, reg=hi)["eng"]) + 100
    sim.log(clear=True)
    client.write(req, bad)
    wait(lambda: client.hr(status)[0] == 202, 10, "status 202 (out of range)")
    program_time(client, 5.0, "two and a half retry waits")
    assert fc06(sim.log(clear=True), addr) == [], "an out-of-range set point went on the wire"
    assert client.hr(status)[0] == 202
    assert sim.ctl("get", addr=addr, reg=reg)["eng"] == before
    good = 1100 if round(10 * before) != 1100 else 1150
    client.write(req, good)
    wait(lambda: round(10 * sim.ctl("get", addr=addr, reg=reg)["eng"]) == good, 10,
         "the next request to reach the controller")
    wait(lambda: client.hr(status)[0] == 0, 10, "status 0 (sent)")
    program_time(client, 2.5, "a doubled write would come within a retry wait")
    assert len(fc06(sim.log(clear=True), addr)) == 1, "the request must be written exactly once"


def test_ld_request_written_while_zone1_is_offline_is_sent_once_it_is_valid(plant):
    """Not used up while it cannot be checked: no FC06 while zone 1 is not valid, exactly one after."""
    sim, client = plant
    wait(lambda: client.coils(10)[C_Z1VALID], 30, "zone 1 valid")
    new = 1250 if round(10 * sim.ctl("get", addr=1, reg="SP1")["eng"]) != 1250 else 1350
    request_while_offline(sim, client, 1, lambda: client.coils(10)[C_Z1VALID], lambda: client.write(Z1SPREQ, new))
    wait(lambda: round(10 * sim.ctl("get", addr=1, reg="SP1")["eng"]) == new, 60,
         "the request to reach the FDC-100")
    wait(lambda: s16(client.hr(Z1SV)[0]) == new, 10, "the PLC to read back the new SV")
    program_time(client, 2.5, "a doubled write would come within a retry wait")
    assert len(fc06(sim.log(clear=True), 1)) == 1, "the request must be written exactly once"
    assert client.hr(Z1SPSTATUS)[0] == 0


def test_ld_zone1_band_alarm_when_pv_is_held_off_the_set_point(plant):
    sim, client = plant
    wait(lambda: client.coils(10)[C_Z1VALID] and not client.coils(10)[C_Z1BAND], 30, "zone 1 valid, in band")
    sv = sim.ctl("get", addr=1, reg="SP1")["eng"]
    sim.ctl("plant", addr=1, temp=sv - 30.0, hold=True)
    try:
        wait(lambda: abs(s16(client.hr(Z1PV)[0]) - round(10 * (sv - 30.0))) <= 1, 10,
             "the PLC to show the held PV")
        assert not client.coils(10)[C_Z1BAND], "the band alarm waits 5 s"
        wait(lambda: client.coils(10)[C_Z1BAND] and client.coils(10)[C_ANY], 20,
             "the PLC to report zone 1 out of band")
        assert not client.coils(10)[C_Z2BAND] and client.coils(10)[C_Z1VALID]
        sim.ctl("plant", addr=1, temp=sv, hold=True)
        wait(lambda: not client.coils(10)[C_Z1BAND], 10, "the band alarm to clear at the set point")
    finally:
        sim.ctl("plant", addr=1, hold=False)


@pytest.mark.parametrize("addr, valid, quiet, err, other", [
    (1, C_Z1VALID, C_Z1QUIET, Z1ERR, C_Z2VALID), (3, C_PARTSVALID, C_PARTSQUIET, COUNTERR, C_Z2VALID)])
def test_ld_quiet_alarm_when_a_device_goes_offline(plant, addr, valid, quiet, err, other):
    sim, client = plant
    wait(lambda: client.coils(10)[valid], 30, "the device valid")
    sim.ctl("offline", addr=addr, on=True)
    try:
        wait(lambda: client.coils(10)[quiet] and client.coils(10)[C_ANY], 30,
             "the PLC to report the device quiet")
        assert not client.coils(10)[valid]
        assert client.hr(err)[0] != 0
        assert client.coils(10)[other], "zone 2 on the same bus keeps working"
    finally:
        sim.ctl("offline", addr=addr, on=False)
    wait(lambda: client.coils(10)[valid] and not client.coils(10)[quiet], 60, "the device to recover")
    wait(lambda: client.hr(err)[0] == 0, 10, "ErrorID to clear")


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


def test_ld_product_switch_downloads_each_zones_recipe_and_back(plant):
    """HR 1026 := 2: each zone downloads product B's recipe, HR 1026 := 1: back to A
    (test_runtime.product_switch: the ST example runs the same check)."""
    sim, client = plant
    product_switch(sim, client)
