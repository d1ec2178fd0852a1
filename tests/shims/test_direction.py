"""RS-485 direction control through the test double (tests/shims/linedouble.c, LD_PRELOAD):
for RTU, ASCII and RTU without CRC, against the paced simulator, the shims switch RTS or a
GPIO line around every request (up before its first byte by the set delay, down after its last
byte has left and before the device's reply starts), or put the port into the kernel's RS-485
mode once; a port or library that refuses the mode gives MBFB_E_DIRECTION (15) and no byte.
GPIO through each libgpiod API: the double is built for libgpiod 1 (soname libgpiod.so.2) and
for libgpiod 2 (libgpiod.so.3), and the log names the API the shims used.

The master runs in a child process under the double, through the shims' shared library
(tools/commission/shims.py); the double records with the shims' clock (CLOCK_MONOTONIC)."""
import json
import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [HERE, os.path.join(ROOT, "tools", "commission"), os.path.join(ROOT, "tools", "sim")]
import line_edges  # noqa: E402
from shims import E_DIRECTION, E_INVAL  # noqa: E402
from simctl import Simulator  # noqa: E402

DOUBLE = os.environ.get("MBFB_LINEDOUBLE", "")      # libgpiod 1's API (libgpiod.so.2)
DOUBLE2 = os.environ.get("MBFB_LINEDOUBLE2", "")    # libgpiod 2's API (libgpiod.so.3)
DOUBLES = {1: DOUBLE, 2: DOUBLE2}
CHIP = "gpiochip-double"
BAUD = 9600

# one device per framing, with a register to read and one to write (value, read back)
LINES = {
    "rtu": dict(device="mvd94:1:SV=100.0,DP=1", fmt="8N2", stop=2, read=(4, 4096, 1), write=(0, 1234)),
    "ascii": dict(device="mts9:1:framing=ascii", fmt="8N1", stop=1, read=(3, 7, 1), write=None),
    "nocrc": dict(device="mts9:1:framing=nocrc", fmt="8N1", stop=1, read=(3, 7, 1), write=None),
}

MASTER = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from shims import Shims
a = json.loads(sys.argv[2])
with Shims.load() as lib:
    bus = lib.open_bus(a["port"], a["baud"], "N", 8, a["stop"], a["framing"],
                       direction=a["mode"], active_low=a["active_low"], before_us=a["before"],
                       after_us=a["after"], gpio_chip=a["chip"], gpio_line=a["line"])
    out = {"bus": bus, "reads": [], "write": None}
    if bus >= 0:
        dev = lib.open_device(bus, 1)
        for _ in range(a["n"]):
            out["reads"].append(lib.read(dev, *a["read"]))
        if a["write"]:
            out["write"] = lib.write(dev, *a["write"])
    print(json.dumps(out))
