"""Reads the RS-485 test double's log (tests/shims/linedouble.c) and checks each request's
driver-enable edges against the frame it frames, for the shims tests and the block tests.

The rules (issue: real wiring, c_shims README "Direction control"):
- the line is idle (receiving) before the first request;
- every request's first byte is written with the line up, at least `before_us` after it went up;
- the line goes down only after the frame has left the UART: not before the write's start plus
  the frame's characters on the wire, plus `after_us`;
- it is down before the device's reply starts (the first byte read after the request), and it
  does not go up again until the next request: never during a reply.
With the kernel's RS-485 mode the kernel switches RTS: the double must show the mode set once,
with the polarity and delays asked for, before the first byte, and no RTS edge from the shims.
"""
from __future__ import annotations

SER_RS485_ENABLED, SER_RS485_RTS_ON_SEND, SER_RS485_RTS_AFTER_SEND = 1, 2, 4


def parse(text: str) -> list[tuple[int, str, list[str]]]:
    events = []
    for line in text.splitlines():
        t, kind, *rest = line.split()
        events.append((int(t), kind, rest))
    return events


def check(text: str, mode: str, char_us: float, before_us: int = 0, after_us: int = 0,
          active_low: bool = False) -> dict:
    """Check the log; return counts. Raises AssertionError naming the request at fault."""
    events = parse(text)
    writes = [e for e in events if e[1] == "write"]
    assert writes, "no request was written"
    if mode == "kernel":
        sets = [e for e in events if e[1] == "rs485"]
        assert len(sets) >= 1 and sets[0][0] < writes[0][0], "RS-485 mode not set before the first byte"
        flags, before_ms, after_ms = int(sets[0][2][0], 16), int(sets[0][2][1]), int(sets[0][2][2])
        want = SER_RS485_ENABLED | (SER_RS485_RTS_AFTER_SEND if active_low else SER_RS485_RTS_ON_SEND)
        assert flags == want, f"RS-485 flags {flags:#x}, want {want:#x}"
        assert before_ms == -(-before_us // 1000) and after_ms == -(-after_us // 1000)
        assert not [e for e in events if e[1] in ("rts", "gpio")], "the shims toggled the line"
        return {"requests": len(writes), "edges": 0}
    edge_kind = {"rts": "rts", "gpio": "gpio"}[mode]
    line_up = None          # None: never set yet
    up_since = None
    pending = None          # the request whose reply is awaited: (write t, chars)
    requests = 0
    margins = []
    for t, kind, rest in events:
        if kind in ("gpioreq",):
            assert writes[0][0] > t, "GPIO requested after the first byte"
            line_up = (rest[2] == "1") != active_low
            assert not line_up, "GPIO requested with the line up (sending)"
        elif kind == edge_kind:
            up = (rest[0] == "1") != active_low     # the level while sending is "up"
            if up:
                assert pending is None or pending[2], \
                    f"line up at {t} before the reply to the request at {pending[0]} started"
                up_since = t
            else:
                if pending is not None and not pending[2]:
                    end = pending[0] + pending[1] * char_us + after_us
                    assert t >= end - 1, (f"line down at {t}, {end - t:.0f} us before the "
                                          f"frame written at {pending[0]} had left")
                    pending = (pending[0], pending[1], True, t)
            line_up = up
        elif kind == "write":
            assert line_up is True, f"request at {t} written with the line down"
            assert t - up_since >= before_us - 1, (f"request at {t} only {t - up_since} us "
                                                   f"after the line went up")
            if pending is not None:
                assert pending[2], f"request at {t} written before the previous one's reply"
            pending = (t, int(rest[0]), False, None)
            requests += 1
        elif kind == "read" and pending is not None:
            if not pending[2]:
                raise AssertionError(f"reply bytes read at {t} with the line still up "
                                     f"(request written at {pending[0]})")
            if pending[3] is not None:
                margins.append(t - pending[3])
                pending = (pending[0], pending[1], True, None)
    assert line_up is False, "the line was left up"
    return {"requests": requests, "edges": requests * 2, "min_margin_us": min(margins or [0])}
