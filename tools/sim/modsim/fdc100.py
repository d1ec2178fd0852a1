"""FDC Series 100 / Brainchild BTC-9100 family: maps/fdc100.json, manual chapter 7.

Per the manual: FC 03, 06, 16 only (else exception 01 and EROR 10); registers 0..79 and the
aliases 128..131 = 64..67 (else 02, EROR 11); writes to read-only or locked registers -> 03 and
EROR 14; out-of-range values -> 03 and EROR 15. Words are unsigned with the linear mapping
M = A * 10^d + offset (section 3.6). CMND (72) commands: reset, manual, auto-tune, calibration.
"""
from __future__ import annotations

from .regmap import ILLEGAL_ADDRESS, ILLEGAL_VALUE, Device, ModbusError, load_map
from .thermal import Loop

MAP = load_map("fdc100")
# Registers (access RW, R, MAN = R/W in manual mode, CAL = R/W after CMND = 0x682D), scales,
# ranges and Example-1 defaults: maps/fdc100.json.
ALIASES = {a: r.addr for r in MAP.registers for a in r.aliases_at}     # 128..131 -> 64..67
BAUDS = tuple(sorted(MAP.bauds(), key=MAP.bauds().get))               # index = BAUD code
PARITY = "".join(sorted(MAP.table("PARI"), key=MAP.table("PARI").get))  # "EON": PARI 0 = Even
DATA_BITS = {int(k): v for k, v in MAP.table("DATA").items()}          # 7 -> 0, 8 -> 1
STOP_BITS = {int(k): v for k, v in MAP.table("STOP").items()}          # 1 -> 0, 2 -> 1
CMND = MAP.table("CMND")
CMD_RESET, CMD_MANUAL, CMD_AUTOTUNE, CMD_CALIBRATE = (
    CMND[k] for k in ("RESET", "MANUAL", "AUTOTUNE", "CALIBRATE"))
MODE = MAP.table("MODE")
MODE_NORMAL, MODE_CAL, MODE_AT, MODE_MANUAL = (
    MODE[k] for k in ("NORMAL", "CALIBRATION", "AUTOTUNE", "MANUAL"))
EROR = MAP.table("EROR")
EROR_FUNC, EROR_ADDR, EROR_RO, EROR_RANGE = (
    EROR[k] for k in ("BAD_FUNCTION", "BAD_ADDRESS", "READ_ONLY", "OUT_OF_RANGE"))
ALFN_DEHI = MAP.code("ALFN", "DEHI")
A = {r.name: r.addr for r in MAP.registers}
AUTOTUNE_S = 120.0                 # simulated seconds MODE shows auto-tuning (choice)
MAX_WORDS = MAP.function(3)["max_words"]       # Example 6 reads 0x50 words (manual: 79)
MAX_WRITE = MAP.function(16)["max_words"]      # "No. of words (1-79)", byte count 2..158
LAST = MAP.function(3)["window"][1]
ALIAS_LO, ALIAS_HI = MAP.function(3)["alias_window"]
LOCK_FREE = {"LOCK", "CMND", "JOB1", "JOB2", "JOB3"}   # writable whatever LOCK is (choice)