"""

pytestmark = pytest.mark.skipif(not (os.path.isfile(DOUBLE) and os.path.isfile(DOUBLE2)),
                                reason="MBFB_LINEDOUBLE / MBFB_LINEDOUBLE2 (the test double's "
                                       "libraries) not built")


def run_master(tmp_path, port, framing, mode, chip=CHIP, refuse=None, active_low=False,
               before=0, after=0, n=4, double=True, api=1, offset=17, double_chip=CHIP,
               preload=None):
    """The master in a child process (under the test double for libgpiod `api`, or what
    `preload` names, unless double=False): its results and the double's log."""
    line = LINES[framing]
    log = tmp_path / f"{framing}-{mode}-v{api}.log"
    env = dict(os.environ)
    if double:
        env.update(LD_PRELOAD=preload or DOUBLES[api], LINEDOUBLE_PORT=port, LINEDOUBLE_LOG=str(log),
                   LINEDOUBLE_GPIOCHIP=double_chip)
    if refuse:
        env["LINEDOUBLE_REFUSE"] = refuse
    arg = dict(port=port, baud=BAUD, stop=line["stop"], framing=framing, mode=mode,
               active_low=active_low, before=before, after=after, chip=chip, line=offset,
               read=line["read"], write=line["write"], n=n)
    proc = subprocess.run([sys.executable, "-c", MASTER, os.path.join(ROOT, "tools", "commission"),
                           json.dumps(arg)], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    text = log.read_text() if log.exists() else ""
    return json.loads(proc.stdout), text


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


@pytest.mark.parametrize("chip,double_chip", [
    ("gpiochip-double", "gpiochip-double"),      # a name under /dev
    ("/dev/gpiochip-double", "gpiochip-double"),  # a path
    ("7", "gpiochip7")])                          # a number: /dev/gpiochip7
def test_gpio_chip_named_each_way_v2(tmp_path, chip, double_chip):
    """libgpiod 1 finds a chip with its own gpiod_chip_open_lookup; libgpiod 2 opens paths
    only, so the shims resolve the name, path or number (or a label, by the labels of the
    chips under /dev) to the path libgpiod 2 is given."""
    api = 2
    with Simulator([LINES["rtu"]["device"]], fmt="8N2", baud=BAUD) as sim:
        out, log = run_master(tmp_path, sim.port, "rtu", "gpio", chip=chip, n=1, api=api,
                              double_chip=double_chip)
    assert [rc for rc, _ in out["reads"]] == [0], out
    assert f"gpioreq mbfb 17 0 v{api}" in log and "misuse" not in log, log


@pytest.mark.parametrize("api", [1, 2])
def test_gpio_line_missing_sends_nothing(tmp_path, api):
    with Simulator([LINES["rtu"]["device"]], fmt="8N2", baud=BAUD) as sim:
        out, log = run_master(tmp_path, sim.port, "rtu", "gpio", n=2, api=api, offset=40)
        frames = sim.log()
    assert [rc for rc, _ in out["reads"]] == [E_DIRECTION] * 2
    assert "write" not in log.split() and "gpioreq" not in log and frames == []


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


REAL_LIBGPIOD = {1: os.environ.get("MBFB_LIBGPIOD1", ""), 2: os.environ.get("MBFB_LIBGPIOD2", "")}
CDEV_DOUBLE = os.environ.get("MBFB_GPIOCDEV_DOUBLE", "")
CDEV_CHIP = "gpiochip5"


def real_libgpiod(api):
    """LD_PRELOAD for the real libgpiod `api` over the kernel's GPIO device double
    (gpiocdev_double.c); skips (fails under MBFB_REQUIRE_TOOLCHAIN=1) without them."""
    why = None
    if not os.path.isfile(CDEV_DOUBLE):
        why = "the GPIO character-device double (MBFB_GPIOCDEV_DOUBLE) is not built"
    elif not os.path.isfile(REAL_LIBGPIOD[api]):
        why = {1: "Debian's libgpiod 1 (libgpiod.so.2, package libgpiod2) is not installed",
               2: "libgpiod 2 was not built: " + os.environ.get("MBFB_LIBGPIOD2_REASON", "?")}[api]
    if why:
        if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
            pytest.fail(why + " (MBFB_REQUIRE_TOOLCHAIN=1)")
        pytest.skip(why)
    return f"{CDEV_DOUBLE}:{REAL_LIBGPIOD[api]}"


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


@pytest.mark.parametrize("api", [1, 2])
@pytest.mark.parametrize("chip,answers", [
    ("gpiochip5", True), ("/dev/gpiochip5", True), ("5", True), ("linedouble", True),
    ("gpiochip6", False), ("6", False), ("pinctrl-none", False)])
def test_real_libgpiod_finds_the_chip(tmp_path, api, chip, answers):
    """A chip named by name, path, number or label (the double's chip is labelled
    "linedouble") through the real libraries; another chip is refused (15), nothing sent."""
    preload = real_libgpiod(api)
    with Simulator([LINES["rtu"]["device"]], fmt="8N2", baud=BAUD) as sim:
        out, log = run_master(tmp_path, sim.port, "rtu", "gpio", chip=chip, api=api, n=1,
                              double_chip=CDEV_CHIP, preload=preload)
        frames = sim.log()
    if answers:
        assert [rc for rc, _ in out["reads"]] == [0], (out, log)
        assert f"gpioreq mbfb 17 0 uapi-v{api}" in log
    else:
        assert [rc for rc, _ in out["reads"]] == [E_DIRECTION], (out, log)
        assert "write" not in log.split() and "gpioreq" not in log and frames == []
    assert "misuse" not in log, log


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
