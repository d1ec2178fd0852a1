"""The timed tests' priority: precedence over ordinary processes, asked of the kernel.

The tests that hold replies against reply timeouts (the fb tests' program and simulator,
the kernel tests' QEMU guests, the soak's smoke run) stand a device on this machine's CPU,
where a real one has its own: neither side's timing may hang on what else the machine runs.
So, as OpenPLC puts its scan thread at SCHED_FIFO, such a test asks for nice MBFB_TEST_NICE
(default NICE; "0" leaves the priority alone) before it starts anything: every process it
starts inherits it. Where that is not allowed (no CAP_SYS_NICE) one line says so and the
test runs as it is. The C tests do the same in tests/shims/mbfb_test_peer.c (t_priority).

    import timed; timed.raise_priority("name")     (in a test's own Python)
    python3 tests/timed.py CMD [ARGS...]           (a launcher: raise, then run CMD)
"""
from __future__ import annotations

import os
import sys

NICE = -10


def raise_priority(test: str) -> None:
    """Ask for nice MBFB_TEST_NICE (default NICE) for this process and what it starts."""
    want = os.environ.get("MBFB_TEST_NICE", "")
    try:
        nice = int(want) if want else NICE
    except ValueError:
        print(f"{test}: MBFB_TEST_NICE={want!r} is not a number: priority left alone",
              file=sys.stderr)
        return
    if nice == 0:
        return
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except OSError as e:
        print(f"note: {test}: nice {nice} not allowed here ({e.strerror}): its timings share "
              f"the machine with everything else", file=sys.stderr)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        print("usage: timed.py CMD [ARGS...]", file=sys.stderr)
        sys.exit(2)
    raise_priority(os.path.basename(sys.argv[1]))
    os.execvp(sys.argv[1], sys.argv[1:])
