#!/usr/bin/env python3
"""strucpp_runtime_v4 (labels strucpp, e2e): the heat-treat example in OpenPLC Runtime v4 itself.

plc_main is built from the runtime's source (OPENPLC_V4_HOME, default /opt/openplc-runtime);
the example (examples/heat_treat_st, its BusPort pointed at the simulator's pty) is compiled
as the Editor and the runtime do it (v4/program-build.mjs, then the runtime's make with
scripts/Makefile.strucpp and runtime_v4_entry.cpp, then scripts/compile-clean.sh's
libplc_<ns>.so) against the v4 package (target mbfb_v4); the daemon runs in private mount and
network namespaces (tools/openplc/rtv4.py) and is driven over its unix socket, the set points
through its DEBUG command (the Editor's debugger: force a variable). Then, CYCLES times:

  START   -> STATUS RUNNING; each instrument polled; the program's Z2SV equals the MV-D94's SV
             (read with DEBUG); a set point forced into %MW1 arrives at the MV-D94, written once;
  STOP    -> STATUS STOPPED; no frame on the line for QUIET s after that answer; PING answered;
             the daemon's threads and fds back to where they were after the first STOP, the
             program .so unmapped;

and a program rebuilt under a new file name (compile-clean.sh's rename) after the last STOP:
START -> the new program runs (DEBUG's MD5), one master on the line (the request rate within
1.5x of the first program's, no frame the simulator could not read). Finally SIGINT: the
daemon exits 0. Exit 77 = skipped with the reason (MBFB_REQUIRE_TOOLCHAIN=1: failure).
"""
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
import oplc  # noqa: E402
import rtv4  # noqa: E402
from simctl import Simulator  # noqa: E402

CYCLES = 5
QUIET = 1.2          # s of silence asked for after STOPPED (the bound is 1 s)
RATE_WINDOW = 3.0    # s of traffic counted for the one-master check
EXAMPLE = os.path.join(ROOT, "examples", "heat_treat_st", "heat_treat_st.st")
MVD94 = 2


def skip(reason):
    print(f"SKIP: {reason}")
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        print("MBFB_REQUIRE_TOOLCHAIN=1: a missing toolchain is a failure")
        sys.exit(1)
    sys.exit(77)


def fail(msg, daemon=None):
    if daemon is not None:
        print(daemon.log_text()[-4000:])
    print(f"FAIL: {msg}")
    sys.exit(1)


def wait(pred, timeout, what, daemon=None):
    """pred()'s first truthy value, polled every 50 ms; after timeout s, fail() naming what
    (with the daemon's log)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.05)
    fail(f"{what} (waited {timeout} s)", daemon)


def runtime_home(v4):
    """Runtime v4's source tree (rtv4.runtime_v4_home), once STruC++ and the v4 package are
    built in v4 and the runtime can be built; else skip() with the reason."""
    if os.environ.get("MBFB_STRUCPP_REASON"):
        skip(os.environ["MBFB_STRUCPP_REASON"])
    if not os.path.exists(os.path.join(v4, "strucpp", "dist", "index.js")) or \
            not os.path.exists(os.path.join(v4, "package", "mbfb", "library.properties")):
        skip(f"STruC++ or the v4 package is not built in {v4}: strucpp_build builds them and says why it could not")
    home = rtv4.runtime_v4_home()
    reason = rtv4.missing(home)
    if reason:
        skip(reason)
    return home


def plc_main(build_dir, home):
    """plc_main built from the runtime's source in the build tree (rtv4.build_plc_main);
    fail() when it does not build."""
    try:
        return rtv4.build_plc_main(home, os.path.join(build_dir, "v4", "openplc-runtime"))
    except RuntimeError as e:
        fail(str(e))


def translate(st, tmp):
    """The program for STruC++: translate.py's workarounds (v4/README.md, gap G1: the
    example's MB_LINE initialiser)."""
    out = os.path.join(tmp, "v4_" + os.path.basename(st))
    r = subprocess.run([sys.executable, os.path.join(ROOT, "v4", "translate.py"), "--mode", "external",
                        "--workarounds", "-o", out, st], capture_output=True, text=True)
    if r.returncode:
        fail(f"translate.py {st}: {r.stderr}")
    return out


def compile_program(rt, v4, st, tmp):
    """ST -> core/generated (program-build.mjs) -> the runtime's make (build/new_libplc.so)."""
    t = time.monotonic()
    try:
        rtv4.program_build(os.path.join(v4, "strucpp"), os.path.join(v4, "package"),
                           [translate(st, tmp)], rt.generated)
        rt.compile()
    except RuntimeError as e:
        fail(str(e))
    print(f"compiled {os.path.basename(st)} in {time.monotonic() - t:.1f} s")


