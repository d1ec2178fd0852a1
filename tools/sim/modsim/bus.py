"""The line's logic, independent of the transport: which device a frame is for, broadcasts,
silence, faults, the frame log and the counters."""
from __future__ import annotations

import random
import time
from collections import deque
from dataclasses import dataclass

from . import frames
from .faults import FaultQueue


@dataclass
class LineSettings:
    """Line parameters shared by every device on it."""
    baud: int = 9600
    data_bits: int = 8
    parity: str = "N"
    stop_bits: int = 2
    framing: str = "rtu"
    time_scale: float = 1.0

    @classmethod
    def parse_format(cls, text: str) -> tuple[int, str, int]:
        """'8N2' -> (8, 'N', 2); ValueError on anything else."""
        text = text.strip().upper()
        if len(text) != 3 or text[0] not in "78" or text[1] not in "NEO" or text[2] not in "12":
            raise ValueError(f"bad --format {text!r} (data 7/8, parity N/E/O, stop 1/2: e.g. 8N2)")
        return int(text[0]), text[1], int(text[2])

    @property
    def char_bits(self) -> int:
        return 1 + self.data_bits + (self.parity != "N") + self.stop_bits

    @property
    def char_time(self) -> float:
        return self.char_bits / self.baud

    @property
    def t35(self) -> float:
        """Inter-frame silence; fixed 1.75 ms above 19200 baud (Modbus serial line spec)."""
        return 3.5 * self.char_time if self.baud <= 19200 else 0.00175


@dataclass
class Reply:
    """A reply a device makes: PDU, the address it answers with, and the fault to apply.
    The transport calls sent() once the reply is out (or will never be): a device with a
    late reply pending is busy until then."""
    addr: int
    pdu: bytes
    fault: object = None
    queue: object = None            # the device's FaultQueue (shapes the faulty frame)
    dev: object = None

    def sent(self):
        if self.dev is not None and self.fault is not None and self.fault.kind == "late":
            self.dev.late_pending -= 1


class Bus:
    """Devices on one line (or one TCP server) and everything that is not transport."""

    def __init__(self, line: LineSettings, devices: list, seed: int):
        self.line = line
        self.devices = devices
        self.seed = seed
        self.faults = {d.addr: FaultQueue(random.Random(f"{seed}:faults:{d.addr}"), d.addr)
                       for d in devices}
        for dev in devices:
            dev.fault_queue = self.faults[dev.addr]
            dev.offline = False
            dev.late_pending = 0        # late replies scheduled and not yet sent
            dev.busy_ignored = 0        # requests it did not hear meanwhile
        self.log = deque(maxlen=4000)
        self.t0 = time.monotonic()
        self.counters = {"rx_frames": 0, "tx_frames": 0, "bad_frames": 0, "foreign": 0,
                         "broadcasts": 0, "rx_bytes": 0, "tx_bytes": 0}

    def device(self, addr: int):
        """Device currently answering at addr (a device may have changed its address)."""
        for dev in self.devices:
            if dev.addr == addr:
                return dev
        return None

    def device_by_key(self, addr: int):
        """Device by its address now or at start (control protocol)."""
        dev = self.device(addr)
        if dev is None:
            for dev2 in self.devices:
                if dev2.fault_queue.addr == addr:
                    return dev2
            raise KeyError(f"no device at address {addr}")
        return dev

    def framings(self) -> set:
        """The framings the devices speak now (a serial line has a receiver for each)."""
        return {dev.framing for dev in self.devices}

    def record(self, direction: str, data: bytes, info: str = "", framing: str | None = None):
        """One frame log entry; `framing` on a line of several framings: which receiver."""
        entry = {"t": round(time.monotonic() - self.t0, 6), "dir": direction,
                 "hex": frames.hexs(data)}
        if info:
            entry["info"] = info
        if framing:
            entry["framing"] = framing
        self.log.append(entry)
        self.counters["rx_bytes" if direction == "rx" else "tx_bytes"] += len(data)
        if direction == "tx":
            self.counters["tx_frames"] += 1

    def request(self, addr: int, pdu: bytes, master: dict | None = None,
                framing: str | None = None) -> Reply | None:
        """Apply a well-formed request; the reply to send, or None for silence. `master`: the
        character format of the sender's port as far as the transport sees it (Device.hears).
        `framing`: the framing the frame was decoded in on a serial line; only the devices that
        speak it hear it (None: Modbus/TCP, every device)."""
        self.counters["rx_frames"] += 1
        if not pdu:
            return None
        if addr == 0:                       # broadcast: applied by all, answered by none
            self.counters["broadcasts"] += 1
            for dev in self.devices:
                if not dev.offline and framing in (None, dev.framing) and dev.hears(master):
                    dev.handle(pdu, broadcast=True)
            return None
        dev = self.device(addr)
        if dev is not None and framing not in (None, dev.framing):
            dev = None                      # a frame in another framing: not one for it
        if dev is None:
            self.counters["foreign"] += 1
            return None
        if dev.offline:
            dev.stats["ignored"] += 1
            return None
        if not dev.hears(master):
            dev.stats["ignored"] += 1
            dev.stats["line_mismatch"] += 1
            if self.log and self.log[-1]["dir"] == "rx":   # recorded just before this call
                self.log[-1]["info"] = "line settings differ: heard as garbage"
            return None
        if dev.late_pending:
            # A half-duplex instrument that has not sent its reply yet is busy: it neither
            # hears nor answers another request (the master's retry included).
            dev.busy_ignored += 1
            if self.log and self.log[-1]["dir"] == "rx":   # recorded just before this call
                self.log[-1]["info"] = "busy: late reply pending"
            return None
        fault = dev.fault_queue.next(pdu[0])
        if fault is not None:
            dev.stats["faults_applied"] += 1
        if fault is not None and fault.kind == "exception":
            dev.stats["requests"] += 1
            dev.stats["exceptions"] += 1
            return Reply(addr, bytes([pdu[0] | 0x80, fault.code]), None)
        reply_addr = addr                   # an ADDR write takes effect after this reply
        pdu_out = dev.handle(pdu)
        if pdu_out is None:
            return None
        dev.stats["replies"] += 1
        if fault is not None and fault.kind == "late":
            dev.late_pending += 1
        return Reply(reply_addr, pdu_out, fault, dev.fault_queue, dev)

    def bad_frame(self):
        self.counters["bad_frames"] += 1

    def stats(self) -> dict:
        devs = {}
        for dev in self.devices:
            entry = dev.describe()
            entry["offline"] = dev.offline
            entry["busy_ignored"] = dev.busy_ignored
            entry["faults"] = {k: v for k, v in dev.fault_queue.applied.items() if v}
            entry["faults_pending"] = len(dev.fault_queue.pending)
            devs[str(dev.addr)] = entry
        return {"line": dict(self.counters), "devices": devs}

    def tick(self, dt: float):
        for dev in self.devices:
            dev.tick(dt)
