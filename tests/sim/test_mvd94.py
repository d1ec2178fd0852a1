"""SetPro MV-D94 / VD model against the SetPro manual, with mbpoll,
minimalmodbus and raw bytes as masters."""
import json
import os

import pytest

from conftest import crc, frames, instrument, mbpoll, mbpoll_values, sim_fixture
import simctl

sim = sim_fixture(["mvd94:1:SV=100.0,DP=1", "vd:2:SV=1000", "mvd94:7"], scope="module")


@pytest.fixture(autouse=True)
def _clean_log(sim):
    sim.log(clear=True)


def test_manual_fc03_example_byte_for_byte(sim):
    """Manual 6.1: SV = 1000 read with mbpoll -> 01 03 02 03 E8 B8 FA."""
    res = mbpoll(sim.port, "-a", 1, "-r", 0, "-c", 1)
    assert res.returncode == 0, res.stdout + res.stderr
    assert mbpoll_values(res) == {0: 1000}
    assert frames(sim) == [("rx", "01 03 00 00 00 01 84 0A"), ("tx", "01 03 02 03 E8 B8 FA")]


def test_manual_fc04_example_byte_for_byte(sim):
    """Manual 6.2: PV 27 (DP 0) via FC04 at 0x1000 -> 01 04 02 00 1B F9 3B."""
    sim.ctl("plant", addr=7, hold=True)
    sim.ctl("set", addr=7, reg="PV", raw=27)
    res = mbpoll(sim.port, "-a", 7, "-t", 3, "-r", 0x1000, "-c", 1)
    assert mbpoll_values(res) == {0x1000: 27}, res.stdout
    assert frames(sim) == [("rx", crc("07 04 10 00 00 01")), ("tx", crc("07 04 02 00 1B"))]
    # the manual's own frame at address 1:
    sim.ctl("plant", addr=1, hold=True)
    sim.ctl("set", addr=1, reg="PV", raw=27)
    inst = instrument(sim.port, 1)
    assert inst.read_register(0x1000, functioncode=4) == 27
    assert frames(sim) == [("rx", "01 04 10 00 00 01 35 0A"), ("tx", "01 04 02 00 1B F9 3B")]
    sim.ctl("plant", addr=1, hold=False)


def test_manual_fc06_example_echo(sim, raw_factory):
    """Manual 6.3: write SV = 500 -> echo 01 06 00 00 01 F4 89 DD; then restore."""
    raw = raw_factory(sim)
    assert raw.xfer("01 06 00 00 01 F4 89 DD").hex(" ").upper() == "01 06 00 00 01 F4 89 DD"
    assert sim.ctl("get", addr=1, reg="SV")["raw"] == 500
    res = mbpoll(sim.port, "-a", 1, "-r", 0, write=[1000])
    assert res.returncode == 0, res.stdout
    assert sim.ctl("get", addr=1, reg="SV")["raw"] == 1000


def test_vd_same_map_and_startup_values(sim):
    """The VD answers the same frames; SV=100.0 with DP=1 is raw 1000 (regardless of decimal)."""
    inst = instrument(sim.port, 2)
    assert inst.read_register(0) == 1000
    assert inst.read_register(0x10) == 0x10            # DP code "0000"
    assert instrument(sim.port, 1).read_register(0x10) == 0x11   # DP=1 -> "000.0"
    assert instrument(sim.port, 1).read_register(0, number_of_decimals=1) == 100.0


def test_negative_values_twos_complement(sim):
    """SPOF = -10 travels as FF F6 (derived frame 01 06 00 01 FF F6 19 BC)."""
    inst = instrument(sim.port, 1)
    inst.write_register(1, -10, signed=True, functioncode=6)
    assert frames(sim)[0] == ("rx", "01 06 00 01 FF F6 19 BC")
    assert inst.read_register(1, signed=True) == -10
    inst.write_register(1, 0, functioncode=6)


@pytest.mark.parametrize("request_hex,reply_hex", [
    ("01 05 00 00 FF 00", "01 85 01"),          # FC05 unsupported (VD's "[03,,05,06]" typo)
    ("01 10 00 00 00 01 02 00 01", "01 90 01"),  # FC16 is not in the manual
    ("01 01 00 00 00 01", "01 81 01"),
    ("01 03 10 00 00 01", "01 83 02"),          # PV's address with FC03
    ("01 04 00 00 00 01", "01 84 02"),          # SV's address with FC04
    ("01 04 10 02 00 02", "01 84 02"),          # past 0x1002
    ("01 03 00 7D 00 02", "01 83 02"),          # past 0x007D
    ("01 03 00 00 00 00", "01 83 03"),          # 0 words
    ("01 03 00 00 00 7F", "01 83 03"),          # > 0x7E words
    ("01 06 00 22 00 00", "01 86 02"),          # FC06 outside 0x0000..0x0021
    ("01 06 00 0F 00 17", "01 86 03"),          # UNIT 0x17: not a unit code (text's typo)
    ("01 06 00 01 04 B0", "01 86 03"),          # SPOF 1200 > 1000
    ("01 06 00 06 0B B9", "01 86 03"),          # PB 3001 > 3000
])
def test_exceptions_per_manual(sim, raw_factory, request_hex, reply_hex):
    raw = raw_factory(sim)
    assert raw.xfer(crc(request_hex)).hex(" ").upper() == crc(reply_hex)


