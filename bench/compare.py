"""Measure OpenPLC v3's built-in "Slave Devices" polling, the mbfb blocks (in OpenPLC v3) and
OpenPLC Runtime v4's own Modbus master plugin on the same simulated bus and faults
(docs/comparison.md). Run: .venv/bin/python bench/compare.py (it makes the v4 plugin's
virtual environment, then runs itself again under tools/openplc/netns.sh) with
MBFB_DIST set (build/plc_lib/dist) and, for the v4 column, MBFB_BUILD (the build tree with
target mbfb_v4 built: STruC++) and OPENPLC_V4_HOME (default /opt/openplc-runtime).
One MV-D94 (slave 2) on a paced 9600 8N2 pty line. The v3 programs publish the same map:
HR0 = PV x10, HR1 = SV x10, HR2 = status (mbfb only), HR1024 = set point request x10, read
and written by pymodbus on the runtime's Modbus TCP server; the v4 program has the same
variables (OPV, OSV, Req), read and forced through the v4 daemon's DEBUG command (the
Editor's debugger), as v4 runs no Modbus server of its own unless its slave plugin is set up."""
import json
import os
import shutil
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", "tools", "openplc"), os.path.join(HERE, "..", "tools", "sim")]
import oplc  # noqa: E402
import rtv4  # noqa: E402
from simctl import Simulator  # noqa: E402

PORT = 5502
TASK = """CONFIGURATION Config0
  RESOURCE Res0 ON PLC
    TASK T(INTERVAL := T#50ms, PRIORITY := 0);
    PROGRAM P WITH T : cmp;
  END_RESOURCE
END_CONFIGURATION
"""
MBFB = """PROGRAM cmp
  VAR
    Z : TempCtrl_MVD94; Sent : INT; W : BOOL;
    L : MB_LINE := (Baud := 9600, DataBits := 8, Parity := 'N', StopBits := 2);
  END_VAR
  VAR
    OPV AT %QW0 : INT;
    OSV AT %QW1 : INT;
    OST AT %QW2 : WORD;
    Req AT %MW0 : INT;
  END_VAR
  W := (Req <> 0) AND (Req <> Sent);
  Z(Enable := TRUE, Port := 'BUS', Line := L, SlaveId := 2, Period := T#500ms,
    WriteSV := W, SVSet := INT_TO_REAL(Req) / 10.0);
  IF W THEN Sent := Req; END_IF;
  OPV := REAL_TO_INT(Z.PV * 10.0); OSV := REAL_TO_INT(Z.SV * 10.0); OST := Z.ErrorID;
END_PROGRAM
""" + TASK
# Slave Devices: %IW100 = input register 0x1000 (PV), %IW101.. = holding 0..33 (SV first),
# %QW100 is written to holding register 0 (SV) on every poll.
SLAVE = """PROGRAM cmp
  VAR
    IPV AT %IW100 : INT;
    ISV AT %IW101 : INT;
    WSV AT %QW100 : INT := 1000;
    OPV AT %QW0 : INT;
    OSV AT %QW1 : INT;
    Req AT %MW0 : INT;
  END_VAR
  OPV := IPV; OSV := ISV; IF Req <> 0 THEN WSV := Req; END_IF;
END_PROGRAM
""" + TASK
MBCONFIG = """Num_Devices = "1"
Polling_Period = "100"
Timeout = "1000"
device0.name = "mvd94"
device0.slave_id = "2"
device0.protocol = "RTU"
device0.address = "BUS"
device0.IP_Port = "0"
device0.RTU_Baud_Rate = "9600"
device0.RTU_Parity = "None"
device0.RTU_Data_Bits = "8"
device0.RTU_Stop_Bits = "2"
device0.RTU_TX_Pause = "0"
device0.Discrete_Inputs_Start = "0"
device0.Discrete_Inputs_Size = "0"
device0.Coils_Start = "0"
device0.Coils_Size = "0"
device0.Input_Registers_Start = "4096"
device0.Input_Registers_Size = "1"
device0.Holding_Registers_Read_Start = "0"
device0.Holding_Registers_Read_Size = "34"
device0.Holding_Registers_Start = "0"
device0.Holding_Registers_Size = "1"
"""
# Runtime v4's modbus_master plugin configured as the v3 Slave Devices above (its JSON, the
# Editor's "Remote devices" page): PV (input 0x1000) to %IW100, holding 0..33 to %IW101..,
# %QW100 written to holding 0 (SV) with FC06 (the plugin offers FC06; Slave Devices only FC16),
# every point every 100 ms, timeout 1000 ms. The program as SLAVE, but WSV is set in the
# program: a located variable's initialiser (`WSV AT %QW100 : INT := 1000`) is not kept in
# Runtime v4 (threaded process image: WSV reads 0 and the plugin writes SV = 0 at once).
PLUGIN_PROGRAM = """PROGRAM cmp
  VAR
    IPV AT %IW100 : INT;
    ISV AT %IW101 : INT;
    WSV AT %QW100 : INT;
    OPV : INT;
    OSV : INT;
    Req : INT;
  END_VAR
  OPV := IPV; OSV := ISV; IF Req <> 0 THEN WSV := Req; ELSE WSV := 1000; END_IF;
END_PROGRAM
""" + TASK


