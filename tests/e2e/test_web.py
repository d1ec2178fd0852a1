"""The way OpenPLC v3's users load a program: its own web page (oplcweb.WebServer: the real
webserver.py of a scratch copy, in the private network namespace), driven over HTTP as the
browser drives it: login with the CSRF token, Upload Program, the program info form, the compile
page and its log, Start PLC. Then the simulator's instruments are read through the runtime's
Modbus TCP server (pymodbus), as in test_runtime.py. One webserver per route:
  install  plc_lib/install.sh into the copy, then the ST example;
  bundle   a pristine copy, the ST example as plc_lib/mkbundle.sh's single file;
  ladder   plc_lib/install.sh, then the ST the OpenPLC Editor made of the ladder example.
A compile error on the page fails the test with the page's compile log; test_page_refuses_*
shows that the routes fail, with that log, when the bundle's FILE lines are broken and when the
library is not installed."""
import contextlib
import os
import subprocess
import sys
import time

import pytest

import oplc
import oplcweb
from oplc import s16, wait
from test_runtime import BEAT, C_PARTSVALID, C_Z1VALID, C_Z2VALID, COUNT, Z1ERR, Z1SV, Z2ERR, Z2SV

sys.path.insert(0, os.path.join(oplc.ROOT, "tools", "sim"))
from simctl import Simulator  # noqa: E402

ST = os.path.join(oplc.ROOT, "examples", "heat_treat_st", "heat_treat_st.st")
LD = os.path.join(oplc.ROOT, "examples", "heat_treat_ld", "heat_treat_ld.st")
MKBUNDLE = os.path.join(oplc.ROOT, "plc_lib", "mkbundle.sh")
ROUTES = {"install": (ST, True, False), "bundle": (ST, False, True), "ladder": (LD, True, False)}


@pytest.fixture
def scratch():
    # run.sh skips the module (exit 77, ctest: skipped) before this when it is missing
    assert oplcweb.python(oplc.openplc_home()), "OpenPLC's webserver Python (.venv of its install.sh) not found"
    with oplc.Scratch() as s:
        yield s


def bundle(program, dist, out):
    """plc_lib/mkbundle.sh program > out."""
    with open(out, "w") as f:
        subprocess.run([MKBUNDLE, "--dist", dist, program], stdout=f, check=True)
    return out


@contextlib.contextmanager
def page(scratch):
    """The webserver of the copy, logged in; prints what it and the runtime said on the way out."""
    web = oplcweb.WebServer(scratch)
    try:
        web.login()
        yield web
    finally:
        web.stop()
        print(f"webserver and runtime output (tail):\n{web.output()[-3000:]}")


def load(web, program, name):
    """Upload, compile (CompileError with the page's log on errors); returns the compile time."""
    web.upload(program, name)
    web.compile()
    return web.compile_s


def shows_the_simulators_values(sim, client):
    """The three instruments valid, the scan running, the set points the simulator holds."""
    wait(lambda: all(client.coils(9)[i] for i in (C_Z1VALID, C_Z2VALID, C_PARTSVALID)), 60,
         "all three devices valid")
    b0 = client.hr(BEAT)[0]
    wait(lambda: client.hr(BEAT)[0] != b0, 10, "the scan heartbeat to move")
    assert client.hr(Z2SV)[0] == sim.ctl("get", addr=2, reg="SV")["raw"]  # DP=1: raw = x10
    assert s16(client.hr(Z1SV)[0]) == round(10 * sim.ctl("get", addr=1, reg="SP1")["eng"])
    assert 0 < client.hr(COUNT)[0] <= sim.ctl("get", addr=3, reg="VALUE")["raw"] & 0xFFFF
    assert client.hr(Z1ERR)[0] == client.hr(Z2ERR)[0] == 0


@pytest.mark.parametrize("route", ROUTES)
def test_route_through_the_web_page(route, scratch, dist, tmp_path):
    program, install, as_bundle = ROUTES[route]
    bus = str(tmp_path / "bus")
    st = oplc.retarget(program, str(tmp_path / os.path.basename(program)), bus)
    if install:
        scratch.install(dist)
    if as_bundle:
        st = bundle(st, dist, str(tmp_path / "upload.st"))
    t0 = time.monotonic()
    with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=30.0, seed=3) as sim, page(scratch) as web:
        load(web, st, f"heat treat ({route})")
        web.start_plc()
        client = oplc.PlcClient(web.modbus_port)
        try:
            shows_the_simulators_values(sim, client)
            assert "Running" in web.get("/dashboard").text
        finally:
            client.close()
        print(f"{route}: webserver up in {web.start_s:.1f} s, compiled in {web.compile_s:.1f} s, "
              f"route {time.monotonic() - t0:.1f} s; Modbus requests retried: {client.retried}")


def test_page_refuses_broken_bundle_and_missing_library(scratch, dist, tmp_path):
    """The routes' own steps (load) on a pristine copy fail, with the page's compile log: the
    bundle with its FILE lines broken (OpenPLC's handler no longer reads them: the shims never
    reach core/), and the plain example without install.sh (the blocks are unknown)."""
    good = bundle(ST, dist, str(tmp_path / "good.st"))
    broken = str(tmp_path / "broken.st")
    with open(good) as f, open(broken, "w") as out:
        text = f.read()
        assert text.count("(*FILE:") > 20
        out.write(text.replace("(*FILE:", "(*FILE "))
    with page(scratch) as web:
        for program, what in ((broken, "broken FILE lines"), (ST, "no library")):
            with pytest.raises(oplcweb.CompileError) as e:
                load(web, program, what)
            log = str(e.value)
            print(f"{what}: refused in {web.compile_s:.1f} s; {log}")
            assert "its compile log:\nGenerating C files" in log and log.endswith(oplcweb.DONE_ERR + "\n")
            # matiec stops at the first use of what it does not know (a block's type or, with
            # the FILE lines left in the program, the C in them)
            assert "Error generating C files" in log and "error" in log.split("Generating C files")[1]
        assert not [n for n in os.listdir(os.path.join(scratch.web, "core")) if n.startswith("mbfb")]
