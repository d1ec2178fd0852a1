"""RTU over TCP on 127.0.0.1 (--rtu-tcp): the simulator as a transparent Ethernet-to-RS-485
gateway. pymodbus's TCP client with its RTU framer (a master we did not write) reads and writes;
raw sockets check the framing of a stream (requests split and joined, garbage, bad CRC), late
replies forwarded on the stream to every open connection, and reopen_port dropping connections."""
import socket
import time

from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from conftest import pymodbus_writes, sim_fixture
from modsim import frames

sim = sim_fixture(["mvd94:1:SV=1000", "fdc100:3", "mts9:5"], transport="rtu-tcp")


def rtu(hexstr: str) -> bytes:
    body = bytes.fromhex(hexstr)
    return body + frames.crc_bytes(body)


def connect(sim):
    s = socket.create_connection(sim.tcp, timeout=2)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def recv_for(s, seconds: float) -> bytes:
    """Everything the socket delivers within `seconds`."""
    out, end = b"", time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        s.settimeout(left)
        try:
            chunk = s.recv(512)
        except socket.timeout:
            break
        if not chunk:
            break
        out += chunk
    return out


def test_ready_line(sim):
    host, port = sim.tcp
    assert host == "127.0.0.1" and port > 0 and sim.ready_line == f"RTU-TCP 127.0.0.1:{port}"


def test_pymodbus_rtu_framer_reads_and_writes(sim):
    c = ModbusTcpClient(sim.tcp[0], port=sim.tcp[1], framer=FramerType.RTU, timeout=1,
                        retries=0)
    assert c.connect()
    try:
        sim.ctl("set", addr=1, reg="SV", raw=1000)
        rr = c.read_holding_registers(0, count=1, slave=1)
        assert not rr.isError() and rr.registers == [1000]
        pymodbus_writes(sim, c)
    finally:
        c.close()


def test_requests_split_joined_garbage_and_bad_crc(sim):
    sim.ctl("set", addr=1, reg="SV", raw=1000)
    req = rtu("010300000001")
    reply = rtu("01030203E8")
    with connect(sim) as s:
        s.sendall(req[:3])                   # one request in two pieces
        time.sleep(0.1)
        s.sendall(req[3:])
        assert recv_for(s, 0.5) == reply
        s.sendall(req + req)                 # two requests in one piece: two replies
        assert recv_for(s, 0.5) == reply + reply
        s.sendall(req[:-1] + bytes([req[-1] ^ 0xFF]))   # bad CRC: silence
        assert recv_for(s, 0.5) == b""
        s.sendall(bytes.fromhex("01 63 00 00"))          # no request starts so: dropped
        assert recv_for(s, 0.3) == b""
        s.sendall(req[:5])                   # a partial request, then silence: dropped
        assert recv_for(s, 0.8) == b""
        s.sendall(req)                       # the line is clean again
        assert recv_for(s, 0.5) == reply
    infos = [f.get("info") for f in sim.log() if f["dir"] == "rx"]
    assert infos.count("bad CRC") == 1 and infos.count("garbage") == 2


def test_a_late_reply_reaches_every_open_connection(sim):
    """A gateway forwards what its line carries: the late reply comes after the master gave
    up, also to a master that connected again meanwhile; the device ignores requests until
    it is out."""
    sim.ctl("set", addr=1, reg="SV", raw=1000)
    sim.ctl("fault", addr=1, kind="late", count=1, delay_ms=600)
    req = rtu("010300000001")
    with connect(sim) as old, connect(sim) as new:
        old.sendall(req)
        assert recv_for(old, 0.3) == b""     # the master's timeout: nothing yet
        new.sendall(req)                     # ignored: the device is busy
        assert recv_for(new, 0.8) == rtu("01030203E8")   # the late reply, on the new one
        assert recv_for(old, 0.1) == rtu("01030203E8")   # and on the old one
        new.sendall(req)
        assert recv_for(new, 0.5) == rtu("01030203E8")
    assert sim.ctl("stats")["devices"]["1"]["busy_ignored"] == 1


def test_reopen_port_drops_the_connections(sim):
    with connect(sim) as s:
        s.sendall(rtu("010300000001"))       # served: the gateway holds the connection
        assert len(recv_for(s, 0.5)) == 7
        sim.ctl("reopen_port", down_ms=200)
        s.settimeout(2)
        assert s.recv(16) == b""             # closed by the gateway
    with connect(sim) as s:                  # the reply to reopen_port: back on the same port
        s.sendall(rtu("010300000001"))
        assert len(recv_for(s, 0.5)) == 7
