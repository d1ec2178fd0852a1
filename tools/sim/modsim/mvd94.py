"""SetPro MV-D94 and VD series (same map): maps/mvd94.json, manual chapters 5-7.

Per the manual: FC 03 (holding 0x0000..0x007D, 1..0x7E words), FC 04 (input 0x1000..0x1002,
PV at 0x1000), FC 06 (0x0000..0x0021); anything else exception 01; quantity 0 or > 0x7E -> 03;
addresses outside the window of the function -> 02; a value out of range or not a valid index
code -> 03. Values are int16 two's complement "regardless of decimal" (eng = raw / 10^dp).
Choices where the manual is silent: words 0x0022..0x007D and input 0x1001/0x1002 read as 0.
The registers, windows and codes come from the map; this file holds the behaviour.
"""
from __future__ import annotations

from .regmap import ILLEGAL_ADDRESS, Device, ModbusError, load_map
from .thermal import Loop

MAP = load_map("mvd94")
BAUD_CODES = {code: bps for bps, code in MAP.bauds().items()}      # code -> bps
ACT_DIR = MAP.code("ACT", "DIR")
HOLDING_END = MAP.function(3)["window"][1]      # FC03 window (manual 6.1)
WRITE_END = MAP.function(6)["window"][1]        # FC06 window: the defined map
INPUT = range(MAP.function(4)["window"][0], MAP.function(4)["window"][1] + 1)
MAX_WORDS = MAP.function(3)["max_words"]
A_DP, A_BAUD, A_ADDR, A_ACT, A_PV = (MAP.reg(n).addr for n in ("DP", "BAUD", "ADDR", "ACT", "PV"))


class MvD94(Device):
    """SetPro MV-D94 temperature controller (also 'vd': the VD map is identical)."""

    KIND = "mvd94"
    MAP = MAP

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.loop = Loop()
        self.store(A_ADDR, addr)
        code = MAP.bauds().get(line.baud)
        if code is not None:
            self.store(A_BAUD, code)

    # ----- encoding -----
    def dp(self) -> int:
        return MAP.scaling("SV", {"DP": self.words[A_DP]})[0]

    def scaling(self, reg):
        if reg.scale == "dpcode":          # DP=1 on the command line means code 0x11
            return 0, MAP.code("DP", "0000")
        if reg.scale == "code":
            return 0, 0
        return MAP.scaling(reg.name, {"DP": self.words[A_DP]})

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

    def word(self, addr):
        if addr == A_PV:
            return self.pv_raw() & 0xFFFF
        return super().word(addr)

    def pv_raw(self) -> int:
        pv = self.loop.plant.temp + self.value("PVOF")
        return max(-32768, min(32767, int(round(pv * 10 ** self.dp()))))

    def store(self, addr, word):
        if addr == A_PV:                    # control 'set' of PV moves the process
            raw = word - 0x10000 if word & 0x8000 else word
            self.loop.plant.temp = raw / 10 ** self.dp() - self.value("PVOF")
            return
        super().store(addr, word)

    def after_write(self, reg, addr, word):
        if reg.name == "ADDR":
            self.addr = word                # answers at the new address from the next frame

    def char_format(self):
        """(baud, data bits, parity, stop bits) the unit speaks: its BAUD code, 8N2 fixed."""
        return BAUD_CODES.get(self.words[A_BAUD]), 8, "N", 2

    # ----- dynamics -----
    def tick(self, dt):
        sv = self.value("SV") + self.value("SPOF")
        td = self.value("TD")
        # The map has no integral time: the model uses TI = 4 * TD (TD = 0: P + manual reset).
        self.loop.run(dt, sv, band=self.value("PB") * 10.0, ti=4.0 * td, td=td,
                      bias=self.value("MR"), hyst=self.value("HYST"),
                      cooling=self.words[A_ACT] == ACT_DIR)

    def power_cycle(self):
        self.loop.restart()

    def describe(self):
        return {**super().describe(), "pv": round(self.loop.plant.temp, 3),
                "output": round(self.loop.output, 2)}


class Vd(MvD94):
    """SetPro VD-2000/2001/2003/2004: same map and protocol as the MV-D94 (maps/mvd94.json)."""
    KIND = "vd"
