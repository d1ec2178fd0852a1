"""The commissioning tool's work on a line: scan, backup, differences, restore."""
from __future__ import annotations

import json
import os
import sys
import time

import instruments as ins
from shims import E_BADREPLY, E_CRC, E_EXCEPTION_BASE, E_NOPORT, E_PORTLOST, E_TIMEOUT

# The manuals' factory line settings. A UART checks one stop bit only, so the 8N2 probe also
# reaches 8N1 devices; the MT-S9's manual states no factory line: 9600 in ASCII (its RTU and
# RTU-without-CRC units answer the 8N2 RTU probe).
FACTORY = [(9600, "8N2", "rtu"),     # MV-D94 / VD: 9600 8N2 (manual 2.1, 4.1)
           (9600, "8E1", "rtu"),     # FDC-100: 9600 8E1 (manual Example 1)
           (9600, "8N1", "ascii")]   # MT-S9 in ASCII
# The models a factory setting is for: their factory address is probed first on it.
FACTORY_MODELS = {FACTORY[0]: ("mvd94", "mts9"), FACTORY[1]: ("fdc100",), FACTORY[2]: ("mts9",)}
FORMATS = ["8N1", "8N2", "8E1", "8O1", "8E2", "8O2", "7N2", "7E1", "7O1", "7E2", "7O2"]
MAX_RUN = 32          # words per backup read (the FDC's own limit is uncertain: 79 or 80)
EXIT_PORT, EXIT_DEVICE = 3, 4
# The reply timeout where something answered: a scan's probe that was answered, garbled or
# answered by another address is worked out again with it, and backup/restore use it. A device
# on a busy line (or a simulator on a loaded machine) may answer later than the shims' shortest
# timeout; its reply must then be neither lost nor taken for another address's. Silent addresses
# keep the short timeout (the sweep's time); this costs time only where something answered.
SLOW_TIMEOUT_MS = 500
SLOW_RETRIES = 1


class LineError(Exception):
    """One line for the user and an exit status (see mbcommission.py)."""

    def __init__(self, status: int, text: str):
        super().__init__(text)
        self.status = status


def all_bauds() -> list:
    return sorted({b for m in ins.maps().values() for b in m.line["bauds"]})


def probe_seconds(baud: int, fmt: str, framing: str) -> float:
    """Time one probe of an absent address costs: the request, the shims' shortest reply
    timeout for it (c_shims/src/mbfb_timing.c: 2 x (frames + 10 ms), at least 50 ms)."""
    bits = 1 + int(fmt[0]) + (fmt[1] != "N") + int(fmt[2])
    char = bits / baud
    frames = 8 + 7 if framing != "ascii" else 17 + 15
    timeout = max(0.05, 2 * (frames * char + 0.01))
    return 8 * char + timeout + 3.5 * char


def settings_to_try(args) -> list:
    """The line settings of a scan, the factory ones first, narrowed by the options."""
    full = [(b, f, fr) for fr in ("rtu", "ascii", "nocrc") for b in all_bauds() for f in FORMATS
            if not (fr != "ascii" and f[0] == "7")]
    narrowed = args.baud or args.format or args.framing
    order = FACTORY + ([s for s in full if s not in FACTORY] if args.full or narrowed else [])
    return [s for s in order if (not args.baud or s[0] in args.baud) and
            (not args.format or s[1] in [f.upper() for f in args.format]) and
            (not args.framing or s[2] in args.framing)]


def factory_addresses(setting) -> list:
    """The factory addresses of the models a factory setting is for: the default of each map's
    address register (MV-D94 ADDR 27, FDC ADDR 39, MT-S9 ID Address Set 6: 1 for all three)."""
    return sorted({ins.maps()[k].reg("ADDR").default for k in FACTORY_MODELS.get(setting, ())})


