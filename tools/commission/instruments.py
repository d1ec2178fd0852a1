"""What the commissioning tool knows of the three instruments, all of it from maps/*.json: how
to recognise one on a line, which registers are its settings, in which order they are restored,
and the ST declaration that drives it.

Identification never guesses: each check reads registers the map defines and states them.
  FDC-100   ADDR (39) = the address, BAUD (40) = the line's baud code, PROG (71) = a model of
            the PROG_MODEL table (model and firmware: PROG = 100 x model.version)
  MV-D94/VD ADDR (27) = the address, BAUD (28) = the line's baud code, PV answers FC04 at 4096
  MT-S9     ID Address Set (6) = the address, Baud Rate Set (7) = the line's baud code, Type (8)
            a code of its TYPE table (the framing it speaks)
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__)))), "maps"))
import mbmap  # noqa: E402

MODELS = {"fdc100": "FDC-100", "mvd94": "MV-D94/VD", "mts9": "MT-S9"}
BLOCKS = {"fdc100": "FDC_Controller", "mvd94": "TempCtrl_MVD94", "mts9": "Counter_MTS9"}
# Registers that set the line (the device would leave it when restored) and values that are
# no settings (a count, a command, factory data); never restored.
LINE_REGS = {"mvd94": {"ADDR", "BAUD"}, "fdc100": {"ADDR", "BAUD", "DATA", "PARI", "STOP", "COMM"},
             "mts9": {"ID Address Set", "Baud Rate Set", "Type"}}
NOT_SETTINGS = {"mvd94": set(), "mts9": {"Real Data"},
                "fdc100": {"CMND", "JOB1", "JOB2", "JOB3", "DATE", "SRNO", "HOUR"}}
# Restore order: what the others' scaling and limits depend on first (the manuals: input type,
# unit and decimal point before limits and set points); the lock register last.
FIRST = {"mvd94": ["TYPE", "UNIT", "DP", "ACT", "LOLT", "HILT"],
         "fdc100": ["INPT", "UNIT", "DP", "INLO", "INHI", "SP1L", "SP1H"],
         "mts9": ["Decimal Set"]}
LOCK = {"mvd94": ("LOCK", 0x20), "fdc100": ("LOCK", 0)}   # register, its unlocked code
AUTHOR = {"mts9": ("Author", 5)}   # set-up writes need Author >= 1..4: raised, then restored


@dataclass
class Found:
    """An instrument identified at an address, with the registers that made it."""
    kind: str
    address: int
    evidence: list
    firmware: str = ""
    framing: str = "rtu"
    format: str = ""
    words: dict = field(default_factory=dict)

    @property
    def model(self) -> str:
        return MODELS.get(self.kind, "unknown")


def maps() -> dict:
    return {k: mbmap.load(k) for k in MODELS}


def _baud_code(m, baud):
    return m.bauds().get(baud)


def identify(read, address: int, baud: int, fmt: str, framing: str) -> Found | None:
    """Which instrument answers at `address`; read(fc, addr, count) -> (rc, words)."""
    fdc, mv, mt = maps()["fdc100"], maps()["mvd94"], maps()["mts9"]
    rc, w = read(3, 39, 5)
    if rc == 0 and w[0] == address and w[1] == _baud_code(fdc, baud):
        rc, p = read(3, 71, 1)
        model = fdc.label("PROG_MODEL", p[0] // 100) if rc == 0 else None
        if model:
            fw = f"version {p[0] % 100} (PROG {p[0] // 100}.{p[0] % 100:02d})"
            data, pari, stop = (fdc.label(t, v) for t, v in zip(("DATA", "PARI", "STOP"), w[2:]))
            return Found("fdc100", address, [
                f"ADDR(39)={w[0]}", f"BAUD(40)={w[1]} ({baud})",
                f"PROG(71)={p[0]} -> {model}, {fw}",
                f"DATA/PARI/STOP(41..43)={w[2]},{w[3]},{w[4]} -> {data}{pari}{stop}"],
                firmware=f"{model} {fw}", format=f"{data}{pari}{stop}")
    rc, w = read(3, 27, 2)
    if rc == 0 and w[0] == address and w[1] == _baud_code(mv, baud):
        rc4, pv = read(4, 4096, 1)
        if rc4 == 0:
            return Found("mvd94", address, [
                f"ADDR(27)={w[0]}", f"BAUD(28)={w[1]} ({mv.label('BAUD', w[1])})",
                f"PV answers FC04 at 4096 ({pv[0]})"], format="8N2")
    rc, w = read(3, 6, 3)
    if rc == 0 and w[0] == address and w[1] == _baud_code(mt, baud):
        speaks = mt.label("TYPE", w[2])
        if speaks is not None:
            return Found("mts9", address, [
                f"ID Address Set(6)={w[0]}", f"Baud Rate Set(7)={w[1]} ({baud})",
                f"Type(8)={w[2]} ({speaks})"], framing=speaks.lower(), format=fmt)
    return None


def settings(kind: str) -> list:
    """The restorable registers of a kind, in restore order (lock/author handled apart)."""
    m = maps()[kind]
    skip = LINE_REGS[kind] | NOT_SETTINGS[kind] | {LOCK.get(kind, ("",))[0]} | \
        {AUTHOR.get(kind, ("",))[0]}
    regs = [r for r in m.registers if r.access == "RW" and r.name not in skip and 3 in r.fc]
    first = [m.reg(n) for n in FIRST[kind]]
    return first + [r for r in regs if r not in first]


def readable(kind: str) -> list:
    """Every register of a kind read with FC03 (a backup holds them all)."""
    return [r for r in maps()[kind].registers if 3 in r.fc]


def describe(kind: str, reg, raw: int, state: dict) -> dict:
    """One register of a backup: raw word(s), engineering value with unit, code name."""
    m = maps()[kind]
    entry = {"addr": reg.addr, "raw": raw, "unit": reg.unit}
    if reg.codes and reg.codes in m.tables:
        entry["code"] = m.label(reg.codes, raw)
    else:
        try:
            entry["value"] = m.to_eng(reg, raw, state)
        except (KeyError, mbmap.MapError):
            entry["value"] = raw
    return entry


def st_declaration(found: Found, port: str, baud: int, fmt: str) -> str:
    """The ST to paste for an instrument: its block and, where not the block's default, MB_LINE."""
    data, parity, stop = int(fmt[0]), fmt[1], int(fmt[2])
    name = f"{found.kind}_{found.address}"
    fields = [f"Baud := {baud}"]
    if data != 8:
        fields.append(f"DataBits := {data}")
    if found.framing != "rtu":
        fields.append(f"Framing := '{found.framing.upper()}'")
    fields += [f"Parity := '{parity}'", f"StopBits := {stop}"]
    return (f"VAR\n  {name}_line : MB_LINE := ({', '.join(fields)});\n"
            f"  {name} : {BLOCKS[found.kind]};\nEND_VAR\n"
            f"{name}(Enable := TRUE, Port := '{port}', SlaveId := {found.address}, "
            f"Line := {name}_line);")