def test_exception_vectors_from_spec(sim, raw_factory):
    raw = raw_factory(sim)
    assert raw.xfer(crc("01 03 10 00 00 01")).hex(" ").upper() == "01 83 02 C0 F1"
    assert raw.xfer(crc("01 05 00 00 FF 00")).hex(" ").upper() == "01 85 01 83 50"


def test_window_edges_answer(sim, raw_factory):
    """0x7E words from 0 and 3 words at 0x1000 are legal; undefined words read as 0."""
    raw = raw_factory(sim)
    got = raw.xfer(crc("01 03 00 00 00 7E"))
    assert got[:3] == bytes([1, 3, 0xFC]) and len(got) == 3 + 0xFC + 2
    assert got[3 + 2 * 0x22:-2] == bytes(2 * (0x7E - 0x22))
    got = raw.xfer(crc("01 04 10 00 00 03"))
    assert got[:3] == bytes([1, 4, 6]) and got[5:9] == bytes(4)
    assert raw.xfer(crc("01 06 00 0F 00 0C")).hex(" ").upper() == "01 06 00 0F 00 0C B9 CC"


def test_silence_bad_crc_foreign_and_broadcast(sim, raw_factory):
    raw = raw_factory(sim)
    assert raw.xfer("01 03 00 00 00 01 84 0B") == b""            # bad CRC
    assert raw.xfer(crc("09 03 00 00 00 01")) == b""             # nobody at 9
    assert raw.xfer(crc("00 03 00 00 00 01")) == b""             # broadcast read: ignored
    # broadcast write (the manual's worked frame): applied by all, answered by none
    assert raw.xfer("00 06 00 00 01 F4 88 0C") == b""
    for addr in (1, 2, 7):
        assert sim.ctl("get", addr=addr, reg="SV")["raw"] == 500
    log = sim.log()
    assert [f["dir"] for f in log] == ["rx"] * 4
    assert log[0]["info"] == "bad CRC"
    stats = sim.ctl("stats")
    assert stats["line"]["foreign"] >= 1 and stats["line"]["broadcasts"] >= 2
    for addr, sv in ((1, 1000), (2, 1000), (7, 100)):
        sim.ctl("set", addr=addr, reg="SV", raw=sv)


def test_address_change_moves_the_slave(sim, raw_factory):
    raw = raw_factory(sim)
    assert raw.xfer(crc("07 06 00 1B 00 08")).hex(" ").upper() == crc("07 06 00 1B 00 08")
    assert raw.xfer(crc("07 03 00 1B 00 01")) == b""
    assert raw.xfer(crc("08 03 00 1B 00 01")).hex(" ").upper() == crc("08 03 02 00 08")
    assert raw.xfer(crc("08 06 00 1B 00 07")).hex(" ").upper() == crc("08 06 00 1B 00 07")


def test_baud_change_makes_it_deaf(sim, raw_factory):
    """BAUD 0x1F (19.2K) while the line runs 9600: the unit hears garbage and stays silent."""
    raw = raw_factory(sim)
    assert raw.xfer(crc("07 06 00 1C 00 1F")).hex(" ").upper() == crc("07 06 00 1C 00 1F")
    assert raw.xfer(crc("07 03 00 00 00 01")) == b""
    sim.ctl("set", addr=7, reg="BAUD", raw=0x1E)
    assert raw.xfer(crc("07 03 00 1C 00 01")).hex(" ").upper() == crc("07 03 02 00 1E")


def test_thermal_model_follows_sv():
    """PV rises toward SV under the controller's own output; a power cycle drops the output."""
    with simctl.Simulator(["mvd94:1:SV=80,PB=5.0,TD=0,MR=10.0"], time_scale=60) as s:
        inst = instrument(s.port, 1)
        first = inst.read_register(0x1000, functioncode=4, signed=True)
        assert 20 <= first <= 35
        s.wait_for(lambda: inst.read_register(0x1000, functioncode=4, signed=True) >= 70,
                   timeout=20)
        s.ctl("power_cycle", addr=1)
        assert s.ctl("stats")["devices"]["1"]["output"] < 100
        # direct (cooling) action with SV below ambient drives PV down
        inst.write_register(0x11, 0x15, functioncode=6)
        inst.write_register(0, 10, functioncode=6)
        s.wait_for(lambda: inst.read_register(0x1000, functioncode=4, signed=True) < 20,
                   timeout=30)