def passes(todo: list, addrs: list) -> list:
    """The scan in passes: [(title, [(setting, addresses)])]. First the factory settings at the
    factory addresses (seconds), then the factory settings at the other addresses, then every
    other setting (with --full or when narrowed) at all of them."""
    factory = [s for s in todo if s in FACTORY]
    first = [(s, [a for a in addrs if a in factory_addresses(s)]) for s in factory]
    first = [(s, a) for s, a in first if a]
    done = {(s, a) for s, al in first for a in al}
    rest = [(s, [a for a in addrs if (s, a) not in done]) for s in factory]
    out = [("factory settings at the factory address", first),
           ("factory settings at the other addresses", [(s, a) for s, a in rest if a]),
           ("the other line settings", [(s, addrs) for s in todo if s not in FACTORY])]
    return [(title, plan) for title, plan in out if plan]


def plan_seconds(plan) -> float:
    return sum(probe_seconds(*s) * len(a) for s, a in plan)


def addresses(text: str) -> list:
    out = []
    try:
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            out += range(int(lo), int(hi or lo) + 1)
    except ValueError:
        raise LineError(2, f"--address {text!r}: expected N, N-M or a comma list") from None
    if not out or min(out) < 1 or max(out) > 247:
        raise LineError(2, f"--address {text!r}: addresses are 1..247")
    return out


def check_port(port: str) -> None:
    if not port.startswith("tcp://") and not os.path.exists(port):
        raise LineError(EXIT_PORT, f"{port}: no such port")


_PROBE_BUS: dict = {}     # the line of the scan's probes, by setting (open_line closes it)


def open_line(lib, port, baud, fmt, framing, retries=-1, timeout_ms=0) -> int:
    """A fresh bus (every bus before it is closed: a new line setting needs a new bus)."""
    _PROBE_BUS.clear()
    lib.shutdown()
    bus = lib.open_bus(port, baud, fmt[1], int(fmt[0]), int(fmt[2]), framing, timeout_ms,
                       retries)
    if bus < 0:
        raise LineError(2, f"{port} at {baud} {fmt} {framing}: {lib.strerror(-bus)}")
    return bus


def reader(lib, dev):
    def read(fc, addr, count):
        rc, words = lib.read(dev, fc, addr, count)
        if rc in (E_NOPORT, E_PORTLOST):
            raise LineError(EXIT_PORT, f"port: {lib.strerror(rc)}")
        return rc, words
    return read


def scan(lib, args) -> list:
    """[((baud, format, framing), Found)] of every instrument that answered, in passes: the
    factory settings at the factory addresses first, then the rest (see passes)."""
    from tqdm import tqdm
    check_port(args.port)
    todo, addrs = settings_to_try(args), addresses(args.address)
    plan = passes(todo, addrs)
    total = sum(plan_seconds(p) for _, p in plan)
    print(f"{len(todo)} line setting(s) x {len(addrs)} address(es): at least {total:.0f} s "
          f"(each silent address costs a request and the shims' shortest reply timeout)")
    if args.settle:
        print("  --settle: each silent address also owes one more reply timeout: about twice that")
    for i, (title, p) in enumerate(plan, 1):
        probes = sum(len(a) for _, a in p)
        print(f"  pass {i}: {title}: {probes} probe(s), at least {plan_seconds(p):.1f} s",
              flush=True)
    found, seen = [], set()
    bar = tqdm(total=round(total, 1), unit="s", disable=args.no_progress, leave=False,
               bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]")
    t0 = time.monotonic()
    try:
        _passes(lib, args, plan, bar, found, seen, t0)
    except KeyboardInterrupt:       # Ctrl-C: what was found so far is still reported
        bar.close()
        lib.shutdown()
        raise Interrupted(found) from None
    bar.close()
    lib.shutdown()
    return found


class Interrupted(Exception):
    """A scan stopped with Ctrl-C; .found: what it had found."""

    def __init__(self, found: list):
        super().__init__("interrupted")
        self.found = found


