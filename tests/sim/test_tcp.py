"""Modbus/TCP transport on 127.0.0.1 with pymodbus's client and mbpoll -m tcp."""
import shutil
import socket
import subprocess
import time

import pytest
from pymodbus.client import ModbusTcpClient

from conftest import REQUIRE, mbpoll_values, pymodbus_writes, sim_fixture

sim = sim_fixture(["mvd94:1:SV=1000", "fdc100:3", "mts9:5"], transport="tcp")


@pytest.fixture
def client(sim):
    host, port = sim.tcp
    c = ModbusTcpClient(host, port=port, timeout=0.5, retries=0)
    assert c.connect()
    yield c
    c.close()


def test_ready_line_and_loopback_only(sim):
    host, port = sim.tcp
    assert host == "127.0.0.1" and port > 0 and sim.ready_line == f"TCP 127.0.0.1:{port}"


def test_pymodbus_reads_and_writes(sim, client):
    rr = client.read_holding_registers(0, count=1, slave=1)
    assert not rr.isError() and rr.registers == [1000]
    rr = client.read_input_registers(0x1000, count=1, slave=1)
    assert not rr.isError() and -100 < rr.registers[0] < 2000
    pymodbus_writes(sim, client)
    rr = client.write_registers(0, [1, 2], slave=1)          # no FC16 on the MV-D94
    assert rr.isError() and rr.exception_code == 1


def test_mbap_bytes_on_the_line(sim):
    host, port = sim.tcp
    sim.log(clear=True)
    with socket.create_connection((host, port), timeout=1) as s:
        s.sendall(bytes.fromhex("12 34 00 00 00 06 01 03 00 00 00 01"))
        got = s.recv(64)
    assert got.hex(" ").upper() == "12 34 00 00 00 05 01 03 02 04 D2"
    assert [f["dir"] for f in sim.log()] == ["rx", "tx"]


def test_unknown_unit_is_silent(sim, client):
    from pymodbus.exceptions import ModbusIOException
    with pytest.raises(ModbusIOException, match="No response"):
        client.read_holding_registers(0, count=1, slave=9)
    assert sim.ctl("stats")["line"]["foreign"] >= 1


def test_faults_on_tcp(sim, client):
    sim.ctl("fault", addr=1, kind="exception", code=4)
    rr = client.read_holding_registers(0, count=1, slave=1)
    assert rr.isError() and rr.exception_code == 4
    assert not sim.control({"op": "fault", "addr": 1, "kind": "bad_crc"})["ok"]
    host, port = sim.tcp
    sim.ctl("fault", addr=1, kind="late", delay_ms=500)
    with socket.create_connection((host, port), timeout=2) as s:
        t0 = time.monotonic()
        s.sendall(bytes.fromhex("00 01 00 00 00 06 01 03 00 00 00 01"))
        assert s.recv(64)[:2] == b"\x00\x01"
        assert time.monotonic() - t0 >= 0.5


def test_mbpoll_tcp(sim):
    exe = shutil.which("mbpoll")
    if exe is None:
        if REQUIRE:
            pytest.fail("mbpoll missing")
        pytest.skip("mbpoll missing")
    host, port = sim.tcp
    sim.ctl("set", addr=1, reg="SV", raw=777)
    res = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-0", "-r", "0", "-c", "1",
                          "-1", "-o", "1", host], capture_output=True, text=True, timeout=10)
    assert mbpoll_values(res) == {0: 777}, res.stdout + res.stderr


def test_reopen_port_tcp(sim):
    host, port = sim.tcp
    reply = sim.ctl("reopen_port", down_ms=200)
    assert reply["port"] == f"{host}:{port}"
    c = ModbusTcpClient(host, port=port, timeout=0.5, retries=0)
    assert c.connect()
    assert not c.read_holding_registers(0, count=1, slave=1).isError()
    c.close()
