"""The quick start without OpenPLC's runtime: ./demo.sh in runner mode, run as a person would.

Two toolchains (argument):
  home    (fb_demo_runner) a matiec-only MATIEC_HOME: the MATIEC_HOME you have, or one laid
          out in a temp dir from OpenPLC's files (iec2c, lib/*.txt, lib/C/*.h as symlinks),
          or the matiec the build made from source (MBFB_MATIEC_BUILD, set by ctest);
  source  (fb_demo_source) the embedded default without network: no MATIEC_HOME, no iec2c on
          PATH, and matiec given only as a source tree (MATIEC_SOURCE_DIR, else OpenPLC's own
          $OPENPLC_HOME/utils/matiec_src), which the build copies and builds into its own tree.
In both, OPENPLC_HOME points nowhere and `demo.sh --build-dir TMP/build` must build the
example's runner with CMake (and matiec, in source mode), start the simulator and show the
live screen. The screen is read while it runs; once it showed what is checked below (or after a
deadline), the demo gets SIGINT as from Ctrl-C in a terminal, and must end, with the runner
gone and its temp files removed. Checked on the screen:
- the PLC's PV of each zone is near the simulator's PV shown beside it (simulator control
  'get'), the part count increases and never passes the simulator's count;
- the operator's set point requests (130 / 110, written to %MW0/%MW1 through the runner's
  control socket) reach the simulated instruments: the simulator's SP1/SV change from their
  start values 120 / 100, and the PLC reads the new SVs back;
- the operator's product change (B, %MW2) is downloaded to both zones (WriteSettings): the
  screen shows both recipes held and the simulator has product B's set points (165 / 145);
- the units, the status words and the trend are on the screen.
Exit 0 pass, 1 fail, 77 skipped with the reason (no matiec, a MATIEC_HOME without iec2c, no
local matiec source; 1 with MBFB_REQUIRE_TOOLCHAIN=1).
"""
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SKIP = 77
BUILD_TIMEOUT = 480     # s, configure + build of the runner in a fresh build dir
WATCH_TIMEOUT = 120     # s after the first screen, for everything below to show
CLEAR = "\033[H\033[2J"
ZONE = re.compile(r"^Zone ([12]) .{12}\s*(-?\d+\.\d)\s+(-?\d+\.\d)\s+(ok|no data)", re.M)
PARTS = re.compile(r"^Parts .*count\s+(\d+)\s+(ok|no data)", re.M)
SIM = re.compile(r"FDC-100 PV (-?[\d.]+) SP1 (-?[\d.]+)\s+MV-D94 PV (-?[\d.]+) SV (-?[\d.]+)"
                 r"\s+MT-S9 count (\d+)")
SCANS = re.compile(r"PLC scans: (\d+)")
METER = re.compile(r"^Energy  meter   #4\s+(-?[\d.]+) V\s*(-?[\d.]+) A\s*(-?[\d.]+) kW\s*"
                   r"(-?[\d.]+) kWh  (ok|no data)", re.M)
SIM_METER = re.compile(r"^\s*meter ([\d.]+) V ([\d.]+) A ([\d.]+) kW ([\d.]+) kWh", re.M)
PRODUCT = re.compile(r"^product: (\S+)\s+recipes: zone 1 (.+?)\s{3}zone 2 (.+?)\s*$", re.M)
WINDOW = 3          # screens back in which the PLC's value must have been the simulator's
PV_TOL = 1.0        # degrees
MIN_SCREENS = 20    # screens with every device valid, at least


def skip(reason):
    print(f"SKIP: {reason}")
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        print("MBFB_REQUIRE_TOOLCHAIN=1: a missing toolchain is a failure")
        sys.exit(1)
    sys.exit(SKIP)


def matiec_home(tmp):
    """MATIEC_HOME if set (and holding iec2c), else a matiec layout made of OpenPLC's files."""
    home = os.environ.get("MATIEC_HOME")
    if home:
        missing = [p for p in ("iec2c", "lib/ieclib.txt") if not os.path.exists(os.path.join(home, p))]
        if missing:
            skip(f"MATIEC_HOME={home} is not a matiec build (no {', '.join(missing)}); "
                 "unset it to use OpenPLC's iec2c")
        return home
    oplc = os.environ.get("OPENPLC_HOME") or "/opt/OpenPLC_v3"
    web = os.path.join(oplc, "webserver")
    if not all(os.path.exists(os.path.join(web, p))
               for p in ("iec2c", "lib/ieclib.txt", "core/lib/iec_std_lib.h")):
        # the matiec the build made from source (tools/matiec), a matiec build like any other
        built = os.environ.get("MBFB_MATIEC_BUILD")
        if built and os.path.exists(os.path.join(built, "iec2c")):
            return built
        skip(f"no matiec: MATIEC_HOME unset, no OpenPLC v3 at {oplc} to take iec2c from, "
             "and the build made none from source")
    view = os.path.join(tmp, "matiec")
    os.makedirs(os.path.join(view, "lib"))
    os.symlink(os.path.join(web, "iec2c"), os.path.join(view, "iec2c"))
    for name in os.listdir(os.path.join(web, "lib")):
        os.symlink(os.path.join(web, "lib", name), os.path.join(view, "lib", name))
    os.symlink(os.path.join(web, "core", "lib"), os.path.join(view, "lib", "C"))
    return view


