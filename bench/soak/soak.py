#!/usr/bin/env python3
"""Soak: the real shims (through their public API) against the device simulator.

Three instruments on one simulated RS-485 line (MV-D94 at 1, FDC-100 at 2, MT-S9 at 3, one
common line setting), about FAULT_RATE of the transactions hit by a fault of every kind the
simulator offers (drop, bad_crc, late 50 ms..5 s, wrong_slave, truncate, noise, exception,
power cycle, device outage, port reopen), numbered writes with distinct values, and every read
checked against the value the simulator's register holds.

How the truth is known (see README.md):
  * The soak owns the registers it writes (MV-D94 SV/A1SP/A2SP/A3SP, FDC JOB1..3, MT-S9 Real
    Data); nothing else changes them. Each write carries a value never written to that register
    before (a per-register counter) from a range no other register uses, so a value names the
    write and the register it was meant for.
  * One request per device is outstanding at a time (like a block), so a device's requests
    reach it in order. When a write finishes, the register is read through the control socket
    (out of band, not on the line): it holds the write's values iff the write was applied.
    That is also the register's value for every read posted after it until the next write, so
    each read has exactly one right answer.
  * Applied twice: the simulator's frame log (fetched and cleared every 0.5 s) has every frame
    the devices received; a write's frame received by an online, not busy device that did not
    answer it with an exception was applied. A write's values are unique, so its frames are
    recognised whatever attempt sent them. Outages are toggled only while the device has no
    request outstanding, with the log fetched just before, so the log batches tell online from
    offline frames exactly.

Prints requests, faults per kind (injected and applied by the simulator), wrong values
delivered as good, writes lost (Done, not applied), applied twice (non-idempotent and
idempotent), reported failed but applied, unconfirmed (MBFB_E_UNCONFIRMED), recovery times and
the bus cost. Exit status 0 when every checked count is zero and every outage recovered, 1 when
not, 2 for a bad command line or a setup failure (one line on stderr).
"""
from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import random
import shutil
import signal
import socket
import statistics
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

REQ_QUEUED, REQ_ACTIVE, REQ_DONE, REQ_FAILED = 1, 2, 3, 4
E_OFFLINE, E_NOPORT, E_PORTLOST, E_UNCONFIRMED = 4, 5, 6, 13
WRITE_IDEMPOTENT, WRITE_ONCE = 0, 1
REPLY_FAULTS = ("drop", "bad_crc", "late", "wrong_slave", "truncate", "noise", "exception")
EVENT_FAULTS = ("power_cycle", "outage", "reopen_port")
# relative weights of the fault kinds (events cost seconds of line time each: rarer)
WEIGHTS = {**{k: 1.0 for k in REPLY_FAULTS}, "power_cycle": 0.5, "outage": 0.15,
           "reopen_port": 0.15}


def die(msg: str):
    print(f"soak: error: {msg}", file=sys.stderr)
    sys.exit(2)


def find_simctl(sim_dir=None):
    for path in ([sim_dir] if sim_dir else [os.path.join(ROOT, r) for r in ("tools/sim", "tests/sim")]):
        if os.path.exists(os.path.join(path, "simctl.py")):
            sys.path.insert(0, path)
            import simctl  # pylint: disable=import-outside-toplevel
            return simctl
    die("simulator client simctl.py not found in tools/sim or tests/sim")
    return None


# ---------------------------------------------------------------------------- shims
class Diag(ctypes.Structure):
    _fields_ = [(n, ctypes.c_uint32) for n in (
        "requests", "good", "timeouts", "crc_errors", "bad_replies", "exceptions", "retries",
        "last_exception", "last_rtt_us", "offline")] + [("last_error", ctypes.c_int32)] + [
        (n, ctypes.c_uint32) for n in (
            "stray_bytes", "resyncs", "refreshes", "refresh_us", "line_permille")]


class Shims:
    """ctypes view of c_shims' public API (mbfb.h)."""

    def __init__(self, path: str):
        self.lib = ctypes.CDLL(path)
        lib = self.lib
        lib.mbfb_bus_open_args.argtypes = [ctypes.c_char_p] + [ctypes.c_int] * 8
        lib.mbfb_dev_open.argtypes = [ctypes.c_int, ctypes.c_int]
        u16p = ctypes.POINTER(ctypes.c_uint16)
        lib.mbfb_post.argtypes = [ctypes.c_int] * 4 + [u16p]
        lib.mbfb_poll.argtypes = [ctypes.c_int]
        lib.mbfb_take.argtypes = [ctypes.c_int, u16p, ctypes.c_int]
        lib.mbfb_dev_diag.argtypes = [ctypes.c_int, ctypes.POINTER(Diag)]
        lib.mbfb_strerror.restype = ctypes.c_char_p
        self.has_post_write = hasattr(lib, "mbfb_post_write")
        if self.has_post_write:
            lib.mbfb_post_write.argtypes = [ctypes.c_int] * 4 + [u16p, ctypes.c_int]
        # resync counters exist only in shims that have them (diag struct of mbfb.h)
        self.has_resync = self.has_post_write

    def post(self, dev, fc, addr, count, values=None, policy=WRITE_IDEMPOTENT):
        buf = (ctypes.c_uint16 * max(1, count))(*(values or [0]))
        if fc in (6, 16) and self.has_post_write:
            return self.lib.mbfb_post_write(dev, fc, addr, count, buf, policy)
        return self.lib.mbfb_post(dev, fc, addr, count, buf)

    def take(self, req, count):
        buf = (ctypes.c_uint16 * 125)()
        rc = self.lib.mbfb_take(req, buf, 125)
        return rc, list(buf[:max(0, rc)])

    def diag(self, dev) -> Diag:
        out = Diag()
        self.lib.mbfb_dev_diag(dev, ctypes.byref(out))
        return out


