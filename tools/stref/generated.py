"""The one write-or-check of every generated file (st_src/REFERENCE.md, docs/errors.md,
maps/README.md, st_src/MB_Settings.st): a generator renders its text and hands it here, to be
written, or compared with the committed file by its staleness test.

    from generated import write_or_check
    sys.exit(write_or_check("stref", text, out=args.out, check=args.check,
                            hint="tools/stref/stref.py --out it"))

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
