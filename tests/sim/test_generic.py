"""The generic device (tools/sim/modsim/generic.py) from a description file (generic_device.json):
FC 01/02/03/04/05/06/15/16 with pymodbus's serial client (RTU and ASCII framers) and
minimalmodbus, typed values decoded by pymodbus's own conversions, exceptions for unmapped
addresses and bad quantities, RTU without CRC with exact bytes, faults, the control protocol,
and bad description files refused with one line."""
import os
import subprocess

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient

import simctl
from conftest import crc, instrument, sim_fixture

HERE = os.path.dirname(os.path.abspath(__file__))
DESC = os.path.join(HERE, "generic_device.json")
DT = ModbusSerialClient.DATATYPE

sim = sim_fixture([f"generic:5:file={DESC}", "mvd94:1:SV=123"])


@pytest.fixture
def client(sim):
    c = ModbusSerialClient(port=sim.port, baudrate=9600, stopbits=2, timeout=1, retries=0)
    assert c.connect()
    yield c
    c.close()


def typed(registers, data_type, order):
    """pymodbus's decoding of words in ABCD/CDAB/BADC/DCBA (its word_order is big/little;
    a byte-swapped order is its words with their bytes swapped first)."""
    if order in ("BADC", "DCBA"):
        registers = [((w & 0xFF) << 8) | (w >> 8) for w in registers]
    return ModbusSerialClient.convert_from_registers(
        registers, data_type, word_order="little" if order in ("CDAB", "DCBA") else "big")


def test_reads_every_table(client):
    rr = client.read_coils(0, count=20, slave=5)
    assert not rr.isError() and rr.bits[:20] == [1, 0, 1, 1, 0, 0, 0, 1, 1] + [0] * 11
    rr = client.read_discrete_inputs(10, count=2000, slave=5)      # the protocol's most
    assert not rr.isError() and rr.bits[:6] == [0, 1, 1, 0, 1, 0] and not any(rr.bits[5:2000])
    rr = client.read_holding_registers(0, count=10, slave=5)
    assert rr.registers == [1, 2, 3, 65535, 0, 0, 0, 0, 0, 0]
    rr = client.read_input_registers(100, count=125, slave=5)      # the protocol's most
    assert rr.registers[:4] == [11, 12, 13, 0] and len(rr.registers) == 125


def test_typed_values_as_pymodbus_decodes_them(client):
    words = client.read_holding_registers(20, count=4, slave=5).registers
    assert typed(words[:2], DT.FLOAT32, "CDAB") == 230.5
    assert typed(words[2:], DT.FLOAT32, "CDAB") == -1.25
    assert typed(client.read_holding_registers(30, count=2, slave=5).registers,
                 DT.INT32, "ABCD") == -100000
    assert typed(client.read_input_registers(0, count=4, slave=5).registers[:2],
                 DT.FLOAT32, "ABCD") == 1.5
    assert typed(client.read_input_registers(300, count=4, slave=5).registers,
                 DT.FLOAT64, "DCBA") == 3.141592653589793


def test_writes_and_control_protocol(sim, client):
    assert not client.write_coil(100, True, slave=5).isError()
    assert sim.ctl("get", addr=5, reg="relay1")["raw"] == 1
    assert not client.write_coils(0, [0, 1, 0, 1, 1, 1, 1, 1, 1, 1], slave=5).isError()
    assert client.read_coils(0, count=10, slave=5).bits[:10] == [0, 1, 0, 1, 1, 1, 1, 1, 1, 1]
    assert sim.ctl("get", addr=5, reg="co:9")["raw"] == 1
    assert not client.write_register(3, 9, slave=5).isError()
    assert sim.ctl("get", addr=5, reg="hr:3")["raw"] == 9
    words = ModbusSerialClient.convert_to_registers(42.25, DT.FLOAT32, word_order="little")
    assert not client.write_registers(22, words, slave=5).isError()          # "bias", CDAB
    assert sim.ctl("get", addr=5, reg="bias")["eng"] == 42.25
    sim.ctl("set", addr=5, reg="setp", eng=99.5)
    assert typed(client.read_holding_registers(20, count=2, slave=5).registers,
                 DT.FLOAT32, "CDAB") == 99.5
    sim.ctl("set", addr=5, reg="count", eng=-7)
    assert sim.ctl("get", addr=5, reg="count")["eng"] == -7
    assert not sim.control({"op": "set", "addr": 5, "reg": "co:1", "raw": 2})["ok"]
    assert not sim.control({"op": "get", "addr": 5, "reg": "hr:15"})["ok"]      # unmapped


