"""Shared base of the device models: a register table with access, range and scaling metadata,
the Modbus PDU handling for FC 03/04/06/16, and the engineering-unit conversions.

The registers, code tables, windows and scales come from the register maps in maps/*.json
(maps/README.md), loaded by maps/mbmap.py: no register table lives here. Each model
(mvd94.py, mts9.py, fdc100.py) overrides only what its manual makes different in behaviour:
address windows, access rules, exception choices, side effects.
"""
from __future__ import annotations

import os
import struct
import sys
from dataclasses import dataclass, field

# maps/ of this checkout (tools/sim/modsim -> the repository root), or $MBFB_MAPS.
MAPS_DIR = os.environ.get("MBFB_MAPS") or os.path.join(
    os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))),
    "maps")
if MAPS_DIR not in sys.path:
    sys.path.insert(0, MAPS_DIR)
import mbmap  # noqa: E402  (maps/mbmap.py)

ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE = 1, 2, 3
ANY_LINE = "any"        # Device.hears: no serial line at all (Modbus/TCP)


class ModbusError(Exception):
    """Raised by a model to answer with an exception reply (code 1, 2 or 3)."""

    def __init__(self, code: int, why: str = ""):
        super().__init__(f"exception {code}: {why}")
        self.code = code


@dataclass
class Reg:
    """One register (or a 32-bit pair, words=2, low word first as on the MT-S9)."""
    addr: int
    name: str
    access: str = "RW"             # "R" or "RW"; models refine it (manual mode, locks, Author)
    lo: int | None = None          # raw range in the register's own sign; None = not checked
    hi: int | None = None
    signed: bool = False
    scale: str = "raw"             # key the model maps to (decimals, offset); see Device.scaling
    codes: dict = field(default_factory=dict)  # index-code registers: label -> code
    default: int = 0
    words: int = 1
    aliases: tuple = ()
    within: tuple = ()             # names of the limits the value must lie within (the map's)

    def from_words(self, words: list[int]) -> int:
        """Raw value (signed if the register is) from its 16-bit words, low word first."""
        value = 0
        for i, word in enumerate(words):
            value |= (word & 0xFFFF) << (16 * i)
        bits = 16 * self.words
        if self.signed and value >= 1 << (bits - 1):
            value -= 1 << bits
        return value

    def to_words(self, value: int) -> list[int]:
        """16-bit words (low word first) of a raw value."""
        value &= (1 << (16 * self.words)) - 1
        return [(value >> (16 * i)) & 0xFFFF for i in range(self.words)]


def load_map(device: str):
    """The device's register map (mbmap.Map) from maps/."""
    return mbmap.load(device, MAPS_DIR)


ACCESS = {"R": "R", "RW": "RW", "RW in manual mode": "MAN", "RW after CMND = 0x682D": "CAL"}


def regs_from_map(m) -> tuple:
    """Reg objects of a map: access R/RW (MAN, CAL: conditional, see fdc100.py), raw range,
    sign, scale key, the index codes of its table, the default, words and aliases."""
    out = []
    for r in m.registers:
        if r.access not in ACCESS:
            raise mbmap.MapError(f"{m.device} {r.name}: access {r.access!r} unknown to the simulator")
        codes = dict(m.table(r.codes)) if r.codes and r.scale in ("code", "dpcode") else {}
        lo, hi = r.range if r.range is not None else (None, None)
        out.append(Reg(r.addr, r.name, ACCESS[r.access], lo=lo, hi=hi, signed=r.signed,
                       scale=r.scale, codes=codes, default=r.default, words=r.words,
                       aliases=r.aliases, within=r.within))
    return tuple(out)


