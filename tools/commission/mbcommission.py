#!/usr/bin/env python3
"""mbcommission: find the instruments on a line, back up, compare and restore their settings.

    mbcommission scan PORT [--baud B] [--format 8N1] [--framing rtu] [--address 1-10] [--full]
                           [--settle]
    mbcommission backup PORT ADDRESS [line options] -o FILE [--st]
    mbcommission diff A.json B.json        |  mbcommission diff A.json --port P --address N
    mbcommission restore FILE PORT ADDRESS [line options] [--yes] [--download]

FILE: a backup (JSON), or a recipe in ST: the settings structure's initial value (what
`backup --st` prints, what a block's MVD94_SETTINGS / FDC_SETTINGS / MTS9_SETTINGS holds).

The Modbus engine is the project's C shims (the blocks' own), loaded as libmbfb.so. Exit
statuses: tools/commission/README.md.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import instruments as ins  # noqa: E402
import lineops  # noqa: E402
import oneline  # noqa: E402
from shims import Shims, ShimsError  # noqa: E402

EXIT_OK, EXIT_DIFFERS, EXIT_USAGE, EXIT_PORT, EXIT_DEVICE, EXIT_PARTIAL, EXIT_FILE, EXIT_LIB = \
    0, 1, 2, 3, 4, 5, 6, 7
EXIT_INTERRUPTED = 130


class Fail(Exception):
    """One line for the user and an exit status."""

    def __init__(self, status: int, text: str):
        super().__init__(text)
        self.status = status


def line_args(p):
    p.add_argument("--baud", type=int, default=9600)
    p.add_argument("--format", default=None, help="e.g. 8N2 (default: the model's factory format)")
    p.add_argument("--framing", default="rtu", choices=["rtu", "ascii", "nocrc"])


def parse(argv):
    p = argparse.ArgumentParser(prog="mbcommission", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("scan", help="find the instruments on a line")
    s.add_argument("port")
    s.add_argument("--baud", type=int, action="append", help="only these bauds (repeatable)")
    s.add_argument("--format", action="append", help="only these formats, e.g. 8N1 (repeatable)")
    s.add_argument("--framing", action="append", choices=["rtu", "ascii", "nocrc"])
    s.add_argument("--address", default="1-247", help="N, N-M or a comma list (default 1-247)")
    s.add_argument("--full", action="store_true", help="after the factory settings, every setting")
    s.add_argument("--no-progress", action="store_true", help="no progress bar")
    s.add_argument("--settle", action="store_true",
                   help="probe on one open line, keeping it silent for one more reply timeout "
                        "after each silent address (the shims' settle, as the blocks do): for an "
                        "adapter that should not be opened anew for each probe; about twice the "
                        "time")
    b = sub.add_parser("backup", help="save every readable setting of one instrument")
    b.add_argument("port")
    b.add_argument("address", type=int)
    line_args(b)
    b.add_argument("-o", "--output", help="the backup file (JSON)")
    b.add_argument("--st", action="store_true", help="print the settings as the ST settings "
                   "structure's initial value (a recipe to paste)")
    b.add_argument("--st-name", metavar="NAME", help="--st: the variable's name (default "
                   "KIND_ADDRESS_recipe, e.g. mvd94_7_recipe)")
    d = sub.add_parser("diff", help="settings that differ: two backups, or a backup and a device")
    d.add_argument("a")
    d.add_argument("b", nargs="?")
    d.add_argument("--port")
    d.add_argument("--address", type=int)
    line_args(d)
    r = sub.add_parser("restore", help="write a backup's settings where the device differs")
    r.add_argument("file")
    r.add_argument("port")
    r.add_argument("address", type=int)
    line_args(r)
    r.add_argument("--yes", action="store_true", help="write (default: dry run, nothing sent)")
    r.add_argument("--download", action="store_true",
                   help="FDC-100 only: the programming-port download of its manual's Example 1, "
                        "the whole parameter block (0x34 words at 0) in one FC16, read back")
    args = p.parse_args(argv)
    if args.cmd == "backup" and not (args.output or args.st):
        p.error("backup needs -o FILE, --st, or both")
    if getattr(args, "st_name", None) and not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", args.st_name):
        p.error(f"--st-name {args.st_name!r}: not an ST identifier")
    if getattr(args, "address", None) is not None and args.cmd != "scan" and \
            not 1 <= args.address <= 247:
        p.error(f"address {args.address}: must be 1..247")
    return args


def load_backup(path: str) -> dict:
    """A backup (JSON), or an ST recipe: {"kind": the kind its type names or None, "st": text}
    (its values are checked here when the type is named, before the port is opened)."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as err:
        raise Fail(EXIT_FILE, f"{path}: {err.strerror}") from None
    except UnicodeDecodeError:
        raise Fail(EXIT_FILE, f"{path}: does not parse: not text") from None
    if ":=" in text and not text.lstrip().startswith("{"):
        kind = ins.st_kind(text)
        if kind is not None:
            try:
                ins.settings_desc.to_raw(kind, ins.settings_desc.parse_initial(kind, text))
            except ins.settings_desc.SettingError as err:
                raise Fail(EXIT_FILE, f"{path}: {err}: nothing written") from None
        return {"kind": kind, "st": text, "model": ins.MODELS.get(kind, "recipe")}
    try:
        data = json.loads(text)
        if data.get("kind") not in ins.MODELS or not isinstance(data.get("registers"), dict):
            raise ValueError("not a backup of mbcommission (kind, registers)")
        return data
    except (ValueError, AttributeError) as err:
        raise Fail(EXIT_FILE, f"{path}: does not parse: {err}") from None