def exception_code(response):
    assert response.isError(), response
    return response.exception_code


def test_exceptions(sim, client, raw_factory):
    # unmapped: past a range's end, in the gap between ranges, a table's wrong half
    assert exception_code(client.read_holding_registers(9, count=2, slave=5)) == 2
    assert exception_code(client.read_holding_registers(12, count=1, slave=5)) == 2
    assert exception_code(client.read_coils(19, count=2, slave=5)) == 2
    assert exception_code(client.read_discrete_inputs(0, count=1, slave=5)) == 2
    assert exception_code(client.read_input_registers(2, count=99, slave=5)) == 2
    assert exception_code(client.write_coil(20, True, slave=5)) == 2
    assert exception_code(client.write_register(10, 1, slave=5)) == 2
    # read-only holding range; a multiple write over a range's end writes nothing
    assert exception_code(client.write_registers(40, [1], slave=5)) == 2
    assert exception_code(client.write_registers(8, [5, 5, 5], slave=5)) == 2
    assert sim.ctl("get", addr=5, reg="hr:8")["raw"] == 0
    assert exception_code(client.write_coils(18, [1, 1, 1], slave=5)) == 2
    assert sim.ctl("get", addr=5, reg="co:18")["raw"] == 0
    raw = raw_factory(sim)
    # quantity before address (03 before 02), FC05 value, byte counts: exact frames
    assert raw.xfer(crc("05 01 00 00 00 00")) == bytes.fromhex(crc("05 81 03"))
    assert raw.xfer(crc("05 02 00 0A 07 D1")) == bytes.fromhex(crc("05 82 03"))    # 2001 bits
    assert raw.xfer(crc("05 03 FF 00 00 7E")) == bytes.fromhex(crc("05 83 03"))    # 126 words
    assert raw.xfer(crc("05 04 FF 00 00 01")) == bytes.fromhex(crc("05 84 02"))
    assert raw.xfer(crc("05 05 00 64 12 34")) == bytes.fromhex(crc("05 85 03"))
    assert raw.xfer(crc("05 0F 00 00 00 03 02 07 00")) == bytes.fromhex(crc("05 8F 03"))
    assert raw.xfer(crc("05 07")) == bytes.fromhex(crc("05 87 01"))                # FC07
    # the exact reply of an odd bit count: LSB first, padded with zeros
    assert raw.xfer(crc("05 02 00 0A 00 05")) == bytes.fromhex(crc("05 02 01 16"))


def test_faults_apply(sim, client):
    sim.ctl("fault", addr=5, kind="exception", code=4, fc=1, count=1)
    assert exception_code(client.read_coils(0, count=1, slave=5)) == 4
    assert not client.read_coils(0, count=1, slave=5).isError()
    sim.ctl("fault", addr=5, kind="drop", fc=4, count=1)
    assert client.read_holding_registers(0, count=1, slave=5).registers == [1]  # FC03 untouched
    with pytest.raises(Exception):                                              # no reply
        client.read_input_registers(100, count=1, slave=5)
    assert client.read_input_registers(100, count=1, slave=5).registers == [11]
    sim.ctl("fault", addr=5, kind="bad_crc", count=1)
    with pytest.raises(Exception):
        client.read_discrete_inputs(10, count=3, slave=5)
    assert client.read_discrete_inputs(10, count=3, slave=5).bits[:3] == [0, 1, 1]
    assert sim.ctl("stats")["devices"]["5"]["faults"] == {"exception": 1, "drop": 1, "bad_crc": 1}


