"""Run the heat-treat example against the simulator and show its live values until Ctrl-C
(what ./demo.sh runs). Two back ends, one screen:

  --backend openplc  the real OpenPLC v3 runtime (inside a private network namespace): a scratch
                     copy of OpenPLC gets plc_lib installed, compiles heat_treat_st.st with
                     OpenPLC's own compile_program.sh and runs its runtime core with the Modbus
                     TCP server on 127.0.0.1:5502; the screen reads it with pymodbus, as a SCADA.
  --backend runner   the project's own runner (tools/runner/fb_host.cpp, built by
                     CMake as heat_treat_st_runner; --runner-exe), where OpenPLC is missing: the
                     same scan loop, its located variables read from the snapshot file it writes
                     and set points written through its control socket, with OpenPLC's Modbus
                     map (tools/runner/runner.py).

Both run the program with BusPort pointed at the simulator's pty. The screen shows what the
PLC publishes next to what the simulator holds. Everything started here is stopped by pid on
exit; temp files and the scratch copy are removed.
"""
import argparse
import collections
import contextlib
import functools
import logging
import os
import re
import shutil
import signal
import struct
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
# The product the operator asks for (%MW2: 1 = A, 2 = B): B first, PRODUCT_FIRST s after both
# zones are valid, then A and B in turn every PRODUCT_PERIOD s.
PRODUCT_FIRST, PRODUCT_PERIOD = 20, 60
PRODUCT_NAME = {0: "-", 1: "A", 2: "B"}
DOWNLOADING = 0xFFFF
BUS_PORT_VAR = "CONFIG0.RES0.HEATTREAT.BUSPORT"  # the example's BusPort (its CONFIGURATION)
TREND_SECONDS = 180     # the trend shows the last 3 minutes
TREND_WIDTH, TREND_HEIGHT = 60, 8
# The energy meter (slave 4, examples/heat_treat_st/energy_meter.json): its power follows zone
# 1's heater output MV1 (a HEATER_W heater) on top of the line's BASE_W, at MAINS_V; the energy
# adds up in plant time (--time-scale). The PLC publishes its registers at HR 16..23 (REALs, low
# word first), its ErrorID at HR 24, its Valid at coil 9.
HEATER_W, BASE_W, MAINS_V = 6000.0, 400.0, 230.0
MODBUS_EXCEPTIONS = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                     4: "device failure", 5: "acknowledge", 6: "device busy"}


def s16(v):
    return v - 65536 if v >= 32768 else v


def real_cdab(lo, hi):
    """An IEEE 754 REAL from two registers, low word first (as the meter sends it)."""
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def error_table(path=os.path.join(ROOT, "c_shims", "include", "mbfb.h")):
    """ErrorID -> (short name, meaning), from the shims' header (the one error table)."""
    table = {}
    with open(path, encoding="utf-8") as f:
        for m in re.finditer(r"#define MBFB_E_(\w+)\s+(\d+)\s*/\*\s*(.*?)\s*(?:\*/|$)", f.read(), re.M):
            if m.group(1) != "EXCEPTION_BASE":
                table[int(m.group(2))] = (m.group(1).lower().replace("_", " "), m.group(3))
    return table


ERRORS = error_table()


def code_name(code):
    """A status code in words: 'E4 offline'."""
    if code in ERRORS:
        return f"E{code} {ERRORS[code][0]}"
    if 128 < code < 256:
        return f"E{code} device refused (Modbus exception {code - 128})"
    return f"E{code} (unknown code)"


def code_meaning(code):
    if code in ERRORS:
        return f"E{code} {ERRORS[code][0]}: {ERRORS[code][1]}"
    if 128 < code < 256:
        what = MODBUS_EXCEPTIONS.get(code - 128, "see the device manual")
        return f"E{code}: the device answered Modbus exception {code - 128} ({what})"
    return f"E{code}: not in c_shims/include/mbfb.h"


