"""Fault injection, seeded and scriptable per device.

A fault spec (control 'fault' op, or an entry of --faults FILE):
  {"addr": 1, "kind": K, "count": N, "skip": S, "prob": P, ...kind parameters}
applies to the device's next N replies (count -1 = until cleared) after letting S replies pass;
with prob < 1 each reply is hit with that probability (from the device's seeded generator);
with "fc": F only replies to function code F count (the others pass untouched).
Several faults may be pending on one device: each counts its own skips, each draws its own
probability, and the first (in the order they were added) that is due and drawn applies; at
most one fault per reply.
A device with a late reply pending is busy: it ignores requests until the reply is out (bus.py).
Kinds and parameters:
  drop                         no reply (the request is still applied)
  bad_crc                      CRC (RTU) or LRC (ASCII) made wrong
  late        delay_ms=1000    reply sent that much later (past the master's timeout)
  wrong_slave slave=addr+1     reply carries another slave address (with a valid CRC)
  truncate    keep=len//2      only the first `keep` bytes of the reply are sent
  noise       bytes=3, where=before|after|both   random bytes around the reply
  exception   code=4           exception reply instead; the request is NOT applied
  clear                        removes the device's pending faults
"""
from __future__ import annotations

KINDS = ("drop", "bad_crc", "late", "wrong_slave", "truncate", "noise", "exception")


def _num(spec: dict, key: str, default, lo, hi=None) -> float:
    """A numeric fault parameter within lo..hi; ValueError (one line) otherwise."""
    value = spec.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
        raise ValueError(f"{key} must be a number, not {value!r}")
    if value < lo or (hi is not None and value > hi):
        raise ValueError(f"{key} must be {lo}..{hi if hi is not None else ''}, not {value}")
    return float(value)


def _int(spec: dict, key: str, default, lo, hi=None) -> int:
    value = _num(spec, key, default, lo, hi)
    if value != int(value):
        raise ValueError(f"{key} must be an integer, not {value}")
    return int(value)


class Fault:
    """One pending fault of a device."""

    def __init__(self, spec: dict, addr: int):
        self.kind = spec["kind"]
        if self.kind not in KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r} (one of {', '.join(KINDS)})")
        self.count = _int(spec, "count", 1, -1)
        self.skip = _int(spec, "skip", 0, 0)
        self.prob = _num(spec, "prob", 1.0, 0.0, 1.0)
        self.delay_ms = _num(spec, "delay_ms", 1000.0, 0.0, 3600e3)
        self.slave = _int(spec, "slave", addr % 247 + 1, 0, 255)
        self.keep = None if spec.get("keep") is None else _int(spec, "keep", 0, 0)
        self.nbytes = _int(spec, "bytes", 3, 0, 4096)
        self.where = spec.get("where", "before")
        self.code = _int(spec, "code", 4, 1, 255)
        self.fc = None if spec.get("fc") is None else _int(spec, "fc", 0, 1, 127)
        if self.count == 0:
            raise ValueError("count must be > 0, or -1 (until cleared)")
        if self.where not in ("before", "after", "both"):
            raise ValueError("where must be before, after or both")


class FaultQueue:
    """Pending faults of one device; next() decides, reply by reply, which one applies."""

    def __init__(self, rng, addr: int):
        self.rng = rng
        self.addr = addr
        self.pending: list[Fault] = []
        self.applied: dict[str, int] = {k: 0 for k in KINDS}

    def add(self, spec: dict) -> Fault:
        if spec.get("kind") == "clear":
            self.pending.clear()
            return None
        fault = Fault(spec, self.addr)
        self.pending.append(fault)
        return fault

    def next(self, fc: int | None = None) -> Fault | None:
        """Fault for the reply about to be made to function fc (None: answer normally).
        Every pending fault for this function counts the reply against its own skip; of those
        due, each draws its own probability in order, and the first drawn applies."""
        chosen = None
        for fault in list(self.pending):
            if fault.fc is not None and fault.fc != fc:
                continue
            if fault.skip > 0:
                fault.skip -= 1
                continue
            if chosen is not None:
                continue
            if fault.prob < 1.0 and self.rng.random() >= fault.prob:
                continue
            chosen = fault
        if chosen is None:
            return None
        if chosen.count > 0:
            chosen.count -= 1
            if chosen.count == 0:
                self.pending.remove(chosen)
        self.applied[chosen.kind] += 1
        return chosen

    def shape(self, fault: Fault, frame: bytes, framing: str, reencode, corrupt) -> tuple:
        """(bytes to send or None, extra delay s) of a reply frame under a fault."""
        kind = fault.kind
        if kind == "drop":
            return None, 0.0
        if kind == "bad_crc":
            return corrupt(frame), 0.0
        if kind == "late":
            return frame, fault.delay_ms / 1000.0
        if kind == "wrong_slave":
            return reencode(fault.slave), 0.0
        if kind == "truncate":
            keep = len(frame) // 2 if fault.keep is None else int(fault.keep)
            return frame[:max(0, min(keep, len(frame) - 1))], 0.0
        if kind == "noise":
            junk = lambda: bytes(self.rng.randrange(256) for _ in range(fault.nbytes))
            before = junk() if fault.where in ("before", "both") else b""
            after = junk() if fault.where in ("after", "both") else b""
            return before + frame + after, 0.0
        return frame, 0.0
