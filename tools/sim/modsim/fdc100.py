"""FDC Series 100 / Brainchild BTC-9100 family: DEVICES.md section 3, manual chapter 7.

Per the manual: FC 03, 06, 16 only (else exception 01 and EROR 10); registers 0..79 and the
aliases 128..131 = 64..67 (else 02, EROR 11); writes to read-only or locked registers -> 03 and
EROR 14; out-of-range values -> 03 and EROR 15. Words are unsigned with the linear mapping
M = A * 10^d + offset (section 3.6). CMND (72) commands: reset, manual, auto-tune, calibration.
"""
from __future__ import annotations

from .regmap import ILLEGAL_ADDRESS, ILLEGAL_VALUE, Device, ModbusError, Reg
from .thermal import Loop

# scale class -> (decimals, offset); S4/S5 depend on INPT/DP (see scaling()).
FIXED = {"N1": (1, 19999), "N2": (2, 19999), "F1": (1, 0), "F2": (2, 0), "F3": (3, 0),
         "U": (0, 0)}
E = 19999
# (name, scale, access, Example-1 default word). Access: RW, R, MAN (R/W in manual mode),
# CAL (R/W after CMND = 0x682D).
MAP = [
    ("SP1", "S4", "RW", 0x4F19), ("SP2", "S7", "RW", 0x4E83), ("SP3", "S6", "RW", 0x4E83),
    ("LOCK", "U", "RW", 0), ("INPT", "U", "RW", 1), ("UNIT", "U", "RW", 0), ("DP", "U", "RW", 1),
    ("INLO", "S4", "RW", 0x4D6D), ("INHI", "S4", "RW", 0x51C4), ("SP1L", "S4", "RW", 0x4D6D),
    ("SP1H", "S4", "RW", 0x6321), ("SHIF", "S4", "RW", E), ("FILT", "U", "RW", 2),
    ("DISP", "U", "RW", 0), ("PB", "S5", "RW", 100), ("TI", "U", "RW", 100),
    ("TD", "F1", "RW", 250), ("OUT1", "U", "RW", 0), ("O1TY", "U", "RW", 0),
    ("O1FT", "N1", "RW", E), ("O1HY", "S5", "RW", 1), ("CYC1", "F1", "RW", 180),
    ("OFST", "F1", "RW", 250), ("RAMP", "U", "RW", 0), ("RR", "S5", "RW", 0),
    ("OUT2", "U", "RW", 2), ("RELO", "S4", "RW", E), ("O2TY", "U", "RW", 0),
    ("O2FT", "N1", "RW", E), ("O2HY", "S5", "RW", 1), ("CYC2", "F1", "RW", 180),
    ("CPB", "U", "RW", 100), ("DB", "N1", "RW", E), ("ALFN", "U", "RW", 2),
    ("REHI", "S4", "RW", 0x5207), ("ALMD", "U", "RW", 0), ("ALHY", "S5", "RW", 1),
    ("ALFT", "U", "RW", 0), ("COMM", "U", "RW", 1), ("ADDR", "U", "RW", 1),
    ("BAUD", "U", "RW", 2), ("DATA", "U", "RW", 1), ("PARI", "U", "RW", 0),
    ("STOP", "U", "RW", 0), ("SEL1", "U", "RW", 2), ("SEL2", "U", "RW", 3),
    ("SEL3", "U", "RW", 4), ("SEL4", "U", "RW", 6), ("SEL5", "U", "RW", 7),
    ("SEL6", "U", "RW", 8), ("SEL7", "U", "RW", 10), ("SEL8", "U", "RW", 17),
    ("DATE", "U", "RW", 0), ("SRNO", "U", "RW", 0), ("HOUR", "U", "RW", 0),
    ("ADLO", "N1", "CAL", E), ("ADHI", "N1", "CAL", E), ("RTDL", "N1", "CAL", E),
    ("RTDH", "N1", "CAL", E), ("CJLO", "N2", "CAL", E), ("CJHI", "N1", "CAL", E),
    ("BPL1", "F2", "R", 0), ("BPL2", "F2", "R", 0), ("CJCL", "F3", "R", 0),
    ("PV", "S4", "R", E), ("SV", "S4", "R", E), ("MV1", "F2", "MAN", 0), ("MV2", "F2", "MAN", 0),
    ("TIMER", "N1", "R", E), ("EROR", "U", "R", 0), ("MODE", "U", "R", 0),
    ("PROG", "F2", "R", 610), ("CMND", "U", "RW", 0), ("JOB1", "U", "RW", 0),
    ("JOB2", "U", "RW", 0), ("JOB3", "U", "RW", 0), ("CJCT", "N2", "R", 22499),
    ("RSV77", "U", "R", 0), ("RSV78", "U", "R", 0), ("RSV79", "U", "R", 0),
]
# Enumerated registers whose legal codes follow from the manual (DEVICES.md 3.1, 3.6).
LIMITS = {"DP": (0, 3), "BAUD": (0, 6), "DATA": (0, 1), "PARI": (0, 2), "STOP": (0, 1),
          "ADDR": (1, 255), "MV1": (0, 10000), "MV2": (0, 10000), "LOCK": (0, 3)}