def matiec_source():
    """A local matiec source tree: MATIEC_SOURCE_DIR, else OpenPLC's utils/matiec_src."""
    src = os.environ.get("MATIEC_SOURCE_DIR")
    if src:
        if not all(os.path.exists(os.path.join(src, p)) for p in ("configure.ac", "lib/ieclib.txt")):
            skip(f"MATIEC_SOURCE_DIR={src} is not a matiec source tree (configure.ac, lib/ieclib.txt)")
        return src
    oplc = os.environ.get("OPENPLC_HOME") or "/opt/OpenPLC_v3"
    src = os.path.join(oplc, "utils", "matiec_src")
    if not all(os.path.exists(os.path.join(src, p)) for p in ("configure.ac", "lib/ieclib.txt")):
        skip(f"no local matiec source: MATIEC_SOURCE_DIR unset and no {src} (OpenPLC v3's copy); "
             "this test builds matiec without network")
    return src


def path_without_iec2c():
    return os.pathsep.join(d for d in os.environ.get("PATH", "").split(os.pathsep)
                           if d and not os.path.exists(os.path.join(d, "iec2c")))


def frames(text):
    """Each complete screen as a dict of what it shows."""
    out = []
    for f in text.split(CLEAR)[1:-1]:  # the last one may still be being written
        zones = {int(z): (float(pv), float(sv), st == "ok") for z, pv, sv, st in ZONE.findall(f)}
        parts, sim, scans = PARTS.search(f), SIM.search(f), SCANS.search(f)
        product = PRODUCT.search(f)
        meter, sim_meter = METER.search(f), SIM_METER.search(f)
        if len(zones) == 2 and parts and sim and scans:
            out.append({"zones": zones, "count": int(parts.group(1)), "parts_ok": parts.group(2) == "ok",
                        "sim": [float(x) for x in sim.groups()], "scans": int(scans.group(1)),
                        "product": product.groups() if product else None,
                        "meter": ([float(x) for x in meter.groups()[:4]] + [meter.group(5) == "ok"]
                                  if meter else None),
                        "sim_meter": [float(x) for x in sim_meter.groups()] if sim_meter else None})
    return out


def seen(fs):
    """What the screens showed so far: name -> bool."""
    valid = [f for f in fs if all(z[2] for z in f["zones"].values()) and f["parts_ok"]]
    return {
        f"{MIN_SCREENS} screens with all devices valid": len(valid) >= MIN_SCREENS + WINDOW,
        "simulator starts at SP1 120 / SV 100": bool(fs) and fs[0]["sim"][1] == 120.0
        and fs[0]["sim"][3] == 100.0,
        "set points reached the instruments": any(f["sim"][1] == 130.0 and f["sim"][3] == 110.0
                                                  for f in fs),
        "PLC reads the new SVs back": any(f["zones"][1][1] == 130.0 and f["zones"][2][1] == 110.0
                                          for f in valid),
        "part count increased": len(valid) >= 2 and valid[-1]["count"] > valid[0]["count"],
        # the operator's product B (%MW2): both zones' recipes held, the simulator at B's set
        # points (SP1 165 / SV 145: the example's product B)
        "product B held on both zones": any(f["product"] == ("B", "held", "held") for f in fs),
        "product B's set points on the instruments": any(f["sim"][1] == 165.0 and f["sim"][3] == 145.0
                                                         for f in fs),
        # the energy meter (MB_Poll + MB_TO_REAL): valid, at the simulator's voltage, and its
        # energy (played from zone 1's heater) rising on the PLC's side
        "meter valid at the simulator's voltage": any(
            f["meter"] and f["meter"][4] and f["sim_meter"] and f["meter"][0] == f["sim_meter"][0]
            for f in fs),
        "meter energy increased": len(meters := [f["meter"] for f in fs if f["meter"] and f["meter"][4]]) >= 2
        and meters[-1][3] > meters[0][3],
    }


def check(fs):
    """Assertions over every screen; returns the list of failures."""
    bad = []
    valid = [f for f in fs if all(z[2] for z in f["zones"].values()) and f["parts_ok"]]
    for name, ok in seen(fs).items():
        if not ok:
            bad.append(f"never seen: {name}")
    # PV and count: what the PLC shows must be a value the simulator had a moment before. The
    # PLC polls every 500 ms and its screen values are read just before the simulator's, which
    # are ramping at time scale 20; screens are >= 0.5 s apart. So the PLC's value must lie
    # within the simulator's values of the same screen and the WINDOW screens before it
    # (>= 1.5 s), +- PV_TOL for the simulator's noise and the 0.1 rounding.
    checked = 0
    for i, f in enumerate(fs):
        if f not in valid or i < WINDOW:
            continue
        checked += 1
        window = fs[i - WINDOW:i + 1]
        for zone, col in ((1, 0), (2, 2)):
            sims = [w["sim"][col] for w in window]
            if not min(sims) - PV_TOL <= f["zones"][zone][0] <= max(sims) + PV_TOL:
                bad.append(f"screen {i}: zone {zone} PV {f['zones'][zone][0]} not among the "
                           f"simulator's recent PVs {sims}")
        counts = [w["sim"][4] for w in window]
        if not min(counts) <= f["count"] <= max(counts):
            bad.append(f"screen {i}: part count {f['count']} not among the simulator's recent {counts}")
    print(f"PV and count checked against the simulator on {checked} screens")
    if checked < MIN_SCREENS:
        bad.append(f"only {checked} screens with all devices valid (want {MIN_SCREENS})")
    counts = [f["count"] for f in valid]
    if any(b < a for a, b in zip(counts, counts[1:])):
        bad.append(f"part count went backwards: {counts}")
    scans = [f["scans"] for f in fs]
    if len(scans) < 2 or scans[-1] <= scans[0]:
        bad.append(f"PLC scans did not advance: {scans[:3]}..{scans[-3:]}")
    return bad


