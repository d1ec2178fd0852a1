#!/usr/bin/env python3
"""strucpp_v4_import (labels strucpp, e2e): tools/oplc_import end to end in OpenPLC Runtime v4,
the Runtime v4 half of e2e_oplc_import (tests/e2e/test_oplc_import.py, OpenPLC v3).

One plant: a relay module (slave 2) and a meter (slave 5) on one RTU line, the simulator's
generic devices (tests/oplc_import/line_*.json). One user program using %IX100.0.., %IW100..,
%QX100.0.., %QW100... Run A: Runtime v4's own Modbus master plugin configured by its JSON
(tests/oplc_import/fixtures/line_v4.json, the same line as v3's line.cfg, its port set to the
simulator's). Run B: no master plugin, the same program converted with `oplc_import --into`
(MB_Poll and the write helpers, built with the v4 package). plc_main is built from the runtime's
source and run in its own network namespace (tools/openplc/rtv4.py); in both runs Runtime v4's
own modbus_slave plugin serves its image tables on 127.0.0.1 inside that namespace, and
pymodbus reads and writes them from inside it (nsenter). Both plugins run in their own virtual
environments, made as the runtime's scripts/manage_plugin_venvs.sh makes them (their
requirements.txt from the package registry), in <build>/v4/plugin-venvs.

What the user's program sees at %IX100.0.. and %IW100.. it copies to %QX200.0.. and %QW200..
(Runtime v4 copies %I into a program before each scan and never commits a program's writes to
%I back to the image: with the blocks, the values exist inside the program that declares them,
which is where `--into` puts them). Checked in both runs: the same values at the same
addresses; relay 2 and the meter's second output register, written through the slave plugin to
%QX100.2 and %QW101, reach the devices; the plugin rewrites the coils at every poll (at least 5
times in 10 polls of unchanged outputs), the converted program not once; with the meter
silent both hold its last values, nothing the program can see changes with the plugin, and the
converted program's status (dev1_Valid, dev1_ErrorID, published by the test's one added line to
%QX0.0 and %QW0) falls. Exit 77 = skipped with the reason (MBFB_REQUIRE_TOOLCHAIN=1: failure).
"""
import concurrent.futures
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tools", "openplc"))
sys.path.insert(0, os.path.join(ROOT, "tools", "sim"))
import rtv4  # noqa: E402
from runtime_v4 import fail, plc_main, runtime_home, skip, translate, wait  # noqa: E402
from simctl import Simulator  # noqa: E402

LINE = os.path.join(ROOT, "tests", "oplc_import")
sys.path.insert(0, LINE)
from line_plant import METER_WORDS, RELAY_INPUTS, user_program  # noqa: E402
PLUGIN_JSON = os.path.join(LINE, "fixtures", "line_v4.json")
CONVERTER = os.path.join(ROOT, "tools", "oplc_import", "oplc_import.py")
PLUGINS = "core/src/drivers/plugins/python"
PORT = 5502                     # the slave plugin's, on 127.0.0.1 in the daemon's namespace
SEEN_BITS, SEEN_WORDS = 1600, 200      # %QX200.0.., %QW200.. on the slave plugin
IMAGE_BITS, IMAGE_WORDS = 800, 100     # %IX100.0.., %IW100.. (discrete inputs, input registers)
COIL0, HR0 = 800, 100                  # %QX100.0, %QW100
MBFB_E_TIMEOUT = 1                     # docs/errors.md: no reply after all retries

USER = user_program(
    decls="    meter_err AT %QW0 : WORD;\n"
    + "".join(f"    seen_in{i} AT %QX200.{i} : BOOL;\n" for i in range(8))
    + "".join(f"    seen_w{i} AT %QW{200 + i} : WORD;\n" for i in range(12)),
    body="".join(f"  seen_in{i} := in{i};\n" for i in range(8))
    + "".join(f"  seen_w{i} := w{i};\n" for i in range(12)))