class Trend:
    """PV and SV of both zones over the last TREND_SECONDS, drawn as characters."""
    SERIES = (("o", "zone 1 PV"), ("-", "zone 1 SV"), ("*", "zone 2 PV"), ("=", "zone 2 SV"))

    def __init__(self):
        self.samples = collections.deque()

    def add(self, t, values):
        """values: one float (or None, no data) per SERIES."""
        self.samples.append((t, values))
        while self.samples and self.samples[0][0] < t - TREND_SECONDS:
            self.samples.popleft()

    def draw(self, now):
        cols = [[None] * len(self.SERIES) for _ in range(TREND_WIDTH)]
        for t, values in self.samples:
            c = int((t - (now - TREND_SECONDS)) / TREND_SECONDS * (TREND_WIDTH - 1))
            if 0 <= c < TREND_WIDTH:
                cols[c] = [v if v is not None else old for v, old in zip(values, cols[c])]
        seen = [v for col in cols for v in col if v is not None]
        legend = "   ".join(f"{ch} {name}" for ch, name in self.SERIES)
        head = f"trend, last {TREND_SECONDS // 60} min, °C:  {legend}"
        if not seen:
            return [head, "  (no values yet)"]
        lo, hi = min(seen), max(seen)
        if hi - lo < 10:
            mid = (hi + lo) / 2
            lo, hi = mid - 5, mid + 5
        grid = [[" "] * TREND_WIDTH for _ in range(TREND_HEIGHT)]
        # SV first, PV on top of it where they meet.
        for k in (1, 3, 0, 2):
            for c, col in enumerate(cols):
                if col[k] is not None:
                    r = round((hi - col[k]) / (hi - lo) * (TREND_HEIGHT - 1))
                    grid[r][c] = self.SERIES[k][0]
        out = [head]
        for r, row in enumerate(grid):
            label = f"{hi - r * (hi - lo) / (TREND_HEIGHT - 1):7.1f}" if r in (0, TREND_HEIGHT // 2, TREND_HEIGHT - 1) else ""
            out.append(f"{label:>7} |{''.join(row)}")
        out.append(f"{'':7} +{'-' * TREND_WIDTH}")
        out.append(f"{'':8}-{TREND_SECONDS // 60} min{'now':>{TREND_WIDTH - 6}}")
        return out


def screen(hr, coils, sim, t0, title, where, trend, note):
    z = [("Zone 1  FDC-100 #1", hr[0], hr[1], hr[2], coils[0], coils[1], coils[2]),
         ("Zone 2  MV-D94  #2", hr[3], hr[4], hr[5], coils[3], coils[4], coils[5])]
    codes = set()
    out = ["\033[H\033[2J",
           f"modbus-fb demo: the heat-treat line, live   (up {time.monotonic() - t0:.0f} s; Ctrl-C stops)",
           f"PLC: {title}", where, "",
           f"{'device':20}{'PV °C':>9}{'SV °C':>9}  {'status':26}alarm"]
    for name, pv, sv, err, valid, band, quiet in z:
        status = ("ok" if valid else "no data") + (f", {code_name(err)}" if err else "")
        codes.add(err)
        alarm = "QUIET" if quiet else ("OUT OF BAND" if band else "-")
        out.append(f"{name:20}{s16(pv) / 10:9.1f}{s16(sv) / 10:9.1f}  {status:26.26}{alarm}")
    status = ("ok" if coils[6] else "no data") + (f", {code_name(hr[7])}" if hr[7] else "")
    codes.add(hr[7])
    out.append(f"{'Parts   MT-S9   #3':20}{'count':>9}{hr[6]:9d}  {status:26.26}{'QUIET' if coils[7] else '-'}")
    status = ("ok" if coils[9] else "no data") + (f", {code_name(hr[24])}" if hr[24] else "")
    codes.add(hr[24])
    volts, amps, watts, kwh = (real_cdab(hr[i], hr[i + 1]) for i in (16, 18, 20, 22))
    out.append(f"{'Energy  meter   #4':20}{volts:7.1f} V{amps:7.2f} A"
               f"{watts / 1000:7.2f} kW{kwh:9.1f} kWh  {status}")
    sp = []
    for zone, st in ((1, hr[9]), (2, hr[10])):
        codes.add(st)
        sp.append(f"zone {zone} " + (code_name(st) if st else "ok"))
    rs = []
    for zone, st, field in ((1, hr[12], hr[14]), (2, hr[13], hr[15])):
        if st == DOWNLOADING:
            rs.append(f"zone {zone} downloading")
        else:
            codes.add(st)
            rs.append(f"zone {zone} " + ("held" if not st else f"{code_name(st)} (field {s16(field)})"))
    out += [f"set point requests: {'   '.join(sp)}",
            f"product: {PRODUCT_NAME.get(hr[11], hr[11]) if hr[11] else 'changing'}   recipes: {'   '.join(rs)}",
            f"any alarm: {'YES' if coils[8] else 'no'}    PLC scans: {hr[8]}", ""]
    out += trend.draw(time.monotonic())
    out += ["", "simulator (the instruments themselves):"] + ["  " + line for line in sim]
    out += ["", "codes now: " + ("none" if not codes - {0} else
                                 "; ".join(code_meaning(c) for c in sorted(codes - {0})))]
    out += ["legend: PV measured, SV set point (°C); count in parts; ok = the block's Valid;",
            "  the meter: read by MB_Poll (input registers 0..7), published as read, four REALs (CDAB);",
            "  alarms: OUT OF BAND = PV more than 10 °C from SV for 5 s, QUIET = no valid data",
            "  for 3 s; E<n> = the block's ErrorID (c_shims/include/mbfb.h, st_src/README.md)", "",
            note]
    sys.stdout.write("\n".join(out) + "\n")
    sys.stdout.flush()


def sim_lines(sim):
    try:
        z1 = [sim.ctl("get", addr=1, reg=r)["eng"] for r in ("PV", "SP1", "MV1")]
        z2 = sim.ctl("get", addr=2, reg="PV")["eng"], sim.ctl("get", addr=2, reg="SV")["eng"]
        n = sim.ctl("get", addr=3, reg="VALUE")["raw"]
        m = [sim.ctl("get", addr=4, reg=r)["eng"] for r in ("voltage", "current", "power", "energy")]
        return [f"FDC-100 PV {z1[0]:.1f} SP1 {z1[1]:.1f}   MV-D94 PV {z2[0]:.1f} SV {z2[1]:.1f}   "
                f"MT-S9 count {n}",
                f"meter {m[0]:.1f} V {m[1]:.2f} A {m[2] / 1000:.2f} kW {m[3]:.1f} kWh",
                f"(°C; the FDC-100's heater output MV1 {z1[2]:.1f} %; count in parts)"]
    except Exception as e:  # the display must not die on a control hiccup
        return [f"(simulator: {e})"]


class MeterPlant:
    """The energy meter's readings, played in the simulator: power from zone 1's heater output,
    current from power and voltage, energy added up in plant time."""

    def __init__(self, sim, time_scale):
        self.sim, self.scale, self.last, self.kwh = sim, time_scale, None, None

    def step(self):
        try:
            now = time.monotonic()
            if self.kwh is None:
                self.kwh = self.sim.ctl("get", addr=4, reg="energy")["eng"]
            mv1 = self.sim.ctl("get", addr=1, reg="MV1")["eng"]
            watts = BASE_W + HEATER_W * max(0.0, min(100.0, mv1)) / 100.0
            if self.last is not None:
                self.kwh += watts / 1000.0 * (now - self.last) * self.scale / 3600.0
            self.last = now
            for reg, value in (("voltage", MAINS_V), ("current", watts / MAINS_V),
                               ("power", watts), ("energy", self.kwh)):
                self.sim.ctl("set", addr=4, reg=reg, eng=value)
        except Exception:  # pylint: disable=broad-except  (the screen shows the simulator's state)
            pass


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
            yield client, f"the OpenPLC v3 runtime (core/openplc of {plc.home})", \
                f"runtime: scratch copy {plc.dir}, Modbus TCP 127.0.0.1:{PORT} (private netns)"
        finally:
            client.close()


@contextlib.contextmanager
def runner_backend(tmp, bus, exe):
    """The example in the project's own runner, read through its snapshot and control socket."""
    print(f"starting the runner {exe} ...", flush=True)
    home = oplc.openplc_home()
    why = (f"OpenPLC v3 at {home} not used: --runner" if home else
           "no OpenPLC v3 runtime installed")
    with Runner(exe, sets={BUS_PORT_VAR: bus}) as plc:
        yield plc, f"the project's own runner ({why})", \
            f"runner: pid {plc.proc.pid}, snapshot {plc.snapshot_path}"


def _stop(*_):
    raise KeyboardInterrupt


class Args(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (not argparse's usage block)
        sys.stderr.write(f"live.py: {message} (--help lists the options)\n")
        sys.exit(2)


def positive(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}")
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number > 0: {text!r}")
    return v


def non_negative(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}")
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number >= 0: {text!r}")
    return v


def main():
    ap = Args(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", choices=("openplc", "runner"), default="openplc")
    ap.add_argument("--runner-exe", help="the runner built from the example (heat_treat_st_runner)")
    ap.add_argument("--time-scale", type=positive, default=20.0,
                    help="simulated plant time per real second (default 20)")
    ap.add_argument("--seconds", type=non_negative, default=0, help="stop after this long (0 = Ctrl-C)")
    args = ap.parse_args()
    if args.backend == "runner" and not args.runner_exe:
        ap.error("--backend runner needs --runner-exe")
    # Nothing but the screen writes to the terminal: pymodbus logs its retries otherwise.
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL + 1)
    logging.getLogger("pymodbus").propagate = False
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
                show(client, sim, title, where, args.seconds, args.time_scale)
    except KeyboardInterrupt:
        pass
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print("\nstopped: PLC and simulator ended, temp files removed.")


def show(client, sim, title, where, seconds, time_scale=1.0):
    """The live screen every 0.5 s, playing the operator and the meter, until Ctrl-C or
    seconds."""
    t0 = time.monotonic()
    meter = MeterPlant(sim, time_scale)
    t_op, step, note = None, -1, "operator: waiting for both zones to be valid"
    product = 0
    trend = Trend()
    while not seconds or time.monotonic() - t0 < seconds:
        try:
            hr, coils = client.hr(0, 25), client.coils(10)
        except Exception as e:  # a PLC that stops answering is shown, not a traceback
            sys.stdout.write(f"\033[H\033[2J{title}: no answer ({e}); retrying\n")
            sys.stdout.flush()
            time.sleep(1)
            continue
        trend.add(time.monotonic(), [s16(hr[0]) / 10 if coils[0] else None, s16(hr[1]) / 10 if coils[0] else None,
                                     s16(hr[3]) / 10 if coils[3] else None, s16(hr[4]) / 10 if coils[3] else None])
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
            note = (f"operator: set points {sp[0]} / {sp[1]} °C written to %MW0/%MW1 (Modbus HR "
                    f"1024/1025) at {time.monotonic() - t0:.0f} s; next in {OPERATOR_PERIOD} s")
        # Play the product change: B, then A and B in turn (%MW2: holding register 1026); each
        # zone's recipe is downloaded (WriteSettings) and the screen shows how it went.
        if t_op is not None and time.monotonic() - t_op >= PRODUCT_FIRST:
            want = 2 if int((time.monotonic() - t_op - PRODUCT_FIRST) // PRODUCT_PERIOD) % 2 == 0 else 1
            if want != product:
                product = want
                client.write(1026, product)
        meter.step()
        screen(hr, coils, sim_lines(sim), t0, title, where, trend, note)
        time.sleep(0.5)


if __name__ == "__main__":
    main()
