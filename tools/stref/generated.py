"""The command line of every generated file (st_src/REFERENCE.md, docs/errors.md,
maps/README.md, st_src/MB_Settings.st), after its arguments: the generator hands its render
function here; bad input is one line and exit code 2; else the text is written, or compared
with the committed file by its staleness test (write_or_check).

    from generated import generate
    sys.exit(generate("stref", lambda: render(...), InputError, out=args.out,
                      check=args.check, hint="tools/stref/stref.py --out it"))

Python standard library only.
"""
from __future__ import annotations

import difflib
import sys

DIFF_LINES = 40   # at most this many lines of the difference shown when a file is stale


def write_or_check(tool: str, text: str, out: str | None = None, check: str | None = None,
                   hint: str = "") -> int:
    """With check: 0 and "<tool>: <check> is up to date" when the file holds exactly text, else 1
    with the start of a unified diff (standard output) and "<tool>: <check> is stale: run <hint>"
    (standard error); a file that cannot be read is stale too. Without check: writes text to out
    (standard output when None) and returns 0. The return value is the exit code."""
    if check:
        try:
            with open(check, encoding="utf-8") as fh:
                have = fh.read()
        except OSError as err:
            print(f"{tool}: {check}: {err.strerror}: run {hint}", file=sys.stderr)
            return 1
        if have != text:
            diff = difflib.unified_diff(have.splitlines(), text.splitlines(), check,
                                        "generated", lineterm="", n=1)
            print("\n".join(list(diff)[:DIFF_LINES]))
            print(f"{tool}: {check} is stale: run {hint}", file=sys.stderr)
            return 1
        print(f"{tool}: {check} is up to date")
        return 0
    if out:
        with open(out, "w", encoding="utf-8") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)
    return 0


def generate(tool: str, render, bad_input, out: str | None = None, check: str | None = None,
             hint: str = "") -> int:
    """A generator's command line after its arguments: the text from render(); an exception
    of the types bad_input is bad input, one line "<tool>: <error>" on standard error and exit
    code 2, nothing written or checked; else write_or_check. The return value is the exit
    code."""
    try:
        text = render()
    except bad_input as err:
        print(f"{tool}: {err}", file=sys.stderr)
        return 2
    return write_or_check(tool, text, out=out, check=check, hint=hint)
