"""RS-485 direction control through the test double (tests/shims/linedouble.c, LD_PRELOAD):
for RTU, ASCII and RTU without CRC, against the paced simulator, the shims switch RTS or a
GPIO line around every request (up before its first byte by the set delay, down after its last
byte has left and before the device's reply starts), or put the port into the kernel's RS-485
mode once; a port or library that refuses the mode gives MBFB_E_DIRECTION (15) and no byte.
GPIO through each libgpiod API: the double is built for libgpiod 1 (soname libgpiod.so.2) and
for libgpiod 2 (libgpiod.so.3), and the log names the API the shims used.

The master runs in a child process under the double, through the shims' shared library
(tools/commission/shims.py); the double records with the shims' clock (CLOCK_MONOTONIC)."""
import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [HERE, os.path.join(ROOT, "tools", "commission"), os.path.join(ROOT, "tools", "sim")]
import line_edges  # noqa: E402
from direction_master import (BAUD, CHIP, CDEV_CHIP, LINES, doubles_built,  # noqa: E402
                              real_libgpiod, run_master)
from shims import E_DIRECTION, E_INVAL  # noqa: E402
from simctl import Simulator  # noqa: E402

pytestmark = pytest.mark.skipif(not doubles_built(),
                                reason="MBFB_LINEDOUBLE / MBFB_LINEDOUBLE2 (the test double's "
                                       "libraries) not built")


@pytest.mark.parametrize("framing", ["rtu", "ascii", "nocrc"])
@pytest.mark.parametrize("mode,active_low,before,after,api", [
    ("rts", False, 0, 0, 1), ("rts", True, 500, 200, 1),
    ("gpio", False, 300, 0, 1), ("gpio", True, 0, 0, 1),
    ("gpio", False, 300, 0, 2), ("gpio", True, 0, 0, 2),
    ("kernel", False, 1500, 0, 1)])
def test_edges_frame_every_request(tmp_path, framing, mode, active_low, before, after, api):
    line = LINES[framing]
    with Simulator([line["device"]], fmt=line["fmt"], baud=BAUD, pace=True) as sim:
        out, log = run_master(tmp_path, sim.port, framing, mode, active_low=active_low,
                              before=before, after=after, api=api)
    assert out["bus"] >= 0
    assert [rc for rc, _ in out["reads"]] == [0] * 4, out     # every read answered
    if line["write"]:
        assert out["write"] == 0                               # the write confirmed
    char_us = 1e6 * (1 + 8 + line["stop"]) / BAUD
    got = line_edges.check(log, mode, char_us, before, after, active_low)
    assert got["requests"] >= 4
    assert "misuse" not in log, log                            # the API used by its rules
    if mode == "gpio":                                         # one request, through the API asked
        reqs = [ln.split()[2:] for ln in log.splitlines() if ln.split()[1] == "gpioreq"]
        assert reqs == [["mbfb", "17", str(int(active_low)), f"v{api}"]], reqs


@pytest.mark.parametrize("framing", ["rtu", "ascii", "nocrc"])
@pytest.mark.parametrize("mode,chip,refuse,api", [
    ("rts", CHIP, "rts", 1),            # a port without modem lines
    ("kernel", CHIP, "rs485", 1),       # a driver without RS-485 mode
    ("kernel", CHIP, "polarity", 1),    # one that drops the polarity asked for
    ("gpio", "gpiochip-none", None, 1),  # no such GPIO chip
    ("gpio", "gpiochip-none", None, 2)])
def test_refused_mode_sends_nothing(tmp_path, framing, mode, chip, refuse, api):
    line = LINES[framing]
    with Simulator([line["device"]], fmt=line["fmt"], baud=BAUD) as sim:
        out, log = run_master(tmp_path, sim.port, framing, mode, chip=chip, refuse=refuse, n=2,
                              api=api)
        frames = sim.log()
    assert out["bus"] >= 0
    assert [rc for rc, _ in out["reads"]] == [E_DIRECTION] * 2
    assert "write" not in log.split()                          # no byte on the wire
    assert frames == []                                        # and the device heard nothing


@pytest.mark.parametrize("api", [1, 2])
@pytest.mark.parametrize("active_low,before", [(False, 300), (True, 0)])
def test_real_libgpiod_edges(tmp_path, api, active_low, before):
    """The real libgpiod 1 (Debian 12's) and 2 (2.2.1, built from source) between the shims
    and the kernel's uAPI (v1 and v2, as each speaks it), through the double of the GPIO
    character device: the line requested once as an output at idle by "mbfb", then up and
    down around every request as with the library doubles."""
    preload = real_libgpiod(api)
    line = LINES["rtu"]
    with Simulator([line["device"]], fmt=line["fmt"], baud=BAUD, pace=True) as sim:
        out, log = run_master(tmp_path, sim.port, "rtu", "gpio", chip=CDEV_CHIP, api=api,
                              active_low=active_low, before=before, double_chip=CDEV_CHIP,
                              preload=preload)
    assert [rc for rc, _ in out["reads"]] == [0] * 4, (out, log)
    assert out["write"] == 0
    got = line_edges.check(log, "gpio", 1e6 * 11 / BAUD, before, 0, active_low)
    assert got["requests"] >= 4 and "misuse" not in log, log
    reqs = [ln.split()[2:] for ln in log.splitlines() if ln.split()[1] == "gpioreq"]
    assert reqs == [["mbfb", "17", str(int(active_low)), f"uapi-v{api}"]], log


def test_real_pty_refuses_rts_and_kernel_mode(tmp_path):
    """Without the double: a pty has neither modem lines nor RS-485 mode, and a GPIO chip
    that does not exist is refused by the real libgpiod (or its absence)."""
    with Simulator([LINES["rtu"]["device"]]) as sim:
        for mode in ("rts", "kernel", "gpio"):
            out, _ = run_master(tmp_path, sim.port, "rtu", mode, chip="gpiochip-none", n=1,
                                double=False)
            assert out["reads"][0][0] == E_DIRECTION, mode
        frames = sim.log()
    assert frames == []


@pytest.mark.parametrize("kw", [
    dict(direction="rts", before_us=100001), dict(direction="gpio", gpio_chip=""),
    dict(direction="gpio", gpio_chip=CHIP, gpio_line=-1), dict(direction="rts", after_us=-1)])
def test_bad_direction_settings_open_nothing(kw):
    from shims import Shims
    with Shims.load() as lib:
        assert lib.open_bus("/dev/null-mbfb-none", BAUD, "N", 8, 2, "rtu", **kw) == -E_INVAL


def test_direction_on_tcp_is_refused():
    from shims import Shims
    with Shims.load() as lib:
        assert lib.open_bus("tcp://127.0.0.1:1", BAUD, "N", 8, 1, "rtu",
                            direction="rts") == -E_INVAL