def plugin_config(bus):
    return [{"name": "mvd94", "protocol": "MODBUS", "config": {
        "type": "SLAVE", "transport": "rtu", "serial_port": bus, "baud_rate": 9600, "parity": "N",
        "stop_bits": 2, "data_bits": 8, "timeout_ms": 1000, "slave_id": 2, "io_points": [
            {"fc": 4, "offset": "0x1000", "iec_location": "%IW100", "len": 1, "cycle_time_ms": 100},
            {"fc": 3, "offset": "0", "iec_location": "%IW101", "len": 34, "cycle_time_ms": 100},
            {"fc": 6, "offset": "0", "iec_location": "%QW100", "len": 1, "cycle_time_ms": 100}]}}]


def fcs(frames):
    """Function codes of the requests the simulator received."""
    out = {}
    for f in frames:
        if f["dir"] == "rx":
            fc = int(f["hex"].split()[1], 16)
            out[fc] = out.get(fc, 0) + 1
    return out


class V3:
    """A program in a scratch OpenPLC v3, read and written over its Modbus TCP server."""

    def __init__(self, kind, dist, tmp, bus):
        self.plc = oplc.Scratch()
        try:
            self._start(kind, dist, tmp, bus)
        except BaseException:
            self.plc.close()
            raise
        self.has_status = kind == "mbfb"

    def _start(self, kind, dist, tmp, bus):
        prog = os.path.join(tmp, f"{kind}.st")
        with open(prog, "w") as f:
            f.write((MBFB if kind == "mbfb" else SLAVE).replace("'BUS'", f"'{bus}'"))
        if kind == "mbfb":
            self.plc.install(dist)
        else:
            with open(os.path.join(self.plc.web, "mbconfig.cfg"), "w") as f:
                f.write(MBCONFIG.replace('"BUS"', f'"{bus}"'))
        self.plc.compile(prog)
        self.plc.start(modbus_port=PORT)
        self.c = oplc.PlcClient(PORT)

    def read(self):
        """(PV x10, SV x10, status or None)."""
        regs = self.c.hr(0, 3)
        return regs[0], regs[1], regs[2] if self.has_status else None

    def request(self, v):
        self.c.write(1024, v)

    def close(self):
        out = {"client retries": self.c.retried}
        self.c.close()
        self.plc.close()
        return out


class V4Plugin:
    """PLUGIN_PROGRAM in Runtime v4's daemon (rtv4.py) with its modbus_master plugin."""

    def __init__(self, build, tmp, bus):
        home = rtv4.runtime_v4_home()
        v4 = os.path.join(build, "v4")
        exe = rtv4.build_plc_main(home, os.path.join(v4, "openplc-runtime"))
        venv = rtv4.plugin_venv(home, "modbus_master", os.path.join(v4, "plugin-venvs"), fetch=False)
        self.rt = rtv4.RuntimeRoot(home, os.path.join(tmp, "v4-runtime"))
        prog = os.path.join(tmp, "v4_plugin.st")
        with open(prog, "w") as f:
            f.write(PLUGIN_PROGRAM)
        rtv4.program_build(os.path.join(v4, "strucpp"), None, [prog], self.rt.generated)
        self.rt.compile()
        self.rt.install()
        conf = os.path.join(tmp, "modbus_master.json")
        with open(conf, "w") as f:
            json.dump(plugin_config(bus), f)
        self.rt.plugin("modbus_master", "core/src/drivers/plugins/python/modbus_master/modbus_master_plugin.py",
                       conf, venv)
        self.d = rtv4.Daemon(exe, self.rt)
        try:
            self.d.wait_status("RUNNING", 30)
        except BaseException:
            self.d.stop()
            raise
        dmap = rtv4.DebugMap(os.path.join(self.rt.generated, "debug-map.json"))
        self.opv, self.osv, self.req = (dmap.find(v) for v in ("P.OPV", "P.OSV", "P.REQ"))

    def read(self):
        get = lambda leaf: int.from_bytes(rtv4.read(self.d, leaf), "little", signed=True)  # noqa: E731
        return get(self.opv), get(self.osv), None

    def request(self, v):
        rtv4.force(self.d, self.req, v.to_bytes(2, "little", signed=True))

    def close(self):
        # STOP first: the daemon's SIGINT shutdown with a plugin running stops the plugins twice
        # (plugin_driver_destroy, then the program's unload) and crashed here (v4.1.4)
        out = {"STOP": self.d.command("STOP")}
        try:
            self.d.wait_status("STOPPED", 30)
        finally:
            out["plc_main exit code"] = self.d.stop()
        return out


