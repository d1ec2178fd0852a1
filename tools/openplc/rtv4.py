"""Drive OpenPLC Runtime v4 from its source: build its daemon (plc_main), build a program .so
the way the runtime does (scripts/compile.sh's make, scripts/compile-clean.sh's rename), run
the daemon and talk to it over its unix socket (START, STOP, STATUS, PING, DEBUG:...).

The runtime's source is only read: OPENPLC_V4_HOME (default /opt/openplc-runtime), a clone of
the runtime's git repository. plc_main is built out of tree; each program is built in a scratch
runtime root (core/generated/ of its own, the rest linked to the source).

plc_main's socket path is a constant of its source (/run/runtime/plc_runtime.socket,
core/src/plc_app/unix_socket.h; its log socket beside it), so the daemon runs in a private
mount namespace whose /run/runtime is a folder of the scratch root (the socket appears there
for the host), and in a private network namespace (its plugins open TCP servers on every
interface). Both need root (CAP_SYS_ADMIN).
"""
import fcntl
import glob
import os
import shutil
import signal
import socket
import subprocess
import threading
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
V4 = os.path.join(ROOT, "v4")
DEFAULT_HOME = "/opt/openplc-runtime"
SOCKET_NAME = "plc_runtime.socket"
LOG_SOCKET_NAME = "log_runtime.socket"   # the daemon's log goes there (the web server listens)


def runtime_v4_home():
    return os.environ.get("OPENPLC_V4_HOME") or DEFAULT_HOME


def missing(home):
    """Why Runtime v4 cannot be built from `home`, or '' when it can."""
    need = ["CMakeLists.txt", "core/src/plc_app/plc_main.c", "core/src/plc_app/unix_socket.h",
            "core/strucpp_runtime/runtime_v4_entry.cpp", "scripts/Makefile.strucpp",
            "scripts/compile.sh", "scripts/compile-clean.sh"]
    gone = [n for n in need if not os.path.exists(os.path.join(home, n))]
    if gone:
        return (f"OpenPLC Runtime v4 source not found at {home} (OPENPLC_V4_HOME; missing "
                f"{', '.join(gone[:3])})")
    if subprocess.run(["pkg-config", "--exists", "python3-embed"]).returncode:
        return "plc_main needs python3-embed (Debian: python3-dev; .ci/apt-packages.txt)"
    with open(os.path.join(home, "core/src/plc_app/unix_socket.h")) as f:
        if "/run/runtime/" + SOCKET_NAME not in f.read():
            return "this runtime's socket is not /run/runtime/plc_runtime.socket (rtv4.py needs updating)"
    if subprocess.run(["unshare", "-m", "-n", "true"], capture_output=True).returncode:
        return "cannot create mount + network namespaces for the daemon (needs root / CAP_SYS_ADMIN)"
    return ""


