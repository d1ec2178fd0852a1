"""Shared helpers of the simulator tests: independent masters (mbpoll, minimalmodbus)."""
import os
import shutil
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
# The simulator (a product, tools/sim) and these helpers.
sys.path[:0] = [HERE, os.path.join(os.path.dirname(os.path.dirname(HERE)), "tools", "sim")]

REQUIRE = os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1"


def sim_fixture(devices, scope: str = "module", **kw):
    """A pytest fixture that yields a started simulator (simctl.Simulator(devices, **kw)) and
    stops it afterwards: `sim = sim_fixture(["fdc100:3"], baud=9600, fmt="8E1")` at module level."""
    import simctl

    @pytest.fixture(scope=scope)
    def _sim():
        with simctl.Simulator(devices, **kw) as sim:
            yield sim
    return _sim


def mbpoll(port, *args, write=(), baud=9600, parity="none", stop=2, timeout=10):
    """Run mbpoll once in RTU mode (0-based references); write: values to write."""
    exe = shutil.which("mbpoll")
    if exe is None:
        if REQUIRE:
            pytest.fail("mbpoll is not installed (.ci/apt-packages.txt)")
        pytest.skip("mbpoll is not installed")
    cmd = [exe, "-m", "rtu", "-b", str(baud), "-P", parity, "-s", str(stop), "-0", "-1",
           "-o", "0.5", *map(str, args), port, *map(str, write)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


def mbpoll_values(result):
    """{reference: value} from mbpoll's '[ref]: value' lines."""
    out = {}
    for line in result.stdout.splitlines():
        line = line.strip()
        if line.startswith("[") and "]:" in line:
            ref, _, val = line[1:].partition("]:")
            out[int(ref)] = int(val.split()[0])
    return out


def instrument(port, addr, mode="rtu", baud=9600, parity="N", stop=2, timeout=0.5):
    """A minimalmodbus Instrument on the pty (closes the port after each call)."""
    import minimalmodbus
    import serial
    # minimalmodbus reuses one Serial object per port name and reopens it with the previous
    # settings. A pty keeps no parity, and refuses (EINVAL) a tcsetattr whose only change is
    # parity: so with parity, or after it, start from a fresh Serial, which minimalmodbus opens
    # at 19200 first (then the real open changes the speed too and is accepted).
    cached = getattr(minimalmodbus, "_serialports", {}).get(port)
    if parity != "N" or (cached is not None and cached.parity != serial.PARITY_NONE):
        minimalmodbus._serialports.pop(port, None)  # pylint: disable=protected-access
    inst = minimalmodbus.Instrument(port, addr, mode=mode, close_port_after_each_call=True)
    inst.serial.baudrate = baud
    inst.serial.parity = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN,
                          "O": serial.PARITY_ODD}[parity]
    inst.serial.stopbits = stop
    inst.serial.bytesize = 8
    inst.serial.timeout = timeout
    inst.clear_buffers_before_each_transaction = True
    return inst


def frames(sim):
    """(direction, hex) pairs of the frames on the line since the last call."""
    return [(f["dir"], f["hex"]) for f in sim.log(clear=True)]


def reply_length(got: bytes):
    """The length of the whole Modbus reply that `got` begins, once its first bytes tell it
    (RTU: by the function code and byte count; ASCII: up to its CR LF), else None."""
    if got[:1] == b":":
        end = got.find(b"\r\n")
        return None if end < 0 else end + 2
    if len(got) < 3:
        return None
    fc = got[1]
    if fc & 0x80:
        return 5                                    # exception: address, fc, code, CRC
    if fc in (1, 2, 3, 4):
        return 5 + got[2]                           # address, fc, byte count, data, CRC
    if fc in (5, 6, 15, 16):
        return 8                                    # the echo of address and value/count
    return None