def run(kind, dist, build, tmp):
    bus = os.path.join(tmp, f"bus-{kind}")
    res = {}
    with Simulator(["mvd94:2:SV=100.0,DP=1"], link=bus, pace=True, seed=3) as sim:
        plc = V4Plugin(build, tmp, bus) if kind == "v4_plugin" else V3(kind, dist, tmp, bus)
        try:
            measure(plc, sim, res)
        finally:
            res.update(plc.close())
    return res


def measure(plc, sim, res):
    end = time.monotonic() + 20
    while plc.read()[1] != 1000 and time.monotonic() < end:
        time.sleep(0.1)
    sim.log(clear=True)
    time.sleep(10)
    f = fcs(sim.log(clear=True))
    res["requests in 10 s"] = f
    refresh = f.get(4, 0)  # one FC04 (PV) per refresh on every side
    res["transactions per refresh"] = round(sum(f.values()) / refresh, 2) if refresh else None
    lat = []
    for v in (1500, 1200, 1400, 1100, 1300):
        t0 = time.monotonic()
        plc.request(v)
        while sim.ctl("get", addr=2, reg="SV")["raw"] != v and time.monotonic() - t0 < 10:
            time.sleep(0.005)
        lat.append(time.monotonic() - t0)
        time.sleep(1.0)
    res["set point to device s (median, max)"] = (round(statistics.median(lat), 3), round(max(lat), 3))
    faults = {}
    for name, req in (("late 1.5 s x3", {"op": "fault", "addr": 2, "kind": "late", "delay_ms": 1500, "count": 3}),
                      ("bad CRC x3", {"op": "fault", "addr": 2, "kind": "bad_crc", "count": 3}),
                      ("gone 8 s", {"op": "offline", "addr": 2, "on": True})):
        time.sleep(2)
        sim.ctl("set", addr=2, reg="PV", raw=777)  # a value the PLC has not seen yet
        seen = []
        sim.log(clear=True)
        sim.control(req)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 8:
            pv, _, st = plc.read()
            seen.append((round(time.monotonic() - t0, 1), pv, st))
            time.sleep(0.25)
        if req["op"] == "offline":
            sim.ctl("offline", addr=2, on=False)
        during = sim.log(clear=True)
        # the fault over (device back, or its 3 faulty replies used up): a new PV in the device,
        # held there (set again every 50 ms: the simulated process drifts); how long until the
        # line carries a reply again, and until the PLC shows the new PV
        t1 = time.monotonic()
        reply_s = fresh_s = None
        while time.monotonic() - t1 < 45 and fresh_s is None:
            sim.ctl("set", addr=2, reg="PV", raw=555)
            if reply_s is None and any(f["dir"] == "tx" for f in sim.log(clear=True)):
                reply_s = round(time.monotonic() - t1, 2)
            if abs(plc.read()[0] - 555) <= 1:
                fresh_s = round(time.monotonic() - t1, 2)
            time.sleep(0.05)
        status = sorted({s for _, _, s in seen if s})
        faults[name] = {"PLC status codes seen": status if seen[0][2] is not None else "none available",
                        "PV values seen": sorted({v for _, v, _ in seen})[:6],
                        "requests during the 8 s": sum(1 for f in during if f["dir"] == "rx"),
                        "first reply on the line after the fault s": reply_s if reply_s is not None else "none in 45 s",
                        "device's PV in the PLC after the fault s": fresh_s if fresh_s is not None else "not in 45 s"}
    res["faults"] = faults


def main():
    dist = os.environ["MBFB_DIST"]
    build = os.environ.get("MBFB_BUILD") or os.path.join(HERE, "..", "build")
    kinds = [k for k in ("slave_devices", "mbfb") if not sys.argv[1:] or k in sys.argv[1:]]
    reason = rtv4.missing(rtv4.runtime_v4_home())
    if not reason and not os.path.exists(os.path.join(build, "v4", "strucpp", "dist", "index.js")):
        reason = f"STruC++ not built in {build}/v4 (cmake --build {build} --target mbfb_v4)"
    want_v4 = not reason and (not sys.argv[1:] or "v4_plugin" in sys.argv[1:])
    if not oplc.in_private_netns():
        # the plugin's venv from the package registry first (the namespace has no network),
        # then this script again in a private network namespace (OpenPLC's servers)
        if want_v4:
            rtv4.plugin_venv(rtv4.runtime_v4_home(), "modbus_master", os.path.join(build, "v4", "plugin-venvs"))
        netns = os.path.join(HERE, "..", "tools", "openplc", "netns.sh")
        os.execv(netns, [netns, sys.executable, os.path.abspath(__file__), *sys.argv[1:]])
    if reason:
        print(f"v4_plugin column skipped: {reason}", file=sys.stderr)
    elif want_v4:
        kinds.append("v4_plugin")
    tmp = tempfile.mkdtemp(prefix="mbfb-compare-")
    try:
        out = {k: run(k, dist, build, tmp) for k in kinds}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
