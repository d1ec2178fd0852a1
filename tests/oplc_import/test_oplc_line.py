"""The converted fixtures/line.cfg (OpenPLC v3 Slave Devices: a relay module at 2, a meter at 5
on one RTU line) built with the library in the project's runner (tools/runner, OpenPLC's scan
loop and located buffers) against the simulator's generic devices: the inputs land at the
located addresses OpenPLC gives them, outputs are written once and then only when they change,
each device's status follows the device (offline: its Valid falls, its values held, the other
device Valid again once the shims back off from the silent one)."""
import os
import sys
import time

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [os.path.join(ROOT, "tools", "sim"), os.path.join(ROOT, "tools", "runner")]
import simctl  # noqa: E402
from runner import Runner  # noqa: E402

EXE = os.environ.get("MBFB_OPLC_LINE_EXE", "")
PROG = "CONFIG0.RES0.INST0."
RELAY_INPUTS = [1, 0, 1, 1, 0, 0, 1, 0]
METER_INPUTS = [2301, 52, 1196, 0, 65535, 7, 8, 9]
METER_HOLDING = [0, 0x4248, 0x3333, 0x3F73]      # 50.0 and 0.95 as REAL, CDAB


def wait(pred, what, timeout=60.0):
    """Wait on a condition (a loaded machine may take long), else fail saying what."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = pred()
        if got:
            return got
        time.sleep(0.05)
    pytest.fail(f"timed out waiting for {what}")


def get(plc, name):
    return plc.command(f"get {PROG}{name}")   # BOOL: true/false


def requests(sim, head):
    """Requests on the line beginning with these bytes (address, function)."""
    return sum(1 for f in sim.log(clear=False) if f["dir"] == "rx" and f["hex"].startswith(head))


@pytest.fixture(scope="module")
def line():
    if not os.path.exists(EXE):
        pytest.fail(f"MBFB_OPLC_LINE_EXE={EXE!r}: run through ctest (target oplc_import_line)")
    devices = [f"generic:2:file={os.path.join(HERE, 'line_relays.json')}",
               f"generic:5:file={os.path.join(HERE, 'line_meter.json')}"]
    with simctl.Simulator(devices) as sim:
        with Runner(EXE, sets={f"{PROG}OPLC_PORT0": sim.port}) as plc:
            yield sim, plc


def test_inputs_at_openplcs_addresses(line):
    sim, plc = line

    def inputs():
        snap = plc.snapshot()
        ix = [int(snap.get("IX", {}).get(f"100.{i}", -1)) for i in range(8)]
        iw = [snap.get("IW", {}).get(str(100 + i), -1) for i in range(12)]
        return (ix, iw) if ix == RELAY_INPUTS and iw == METER_INPUTS + METER_HOLDING else None
    wait(inputs, "%IX100.0..7 and %IW100..111 to hold the devices' values")
    wait(lambda: get(plc, "DEV0_VALID") == "true" and get(plc, "DEV1_VALID") == "true",
         "both devices Valid")
    assert get(plc, "DEV0_ERRORID") == "0" and get(plc, "DEV1_ERRORID") == "0"


def test_outputs_written_only_when_they_change(line):
    sim, plc = line
    # the outputs start FALSE / 0 and were never written: written once at start
    wait(lambda: [sim.ctl("get", addr=2, reg=f"co:{i}")["raw"] for i in range(4)] == [0] * 4,
         "the relays switched off by the first write")
    wait(lambda: get(plc, "DEV0_WRITE0.HELD") == "true", "the first coil write confirmed")
    assert requests(sim, "02 0F") == 1 and requests(sim, "05 10") == 1
    plc.command("set %QX100.2 1")
    plc.command("set %QW101 1234")
    wait(lambda: sim.ctl("get", addr=2, reg="co:2")["raw"] == 1, "relay 3 switched on")
    wait(lambda: sim.ctl("get", addr=5, reg="out2")["raw"] == 1234, "out2 written")
    # many refreshes later: no write again
    start = int(get(plc, "DEV0_POLL0.REFRESHES"))
    wait(lambda: int(get(plc, "DEV0_POLL0.REFRESHES")) >= start + 5, "five more refreshes")
    assert requests(sim, "02 0F") == 2 and requests(sim, "05 10") == 2
    assert requests(sim, "02 02") >= 6                          # the inputs are polled


def test_status_per_device(line):
    sim, plc = line
    sim.ctl("offline", addr=5, on=True)
    wait(lambda: get(plc, "DEV1_VALID") == "false", "the meter's Valid to fall")
    wait(lambda: get(plc, "DEV1_ERRORID") != "0", "the meter's ErrorID")
    # the relays share the line: the default StaleTime counts its Timeout (5 x 1000 ms: the
    # meter's unanswered requests and the wait after each), so they stay Valid (t_neighbour.st)
    wait(lambda: get(plc, "DEV0_VALID") == "true", "the relays Valid beside the silent meter")
    assert get(plc, "DEV1_VALID") == "false"
    assert plc.snapshot()["IW"]["100"] == METER_INPUTS[0]     # the last value held, as v3 does
    sim.ctl("offline", addr=5, on=False)
    wait(lambda: get(plc, "DEV1_VALID") == "true", "the meter back")