# ---------------------------------------------------------------------------- model
class Counter:
    """Distinct values for one register: base + n (mod span), never reused within a run of
    fewer than `span` writes to it."""

    def __init__(self, base, span):
        self.base, self.span, self.n = base, span, 0

    def next(self):
        v = self.base + self.n % self.span
        self.n += 1
        return v


class Device:
    def __init__(self, kind, addr, spec, reads, writes, checked, owned):
        self.kind, self.addr, self.spec = kind, addr, spec
        self.reads = reads        # [(fc, addr, count)]
        self.writes = writes      # [(fc, addr, [counter per word], policy, make_words)]
        self.checked = checked    # word addresses checked in reads (FC03)
        self.owned = owned        # registers the soak writes (control names/numbers)
        self.cur = {}             # word address -> value the device holds now
        self.handle = -1
        self.out = None           # outstanding request dict
        self.hold = False         # no new request (event pending)
        self.resume_at = 0.0
        self.fail_since = None    # time of the first failure of the current streak
        self.offline = False      # simulator outage on (soak's view, see log batches)
        self.backoff = False      # last result: MBFB_E_OFFLINE (the shims' back-off)
        self.ready_at = 0.0       # the device can answer again from here on (a lower bound:
                                  # end of its late reply's delay, of an outage, of the port's
                                  # absence); what recovery takes beyond it is the master's
        self.write_frames = {}    # frame prefix hex -> write record (for the log)
        self.unknown = []         # UNCONFIRMED writes found not applied when they ended


def word_split32(v):
    v &= 0xFFFFFFFF
    return [v & 0xFFFF, v >> 16]    # MT-S9: low word first


def make_devices():
    mv = Device("mvd94", 1, "mvd94:1",
                reads=[(3, 0x00, 1), (3, 0x03, 1), (3, 0x04, 1), (3, 0x05, 1), (3, 0x00, 6),
                       (4, 0x1000, 1)],
                writes=[(6, 0x00, [Counter(1001, 8999)], WRITE_IDEMPOTENT),
                        (6, 0x03, [Counter(-1000, 667)], WRITE_IDEMPOTENT),
                        (6, 0x04, [Counter(-333, 667)], WRITE_IDEMPOTENT),
                        (6, 0x05, [Counter(334, 667)], WRITE_IDEMPOTENT)],
                checked=range(0, 6), owned=[0, 1, 2, 3, 4, 5])
    fdc = Device("fdc100", 2, "fdc100:2",
                 reads=[(3, 73, 1), (3, 74, 1), (3, 75, 1), (3, 73, 3), (3, 64, 8)],
                 writes=[(6, 73, [Counter(0x1000, 0x4000)], WRITE_IDEMPOTENT),
                         (6, 74, [Counter(0x5000, 0x4000)], WRITE_IDEMPOTENT),
                         (16, 73, [Counter(0x1000, 0x4000), Counter(0x5000, 0x4000),
                                   Counter(0x9000, 0x4000)], WRITE_ONCE),
                         (16, 75, [Counter(0x9000, 0x4000)], WRITE_ONCE)],
                 checked=range(73, 76), owned=[73, 74, 75])
    # counters shared per register between the FC06 and FC16 writes of the FDC
    fdc.writes[2][2][0] = fdc.writes[0][2][0]
    fdc.writes[2][2][1] = fdc.writes[1][2][0]
    fdc.writes[3][2][0] = fdc.writes[2][2][2]
    mt = Device("mts9", 3, "mts9:3:rate=0",
                reads=[(3, 0, 2), (3, 0, 10), (3, 2, 2)],
                writes=[(16, 0, [Counter(100000, 800000)], WRITE_ONCE)],
                checked=range(0, 10), owned=[0, 2, 4, 5, 6, 7, 8, 9])
    return [mv, fdc, mt]


def to_u16(v):
    return v & 0xFFFF


def write_words(dev, w):
    fc, addr, counters, _policy = w
    if dev.kind == "mts9":
        return word_split32(counters[0].next())
    return [to_u16(c.next()) for c in counters]


