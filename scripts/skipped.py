#!/usr/bin/env python3
"""skipped.py CTEST_OUTPUT LASTTEST_LOG - each skipped test of the last ctest run and why.

ctest lists skipped tests ("<n> - <name> (Skipped)") without their output; the reason (our
tests print "SKIP: <reason>" before exit code 77) is in build/Testing/Temporary/LastTest.log.
Prints nothing when no test was skipped."""
import re
import sys


def skipped_names(ctest_output):
    return re.findall(r"^\s*\d+ - (\S+) \(Skipped\)$", ctest_output, re.M)


def reasons(last_test_log):
    """test name -> its SKIP line (else its last line of output)."""
    out = {}
    for m in re.finditer(r"^\d+/\d+ Test: (\S+)$.*?^Output:\n-+\n(.*?)<end of output>",
                         last_test_log, re.M | re.S):
        lines = [ln.strip() for ln in m.group(2).splitlines() if ln.strip()]
        skips = [ln.split("SKIP:", 1)[1].strip() for ln in lines if ln.startswith("SKIP:")]
        out[m.group(1)] = skips[0] if skips else (lines[-1] if lines else "(no reason printed)")
    return out


def main():
    if len(sys.argv) != 3:
        print("usage: skipped.py CTEST_OUTPUT LASTTEST_LOG", file=sys.stderr)
        return 2
    try:
        with open(sys.argv[1], errors="replace") as f:
            names = skipped_names(f.read())
        with open(sys.argv[2], errors="replace") as f:
            why = reasons(f.read())
    except OSError as e:
        print(f"skipped.py: {e}", file=sys.stderr)
        return 1
    if names:
        print(f"\nSkipped, and why ({len(names)}):")
        for name in names:
            print(f"  {name}: {why.get(name, '(no output in the log)')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