def applied(path: str, want: dict, have: dict) -> dict:
    """The backup to restore: `want` itself, or for an ST recipe the device's own backup with
    the recipe's fields over it (a recipe of another model is refused)."""
    if "st" not in want:
        return want
    if want["kind"] not in (None, have["kind"]):
        raise Fail(EXIT_DEVICE, f"the recipe is {ins.settings_desc.type_name(want['kind'])} ({want['model']}), "
                   f"address {have['line']['address']} is an {have['model']}: nothing written")
    try:
        return ins.recipe_backup(have["kind"], want["st"], have)
    except ins.settings_desc.SettingError as err:
        raise Fail(EXIT_FILE, f"{path}: {err}: nothing written") from None


def print_diff(rows) -> None:
    for name, old, new in rows:
        print(f"  {name:<16} {old:>22}  ->  {new}")


def cmd_scan(args, lib) -> int:
    try:
        found, stopped = lineops.scan(lib, args), None
    except lineops.Interrupted as err:
        found, stopped = err.found, err
    if stopped is not None:
        print_found(args, found)
        print(f"mbcommission: interrupted: the scan stopped before its end; {len(found)} "
              "instrument(s) found until then (listed)", file=sys.stderr)
        return EXIT_INTERRUPTED
    if not found:
        print("no instrument answered")
        return EXIT_DEVICE
    print_found(args, found)
    return EXIT_OK


def print_found(args, found) -> None:
    """The table, then one MB_LINE with the blocks that use it (or what to change first)."""
    if not found:
        return
    print(f"\n{'address':>7}  {'model':<10} {'framing':<6} {'baud':>6}  format  identified by")
    for (baud, fmt, framing), f in found:
        print(f"{f.address:>7}  {f.model:<10} {f.framing.upper():<6} {baud:>6}  {f.format or fmt:<6}  "
              + "; ".join(f.evidence))
    print(oneline.declarations(found, args.port))


def cmd_backup(args, lib) -> int:
    data = lineops.backup(lib, args)
    if args.output:
        lineops.write_backup(args.output, data)
        print(f"{data['model']} at {args.address}: {len(data['registers'])} registers -> "
              f"{args.output}", file=sys.stderr if args.st else sys.stdout)
    if args.st:
        sys.stdout.write(ins.st_recipe(data, args.st_name))
    return EXIT_OK


