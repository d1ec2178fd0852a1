"""GPIO direction control: finding the chip and the line, through the library doubles
(tests/shims/linedouble.c) and through the real libgpiod 1 and 2 over the double of the kernel's
GPIO device (gpiocdev_double.c). An unpaced line and no timing checks: these run beside other
tests (the edges' timing is test_direction.py's)."""
import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [HERE, os.path.join(ROOT, "tools", "commission"), os.path.join(ROOT, "tools", "sim")]
from direction_master import (BAUD, CDEV_CHIP, LINES, doubles_built, real_libgpiod,  # noqa: E402
                              run_master)
from shims import E_DIRECTION  # noqa: E402
from simctl import Simulator  # noqa: E402

pytestmark = pytest.mark.skipif(not doubles_built(),
                                reason="MBFB_LINEDOUBLE / MBFB_LINEDOUBLE2 (the test double's "
                                       "libraries) not built")


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
