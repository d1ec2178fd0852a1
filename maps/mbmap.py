"""The register maps of maps/*.json, loaded: one Map per device (maps/README.md describes them).

    import mbmap
    m = mbmap.load("fdc100")
    m.reg("SP1").addr                 # 0
    m.code("CMND", "RESET")           # 0x6825
    m.to_eng("SP1", 20249, {})        # 25.0 (INPT, DP, ALFN from the state dict, else defaults)

Used by the simulator (tools/sim/modsim), mkdoc.py, check_spec.py and the tests (tests/maps).
Python standard library only.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

HERE = os.path.dirname(os.path.abspath(__file__))
DEVICES = ("mvd94", "mts9", "fdc100")
RECIPE_PARTS = ("", "first", "limit", "lock", "author", "line", "no")


class MapError(ValueError):
    """A map file is missing, malformed or inconsistent."""


@dataclass(frozen=True)
class Register:
    addr: int
    name: str
    access: str                    # "R", "RW", or an RW condition ("RW in manual mode")
    fc: tuple
    type: str                      # "int16", "uint16", "int32 low word first"
    scale: str                     # key of the map's "scales"
    range: tuple | None            # raw (lo, hi) in the register's sign, or None
    unit: str
    default: int
    meaning: str
    source: str
    confidence: str
    words: int = 1
    codes: str | None = None       # table name of an index-code register
    aliases: tuple = ()
    aliases_at: tuple = ()         # other addresses that read/write the same register
    note: str = ""
    recipe: str = ""               # its part in a settings download (maps/settings.py): "first",
                                   # "limit", "lock", "author", "line", "no"; "" = an ordinary one
    unlocked: int | None = None    # "lock"/"author": the code that opens the unit for writes
    within: tuple = ()             # the limits (register names) a set point must lie within
    st_field: str = ""             # its ST field name where the map name is no ST identifier

    @property
    def signed(self) -> bool:
        return self.type.startswith("int")

    @property
    def writable(self) -> bool:
        return "W" in self.access


@dataclass
class Map:
    device: str
    data: dict
    registers: list = field(default_factory=list)

    def __post_init__(self):
        self.by_name = {}
        self.by_addr = {}
        for r in self.registers:
            self.by_addr[r.addr] = r
            for key in (r.name, *r.aliases):
                k = norm(key)
                if k in self.by_name and self.by_name[k] is not r:
                    raise MapError(f"{self.device}: name {key!r} used twice")
                self.by_name[k] = r

    # ----- look-ups -----
    @property
    def kinds(self) -> list:
        return self.data["kinds"]

    @property
    def line(self) -> dict:
        return self.data["line"]

    @property
    def tables(self) -> dict:
        return self.data["tables"]

    @property
    def frames(self) -> list:
        return self.data.get("frames", [])

    @property
    def st_prefix(self) -> str:
        return self.data["st_prefix"]

    def function(self, fc: int) -> dict:
        return self.data["functions"].get(str(fc), {})

    @property
    def function_codes(self) -> tuple:
        return tuple(sorted(int(k) for k in self.data["functions"]))

    def reg(self, name) -> Register:
        """Register by name or alias (case and punctuation insensitive), or by address."""
        if isinstance(name, int):
            return self.by_addr[name]
        r = self.by_name.get(norm(name))
        if r is None:
            raise KeyError(f"{self.device} has no register named {name!r}")
        return r

    def table(self, name: str) -> dict:
        """label -> code of a table."""
        t = self.tables.get(name)
        if t is None:
            raise KeyError(f"{self.device} has no table {name!r}")
        return t.get("codes", {})

    def code(self, table: str, label: str):
        """Code of a label: exact (any case), else the one label equal without punctuation
        (DP labels 0000, 000.0, 00.00 differ only by their dot, so they must match exactly)."""
        codes = self.table(table)
        for k, v in codes.items():
            if k.upper() == str(label).upper() or st_name(k) == str(label).upper():
                return v
        loose = [v for k, v in codes.items() if norm(k) == norm(label)]
        if len(loose) == 1:
            return loose[0]
        raise KeyError(f"{self.device} table {table} has no {label!r}")

    def label(self, table: str, code) -> str | None:
        for k, v in self.table(table).items():
            if v == code:
                return k
        return None

    def bauds(self) -> dict:
        """baud (int) -> code of the device's baud register (BAUD / BAUD_BPS tables)."""
        t = self.tables.get("BAUD_BPS") or self.tables["BAUD"]
        return {int(k): v for k, v in t["codes"].items()}

    # ----- scaling: eng = (raw - offset) / 10^decimals -----
    def scaling(self, reg, state: dict | None = None) -> tuple[int, int]:
        """(decimals, offset) of a register given the device's current raw words by name
        (`state`: e.g. {"DP": 0x11} or {"INPT": 12, "DP": 1, "ALFN": 2}; missing: defaults)."""
        r = reg if isinstance(reg, Register) else self.reg(reg)
        sc = self.data["scales"][r.scale]
        dec = sc.get("decimals", 0)
        if isinstance(dec, int):
            return dec, sc.get("offset", 0)
        st = {k.upper(): v for k, v in (state or {}).items()}

        def val(name):
            return st.get(name, self.reg(name).default)
        if self.device == "mvd94":            # "DP code - 0x10"
            return max(0, min(3, val("DP") - 0x10)), 0
        if self.device == "fdc100":           # "1, or DP when INPT is linear" (+ S6: ALFN = 1)
            linear = val("INPT") > 10
            fixed = r.scale == "S6" and val("ALFN") == self.code("ALFN", "TIMR")
            d = min(val("DP"), 3) if linear and not fixed else 1
            return d, sc.get("offset", 0)
        raise MapError(f"{self.device}: scale {r.scale} has rule {dec!r} with no implementation")

    def to_eng(self, reg, raw: int, state: dict | None = None) -> float:
        dec, off = self.scaling(reg, state)
        return (raw - off) / 10 ** dec

    def from_eng(self, reg, value: float, state: dict | None = None) -> int:
        dec, off = self.scaling(reg, state)
        return int(round(value * 10 ** dec)) + off

    def in_range(self, reg, raw: int) -> bool:
        r = reg if isinstance(reg, Register) else self.reg(reg)
        if r.codes and r.codes in self.tables and raw not in self.table(r.codes).values():
            return False
        if r.range is not None and not r.range[0] <= raw <= r.range[1]:
            return False
        return True

    # ----- words -----
    def decode_words(self, reg, words: list[int]) -> int:
        """Raw value of a register from its 16-bit words (low word first), signed if it is."""
        r = reg if isinstance(reg, Register) else self.reg(reg)
        value = 0
        for i, w in enumerate(words[:r.words]):
            value |= (w & 0xFFFF) << (16 * i)
        bits = 16 * r.words
        if r.signed and value >= 1 << (bits - 1):
            value -= 1 << bits
        return value

    def encode_words(self, reg, value: int) -> list[int]:
        r = reg if isinstance(reg, Register) else self.reg(reg)
        value &= (1 << (16 * r.words)) - 1
        return [(value >> (16 * i)) & 0xFFFF for i in range(r.words)]


