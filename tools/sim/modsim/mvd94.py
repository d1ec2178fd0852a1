"""SetPro MV-D94 and VD series (same map): DEVICES.md section 1, manual chapters 5-7.

Per the manual: FC 03 (holding 0x0000..0x007D, 1..0x7E words), FC 04 (input 0x1000..0x1002,
PV at 0x1000), FC 06 (0x0000..0x0021); anything else exception 01; quantity 0 or > 0x7E -> 03;
addresses outside the window of the function -> 02; a value out of range or not a valid index
code -> 03. Values are int16 two's complement "regardless of decimal" (eng = raw / 10^dp).
Choices where the manual is silent: words 0x0022..0x007D and input 0x1001/0x1002 read as 0.
"""
from __future__ import annotations

from .regmap import ILLEGAL_ADDRESS, Device, ModbusError, Reg
from .thermal import Loop

BAUD_CODES = {0x1C: 2400, 0x1D: 4800, 0x1E: 9600, 0x1F: 19200}
TYPE = {"J": 0, "K": 1, "T": 2, "E": 3, "B": 4, "R": 5, "S": 6, "N": 7, "C": 8,
        "D-PT": 9, "J-PT": 10, "LINE": 11}
UNIT = {"degC": 0x0C, "C": 0x0C, "degF": 0x0D, "F": 0x0D, "ENG": 0x0E}
DP = {"0000": 0x10, "000.0": 0x11, "00.00": 0x12, "0.000": 0x13}
ACT = {"REV": 0x14, "DIR": 0x15}
AFU = {"NONE": 0x16, "HI": 0x30, "LO": 0x31, "DIF.H": 0x32, "DIF.L": 0x33, "BD.HI": 0x34,
       "BD.LO": 0x35, "T.ON": 0x36, "T.OFF": 0x37, "NONE38": 0x38}   # None: 0x16 or 0x38 (L)
AMD = {"NONE": 0x16, "STDY": 0x17, "LATH": 0x18, "ST.LA": 0x19}
LOCK = {f"{i:04b}": 0x20 + i for i in range(16)}
BAUD = {"2.4K": 0x1C, "4.8K": 0x1D, "9.6K": 0x1E, "19.2K": 0x1F}


def _dps(addr, name, lo, hi, default=0):
    """int16 register scaled by DP (eng = raw / 10^dp)."""
    return Reg(addr, name, lo=lo, hi=hi, signed=True, scale="dp", default=default)


REGS = (
    _dps(0x00, "SV", -1999, 9999, 100),   # range LOLT..HILT, checked in in_range
    _dps(0x01, "SPOF", -1000, 1000), _dps(0x02, "PVOF", -1000, 1000),
    _dps(0x03, "A1SP", -1000, 1000, 10), _dps(0x04, "A2SP", -1000, 1000, 10),
    _dps(0x05, "A3SP", -1000, 1000, 10),
    Reg(0x06, "PB", lo=0, hi=3000, scale="x10", default=100),
    Reg(0x07, "TD", lo=0, hi=900, default=30),
    Reg(0x08, "CT", lo=0, hi=100, default=20),
    _dps(0x09, "HYST", 0, 2000, 1), _dps(0x0A, "A1HY", 0, 2000, 1),
    _dps(0x0B, "A2HY", 0, 2000, 1), _dps(0x0C, "A3HY", 0, 2000, 1),
    Reg(0x0D, "LOCK", codes=LOCK, default=0x20),
    Reg(0x0E, "TYPE", codes=TYPE, default=TYPE["K"]),
    Reg(0x0F, "UNIT", codes=UNIT, default=0x0C),
    Reg(0x10, "DP", codes=DP, scale="dpcode", default=0x10),
    Reg(0x11, "ACT", codes=ACT, default=0x14),
    _dps(0x12, "LOLT", -1999, 9999, -1999), _dps(0x13, "HILT", -1999, 9999, 9999),
    Reg(0x14, "FILT", lo=0, hi=1000, scale="x10", default=0),
    Reg(0x15, "A1FU", codes=AFU, default=0x30), Reg(0x16, "A1MD", codes=AMD, default=0x16),
    Reg(0x17, "A2FU", codes=AFU, default=0x31), Reg(0x18, "A2MD", codes=AMD, default=0x16),
    Reg(0x19, "A3FU", codes=AFU, default=0x32), Reg(0x1A, "A3MD", codes=AMD, default=0x16),
    Reg(0x1B, "ADDR", lo=1, hi=255, default=1),
    Reg(0x1C, "BAUD", codes=BAUD, default=0x1E, aliases=("BAND",)),
    Reg(0x1D, "CH01", lo=0, hi=2000), Reg(0x1E, "CL01", lo=0, hi=2000),
    Reg(0x1F, "RTSH", lo=0, hi=3000, default=3000), Reg(0x20, "RTSL", lo=0, hi=3000),
    Reg(0x21, "MR", lo=0, hi=1000, scale="x10", default=0),
    Reg(0x1000, "PV", access="R", signed=True, scale="dp"),
)