def cmd_diff(args, lib) -> int:
    a = load_backup(args.a)
    if args.b:
        b = load_backup(args.b)
    elif args.port and args.address:
        b = lineops.backup(lib, args)
    else:
        raise Fail(EXIT_USAGE, "diff needs a second backup, or --port and --address")
    if "st" in b:
        raise Fail(EXIT_USAGE, "diff: the second file must be a backup (JSON); an ST recipe goes "
                   "first, against a device (--port, --address)")
    if "st" in a:
        if args.b:
            raise Fail(EXIT_USAGE, "diff: an ST recipe is compared with a device: --port, --address")
        a = applied(args.a, a, b)
    if a["kind"] != b["kind"]:
        raise Fail(EXIT_DEVICE, f"{a['model']} and {b['model']}: different models")
    rows = lineops.differences(a, b)
    print(f"{len(rows)} setting(s) differ" + (":" if rows else ""))
    print_diff(rows)
    return EXIT_DIFFERS if rows else EXIT_OK


def cmd_restore(args, lib) -> int:
    want = load_backup(args.file)
    if args.download and want["kind"] not in (None, *lineops.DOWNLOAD):
        raise Fail(EXIT_USAGE, f"--download is the FDC-100's programming-port download; the "
                   f"backup is of an {want['model']}: nothing written")
    if args.download and "st" not in want:
        try:
            lineops.download_block(want["kind"], want, want)
        except KeyError as err:
            raise Fail(EXIT_FILE, f"{args.file}: the backup lacks {err.args[0]} of the "
                       "download block") from None
    have = lineops.backup(lib, args)
    want = applied(args.file, want, have)
    if have["kind"] != want["kind"]:
        raise Fail(EXIT_DEVICE, f"the backup is of an {want['model']}, address {args.address} "
                   f"is an {have['model']}: nothing written")
    if args.download and have["kind"] not in lineops.DOWNLOAD:
        raise Fail(EXIT_USAGE, f"--download is the FDC-100's programming-port download; address "
                   f"{args.address} is an {have['model']}: nothing written")
    rows = lineops.differences(have, want)
    print(f"{len(rows)} setting(s) differ" + (":" if rows else ""))
    print_diff(rows)
    if not rows:
        return EXIT_OK
    if args.download:
        start, count = lineops.DOWNLOAD[want["kind"]]
        how = f"the whole block, one FC16 of {count} words at {start}"
        if not args.yes:
            print(f"dry run: nothing written (--yes --download writes {how})")
            return EXIT_DIFFERS
        done, failed = lineops.download(lib, args, have, want)
        if failed:
            step, err = failed
            raise Fail(EXIT_PARTIAL, f"{step} failed ({err}); done: {', '.join(done) or 'nothing'};"
                       " run again to finish")
        print(f"downloaded {how}, read back: {len(rows)} setting(s) changed")
        return EXIT_OK
    if not args.yes:
        print("dry run: nothing written (--yes writes them)")
        return EXIT_DIFFERS
    done, failed = lineops.restore(lib, args, have, want)
    if failed:
        name, err = failed
        left = [n for n, _, _ in rows if n not in done]
        raise Fail(EXIT_PARTIAL, f"{name} not written ({err}); written: {', '.join(done) or 'none'};"
                   f" not written: {', '.join(left)}; run again to finish")
    print(f"restored {len(done)} setting(s), each read back")
    return EXIT_OK


def main(argv=None) -> int:
    args = parse(argv)
    try:
        with Shims.load() as lib:
            return {"scan": cmd_scan, "backup": cmd_backup, "diff": cmd_diff,
                    "restore": cmd_restore}[args.cmd](args, lib)
    except ShimsError as err:
        print(f"mbcommission: {err}", file=sys.stderr)
        return EXIT_LIB
    except ins.mbmap.MapError as err:
        print(f"mbcommission: {err}", file=sys.stderr)
        return EXIT_FILE
    except (Fail, lineops.LineError) as err:
        print(f"mbcommission: {err}", file=sys.stderr)
        return err.status
    except KeyboardInterrupt:
        print("mbcommission: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