def test_broadcast_write_applied_not_answered(sim, raw_factory):
    raw = raw_factory(sim)
    assert raw.xfer(crc("00 05 00 65 FF 00")) == b""
    assert sim.ctl("get", addr=5, reg="relay2")["raw"] == 1
    assert raw.xfer(crc("00 01 00 65 00 01")) == b""


def test_ascii_and_nocrc_framings(raw_factory):
    """Three generic devices of one description on one line, one per framing: pymodbus's
    ASCII framer and minimalmodbus in ASCII, exact no-CRC bytes (the reply with a real CRC)."""
    with simctl.Simulator([f"generic:2:file={DESC},framing=ascii",
                           f"generic:3:file={DESC},framing=nocrc",
                           f"generic:4:file={DESC}"]) as line:
        c = ModbusSerialClient(port=line.port, framer=FramerType.ASCII, baudrate=9600,
                               stopbits=2, timeout=1, retries=0)
        assert c.connect()
        try:
            assert c.read_coils(0, count=4, slave=2).bits[:4] == [1, 0, 1, 1]
            assert not c.write_coils(0, [0, 0], slave=2).isError()
            assert c.read_coils(0, count=4, slave=2).bits[:4] == [0, 0, 1, 1]
            assert exception_code(c.read_holding_registers(10, count=1, slave=2)) == 2
            with pytest.raises(Exception):          # ASCII to the RTU device: silence
                c.read_discrete_inputs(10, count=3, slave=4)
        finally:
            c.close()
        assert line.ctl("get", addr=2, reg="co:0")["raw"] == 0
        inst = instrument(line.port, 2, mode="ascii")
        inst.write_bit(101, 1, functioncode=5)
        assert inst.read_bits(100, 2, functioncode=1) == [0, 1]
        assert inst.read_float(20, functioncode=3, byteorder=3) == 230.5     # CDAB
        raw = raw_factory(line)
        assert raw.xfer("03 03 00 00 00 02") == bytes.fromhex(crc("03 03 04 00 01 00 02"))
        assert raw.xfer("03 05 00 64 FF 00 00 00") == bytes.fromhex(crc("03 05 00 64 FF 00"))
        assert line.ctl("get", addr=3, reg="relay1")["raw"] == 1
        assert raw.xfer("04 03 00 00 00 01 00 00") == b""                 # RTU, bad CRC
        assert raw.xfer(crc("04 03 00 00 00 01")) == bytes.fromhex(crc("04 03 02 00 01"))


@pytest.mark.parametrize("desc, says", [
    ('{"holding": [{"start": 0, "values": [1, 2]}, {"start": 1, "values": [3]}]}',
     "holding[1]: address 1 is already in another holding range"),
    ('{"input": [{"start": 0, "type": "real", "values": [1]}]}', "type 'real' is not one of"),
    ('{"coils": [{"start": 0, "values": [2]}]}', "a bit is 0 or 1"),
    ('{"holding": [{"start": 0, "type": "int16", "values": [40000]}]}', "does not fit int16"),
    ('{"holding": [{"start": 65535, "count": 2}]}', "past address 65535"),
    ('{"holdings": []}', "unknown key 'holdings'"),
    ('{}', "no range at all"),
    ('[1', "not JSON"),
])
def test_bad_descriptions_one_line(tmp_path, desc, says):
    path = tmp_path / "dev.json"
    path.write_text(desc)
    out = subprocess.run([simctl.VENV_PYTHON, simctl.MBSIM, "--pty", "--device",
                          f"generic:5:file={path}"], capture_output=True, text=True,
                         timeout=30, check=False)
    assert out.returncode == 2 and out.stdout == ""
    assert len(out.stderr.splitlines()) == 1 and says in out.stderr, out.stderr


def test_description_required():
    out = subprocess.run([simctl.VENV_PYTHON, simctl.MBSIM, "--pty", "--device", "generic:5"],
                         capture_output=True, text=True, timeout=30, check=False)
    assert out.returncode == 2 and "needs file=PATH" in out.stderr
    assert len(out.stderr.splitlines()) == 1