# pymodbus in the daemon's network namespace: one JSON request per line on stdin, one answer
# per line on stdout ({"error": ...} while the slave plugin is not up yet).
CLIENT = r"""
import json, sys
from pymodbus.client import ModbusTcpClient
c = ModbusTcpClient("127.0.0.1", port=int(sys.argv[1]), timeout=2, retries=0)
for line in sys.stdin:
    q = json.loads(line)
    try:
        if not c.connected and not c.connect():
            raise OSError("no connection")
        if q["op"] == "read":
            def ok(r):
                if r.isError():
                    raise OSError(str(r))
                return r
            a = {"seen_bits": ok(c.read_coils(q["seen_bits"], count=8)).bits[:8],
                 "seen_words": ok(c.read_holding_registers(q["seen_words"], count=12)).registers,
                 "image_bits": ok(c.read_discrete_inputs(q["image_bits"], count=8)).bits[:8],
                 "image_words": ok(c.read_input_registers(q["image_words"], count=12)).registers,
                 "status": [ok(c.read_coils(0, count=1)).bits[0],
                            ok(c.read_holding_registers(0, count=1)).registers[0]]}
        elif q["op"] == "coil":
            a = {"ok": not c.write_coil(q["addr"], q["value"]).isError()}
        else:
            a = {"ok": not c.write_register(q["addr"], q["value"]).isError()}
    except Exception as e:
        c.close()
        a = {"error": f"{type(e).__name__}: {e}"}
    print(json.dumps(a), flush=True)
"""