class Device:
    """A Modbus slave model. Subclasses set KIND and MAP (the device's register map: REGS
    and FUNCTIONS follow from it) and override hooks."""

    KIND = "?"
    MAP = None
    REGS: tuple = ()
    FUNCTIONS = (3, 6)               # supported function codes; anything else -> exception 01

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if "MAP" in cls.__dict__:
            cls.REGS = regs_from_map(cls.MAP)
            cls.FUNCTIONS = cls.MAP.function_codes

    def __init__(self, addr: int, line, rng):
        self.addr = addr
        self.line = line             # LineSettings: baud, format, framing, time_scale
        self.rng = rng
        self.regs = {r.addr: r for r in self.REGS}
        self.by_name = {}
        for r in self.REGS:
            for key in (r.name, *r.aliases):
                self.by_name[key.upper()] = r
        self.words: dict[int, int] = {}
        self.load_defaults()
        self.stats = {"requests": 0, "replies": 0, "exceptions": 0, "broadcasts": 0,
                      "ignored": 0, "line_mismatch": 0, "faults_applied": 0}

    # ----- state -----
    def load_defaults(self):
        """Factory values of every register."""
        for r in self.REGS:
            for i, w in enumerate(r.to_words(r.default)):
                self.words[r.addr + i] = w

    def finish(self):
        """Hook: called once the start-up options are taken; ValueError if one is missing."""

    def power_cycle(self):
        """Reset volatile state. Default: registers are non-volatile (EEPROM), nothing to do."""

    def tick(self, dt: float):
        """Advance the model's dynamics by dt seconds of simulated time."""

    def char_format(self) -> tuple:
        """(baud, data bits, parity, stop bits) the device speaks, from its own comm registers;
        None where the manual does not say (the line's setting is taken). Default: the line."""
        return self.line.baud, self.line.data_bits, self.line.parity, self.line.stop_bits

    @property
    def framing(self) -> str:
        """The framing the device speaks: RTU (the MT-S9 overrides it: its Type register)."""
        return "rtu"

    def hears(self, master: dict | None = None) -> bool:
        """Does a frame sent by this master reach the device as sent? `master` holds the
        character format the master's port is set to, as far as the transport can see it
        (on a pty: the baud; parity and data bits are invisible there and taken from the line,
        --format). None: the line itself (TCP, a real serial port). A device whose baud, data
        bits or parity differ hears garbage and stays silent, like a UART with framing or
        parity errors. Stop bits are not compared: a UART checks only the first stop bit, so a
        master at 8N1 and a device at 8N2 understand each other."""
        if master == ANY_LINE:
            return True
        seen = {"baud": self.line.baud, "data": self.line.data_bits, "parity": self.line.parity}
        if master:
            seen.update(master)
        own = dict(zip(("baud", "data", "parity"), self.char_format()[:3]))
        return all(v is None or v == seen[k] for k, v in own.items())

    # ----- register access by name/number (control protocol, start-up options) -----
    def lookup(self, key) -> Reg:
        """Register by name (case-insensitive), by number, or by a numeric string."""
        if isinstance(key, int) or (isinstance(key, str) and key.strip().lstrip("-").isdigit()):
            num = int(key)
            if num in self.regs:
                return self.regs[num]
            for r in self.REGS:
                if r.addr <= num < r.addr + r.words:
                    return Reg(num, f"word {num}", r.access)
            raise KeyError(f"{self.KIND} has no register {num}")
        reg = self.by_name.get(str(key).strip().upper())
        if reg is None:
            raise KeyError(f"{self.KIND} has no register named {key!r}")
        return reg

    def reg_words(self, reg: Reg) -> list[int]:
        """The words of a register as a master would read them (control 'get')."""
        return self.read_words(reg.addr, reg.words)

    def get_raw(self, reg: Reg) -> int:
        """Raw value as a master would read it (signed registers come back signed)."""
        return reg.from_words(self.read_words(reg.addr, reg.words))

    def set_raw(self, reg: Reg, value: int):
        """Store a raw value, bypassing access rules (control 'set', start-up options)."""
        for i, w in enumerate(reg.to_words(int(value))):
            self.store(reg.addr + i, w)

    def store(self, addr: int, word: int):
        """Hook: where a word really lives (aliases, live values). Default: the word table."""
        self.words[addr] = word & 0xFFFF

    def read_words(self, addr: int, count: int) -> list[int]:
        """Current words (live values included); the window checks are done by the caller."""
        return [self.word(a) for a in range(addr, addr + count)]

    def word(self, addr: int) -> int:
        """Hook: one word as read. Default: the word table (0 where nothing is defined)."""
        return self.words.get(addr, 0)

    # ----- engineering units -----
    def scaling(self, reg: Reg) -> tuple[int, int]:
        """(decimals, offset) of a register: eng = (raw - offset) / 10**decimals."""
        return 0, 0

    def to_eng(self, reg: Reg, raw: int) -> float:
        dec, off = self.scaling(reg)
        return (raw - off) / 10 ** dec

    def from_eng(self, reg: Reg, value) -> int:
        """Raw value of an engineering value (a number, or an index-code label)."""
        if isinstance(value, str):
            text = value.strip()
            for label, code in reg.codes.items():
                if label.upper() == text.upper():
                    return code
            if text.lower().startswith("0x"):
                return int(text, 16)
            value = float(text)
        dec, off = self.scaling(reg)
        return int(round(value * 10 ** dec)) + off

    def set_eng(self, name: str, value):
        """Start-up option NAME=VALUE; the range is checked like a master's write would be."""
        reg = self.lookup(name)
        try:
            raw = self.from_eng(reg, value)
        except (ValueError, OverflowError):
            codes = f" or one of {', '.join(reg.codes)}" if reg.codes else ""
            raise ValueError(f"{self.KIND}:{self.addr}: {name}={value}: not a number{codes}") \
                from None
        if not self.in_range(reg, raw):
            raise ValueError(f"{self.KIND}:{self.addr}: {name}={value} (raw {raw}) is out of range")
        self.set_raw(reg, raw)

    def option(self, name: str, value: str) -> bool:
        """Hook for non-register start-up options (framing=, rate=, ...). True if consumed."""
        return False

    def in_range(self, reg: Reg, raw: int) -> bool:
        """Range check of a raw value (already in the register's sign)."""
        if reg.codes and raw not in reg.codes.values():
            return False
        if reg.lo is not None and raw < reg.lo:
            return False
        if reg.hi is not None and raw > reg.hi:
            return False
        if reg.within:               # a set point within its limits (the map's "within")
            low, high = (self.limit_raw(self.by_name[n.upper()]) for n in reg.within)
            return low <= raw <= high
        return True

    def limit_raw(self, reg: Reg) -> int:
        """A limit's raw value for the within check (the FDC: as after the FC16 being checked)."""
        return self.get_raw(reg)

    # ----- Modbus PDU handling -----
    def handle(self, pdu: bytes, broadcast: bool = False) -> bytes | None:
        """Apply a request PDU; return the reply PDU (None: no reply, e.g. broadcast)."""
        self.stats["broadcasts" if broadcast else "requests"] += 1
        fc = pdu[0]
        try:
            if fc not in self.FUNCTIONS:
                raise ModbusError(ILLEGAL_FUNCTION, f"function {fc:#04x} not supported")
            if broadcast and not self.broadcast_allowed(fc):
                return None
            reply = self.dispatch(fc, pdu[1:])
        except ModbusError as err:
            self.on_exception(err.code)
            if broadcast:
                return None
            self.stats["exceptions"] += 1
            return bytes([fc | 0x80, err.code])
        return None if broadcast else reply

    def broadcast_allowed(self, fc: int) -> bool:
        """Broadcast applies writes only; reads are 'not possible' (ignored)."""
        return fc in (5, 6, 15, 16)

    def on_exception(self, code: int):
        """Hook: a model may record an error code (FDC EROR)."""

    def dispatch(self, fc: int, data: bytes) -> bytes:
        if fc in (3, 4):
            start, count = self._unpack(data, ">HH")
            values = self.read_block(fc, start, count)
            return bytes([fc, 2 * len(values)]) + struct.pack(f">{len(values)}H", *values)
        if fc == 6:
            addr, value = self._unpack(data, ">HH")
            self.write_block(6, addr, [value])
            return bytes([fc]) + data[:4]
        if fc == 16:
            if len(data) < 5:
                raise ModbusError(ILLEGAL_VALUE, "short FC16")
            start, count, nbytes = struct.unpack(">HHB", data[:5])
            if not 1 <= count <= self.max_write(16) or nbytes != 2 * count or len(data) != 5 + nbytes:
                raise ModbusError(ILLEGAL_VALUE, "bad FC16 count/byte count")
            values = list(struct.unpack(f">{count}H", data[5:]))
            self.write_block(16, start, values)
            return bytes([fc]) + data[:4]
        raise ModbusError(ILLEGAL_FUNCTION, f"function {fc:#04x} not supported")

    @staticmethod
    def _unpack(data: bytes, fmt: str):
        if len(data) != struct.calcsize(fmt):
            raise ModbusError(ILLEGAL_VALUE, "bad PDU length")
        return struct.unpack(fmt, data)

    def max_read(self, fc: int) -> int:
        return 125

    def max_write(self, fc: int) -> int:
        return 123

    def read_block(self, fc: int, start: int, count: int) -> list[int]:
        """Checks quantity (03) then address window (02), then reads. Models set the window."""
        if not 1 <= count <= self.max_read(fc):
            raise ModbusError(ILLEGAL_VALUE, f"quantity {count}")
        if not self.readable(fc, start, count):
            raise ModbusError(ILLEGAL_ADDRESS, f"FC{fc:02d} {start}+{count}")
        return self.read_words(start, count)

    def readable(self, fc: int, start: int, count: int) -> bool:
        """Hook: is the whole block inside an address window of this function?"""
        end = start + count
        return fc == 3 and all(a in self.regs or self._inside(a) for a in range(start, end))

    def _inside(self, addr: int) -> bool:
        return any(r.addr <= addr < r.addr + r.words for r in self.REGS)

    def write_block(self, fc: int, start: int, values: list[int]):
        """Checks every word first (nothing is written if one fails), then stores them."""
        plan = [(self.writable_reg(start + i), start + i, word) for i, word in enumerate(values)]
        for reg, addr, word in plan:             # addresses first (02), then values (03)
            self.check_write(reg, addr, reg.from_words([word]) if reg.words == 1 else word)
        for reg, addr, word in plan:
            self.store(addr, word)
        for reg, addr, word in plan:
            self.after_write(reg, addr, word)

    def writable_reg(self, addr: int) -> Reg:
        """Register at a written address, or exception 02."""
        for r in self.REGS:
            if r.addr <= addr < r.addr + r.words:
                return r
        raise ModbusError(ILLEGAL_ADDRESS, f"no register {addr}")

    def check_write(self, reg: Reg, addr: int, raw: int):
        """Access and range checks of one written word; raise ModbusError."""
        if "W" not in reg.access:
            raise ModbusError(ILLEGAL_ADDRESS, f"{reg.name} is read-only")
        if reg.words == 1 and not self.in_range(reg, raw):
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name}={raw} out of range")

    def after_write(self, reg: Reg, addr: int, word: int):
        """Hook: side effects of a successful write (commands, address change...)."""

    def describe(self) -> dict:
        return {"kind": self.KIND, "addr": self.addr, **self.stats}
