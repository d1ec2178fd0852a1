"""FDC Series 100 (BTC-9100) model against the FDC manual: examples 1-7,
aliases, exceptions with their EROR codes, commands, locks, scaling, power cycle."""
import pytest

from conftest import crc, frames, instrument, mbpoll, mbpoll_values, sim_fixture
import simctl  # noqa: E402  (tools/sim, on the path conftest sets)

# Linux ptys cannot carry parity, so the line runs 8N1 and the FDC's PARI follows it (2 = None).
sim = sim_fixture(["fdc100:1", "fdc100:3:SP1=150.0"], fmt="8N1", time_scale=20)


@pytest.fixture
def raw_factory(raw_factory):
    """Raw masters at this line's 8N1 (the simulator hears only a master on the line)."""
    return lambda port, baud=9600, stop=1: raw_factory(port, baud, stop)

EX1_WORDS = ("4F19 4E83 4E83 0000 0001 0000 0001 4D6D 51C4 4D6D 6321 4E1F 0002 0000 0064 0064 "
             "00FA 0000 0000 4E1F 0001 00B4 00FA 0000 0000 0002 4E1F 0000 4E1F 0001 00B4 0064 "
             "4E1F 0002 5207 0000 0001 0000 0001 0001 0002 0001 0000 0000 0002 0003 0004 0006 "
             "0007 0008 000A 0011")


def hexu(data):
    return data.hex(" ").upper()


def eror(s, addr=1):
    return s.ctl("get", addr=addr, reg="EROR")["raw"]


def test_example1_download_defaults(sim, raw_factory):
    req = "01 10 00 00 00 34 68 " + " ".join(w[:2] + " " + w[2:] for w in EX1_WORDS.split())
    assert crc(req).endswith("8E C3")                  # the manual's Example 1
    assert hexu(raw_factory(sim).xfer(crc(req))) == "01 10 00 00 00 34 C1 DE"
    assert sim.ctl("get", addr=1, reg="SP1")["eng"] == 25.0
    assert sim.ctl("get", addr=1, reg="REHI")["eng"] == 100.0
    assert sim.ctl("get", addr=1, reg="SP1H")["eng"] == 537.8
    # Example 1 also set PARI = 0 (Even): on this 8N1 line the unit now hears only parity
    # errors and stays silent, as a real one would, until PARI is None again.
    assert raw_factory(sim).xfer("01 03 00 80 00 04 45 E1") == b""
    sim.ctl("set", addr=1, reg="PARI", raw=2)


def test_download_block_is_checked_as_one_set(raw_factory):
    """Example 1's block brings SP1 with its limits: SP1 is checked against the block's own
    SP1L..SP1H, not the unit's old ones (else a download to a unit with narrower limits fails);
    an SP1 outside the block's limits is refused and nothing is written."""
    words = EX1_WORDS.split()
    words[42] = "0002"                                 # PARI None: this line is 8N1

    def block(sp1):
        body = "01 10 00 00 00 34 68 " + " ".join(w[:2] + " " + w[2:] for w in [sp1] + words[1:])
        return crc(body)
    with simctl.Simulator(["fdc100:1"], fmt="8N1") as s:
        raw = raw_factory(s)
        s.ctl("set", addr=1, reg="SP1H", raw=20500)    # SP1 may not exceed 20500 now
        assert hexu(raw.xfer(block("6400"))) == crc("01 90 03")     # above the block's 6321
        assert s.ctl("get", addr=1, reg="SP1H")["raw"] == 20500     # nothing written
        assert hexu(raw.xfer(block("5208"))) == "01 10 00 00 00 34 C1 DE"
        assert s.ctl("get", addr=1, reg="SP1")["raw"] == 0x5208
        assert s.ctl("get", addr=1, reg="SP1H")["raw"] == 0x6321
        assert hexu(raw.xfer(crc("01 06 00 00 64 00"))) == crc("01 86 03")   # FC06: limits


def test_example2_aliases_128_and_64(sim, raw_factory):
    sim.ctl("plant", addr=1, hold=True, temp=25.0)
    raw = raw_factory(sim)
    high = raw.xfer("01 03 00 80 00 04 45 E1")
    low = raw.xfer("01 03 00 40 00 04 45 DD")
    assert high[:3] == bytes([1, 3, 8]) and high[3:5] == bytes.fromhex("4F19")  # PV 25.0
    assert high[3:7] == low[3:7]                       # PV, SV identical through both windows
    res = mbpoll(sim.port, "-a", 1, "-r", 128, "-c", 2, stop=1)
    assert mbpoll_values(res)[128] == 0x4F19, res.stdout + res.stderr
    sim.ctl("plant", addr=1, hold=False)


def test_example6_reads_80_words_and_not_81(sim, raw_factory):
    raw = raw_factory(sim)
    got = raw.xfer("01 03 00 00 00 50 45 F6")
    assert got[:3] == bytes([1, 3, 160]) and len(got) == 165
    assert hexu(raw.xfer(crc("01 03 00 00 00 51"))) == crc("01 83 03")


@pytest.mark.parametrize("request_hex,reply_hex,code", [
    ("01 01 00 00 00 01", "01 81 01 81 90", 10),      # bad function
    ("01 05 00 00 FF 00", crc("01 85 01"), 10),
    ("01 03 00 50 00 01", "01 83 02 C0 F1", 11),      # 80..127 do not exist
    ("01 03 00 4F 00 02", "01 83 02 C0 F1", 11),
    ("01 03 00 83 00 02", "01 83 02 C0 F1", 11),      # past 131
    ("01 06 00 40 00 00", "01 86 03 02 61", 14),      # PV is read-only
    ("01 06 00 42 00 00", "01 86 03 02 61", 14),      # MV1 outside manual mode
    ("01 06 00 37 00 00", "01 86 03 02 61", 14),      # ADLO before the calibration unlock
    ("01 06 00 00 FF FF", "01 86 03 02 61", 15),      # SP1 above SP1H
    ("01 06 00 06 00 04", "01 86 03 02 61", 15),      # DP 0..3
    ("01 06 00 48 12 34", "01 86 03 02 61", 15),      # not a command code
])
def test_exceptions_and_eror(sim, raw_factory, request_hex, reply_hex, code):
    raw = raw_factory(sim)
    sim.ctl("set", addr=1, reg="EROR", raw=0)
    assert hexu(raw.xfer(crc(request_hex))) == reply_hex
    assert eror(sim) == code