class Fdc100(Device):
    """FDC Series 100 (BTC-9100) PID controller."""

    KIND = "fdc100"
    MAP = MAP

    def __init__(self, addr, line, rng):
        super().__init__(addr, line, rng)
        self.loop = Loop()
        self.mode = MODE_NORMAL
        self.at_left = 0.0
        self.eror_set = False
        self.block = {}             # the words of an FC16 being checked: address -> word
        self.words[A["ADDR"]] = addr
        if line.baud in BAUDS:
            self.words[A["BAUD"]] = BAUDS.index(line.baud)
        self.words[A["DATA"]] = DATA_BITS[line.data_bits]
        self.words[A["PARI"]] = PARITY.index(line.parity)
        self.words[A["STOP"]] = STOP_BITS[line.stop_bits]

    # ----- encoding -----
    def scaling(self, reg):
        """Scale classes of the map: *4..*7 follow INPT/DP (and ALFN for *6), the rest fixed."""
        w = self.words
        return MAP.scaling(reg.name, {"INPT": w[A["INPT"]], "DP": w[A["DP"]], "ALFN": w[A["ALFN"]]})

    def value(self, name):
        reg = self.by_name[name]
        return self.to_eng(reg, self.word(reg.addr))

    def eng_to_word(self, name, value):
        return max(0, min(0xFFFF, self.from_eng(self.by_name[name], value)))

    # ----- windows, access, ranges -----
    def max_read(self, fc):
        return MAX_WORDS

    def max_write(self, fc):
        return MAX_WRITE

    def readable(self, fc, start, count):
        end = start + count - 1
        return end <= LAST or (start >= ALIAS_LO and end <= ALIAS_HI)

    def writable_reg(self, addr):
        return super().writable_reg(ALIASES.get(addr, addr))

    def check_write(self, reg, addr, raw):
        access = reg.access
        if access == "MAN":
            access = "RW" if self.mode == MODE_MANUAL else "R"
        elif access == "CAL":
            access = "RW" if self.mode == MODE_CAL else "R"
        lock = self.words[A["LOCK"]]
        locked = lock and reg.name not in LOCK_FREE and (reg.name != "SP1" or lock >= 3)
        if access == "R" or locked:
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name} read-only or locked")
        if not self.in_range(reg, raw):
            raise ModbusError(ILLEGAL_VALUE, f"{reg.name}={raw} out of range")

    def limit_raw(self, reg):
        """SP1 lies within SP1L..SP1H as they are after the write: an FC16 that brings new
        limits with SP1 (Example 1's whole parameter block) is checked as one set."""
        return self.block.get(reg.addr, self.words[reg.addr])

    def in_range(self, reg, raw):
        if reg.name == "CMND":
            return raw in CMND.values()
        return super().in_range(reg, raw)

    def on_exception(self, code):
        """EROR (69) gets the communication error of the exception (Table A.1)."""
        if code == 1:
            self.words[A["EROR"]] = EROR_FUNC
        elif code == 2:
            self.words[A["EROR"]] = EROR_ADDR
        elif not self.eror_set:
            self.words[A["EROR"]] = EROR_RANGE
        self.eror_set = False

    def write_block(self, fc, start, values):
        if not self.readable(16, start, len(values)):
            raise ModbusError(ILLEGAL_ADDRESS, f"write {start}+{len(values)}")
        self.block = {ALIASES.get(start + i, start + i): w for i, w in enumerate(values)}
        try:
            super().write_block(fc, start, values)
        except ModbusError as err:
            if err.code == ILLEGAL_VALUE:
                self.words[A["EROR"]] = EROR_RO if "read-only" in str(err) else EROR_RANGE
                self.eror_set = True
            raise
        finally:
            self.block = {}

    # ----- live words and aliases -----
    def word(self, addr):
        addr = ALIASES.get(addr, addr)
        if addr == A["PV"]:
            return self.eng_to_word("PV", self.loop.plant.temp + self.value("SHIF"))
        if addr == A["SV"]:
            return self.words[A["SP1"]]
        if addr == A["MV1"]:
            return int(round(self.loop.output * 100))
        if addr == A["MODE"]:
            return (self.mode << 8) | self.alarm()
        return self.words.get(addr, 0)

    def store(self, addr, word):
        addr = ALIASES.get(addr, addr)
        if addr == A["PV"]:               # control 'set' of PV moves the process
            self.loop.plant.temp = self.to_eng(self.by_name["PV"], word) - self.value("SHIF")
        elif addr == A["MV1"]:
            self.loop.manual = word / 100.0 if self.mode == MODE_MANUAL else None
            self.loop.output = word / 100.0
        elif addr == A["MODE"]:
            self.mode = word >> 8
        else:
            self.words[addr] = word & 0xFFFF

    def alarm(self) -> int:
        """Alarm status (low byte of MODE). Modelled: ALFN 2 = deviation high (PV > SV + SP3)."""
        if self.words[A["ALFN"]] == ALFN_DEHI:
            return int(self.value("PV") > self.value("SP1") + self.value("SP3"))
        return 0

    # ----- commands -----
    def after_write(self, reg, addr, word):
        if reg.name == "ADDR":
            self.addr = word
        if reg.name != "CMND":
            return
        if word == CMD_RESET:             # like the R key: back to automatic control
            self.mode, self.loop.manual, self.words[A["EROR"]] = MODE_NORMAL, None, 0
        elif word == CMD_MANUAL:
            self.mode, self.loop.manual = MODE_MANUAL, self.loop.output
        elif word == CMD_AUTOTUNE:
            self.mode, self.loop.manual, self.at_left = MODE_AT, None, AUTOTUNE_S
        elif word == CMD_CALIBRATE:
            self.mode = MODE_CAL

    def char_format(self):
        """(baud, data bits, parity, stop bits) from its BAUD, DATA, PARI and STOP registers."""
        w = self.words
        inv = lambda table, code: next((k for k, v in table.items() if v == code), None)  # noqa: E731
        return (BAUDS[w[A["BAUD"]]] if w[A["BAUD"]] < len(BAUDS) else -1,
                inv(DATA_BITS, w[A["DATA"]]) or -1,
                PARITY[w[A["PARI"]]] if w[A["PARI"]] < len(PARITY) else "?",
                inv(STOP_BITS, w[A["STOP"]]) or -1)

    # ----- dynamics -----
    def tick(self, dt):
        if self.mode == MODE_AT:
            self.at_left -= dt
            if self.at_left <= 0:
                self.mode = MODE_NORMAL
        self.loop.run(dt, self.value("SP1"), band=self.value("PB"), ti=self.words[A["TI"]],
                      td=self.value("TD"), bias=0.0, hyst=self.value("O1HY"),
                      cooling=self.words[A["OUT1"]] == 1)

    def power_cycle(self):
        """Volatile state: mode (manual, auto-tune, calibration unlock), error code, output."""
        self.loop.restart()
        self.mode = MODE_NORMAL
        self.words[A["EROR"]] = 0
        self.words[A["CMND"]] = 0

    def describe(self):
        return {**super().describe(), "pv": round(self.loop.plant.temp, 3),
                "output": round(self.loop.output, 2), "mode": self.mode}