def expected_words(dev, addr, count):
    """Expected values of the checked words of a read (None where unchecked)."""
    out = []
    for a in range(addr, addr + count):
        if a in dev.checked:
            out.append(dev.cur.get(a))
        else:
            out.append(None)
    if dev.kind == "mts9":   # Display Data = Real Data (values inside 6 digits)
        out = [dev.cur.get(0) if a == 2 else dev.cur.get(1) if a == 3 else v
               for a, v in zip(range(addr, addr + count), out)]
    return out


def request_frame(slave, fc, addr, count, values) -> bytes:
    if fc == 6:
        return bytes([slave, 6, addr >> 8, addr & 255, values[0] >> 8, values[0] & 255])
    body = bytes([slave, 16, addr >> 8, addr & 255, count >> 8, count & 255, 2 * count])
    return body + b"".join(bytes([v >> 8, v & 255]) for v in values)


# ---------------------------------------------------------------------------- soak
class Soak:
    def __init__(self, args, simctl, shims):
        self.a = args
        self.simctl = simctl
        self.shims = shims
        self.rng = random.Random(args.seed)
        self.devs = make_devices()
        self.by_addr = {d.addr: d for d in self.devs}
        self.stats = {
            "transactions": 0, "reads": 0, "writes": 0, "good_reads": 0, "failed_reads": 0,
            "not_sent_offline": 0, "not_sent_offline_device_able": 0, "not_sent_noport": 0,
            "master_share_clamped": 0, "wrong_values": 0, "writes_done": 0, "writes_failed": 0,
            "writes_lost": 0, "writes_failed_applied": 0, "unconfirmed": 0,
            "unconfirmed_applied": 0, "unconfirmed_applied_late": 0,
            "doubled_once": 0, "doubled_idempotent": 0,
            "log_inconsistent": 0, "results": {}}
        self.injected = {k: 0 for k in (*REPLY_FAULTS, *EVENT_FAULTS)}
        # fault: from the first failed request of a streak to the next good reply;
        # fault_master_share: the same from when the device could answer again (Device.ready_at)
        # master_share: every recovery below (faults, outages, ...) from when the device
        # could answer again (Device.ready_at): the part of it that is the master's
        self.recovery = {"fault": [], "outage": [], "reopen_port": [], "power_cycle": [],
                         "master_share": []}
        self.pending_recovery = []   # (kind, device or None, since)
        self.wrong_examples = []
        self.write_examples = []
        self.log_examples = []
        self.writes = []
        self.unrecovered = 0
        self.final_reads = 0         # reads of the final recovery check (on the wire too)
        self.events_busy = 0         # background control ops running (reopen_port)
        self.last_log = 0.0
        self.trace = open(args.trace, "w", encoding="utf-8") if args.trace else None
        self.log_frames = 0
        self.line_bytes = self.line_frames = self.rx_frames = 0

    # ---- simulator ----
    def ctl(self, **req):
        rep = self.sim.control(req)
        if not rep.get("ok"):
            raise RuntimeError(f"simulator: {req}: {rep.get('error')}")
        return rep

    def read_reg_words(self, dev, reg):
        return self.ctl(op="get", addr=dev.addr, reg=reg)["words"]

    def refresh_truth(self, dev, regs):
        for reg in regs:
            words = self.read_reg_words(dev, reg)
            for i, w in enumerate(words):
                dev.cur[reg + i] = w & 0xFFFF

    def fetch_log(self):
        frames = self.ctl(op="log", clear=True)["frames"]
        self.log_frames += len(frames)
        if self.trace:
            for f in frames:
                self.trace.write(json.dumps({"ev": "frame", **f}) + "\n")
        if len(frames) >= 3990:
            self.stats["log_inconsistent"] += 1   # the log may have overflowed
        for i, f in enumerate(frames):
            nbytes = len(f["hex"].split())
            if nbytes:   # line use: every frame heard or sent (faulty ones included)
                self.line_bytes += nbytes
                self.line_frames += 1
                if f["dir"] == "rx":
                    self.rx_frames += 1
            if f["dir"] != "rx" or f.get("info") or not f["hex"]:
                continue
            raw = bytes.fromhex(f["hex"])
            if len(raw) < 8:
                continue
            dev = self.by_addr.get(raw[0])
            if dev is None or dev.offline:
                continue
            rec = dev.write_frames.get(raw[:-2])
            if rec is None:
                continue
            nxt = frames[i + 1] if i + 1 < len(frames) else None
            if nxt and nxt["dir"] == "tx" and nxt["hex"]:
                b = bytes.fromhex(nxt["hex"])
                if len(b) >= 2 and b[0] == raw[0] and b[1] == (raw[1] | 0x80):
                    continue   # an exception answer: not applied
            rec["received"] += 1
        self.last_log = time.monotonic()

    def background_ctl(self, req):
        """A control op that blocks the simulator's answer (reopen_port waits out down_ms):
        on its own connection in a thread, so the soak keeps running."""
        def run():
            try:
                with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                    s.settimeout(30)
                    s.connect(self.sim.control_path)
                    s.sendall((json.dumps(req) + "\n").encode())
                    s.makefile("rb").readline()
            except OSError:
                pass
            finally:
                self.events_done.append(req)
        self.events_busy += 1
        threading.Thread(target=run, daemon=True).start()

    def tr(self, ev, **kw):
        if self.trace:
            self.trace.write(json.dumps({"ev": ev, "t": round(time.monotonic() - self.t0, 6),
                                         **kw}) + "\n")

    def hold_pty(self):
        """Keep the simulator's current pty allocated while the soak runs.

        The simulator's reopen_port leaves its --symlink naming the old pty during the down
        time; if another program on the machine (a test, another simulator) is given that
        pty number meanwhile, the shims reopening the link would talk to it. Holding the
        slave side open keeps the number from being reused (opening it then fails, as for a
        port that is gone); the soak never reads from it, so it takes no bytes."""
        try:
            fd = os.open(os.path.realpath(self.link), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return
        if self.held_fd is not None:
            os.close(self.held_fd)
        self.held_fd = fd

    # ---- faults ----
    def pick_fault(self):
        kinds = list(WEIGHTS)
        return self.rng.choices(kinds, weights=[WEIGHTS[k] for k in kinds])[0]

    def inject(self, dev, now):
        if dev.backoff and not self.a.faults_in_backoff:
            return   # not on the wire: the fault would wait for a reply that does not come
        kind = self.pick_fault()
        self.tr("fault", dev=dev.addr, kind=kind)
        if kind in REPLY_FAULTS:
            # at most one fault pending per device: one not applied yet (its reply never
            # came: device busy or offline) is dropped, so faults cannot pile up
            self.ctl(op="fault", addr=dev.addr, kind="clear")
            spec = {"op": "fault", "addr": dev.addr, "kind": kind, "count": 1}
            if kind == "late":
                lo, hi = self.a.late_min_ms, self.a.late_max_ms
                spec["delay_ms"] = round(math.exp(self.rng.uniform(math.log(lo), math.log(hi))))
                # busy (deaf) until its late reply is out: the reply's request is posted
                # after now, so now + delay is a lower bound of when it can answer again
                # (in an outage, the reply it delays comes only after the outage)
                start = dev.outage_end if dev.offline else now
                dev.ready_at = max(dev.ready_at, start + spec["delay_ms"] / 1000)
            elif kind == "noise":
                spec["bytes"] = self.rng.randint(1, 6)
                spec["where"] = self.rng.choice(("before", "after", "both"))
            elif kind == "truncate":
                spec["keep"] = self.rng.randint(1, 4)
            self.ctl(**spec)
            self.injected[kind] += 1
            return
        if kind == "power_cycle":
            self.fetch_log()
            self.ctl(op="power_cycle", addr=dev.addr)
            self.injected[kind] += 1
            self.pending_recovery.append(("power_cycle", dev, now))
            return
        if kind == "outage":
            if any(d.offline for d in self.devs):
                return   # one outage at a time
            self.fetch_log()
            self.ctl(op="offline", addr=dev.addr, on=True)
            dev.offline = True
            dev.outage_end = now + self.rng.uniform(self.a.outage_min_s, self.a.outage_max_s)
            dev.ready_at = max(dev.ready_at, dev.outage_end)
            self.injected[kind] += 1
            return
        if kind == "reopen_port":
            if self.events_busy:
                return
            self.injected[kind] += 1
            self.reopen_at = now
            down_ms = self.rng.randint(100, 1000)
            for d in self.devs:
                d.ready_at = max(d.ready_at, now + down_ms / 1000)
            self.background_ctl({"op": "reopen_port", "down_ms": down_ms})
            self.pending_recovery.append(("reopen_port", None, now))

    # ---- requests ----
    def post_next(self, dev, now):
        if self.rng.random() < self.a.fault_rate:
            self.inject(dev, now)
        is_write = self.rng.random() < self.a.write_share
        if is_write:
            w = self.rng.choice(dev.writes)
            fc, addr, counters, policy = w
            values = write_words(dev, w)
            count = len(values)
            rec = {"dev": dev.addr, "fc": fc, "addr": addr, "values": values, "policy": policy,
                   "received": 0, "result": None, "applied": None, "t": now}
            dev.write_frames[request_frame(dev.addr, fc, addr, count, values)] = rec
            h = self.shims.post(dev.handle, fc, addr, count, values, policy)
            req = {"write": rec, "fc": fc, "addr": addr, "count": count}
        else:
            fc, addr, count = self.rng.choice(dev.reads)
            h = self.shims.post(dev.handle, fc, addr, count)
            req = {"write": None, "fc": fc, "addr": addr, "count": count,
                   "expect": expected_words(dev, addr, count)}
        if h <= 0:
            raise RuntimeError(f"mbfb_post failed: {h}")
        req["h"], req["t"] = h, now
        dev.out = req
        self.tr("post", dev=dev.addr, fc=req["fc"], addr=req["addr"], count=req["count"],
                values=req["write"]["values"] if req["write"] else None)

    def master_share(self, dev, since, now):
        """A recovery's share that is the master's: from when the device could answer."""
        share = now - max(since, dev.ready_at)
        self.stats["master_share_clamped"] += share < 0
        self.recovery["master_share"].append(max(0.0, share))
        self.tr("recovered", dev=dev.addr, since=round(since - self.t0, 3),
                ready=round(dev.ready_at - self.t0, 3), share=round(share, 3))

    def finish(self, dev, req, now):
        rc, words = self.shims.take(req["h"], req["count"])
        dev.out = None
        st = self.stats
        result = 0 if rc >= 0 else -rc
        st["results"][result] = st["results"].get(result, 0) + 1
        self.tr("done", dev=dev.addr, result=result, words=words[:8])
        dev.backoff = result == E_OFFLINE
        if result in (E_OFFLINE, E_NOPORT):
            # not on the wire (back-off, or the port is not there): not a transaction; wait
            # a block's period before the next request instead of spinning
            st["not_sent_offline" if result == E_OFFLINE else "not_sent_noport"] += 1
            if result == E_OFFLINE and now >= dev.ready_at and not dev.offline:
                st["not_sent_offline_device_able"] += 1   # refused while it could answer
            dev.resume_at = now + 0.05
        else:
            st["transactions"] += 1
        if result == 0:
            if dev.fail_since is not None:
                self.recovery["fault"].append(now - dev.fail_since)
                self.master_share(dev, dev.fail_since, now)
                dev.fail_since = None
            for item in list(self.pending_recovery):
                kind, pdev, since = item
                if pdev is None or pdev is dev:
                    self.recovery[kind].append(now - since)
                    self.master_share(dev, since, now)
                    self.pending_recovery.remove(item)
        elif dev.fail_since is None and result < 128:
            dev.fail_since = req["t"]
        rec = req["write"]
        sent = result not in (E_OFFLINE, E_NOPORT)
        if rec is None:
            st["reads"] += sent
            if result != 0:
                st["failed_reads"] += 1
                return
            st["good_reads"] += 1
            bad = [(req["addr"] + i, e, w) for i, (e, w) in enumerate(zip(req["expect"], words))
                   if e is not None and e != w]
            if bad and self.applied_late(dev, bad):
                return
            if bad:
                st["wrong_values"] += 1
                if len(self.wrong_examples) < 20:
                    self.wrong_examples.append({"dev": dev.kind, "fc": req["fc"],
                                                "addr": req["addr"], "count": req["count"],
                                                "wrong": bad[:4], "t": round(now - self.t0, 3)})
            return
        st["writes"] += sent
        rec["result"] = result
        regs = list(range(rec["addr"], rec["addr"] + (1 if dev.kind == "mts9" else
                                                       len(rec["values"]))))
        self.refresh_truth(dev, [rec["addr"]] if dev.kind == "mts9" else regs)
        if dev.kind == "mts9":
            now_words = [dev.cur[0], dev.cur[1]]
        else:
            now_words = [dev.cur[r] for r in regs]
        rec["applied"] = now_words == rec["values"]
        self.tr("truth", dev=dev.addr, words=now_words, applied=rec["applied"])
        # an earlier write of unknown outcome to these registers is superseded by this one
        # once this one is on the device (frames reach it in the order sent)
        if rec["applied"]:
            dev.unknown = [u for u in dev.unknown
                           if not set(range(u["addr"], u["addr"] + len(u["values"]))) & set(regs)]
        self.writes.append(rec)
        if result == 0:
            st["writes_done"] += 1
            if not rec["applied"]:
                st["writes_lost"] += 1
                self.note_write("lost (Done, not applied)", dev, rec, now_words)
        elif result == E_UNCONFIRMED:
            st["unconfirmed"] += 1
            if rec["applied"]:
                st["unconfirmed_applied"] += 1
            else:
                dev.unknown.append(rec)   # its outcome is unknown: it may still be applied
        else:
            st["writes_failed"] += 1
            if rec["applied"]:
                st["writes_failed_applied"] += 1
                self.note_write(f"failed {result} but applied", dev, rec, now_words)

    def applied_late(self, dev, bad) -> bool:
        """A read that differs from the soak's view of the device, explained by an UNCONFIRMED
        write found not applied when it ended (MBFB_E_UNCONFIRMED: "may have been applied"):
        the read shows exactly that write's words, and the simulator's own frame log shows the
        device heard the write's frame (a starved simulator reads a frame after the master has
        given up). Then the device holds those words: the soak's view follows, and the write
        counts as unconfirmed and applied (late), not the read as wrong."""
        self.fetch_log()                              # the frames heard up to now
        for rec in dev.unknown:
            words = {rec["addr"] + i: v for i, v in enumerate(rec["values"])}
            if dev.kind == "mts9" and rec["addr"] == 0:   # Display Data mirrors Real Data
                words.update({2: rec["values"][0], 3: rec["values"][1]})
            if rec["received"] and all(words.get(a) == w for a, _e, w in bad):
                dev.unknown.remove(rec)
                for a, v in words.items():
                    if a in dev.cur:
                        dev.cur[a] = v
                rec["applied"] = True
                self.stats["unconfirmed_applied"] += 1
                self.stats["unconfirmed_applied_late"] += 1
                self.tr("applied_late", dev=dev.addr, values=rec["values"])
                return True
        return False

    def note_write(self, what, dev, rec, now_words):
        kind = what.split()[0]   # up to 10 examples of each kind (lost, failed, applied)
        if sum(e["what"].split()[0] == kind for e in self.write_examples) < 10:
            self.write_examples.append({"what": what, "dev": dev.kind, "fc": rec["fc"],
                                        "addr": rec["addr"], "values": rec["values"],
                                        "device_holds": now_words,
                                        "t": round(time.monotonic() - self.t0, 3)})

    # ---- main loop ----
    def run(self):
        a = self.a
        tmp = tempfile.mkdtemp(prefix="mbfb-soak-")
        link = os.path.join(tmp, "rs485")
        self.events_done = []
        self.reopen_at = None
        self.link = link
        self.held_fd = None
        devices = [d.spec for d in self.devs]
        try:
            self.sim = self.simctl.Simulator(devices, baud=a.baud, fmt=a.format, seed=a.seed,
                                             link=link, pace=a.pace)
            self.sim.start()
        except Exception as err:  # pylint: disable=broad-except
            shutil.rmtree(tmp, ignore_errors=True)
            lines = [ln for ln in str(err).splitlines() if ln.strip()] or ["?"]
            die(f"simulator did not start: {lines[-1].strip()}")   # its last word
        try:
            self.hold_pty()
            return self._run(link)
        finally:
            if self.held_fd is not None:
                os.close(self.held_fd)
            self.sim.stop()
            self.shims.lib.mbfb_shutdown()
            shutil.rmtree(tmp, ignore_errors=True)

    def _run(self, link):
        a = self.a
        parity = {"N": ord("N"), "E": ord("E"), "O": ord("O")}[a.format[1]]
        bus = self.shims.lib.mbfb_bus_open_args(link.encode(), len(link), a.baud, parity,
                                                int(a.format[0]), int(a.format[2]), 0, 0, -1)
        if bus < 0:
            die(f"mbfb_bus_open: {self.shims.lib.mbfb_strerror(bus).decode()}")
        for dev in self.devs:
            dev.handle = self.shims.lib.mbfb_dev_open(bus, dev.addr)
            self.refresh_truth(dev, dev.owned)
        self.t0 = time.monotonic()
        total = a.transactions
        last_report = self.t0
        while self.stats["transactions"] < total:
            now = time.monotonic()
            if now - self.last_log > 0.5:
                self.fetch_log()
            if self.events_done:
                self.events_done.clear()
                for d in self.devs:           # the port is back (reopen_port answered)
                    d.ready_at = max(d.ready_at, now)
                self.events_busy = 0
                self.hold_pty()   # the port is back: hold its new pty number
            for dev in self.devs:
                if dev.out is not None:
                    st = self.shims.lib.mbfb_poll(dev.out["h"])
                    if st in (REQ_DONE, REQ_FAILED):
                        self.finish(dev, dev.out, now)
                if dev.out is None and dev.offline and now >= dev.outage_end:
                    self.fetch_log()            # frames so far: heard while offline
                    self.ctl(op="offline", addr=dev.addr, on=False)
                    dev.offline = False
                    dev.ready_at = max(dev.ready_at, time.monotonic())
                    self.pending_recovery.append(("outage", dev, time.monotonic()))
                if dev.out is None and now >= dev.resume_at and \
                        self.stats["transactions"] + sum(d.out is not None for d in self.devs) < total:
                    self.post_next(dev, now)
            if a.progress and now - last_report > a.progress:
                last_report = now
                s = self.stats
                print(f"[{now - self.t0:7.0f} s] {s['transactions']} txn, wrong {s['wrong_values']},"
                      f" lost {s['writes_lost']}, failed-applied {s['writes_failed_applied']}",
                      file=sys.stderr, flush=True)
            time.sleep(0.0005)
        # drain: finish outstanding, end any outage, let reopen finish, then recovery check
        self.elapsed = time.monotonic() - self.t0
        end = time.monotonic() + 60
        while any(d.out for d in self.devs) and time.monotonic() < end:
            for dev in self.devs:
                if dev.out and self.shims.lib.mbfb_poll(dev.out["h"]) in (REQ_DONE, REQ_FAILED):
                    self.finish(dev, dev.out, time.monotonic())
            time.sleep(0.001)
        for dev in self.devs:
            if dev.offline:
                self.fetch_log()
                self.ctl(op="offline", addr=dev.addr, on=False)
                dev.offline = False
                self.pending_recovery.append(("outage", dev, time.monotonic()))
        while self.events_busy and not self.events_done and time.monotonic() < end:
            time.sleep(0.05)
        self.final_recovery()
        self.fetch_log()
        self.sim_stats = self.ctl(op="stats")
        self.diags = {d.kind: self.shims.diag(d.handle) for d in self.devs}
        return self.report()

    def final_recovery(self):
        """Every device must answer a plain read again by itself, within 60 s."""
        for dev in self.devs:
            fc, addr, count = dev.reads[0]
            deadline = time.monotonic() + 60
            ok = False
            while time.monotonic() < deadline and not ok:
                h = self.shims.post(dev.handle, fc, addr, count)
                self.final_reads += 1
                while self.shims.lib.mbfb_poll(h) not in (REQ_DONE, REQ_FAILED):
                    time.sleep(0.002)
                rc, _ = self.shims.take(h, count)
                ok = rc >= 0
                if not ok:
                    time.sleep(0.1)
            if ok:
                now = time.monotonic()
                for item in list(self.pending_recovery):
                    kind, pdev, since = item
                    if pdev is None or pdev is dev:
                        self.recovery[kind].append(now - since)
                        self.pending_recovery.remove(item)
            else:
                self.unrecovered += 1

    def report(self):
        s = self.stats
        for rec in self.writes:
            if rec["received"] >= 2:
                key = "doubled_once" if rec["policy"] == WRITE_ONCE else "doubled_idempotent"
                s[key] += 1
                if rec["policy"] == WRITE_ONCE:
                    self.note_write(f"applied {rec['received']} times", self.by_addr[rec["dev"]],
                                    rec, rec["values"])
            if rec["applied"] and rec["received"] == 0:
                s["log_inconsistent"] += 1
                if len(self.log_examples) < 10:
                    self.log_examples.append({k: rec[k] for k in ("dev", "fc", "addr", "values",
                                                                  "result")})
        self.unrecovered += len(self.pending_recovery)
        applied = {}
        for dev in self.sim_stats["devices"].values():
            for k, v in dev.get("faults", {}).items():
                applied[k] = applied.get(k, 0) + v
        resyncs = sum(d.resyncs for d in self.diags.values())
        retries = sum(d.retries for d in self.diags.values())
        faults = sum(self.injected.values())
        char_s = (1 + 8 + (self.a.format[1] != "N") + int(self.a.format[2])) / self.a.baud
        bus_s = self.line_bytes * char_s + self.line_frames * 3.5 * char_s

        def dist(xs):
            if not xs:
                return None
            xs = sorted(xs)
            return {"n": len(xs), "median_s": round(statistics.median(xs), 3),
                    "p99_s": round(xs[min(len(xs) - 1, int(len(xs) * 0.99))], 3),
                    "max_s": round(xs[-1], 3)}
        out = {
            "shims": {"post_write": self.shims.has_post_write,
                      "lib": os.path.basename(self.a.lib)},
            "line": f"{self.a.baud} {self.a.format}{' paced' if self.a.pace else ''}",
            "seed": self.a.seed, "fault_rate": self.a.fault_rate,
            "elapsed_s": round(self.elapsed, 1),
            **{k: v for k, v in s.items() if k != "results"},
            "results": {str(k): v for k, v in sorted(s["results"].items())},
            "faults_injected": self.injected, "faults_applied_by_sim": applied,
            "unrecovered": self.unrecovered,
            "recovery": {k: dist(v) for k, v in self.recovery.items()},
            "bus": {"request_frames_seen_by_sim": self.rx_frames,
                    "line_frames": self.line_frames, "line_bytes": self.line_bytes,
                    "bus_time_s": round(bus_s, 2),
                    "bus_ms_per_transaction": round(1000 * bus_s / max(1, s["transactions"]), 3),
                    "retries": retries, "resyncs": resyncs,
                    "extra_frames_per_fault": round((self.rx_frames - s["transactions"] -
                                                     self.final_reads) /
                                                    max(1, faults), 2)},
            "wrong_examples": self.wrong_examples, "log_examples": self.log_examples, "write_examples": self.write_examples,
        }
        return out


def print_report(r):
    p = print
    p(f"soak: {r['transactions']} transactions ({r['reads']} reads, {r['writes']} writes) in "
      f"{r['elapsed_s']} s on {r['line']}, seed {r['seed']}, fault rate {r['fault_rate']}")
    p(f"  shims: mbfb_post_write {'yes' if r['shims']['post_write'] else 'no (old shims)'}")
    p("  faults injected: " + ", ".join(f"{k} {v}" for k, v in r["faults_injected"].items()))
    p("  reply faults applied by the simulator: " +
      ", ".join(f"{k} {v}" for k, v in sorted(r["faults_applied_by_sim"].items())))
    p(f"  not sent: device in back-off {r['not_sent_offline']} (of them while the device could "
      f"answer: {r['not_sent_offline_device_able']}), port not there {r['not_sent_noport']}")
    p(f"  results: " + ", ".join(f"{k}: {v}" for k, v in r["results"].items()))
    p(f"  WRONG VALUES delivered as good:    {r['wrong_values']}  (of {r['good_reads']} good reads)")
    p(f"  writes lost (Done, not applied):   {r['writes_lost']}  (of {r['writes_done']} Done)")
    p(f"  non-idempotent writes applied 2+:  {r['doubled_once']}")
    p(f"  idempotent writes applied 2+:      {r['doubled_idempotent']}")
    p(f"  reported failed but applied:       {r['writes_failed_applied']}  (of {r['writes_failed']} failed)")
    p(f"  unconfirmed (MBFB_E_UNCONFIRMED):  {r['unconfirmed']}  (of which applied: {r['unconfirmed_applied']}; "
      f"heard by the device only after the master gave up: {r['unconfirmed_applied_late']})")
    p(f"  outages not recovered:             {r['unrecovered']}")
    p(f"  log inconsistencies:               {r['log_inconsistent']}")
    names = {"master_share": "any of these, from when the device could answer"}
    for k, v in r["recovery"].items():
        if v:
            p(f"  recovery after {names.get(k, k)}: n {v['n']}, median {v['median_s']} s,"
              f" p99 {v['p99_s']} s, max {v['max_s']} s")
    if r.get("master_share_clamped"):
        p(f"  (of them {r['master_share_clamped']} answered before the soak's bound, counted 0)")
    b = r["bus"]
    p(f"  bus: {b['request_frames_seen_by_sim']} request frames for {r['transactions']} "
      f"transactions; retries {b['retries']}, resyncs {b['resyncs']}; "
      f"{b['extra_frames_per_fault']} extra request frames per fault; bus time "
      f"{b['bus_time_s']} s, {b['bus_ms_per_transaction']} ms per transaction")
    for ex in r["wrong_examples"][:5]:
        p(f"  wrong: {ex}")
    for ex in r["write_examples"][:12]:
        p(f"  write: {ex}")
    for ex in r["log_examples"][:5]:
        p(f"  applied but not in the log: {ex}")


def failed(r) -> bool:
    return any(r[k] for k in ("wrong_values", "writes_lost", "doubled_once",
                              "writes_failed_applied", "unrecovered"))


def main(argv=None):
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))   # stop the simulator on SIGTERM
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", "--transactions", type=int, default=100000)
    ap.add_argument("--fault-rate", type=float, default=0.05)
    ap.add_argument("--write-share", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--baud", type=int, default=9600)
    ap.add_argument("--format", default="8N2")
    ap.add_argument("--pace", action="store_true", help="pace the line like RS-485 (slower)")
    ap.add_argument("--late-min-ms", type=float, default=50)
    ap.add_argument("--late-max-ms", type=float, default=5000)
    ap.add_argument("--outage-min-s", type=float, default=1.0)
    ap.add_argument("--outage-max-s", type=float, default=5.0)
    ap.add_argument("--lib", default=os.environ.get("MBFB_SOAK_LIB"),
                    help="the shims as a shared library (build target mbfb_soak_lib)")
    ap.add_argument("--sim-dir", help="folder of simctl.py (default: tools/sim, else tests/sim)")
    ap.add_argument("--faults-in-backoff", action="store_true",
                    help="inject faults and events also while the shims hold the device in "
                         "back-off (reply faults then wait for its next reply)")
    ap.add_argument("--trace", help="write every request, result and frame to this file")
    ap.add_argument("--json", help="also write the figures to this file")
    ap.add_argument("--progress", type=float, default=0, help="progress line every N s")
    a = ap.parse_args(argv)
    if a.transactions < 1 or not 0 <= a.fault_rate <= 1 or not 0 <= a.write_share <= 1:
        die("bad --transactions/--fault-rate/--write-share")
    if len(a.format) != 3 or a.format[0] != "8" or a.format[1] not in "NEO" or a.format[2] not in "12":
        die(f"bad --format {a.format!r} (8N1, 8N2, 8E1, ...)")
    if not a.lib or not os.path.exists(a.lib):
        die("the shims library is needed: --lib PATH or MBFB_SOAK_LIB (cmake target mbfb_soak_lib)")
    simctl = find_simctl(a.sim_dir)
    shims = Shims(a.lib)
    r = Soak(a, simctl, shims).run()
    print_report(r)
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(r, fh, indent=1)
    return 1 if failed(r) else 0


if __name__ == "__main__":
    sys.exit(main())
