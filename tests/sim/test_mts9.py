"""MT-S9 counter/meter against the MT-S9 manual: the three framings, 32-bit
values low word first, counting, Over-Flow, Decimal Set and the Author gate."""
import time

import minimalmodbus
import pytest

from conftest import crc, frames, instrument, mbpoll, mbpoll_values, sim_fixture
import simctl

rtu = sim_fixture(["mts9:1:framing=rtu,digits=6", "mts9:2:rate=5000,digits=4"],
                  fmt="8N1", scope="module")


@pytest.fixture
def raw_factory(raw_factory):
    """Raw masters at these lines' 8N1 (the simulator hears only a master on the line)."""
    return lambda port, baud=9600, stop=1: raw_factory(port, baud, stop)


def hexu(data):
    return data.hex(" ").upper()


def test_rtu_manual_frames(rtu, raw_factory):
    raw = raw_factory(rtu)
    rtu.ctl("set", addr=1, reg="Real Data", raw=0x00020000)      # words 0000 0002 on the wire
    assert hexu(raw.xfer("01 03 00 00 00 02 C4 0B")) == "01 03 04 00 00 00 02 7B F2"
    assert hexu(raw.xfer("01 06 00 00 00 02 08 0B")) == "01 06 00 00 00 02 08 0B"
    assert rtu.ctl("get", addr=1, reg="Real Data")["raw"] == 0x00020002   # low word written
    assert hexu(raw.xfer("01 10 00 00 00 02 04 00 0A 01 02 53 FC")) == "01 10 00 00 00 02 41 C8"
    assert rtu.ctl("get", addr=1, reg="Real Data")["raw"] == 16908298


