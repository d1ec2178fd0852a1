"""MT-S9 counter/meter: maps/mts9.json (RTU, RTU without CRC, ASCII).

Real Data and Display Data are signed 32-bit values stored LOW word first (the FC16 example's
CRC 53 FC proves it). The meter counts at `rate` counts per simulated second, shows Decimal Set,
raises Over-Flow when the value does not fit its digits, and gates its set-up registers with
Author. The manual documents no exceptions, defaults or broadcast; the choices are in README.md.
"""
from __future__ import annotations

from .regmap import ILLEGAL_VALUE, Device, ModbusError, load_map

MAP = load_map("mts9")
BAUDS = tuple(sorted(MAP.bauds(), key=MAP.bauds().get))         # index = code
TYPES = {k.lower(): v for k, v in MAP.table("TYPE").items()}     # ascii 0, rtu 1, nocrc 2
NAMES = {v: k for k, v in TYPES.items()}
DIGITS = {int(k): tuple(v) for k, v in MAP.table("DIGITS").items()}
DECIMALS_MAX = {int(k): v for k, v in MAP.table("DECIMALS_MAX").items()}
# Author level needed to write each set-up register (cumulative reading of the Author matrix).
AUTHOR_LEVEL = {MAP.reg(k).name: v for k, v in MAP.table("AUTHOR").items()}
A_REAL, A_DISPLAY, A_OVER, A_ID, A_BAUD, A_TYPE, A_AUTHOR = (
    MAP.reg(n).addr for n in ("REAL", "DISPLAY", "OVERFLOW", "ID", "BAUD", "TYPE", "AUTHOR"))
LAST = MAP.function(3)["window"][1]


class MtS9(Device):
    """MT-S9 96x48 counter/meter."""

    KIND = "mts9"
    MAP = MAP

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.rate = 0.0             # counts per simulated second
        self.digits = 6
        self.frac = 0.0
        self.words[A_ID] = addr
        self.words[A_TYPE] = TYPES[line.framing]
        if line.baud in BAUDS:
            self.words[A_BAUD] = BAUDS.index(line.baud)

    def option(self, name, value):
        key = name.lower()
        if key == "framing":
            if value not in TYPES:
                raise ValueError(f"mts9 framing must be one of {sorted(TYPES)}")
            self.words[A_TYPE] = TYPES[value]
        elif key == "rate":
            self.rate = float(value)
        elif key == "digits":
            if int(value) not in DIGITS:
                raise ValueError("mts9 digits must be 4, 6 or 8")
            self.digits = int(value)
        else:
            return False
        return True

    # ----- live words -----
    def real(self) -> int:
        return self.by_name["REAL"].from_words([self.words[A_REAL], self.words[A_REAL + 1]])

    def display(self) -> tuple[int, int]:
        """(display value, overflow flag): the value is clamped to what the digits can show."""
        lo, hi = DIGITS[self.digits]
        value = self.real()
        return max(lo, min(hi, value)), int(not lo <= value <= hi)

    def word(self, addr):
        if addr in (A_DISPLAY, A_DISPLAY + 1):
            words = self.by_name["DISPLAY"].to_words(self.display()[0])
            return words[addr - A_DISPLAY]
        if addr == A_OVER:
            return self.display()[1]
        return super().word(addr)

    def readable(self, fc, start, count):
        return fc == 3 and start + count - 1 <= LAST

    # ----- writes -----
    def in_range(self, reg, raw):
        if reg.name == "Decimal Set":
            return 0 <= raw <= DECIMALS_MAX[self.digits]
        return super().in_range(reg, raw)

    def check_write(self, reg, addr, raw):
        need = AUTHOR_LEVEL.get(reg.name, 0)
        if self.words[A_AUTHOR] < need:
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name} needs Author >= {need}")
        super().check_write(reg, addr, raw)

    def after_write(self, reg, addr, word):
        if reg.name == "ID Address Set":
            self.addr = word
        if reg.name == "Real Data":
            self.frac = 0.0

    def char_format(self):
        """Its Baud Rate Set; the character format is not in the manual: the unit is taken to
        be set to the line's (--format), and a master must match it like any other."""
        code = self.words[A_BAUD]
        return ((BAUDS[code] if code < len(BAUDS) else -1), self.line.data_bits,
                self.line.parity, self.line.stop_bits)

    @property
    def framing(self):
        """Its Type register: it hears and answers frames of that framing only."""
        return NAMES.get(self.words[A_TYPE], "?")

    # ----- dynamics -----
    def tick(self, dt):
        if not self.rate:
            return
        self.frac += self.rate * dt
        whole = int(self.frac)
        if whole:
            self.frac -= whole
            value = self.real() + whole
            value = max(-(1 << 31), min((1 << 31) - 1, value))
            self.set_raw(self.by_name["REAL"], value)

    def power_cycle(self):
        """Author falls back to 0 (writes locked) at power-up; the count is retained (choice)."""
        self.words[A_AUTHOR] = 0
        self.frac = 0.0

    def describe(self):
        return {**super().describe(), "value": self.real(), "rate": self.rate}
