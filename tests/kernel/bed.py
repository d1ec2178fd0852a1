"""The kernel test bed: one QEMU guest (TCG) with the real serial drivers, a test program in it,
the simulator on the host end of each of its serial lines.

    from bed import Bed, Port
    run = Bed(build_dir).boot(program, args=[...], modules=[...], setup=[...],
                              ports=[Port("8250", "--device mvd94:1"), Port("ftdi", ...)])
    run.rc, run.output (the program's stdout + stderr), run.trace (QEMU trace events),
    run.marks (host times of the program's marks), run.sims[i] (log, stats)

The guest: Debian's kernel (tests/kernel/fetch_guest.sh, kept in the tool cache), an
initramfs written here: busybox-static, the modules asked for (insmod, in order), the program
with the shared libraries `ldd` names, and an init (guest_init.sh) that loads the modules, runs
the setup lines, waits for the ports' device nodes, runs the program with its output kept in
the guest's memory, and prints it on the console at the end (the console UART stays quiet
while the program runs: its trace events would mix with the ports'). ttyS0 is the console,
ttyS1 the first 8250 port (null when none), ttyS2 the control line, ttyS3 a second 8250 port;
the FTDI ports are ttyUSB0, ttyUSB1, ... (QEMU usb-serial behind an xHCI controller).
Bed(build_dir, "arm64") (or "armhf"): an ARM guest of QEMU's virt machine, Debian's kernel and
busybox-static of that architecture, the program cross-built (tests/cross) with its libraries
from the multiarch folders; its one UART, the PL011 (Port("pl011", ...), /dev/ttyAMA0), is the
port; the console and the control line are virtio consoles (hvc0, hvc1).

The control line: the program writes one JSON object per line on /dev/ttyS2 and reads one line
back: {"mark": NAME} (the bed notes the host time: the trace's clock) or {"sim": I, ...} (a
request to simulator I's control socket, docs/contracts.md section 3; its answer comes back).

Each port's host end: mode "pty" (QEMU makes a pty, the simulator serves it with --serial: no
pacing, any baud) or "paced" (the simulator with --pty --pace behind tools/sim/ptyline, at the
line's baud, and QEMU's tty chardev on ptyline's side: the request is paced like a wire before
the simulator hears it, and the reply after its turnaround).
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import select
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import gencache  # noqa: E402  (the tool cache's place)
sys.path.insert(0, os.path.dirname(HERE))
import timed  # noqa: E402  (tests/timed.py: the guests and simulators before other load)
SIM = os.path.join(ROOT, "tools", "sim", "mbsim.py")
QEMU = os.environ.get("MBFB_QEMU", "qemu-system-x86_64")
BUSYBOX = os.environ.get("MBFB_BUSYBOX", "/bin/busybox")
BOOT_LIMIT_S = 150  # one boot of the PC guest, program included, is stopped after this


@dataclasses.dataclass
class Guest:
    """One kind of guest: the PC (amd64, this machine's own userland) or an ARM board
    (QEMU's virt machine; Debian's kernel and busybox-static for that architecture, the
    program cross-built: tests/cross)."""
    arch: str            # Debian architecture of the kernel and userland
    qemu: str
    machine: list        # QEMU's machine arguments
    triple: str          # the program's shared libraries: /lib/<triple> (None: ldd)
    qemu_package: str
    console: str         # the kernel's console= (and where init prints)
    ctl: str             # the control line in the guest
    modules: tuple       # loaded first (the console's and the control line's driver)
    limit_s: float = BOOT_LIMIT_S  # one boot, program included, is stopped after this


GUESTS = {
    "amd64": Guest("amd64", QEMU, ["-M", "pc"], None, "qemu-system-x86", "ttyS0",
                   "/dev/ttyS2", ()),
    # virt has one PL011 (the test port, /dev/ttyAMA0); the console and the control line are
    # virtio consoles (hvc0, hvc1)
    "arm64": Guest("arm64", "qemu-system-aarch64", ["-M", "virt", "-cpu", "cortex-a53"],
                   "aarch64-linux-gnu", "qemu-system-arm", "hvc0", "/dev/hvc1",
                   ("virtio_mmio", "virtio_console"), 300),
    "armhf": Guest("armhf", "qemu-system-arm", ["-M", "virt", "-cpu", "cortex-a15"],
                   "arm-linux-gnueabihf", "qemu-system-arm", "hvc0", "/dev/hvc1",
                   ("virtio_mmio", "virtio_console"), 300),
}


class Skip(Exception):
    """The bed cannot run here (no QEMU, no kernel package): the reason."""


@dataclasses.dataclass
class Port:
    kind: str            # "8250" or "ftdi" (PC), "pl011" (ARM)
    sim_args: str        # the simulator's arguments (devices, --baud, --format ...)
    mode: str = "pty"    # "pty" or "paced" (see the module's doc)


@dataclasses.dataclass
class Run:
    rc: int | None
    output: str
    console: str
    trace: list          # (t, name, {field: value}) in host wall time
    marks: list          # (t, name) in host wall time
    sims: list           # per port: {"log": [...], "stats": {...}}
    seconds: float


def skip_or_fail(reason: str) -> None:
    """Print why the bed cannot run and exit: 77 (ctest SKIP_RETURN_CODE), or 1 when
    MBFB_REQUIRE_TOOLCHAIN=1 asks for every toolchain."""
    if os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1":
        print(f"FAIL: {reason} (MBFB_REQUIRE_TOOLCHAIN=1)")
        sys.exit(1)
    print(f"SKIP: {reason}")
    sys.exit(77)


# ---- the initramfs (cpio newc, written here: no cpio tool needed) ----------------------------
class Cpio:
    def __init__(self):
        self.parts = []
        self.ino = 1
        self.dirs = set()

    def _entry(self, name: str, mode: int, data: bytes = b""):
        name_b = name.encode() + b"\0"
        hdr = "070701" + "".join(f"{v:08x}" for v in (
            self.ino, mode, 0, 0, 1, 0, len(data), 0, 0, 0, 0, len(name_b), 0))
        self.ino += 1
        blob = hdr.encode() + name_b
        blob += b"\0" * (-len(blob) % 4) + data
        blob += b"\0" * (-len(blob) % 4)
        self.parts.append(blob)

    def dir(self, path: str):
        path = path.strip("/")
        if not path or path in self.dirs:
            return
        self.dir(os.path.dirname(path))
        self.dirs.add(path)
        self._entry(path, stat.S_IFDIR | 0o755)

    def file(self, path: str, data: bytes, mode: int = 0o755):
        path = path.strip("/")
        self.dir(os.path.dirname(path))
        self._entry(path, stat.S_IFREG | mode, data)

    def symlink(self, path: str, target: str):
        path = path.strip("/")
        self.dir(os.path.dirname(path))
        self._entry(path, stat.S_IFLNK | 0o777, target.encode())

    def bytes(self) -> bytes:
        self._entry("TRAILER!!!", 0)
        return b"".join(self.parts)


def shared_libs(program: str, triple: str = None) -> list:
    """The shared objects `ldd` says the program loads (with the dynamic loader); for a
    program of another architecture (triple), its interpreter and NEEDED entries, followed,
    from Debian's multiarch folders (/lib/<triple>: libc6:<arch>, libmodbus5:<arch>)."""
    if triple:
        dirs = [f"/lib/{triple}", f"/usr/lib/{triple}"]
        libs, todo = [], [program]
        while todo:
            elf = todo.pop()
            out = subprocess.run([f"{triple}-readelf", "-d", "-l", elf], capture_output=True,
                                 text=True).stdout
            interp = re.findall(r"interpreter: (\S+?)\]", out)
            for name in interp + re.findall(r"\(NEEDED\).*\[(.+?)\]", out):
                path = name if name.startswith("/") else next(
                    (os.path.join(d, name) for d in dirs if os.path.exists(os.path.join(d, name))),
                    None)
                if path is None:
                    raise Skip(f"{name} for {triple} not found in {dirs} (multiarch libc6 / "
                               f"libmodbus5 of that architecture)")
                if path not in libs:
                    libs.append(path)
                    todo.append(os.path.realpath(path))
        return libs
    out = subprocess.run(["ldd", program], capture_output=True, text=True).stdout
    libs = []
    for line in out.splitlines():
        m = re.search(r"(/\S+)", line.split("=>")[-1])
        if m and os.path.exists(m.group(1)):
            libs.append(m.group(1))
    return libs


TRACE_RE = re.compile(r"^\d+@(\d+)\.(\d+):(\w+) ?(.*)$")


def parse_trace(text: str) -> list:
    """QEMU's log trace backend: 'pid@sec.usec:name field value ...' -> (t, name, fields)."""
    events = []
    for line in text.splitlines():
        m = TRACE_RE.match(line)
        if not m:
            continue
        t = int(m.group(1)) + int(m.group(2)) / 1e6
        fields = {}
        for k, v in re.findall(r"(\w+):?[ =]+(0x[0-9a-fA-F]+|-?\d+(?:\.\d+)?)", m.group(4)):
            fields[k] = int(v, 0) if not re.match(r"-?\d+\.\d+$", v) else float(v)
        events.append((t, m.group(3), fields))
    return events


def tool_cache(build_dir: str, name: str) -> str:
    """Where a download or build that does not change with the checkout is kept: NAME in the
    tool cache (MBFB_TOOL_CACHE, scripts/gencache.py), so that a fresh clone finds it; in the
    build tree when MBFB_TOOL_CACHE is empty."""
    return os.path.join(gencache.tool_cache() or os.path.abspath(build_dir), name)


class Bed:
    def __init__(self, build_dir: str, arch: str = "amd64"):
        self.build = os.path.abspath(build_dir)
        self.guest = GUESTS[arch]
        # Debian's kernel and busybox for the guest, downloaded once (a few hundred MB)
        self.cache = tool_cache(build_dir, f"kernel-guest-{arch}")
        self.busybox = BUSYBOX if arch == "amd64" else \
            os.path.join(self.cache, "root", "bin", "busybox")
        # the guest's timers and the simulators stand for hardware: precedence over other load
        timed.raise_priority(f"kernel bed ({arch})")

    # ---- what the guest is made of ----
    def kernel(self):
        g = self.guest
        if shutil.which(g.qemu) is None:
            raise Skip(f"{g.qemu} not found (Debian package {g.qemu_package}, "
                       f".ci/apt-packages.txt)")
        if g.arch == "amd64" and not os.path.exists(BUSYBOX):
            raise Skip(f"{BUSYBOX} not found (Debian package busybox-static)")
        r = subprocess.run([os.path.join(HERE, "fetch_guest.sh"), self.cache, g.arch],
                           capture_output=True, text=True)
        if r.returncode != 0:
            raise Skip("no guest kernel: " + (r.stderr.strip().splitlines() or ["?"])[-1])
        release = r.stdout.strip()
        root = os.path.join(self.cache, "root")
        if not os.path.exists(self.busybox):
            raise Skip(f"no busybox in the {g.arch} guest packages (busybox-static:{g.arch})")
        return os.path.join(root, "boot", f"vmlinuz-{release}"), \
            os.path.join(root, "lib", "modules", release)

    def initramfs(self, path, moddir, program, args, modules, setup, wait, files):
        c = Cpio()
        c.file("bin/busybox", open(self.busybox, "rb").read())
        c.symlink("bin/sh", "busybox")
        c.file("init", open(os.path.join(HERE, "guest_init.sh"), "rb").read())
        index = {}
        for d, _, names in os.walk(moddir):
            for n in names:
                if n.endswith(".ko"):
                    index[n[:-3].replace("-", "_")] = os.path.join(d, n)
        builtin = set()
        if os.path.exists(os.path.join(moddir, "modules.builtin")):
            builtin = {os.path.basename(ln.strip())[:-3].replace("-", "_")
                       for ln in open(os.path.join(moddir, "modules.builtin"))}
        loaded = []
        for m in modules:
            src = index.get(m.replace("-", "_"))
            if src is None and m.replace("-", "_") in builtin:
                continue  # built into this kernel
            if src is None:
                raise Skip(f"module {m} is not in the guest kernel package")
            c.file(f"lib/modules/{m}.ko", open(src, "rb").read(), 0o644)
            loaded.append(m)
        modules = loaded
        for lib in shared_libs(program, self.guest.triple):
            c.file(lib, open(os.path.realpath(lib), "rb").read())
        for src, dest in files:
            data = open(src, "rb").read()
            c.file(dest, data)
            if data[:4] == b"\x7fELF":  # another program: its libraries too
                for lib in shared_libs(src, self.guest.triple):
                    c.file(lib, open(os.path.realpath(lib), "rb").read())
        c.file("bin/test-program", open(program, "rb").read())
        conf = {"modules": " ".join(modules), "wait": " ".join(wait),
                "args": " ".join(args)}
        for k, v in conf.items():
            c.file(f"etc/bed/{k}", (v + "\n").encode(), 0o644)
        c.file("etc/bed/setup", ("\n".join(setup) + "\n").encode(), 0o644)
        g = self.guest
        c.file("etc/bed/console", (f"/dev/{g.console}\n" if g.arch != "amd64" else "").encode(),
               0o644)
        c.file("etc/bed/ctl", (g.ctl + "\n").encode(), 0o644)
        with open(path, "wb") as f:
            f.write(c.bytes())

    # ---- one boot ----
    def boot(self, program, args=(), modules=(), setup=(), ports=(), files=(),
             trace_events=("serial_*", "usb_serial_*"), memory_mb=256, sim_sets=None) -> Run:
        """One boot. sim_sets: {NAME: simulator arguments}: the program may ask for a pty
        port's simulator to be restarted with one of them ({"restart": I, "set": NAME} on the
        control line), e.g. before each fb test program."""
        self.sim_sets = dict(sim_sets or {})
        vmlinuz, moddir = self.kernel()
        work = tempfile.mkdtemp(prefix="kbed.")
        procs = []
        try:
            modules = list(self.guest.modules) + list(modules)
            if self.guest.arch != "amd64" and tuple(trace_events) == ("serial_*", "usb_serial_*"):
                trace_events = ("pl011_write", "pl011_read", "pl011_baudrate_change")
            return self._boot(work, procs, vmlinuz, moddir, program, list(args), modules,
                              list(setup), list(ports), list(files), trace_events, memory_mb)
        finally:
            for p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            for p in procs:
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            keep = os.environ.get("MBFB_KERNEL_KEEP")  # a folder for the trace and logs
            if keep:
                shutil.rmtree(keep, ignore_errors=True)
                shutil.copytree(work, keep, ignore=shutil.ignore_patterns("initrd", "*.sock",
                                                                          "line*"))
            shutil.rmtree(work, ignore_errors=True)

    def _sim(self, procs, work, i, port: Port, where: list):
        ctl = os.path.join(work, f"sim{i}.sock")
        cmd = [sys.executable, SIM, *where, "--control", ctl, *port.sim_args.split()]
        env = dict(os.environ)
        ptyline = os.path.join(self.build, "tools", "sim", "ptyline", "mbfb-ptyline")
        if os.path.exists(ptyline):
            env.setdefault("MBFB_PTYLINE", ptyline)
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=open(
            os.path.join(work, f"sim{i}.err"), "w"), text=True, env=env)
        procs.append(p)
        line = p.stdout.readline()
        if not line:
            raise RuntimeError(f"simulator {i} did not start: " +
                               open(os.path.join(work, f"sim{i}.err")).read()[-800:])
        return ctl, line.split()[-1]

    def _boot(self, work, procs, vmlinuz, moddir, program, args, modules, setup, ports, files,
              trace_events, memory_mb):
        t_start = time.monotonic()
        self.live = {}  # pty port -> (its simulator, where it serves, the port)
        kinds = [p.kind for p in ports]
        wait = []
        n8250 = nftdi = 0
        serial_slots = {1: None, 3: None}
        pl011 = None
        arm = self.guest.arch != "amd64"
        for i, p in enumerate(ports):
            if (p.kind == "pl011") != arm:
                raise ValueError(f"port kind {p.kind} on the {self.guest.arch} guest")
            if p.kind == "pl011":
                if pl011 is not None:
                    raise ValueError("QEMU's virt machine has one PL011")
                pl011 = i
                wait.append("/dev/ttyAMA0")
            elif p.kind == "8250":
                slot = (1, 3)[n8250]
                n8250 += 1
                serial_slots[slot] = i
                wait.append(f"/dev/ttyS{slot}")
            elif p.kind == "ftdi":
                wait.append(f"/dev/ttyUSB{nftdi}")
                nftdi += 1
            else:
                raise ValueError(f"port kind {p.kind}")
        initrd = os.path.join(work, "initrd")
        self.initramfs(initrd, moddir, program, args, modules, setup, wait, files)

        # paced ports: the simulator (behind ptyline) first, QEMU opens its side
        ctls = [None] * len(ports)
        chardev = {}
        for i, p in enumerate(ports):
            if p.mode == "paced":
                link = os.path.join(work, f"line{i}")
                ctls[i], _ = self._sim(procs, work, i, p, ["--pty", "--pace", "--symlink", link])
                chardev[i] = f"serial,path={os.path.realpath(link)}"
            else:
                chardev[i] = "pty"
        trace_file = os.path.join(work, "trace.log")
        console = os.path.join(work, "console.log")
        g = self.guest
        cmd = [g.qemu, "-accel", "tcg", *g.machine, "-m", str(memory_mb), "-nodefaults",
               "-no-user-config", "-display", "none", "-no-reboot", "-S", "-monitor", "stdio",
               "-kernel", vmlinuz, "-initrd", initrd,
               "-append", f"console={g.console} quiet loglevel=3 panic=-1" +
               ("" if arm else " 8250.nr_uarts=4"),
               "-D", trace_file, "-msg", "timestamp=on"]
        for ev in trace_events:
            cmd += ["-trace", f"enable={ev}"]
        if arm:
            # the PL011 (the first -serial), the console and the control line on virtio
            if pl011 is not None:
                cmd += ["-chardev", f"{chardev[pl011]},id=p{pl011}",
                        "-serial", f"chardev:p{pl011}"]
            else:
                cmd += ["-serial", "null"]
            cmd += ["-device", "virtio-serial-device",
                    "-chardev", f"file,id=con,path={console}", "-device", "virtconsole,chardev=con",
                    "-chardev", "pty,id=ctl", "-device", "virtconsole,chardev=ctl"]
        else:
            cmd += self._pc_ports(console, serial_slots, chardev, ports, nftdi)
        # "char device redirected to ..." comes on stdout or stderr (the monitor has stdio)
        qemu = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        procs.append(qemu)
        # "char device redirected to /dev/pts/N (label X)" on stderr, one per pty chardev
        ptys = {}
        want = 1 + sum(1 for p in ports if p.mode == "pty")
        deadline = time.monotonic() + 30
        err_seen = ""
        out_fd = qemu.stdout.fileno()
        while len(ptys) < want and time.monotonic() < deadline:
            r, _, _ = select.select([out_fd], [], [], 1)
            if not r:
                if qemu.poll() is not None:
                    break
                continue
            chunk = os.read(out_fd, 4096).decode(errors="replace")
            if not chunk:
                break
            err_seen += chunk
            for m in re.finditer(r"redirected to (\S+) \(label (\w+)\)", err_seen):
                ptys[m.group(2)] = m.group(1)
        if len(ptys) < want:
            raise RuntimeError("QEMU did not start: " + err_seen[-800:])
        for i, p in enumerate(ports):
            if p.mode == "pty":
                ctls[i], _ = self._sim(procs, work, i, p, ["--serial", ptys[f"p{i}"]])
                self.live[i] = (procs[-1], ["--serial", ptys[f"p{i}"]], p)
        ctl_fd = os.open(ptys["ctl"], os.O_RDWR | os.O_NOCTTY)
        import tty
        tty.setraw(ctl_fd)
        marks = []
        self.live_work, self.live_procs = work, procs
        relay = threading.Thread(target=self._relay, args=(ctl_fd, ctls, marks), daemon=True)
        relay.start()
        if arm:
            # QEMU's PL011 does not pass the guest's line settings to its chardev (its 16550
            # does), and QEMU opens a tty chardev at 115200 8N1: a paced line then gets the
            # line's own settings, as the guest programs them
            for i, p in enumerate(ports):
                if p.mode == "paced":
                    line_termios(os.path.realpath(os.path.join(work, f"line{i}")), p.sim_args)
        qemu.stdin.write("cont\n")
        qemu.stdin.flush()
        threading.Thread(target=lambda: drain(out_fd), daemon=True).start()
        try:
            qemu.wait(timeout=self.guest.limit_s)
        except subprocess.TimeoutExpired:
            qemu.kill()
            qemu.wait()
        os.close(ctl_fd)
        sims = []
        for ctl in ctls:
            sims.append({"log": sim_request(ctl, {"op": "log"}).get("log", []),
                         "stats": sim_request(ctl, {"op": "stats"})})
        with open(os.path.join(work, "marks.json"), "w") as f:
            json.dump(marks, f)
        text = open(console, errors="replace").read()
        m = re.search(r"BED: output begin\r?\n(.*)BED: output end\r?\nBED: exit (\d+)", text, re.S)
        output = m.group(1).replace("\r\n", "\n") if m else ""
        rc = int(m.group(2)) if m else None
        return Run(rc, output, text, parse_trace(open(trace_file, errors="replace").read()),
                   marks, sims, time.monotonic() - t_start)

    @staticmethod
    def _pc_ports(console, serial_slots, chardev, ports, nftdi):
        """The PC guest's serial lines: ttyS0 the console, ttyS1 and ttyS3 8250 ports,
        ttyS2 the control line, FTDI ports behind an xHCI controller."""
        cmd = ["-chardev", f"file,id=con,path={console}", "-serial", "chardev:con"]
        for slot in (1, 2, 3):
            if slot == 2:
                cmd += ["-chardev", "pty,id=ctl", "-serial", "chardev:ctl"]
            elif serial_slots[slot] is not None:
                i = serial_slots[slot]
                cmd += ["-chardev", f"{chardev[i]},id=p{i}", "-serial", f"chardev:p{i}"]
            else:
                cmd += ["-serial", "null"]
        if nftdi:
            cmd += ["-device", "qemu-xhci,id=xhci"]
            for i, p in enumerate(ports):
                if p.kind == "ftdi":
                    cmd += ["-chardev", f"{chardev[i]},id=p{i}",
                            "-device", f"usb-serial,bus=xhci.0,chardev=p{i}"]
        return cmd

    def _restart(self, i, name, ctls) -> dict:
        """Simulator i (a pty port's) stopped by pid and started again with the set name."""
        if i not in self.live or name not in self.sim_sets:
            return {"ok": False, "error": "no such pty port or simulator set"}
        proc, where, port = self.live[i]
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        new = Port(port.kind, self.sim_sets[name], port.mode)
        try:
            ctls[i], _ = self._sim(self.live_procs, self.live_work, i, new, where)
        except RuntimeError as e:
            return {"ok": False, "error": str(e)}
        self.live[i] = (self.live_procs[-1], where, new)
        return {"ok": True}

    def _relay(self, fd, ctls, marks):
        buf = b""
        while True:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                now = time.time()
                try:
                    req = json.loads(line.decode(errors="replace").strip() or "{}")
                except ValueError:
                    reply = {"ok": False, "error": "not JSON"}
                else:
                    if "mark" in req:
                        marks.append((now, req["mark"]))
                        reply = {"ok": True}
                    elif "restart" in req:
                        reply = self._restart(req["restart"], req.get("set"), ctls)
                    elif "sim" in req:
                        i = req.pop("sim")
                        reply = sim_request(ctls[i], req) if 0 <= i < len(ctls) and ctls[i] \
                            else {"ok": False, "error": "no such simulator"}
                    else:
                        reply = {"ok": False, "error": "unknown request"}
                try:
                    os.write(fd, (json.dumps(reply) + "\n").encode())
                except OSError:
                    return


