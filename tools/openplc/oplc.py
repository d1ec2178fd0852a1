"""Drive a scratch copy of OpenPLC v3: install plc_lib, compile with OpenPLC's own
compile_program.sh, run the runtime core, talk to its interactive server.

Used by the e2e tests and by demo.sh. The user's OpenPLC (OPENPLC_HOME) is only read: every
change happens in a copy under /tmp that close() removes. The runtime's Modbus TCP server binds
every interface, so start() refuses to run outside a private network namespace (netns.sh).
"""
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
INTERACTIVE_PORT = 43628  # fixed in OpenPLC's core/interactive_server.cpp
SKIP = 77


def openplc_home():
    """The OpenPLC v3 to copy, or None when it is not installed."""
    home = os.environ.get("OPENPLC_HOME") or "/opt/OpenPLC_v3"
    ok = all(os.path.exists(os.path.join(home, "webserver", p))
             for p in ("iec2c", "scripts/compile_program.sh", "core/glue_generator", "lib/ieclib.txt"))
    return home if ok else None


def in_private_netns():
    """True when the only network interface is loopback (we run under netns.sh)."""
    with open("/proc/net/dev") as f:
        names = [line.split(":")[0].strip() for line in f.readlines()[2:]]
    return names == ["lo"]


class CompileError(RuntimeError):
    pass


class Scratch:
    """A throw-away copy of an OpenPLC v3 installation (webserver/ and the snap7 wrapper that
    compile_program.sh copies in). Use as a context manager."""

    def __init__(self, home=None, keep=False):
        self.home = home or openplc_home()
        if not self.home:
            raise FileNotFoundError("OpenPLC v3 not found (set OPENPLC_HOME)")
        self.dir = tempfile.mkdtemp(prefix="openplc-scratch-")
        self.keep = keep
        shutil.copytree(os.path.join(self.home, "webserver"), os.path.join(self.dir, "webserver"),
                        symlinks=True, ignore=shutil.ignore_patterns(".git", "__pycache__"))
        wrapper = os.path.join("utils", "snap7_src", "wrapper")
        shutil.copytree(os.path.join(self.home, wrapper), os.path.join(self.dir, wrapper), symlinks=True)
        self.web = os.path.join(self.dir, "webserver")
        self.proc = None
        self.log = None
        self.isock = None             # the one connection to the interactive server (start)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def run_script(self, script, *args):
        """Run one of plc_lib's scripts on this copy; returns its output."""
        r = subprocess.run([os.path.join(ROOT, "plc_lib", script), *args, self.dir],
                           capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(f"{script} failed:\n{r.stdout}{r.stderr}")
        return r.stdout

    def install(self, dist=None):
        return self.run_script("install.sh", *(["--dist", dist] if dist else []))

    def uninstall(self):
        return self.run_script("uninstall.sh")

    def compile(self, st_path, name="program.st"):
        """Compile an ST program exactly as OpenPLC does (scripts/compile_program.sh)."""
        dst = os.path.join(self.web, "st_files", name)
        if os.path.abspath(st_path) != os.path.abspath(dst):
            shutil.copyfile(st_path, dst)
        r = subprocess.run(["./scripts/compile_program.sh", name], cwd=self.web,
                           capture_output=True, text=True)
        out = r.stdout + r.stderr
        if r.returncode or "Compilation finished successfully" not in out:
            raise CompileError(f"compile_program.sh {name} failed:\n{out}")
        return out

    def start(self, modbus_port=None, timeout=10.0):
        """Start core/openplc (from webserver/, as OpenPLC does) and, if asked, its Modbus TCP
        server on modbus_port. Returns once the interactive server answers."""
        if not in_private_netns():
            raise RuntimeError("refusing to start the OpenPLC runtime outside a private network "
                               "namespace (its servers bind every interface): run under tools/openplc/netns.sh")
        self.log = open(os.path.join(self.dir, "runtime.log"), "w+")
        # stdbuf: its printf lines reach the log as they are written, also when it dies
        self.proc = subprocess.Popen(["stdbuf", "-oL", "./core/openplc"], cwd=self.web, stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=_die_with_parent)
        # One connection to the interactive server for every command: the runtime hands each
        # accepted client's fd to its thread through one stack variable (interactive_server.cpp,
        # startInteractiveServer; server.cpp's startServer alike), so two clients accepted close
        # together can both be served on the second's fd, and the thread that finds it closed
        # closes it again, by then perhaps the Modbus server's listening socket (seen: "Server:
        # Listening on port 5502", then every connection refused). No probe connections either.
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.isock = socket.create_connection(("127.0.0.1", INTERACTIVE_PORT), timeout=1)
                break
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("OpenPLC runtime did not start:\n" + self.runtime_log())
                time.sleep(0.1)
        if modbus_port:
            # Its log says when the Modbus server listens. A command sent right after the
            # interactive server starts listening may be dropped, and a second start_modbus
            # stops the server the first one is starting: ask again only while the log shows
            # no start_modbus taken.
            taken = f"Issued start_modbus() command to start on port: {modbus_port}"
            listening = f"Server: Listening on port {modbus_port}"
            deadline = time.monotonic() + timeout
            self.command(f"start_modbus({modbus_port})")
            while True:
                log = self.logs()
                if listening in log:
                    return
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"Modbus server not up on {modbus_port}:\n" + self.runtime_log())
                if taken not in log:
                    self.command(f"start_modbus({modbus_port})")
                time.sleep(0.2)

    def command(self, cmd, wait=0.5):
        """Send one command to the runtime's interactive server (interactive_server.cpp) on the
        one connection start() opened; returns what it answers within `wait` s of silence."""
        self.isock.sendall(cmd.encode() + b"\n")
        self.isock.settimeout(wait)
        out = b""
        try:
            while chunk := self.isock.recv(65536):
                out += chunk
        except socket.timeout:
            pass
        return out.decode(errors="replace")

    def logs(self):
        """The runtime's own log buffer (its runtime_logs() command)."""
        return self.command("runtime_logs()", wait=0.3)

    def runtime_log(self):
        if not self.log:
            return ""
        self.log.flush()
        with open(self.log.name) as f:
            return f.read()

    def stop(self):
        """Stop the runtime we started: quit() first, then SIGKILL by pid."""
        if self.proc and self.proc.poll() is None:
            try:
                if self.isock is not None:    # the connection start() opened
                    self.command("quit()")
                    self.proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                pass
            if self.proc.poll() is None:
                os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        self.proc = None
        if self.isock:
            self.isock.close()
            self.isock = None

    def close(self):
        self.stop()
        if self.log:
            self.log.close()
            self.log = None
        if not self.keep:
            shutil.rmtree(self.dir, ignore_errors=True)