def norm(name: str) -> str:
    """Names compare without case, spaces, dashes, dots or underscores: 'Real Data' = REAL_DATA."""
    return "".join(ch for ch in str(name).upper() if ch.isalnum())


def st_name(name: str) -> str:
    """A name or label as an ST identifier part: upper case, '_' for any other character
    ('Real Data' -> REAL_DATA, 'DIF.H' -> DIF_H, '00.00' -> 00_00)."""
    return "".join(ch if ch.isalnum() else "_" for ch in str(name).upper())


def path_of(device: str, folder: str | None = None) -> str:
    return os.path.join(folder or HERE, f"{device}.json")


_CACHE: dict = {}


def load(device: str, folder: str | None = None) -> Map:
    """The map of a device ('mvd94', 'vd', 'mts9', 'fdc100'), checked for consistency."""
    device = {"vd": "mvd94"}.get(device, device)
    path = path_of(device, folder)
    if path in _CACHE:
        return _CACHE[path]
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except OSError as err:
        raise MapError(f"register map {path}: {err.strerror}") from None
    except json.JSONDecodeError as err:
        raise MapError(f"register map {path}: not JSON ({err})") from None
    regs = []
    for e in data.get("registers", []):
        try:
            regs.append(Register(
                addr=e["addr"], name=e["name"], access=e["access"], fc=tuple(e["fc"]),
                type=e["type"], scale=e["scale"],
                range=tuple(e["range"]) if e.get("range") is not None else None,
                unit=e.get("unit", ""), default=e.get("default", 0), meaning=e.get("meaning", ""),
                source=e["source"], confidence=e.get("confidence", ""), words=e.get("words", 1),
                codes=e.get("codes"), aliases=tuple(e.get("aliases", ())),
                aliases_at=tuple(e.get("aliases_at", ())), note=e.get("note", ""),
                recipe=e.get("recipe", ""), unlocked=e.get("unlocked"),
                within=tuple(e.get("within", ())), st_field=e.get("st_field", "")))
        except KeyError as err:
            raise MapError(f"{path}: register {e.get('name', e.get('addr'))} lacks {err}") from None
    m = Map(device=data.get("device", device), data=data, registers=regs)
    problems = validate(m)
    if problems:
        raise MapError(f"{path}: " + "; ".join(problems))
    _CACHE[path] = m
    return m


def validate(m: Map) -> list[str]:
    """Internal consistency: scales and tables exist, addresses don't overlap, defaults in range."""
    out = []
    seen = {}
    for r in m.registers:
        if r.scale not in m.data.get("scales", {}):
            out.append(f"{r.name}: unknown scale {r.scale}")
        if r.codes and r.codes not in m.tables:
            out.append(f"{r.name}: unknown table {r.codes}")
        for a in [*range(r.addr, r.addr + r.words), *r.aliases_at]:
            if a in seen:
                out.append(f"address {a} is both {seen[a]} and {r.name}")
            seen[a] = r.name
        for fc in r.fc:
            if str(fc) not in m.data.get("functions", {}):
                out.append(f"{r.name}: function {fc} not in the map's functions")
        if r.range is not None and r.range[0] > r.range[1]:
            out.append(f"{r.name}: empty range {r.range}")
        if r.recipe not in RECIPE_PARTS:
            out.append(f"{r.name}: recipe {r.recipe!r} is none of {RECIPE_PARTS}")
        if (r.unlocked is None) != (r.recipe not in ("lock", "author")):
            out.append(f"{r.name}: 'unlocked' goes with recipe lock/author, and only there")
        for w in r.within:
            if norm(w) not in m.by_name:
                out.append(f"{r.name}: within names no register {w!r}")
        if r.words == 1 and r.range is not None and not r.range[0] <= r.default <= r.range[1]:
            out.append(f"{r.name}: default {r.default} outside {r.range}")
    return out
