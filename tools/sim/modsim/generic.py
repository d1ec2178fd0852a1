"""A generic Modbus device served from a description file (tools/sim/README.md, "Generic device").

The description names what the device holds: holding and input register ranges and coil and
discrete-input bit ranges, each with its values (16-bit words, or typed values INT/UINT/DINT/
UDINT/REAL/LREAL in a word and byte order). The device answers FC 01/02/03/04/05/06/15/16 on
whatever framing the line gives it (framing=rtu|nocrc|ascii, as the MT-S9), checks requests in
the Modbus order (function 01, quantity 03, address 02, value 03), and answers an address that
no range of that table maps with exception 02. Faults, offline and power cycle are the line's
(bus.py), as for the instrument models. Tests thus need no Python class per device.
"""
from __future__ import annotations

import json
import struct

from .regmap import ILLEGAL_ADDRESS, ILLEGAL_VALUE, Device, ModbusError, Reg

# Protocol limits (Modbus Application Protocol 1.1b3, 6.1..6.12).
MAX_READ_BITS, MAX_WRITE_BITS, MAX_READ_REGS, MAX_WRITE_REGS = 2000, 1968, 125, 123
COIL_ON, COIL_OFF = 0xFF00, 0x0000

# table -> (short name for the control protocol, read FC, write FCs, holds bits)
TABLES = {
    "coils": ("co", 1, (5, 15), True),
    "discrete": ("di", 2, (), True),
    "holding": ("hr", 3, (6, 16), False),
    "input": ("ir", 4, (), False),
}
READ_FC = {spec[1]: table for table, spec in TABLES.items()}
SHORT = {spec[0]: table for table, spec in TABLES.items()}
# type -> (struct format of the big-endian value, words)
TYPES = {"uint16": (">H", 1), "int16": (">h", 1), "uint32": (">I", 2), "int32": (">i", 2),
         "float32": (">f", 2), "uint64": (">Q", 4), "int64": (">q", 4), "float64": (">d", 4)}
ORDERS = ("ABCD", "CDAB", "BADC", "DCBA")   # ABCD: high word first, high byte first (Modbus)
RANGE_KEYS = {"start", "count", "values", "type", "order", "names", "writable"}


class DescriptionError(ValueError):
    """The description file is missing, not JSON, or inconsistent (one line)."""


def encode(value, typ: str, order: str) -> list[int]:
    """Words on the wire of one typed value: the big-endian bytes, words reversed for CDAB/DCBA,
    bytes swapped within each word for BADC/DCBA."""
    fmt, nwords = TYPES[typ]
    if fmt[-1] in "fd":
        raw = struct.pack(fmt, float(value))
    else:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{value!r} is not an integer")
        raw = struct.pack(fmt, value)          # struct.error (a ValueError) when out of range
    words = [raw[2 * i:2 * i + 2] for i in range(nwords)]
    if order in ("CDAB", "DCBA"):
        words.reverse()
    if order in ("BADC", "DCBA"):
        words = [w[::-1] for w in words]
    return [int.from_bytes(w, "big") for w in words]


def decode(words: list[int], typ: str, order: str):
    """The typed value of its words on the wire (inverse of encode)."""
    fmt, _ = TYPES[typ]
    parts = [(w & 0xFFFF).to_bytes(2, "big") for w in words]
    if order in ("BADC", "DCBA"):
        parts = [p[::-1] for p in parts]
    if order in ("CDAB", "DCBA"):
        parts.reverse()
    return struct.unpack(fmt, b"".join(parts))[0]


class Value(Reg):
    """A named value or one word/bit of a table (control protocol get/set, start-up options).
    Its raw value is the unsigned pattern of its words in ABCD; eng is the typed value."""

    def __init__(self, table: str, addr: int, name: str, typ: str = "uint16",
                 order: str = "ABCD", writable: bool = True):
        super().__init__(addr, name, "RW" if writable else "R", words=TYPES[typ][1],
                         scale="raw" if typ == "uint16" else typ)
        self.table, self.typ, self.order = table, typ, order

    def to_words(self, value: int) -> list[int]:
        """Wire words of a raw ABCD pattern, in the value's order."""
        return encode(value & ((1 << (16 * self.words)) - 1), f"uint{16 * self.words}", self.order)

    def from_words(self, words: list[int]) -> int:
        return decode(words, f"uint{16 * self.words}", self.order)


