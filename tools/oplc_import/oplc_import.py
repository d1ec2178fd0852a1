#!/usr/bin/env python3
"""oplc_import - carry OpenPLC's Modbus master configuration over to the function blocks.

Reads OpenPLC v3's Slave Devices (mbconfig.cfg) or Runtime v4's Modbus master plugin JSON and
writes Structured Text that polls the same devices with MB_Poll into the same located
addresses, writes outputs when they change, and shows each device's status. An entry the
blocks cannot serve as given is named on one line (README.md lists the ids) and nothing is
written. Python standard library only.

    oplc_import.py mbconfig.cfg -o slaves.st                # a PROGRAM of its own
    oplc_import.py mbconfig.cfg --into main.st -o main_mb.st # into the program using %IW100..
    oplc_import.py modbus_master.json --into main.st -o main_mb.st  # Runtime v4: --into
"""
from __future__ import annotations

import argparse
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gen  # noqa: E402
import readers  # noqa: E402
from readers import Problem  # noqa: E402

PROG = "oplc_import"
# Runtime v4 copies %I into each program before its scan and never commits a program's writes
# to %I (core/src/plc_app/image_tables.cpp, copy-out): a PROGRAM of its own filling %IW100 fills
# it for nobody else.
V4_NOTE = (f"{PROG}: note: Runtime v4 passes no program's writes to %I on to other programs or "
           "plugins: put this into the program that uses the addresses (--into FILE)")


class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.exit(2, f"{PROG}: error OI-00: {message} (see --help)\n")


def parse_args(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("config", help="mbconfig.cfg (v3) or the plugin's JSON (v4)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--v3", action="store_true", help="read as mbconfig.cfg (default: by content)")
    fmt.add_argument("--v4", action="store_true", help="read as the v4 plugin's JSON")
    p.add_argument("-o", "--output", required=True, help="the ST file to write ('-': stdout)")
    p.add_argument("--into", metavar="ST_FILE",
                   help="the user's program: the converted part goes into the PROGRAM that "
                        "declares the served addresses, under the user's own names")
    p.add_argument("--pou", help="with --into: that PROGRAM (default: the one declaring the "
                                 "served addresses, else the first)")
    p.add_argument("--name", default="oplc_slaves", help="without --into: the PROGRAM's name")
    p.add_argument("--port", action="append", default=[], metavar="OLD=NEW",
                   help="use serial port NEW where the configuration says OLD (repeatable)")
    p.add_argument("--ignore-pause", action="store_true",
                   help="convert v3 devices with an RTU_TX_Pause (the blocks pace the line "
                        "themselves)")
    return p.parse_args(argv)


def convert(args) -> tuple[str | None, list]:
    """(the ST text, problems); text None when there are problems. Sets args.v4 to the format
    read."""
    try:
        with open(args.config, encoding="utf-8") as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError) as err:
        raise Problem("OI-01", args.config, getattr(err, "strerror", None) or str(err)) from None
    v4 = args.v4 = args.v4 or (not args.v3 and text.lstrip().startswith("["))
    source = os.path.basename(args.config)
    if v4:
        devices, _, problems = readers.read_v4(text, source)
        flavour = "Runtime v4 Modbus master plugin"
    else:
        devices, _, problems = readers.read_v3(text, source, args.ignore_pause)
        flavour = "OpenPLC v3 Slave Devices"
    ports = {}
    for item in args.port:
        old, eq, new = item.partition("=")
        if not eq or not old or not new:
            problems.append(Problem("OI-00", "--port", f"{item!r} is not OLD=NEW"))
        ports[old] = new
    for dev in devices:
        dev.port = ports.get(dev.port, dev.port)
    gen.check_located(devices, problems)
    gen.check_ports(devices, problems)
    if not devices and not problems:
        problems.append(Problem("OI-01", source, "no device configured"))
    names, pou = {}, args.pou
    user = None
    if args.into:
        try:
            with open(args.into, encoding="utf-8") as fh:
                user = fh.read()
        except (OSError, UnicodeDecodeError) as err:
            raise Problem("OI-01", args.into,
                          getattr(err, "strerror", None) or str(err)) from None
        served = {loc for d in devices for r in d.reads + d.writes for loc in r.located}
        names, owner, more = gen.user_names(user, served, os.path.basename(args.into))
        problems += more
        pou = pou or owner
    if problems:
        return None, problems
    try:
        prog = gen.Program(devices, source, flavour, names)
        if user is not None:
            return gen.insert(user, prog, pou), []
        if not re.fullmatch(r"[A-Za-z_]\w*", args.name):
            return None, [Problem("OI-00", "--name", f"{args.name!r} is no ST identifier")]
        return prog.standalone(args.name), []
    except Problem as p:
        return None, [p]


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        text, problems = convert(args)
    except Problem as p:
        text, problems = None, [p]
    if problems:
        for p in problems:
            print(f"{PROG}: error {p.pid}: {p.where}: {p.what}", file=sys.stderr)
        return 2                        # and nothing written
    if args.v4 and not args.into:
        print(V4_NOTE, file=sys.stderr)
    if args.output == "-":
        sys.stdout.write(text)
        return 0
    try:
        tmp = args.output + ".tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, args.output)
    except OSError as err:
        print(f"{PROG}: error OI-01: {args.output}: {err.strerror}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
