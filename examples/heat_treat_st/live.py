"""Run the heat-treat example against the simulator and show its live values until Ctrl-C
(what ./demo.sh runs). Two back ends, one screen:

  --backend openplc  the real OpenPLC v3 runtime (inside a private network namespace): a scratch
                     copy of OpenPLC gets plc_lib installed, compiles heat_treat_st.st with
                     OpenPLC's own compile_program.sh and runs its runtime core with the Modbus
                     TCP server on 127.0.0.1:5502; the screen reads it with pymodbus, as a SCADA.
  --backend runner   the project's own runner (tools/runner/fb_host.cpp in program mode, built by
                     CMake as heat_treat_st_runner; --runner-exe), where OpenPLC is missing: the
                     same scan loop, its located variables read from the snapshot file it writes
                     and set points written through its control socket, with OpenPLC's Modbus
                     map (tools/runner/runner.py).

Both run the program with BusPort pointed at the simulator's pty. The screen shows what the
PLC publishes next to what the simulator holds. Everything started here is stopped by pid on
exit; temp files and the scratch copy are removed.
"""
import argparse
import contextlib
import functools
import os
import shutil
import signal
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [os.path.join(ROOT, "tools", "openplc"), os.path.join(ROOT, "tools", "sim"),
                os.path.join(ROOT, "tools", "runner")]
import oplc  # noqa: E402
from runner import Runner  # noqa: E402
from simctl import Simulator  # noqa: E402

PORT = 5502
# Zone 1 / zone 2 set points the demo sends, a new pair every OPERATOR_PERIOD s; the first
# differs from the simulator's start (120 / 100), so a change shows at once.
OPERATOR = [(130, 110), (180, 150), (150, 90)]
OPERATOR_PERIOD = 40
BUS_PORT_VAR = "CONFIG0.RES0.HEATTREAT.BUSPORT"  # the example's BusPort (its CONFIGURATION)


def s16(v):
    return v - 65536 if v >= 32768 else v


def screen(hr, coils, sim, t0, title, where):
    z = [("Zone 1  FDC-100 #1", hr[0], hr[1], hr[2], coils[0], coils[1], coils[2]),
         ("Zone 2  MV-D94  #2", hr[3], hr[4], hr[5], coils[3], coils[4], coils[5])]
    out = ["\033[H\033[2J",
           f"modbus-fb demo: heat-treat line in {title}   (up {time.monotonic() - t0:5.0f} s)",
           f"{where}   Ctrl-C stops", "",
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


@contextlib.contextmanager
def openplc_backend(tmp, bus):
    """The example in a scratch copy of OpenPLC v3, read over its Modbus TCP server."""
    dist = os.path.join(tmp, "dist")
    print("generating the library (plc_lib/mkdist.sh) ...", flush=True)
    if os.system(f"'{ROOT}/plc_lib/mkdist.sh' '{dist}' >/dev/null"):
        sys.exit("plc_lib/mkdist.sh failed")
    with oplc.Scratch() as plc:
        print(f"installing plc_lib into {plc.dir} ...", flush=True)
        plc.install(dist)
        print("compiling the example with OpenPLC's compile_program.sh ...", flush=True)
        plc.compile(oplc.retarget(os.path.join(HERE, "heat_treat_st.st"),
                                  os.path.join(tmp, "heat_treat_st.st"), bus))
        plc.start(modbus_port=PORT)
        client = oplc.PlcClient(PORT)
        try:
            yield client, "the OpenPLC v3 runtime", \
                f"runtime: {plc.dir}   Modbus TCP 127.0.0.1:{PORT} (private netns)"
        finally:
            client.close()


@contextlib.contextmanager
def runner_backend(tmp, bus, exe):
    """The example in the project's own runner, read through its snapshot and control socket."""
    print(f"starting the runner {exe} ...", flush=True)
    with Runner(exe, sets={BUS_PORT_VAR: bus}) as plc:
        yield plc, "the project's own runner (no OpenPLC)", \
            f"runner: pid {plc.proc.pid}, snapshot {plc.snapshot_path}"


def _stop(*_):
    raise KeyboardInterrupt


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", choices=("openplc", "runner"), default="openplc")
    ap.add_argument("--runner-exe", help="the runner built from the example (heat_treat_st_runner)")
    ap.add_argument("--time-scale", type=float, default=20.0)
    ap.add_argument("--seconds", type=float, default=0, help="stop after this long (0 = Ctrl-C)")
    args = ap.parse_args()
    if args.backend == "runner" and not args.runner_exe:
        ap.error("--backend runner needs --runner-exe")
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _stop)
    tmp = tempfile.mkdtemp(prefix="mbfb-demo-")
    bus = os.path.join(tmp, "bus")
    try:
        if args.backend == "runner":
            backend = functools.partial(runner_backend, exe=args.runner_exe)
        else:
            backend = openplc_backend
        with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=args.time_scale) as sim:
            print(f"simulator on {sim.port} ({bus})", flush=True)
            with backend(tmp, bus) as (client, title, where):
                show(client, sim, title, where, args.seconds)
    except KeyboardInterrupt:
        pass
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print("\nstopped: PLC and simulator ended, temp files removed.")


def show(client, sim, title, where, seconds):
    """The live screen every 0.5 s, playing the operator, until Ctrl-C or seconds."""
    t0 = time.monotonic()
    t_op, step, note = None, -1, "operator: waiting for both zones to be valid"
    while not seconds or time.monotonic() - t0 < seconds:
        hr, coils = client.hr(0, 9), client.coils(9)
        # Play the operator once both zones show valid data: a new pair of set points every
        # OPERATOR_PERIOD s, written to the PLC's %MW0/%MW1 (OpenPLC: holding registers
        # 1024/1025); the example sends each new one to its instrument once.
        if t_op is None and coils[0] and coils[3]:
            t_op = time.monotonic()
        if t_op is not None and int((time.monotonic() - t_op) // OPERATOR_PERIOD) != step:
            step = int((time.monotonic() - t_op) // OPERATOR_PERIOD)
            sp = OPERATOR[step % len(OPERATOR)]
            client.write(1024, sp[0] * 10)
            client.write(1025, sp[1] * 10)
            note = (f"operator: set points {sp[0]} / {sp[1]} written to %MW0/%MW1 (Modbus HR "
                    f"1024/1025) at {time.monotonic() - t0:.0f} s; next in {OPERATOR_PERIOD} s")
        screen(hr, coils, sim_lines(sim), t0, title, where)
        print("\n" + note, flush=True)
        time.sleep(0.5)


if __name__ == "__main__":
    main()
