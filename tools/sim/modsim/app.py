"""The simulator process: builds the devices from the command line and serves them."""
from __future__ import annotations

import argparse
import asyncio
import glob
import json
import os
import random
import signal
import sys
import time

from .bus import Bus, LineSettings
from .control import Control
from .fdc100 import Fdc100
from .generic import Generic
from .mts9 import MtS9
from .mvd94 import MvD94, Vd
from .regmap import mbmap
from .rtutcp import RtuTcpLine
from .tcp import TcpLine
from .transport import SerialLine

import settings  # noqa: E402  (maps/settings.py, on the path through regmap)

KINDS = {"mvd94": MvD94, "vd": Vd, "mts9": MtS9, "fdc100": Fdc100, "generic": Generic}
FRAMED = ("mts9", "generic")    # kinds that take framing=
TICK_S = 0.05       # real seconds between steps of the dynamics


class Parser(argparse.ArgumentParser):
    """Command-line errors are one line on stderr and exit 2 (no usage dump, no traceback)."""

    def error(self, message):
        self.exit(2, f"mbsim: error: {message} (see --help)\n")


def parse_tcp(text: str, option: str = "--tcp") -> tuple[str, int]:
    """'127.0.0.1:PORT' -> (host, port); ValueError for anything else."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{option} {text!r}: expected 127.0.0.1:PORT with PORT 0..65535")
    host = host.strip("[]") or "127.0.0.1"
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise ValueError(f"{option} {text!r}: the simulator listens on 127.0.0.1 only")
    return host, int(port)


def parse_args(argv):
    p = Parser(prog="mbsim.py", description=__doc__ + " See tools/sim/README.md.")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pty")
    where.add_argument("--serial", metavar="DEVICE", help="serve on a serial device")
    where.add_argument("--tcp", metavar="127.0.0.1:PORT", help="Modbus/TCP (PORT 0: any free)")
    where.add_argument("--rtu-tcp", metavar="127.0.0.1:PORT",
                       help="RTU frames over TCP, as a transparent gateway (PORT 0: any free)")
    p.add_argument("--symlink", metavar="PATH", help="with --pty: symlink to the pty")
    p.add_argument("--baud", type=int, default=9600)
    p.add_argument("--format", default="8N2", help="data bits, parity N/E/O, stop bits")
    p.add_argument("--device", action="append", default=[], metavar="KIND:ADDR[:NAME=VALUE,...]",
                   help="repeatable; KIND = " + " | ".join(KINDS))
    p.add_argument("--time-scale", type=float, default=1.0)
    p.add_argument("--pace", action="store_true", help="pace replies like RS-485 at --baud")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--faults", metavar="FILE", help="JSON list of control requests/faults")
    p.add_argument("--control", metavar="PATH", help="Unix socket of the control protocol")
    p.add_argument("--ptyline", metavar="PATH", help="mbfb-ptyline binary for --pty --pace "
                   "(default: $MBFB_PTYLINE, else build*/tools/sim/ptyline/mbfb-ptyline; "
                   "'none': pace replies inside the simulator)")
    args = p.parse_args(argv)
    if not args.device:
        p.error("at least one --device is required")
    if args.symlink and not args.pty:
        p.error("--symlink needs --pty")
    if not args.time_scale > 0 or args.time_scale == float("inf"):
        p.error("--time-scale must be a number > 0")
    if not 50 <= args.baud <= 4000000:
        p.error(f"--baud {args.baud}: must be 50..4000000")
    for option, value in (("--tcp", args.tcp), ("--rtu-tcp", args.rtu_tcp)):
        if value:
            try:
                parse_tcp(value, option)
            except ValueError as err:
                p.error(str(err))
    return args


def parse_device(text: str):
    """'mvd94:1:SV=100.0,DP=1' -> ('mvd94', 1, [('SV', '100.0'), ('DP', '1')])."""
    parts = text.split(":", 2)
    if len(parts) < 2 or parts[0] not in KINDS:
        raise ValueError(f"--device {text!r}: expected KIND:ADDR[:NAME=VALUE,...], "
                         f"KIND one of {', '.join(KINDS)}")
    try:
        addr = int(parts[1], 0)
    except ValueError:
        raise ValueError(f"--device {text!r}: address {parts[1]!r} is not a number") from None
    if not 1 <= addr <= 255:
        raise ValueError(f"--device {text!r}: address must be 1..255 (0 is broadcast)")
    items = []
    for item in (parts[2].split(",") if len(parts) == 3 and parts[2] else []):
        name, eq, value = item.partition("=")
        if not eq or not name.strip():
            raise ValueError(f"--device {text!r}: {item!r} is not NAME=VALUE")
        items.append((name.strip(), value.strip()))
    return parts[0], addr, items


def build(args):
    """LineSettings and devices from the arguments; ValueError on any inconsistency."""
    data, parity, stop = LineSettings.parse_format(args.format)
    specs = [parse_device(d) for d in args.device]
    addrs = [a for _, a, _ in specs]
    if len(set(addrs)) != len(addrs):
        raise ValueError("two devices share an address")
    # Devices of different framings share a line (each hears every byte and answers frames of
    # its own framing). An MT-S9 or generic device given no framing= takes the one framing the
    # others were given, else RTU.
    framings = {v for k, _, items in specs if k in FRAMED for n, v in items if n.lower() == "framing"}
    bad = framings - {"rtu", "nocrc", "ascii"}
    if bad:
        raise ValueError(f"framing must be rtu, nocrc or ascii, not {sorted(bad)[0]!r}")
    framing = next(iter(framings)) if len(framings) == 1 else "rtu"
    if args.rtu_tcp and framings - {"rtu"}:
        raise ValueError(f"--rtu-tcp carries rtu framing only, not {sorted(framings - {'rtu'})[0]}")
    line = LineSettings(args.baud, data, parity, stop, framing, args.time_scale)
    devices = []
    for kind, addr, items in specs:
        dev = KINDS[kind](addr, line, random.Random(f"{args.seed}:dev:{addr}"))
        items = [it for it in items if not dev.option(*it)]
        dev.finish()
        items.sort(key=lambda it: init_rank(kind, it[0]))
        for name, value in items:
            try:
                dev.set_eng(name, value)
            except KeyError as err:
                raise ValueError(str(err).strip('"')) from None
        if not args.tcp:
            check_line(kind, addr, dev, line)
        if not args.tcp and not dev.hears(None):
            print(f"mbsim: warning: {kind}:{addr} settings do not match the line; it stays "
                  "silent", file=sys.stderr)
        devices.append(dev)
    return line, devices


def find_ptyline(given: str | None) -> str | None:
    """The ptyline binary: --ptyline, $MBFB_PTYLINE, or the newest build*/ of this checkout."""
    if given == "none":
        return None
    if given:
        if not os.access(given, os.X_OK):
            raise ValueError(f"--ptyline {given}: not an executable")
        return given
    env = os.environ.get("MBFB_PTYLINE")
    if env and os.access(env, os.X_OK):
        return env
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__)))))
    found = glob.glob(os.path.join(root, "build*", "tools", "sim", "ptyline", "mbfb-ptyline"))
    found = [f for f in found if os.access(f, os.X_OK)]
    return max(found, key=os.path.getmtime) if found else None


def init_rank(kind: str, name: str) -> int:
    """Start-up options are set in the order the instrument needs them written (the settings
    description, maps/settings.py): what scales the others (input type, unit, decimal point),
    then the limits, then the rest."""
    if kind not in mbmap.DEVICES and kind != "vd":
        return settings.ORDER[""]
    try:
        part = mbmap.load(kind).reg(name).recipe
    except KeyError:
        return settings.ORDER[""]
    return settings.ORDER[part] if part in ("first", "limit") else settings.ORDER[""]


def check_line(kind, addr, dev, line):
    """The line's baud and format must be ones the device can speak (its map's "line"); the
    stop bits need not match (a UART checks only the first stop bit)."""
    spec = dev.MAP.line if dev.MAP is not None else {}
    fmt = f"{line.data_bits}{line.parity}{line.stop_bits}"
    if spec.get("bauds") and line.baud not in spec["bauds"]:
        raise ValueError(f"{kind}:{addr} cannot run at {line.baud} baud (it speaks "
                         f"{', '.join(map(str, spec['bauds']))}): put it on a line of its own")
    if spec.get("formats") and fmt[:2] not in [f[:2] for f in spec["formats"]]:
        raise ValueError(f"{kind}:{addr} speaks {' or '.join(spec['formats'])}, not {fmt} "
                         "(--format): put it on a line of its own")


class App:
    """Bus + transport + control socket + the clock of the dynamics."""

    def __init__(self, args, line, devices):
        self.args = args
        self.bus = Bus(line, devices, args.seed)
        if args.tcp:
            host, port = parse_tcp(args.tcp)
            self.transport = TcpLine(self.bus, host, port)
            self.transport_kind = "tcp"
        elif args.rtu_tcp:
            host, port = parse_tcp(args.rtu_tcp, "--rtu-tcp")
            self.transport = RtuTcpLine(self.bus, host, port, pace=args.pace, seed=args.seed)
            self.transport_kind = "rtu-tcp"
        else:
            ptyline = find_ptyline(args.ptyline) if args.pace and args.pty else None
            if args.pace and args.pty and ptyline is None:
                print("mbsim: note: mbfb-ptyline not found; --pace paces replies only and "
                      "line statistics are unavailable", file=sys.stderr)
            self.transport = SerialLine(self.bus, device=args.serial, link=args.symlink,
                                        pace=args.pace, seed=args.seed, ptyline=ptyline)
            self.transport_kind = "serial"
        self.control = Control(self)
        self.ready_line = None
        self.stopping = asyncio.Event()

    def line_stats(self) -> dict:
        return self.transport.line_stats()

    async def ticker(self):
        last = time.monotonic()
        while True:
            await asyncio.sleep(TICK_S)
            now = time.monotonic()
            self.bus.tick((now - last) * self.bus.line.time_scale)
            last = now

    async def scripted(self, req):
        await asyncio.sleep(float(req.get("at_ms", 0)) / 1000.0)
        try:
            await self.control.execute(req)
        except Exception as err:  # pylint: disable=broad-except
            print(f"mbsim: --faults entry {req}: {err}", file=sys.stderr)

    async def run(self) -> int:
        try:
            return await self._run()
        finally:                    # also after an error at start: nothing left behind
            self.transport.close()
            self.control.close()

    async def _run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.stopping.set)
        script = []
        if self.args.faults:
            with open(self.args.faults, encoding="utf-8") as fh:
                script = json.load(fh)
            if not isinstance(script, list):
                raise ValueError("--faults FILE must hold a JSON list")
        if self.args.control:
            await self.control.start(self.args.control)
        self.ready_line = await self.transport.start()
        tasks = [asyncio.ensure_future(self.ticker())]
        for req in script:          # immediate entries are applied before the ready line
            if not isinstance(req, dict):
                raise ValueError(f"--faults entry {json.dumps(req)}: not a JSON object")
            req = dict(req)
            req.setdefault("op", "fault")
            if float(req.get("at_ms", 0)) <= 0:
                try:
                    await self.control.execute(req)
                except Exception as err:  # pylint: disable=broad-except  (one line, exit 2)
                    raise ValueError(f"--faults entry {json.dumps(req)}: {err}") from None
            else:
                tasks.append(asyncio.ensure_future(self.scripted(req)))
        print(self.ready_line, flush=True)
        await self.stopping.wait()
        for task in tasks:
            task.cancel()
        return 0


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        line, devices = build(args)
        app = App(args, line, devices)
        return asyncio.run(app.run())
    except KeyboardInterrupt:       # Ctrl-C before the handlers were installed
        return 130
    except (ValueError, OSError, KeyError, TypeError, OverflowError) as err:
        print(f"mbsim: error: {str(err).strip(chr(34))}", file=sys.stderr)
        return 2