HOLDING_END = 0x007D      # FC03 window (manual 6.1)
WRITE_END = 0x0021        # FC06 window: the defined map
INPUT = range(0x1000, 0x1003)
MAX_WORDS = 0x7E


class MvD94(Device):
    """SetPro MV-D94 temperature controller (also 'vd': the VD map is identical)."""

    KIND = "mvd94"
    REGS = REGS
    FUNCTIONS = (3, 4, 6)

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.loop = Loop()
        self.store(0x1B, addr)
        code = {v: k for k, v in BAUD_CODES.items()}.get(line.baud)
        if code is not None:
            self.store(0x1C, code)

    # ----- encoding -----
    def dp(self) -> int:
        return max(0, min(3, self.words[0x10] - 0x10))

    def scaling(self, reg):
        if reg.scale == "dp":
            return self.dp(), 0
        if reg.scale == "x10":
            return 1, 0
        if reg.scale == "dpcode":          # DP=1 on the command line means code 0x11
            return 0, 0x10
        return 0, 0

    def value(self, name: str) -> float:
        reg = self.by_name[name]
        return self.to_eng(reg, self.get_raw(reg))

    # ----- windows and checks -----
    def max_read(self, fc):
        return MAX_WORDS

    def readable(self, fc, start, count):
        end = start + count - 1
        if fc == 3:
            return end <= HOLDING_END
        return start in INPUT and end in INPUT

    def writable_reg(self, addr):
        if addr > WRITE_END:
            raise ModbusError(ILLEGAL_ADDRESS, f"FC06 at {addr:#06x}")
        return super().writable_reg(addr)

    def in_range(self, reg, raw):
        if reg.name == "SV":
            lo = self.get_raw(self.by_name["LOLT"])
            hi = self.get_raw(self.by_name["HILT"])
            return min(lo, hi) <= raw <= max(lo, hi)
        return super().in_range(reg, raw)

    def word(self, addr):
        if addr == 0x1000:
            return self.pv_raw() & 0xFFFF
        return super().word(addr)

    def pv_raw(self) -> int:
        pv = self.loop.plant.temp + self.value("PVOF")
        return max(-32768, min(32767, int(round(pv * 10 ** self.dp()))))

    def store(self, addr, word):
        if addr == 0x1000:                  # control 'set' of PV moves the process
            raw = word - 0x10000 if word & 0x8000 else word
            self.loop.plant.temp = raw / 10 ** self.dp() - self.value("PVOF")
            return
        super().store(addr, word)

    def after_write(self, reg, addr, word):
        if reg.name == "ADDR":
            self.addr = word                # answers at the new address from the next frame

    def line_matches(self):
        return BAUD_CODES.get(self.words[0x1C]) == self.line.baud

    # ----- dynamics -----
    def tick(self, dt):
        sv = self.value("SV") + self.value("SPOF")
        td = self.value("TD")
        # The map has no integral time: the model uses TI = 4 * TD (TD = 0: P + manual reset).
        self.loop.run(dt, sv, band=self.value("PB") * 10.0, ti=4.0 * td, td=td,
                      bias=self.value("MR"), hyst=self.value("HYST"),
                      cooling=self.words[0x11] == ACT["DIR"])

    def power_cycle(self):
        self.loop.restart()

    def describe(self):
        return {**super().describe(), "pv": round(self.loop.plant.temp, 3),
                "output": round(self.loop.output, 2)}


class Vd(MvD94):
    """SetPro VD-2000/2001/2003/2004: same map and protocol as the MV-D94 (DEVICES.md 1.1)."""
    KIND = "vd"