REGS = tuple(Reg(i, n, access=a, scale=s, default=d, lo=LIMITS.get(n, (None, None))[0],
                 hi=LIMITS.get(n, (None, None))[1]) for i, (n, s, a, d) in enumerate(MAP))
ALIASES = {128: 64, 129: 65, 130: 66, 131: 67}
BAUDS = (2400, 4800, 9600, 14400, 19200, 28800, 38400)
PARITY = "EON"                     # PARI 0 = Even, 1 = Odd, 2 = None
CMD_RESET, CMD_MANUAL, CMD_AUTOTUNE, CMD_CALIBRATE = 0x6825, 0x6827, 0x6828, 0x682D
MODE_NORMAL, MODE_CAL, MODE_AT, MODE_MANUAL = 0x00, 0x01, 0x02, 0x03
EROR_FUNC, EROR_ADDR, EROR_RO, EROR_RANGE = 10, 11, 14, 15
AUTOTUNE_S = 120.0                 # simulated seconds MODE shows auto-tuning (choice)
MAX_WORDS = 80                     # Example 6 reads 0x50 words (manual table: 79), see 3.3
LOCK_FREE = {"LOCK", "CMND", "JOB1", "JOB2", "JOB3"}   # writable whatever LOCK is (choice)


class Fdc100(Device):
    """FDC Series 100 (BTC-9100) PID controller."""

    KIND = "fdc100"
    REGS = REGS
    FUNCTIONS = (3, 6, 16)

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.loop = Loop()
        self.mode = MODE_NORMAL
        self.at_left = 0.0
        self.eror_set = False
        self.words[39] = addr
        if line.baud in BAUDS:
            self.words[40] = BAUDS.index(line.baud)
        self.words[41] = 1 if line.data_bits == 8 else 0
        self.words[42] = PARITY.index(line.parity)
        self.words[43] = 1 if line.stop_bits == 2 else 0

    # ----- encoding -----
    def linear_input(self) -> bool:
        """INPT codes 0..10 are thermocouples/RTDs (non-linear), 11 and up linear (L)."""
        return self.words[4] > 10

    def scaling(self, reg):
        if reg.scale in ("S4", "S6", "S7"):
            fixed = (reg.scale == "S6" and self.words[33] == 1)
            d = self.words[6] if self.linear_input() and not fixed else 1
            return min(d, 3), E
        if reg.scale == "S5":
            return (min(self.words[6], 3) if self.linear_input() else 1), 0
        return FIXED[reg.scale]

    def value(self, name):
        reg = self.by_name[name]
        return self.to_eng(reg, self.word(reg.addr))

    def eng_to_word(self, name, value):
        return max(0, min(0xFFFF, self.from_eng(self.by_name[name], value)))

    # ----- windows, access, ranges -----
    def max_read(self, fc):
        return MAX_WORDS

    def max_write(self, fc):
        return 79                        # "No. of words (1-79)", byte count 2..158

    def readable(self, fc, start, count):
        end = start + count - 1
        return end <= 79 or (start >= 128 and end <= 131)

    def writable_reg(self, addr):
        return super().writable_reg(ALIASES.get(addr, addr))

    def check_write(self, reg, addr, raw):
        access = reg.access
        if access == "MAN":
            access = "RW" if self.mode == MODE_MANUAL else "R"
        elif access == "CAL":
            access = "RW" if self.mode == MODE_CAL else "R"
        locked = self.words[3] and reg.name not in LOCK_FREE and (
            reg.name != "SP1" or self.words[3] >= 3)
        if access == "R" or locked:
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name} read-only or locked")
        if not self.in_range(reg, raw):
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name}={raw} out of range")

    def in_range(self, reg, raw):
        if reg.name == "SP1":
            return self.words[9] <= raw <= self.words[10]
        if reg.name == "CMND":
            return raw in (CMD_RESET, CMD_MANUAL, CMD_AUTOTUNE, CMD_CALIBRATE)
        return super().in_range(reg, raw)

    def on_exception(self, code):
        """EROR (69) gets the communication error of the exception (Table A.1)."""
        if code == 1:
            self.words[69] = EROR_FUNC
        elif code == 2:
            self.words[69] = EROR_ADDR
        elif not self.eror_set:
            self.words[69] = EROR_RANGE
        self.eror_set = False

    def write_block(self, fc, start, values):
        if not (start + len(values) - 1 <= 79 or (start >= 128 and start + len(values) - 1 <= 131)):
            raise ModbusError(ILLEGAL_ADDRESS, f"write {start}+{len(values)}")
        try:
            super().write_block(fc, start, values)
        except ModbusError as err:
            if err.code == ILLEGAL_VALUE:
                self.words[69] = EROR_RO if "read-only" in str(err) else EROR_RANGE
                self.eror_set = True
            raise

    # ----- live words and aliases -----
    def word(self, addr):
        addr = ALIASES.get(addr, addr)
        if addr == 64:
            return self.eng_to_word("PV", self.loop.plant.temp + self.value("SHIF"))
        if addr == 65:
            return self.words[0]
        if addr == 66:
            return int(round(self.loop.output * 100))
        if addr == 70:
            return (self.mode << 8) | self.alarm()
        return self.words.get(addr, 0)

    def store(self, addr, word):
        addr = ALIASES.get(addr, addr)
        if addr == 64:                    # control 'set' of PV moves the process
            self.loop.plant.temp = self.to_eng(self.by_name["PV"], word) - self.value("SHIF")
        elif addr == 66:
            self.loop.manual = word / 100.0 if self.mode == MODE_MANUAL else None
            self.loop.output = word / 100.0
        elif addr == 70:
            self.mode = word >> 8
        else:
            self.words[addr] = word & 0xFFFF

    def alarm(self) -> int:
        """Alarm status (low byte of MODE). Modelled: ALFN 2 = deviation high (PV > SV + SP3)."""
        if self.words[33] == 2:
            return int(self.value("PV") > self.value("SP1") + self.value("SP3"))
        return 0

    # ----- commands -----
    def after_write(self, reg, addr, word):
        if reg.name == "ADDR":
            self.addr = word
        if reg.name != "CMND":
            return
        if word == CMD_RESET:             # like the R key: back to automatic control
            self.mode, self.loop.manual, self.words[69] = MODE_NORMAL, None, 0
        elif word == CMD_MANUAL:
            self.mode, self.loop.manual = MODE_MANUAL, self.loop.output
        elif word == CMD_AUTOTUNE:
            self.mode, self.loop.manual, self.at_left = MODE_AT, None, AUTOTUNE_S
        elif word == CMD_CALIBRATE:
            self.mode = MODE_CAL

    def line_matches(self):
        w = self.words
        return (w[40] < len(BAUDS) and BAUDS[w[40]] == self.line.baud
                and w[42] <= 2 and PARITY[w[42]] == self.line.parity
                and (8 if w[41] == 1 else 7) == self.line.data_bits)

    # ----- dynamics -----
    def tick(self, dt):
        if self.mode == MODE_AT:
            self.at_left -= dt
            if self.at_left <= 0:
                self.mode = MODE_NORMAL
        self.loop.run(dt, self.value("SP1"), band=self.value("PB"), ti=self.words[15],
                      td=self.value("TD"), bias=0.0, hyst=self.value("O1HY"),
                      cooling=self.words[17] == 1)

    def power_cycle(self):
        """Volatile state: mode (manual, auto-tune, calibration unlock), error code, output."""
        self.loop.restart()
        self.mode = MODE_NORMAL
        self.words[69] = 0
        self.words[72] = 0

    def describe(self):
        return {**super().describe(), "pv": round(self.loop.plant.temp, 3),
                "output": round(self.loop.output, 2), "mode": self.mode}
