"""MT-S9 counter/meter: DEVICES.md section 2 (RTU, RTU without CRC, ASCII).

Real Data and Display Data are signed 32-bit values stored LOW word first (the FC16 example's
CRC 53 FC proves it). The meter counts at `rate` counts per simulated second, shows Decimal Set,
raises Over-Flow when the value does not fit its digits, and gates its set-up registers with
Author. The manual documents no exceptions, defaults or broadcast; the choices are in README.md.
"""
from __future__ import annotations

from .regmap import ILLEGAL_VALUE, Device, ModbusError, Reg

BAUDS = (2400, 4800, 9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200)
TYPES = {"ascii": 0, "rtu": 1, "nocrc": 2}
DIGITS = {4: (-1999, 9999), 6: (-199999, 999999), 8: (-19999999, 99999999)}
# Author level needed to write each set-up register (cumulative reading of DEVICES.md 2.7).
AUTHOR_LEVEL = {"DECIMAL": 1, "ID": 2, "BAUD": 3, "TYPE": 4}

REGS = (
    Reg(0, "Real Data", signed=True, words=2, aliases=("REAL", "REALDATA", "VALUE")),
    Reg(2, "Display Data", access="R", signed=True, words=2, aliases=("DISPLAY",)),
    Reg(4, "Over-Flow Sign", access="R", lo=0, hi=1, aliases=("OVERFLOW", "OVER-FLOW")),
    Reg(5, "Decimal Set", lo=0, hi=7, aliases=("DECIMAL",)),
    Reg(6, "ID Address Set", lo=1, hi=247, default=1, aliases=("ID", "ADDR")),
    Reg(7, "Baud Rate Set", lo=0, hi=9, default=2, aliases=("BAUD",)),
    Reg(8, "Type", lo=0, hi=2, default=1, aliases=("FRAMING_CODE",)),
    Reg(9, "Author", lo=0, hi=5, default=0, aliases=("AUTH",)),
)


class MtS9(Device):
    """MT-S9 96x48 counter/meter."""

    KIND = "mts9"
    REGS = REGS
    FUNCTIONS = (3, 6, 16)

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.rate = 0.0             # counts per simulated second
        self.digits = 6
        self.frac = 0.0
        self.words[6] = addr
        self.words[8] = TYPES[line.framing]
        if line.baud in BAUDS:
            self.words[7] = BAUDS.index(line.baud)

    def option(self, name, value):
        key = name.lower()
        if key == "framing":
            if value not in TYPES:
                raise ValueError(f"mts9 framing must be one of {sorted(TYPES)}")
            self.words[8] = TYPES[value]
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
        return self.by_name["REAL"].from_words([self.words[0], self.words[1]])

    def display(self) -> tuple[int, int]:
        """(display value, overflow flag): the value is clamped to what the digits can show."""
        lo, hi = DIGITS[self.digits]
        value = self.real()
        return max(lo, min(hi, value)), int(not lo <= value <= hi)

    def word(self, addr):
        if addr in (2, 3):
            words = self.by_name["DISPLAY"].to_words(self.display()[0])
            return words[addr - 2]
        if addr == 4:
            return self.display()[1]
        return super().word(addr)

    def readable(self, fc, start, count):
        return fc == 3 and start + count - 1 <= 9

    # ----- writes -----
    def in_range(self, reg, raw):
        if reg.name == "Decimal Set":
            return 0 <= raw <= self.digits - 1
        return super().in_range(reg, raw)

    def check_write(self, reg, addr, raw):
        need = next((lvl for key, lvl in AUTHOR_LEVEL.items() if self.by_name[key] is reg), 0)
        if self.words[9] < need:
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name} needs Author >= {need}")
        super().check_write(reg, addr, raw)

    def after_write(self, reg, addr, word):
        if reg.name == "ID Address Set":
            self.addr = word
        if reg.name == "Real Data":
            self.frac = 0.0

    def line_matches(self):
        w = self.words
        return w[7] < len(BAUDS) and BAUDS[w[7]] == self.line.baud and \
            w[8] == TYPES[self.line.framing]

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
        self.words[9] = 0
        self.frac = 0.0

    def describe(self):
        return {**super().describe(), "value": self.real(), "rate": self.rate}
