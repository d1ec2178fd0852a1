"""Measure OpenPLC's built-in "Slave Devices" polling against the mbfb blocks on the same
simulated bus (docs/comparison.md). Run: tools/openplc/netns.sh .venv/bin/python bench/compare.py
with MBFB_DIST set (build/plc_lib/dist). One MV-D94 (slave 2) on a paced 9600 8N2 pty line.
Both programs publish the same map: HR0 = PV x10, HR1 = SV x10, HR2 = status (mbfb only),
HR1024 = set point request x10."""
import json
import os
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", "tools", "openplc"), os.path.join(HERE, "..", "tools", "sim")]
import oplc  # noqa: E402
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


def fcs(frames):
    """Function codes of the requests the simulator received."""
    out = {}
    for f in frames:
        if f["dir"] == "rx":
            fc = int(f["hex"].split()[1], 16)
            out[fc] = out.get(fc, 0) + 1
    return out


def run(kind, dist, tmp):
    bus = os.path.join(tmp, f"bus-{kind}")
    res = {}
    with Simulator(["mvd94:2:SV=100.0,DP=1"], link=bus, pace=True, seed=3) as sim, oplc.Scratch() as plc:
        prog = os.path.join(tmp, f"{kind}.st")
        with open(prog, "w") as f:
            f.write((MBFB if kind == "mbfb" else SLAVE).replace("'BUS'", f"'{bus}'"))
        if kind == "mbfb":
            plc.install(dist)
        else:
            with open(os.path.join(plc.web, "mbconfig.cfg"), "w") as f:
                f.write(MBCONFIG.replace('"BUS"', f'"{bus}"'))
        plc.compile(prog)
        plc.start(modbus_port=PORT)
        c = oplc.PlcClient(PORT)
        end = time.monotonic() + 20
        while c.hr(1)[0] != 1000 and time.monotonic() < end:
            time.sleep(0.1)
        sim.log(clear=True)
        time.sleep(10)
        f = fcs(sim.log(clear=True))
        res["requests in 10 s"] = f
        refresh = f.get(4, 0)  # one FC04 (PV) per refresh on both sides
        res["transactions per refresh"] = round(sum(f.values()) / refresh, 2) if refresh else None
        lat = []
        for v in (1500, 1200, 1400, 1100, 1300):
            t0 = time.monotonic()
            c.write(1024, v)
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
            sim.control(req)
            t0 = time.monotonic()
            while time.monotonic() - t0 < 8:
                regs = c.hr(0, 3)
                seen.append((round(time.monotonic() - t0, 1), regs[0], regs[2] if kind == "mbfb" else None))
                time.sleep(0.25)
            if req["op"] == "offline":
                sim.ctl("offline", addr=2, on=False)
            status = sorted({s for _, _, s in seen if s})
            faults[name] = {"PLC status codes seen": status if kind == "mbfb" else "none available",
                            "PV values seen": sorted({v for _, v, _ in seen})[:6]}
        res["faults"] = faults
        res["client retries"] = c.retried
        c.close()
    return res


def main():
    dist = os.environ["MBFB_DIST"]
    tmp = tempfile.mkdtemp(prefix="mbfb-compare-")
    try:
        out = {k: run(k, dist, tmp) for k in ("slave_devices", "mbfb")}
    finally:
        import shutil
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