def test_fc16_is_all_or_nothing(sim, raw_factory):
    """One bad word (SP1 above SP1H) rejects the whole block: SP2 keeps its value."""
    before = sim.ctl("get", addr=1, reg="SP2")["raw"]
    got = raw_factory(sim).xfer(crc("01 10 00 00 00 02 04 FF FF 4E 1F"))
    assert hexu(got) == crc("01 90 03")
    assert sim.ctl("get", addr=1, reg="SP2")["raw"] == before


def test_example5_manual_mode_and_example3_reset(sim, raw_factory):
    raw = raw_factory(sim)
    assert hexu(raw.xfer("01 06 00 48 68 27 66 06")) == "01 06 00 48 68 27 66 06"
    assert sim.ctl("get", addr=1, reg="MODE")["raw"] >> 8 == 3
    inst = instrument(sim.port, 1, stop=1)
    inst.write_register(130, 55.5, number_of_decimals=2, functioncode=6)   # MV1 via alias
    assert inst.read_register(66, number_of_decimals=2) == 55.5
    assert sim.ctl("stats")["devices"]["1"]["output"] == 55.5
    assert hexu(raw.xfer("01 06 00 48 68 25 E7 C7")) == "01 06 00 48 68 25 E7 C7"
    assert sim.ctl("get", addr=1, reg="MODE")["raw"] >> 8 == 0
    assert hexu(raw.xfer(crc("01 06 00 42 00 00"))) == "01 86 03 02 61"


def test_example4_autotune_shows_then_returns(sim, raw_factory):
    raw = raw_factory(sim)
    assert hexu(raw.xfer("01 06 00 48 68 28 26 02")) == "01 06 00 48 68 28 26 02"
    inst = instrument(sim.port, 1, stop=1)
    assert inst.read_register(70) >> 8 == 2
    # 120 simulated seconds at time-scale 20 = 6 s
    sim.wait_for(lambda: inst.read_register(70) >> 8 == 0, timeout=20)


def test_example7_calibration_unlock(sim, raw_factory):
    raw = raw_factory(sim)
    assert hexu(raw.xfer(crc("01 06 00 37 4E 20"))) == "01 86 03 02 61"
    assert hexu(raw.xfer("01 06 00 48 68 2D E6 01")) == "01 06 00 48 68 2D E6 01"
    assert hexu(raw.xfer(crc("01 06 00 37 4E 20"))) == crc("01 06 00 37 4E 20")
    sim.ctl("power_cycle", addr=1)                     # the unlock does not survive
    assert hexu(raw.xfer(crc("01 06 00 37 4E 21"))) == "01 86 03 02 61"


def test_lock_levels(sim, raw_factory):
    raw = raw_factory(sim)
    sim.ctl("set", addr=1, reg="LOCK", raw=1)
    assert hexu(raw.xfer(crc("01 06 00 01 4E 83"))) == "01 86 03 02 61"    # SP2 locked
    assert eror(sim) == 14
    assert hexu(raw.xfer(crc("01 06 00 00 4F 19"))) == crc("01 06 00 00 4F 19")  # SP1 free
    sim.ctl("set", addr=1, reg="LOCK", raw=3)
    assert hexu(raw.xfer(crc("01 06 00 00 4F 19"))) == "01 86 03 02 61"
    assert hexu(raw.xfer(crc("01 06 00 03 00 00"))) == crc("01 06 00 03 00 00")  # unlock


def test_scaling_linear_input_uses_dp(sim):
    """*4 registers: d = 1 for thermocouples; d = DP for linear inputs (INPT > 10)."""
    sim.ctl("set", addr=3, reg="SP1", raw=19999 + 1500)
    assert sim.ctl("get", addr=3, reg="SP1")["eng"] == 150.0
    sim.ctl("set", addr=3, reg="INPT", raw=11)
    sim.ctl("set", addr=3, reg="DP", raw=2)
    assert sim.ctl("get", addr=3, reg="SP1")["eng"] == 15.0
    sim.ctl("set", addr=3, reg="INPT", raw=1)


def test_startup_value_and_thermal_dynamics(sim):
    """SP1=150.0 at start; the PID drives PV up from ambient (time-scale 20)."""
    inst = instrument(sim.port, 3, stop=1)
    assert (inst.read_register(0) - 19999) / 10 == 150.0
    inst.write_register(0, 19999 + 3000, functioncode=6)          # SP1 = 300.0
    start = (inst.read_register(64) - 19999) / 10
    sim.wait_for(lambda: (inst.read_register(64) - 19999) / 10 > start + 5, timeout=20)
    assert inst.read_register(66) > 0                   # MV1 shows the output


def test_broadcast_applied_without_reply(sim, raw_factory):
    raw = raw_factory(sim)
    assert raw.xfer(crc("00 06 00 49 00 07")) == b""
    assert sim.ctl("get", addr=1, reg="JOB1")["raw"] == 7
    assert sim.ctl("get", addr=3, reg="JOB1")["raw"] == 7
    assert [d for d, _ in frames(sim)][-1] == "rx"