class SlaveClient:
    """Runtime v4's modbus_slave plugin, read and written by pymodbus from inside the daemon's
    network namespace (the plugin listens there only)."""

    def __init__(self, pid):
        self.proc = subprocess.Popen(["nsenter", f"--net=/proc/{pid}/ns/net", "--", sys.executable,
                                      "-c", CLIENT, str(PORT)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask(self, **q):
        self.proc.stdin.write(json.dumps(q) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the namespace's Modbus client exited ({self.proc.wait()})")
        return json.loads(line)

    def view(self):
        """What the program shows: ((bits, words) the user's program saw at %IX100.0.. and
        %IW100.., [%QX0.0, %QW0]), the image's %IX100.0.. and %IW100.., or None."""
        a = self.ask(op="read", seen_bits=SEEN_BITS, seen_words=SEEN_WORDS,
                     image_bits=IMAGE_BITS, image_words=IMAGE_WORDS)
        if "error" in a:
            return None
        return ((a["seen_bits"], a["seen_words"]), a["status"], (a["image_bits"], a["image_words"]))

    def close(self):
        self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def frames(sim, head):
    return sum(1 for f in sim.log(clear=False) if f["dir"] == "rx" and f["hex"].startswith(head))


def program(v4, rt, st, tmp, package):
    t = time.monotonic()
    try:
        rtv4.program_build(os.path.join(v4, "strucpp"), package, [translate(st, tmp)], rt.generated)
        rt.compile()
        rt.install()
    except RuntimeError as e:
        fail(str(e))
    print(f"{os.path.basename(st)}: compiled for Runtime v4 in {time.monotonic() - t:.1f} s")


def run_plant(exe, home, v4, venvs, tmp, sim, bus, kind):
    """The plant in a scratch Runtime v4, the same steps in both runs: (the values the program
    saw, the coil writes (FC15) during ten polls of unchanged outputs, the status and view
    before and while the meter is silent, the image's %IX100../%IW100..)."""
    work = os.path.join(tmp, kind)
    os.makedirs(work)
    rt = rtv4.RuntimeRoot(home, os.path.join(work, "runtime"))
    user = os.path.join(work, "main.st")
    with open(user, "w") as f:
        f.write(USER)
    if kind == "plugin":
        program(v4, rt, user, work, None)
        conf = os.path.join(work, "modbus_master.json")
        with open(PLUGIN_JSON) as f:
            text = f.read().replace('"/dev/ttyUSB0"', json.dumps(bus))
        with open(conf, "w") as f:
            f.write(text)
        rt.plugin("modbus_master", f"{PLUGINS}/modbus_master/modbus_master_plugin.py", conf, venvs["modbus_master"])
    else:
        conv = subprocess.run([sys.executable, CONVERTER, PLUGIN_JSON, "--port", f"/dev/ttyUSB0={bus}",
                               "--into", user, "-o", "-"], capture_output=True, text=True)
        if conv.returncode:
            fail(f"oplc_import: {conv.stderr}")
        end = "(* end of the converted part *)"
        if conv.stdout.count(end) != 1:
            fail(f"oplc_import's output has {conv.stdout.count(end)} '{end}'")
        converted = os.path.join(work, "main_mb.st")
        with open(converted, "w") as f:
            f.write(conv.stdout.replace(end, end + "\n  meter_ok := dev1_Valid;\n  meter_err := dev1_ErrorID;"))
        program(v4, rt, converted, work, os.path.join(v4, "package"))
    slave_conf = os.path.join(work, "modbus_slave.json")
    with open(slave_conf, "w") as f:
        json.dump({"network_configuration": {"host": "127.0.0.1", "port": PORT}}, f)
    rt.plugin("modbus_slave", f"{PLUGINS}/modbus_slave/simple_modbus.py", slave_conf, venvs["modbus_slave"])

    for reg in ("co:0", "co:1", "co:2", "co:3", "out1", "out2"):
        sim.ctl("set", addr=2 if reg.startswith("co") else 5, reg=reg, raw=1)
    sim.log(clear=True)
    t0 = time.monotonic()
    daemon = rtv4.Daemon(exe, rt)
    client = None
    try:
        daemon.wait_status("RUNNING", 30)
        client = SlaveClient(daemon.pid)
        want = (RELAY_INPUTS, METER_WORDS)
        view = wait(lambda: (lambda v: v if v and v[0] == want else None)(client.view()), 60,
                    f"{kind}: the devices' values in the program at %IX100.0.. and %IW100..", daemon)
        print(f"{kind}: the program saw the devices' values {time.monotonic() - t0:.1f} s after plc_main started")
        if not client.ask(op="coil", addr=COIL0 + 2, value=True).get("ok") or \
                not client.ask(op="reg", addr=HR0 + 1, value=1234).get("ok"):
            fail(f"{kind}: the slave plugin refused a write to %QX100.2 or %QW101", daemon)
        wait(lambda: sim.ctl("get", addr=2, reg="co:2")["raw"] == 1 and
             [sim.ctl("get", addr=2, reg=f"co:{i}")["raw"] for i in (0, 1, 3)] == [0, 0, 0],
             30, f"{kind}: the relays as %QX100.0.. say", daemon)
        wait(lambda: sim.ctl("get", addr=5, reg="out2")["raw"] == 1234, 30, f"{kind}: %QW101 at the meter", daemon)
        wait(lambda: frames(sim, "05 10") and frames(sim, "02 0F"), 30, f"{kind}: the writes logged", daemon)
        polls0, writes0 = frames(sim, "02 02"), frames(sim, "02 0F")
        wait(lambda: frames(sim, "02 02") >= polls0 + 10, 60, f"{kind}: ten more polls of the relays", daemon)
        rewrites = frames(sim, "02 0F") - writes0
        before = client.view()
        sim.ctl("offline", addr=5, on=True)
        asked0 = frames(sim, "05 04")
        # three requests to the silent meter unanswered (each waits its 1 s timeout) ...
        wait(lambda: frames(sim, "05 04") >= asked0 + 3, 60, f"{kind}: requests to the silent meter", daemon)
        if kind == "blocks":   # ... and the converted program's status down: Valid FALSE (the
            # data stale), then the failed refresh's ErrorID (after the shims' attempts)
            wait(lambda: (lambda v: v and not v[1][0] and v[1][1])(client.view()), 30,
                 f"{kind}: the converted program's meter status (Valid FALSE, ErrorID)", daemon)
        during = client.view()
        sim.ctl("offline", addr=5, on=False)
        daemon.command("STOP")   # STOP before SIGINT: the daemon's SIGINT shutdown with a plugin crashed (bench/compare.py)
        daemon.wait_status("STOPPED", 30)
        return view[0], rewrites, before, during, view[2]
    except (RuntimeError, TimeoutError) as e:
        fail(f"{kind}: {e}", daemon)
    finally:
        if client:
            client.close()
        code = daemon.stop()
        print(f"{kind}: plc_main exited {code}")


def main():
    build_dir, v4 = sys.argv[1], sys.argv[2]
    home = runtime_home(v4)
    for p in ("modbus_master", "modbus_slave"):
        if not os.path.exists(os.path.join(home, PLUGINS, p, "requirements.txt")):
            skip(f"Runtime v4 at {home} has no {p} plugin ({PLUGINS}/{p})")
    if shutil.which("nsenter") is None:
        skip("nsenter (util-linux) not found: the test reads the slave plugin inside the daemon's namespace")
    # the two venvs side by side (about 40 s each the first time in a build tree, then kept)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        made = {p: pool.submit(rtv4.plugin_venv, home, p, os.path.join(v4, "plugin-venvs"))
                for p in ("modbus_master", "modbus_slave")}
    venvs = {}
    for p, f in made.items():
        try:
            venvs[p] = f.result()
        except RuntimeError as e:
            skip(f"the {p} plugin's Python packages ({PLUGINS}/{p}/requirements.txt) could not be installed: {e}")
    print(f"Runtime v4: {home} {rtv4.version(home)}")
    exe = plc_main(build_dir, home)

    tmp = tempfile.mkdtemp(prefix="mbfb-v4import-")
    try:
        bus = os.path.join(tmp, "bus")
        with Simulator([f"generic:2:file={os.path.join(LINE, 'line_relays.json')}",
                        f"generic:5:file={os.path.join(LINE, 'line_meter.json')}"], link=bus) as sim:
            a = run_plant(exe, home, v4, venvs, tmp, sim, bus, "plugin")
            b = run_plant(exe, home, v4, venvs, tmp, sim, bus, "blocks")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    check(a, b)


def check(a, b):
    want = (RELAY_INPUTS, METER_WORDS)
    (seen_a, rew_a, before_a, during_a, image_a), (seen_b, rew_b, before_b, during_b, image_b) = a, b
    print(f"plugin: image %IX100.0.. {image_a[0]}, %IW100.. {image_a[1]}")
    print(f"blocks: image %IX100.0.. {image_b[0]}, %IW100.. {image_b[1]} (a program's %I is not committed)")
    print(f"coil writes in 10 polls of unchanged outputs: plugin {rew_a}, blocks {rew_b}")
    print(f"meter silent: plugin's status (%QX0.0, %QW0) {before_a[1]} -> {during_a[1]}, "
          f"blocks' {before_b[1]} -> {during_b[1]}")
    if not seen_a == seen_b == want:
        fail(f"the program saw {seen_a} with the plugin, {seen_b} with the blocks; the devices hold {want}")
    if not during_a[0] == during_b[0] == want:
        fail(f"with the meter silent the program saw {during_a[0]} (plugin), {during_b[0]} (blocks): "
             "not the last values")
    if rew_a < 5:
        fail(f"the plugin rewrote the coils {rew_a} times in 10 polls (it writes at every poll)")
    if rew_b != 0:
        fail(f"the converted program rewrote unchanged coils {rew_b} times in 10 polls")
    if during_a != before_a:
        fail(f"with the plugin, the program's view changed while the meter was silent: {before_a} -> {during_a}")
    if before_b[1] != [True, 0]:
        fail(f"the converted program's meter status before the fault: {before_b[1]}, not [True, 0]")
    if during_b[1] != [False, MBFB_E_TIMEOUT]:
        fail(f"the converted program's meter status with the meter silent: {during_b[1]}, "
             f"not [False, {MBFB_E_TIMEOUT}] (Valid FALSE, ErrorID MBFB_E_TIMEOUT)")
    print(f"PASS: the same values at the same addresses with Runtime v4's plugin and with the converted "
          f"program; only the converted program reports the silent meter (Valid FALSE, ErrorID {during_b[1][1]}: MBFB_E_TIMEOUT)")


if __name__ == "__main__":
    main()
