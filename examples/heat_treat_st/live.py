"""Run the heat-treat example in the real OpenPLC v3 runtime against the simulator and show its
live values until Ctrl-C (what ./demo.sh runs, inside a private network namespace).

A scratch copy of OpenPLC gets plc_lib installed, compiles heat_treat_st.st with OpenPLC's own
compile_program.sh and runs its runtime core with the Modbus TCP server on 127.0.0.1:5502; the
screen shows what a SCADA would read there (pymodbus), next to what the simulator holds.
Everything started here is stopped by pid on exit; the scratch copy is removed.
"""
import argparse
import os
import signal
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [os.path.join(ROOT, "tests", "e2e"), os.path.join(ROOT, "tests", "sim")]
import oplc  # noqa: E402
from simctl import Simulator  # noqa: E402

PORT = 5502
OPERATOR = [(120, 100), (180, 150), (150, 90)]  # zone 1 / zone 2 set points the demo sends


def s16(v):
    return v - 65536 if v >= 32768 else v


def screen(hr, coils, sim, t0, scratch):
    z = [("Zone 1  FDC-100 #1", hr[0], hr[1], hr[2], coils[0], coils[1], coils[2]),
         ("Zone 2  MV-D94  #2", hr[3], hr[4], hr[5], coils[3], coils[4], coils[5])]
    out = ["\033[H\033[2J",
           f"modbus-fb demo: heat-treat line in the OpenPLC v3 runtime   (up {time.monotonic() - t0:5.0f} s)",
           f"runtime: {scratch}   Modbus TCP 127.0.0.1:{PORT} (private netns)   Ctrl-C stops", "",
           f"{'device':20}{'PV':>9}{'SV':>9}  {'status':16}alarm"]
    for name, pv, sv, err, valid, band, quiet in z:
        status = "ok" if valid else "no data"
        status += f" (E{err})" if err else ""
        alarm = "QUIET" if quiet else ("OUT OF BAND" if band else "-")
        out.append(f"{name:20}{s16(pv) / 10:9.1f}{s16(sv) / 10:9.1f}  {status:16}{alarm}")
    status = ("ok" if coils[6] else "no data") + (f" (E{hr[7]})" if hr[7] else "")
    out.append(f"{'Parts   MT-S9   #3':20}{'count':>9}{hr[6]:9d}  {status:16}{'QUIET' if coils[7] else '-'}")
    out += ["", f"any alarm: {'YES' if coils[8] else 'no'}    PLC scans: {hr[8]}", "",
            "simulator (the instruments themselves):"]
    for line in sim:
        out.append("  " + line)
    sys.stdout.write("\n".join(out) + "\n")
    sys.stdout.flush()


def sim_lines(sim):
    try:
        z1 = sim.ctl("get", addr=1, reg="PV")["eng"], sim.ctl("get", addr=1, reg="SP1")["eng"]
        z2 = sim.ctl("get", addr=2, reg="PV")["eng"], sim.ctl("get", addr=2, reg="SV")["eng"]
        n = sim.ctl("get", addr=3, reg="VALUE")["raw"]
        return [f"FDC-100 PV {z1[0]:.1f} SP1 {z1[1]:.1f}   MV-D94 PV {z2[0]:.1f} SV {z2[1]:.1f}   "
                f"MT-S9 count {n}"]
    except Exception as e:  # the display must not die on a control hiccup
        return [f"(simulator: {e})"]


def _stop(*_):
    raise KeyboardInterrupt


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--time-scale", type=float, default=20.0)
    ap.add_argument("--seconds", type=float, default=0, help="stop after this long (0 = Ctrl-C)")
    args = ap.parse_args()
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _stop)
    tmp = tempfile.mkdtemp(prefix="mbfb-demo-")
    bus = os.path.join(tmp, "bus")
    dist = os.path.join(tmp, "dist")
    print("generating the library (plc_lib/mkdist.sh) ...", flush=True)
    if os.system(f"'{ROOT}/plc_lib/mkdist.sh' '{dist}' >/dev/null"):
        sys.exit("plc_lib/mkdist.sh failed")
    try:
        with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=args.time_scale) as sim, \
                oplc.Scratch() as plc:
            print(f"simulator on {sim.port} ({bus}); installing plc_lib into {plc.dir} ...", flush=True)
            plc.install(dist)
            print("compiling the example with OpenPLC's compile_program.sh ...", flush=True)
            plc.compile(oplc.retarget(os.path.join(HERE, "heat_treat_st.st"),
                                      os.path.join(tmp, "heat_treat_st.st"), bus))
            plc.start(modbus_port=PORT)
            client = oplc.PlcClient(PORT)
            t0 = time.monotonic()
            step = -1
            try:
                while not args.seconds or time.monotonic() - t0 < args.seconds:
                    # Play the operator: a new pair of set points every 40 s, written to the
                    # PLC's Modbus TCP server (the example sends them to the instruments).
                    if int((time.monotonic() - t0) // 40) != step:
                        step = int((time.monotonic() - t0) // 40)
                        sp = OPERATOR[step % len(OPERATOR)]
                        client.write(1024, sp[0] * 10)
                        client.write(1025, sp[1] * 10)
                    screen(client.hr(0, 9), client.coils(9), sim_lines(sim), t0, plc.dir)
                    print(f"\noperator: set points {sp[0]} / {sp[1]} written to HR 1024/1025"
                          " (changes every 40 s)")
                    time.sleep(0.5)
            finally:
                client.close()
    except KeyboardInterrupt:
        pass
    finally:
        import shutil
        shutil.rmtree(tmp, ignore_errors=True)
    print("\nstopped: runtime and simulator ended, scratch copy removed.")


if __name__ == "__main__":
    main()
