"""The issue's end-to-end scenario, in the real OpenPLC v3 runtime: plc_lib installed into a
scratch copy, the ST example compiled by OpenPLC's compile_program.sh, the runtime core running
with its Modbus TCP server on loopback (private namespace), the simulator on a pty, and pymodbus
as an independent client of the PLC."""
import contextlib
import os
import struct
import sys
import time

import pytest

import oplc
from oplc import s16, wait

sys.path.insert(0, os.path.join(oplc.ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402

EXAMPLE = os.path.join(oplc.ROOT, "examples", "heat_treat_st", "heat_treat_st.st")
PORT = 5502
# Holding registers / coils of the example (see its header comment).
Z1PV, Z1SV, Z1ERR, Z2PV, Z2SV, Z2ERR, COUNT, COUNTERR, BEAT, Z1SPSTATUS, Z2SPSTATUS = range(11)
PRODUCTHELD, Z1RSTATUS = 11, 12
Z2SPREQ, PRODUCTREQ = 1025, 1026
C_Z1VALID, C_Z2VALID, C_Z2QUIET, C_PARTSVALID, C_ANY = 0, 3, 5, 6, 8
METER, METERERR, C_METERVALID = 16, 24, 9       # HR 16..23 the meter's registers as read


@contextlib.contextmanager
def running_example(tmp, dist, program, seed):
    """The simulator with the example's devices on a pty and `program` (an examples/heat_treat_*
    ST file) compiled into a scratch OpenPLC with plc_lib, running; yields (sim, plc, client)."""
    bus = str(tmp / "bus")
    with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=30.0, seed=seed) as sim, \
            oplc.Scratch() as plc:
        plc.install(dist)
        plc.compile(oplc.retarget(program, str(tmp / os.path.basename(program)), bus))
        plc.start(modbus_port=PORT)
        client = oplc.PlcClient(PORT)
        try:
            yield sim, plc, client
        finally:
            client.close()
            print(f"requests retried on OpenPLC's Modbus server: {client.retried}")
            print(plc.runtime_log()[-3000:])


@pytest.fixture(scope="module")
def plant(tmp_path_factory, dist):
    with running_example(tmp_path_factory.mktemp("rt"), dist, EXAMPLE, seed=1) as running:
        yield running


def fc06(frames, slave):
    """(register, value) of each FC06 request to `slave` in the simulator's log."""
    out = []
    for f in frames:
        b = [int(x, 16) for x in f["hex"].split()]
        if f["dir"] == "rx" and len(b) >= 6 and b[0] == slave and b[1] == 6:
            out.append((b[2] << 8 | b[3], b[4] << 8 | b[5]))
    return out


TASK_S = 0.050  # the examples' task interval (T#50ms)


def program_time(client, seconds, what):
    """Wait until the program has run `seconds` of its own time: that many task intervals of
    scans, counted by its heartbeat (HR 8, +1 per scan). OpenPLC v3 advances the program's
    clock by one interval per scan (its TONs count in scans), so this is the program's retry
    wait however slowly a loaded machine runs it; a wait for that, not a clock."""
    n = round(seconds / TASK_S)
    b0 = client.hr(BEAT)[0]
    wait(lambda: (client.hr(BEAT)[0] - b0) & 0xFFFF >= n, 30 + 20 * seconds,
         f"{n} scans of the program ({what})")


def request_while_offline(sim, client, slave, valid, write):
    """Take `slave` offline, wait until not valid(), clear the simulator's log, write() the
    request, check that no FC06 goes to it for longer than the program's 2 s retry wait (in
    the program's time), and bring it back online (also on failure)."""
    sim.ctl("offline", addr=slave, on=True)
    try:
        wait(lambda: not valid(), 30, f"slave {slave} not valid")
        sim.log(clear=True)
        write()
        program_time(client, 3.0, "one and a half retry waits")
        assert fc06(sim.log(clear=False), slave) == [], "a request was sent while the zone was not valid"
    finally:
        sim.ctl("offline", addr=slave, on=False)


def hr(client, addr, count=1):
    return client.hr(addr, count)


def coils(client, count=9):
    return client.coils(count)


def test_plc_shows_the_simulators_values(plant):
    sim, plc, client = plant
    wait(lambda: all(coils(client)[i] for i in (C_Z1VALID, C_Z2VALID, C_PARTSVALID)), 30,
         "all three devices valid")
    b0 = hr(client, BEAT)[0]
    wait(lambda: hr(client, BEAT)[0] != b0, 5, "the scan heartbeat to move")
    # Set points do not move by themselves: they must be equal.
    assert hr(client, Z2SV)[0] == sim.ctl("get", addr=2, reg="SV")["raw"]  # DP=1: raw = x10
    assert s16(hr(client, Z1SV)[0]) == round(10 * sim.ctl("get", addr=1, reg="SP1")["eng"])
    # PV and count move: the PLC's value lies between two simulator readings around it.
    lo = sim.ctl("get", addr=2, reg="PV")["raw"]
    mid = s16(hr(client, Z2PV)[0])
    hi = sim.ctl("get", addr=2, reg="PV")["raw"]
    assert min(lo, hi) - 50 <= mid <= max(lo, hi) + 50, (lo, mid, hi)
    c = hr(client, COUNT)[0]
    assert 0 < c <= sim.ctl("get", addr=3, reg="VALUE")["raw"] & 0xFFFF
    assert hr(client, Z1ERR)[0] == hr(client, Z2ERR)[0] == hr(client, COUNTERR)[0] == 0


def test_energy_meter_beside_the_instruments(plant):
    """The meter (a generic device: IEEE 754 REALs, CDAB) polled by MB_Poll on the instruments'
    line: its registers at HR 16..23 as the simulator holds them, changed ones too."""
    sim, plc, client = plant
    want = []
    for reg in ("voltage", "current", "power", "energy"):
        want += sim.ctl("get", addr=4, reg=reg)["words"]
    assert abs(struct.unpack(">f", struct.pack(">HH", want[1], want[0]))[0] - 230.4) < 1e-4
    wait(lambda: coils(client, 10)[C_METERVALID] and hr(client, METER, 8) == want, 30,
         "the meter's registers at HR 16..23")
    assert hr(client, METERERR)[0] == 0
    sim.ctl("set", addr=4, reg="power", eng=1500.5)
    words = sim.ctl("get", addr=4, reg="power")["words"]
    wait(lambda: hr(client, METER + 4, 2) == words, 30, "the new power at HR 20..21")
    assert all(coils(client)[i] for i in (C_Z1VALID, C_Z2VALID, C_PARTSVALID))


def test_set_point_reaches_the_instrument_and_pv_follows(plant):
    sim, plc, client = plant
    wait(lambda: coils(client)[C_Z2VALID], 30, "zone 2 valid")
    new = 1500  # 150.0
    assert sim.ctl("get", addr=2, reg="SV")["raw"] != new
    sim.log(clear=True)
    t0 = time.monotonic()
    client.write(Z2SPREQ, new)
    wait(lambda: sim.ctl("get", addr=2, reg="SV")["raw"] == new, 10, "SV to reach the MV-D94")
    print(f"set point reached the simulated MV-D94 {time.monotonic() - t0:.2f} s after the Modbus write")
    wait(lambda: hr(client, Z2SV)[0] == new, 10, "the PLC to read back the new SV")
    assert fc06(sim.log(clear=True), 2) == [(0, new)], "the request must be written exactly once"
    assert hr(client, Z2SPSTATUS)[0] == 0
    wait(lambda: abs(s16(hr(client, Z2PV)[0]) - new) < 50, 120, "PV to follow the new set point")


def test_pulled_device_is_reported_and_recovers(plant):
    sim, plc, client = plant
    wait(lambda: coils(client)[C_Z2VALID], 30, "zone 2 valid")
    sim.ctl("offline", addr=2, on=True)
    try:
        wait(lambda: coils(client)[C_Z2QUIET] and not coils(client)[C_Z2VALID], 30,
             "the PLC to report zone 2 quiet")
        assert hr(client, Z2ERR)[0] != 0, "ErrorID must say why"
        assert coils(client)[C_ANY]
        assert coils(client)[C_Z1VALID], "the other devices on the bus keep working"
    finally:
        sim.ctl("offline", addr=2, on=False)
    wait(lambda: coils(client)[C_Z2VALID] and not coils(client)[C_Z2QUIET], 60,
         "zone 2 to recover")
    wait(lambda: hr(client, Z2ERR)[0] == 0, 10, "ErrorID to clear")


def test_request_written_while_the_device_is_offline_is_sent_once_it_is_valid(plant):
    """Not used up while it cannot be checked: no FC06 while zone 2 is not valid, exactly one after."""
    sim, plc, client = plant
    wait(lambda: coils(client)[C_Z2VALID], 30, "zone 2 valid")
    new = 1200 if sim.ctl("get", addr=2, reg="SV")["raw"] != 1200 else 1250
    request_while_offline(sim, client, 2, lambda: coils(client)[C_Z2VALID], lambda: client.write(Z2SPREQ, new))
    wait(lambda: sim.ctl("get", addr=2, reg="SV")["raw"] == new, 60, "the request to reach the MV-D94")
    wait(lambda: hr(client, Z2SV)[0] == new, 10, "the PLC to read back the new SV")
    program_time(client, 2.5, "a doubled write would come within a retry wait")
    assert fc06(sim.log(clear=True), 2) == [(0, new)], "the request must be written exactly once"
    assert hr(client, Z2SPSTATUS)[0] == 0


def test_out_of_range_request_is_refused_not_sent_and_not_retried(plant):
    """202 in the status register, nothing on the wire, no retry loop; the next request works."""
    sim, plc, client = plant
    wait(lambda: coils(client)[C_Z2VALID], 30, "zone 2 valid")
    sv = sim.ctl("get", addr=2, reg="SV")["raw"]
    hilt = sim.ctl("get", addr=2, reg="HILT")["raw"]  # DP=1: raw = x10
    sim.log(clear=True)
    client.write(Z2SPREQ, hilt + 100)
    wait(lambda: hr(client, Z2SPSTATUS)[0] == 202, 10, "status 202 (out of range)")
    program_time(client, 5.0, "two and a half retry waits: a retry would be an FC06 or another status")
    assert fc06(sim.log(clear=True), 2) == [], "an out-of-range set point went on the wire"
    assert hr(client, Z2SPSTATUS)[0] == 202
    assert sim.ctl("get", addr=2, reg="SV")["raw"] == sv
    good = 1100 if sv != 1100 else 1150
    client.write(Z2SPREQ, good)
    wait(lambda: sim.ctl("get", addr=2, reg="SV")["raw"] == good, 10, "the next request to reach the MV-D94")
    wait(lambda: hr(client, Z2SPSTATUS)[0] == 0, 10, "status 0 (sent)")
    program_time(client, 2.5, "a doubled write would come within a retry wait")
    assert fc06(sim.log(clear=True), 2) == [(0, good)], "the request must be written exactly once"


# Product B of the examples (Line_Products): A, captured at the first read, with these fields
# (simulator register: engineering value); A's set points are the simulator's initial ones.
PRODUCT_B = {1: {"SP1": 165.0, "PB": 15.0}, 2: {"SV": 145.0, "A1SP": 5.0, "PB": 12.0, "TD": 40}}
PRODUCT_A_SP = {1: ("SP1", 120.0), 2: ("SV", 100.0)}
# the register of each field (maps/fdc100.json, maps/mvd94.json)
ADDR = {1: {"SP1": 0, "PB": 14}, 2: {"SV": 0, "A1SP": 3, "PB": 6, "TD": 7}}


def product_switch(sim, client):
    """HR 1026 := 2: each zone downloads product B's recipe (WriteSettings): the line shows
    product 2 held (HR 11) with both recipe statuses 0, the simulator holds B's fields, each
    written once and nothing else (A1SP and TD of zone 2 too: the whole recipe, not only the
    set point). HR 1026 := 1: back to A, the line as first read. Both examples: their
    Line_Products, the same block (the LD example's is read from the ST example's text)."""
    assert "SP1=120.0" in oplc.EXAMPLE_DEVICES[0] and "SV=100.0" in oplc.EXAMPLE_DEVICES[1]
    wait(lambda: client.coils(10)[C_Z1VALID] and client.coils(10)[C_Z2VALID], 30, "both zones valid")
    a = {n: {f: sim.ctl("get", addr=n, reg=f)["eng"] for f in PRODUCT_B[n]} for n in (1, 2)}
    for n, (reg, sp) in PRODUCT_A_SP.items():
        a[n][reg] = sp
    assert all(a[n][f] != PRODUCT_B[n][f] for n in (1, 2) for f in PRODUCT_B[n]), a
    sim.log(clear=True)
    client.write(PRODUCTREQ, 2)
    wait(lambda: client.hr(PRODUCTHELD)[0] == 2, 30, "the line to hold product B (HR 11)")
    assert client.hr(Z1RSTATUS, 4) == [0, 0, 0, 0], "recipe status and field of both zones"
    log = sim.log(clear=True)
    for n in (1, 2):
        for f, v in PRODUCT_B[n].items():
            assert sim.ctl("get", addr=n, reg=f)["eng"] == v, (n, f)
        assert sorted(r for r, _ in fc06(log, n)) == sorted(ADDR[n].values()), \
            f"zone {n}: one write per field that differs, nothing else"
    client.write(PRODUCTREQ, 1)
    wait(lambda: client.hr(PRODUCTHELD)[0] == 1, 30, "the line to hold product A again")
    assert client.hr(Z1RSTATUS, 2) == [0, 0]
    for n in (1, 2):
        for f, v in a[n].items():
            assert sim.ctl("get", addr=n, reg=f)["eng"] == v, (n, f)


def test_product_switch_downloads_each_zones_recipe_and_back(plant):
    sim, plc, client = plant
    product_switch(sim, client)