def test_32bit_low_word_first_with_independent_masters(rtu):
    """minimalmodbus CDAB (BYTEORDER_LITTLE_SWAP) and mbpoll's default word order agree."""
    inst = instrument(rtu.port, 1, stop=1)
    inst.write_long(0, -123456, signed=True, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP)
    assert rtu.ctl("get", addr=1, reg="REAL")["raw"] == -123456
    assert inst.read_long(0, signed=True, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == -123456
    res = mbpoll(rtu.port, "-a", 1, "-t", "4:int", "-r", 0, "-c", 1, stop=1)
    assert mbpoll_values(res) == {0: -123456}, res.stdout + res.stderr
    # Display Data = the value when it fits 6 digits
    assert inst.read_long(2, signed=True, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == -123456
    assert inst.read_register(4) == 0


def test_overflow_and_display_clamp(rtu):
    inst = instrument(rtu.port, 1, stop=1)
    rtu.ctl("set", addr=1, reg="REAL", raw=1234567)                # 7 digits > 6
    assert inst.read_register(4) == 1
    assert inst.read_long(2, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == 999999
    rtu.ctl("set", addr=1, reg="REAL", raw=-200000)
    assert inst.read_register(4) == 1
    assert inst.read_long(2, signed=True, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == -199999
    rtu.ctl("set", addr=1, reg="REAL", raw=0)
    assert inst.read_register(4) == 0


def test_counts_at_its_rate_and_overflows_past_4_digits(rtu):
    inst = instrument(rtu.port, 2, stop=1)
    first = inst.read_long(0, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP)
    rtu.wait_for(lambda: inst.read_long(0, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP)
                 > first + 300, timeout=10)
    rtu.wait_for(lambda: inst.read_register(4) == 1, timeout=20)       # past 9999
    assert inst.read_long(2, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == 9999


def test_author_gates_setup_registers(rtu, raw_factory):
    raw = raw_factory(rtu)
    assert hexu(raw.xfer(crc("01 06 00 05 00 02"))) == crc("01 86 03")     # Author 0: locked
    assert hexu(raw.xfer(crc("01 06 00 09 00 01"))) == crc("01 06 00 09 00 01")
    assert hexu(raw.xfer(crc("01 06 00 05 00 02"))) == crc("01 06 00 05 00 02")  # Decimal 2
    assert hexu(raw.xfer(crc("01 03 00 05 00 01"))) == crc("01 03 02 00 02")
    assert hexu(raw.xfer(crc("01 06 00 07 00 04"))) == crc("01 86 03")     # Baud needs 3
    assert hexu(raw.xfer(crc("01 06 00 05 00 06"))) == crc("01 86 03")     # 6 decimals > 6 digits
    assert hexu(raw.xfer(crc("01 06 00 09 00 06"))) == crc("01 86 03")     # Author 0..5
    rtu.ctl("power_cycle", addr=1)                                          # Author back to 0
    assert rtu.ctl("get", addr=1, reg="Author")["raw"] == 0
    assert rtu.ctl("get", addr=1, reg="Decimal")["raw"] == 2                # setting kept
    assert hexu(raw.xfer(crc("01 06 00 05 00 00"))) == crc("01 86 03")


@pytest.mark.parametrize("request_hex,reply_hex", [
    ("01 04 00 00 00 01", "01 84 01"),
    ("01 03 00 09 00 02", "01 83 02"),
    ("01 03 00 00 00 00", "01 83 03"),
    ("01 06 00 02 00 00", "01 86 02"),       # Display Data is read-only
    ("01 06 00 0A 00 00", "01 86 02"),
])
def test_exceptions(rtu, raw_factory, request_hex, reply_hex):
    assert hexu(raw_factory(rtu).xfer(crc(request_hex))) == crc(reply_hex)


def lrc_frame(body_hex):
    """':' hex LRC CR LF of a frame body, the LRC computed here (two's complement of the sum)."""
    body = bytes.fromhex(body_hex)
    return b":" + (body + bytes([-sum(body) & 0xFF])).hex().upper().encode() + b"\r\n"


def test_type_register_switches_framing(rtu, raw_factory):
    """Type = 0 (ASCII) on an RTU line: the meter answers the write, then is deaf to RTU and
    answers ASCII on the same line (the other meter still answers RTU)."""
    raw = raw_factory(rtu)
    rtu.ctl("set", addr=2, reg="Author", raw=5)
    assert hexu(raw.xfer(crc("02 06 00 08 00 00"))) == crc("02 06 00 08 00 00")
    assert raw.xfer(crc("02 03 00 08 00 01")) == b""
    assert raw.xfer(lrc_frame("02 03 00 08 00 01")) == lrc_frame("02 03 02 00 00")
    assert hexu(raw.xfer(crc("01 03 00 08 00 01"))) == crc("01 03 02 00 01")
    rtu.ctl("set", addr=2, reg="Type", raw=1)
    assert hexu(raw.xfer(crc("02 03 00 08 00 01"))) == crc("02 03 02 00 01")


def test_request_at_once_after_a_reply(raw_factory):
    """A master that sends its next request the moment another framing's reply is in. The
    MV-D94's RTU receiver still holds the ASCII request (at 2400 baud its t3.5 is 16 ms, far
    longer than this master takes): the reply on the line ends that frame, so the RTU request
    is framed alone and answered, every time (it was appended to the held bytes and lost)."""
    with simctl.Simulator(["mvd94:1:SV=123", "mts9:2:framing=ascii"], baud=2400,
                          fmt="8N2") as sim:
        raw = raw_factory(sim, baud=2400, stop=2)
        for _ in range(5):
            # by_log=False: back the moment the whole reply is in, no control round trip
            assert raw.xfer(lrc_frame("02 03 00 08 00 01"), by_log=False) == \
                lrc_frame("02 03 02 00 00")
            assert hexu(raw.xfer(crc("01 03 00 00 00 01"))) == crc("01 03 02 00 7B")


def test_frame_end_due_before_the_next_bytes(raw_factory):
    """The simulator stalled (SIGSTOP) after it read a lone address byte and until the next
    request was in: the frame end that fell due meanwhile (the byte is garbage after
    LONG_GAP, 50 ms) goes first, and the request is framed alone and answered. asyncio runs
    a loop iteration's I/O before its due timers: the request was appended to the byte and
    lost. The ASCII meter on the line logs the byte at once (no ':'): the simulator had read
    it before it stopped."""
    import os
    import signal
    request = crc("01 03 00 00 00 01")
    with simctl.Simulator(["mvd94:1:SV=123", "mts9:2:framing=ascii"], fmt="8N2") as sim:
        raw = raw_factory(sim, stop=2)
        for _ in range(3):
            sim.log()
            raw._send("01")                     # pylint: disable=protected-access
            sim.wait_for(lambda: sim.log(clear=False), interval=0.001)
            os.kill(sim.proc.pid, signal.SIGSTOP)
            try:
                time.sleep(0.15)
                raw._send(request)              # pylint: disable=protected-access
                time.sleep(0.05)
            finally:
                os.kill(sim.proc.pid, signal.SIGCONT)
            got, end = b"", time.monotonic() + 10.0
            while len(got) < 7 and time.monotonic() < end:
                got += raw.ser.read(64)
                time.sleep(0.01)
            assert [f["hex"] for f in sim.log()
                    if f["dir"] == "rx" and f.get("framing") == "rtu"] == ["01", request]
            assert hexu(got) == crc("01 03 02 00 7B")


def test_three_framings_on_one_line(raw_factory):
    """An MV-D94 (RTU), an MT-S9 on ASCII and one on RTU without CRC on one line: each device
    hears every byte and answers only frames of its own framing addressed to it."""
    with simctl.Simulator(["mvd94:1:SV=123", "mts9:2:framing=ascii", "mts9:3:framing=nocrc"],
                          fmt="8N2") as sim:
        raw = raw_factory(sim, stop=2)
        assert hexu(raw.xfer(crc("01 03 00 00 00 01"))) == crc("01 03 02 00 7B")
        assert raw.xfer(lrc_frame("02 03 00 08 00 01")) == lrc_frame("02 03 02 00 00")
        # no CRC at all, or a wrong one: the no-CRC meter answers, once, with a real CRC
        assert hexu(raw.xfer("03 03 00 08 00 01")) == crc("03 03 02 00 02")
        assert hexu(raw.xfer("03 03 00 08 00 01 00 00")) == crc("03 03 02 00 02")
        # a frame in another framing than the addressed device's: silence
        assert raw.xfer(crc("02 03 00 08 00 01")) == b""          # RTU to the ASCII meter
        assert raw.xfer(lrc_frame("01 03 00 00 00 01")) == b""    # ASCII to the MV-D94
        assert raw.xfer(lrc_frame("03 03 00 08 00 01")) == b""    # ASCII to the no-CRC meter
        assert raw.xfer("01 03 00 00 00 01 00 00") == b""          # bad CRC to the MV-D94
        # a write in ASCII reaches the ASCII meter only
        assert raw.xfer(lrc_frame("02 06 00 09 00 05")) == lrc_frame("02 06 00 09 00 05")
        assert sim.ctl("get", addr=2, reg="Author")["raw"] == 5
        assert sim.ctl("get", addr=3, reg="Author")["raw"] == 0
        # the frame log says which receiver took each frame
        sim.log(clear=True)
        raw.xfer(lrc_frame("02 03 00 08 00 01"))
        # (the RTU receivers judge the frame once the line has been quiet: after the reply)
        got, end = set(), time.monotonic() + 10
        while ("rx", "rtu", "bad CRC") not in got and time.monotonic() < end:
            got |= {(f["dir"], f.get("framing"), f.get("info", "")) for f in sim.log(clear=True)}
            time.sleep(0.01)
        assert ("rx", "ascii", "") in got and ("tx", "ascii", "") in got, got
        assert ("rx", "rtu", "bad CRC") in got, got


def test_nocrc_manual_frames(raw_factory):
    with simctl.Simulator(["mts9:1:framing=nocrc"], fmt="8N1") as sim:
        raw = raw_factory(sim)
        # FC03: the corrected no-CRC reply (value 0) carries the real CRC FA 33
        assert hexu(raw.xfer("01 03 00 00 00 02 00 00")) == "01 03 04 00 00 00 00 FA 33"
        assert hexu(raw.xfer("01 06 00 00 00 02 00 00")) == "01 06 00 00 00 02 08 0B"
        assert hexu(raw.xfer("01 10 00 00 00 02 04 00 0A 01 02 00 00")) == \
            "01 10 00 00 00 02 41 C8"
        assert sim.ctl("get", addr=1, reg="REAL")["raw"] == 16908298
        # a real CRC is accepted too (the field is not checked), and so is no CRC at all
        assert hexu(raw.xfer("01 03 00 08 00 01 05 C8")) == crc("01 03 02 00 02")
        assert hexu(raw.xfer("01 03 00 08 00 01")) == crc("01 03 02 00 02")
        assert sim.ctl("get", addr=1, reg="Type")["raw"] == 2


def test_ascii_manual_frames_and_minimalmodbus():
    # 8N1, not the usual 7E1 of Modbus ASCII: Linux ptys are always CS8 without parity
    # (tcsetattr fails with EINVAL when CS7 or PARENB is the only change asked for).
    with simctl.Simulator(["mts9:1:framing=ascii"], fmt="8N1") as sim:
        import serial
        ser = serial.Serial(sim.port, 9600, timeout=0.5)
        try:
            def xfer(frame):
                ser.reset_input_buffer()
                ser.write(frame)
                return ser.read_until(b"\n")
            sim.ctl("set", addr=1, reg="REAL", raw=0x07140714)
            assert xfer(b":010300000002FA\r\n") == b":01030407140714C2\r\n"
            assert xfer(b":010600000002F7\r\n") == b":010600000002F7\r\n"
            assert xfer(b":01100000000204000A0102DC\r\n") == b":011000000002ED\r\n"
            assert sim.ctl("get", addr=1, reg="REAL")["raw"] == 16908298
            assert xfer(b":01100000000204000A0102FA\r\n") == b""   # the manual's wrong LRC
        finally:
            ser.close()
        inst = instrument(sim.port, 1, mode=minimalmodbus.MODE_ASCII, parity="N", stop=1)
        inst.write_long(0, 4242, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP)
        assert inst.read_long(0, byteorder=minimalmodbus.BYTEORDER_LITTLE_SWAP) == 4242
        log = frames(sim)
        assert ("rx", ":01100000000204000A0102DC\r\n".encode().hex(" ").upper()) in log