def fc06(frames, slave):
    out = []
    for f in frames:
        b = bytes.fromhex(f["hex"])
        if f["dir"] == "rx" and len(b) >= 6 and b[0] == slave and b[1] == 6:
            out.append(int.from_bytes(b[4:6], "big"))
    return out


def main():
    build_dir, v4 = sys.argv[1], sys.argv[2]
    home = runtime_home(v4)
    print(f"Runtime v4: {home} {rtv4.version(home)}; Makefile.strucpp "
          f"{'with' if rtv4.has_libraries_support(home) else 'without (v4/libraries.mk added)'} libraries/ support")
    exe = plc_main(build_dir, home)

    tmp = tempfile.mkdtemp(prefix="mbfb-rtv4-")
    try:
        run(exe, home, v4, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run(exe, home, v4, tmp):
    bus = os.path.join(tmp, "bus")
    st1 = oplc.retarget(EXAMPLE, os.path.join(tmp, "heat_treat_st.st"), bus)
    rt = rtv4.RuntimeRoot(home, os.path.join(tmp, "runtime"))
    compile_program(rt, v4, st1, tmp)
    lib = rt.install()
    dmap = rtv4.DebugMap(os.path.join(rt.generated, "debug-map.json"))
    z2sv, z2valid, z2req = (dmap.find(p) for p in ("HEATTREAT.Z2SV", "HEATTREAT.ZONE2.VALID", "HEATTREAT.Z2SPREQ"))

    with Simulator(oplc.EXAMPLE_DEVICES, link=bus, time_scale=30.0, seed=1) as sim:
        daemon = rtv4.Daemon(exe, rt)
        try:
            cycles(daemon, sim, lib, (z2sv, z2valid, z2req))
            rebuilt(daemon, sim, rt, v4, st1, tmp, lib)
        except (RuntimeError, TimeoutError) as e:
            fail(str(e), daemon)
        finally:
            code = daemon.stop()
        if code != 0:
            fail(f"plc_main exited {code} on SIGINT (signal {-code if code < 0 else 0})", daemon)
        print("SIGINT: plc_main exited 0")
    print(f"PASS: {CYCLES} Stop/Start cycles and a rebuilt program in Runtime v4")


def running(daemon, sim, leaves, setpoint, frames):
    """After START: traffic to each instrument, Z2SV = the MV-D94's SV, the set point written once."""
    z2sv, z2valid, z2req = leaves
    daemon.wait_status("RUNNING", 30)

    def heard_all():
        frames.extend(sim.log(clear=True))
        heard = {bytes.fromhex(f["hex"])[0] for f in frames if f["dir"] == "rx"}
        return {1, 2, 3} <= heard
    wait(heard_all, 15, "no request to each of the 3 instruments after START", daemon)
    wait(lambda: rtv4.read(daemon, z2valid) == b"\x01", 15, "Zone2.Valid never TRUE", daemon)
    sv = sim.ctl("get", addr=MVD94, reg="SV")["raw"]
    got = int.from_bytes(rtv4.read(daemon, z2sv), "little", signed=True)
    if got != sv:
        fail(f"Z2SV {got} in the program, SV {sv} in the MV-D94", daemon)
    rtv4.force(daemon, z2req, setpoint.to_bytes(2, "little", signed=True))
    wait(lambda: sim.ctl("get", addr=MVD94, reg="SV")["raw"] == setpoint, 15,
         f"set point {setpoint} never reached the MV-D94", daemon)
    time.sleep(1.0)   # a doubled write would come within the next scans
    frames.extend(sim.log(clear=True))
    writes = [v for v in fc06(frames, MVD94) if v == setpoint]
    if len(writes) != 1:
        fail(f"set point {setpoint} written {len(writes)} times", daemon)
    return sv


def stopped(daemon, sim, lib):
    """STOP -> STOPPED; then QUIET s without a frame; PING; the .so unmapped. Returns (s from
    STOP to STOPPED, threads, fds)."""
    reply = daemon.command("STOP")
    if reply != "STOP:OK":
        fail(f"STOP answered {reply}", daemon)
    t_cmd = time.monotonic()
    t_stopped = daemon.wait_status("STOPPED", 30)
    rx0 = sim.ctl("stats")["line"]["rx_frames"]
    time.sleep(QUIET)
    rx1 = sim.ctl("stats")["line"]["rx_frames"]
    if rx1 != rx0:
        late = [f for f in sim.log(clear=True) if f["dir"] == "rx"]
        fail(f"{rx1 - rx0} frame(s) on the line within {QUIET} s of STOPPED: {late[-3:]}", daemon)
    sim.log(clear=True)
    if daemon.command("PING") != "PING:OK":
        fail("no PING:OK after STOP", daemon)
    if daemon.mapped(lib):
        fail(f"{lib} still mapped after STOP (dlclose did not unmap it)", daemon)
    # (daemon.command returns once the daemon has closed that connection too)
    return t_stopped - t_cmd, daemon.threads(), daemon.fds()


def cycles(daemon, sim, lib, leaves):
    base = None
    for i in range(CYCLES):
        if i:
            reply = daemon.command("START")
            if reply != "START:OK":
                fail(f"START answered {reply} (cycle {i + 1})", daemon)
        # (the daemon starts the program itself when it starts)
        frames = []
        setpoint = 1100 + 10 * i
        sv = running(daemon, sim, leaves, setpoint, frames)
        stop_s, threads, fds = stopped(daemon, sim, lib)
        if base is None:
            base = (threads, fds)
        # the connection of the last command may still be open in the daemon: a leak stays
        end = time.monotonic() + 2.0
        while (threads, fds) != base and time.monotonic() < end:
            time.sleep(0.1)
            threads, fds = daemon.threads(), daemon.fds()
        if (threads, fds) != base:
            fail(f"cycle {i + 1}: threads {threads}, fds {fds} after STOP; {base[0]}, {base[1]} after the first", daemon)
        print(f"cycle {i + 1}: RUNNING, 3 instruments polled, Z2SV = SV = {sv}, set point {setpoint} "
              f"written once; STOP -> STOPPED in {stop_s:.2f} s, {QUIET} s silent, PING ok, "
              f"threads {threads}, fds {len(fds)}, {lib} unmapped")


def rate(sim):
    """rx frames per second over RATE_WINDOW once all zones are valid."""
    sim.log(clear=True)
    a = sim.ctl("stats")["line"]["rx_frames"]
    time.sleep(RATE_WINDOW)
    b = sim.ctl("stats")["line"]["rx_frames"]
    return (b - a) / RATE_WINDOW


def rebuilt(daemon, sim, rt, v4, st1, tmp, lib1):
    """A program rebuilt (a changed constant) under a new file name: one master on the line."""
    md5_1 = open(os.path.join(rt.generated, "defines.h")).read().split('"')[1]
    # the first program's request rate, for comparison: START it once more
    if daemon.command("START") != "START:OK":
        fail("START refused", daemon)
    daemon.wait_status("RUNNING", 30)
    wait(lambda: len([f for f in sim.log(clear=True) if f["dir"] == "rx"]) > 0, 15, "no traffic", daemon)
    time.sleep(2.0)
    r1 = rate(sim)
    bad0 = sim.ctl("stats")["line"]["bad_frames"]
    st2 = os.path.join(tmp, "heat_treat_st_2.st")
    text = open(st1).read()
    assert text.count("Band : REAL := 10.0;") == 1
    open(st2, "w").write(text.replace("Band : REAL := 10.0;", "Band : REAL := 12.0;"))
    # the runtime's order: build while running, STOP, compile-clean.sh, START
    compile_program(rt, v4, st2, tmp)
    stopped(daemon, sim, lib1)
    lib2 = rt.install()
    if lib2 == lib1:
        fail("compile-clean.sh gave the rebuilt program the old name")
    if daemon.command("START") != "START:OK":
        fail("START of the rebuilt program refused", daemon)
    daemon.wait_status("RUNNING", 30)
    md5 = daemon.debug(bytes([0x45, 0xDE, 0xAD]))   # FC 0x45 with its 2 probe bytes
    md5_2 = open(os.path.join(rt.generated, "defines.h")).read().split('"')[1]
    if md5_2 == md5_1 or md5_2.encode() not in md5:
        fail(f"DEBUG MD5 {md5!r}: not the rebuilt program's {md5_2} (the first's {md5_1})", daemon)
    if not daemon.mapped(lib2) or daemon.mapped(lib1):
        fail(f"mapped: {lib2} {daemon.mapped(lib2)}, {lib1} {daemon.mapped(lib1)}", daemon)
    wait(lambda: len([f for f in sim.log(clear=True) if f["dir"] == "rx"]) > 0, 15, "no traffic", daemon)
    time.sleep(2.0)
    r2 = rate(sim)
    bad = sim.ctl("stats")["line"]["bad_frames"] - bad0
    if r2 > 1.5 * r1 or bad:
        fail(f"two masters? {r2:.1f} requests/s with {lib2} against {r1:.1f} with {lib1}, "
             f"{bad} unreadable frames", daemon)
    print(f"rebuilt program {lib2} (md5 {md5_2}): {r2:.1f} requests/s against {r1:.1f} before, "
          f"0 unreadable frames, {lib1} unmapped")
    stopped(daemon, sim, lib2)



if __name__ == "__main__":
    main()
