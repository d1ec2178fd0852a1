"""The shims set the MT-S9's rates outside the termios B* table (14400, 28800, 76800) exactly
(termios2 / BOTHER) and a pty reads the rate back; the simulated MT-S9 answers at each, and not
a master at another rate. Through the shims' shared library (tools/commission/shims.py)."""
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path[:0] = [os.path.join(ROOT, "tools", "commission"), os.path.join(ROOT, "tools", "sim")]
from modsim.transport import get_speed  # noqa: E402
from shims import E_TIMEOUT, Shims  # noqa: E402
from simctl import Simulator  # noqa: E402


@pytest.fixture(scope="module")
def lib():
    with Shims.load() as shims:
        yield shims


@pytest.mark.parametrize("baud", [14400, 28800, 76800])
def test_exact_rate_on_a_pty(lib, baud):
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        bus = lib.open_bus(port, baud, "N", 8, 1, "rtu", timeout_ms=20, retries=0)
        assert bus >= 0
        rc, _ = lib.read(lib.open_device(bus, 1), 3, 0, 1)   # the worker opens the port
        assert rc == E_TIMEOUT                                 # nobody answers on this pty
        assert get_speed(slave) == baud and get_speed(master) == baud
    finally:
        lib.shutdown()
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("baud", [14400, 28800, 76800])
def test_mts9_answers_at_its_rate_only(lib, baud):
    with Simulator(["mts9:1"], baud=baud, fmt="8N1") as sim:
        dev = lib.open_device(lib.open_bus(sim.port, baud, "N", 8, 1, "rtu"), 1)
        rc, words = lib.read(dev, 3, 7, 1)                     # Baud Rate Set
        assert rc == 0 and words == [{14400: 3, 28800: 5, 76800: 8}[baud]]
        lib.shutdown()
        other = 19200
        dev = lib.open_device(lib.open_bus(sim.port, other, "N", 8, 1, "rtu", retries=0), 1)
        assert lib.read(dev, 3, 7, 1)[0] == E_TIMEOUT            # another rate: no answer
        lib.shutdown()