class Generic(Device):
    """A device whose tables come from a description file (file=PATH)."""

    KIND = "generic"
    FUNCTIONS = (1, 2, 3, 4, 5, 6, 15, 16)

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.tables = {t: {} for t in TABLES}      # table -> {address: word or bit}
        self.readonly = {t: set() for t in TABLES}
        self.names = {}                            # upper-case name -> Value
        self.kind_framing = line.framing if line.framing in ("rtu", "nocrc", "ascii") else "rtu"
        self.source = None

    # ----- start-up: file=, framing= -----
    def option(self, name, value):
        key = name.lower()
        if key == "file":
            self.load(value)
        elif key == "framing":
            if value not in ("rtu", "nocrc", "ascii"):
                raise ValueError("generic framing must be one of ascii, nocrc, rtu")
            self.kind_framing = value
        else:
            return False
        return True

    def finish(self):
        if self.source is None:
            raise ValueError(f"generic:{self.addr} needs file=PATH (a description, "
                             "tools/sim/README.md \"Generic device\")")

    def load(self, path: str):
        """Read and check the description; DescriptionError names the file and the entry."""
        try:
            with open(path, encoding="utf-8") as fh:
                desc = json.load(fh)
        except OSError as err:
            raise DescriptionError(f"generic:{self.addr} file {path}: {err.strerror}") from None
        except json.JSONDecodeError as err:
            raise DescriptionError(f"generic:{self.addr} file {path}: not JSON ({err})") from None
        try:
            self.describe_from(desc)
        except (ValueError, TypeError, struct.error) as err:
            raise DescriptionError(f"generic:{self.addr} file {path}: {err}") from None
        self.source = path

    def describe_from(self, desc):
        if not isinstance(desc, dict):
            raise ValueError("the description is a JSON object")
        unknown = set(desc) - set(TABLES) - {"description"}
        if unknown:
            raise ValueError(f"unknown key {sorted(unknown)[0]!r} (tables: {', '.join(TABLES)})")
        for table in TABLES:
            ranges = desc.get(table, [])
            if not isinstance(ranges, list):
                raise ValueError(f"{table}: a list of ranges")
            for i, rng in enumerate(ranges):
                self.add_range(table, f"{table}[{i}]", rng)
        if not any(self.tables.values()):
            raise ValueError("no range at all")

    def add_range(self, table: str, where: str, rng):
        if not isinstance(rng, dict):
            raise ValueError(f"{where}: a range is a JSON object")
        unknown = set(rng) - RANGE_KEYS
        if unknown:
            raise ValueError(f"{where}: unknown key {sorted(unknown)[0]!r}")
        bits = TABLES[table][3]
        start = rng.get("start")
        if isinstance(start, bool) or not isinstance(start, int) or not 0 <= start <= 0xFFFF:
            raise ValueError(f"{where}: start must be 0..65535")
        typ, order = rng.get("type", "uint16"), rng.get("order", "ABCD")
        if bits and ("type" in rng or "order" in rng):
            raise ValueError(f"{where}: bits have no type or order")
        if typ not in TYPES:
            raise ValueError(f"{where}: type {typ!r} is not one of {', '.join(TYPES)}")
        if order not in ORDERS:
            raise ValueError(f"{where}: order {order!r} is not one of {', '.join(ORDERS)}")
        values = rng.get("values", [])
        if not isinstance(values, list):
            raise ValueError(f"{where}: values must be a list")
        names = rng.get("names", [])
        if not isinstance(names, list) or len(names) > len(values) or \
                not all(isinstance(n, str) and n for n in names):
            raise ValueError(f"{where}: names must be strings, at most one per value")
        writable = rng.get("writable", True)
        if not isinstance(writable, bool) or (not writable and table in ("discrete", "input")):
            raise ValueError(f"{where}: writable is true or false, for coils and holding only")
        per = 1 if bits else TYPES[typ][1]
        words = []
        for k, value in enumerate(values):
            if bits:
                if value not in (0, 1) or isinstance(value, float):
                    raise ValueError(f"{where}: values[{k}] {value!r}: a bit is 0 or 1")
                words.append(int(value))
            else:
                try:
                    words += encode(value, typ, order)
                except (ValueError, struct.error) as err:
                    raise ValueError(f"{where}: values[{k}] {value!r} does not fit {typ} "
                                     f"({err})") from None
        count = rng.get("count", len(words))
        if isinstance(count, bool) or not isinstance(count, int) or count < max(1, len(words)):
            raise ValueError(f"{where}: count must be >= 1 and hold the values "
                             f"({len(words)} {'bits' if bits else 'words'})")
        if start + count > 0x10000:
            raise ValueError(f"{where}: start + count past address 65535")
        held = self.tables[table]
        clash = next((a for a in range(start, start + count) if a in held), None)
        if clash is not None:
            raise ValueError(f"{where}: address {clash} is already in another {table} range")
        for a in range(start, start + count):
            held[a] = words[a - start] if a - start < len(words) else 0
            if not writable:
                self.readonly[table].add(a)
        for k, name in enumerate(names):
            key = name.upper()
            if key in self.names or key.partition(":")[0].lower() in SHORT:
                raise ValueError(f"{where}: name {name!r} used twice or shaped like 'hr:N'")
            if bits:
                self.names[key] = Value(table, start + k, name, writable=writable)
            else:
                self.names[key] = Value(table, start + k * per, name, typ, order, writable)

    # ----- line -----
    @property
    def framing(self):
        return self.kind_framing

    # ----- control protocol: names, or TABLE:ADDRESS (hr:0, ir:3, co:5, di:7), or a number -----
    def lookup(self, key) -> Reg:
        text = str(key).strip()
        if text.upper() in self.names:
            return self.names[text.upper()]
        short, sep, num = text.partition(":")
        table = SHORT.get(short.lower()) or (short.lower() if short.lower() in TABLES else None)
        if not sep:
            table, num = "holding", text
        if table is None or not num.strip().isdigit():
            raise KeyError(f"generic:{self.addr} has no value named {key!r} (names, or "
                           "hr:N, ir:N, co:N, di:N)")
        addr = int(num)
        if addr not in self.tables[table]:
            raise KeyError(f"generic:{self.addr} maps no {table} address {addr}")
        return Value(table, addr, f"{TABLES[table][0]}:{addr}",
                     writable=addr not in self.readonly[table])

    def reg_words(self, reg) -> list[int]:
        return [self.tables[reg.table].get(a, 0) for a in range(reg.addr, reg.addr + reg.words)]

    def get_raw(self, reg) -> int:
        return reg.from_words(self.reg_words(reg))

    def set_raw(self, reg, value: int):
        if TABLES[reg.table][3] and value not in (0, 1):
            raise ValueError(f"{reg.name}: a bit is 0 or 1")
        for i, w in enumerate(reg.to_words(int(value))):
            self.tables[reg.table][reg.addr + i] = w

    def to_eng(self, reg, raw):
        if reg.scale == "raw":
            return raw
        pattern = "uint%d" % (16 * reg.words)
        return decode(encode(raw, pattern, "ABCD"), reg.typ, "ABCD")

    def from_eng(self, reg, value) -> int:
        if isinstance(value, str):
            value = float(value) if reg.typ.startswith("float") else int(value, 0)
        if reg.scale == "raw":
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(f"{reg.name}: {value} is not an integer")
            return int(value)
        pattern = "uint%d" % (16 * reg.words)
        return decode(encode(value, reg.typ, "ABCD"), pattern, "ABCD")

    def in_range(self, reg, raw):
        return True

    # ----- Modbus PDU handling -----
    def dispatch(self, fc, data):
        if fc in (1, 2, 3, 4):
            start, count = self._unpack(data, ">HH")
            table = READ_FC[fc]
            bits = TABLES[table][3]
            if not 1 <= count <= (MAX_READ_BITS if bits else MAX_READ_REGS):
                raise ModbusError(ILLEGAL_VALUE, f"quantity {count}")
            self._mapped(table, start, count)
            held = self.tables[table]
            if bits:
                packed = pack_bits([held[a] for a in range(start, start + count)])
                return bytes([fc, len(packed)]) + packed
            words = [held[a] for a in range(start, start + count)]
            return bytes([fc, 2 * count]) + struct.pack(f">{count}H", *words)
        if fc == 5:
            addr, value = self._unpack(data, ">HH")
            if value not in (COIL_ON, COIL_OFF):
                raise ModbusError(ILLEGAL_VALUE, f"FC05 value {value:#06x}")
            self._store("coils", addr, [int(value == COIL_ON)])
            return bytes([fc]) + data
        if fc == 6:
            addr, value = self._unpack(data, ">HH")
            self._store("holding", addr, [value])
            return bytes([fc]) + data
        if fc in (15, 16):
            if len(data) < 5:
                raise ModbusError(ILLEGAL_VALUE, f"short FC{fc}")
            start, count, nbytes = struct.unpack(">HHB", data[:5])
            bits = fc == 15
            need = (count + 7) // 8 if bits else 2 * count
            if not 1 <= count <= (MAX_WRITE_BITS if bits else MAX_WRITE_REGS) or \
                    nbytes != need or len(data) != 5 + nbytes:
                raise ModbusError(ILLEGAL_VALUE, f"FC{fc} quantity {count} / byte count {nbytes}")
            if bits:
                values = unpack_bits(data[5:], count)
            else:
                values = list(struct.unpack(f">{count}H", data[5:]))
            self._store("coils" if bits else "holding", start, values)
            return bytes([fc]) + data[:4]
        return super().dispatch(fc, data)

    def _mapped(self, table: str, start: int, count: int, write: bool = False):
        """Exception 02 unless every address is in a range of the table (and writable)."""
        held = self.tables[table]
        for a in range(start, start + count):
            if a not in held:
                raise ModbusError(ILLEGAL_ADDRESS, f"{table} {a} not mapped")
            if write and a in self.readonly[table]:
                raise ModbusError(ILLEGAL_ADDRESS, f"{table} {a} is read-only")

    def _store(self, table: str, start: int, values: list[int]):
        """All or nothing: every address is checked before one is written."""
        self._mapped(table, start, len(values), write=True)
        for i, v in enumerate(values):
            self.tables[table][start + i] = v

    def describe(self):
        return {**super().describe(), "file": self.source, "framing": self.framing}


def pack_bits(bits: list[int]) -> bytes:
    """Bits as on the wire: bit i in byte i // 8 at bit i % 8 (LSB first), zero-padded."""
    out = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> list[int]:
    """The first `count` bits of packed bytes (inverse of pack_bits)."""
    return [(data[i // 8] >> (i % 8)) & 1 for i in range(count)]