def version(home):
    """The runtime's VERSION file and its git commit."""
    try:
        v = open(os.path.join(home, "VERSION")).read().strip()
    except OSError:
        v = "?"
    r = subprocess.run(["git", "-C", home, "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True)
    return f"{v} ({r.stdout.strip() or 'no git'})"


def has_libraries_support(home):
    """True when the runtime's Makefile.strucpp compiles core/generated/libraries/*/src."""
    with open(os.path.join(home, "scripts", "Makefile.strucpp")) as f:
        return "libraries" in f.read()


def _locked(path):
    f = open(path, "w")
    fcntl.flock(f, fcntl.LOCK_EX)
    return f


def build_plc_main(home, out_dir):
    """plc_main built out of tree in out_dir (cmake; incremental); returns its path."""
    os.makedirs(out_dir, exist_ok=True)
    with _locked(os.path.join(out_dir, ".lock")):
        exe = os.path.abspath(os.path.join(out_dir, "plc_main"))
        if not os.path.exists(os.path.join(out_dir, "CMakeCache.txt")):
            r = subprocess.run(["cmake", "-S", home, "-B", out_dir, "-DCMAKE_BUILD_TYPE=Release"],
                               capture_output=True, text=True)
            if r.returncode:
                raise RuntimeError(f"plc_main: cmake failed:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
        r = subprocess.run(["nice", "-n", "10", "cmake", "--build", out_dir, "--target", "plc_main", "-j2"],
                           capture_output=True, text=True)
        if r.returncode or not os.path.exists(exe):
            raise RuntimeError(f"plc_main did not build:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
        return exe


def program_build(strucpp_dir, package_dir, sources, gen_dir):
    """core/generated/ for `sources` (ST), as the Editor writes it (v4/program-build.mjs), with
    the package's library folder in core/generated/libraries/ (package_dir None: no library)."""
    shutil.rmtree(gen_dir, ignore_errors=True)
    lib = ["-L", package_dir] if package_dir else []
    r = subprocess.run(["node", os.path.join(V4, "program-build.mjs"), "--strucpp", strucpp_dir,
                        *lib, "-o", gen_dir, *sources], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"program-build.mjs failed:\n{r.stdout}{r.stderr}")
    for props in glob.glob(os.path.join(package_dir, "*", "library.properties")) if package_dir else []:
        d = os.path.dirname(props)
        shutil.copytree(d, os.path.join(gen_dir, "libraries", os.path.basename(d)))


def plugin_venv(home, plugin, venvs_dir, fetch=True):
    """The virtual environment of one of the runtime's Python plugins, as its
    scripts/manage_plugin_venvs.sh makes it (the plugin's requirements.txt from the package
    registry), in venvs_dir/<plugin>; made once (fetch=False: must exist). Returns its path."""
    venv = os.path.abspath(os.path.join(venvs_dir, plugin))
    req = os.path.join(home, "core/src/drivers/plugins/python", plugin, "requirements.txt")
    os.makedirs(venvs_dir, exist_ok=True)
    with _locked(os.path.join(venvs_dir, f".{plugin}.lock")):
        if not os.path.exists(os.path.join(venv, ".mbfb-done")):
            if not fetch:
                raise RuntimeError(f"{venv} not made: make it where the package registry is reachable "
                                   "(bench/compare.py does, outside the network namespace)")
            shutil.rmtree(venv, ignore_errors=True)
            for cmd in (["python3", "-m", "venv", venv],
                        [os.path.join(venv, "bin", "pip"), "install", "-q", "-r", req]):
                r = subprocess.run(cmd, capture_output=True, text=True)
                if r.returncode:
                    raise RuntimeError(f"{' '.join(cmd)}:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
            open(os.path.join(venv, ".mbfb-done"), "w").close()
    return venv


class RuntimeRoot:
    """A scratch runtime root: core/generated/ and build/ of its own, the runtime's sources
    (core/src, core/strucpp_runtime, scripts) linked from OPENPLC_V4_HOME."""

    def __init__(self, home, path):
        self.home = home
        self.dir = path = os.path.abspath(path)
        os.makedirs(os.path.join(path, "core"), exist_ok=True)
        for rel in ("core/src", "core/strucpp_runtime", "scripts"):
            dst = os.path.join(path, rel)
            if not os.path.lexists(dst):
                os.symlink(os.path.join(home, rel), dst)
        os.makedirs(os.path.join(path, "build"), exist_ok=True)
        self.rundir = os.path.join(path, "run")
        os.makedirs(self.rundir, exist_ok=True)
        # no plugins: an empty plugins.conf (else plc_main copies plugins_default.conf)
        conf = os.path.join(path, "plugins.conf")
        if not os.path.exists(conf):
            open(conf, "w").close()
        self.generated = os.path.join(path, "core", "generated")

    def plugin(self, name, path, config, venv=""):
        """Enable one of the runtime's plugins (path relative to OPENPLC_V4_HOME) in
        plugins.conf (name,path,enabled,type,config,venv; type 0 = Python)."""
        with open(os.path.join(self.dir, "plugins.conf"), "a") as f:
            f.write(f"{name},{os.path.join(self.home, path)},1,0,{config},{venv}\n")

    def compile(self, jobs=2):
        """Build core/generated/ into build/new_libplc.so as compile.sh does: make with the
        runtime's Makefile.strucpp, plus v4/libraries.mk where that Makefile has no libraries/
        support (runtimes before it); returns the make output."""
        cmd = ["nice", "-n", "10", "make", f"-j{jobs}", "-f", "scripts/Makefile.strucpp"]
        if not has_libraries_support(self.home):
            cmd += ["-f", os.path.join(V4, "libraries.mk")]
        env = {**os.environ, "CCACHE_DISABLE": "1"}
        r = subprocess.run(cmd, cwd=self.dir, capture_output=True, text=True, env=env)
        if r.returncode:
            raise RuntimeError(f"{' '.join(cmd[3:])} failed:\n{r.stdout[-4000:]}{r.stderr[-4000:]}")
        return r.stdout

    def install(self):
        """scripts/compile-clean.sh: the old libplc_*.so removed, build/new_libplc.so renamed
        to build/libplc_<ns>.so (what the runtime loads on the next START); returns its name."""
        r = subprocess.run(["bash", "scripts/compile-clean.sh"], cwd=self.dir, capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(f"compile-clean.sh failed:\n{r.stdout}{r.stderr}")
        libs = glob.glob(os.path.join(self.dir, "build", "libplc_*.so"))
        assert len(libs) == 1, libs
        return os.path.basename(libs[0])


class Daemon:
    """plc_main running in `root` (cwd), in private mount and network namespaces."""

    def __init__(self, plc_main, root, args=("--print-logs",)):
        self.root = root
        self.sock_path = os.path.join(root.rundir, SOCKET_NAME)
        for f in os.listdir(root.rundir):
            os.unlink(os.path.join(root.rundir, f))
        # a listener on the log socket, as the runtime's web server is: without one the daemon
        # opens and closes a socket every second trying to connect (its fd count would flicker)
        self.log_sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.log_sock.bind(os.path.join(root.rundir, LOG_SOCKET_NAME))
        self.log_sock.listen(4)
        self.log_lines = []
        threading.Thread(target=self._log_sink, daemon=True).start()
        self.log_path = os.path.join(root.dir, "plc_main.log")
        self.log = open(self.log_path, "wb")
        script = ('mount -t tmpfs -o size=1m,mode=755 mbfb-run /run && mkdir /run/runtime && '
                  'mount --bind "$1" /run/runtime && ip link set lo up && cd "$2" && shift 2 && exec "$@"')
        self.proc = subprocess.Popen(
            ["unshare", "-m", "-n", "--propagation", "private", "--", "sh", "-c", script, "rtv4",
             root.rundir, root.dir, "stdbuf", "-oL", "-eL", plc_main, *args],
            stdout=self.log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.pid = self.proc.pid   # unshare, sh and stdbuf exec: the pid is plc_main's
        end = time.monotonic() + 15
        while not os.path.exists(self.sock_path):
            if self.proc.poll() is not None:
                raise RuntimeError(f"plc_main exited ({self.proc.returncode}):\n{self.log_text()[-3000:]}")
            if time.monotonic() > end:
                self.stop()
                raise RuntimeError(f"plc_main: no socket after 15 s:\n{self.log_text()[-3000:]}")
            time.sleep(0.05)

    def _log_sink(self):
        while True:
            try:
                conn, _ = self.log_sock.accept()
            except OSError:
                return
            with conn:
                while True:
                    try:
                        data = conn.recv(65536)
                    except OSError:
                        break
                    if not data:
                        break
                    self.log_lines.append(data)

    def exit_text(self):
        code = self.proc.poll()
        if code is None:
            return "plc_main is running"
        return f"plc_main exited {code}" + (f" (signal {-code})" if code < 0 else "")

    def log_text(self):
        with open(self.log_path, errors="replace") as f:
            return f.read()

    def command(self, cmd, timeout=10.0):
        """One command on a fresh connection (the daemon serves one client at a time). Returns
        once the daemon has closed its end too (it reads until our end is shut: then its
        connection is gone from its threads and fds, and the next command has the socket)."""
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(timeout)
        try:
            try:
                s.connect(self.sock_path)
            except OSError as e:
                raise RuntimeError(f"{cmd}: {e}; {self.exit_text()}") from None
            s.sendall((cmd + "\n").encode())
            buf = b""
            while not buf.endswith(b"\n"):
                chunk = s.recv(65536)
                if not chunk:
                    break
                buf += chunk
            try:
                s.shutdown(socket.SHUT_WR)
                while s.recv(65536):     # until the daemon closes: EOF
                    pass
            except OSError:              # it closed first, or did not within the timeout
                pass
            return buf.decode(errors="replace").strip()
        finally:
            s.close()

    def status(self):
        return self.command("STATUS").partition(":")[2]

    def wait_status(self, want, timeout=30.0, interval=0.02):
        """Poll STATUS until it is `want`; returns time.monotonic() of that answer."""
        end = time.monotonic() + timeout
        last = None
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"plc_main died (exit {self.proc.returncode}, signal "
                                   f"{-self.proc.returncode if self.proc.returncode < 0 else 0}) "
                                   f"waiting for {want}:\n{self.log_text()[-3000:]}")
            last = self.status()
            if last == want:
                return time.monotonic()
            time.sleep(interval)
        raise TimeoutError(f"STATUS stayed {last}, not {want}, for {timeout} s:\n{self.log_text()[-3000:]}")

    def debug(self, frame: bytes) -> bytes:
        """One debugger request (FC 0x41..0x45 frame) through the socket's DEBUG: command."""
        reply = self.command("DEBUG:" + frame.hex(" "))   # its parser wants bytes apart
        if not reply.startswith("DEBUG:") or "ERROR" in reply:
            raise RuntimeError(f"DEBUG {frame.hex()}: {reply}")
        return bytes.fromhex(reply[6:].replace(" ", ""))

    def threads(self):
        return len(os.listdir(f"/proc/{self.pid}/task"))

    def fds(self):
        """The daemon's open files: sorted readlink of /proc/PID/fd/*."""
        d = f"/proc/{self.pid}/fd"
        out = []
        for n in os.listdir(d):
            try:
                out.append(os.readlink(os.path.join(d, n)))
            except OSError:
                pass
        return sorted(out)

    def mapped(self, name):
        """True when a file named `name` is mapped into the daemon."""
        with open(f"/proc/{self.pid}/maps") as f:
            return any(line.rstrip().endswith("/" + name) for line in f)

    def stop(self, timeout=15.0):
        """SIGINT (the daemon's own shutdown: unload, exit), then SIGKILL; returns its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        self.log_sock.close()
        return self.proc.returncode


class DebugMap:
    """A program's debug-map.json (v4/program-build.mjs): (array, element) of a variable."""

    def __init__(self, path):
        import json
        with open(path) as f:
            self.map = json.load(f)

    def find(self, suffix):
        """The leaf whose path ends with `suffix` (case-insensitive): dict with arrayIdx, elemIdx,
        type, size."""
        hits = [v for v in self.map["leaves" if "leaves" in self.map else "vars"]
                if v["path"].upper().endswith(suffix.upper())]
        if len(hits) != 1:
            raise KeyError(f"{suffix}: {len(hits)} variables match")
        return hits[0]


def force(daemon, leaf, value_bytes):
    """FC 0x42 DEBUG_SET: force `leaf` to value_bytes (the variable's own bytes)."""
    frame = bytes([0x42, leaf["arrayIdx"]]) + leaf["elemIdx"].to_bytes(2, "big") + b"\x01" \
        + len(value_bytes).to_bytes(2, "big") + value_bytes
    reply = daemon.debug(frame)
    if reply[:2] != bytes([0x42, 0x7E]):
        raise RuntimeError(f"force {leaf['path']}: {reply.hex()}")


def read(daemon, leaf):
    """FC 0x43 DEBUG_GET of one variable: its bytes."""
    e = leaf["elemIdx"].to_bytes(2, "big")
    reply = daemon.debug(bytes([0x43, leaf["arrayIdx"]]) + e + e)
    if reply[:2] != bytes([0x43, 0x7E]):
        raise RuntimeError(f"read {leaf['path']}: {reply.hex()}")
    n = int.from_bytes(reply[8:10], "big")
    return reply[10:10 + n]