def main():
    mode = sys.argv[1] if len(sys.argv) > 1 else "home"
    if mode not in ("home", "source"):
        print(f"usage: {sys.argv[0]} [home|source]", file=sys.stderr)
        return 2
    tmp = tempfile.mkdtemp(prefix="fbtest-demo-")
    out_path = os.path.join(tmp, "screen.txt")
    proc = None
    try:
        env = dict(os.environ, OPENPLC_HOME=os.path.join(tmp, "no-openplc"))
        if mode == "home":
            env["MATIEC_HOME"] = matiec_home(tmp)
            lib = env["MATIEC_HOME"]
        else:
            env.pop("MATIEC_HOME", None)
            env.update(MATIEC_SOURCE_DIR=matiec_source(), MBFB_FETCH_MATIEC="OFF",
                       PATH=path_without_iec2c())
            lib = os.path.join(tmp, "build", "_matiec", "src")
        for k in ("MATIEC_HOME", "MATIEC_SOURCE_DIR", "OPENPLC_HOME"):
            print(f"{k}={env.get(k, '(unset)')}")
        with open(out_path, "w") as out:
            # Its own session: SIGINT to its process group is Ctrl-C in a terminal.
            proc = subprocess.Popen([os.path.join(ROOT, "demo.sh"), "--build-dir", os.path.join(tmp, "build"),
                                     "--time-scale", "20"], stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, env=env, start_new_session=True)
        start, first = time.monotonic(), None
        while True:
            time.sleep(0.5)
            with open(out_path, errors="replace") as f:
                text = f.read()
            fs = frames(text)
            if proc.poll() is not None:
                break
            if fs and first is None:
                first = time.monotonic()
                print(f"first screen {first - start:.0f} s after start (build included)")
            if first is None and time.monotonic() - start > BUILD_TIMEOUT:
                break
            if first is not None and (all(seen(fs).values()) or time.monotonic() - first > WATCH_TIMEOUT):
                break
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                print("FAIL: demo.sh still running 30 s after Ctrl-C")
        with open(out_path, errors="replace") as f:
            text = f.read()
        fs = frames(text)
        print(f"{len(fs)} screens; the last one:\n{text.split(CLEAR)[-1] if CLEAR in text else text[-4000:]}")
        bad = [] if fs else ["no screen was shown"]
        bad += check(fs) if fs else []
        if proc.returncode != 0:
            bad.append(f"demo.sh exited {proc.returncode}")
        if f"fb: matiec library {lib}/lib, C headers {lib}/lib/C" not in text:
            bad.append(f"the build did not use the matiec of {lib}")
        if mode == "source" and f"-- toolchain: matiec built from MATIEC_SOURCE_DIR={env['MATIEC_SOURCE_DIR']}" not in text:
            bad.append("the configure summary does not say matiec was built from the source tree")
        last = text.split(CLEAR)[-2] if text.count(CLEAR) >= 2 else ""
        for what in ("PV °C", "SV °C", "count in parts", "heater output MV1", "trend, last 3 min",
                     "codes now:", "legend:"):
            if what not in last:
                bad.append(f"the screen does not show {what!r}")
        if not re.search(r"^ *(?:-?\d+\.\d)? *\|[^\n]*[o*]", last, re.M):
            bad.append("the trend has no PV point")
        if "the project's own runner" not in text:
            bad.append("the screen does not name the runner")
        if "stopped: PLC and simulator ended" not in text:
            bad.append("no clean stop message after Ctrl-C")
        pids = [int(p) for p in re.findall(r"runner: pid (\d+)", text)]
        if pids and os.path.exists(f"/proc/{pids[-1]}"):
            bad.append(f"runner pid {pids[-1]} still running after the demo ended")
        temp = re.escape(tempfile.gettempdir())
        for path in set(re.findall(temp + r"/mbfb-(?:demo|runner)-[^/\s]+", text)):
            if os.path.exists(path):
                bad.append(f"temp dir left behind: {path}")
        for b in bad:
            print(f"FAIL: {b}")
        if bad:
            print(f"--- demo output (head) ---\n{text[:3000]}")
        return 1 if bad else 0
    finally:
        if proc is not None and proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