def _passes(lib, args, plan, bar, found, seen, t0):
    from tqdm import tqdm
    for i, (title, p) in enumerate(plan, 1):
        for setting, pass_addrs in p:
            baud, fmt, framing = setting
            bar.set_description(f"pass {i}/{len(plan)} {baud} {fmt} {framing}")
            silent = []                      # (time sent, address) of its silent probes
            for a in pass_addrs:
                sent = time.monotonic()
                rc, read, dev = probe(lib, args, setting, a, fresh=not args.settle)
                bar.update(probe_seconds(baud, fmt, framing))
                if args.settle:
                    _identify(read, rc, a, setting, found, seen, tqdm)
                elif rc == E_TIMEOUT and not lib.stray_bytes(dev):
                    silent.append((sent, a))
                else:
                    # answered, garbled, answered by another address, or bytes heard before
                    # the request: the answer may be a late reply of an address probed before
                    # (within the slow timeout), or of an earlier request to this one, and
                    # bytes heard before it a late reply dropped. Those and this one again.
                    window = SLOW_TIMEOUT_MS / 1000 + probe_seconds(baud, fmt, framing)
                    again = [b for t, b in silent if sent - t < window] if rc in (
                        E_CRC, E_BADREPLY, E_TIMEOUT) else []
                    _recheck(lib, args, setting, again + [a], found, seen, tqdm)
                    silent = []
        tqdm.write(f"pass {i} done ({title}) after {time.monotonic() - t0:.1f} s: "
                   f"{len(found)} instrument(s) found so far")
        sys.stdout.flush()


def _recheck(lib, args, setting, addrs, found, seen, tqdm) -> None:
    """Probe addrs again and identify what answers, on a line with the slow timeout and a
    retry: first the line is left silent for that timeout (a late reply still under way is
    heard and dropped by the shims before the request), and after each silent address the
    shims owe the settle (its late reply cannot be taken for the next one's). What answered
    the first probe but not this one was another request's late reply: not reported."""
    baud, fmt, framing = setting
    bus = open_line(lib, args.port, baud, fmt, framing, retries=SLOW_RETRIES,
                    timeout_ms=SLOW_TIMEOUT_MS)
    time.sleep(SLOW_TIMEOUT_MS / 1000)
    for b in addrs:
        read = reader(lib, lib.open_device(bus, b))
        rc, _ = read(3, 0, 1)
        if rc in (E_CRC, E_BADREPLY):
            tqdm.write(f"a garbled or foreign reply at {b}, {baud} {fmt} {framing.upper()}, "
                       f"again after {SLOW_TIMEOUT_MS} ms of silence: noise, or a device "
                       "slower than that")
        _identify(read, rc, b, setting, found, seen, tqdm)


def probe(lib, args, setting, a, fresh: bool):
    """One FC03 of register 0 at address a, one attempt: (rc, read, device handle). fresh: on a line opened
    for it, so that it owes no settle (the shims' response timeout of silence after a request
    another address left unanswered, which would double the cost of every silent address);
    else on the line of the probe before (opened when the setting changes)."""
    baud, fmt, framing = setting
    bus = _PROBE_BUS.get(setting)
    if fresh or bus is None:
        bus = open_line(lib, args.port, baud, fmt, framing, retries=0)
        _PROBE_BUS[setting] = bus
    dev = lib.open_device(bus, a)
    read = reader(lib, dev)
    rc, _ = read(3, 0, 1)
    return rc, read, dev


def _identify(read, rc, a, setting, found, seen, tqdm) -> None:
    """After a probe that was answered (data or an exception): which instrument, into found."""
    baud, fmt, framing = setting
    if rc != 0 and rc < E_EXCEPTION_BASE:
        return
    f = ins.identify(read, a, baud, fmt, framing)
    if f is None:
        f = ins.Found("unknown", a, [f"answered FC03 at 0 ({'exception %d' % (rc - 128) if rc else 'data'});"
                                     " fits none of MV-D94/VD, MT-S9, FDC-100"], framing=framing)
        tqdm.write(f"unknown Modbus device at {a}, {baud} {fmt} {framing.upper()}")
    k = (a, f.kind, baud, f.framing)
    if k not in seen:
        seen.add(k)
        found.append((setting, f))


