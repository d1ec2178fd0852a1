"""Fault injection, seeded and scriptable per device.

A fault spec (control 'fault' op, or an entry of --faults FILE):
  {"addr": 1, "kind": K, "count": N, "skip": S, "prob": P, ...kind parameters}
applies to the device's next N replies (count -1 = until cleared) after letting S replies pass;
with prob < 1 each reply is hit with that probability (from the device's seeded generator);
with "fc": F only replies to function code F count (the others pass untouched).
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


class Fault:
    """One pending fault of a device."""

    def __init__(self, spec: dict, addr: int):
        self.kind = spec["kind"]
        if self.kind not in KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r} (one of {', '.join(KINDS)})")
        self.count = int(spec.get("count", 1))
        self.skip = int(spec.get("skip", 0))
        self.prob = float(spec.get("prob", 1.0))
        self.delay_ms = float(spec.get("delay_ms", 1000))
        self.slave = int(spec.get("slave", addr % 247 + 1)) & 0xFF
        self.keep = spec.get("keep")
        self.nbytes = int(spec.get("bytes", 3))
        self.where = spec.get("where", "before")
        self.code = int(spec.get("code", 4))
        self.fc = None if spec.get("fc") is None else int(spec["fc"])
        if not 0 <= self.prob <= 1 or self.count == 0 or self.where not in ("before", "after", "both"):
            raise ValueError("bad fault parameters (prob 0..1, count != 0, where before/after/both)")
        if self.fc is not None and not 1 <= self.fc <= 127:
            raise ValueError("fc must be a function code 1..127")
        if self.kind == "exception" and not 1 <= self.code <= 255:
            raise ValueError("exception code must be 1..255")


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
        """Fault for the reply about to be made to function fc (None: answer normally)."""
        for fault in self.pending:
            if fault.fc is not None and fault.fc != fc:
                continue
            if fault.skip > 0:
                fault.skip -= 1
                return None
            if fault.prob < 1.0 and self.rng.random() >= fault.prob:
                return None
            if fault.count > 0:
                fault.count -= 1
                if fault.count == 0:
                    self.pending.remove(fault)
            self.applied[fault.kind] += 1
            return fault
        return None

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