def _die_with_parent():
    """In the child: SIGKILL it if the process that started it dies without cleaning up."""
    import ctypes
    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def wait(pred, timeout, what):
    """pred()'s first truthy value, polled every 0.1 s; AssertionError after timeout seconds."""
    end = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout}s waiting for {what}")
        time.sleep(0.1)


def s16(v):
    """A Modbus register as a signed 16-bit value."""
    return v - 65536 if v >= 32768 else v


EXAMPLE_BUS = "/tmp/heat_treat_bus"  # BusPort of examples/heat_treat_*; tests point it elsewhere


def retarget(src, dst, bus_port):
    """Copy an example program to dst with its BusPort set to bus_port (the only change)."""
    with open(src) as f:
        text = f.read()
    old = f"'{EXAMPLE_BUS}'"
    assert text.count(old) == 1, f"{src}: expected one BusPort initialiser {old}"
    with open(dst, "w") as f:
        f.write(text.replace(old, f"'{bus_port}'"))
    return dst


# The example's devices on the simulated bus (examples/heat_treat_st/README.md).
# The FDC-100 is set to no parity (PARI=2) to share the MV-D94's 8N2 line.
EXAMPLE_DEVICES = ["fdc100:1:PARI=2,SP1=120.0", "mvd94:2:SV=100.0,DP=1", "mts9:3:rate=5",
                   "generic:4:file=" + os.path.join(ROOT, "examples", "heat_treat_st",
                                                    "energy_meter.json")]


class PlcClient:
    """pymodbus client of the runtime's Modbus TCP server. OpenPLC's server now and then leaves
    a request unanswered (seen with a blank program too, no mbfb code in it: about 1 in 100
    requests under a tight request loop), so a failed request is retried on a fresh connection;
    `retried` counts those."""

    def __init__(self, port, attempts=4):
        from pymodbus.client import ModbusTcpClient
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=1, retries=0)
        self.attempts = attempts
        self.retried = 0
        self.client.connect()

    def _call(self, fn, *args, **kw):
        from pymodbus.exceptions import ModbusException
        for attempt in range(self.attempts):
            try:
                r = fn(*args, **kw)
                if not r.isError():
                    return r
                err = r
            except ModbusException as e:
                err = e
            self.retried += 1
            self.client.close()
            self.client.connect()
        raise RuntimeError(f"Modbus request failed {self.attempts} times: {err}")

    def hr(self, addr, count=1):
        return self._call(self.client.read_holding_registers, addr, count=count).registers

    def coils(self, count=9):
        return self._call(self.client.read_coils, 0, count=count).bits[:count]

    def write(self, addr, value):
        self._call(self.client.write_register, addr, value)

    def write_coil(self, addr, value):
        self._call(self.client.write_coil, addr, value)

    def close(self):
        self.client.close()