def line_termios(path, sim_args):
    """Set a tty's baud and character format (raw) from the simulator's --baud / --format."""
    import termios
    args = sim_args.split()
    baud = int(args[args.index("--baud") + 1]) if "--baud" in args else 9600
    fmt = args[args.index("--format") + 1] if "--format" in args else "8N1"
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        iflag, oflag, cflag, lflag, _, _, cc = termios.tcgetattr(fd)
        speed = getattr(termios, f"B{baud}")
        cflag &= ~(termios.CSIZE | termios.PARENB | termios.PARODD | termios.CSTOPB)
        cflag |= termios.CS8 | termios.CLOCAL | termios.CREAD
        cflag |= {"N": 0, "E": termios.PARENB, "O": termios.PARENB | termios.PARODD}[fmt[1]]
        cflag |= termios.CSTOPB if fmt[2] == "2" else 0
        termios.tcsetattr(fd, termios.TCSANOW, [0, 0, cflag, 0, speed, speed, cc])
    finally:
        os.close(fd)


def drain(fd):
    """Read and drop a pipe until it closes (QEMU's monitor output)."""
    try:
        while os.read(fd, 4096):
            pass
    except OSError:
        pass


def sim_request(ctl, req) -> dict:
    """One request to a simulator's control socket."""
    if ctl is None:
        return {}
    try:
        with socket.socket(socket.AF_UNIX) as s:
            s.settimeout(5)
            s.connect(ctl)
            s.sendall((json.dumps(req) + "\n").encode())
            data = b""
            while not data.endswith(b"\n"):
                chunk = s.recv(65536)
                if not chunk:
                    break
                data += chunk
        return json.loads(data or b"{}")
    except (OSError, ValueError) as e:
        return {"ok": False, "error": str(e)}