class RawPort:
    """A bare serial master (pyserial) to put exact bytes on the line and read what comes.
    Given the simulator (`sim`, or a port string and `sim=`), a request that gets no answer
    is known as such from the simulator's frame log; without it, silence is QUIET s."""

    QUIET = 0.5          # after the simulator logged the request (or, without it, after the
                         # send) this long with no reply and no byte is silence
    GAP = 0.5            # bytes that stop short of a whole reply: cut after this pause

    def __init__(self, port, baud=9600, stop=2, sim=None):
        import serial
        if hasattr(port, "port"):
            port, sim = port.port, port
        self.sim = sim
        # The simulator hears only a master whose port matches the device's line (a pty
        # shows it the baud; stop bits need not match): 8N2 by default, as the default line.
        self.ser = serial.Serial(port, baud, stopbits=stop, timeout=0)

    def _send(self, data):
        if isinstance(data, str):
            data = bytes.fromhex(data)
        self.ser.reset_input_buffer()
        self.ser.write(data)
        self.ser.flush()

    def xfer(self, data, wait=None, timeout=10.0, by_log=True):
        """Send bytes (or a hex string); return the answer. `wait`: a master with that
        timeout, everything received within `wait` s (for the tests of late replies).
        Otherwise it waits on what it knows, within `timeout` s however long a loaded machine
        holds either side back: with the simulator, the reply it logs (read to its length,
        noise and cuts included) or, once it logged the request, none for QUIET s (silence);
        without, a whole reply (reply_length), or what came once the line paused GAP s,
        or QUIET s with nothing. by_log=False: not the log (the test holds the simulator's
        control socket meanwhile), as without a simulator."""
        import time
        sim = self.sim if by_log and wait is None else None
        n0 = len(sim.log(clear=False)) if sim is not None else 0
        self._send(data)
        now = time.monotonic()
        got, start, last, heard, need, nrx = b"", now, now, None, None, 0
        while now - start < timeout:
            chunk = self.ser.read(512)
            now = time.monotonic()
            if chunk:
                got, last = got + chunk, now
            if wait is not None:
                if now - start >= wait:
                    break
            elif sim is not None:
                if need is None:
                    dirs = [(f["dir"], f["hex"]) for f in sim.log(clear=False)[n0:]]
                    tx = [bytes.fromhex(h) for d, h in dirs if d == "tx"]
                    rx = sum(d == "rx" for d, _ in dirs)
                    if tx:
                        need = len(tx[-1])
                    elif rx > nrx:          # silence counts from the last receiver's entry:
                        heard, nrx = now, rx   # on a line of several framings each logs it
                if need is not None and len(got) >= need:
                    break
                if need is None and heard is not None and now - heard > self.QUIET:
                    break
            elif got:
                need = reply_length(got)
                if (need is not None and len(got) >= need) or now - last > self.GAP:
                    break
            elif now - start > self.QUIET:
                break
            time.sleep(0.005)
        return got

    def ask(self, sim, data, timeout=10.0):
        """Send a request to the simulator `sim` and read its answer, waiting on the
        simulator's frame log instead of a fixed time: it logs each reply as it writes it
        (a dropped one as an empty frame), and this reads exactly those bytes from the port,
        however long a loaded machine holds either side back (a fixed wait took a reply that
        came late for a missing one). Clears the simulator's log."""
        import time
        sim.log()                           # clear: the answer is the next "tx" entry
        self._send(data)
        end, tx = time.monotonic() + timeout, []
        while not tx and time.monotonic() < end:
            tx = [f["hex"] for f in sim.log() if f["dir"] == "tx"]
            time.sleep(0.002)
        assert len(tx) == 1, f"the simulator logged {len(tx)} answers to one request: {tx}"
        sent, got = bytes.fromhex(tx[0]), b""
        while len(got) < len(sent) and time.monotonic() < end:
            got += self.ser.read(512)
            time.sleep(0.002)
        return got

    def close(self):
        self.ser.close()


@pytest.fixture
def raw_factory():
    """raw_factory(port or simulator) -> RawPort; closed after the test."""
    ports = []

    def make(port, baud=9600, stop=2, sim=None):
        ports.append(RawPort(port, baud, stop, sim))
        return ports[-1]
    yield make
    for p in ports:
        p.close()


def pymodbus_writes(sim, client):
    """What a pymodbus client writes through the simulator of test_tcp and test_rtutcp (an
    MV-D94 at 1, an FDC-100 at 3, an MT-S9 at 5), checked on the devices: the MV-D94's SV
    (FC06), four FDC words read, the MT-S9's REAL (FC16, low word first)."""
    assert not client.write_register(0, 1234, slave=1).isError()
    assert sim.ctl("get", addr=1, reg="SV")["raw"] == 1234
    rr = client.read_holding_registers(128, count=4, slave=3)
    assert not rr.isError() and len(rr.registers) == 4
    assert not client.write_registers(0, [0x000A, 0x0102], slave=5).isError()
    assert sim.ctl("get", addr=5, reg="REAL")["raw"] == 16908298


def crc(frame_hex):
    """Frame hex + its CRC-16/MODBUS (low byte first), computed independently of pymodbus."""
    data = bytes.fromhex(frame_hex)
    c = 0xFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return (data + bytes([c & 0xFF, c >> 8])).hex(" ").upper()
