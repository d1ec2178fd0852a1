"""The simulator enforces the line like a UART: a master whose baud differs from the device's, or
a device moved to another parity, gets nothing valid; other stop bits do not matter (a UART
checks only the first stop bit, so 8N1 talks to 8N2). On the simulator's own pty and through
ptyline. Masters we did not write: minimalmodbus (pyserial) and pymodbus.

On a Linux pty a master's parity and data bits are invisible (the kernel drops PARENB and CS7),
so a master's parity cannot be checked there: the parity checks below move the device instead.
A pty also refuses (EINVAL) a tcsetattr whose only change is PARENB, so pyserial cannot open it
at 8E1 right after a master at 8N1 on the same pty (and pymodbus, which sets the port twice, never
can): the 8E1 master here is minimalmodbus, opened with a fresh port object.
"""
import minimalmodbus
import pytest

from conftest import instrument
from test_cli import os_ptyline
import simctl

NO_REPLY = (minimalmodbus.NoResponseError, minimalmodbus.InvalidResponseError)
# A reply is awaited up to ANSWER_S (a read that is answered returns as soon as it is, so a
# loaded machine that holds the simulator back costs no failure); where none may come, the
# master listens SILENCE_S.
ANSWER_S, SILENCE_S = 3.0, 0.3


def read_sv(port, timeout=ANSWER_S, **line):
    return instrument(port, 1, timeout=timeout, **line).read_register(0)


def pymodbus_read(port, parity, stopbits, baud=9600):
    """One FC03 read of register 0 at slave 1 with pymodbus; the value, or None if no valid reply."""
    from pymodbus.client import ModbusSerialClient
    client = ModbusSerialClient(port=port, baudrate=baud, parity=parity, stopbits=stopbits,
                                bytesize=8, timeout=ANSWER_S, retries=0)
    try:
        assert client.connect()
        try:
            rr = client.read_holding_registers(0, count=1, slave=1)
        except Exception:  # pylint: disable=broad-except  (pymodbus raises on no reply)
            return None
        return None if rr.isError() else rr.registers[0]
    finally:
        client.close()


def test_other_stop_bits_are_heard_and_another_baud_is_not():
    with simctl.Simulator(["mvd94:1:SV=1000"]) as sim:        # the MV-D94: 9600 8N2 only
        assert read_sv(sim.port, stop=1) == 1000              # 8N1 master, 8N2 device
        assert read_sv(sim.port, stop=2) == 1000
        assert pymodbus_read(sim.port, "N", 1) == 1000
        with pytest.raises(NO_REPLY):
            read_sv(sim.port, SILENCE_S, baud=19200, stop=1)
        dev = sim.ctl("stats")["devices"]["1"]
        assert dev["line_mismatch"] == 1 and dev["replies"] == 3
        log = sim.log()
        infos = [f.get("info") for f in log if f["dir"] == "rx"]
        assert infos.count("line settings differ: heard as garbage") == 1
        assert [f["hex"] for f in log if f["dir"] == "tx"] == ["01 03 02 03 E8 B8 FA"] * 3


def test_a_master_at_another_baud_gets_nothing():
    with simctl.Simulator(["mvd94:1:SV=1000"]) as sim:
        with pytest.raises(NO_REPLY):
            read_sv(sim.port, SILENCE_S, baud=19200)
        assert read_sv(sim.port) == 1000


def test_a_device_moved_to_another_baud_answers_there_only():
    """A master writes the MV-D94's BAUD (19.2K, code 0x1F): the unit answers at 19200 only."""
    with simctl.Simulator(["mvd94:1:SV=1000"]) as sim:
        instrument(sim.port, 1).write_register(0x1C, 0x1F, functioncode=6)
        with pytest.raises(NO_REPLY):
            read_sv(sim.port, SILENCE_S)
        assert read_sv(sim.port, baud=19200) == 1000


def test_fdc_at_its_factory_8e1():
    """An FDC at 9600 8E1: a master at 8E1 is heard; a master at 4800 is not."""
    with simctl.Simulator(["fdc100:1"], fmt="8E1") as sim:
        assert instrument(sim.port, 1, parity="E", stop=1, timeout=ANSWER_S).read_register(39) == 1
        with pytest.raises(NO_REPLY):
            instrument(sim.port, 1, baud=4800, parity="E", stop=1,
                       timeout=SILENCE_S).read_register(39)
        assert sim.ctl("stats")["devices"]["1"]["line_mismatch"] == 1


def test_a_device_moved_to_another_parity_hears_garbage():
    """An FDC on a 9600 8N1 line set to even parity (PARI 0) hears the line's frames as parity
    errors and stays silent; set back to none (PARI 2) it answers. Its STOP moved to 2 stop
    bits does not matter."""
    with simctl.Simulator(["fdc100:1"], fmt="8N1") as sim:
        assert read_fdc(sim.port) == 1
        sim.ctl("set", addr=1, reg="STOP", raw=1)            # 2 stop bits: still heard
        assert read_fdc(sim.port) == 1
        sim.ctl("set", addr=1, reg="PARI", raw=0)            # even parity: garbage
        with pytest.raises(NO_REPLY):
            read_fdc(sim.port, SILENCE_S)
        sim.ctl("set", addr=1, reg="PARI", raw=2)
        assert read_fdc(sim.port) == 1
        assert sim.ctl("stats")["devices"]["1"]["line_mismatch"] == 1


def read_fdc(port, timeout=ANSWER_S):
    return instrument(port, 1, parity="N", stop=1, timeout=timeout).read_register(39)


def test_through_ptyline_a_wrong_line_is_garbled():
    binary = os_ptyline()
    with simctl.Simulator(["mvd94:1:SV=1000"], pace=True, extra=["--ptyline", binary]) as sim:
        with pytest.raises(NO_REPLY):
            read_sv(sim.port, SILENCE_S, baud=19200)
        stats = sim.ctl("line_stats")["stats"]
        assert stats["m2s"]["format_errors"] == 8          # the whole request, as NUL bytes
        assert stats["s2m"]["bytes"] == 0
        assert read_sv(sim.port, stop=1) == 1000          # other stop bits: heard
        assert pymodbus_read(sim.port, "N", 2) == 1000
        line = sim.ctl("stats")["line"]
        # the garbled request, heard as garbage: its 8 NUL bytes and nothing else. The count of
        # bad frames is not asserted: a line paced on ptys that the scheduler stalls for more
        # than t3.5 (4 ms) between two NULs cuts it in two, as that silence would on a wire.
        garbage = [f["hex"].split() for f in sim.log() if f["dir"] == "rx" and f.get("info")]
        assert sum(garbage, []) == ["00"] * 8, garbage
        assert line["rx_frames"] == 2 and line["bad_frames"] == len(garbage)
        stats = sim.ctl("line_stats")["stats"]
        assert stats["m2s"]["format_errors"] == 8 and stats["s2m"]["frames"] == 2


@pytest.mark.parametrize("devices,fmt,baud,why", [
    (["mvd94:1"], "8O2", 9600, "speaks 8N2"),
    (["vd:1"], "8E1", 9600, "speaks 8N2"),
    (["mvd94:1"], "8N2", 38400, "cannot run at 38400"),
    (["fdc100:1"], "8N2", 57600, "cannot run at 57600"),
])
def test_a_device_on_a_line_it_cannot_speak_is_refused(devices, fmt, baud, why):
    with pytest.raises(simctl.SimulatorError) as err:
        simctl.Simulator(devices, fmt=fmt, baud=baud).start()
    assert why in str(err.value)
