"""The master of the direction tests (test_direction.py, test_gpio_lookup.py): one bus with a
direction mode in a child process under a test double (tests/shims/linedouble.c, LD_PRELOAD),
through the shims' shared library (tools/commission/shims.py); its results and the double's log.
"""
import json
import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

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


REAL_LIBGPIOD = {1: os.environ.get("MBFB_LIBGPIOD1", ""), 2: os.environ.get("MBFB_LIBGPIOD2", "")}
CDEV_DOUBLE = os.environ.get("MBFB_GPIOCDEV_DOUBLE", "")
CDEV_CHIP = "gpiochip5"


def doubles_built():
    """Whether both builds of the library double are there (else the tests skip)."""
    return os.path.isfile(DOUBLE) and os.path.isfile(DOUBLE2)


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