def _find(lib, args):
    """Open the line of args and identify the instrument at args.address:
    (read, Found, format, device handle)."""
    check_port(args.port)
    for fmt in [args.format.upper()] if args.format else ["8N2", "8E1", "8N1"]:
        bus = open_line(lib, args.port, args.baud, fmt, args.framing,
                        timeout_ms=SLOW_TIMEOUT_MS)
        dev = lib.open_device(bus, args.address)
        read = reader(lib, dev)
        f = ins.identify(read, args.address, args.baud, fmt, args.framing)
        if f is not None:
            return read, f, fmt, dev
    raise LineError(EXIT_DEVICE, f"none of MV-D94/VD, MT-S9, FDC-100 answers at {args.address}, "
                    f"{args.baud} {args.format or '8N2/8E1/8N1'} {args.framing.upper()}")


def backup(lib, args) -> dict:
    """Every FC03 register of the instrument at args.address, raw and in engineering units."""
    read, f, fmt, _ = _find(lib, args)
    m = ins.maps()[f.kind]
    regs = ins.readable(f.kind)
    words, run = {}, []
    for r in regs + [None]:
        if run and (r is None or r.addr != run[-1].addr + run[-1].words or
                    r.addr + r.words - run[0].addr > MAX_RUN):
            first, n = run[0].addr, run[-1].addr + run[-1].words - run[0].addr
            rc, w = read(3, first, n)
            if rc != 0:
                raise LineError(5, f"{f.model} at {args.address} stopped answering: reading "
                                f"{first}..{first + n - 1}: {lib.strerror(rc)}")
            for x in run:
                words[x.name] = m.decode_words(x, w[x.addr - first:x.addr - first + x.words])
            run = []
        if r is not None:
            run.append(r)
    state = {k: v for k, v in words.items() if k in ("DP", "INPT", "ALFN")}
    return {"tool": "mbcommission backup", "kind": f.kind, "model": f.model,
            "firmware": f.firmware, "identified_by": f.evidence,
            "line": {"port": args.port, "address": args.address, "baud": args.baud,
                     "format": f.format or fmt, "framing": f.framing},
            "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "registers": {r.name: ins.describe(f.kind, r, words[r.name], state) for r in regs}}


def write_backup(path: str, data: dict) -> None:
    """JSON with one register per line, in address order: readable and diffable."""
    head = {k: v for k, v in data.items() if k != "registers"}
    lines = [f"  {json.dumps(k)}: {json.dumps(v, sort_keys=True)}" for k, v in head.items()]
    regs = sorted(data["registers"].items(), key=lambda kv: kv[1]["addr"])
    body = ",\n".join(f"    {json.dumps(k)}: {json.dumps(v, sort_keys=True)}" for k, v in regs)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("{\n" + ",\n".join(lines) + ',\n  "registers": {\n' + body + "\n  }\n}\n")


def show(entry: dict) -> str:
    if "code" in entry:
        return f"{entry['code']} ({entry['raw']})"
    return f"{entry.get('value', entry['raw'])} {entry.get('unit', '')}".strip()


def differences(have: dict, want: dict) -> list:
    """[(name, have shown, want shown)] of the restorable settings that differ, restore order."""
    lock = [ins.LOCK[have["kind"]][0]] if have["kind"] in ins.LOCK else []
    names = [r.name for r in ins.settings(have["kind"])] + lock
    return [(n, show(have["registers"][n]), show(want["registers"][n])) for n in names
            if n in want["registers"] and have["registers"][n]["raw"] != want["registers"][n]["raw"]]


def write_checked(lib, read, dev, addr: int, raw: int):
    """FC06 of raw to addr, read back with FC03: None when the device holds it, else why not."""
    rc = lib.write(dev, addr, raw)
    if rc == 0:
        rc, w = read(3, addr, 1)
        if rc == 0 and w[0] != raw & 0xFFFF:
            return f"read back {w[0]}, not {raw & 0xFFFF}"
    return None if rc == 0 else lib.strerror(rc)


def restore(lib, args, have: dict, want: dict):
    """Write what differs, each read back: (written names, None) or (written, (name, error))."""
    read, f, _, dev = _find(lib, args)
    m, kind, done = ins.maps()[f.kind], f.kind, []

    def put(name, raw):
        return write_checked(lib, read, dev, m.reg(name).addr, raw)

    rows = differences(have, want)
    prelude = []                        # access first: unlock, or raise the author level
    if kind in ins.LOCK and have["registers"][ins.LOCK[kind][0]]["raw"] != ins.LOCK[kind][1]:
        prelude.append(ins.LOCK[kind])
    if kind in ins.AUTHOR:
        prelude.append(ins.AUTHOR[kind])
    for name, raw in prelude:
        err = put(name, raw)
        if err:
            return done, (name, err)
    for name, _, _ in rows:
        err = put(name, want["registers"][name]["raw"])
        if err:
            return done, (name, err)
        done.append(name)
    if kind in ins.AUTHOR:              # the author level back to what it was
        name = ins.AUTHOR[kind][0]
        err = put(name, have["registers"][name]["raw"])
        if err:
            return done, (name, err)
    elif kind in ins.LOCK and ins.LOCK[kind][0] not in done:
        name = ins.LOCK[kind][0]        # locked before and unchanged by the backup: lock again
        if have["registers"][name]["raw"] != ins.LOCK[kind][1]:
            err = put(name, have["registers"][name]["raw"])
            if err:
                return done, (name, err)
    return done, None


# The FDC's programming-port download (manual Example 1): one FC16 of the parameter block,
# 0x34 words from address 0 (SP1 .. SEL8), at 9600 8E1.
DOWNLOAD = {"fdc100": (0, 0x34)}


def download_block(kind: str, have: dict, want: dict) -> list:
    """The words of the block: the backup's, but the target's own line registers (ADDR, BAUD,
    DATA, PARI, STOP, COMM: the unit stays on its line at its address) and its lock as it is
    now (opened before, set after). KeyError names a register the backup lacks."""
    start, count = DOWNLOAD[kind]
    by_addr = {e["addr"]: (n, e) for n, e in want["registers"].items()}
    keep = ins.LINE_REGS[kind] | {ins.LOCK[kind][0]}
    words = []
    for a in range(start, start + count):
        if a not in by_addr:
            raise KeyError(f"register {a}")
        name, entry = by_addr[a]
        words.append(have["registers"][name]["raw"] if name in keep else entry["raw"])
    return words


def download(lib, args, have: dict, want: dict):
    """The block in one FC16, the lock opened before it and set to the backup's after; each
    step read back. (steps done, None) or (steps done, (step, error))."""
    read, f, _, dev = _find(lib, args)
    kind, m = f.kind, ins.maps()[f.kind]
    start, count = DOWNLOAD[kind]
    words = download_block(kind, have, want)
    lock, unlocked = ins.LOCK[kind]
    done = []

    def put(name, raw):
        return write_checked(lib, read, dev, m.reg(name).addr, raw)

    if have["registers"][lock]["raw"] != unlocked:
        words[m.reg(lock).addr - start] = unlocked
        err = put(lock, unlocked)
        if err:
            return done, (f"{lock} (unlock)", err)
        done.append(f"{lock} opened")
    rc = lib.write_block(dev, start, words)
    if rc != 0:
        return done, (f"FC16 of {count} words at {start}", lib.strerror(rc))
    back = []
    for a in range(start, start + count, MAX_RUN):
        n = min(MAX_RUN, start + count - a)
        rc, w = read(3, a, n)
        if rc != 0:
            return done, ("read-back of the block", lib.strerror(rc))
        back += w
    wrong = [m.reg(start + i).name for i, (x, y) in enumerate(zip(words, back)) if x != y]
    if wrong:
        return done, ("read-back of the block", f"differs at {', '.join(wrong)}")
    done.append(f"block of {count} words at {start} (read back)")
    want_lock = want["registers"][lock]["raw"]
    if want_lock != unlocked:
        err = put(lock, want_lock)
        if err:
            return done, (lock, err)
        done.append(f"{lock} = {want_lock}")
    return done, None
