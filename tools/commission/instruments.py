"""What the commissioning tool knows of the three instruments, all of it from maps/*.json: how
to recognise one on a line, which registers are its settings, in which order they are restored,
and its settings as an ST recipe (the declarations of a scan: oneline.py).

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
import settings as settings_desc  # noqa: E402

MODELS = {"fdc100": "FDC-100", "mvd94": "MV-D94/VD", "mts9": "MT-S9"}
BLOCKS = {"fdc100": "FDC_Controller", "mvd94": "TempCtrl_MVD94", "mts9": "Counter_MTS9"}


def __getattr__(name):
    """LINE_REGS (kind -> names of the registers that set the line), LOCK and AUTHOR (kind ->
    (register, the code that opens it)): from the one description of the settings,
    maps/settings.py (keys "recipe", "unlocked" of the registers in maps/*.json). Worked out
    on first use, so that a broken map is reported by the command (exit 6), not at import."""
    if name == "LINE_REGS":
        value = {k: {r.name for r in mbmap.load(k).registers if r.recipe == "line"}
                 for k in MODELS}
    elif name in ("LOCK", "AUTHOR"):
        value = {k: (a[0].name, a[1]) for k in MODELS
                 for a in [settings_desc.access_register(k)] if a and a[2] == name.lower()}
    else:
        raise AttributeError(name)
    globals()[name] = value
    return value


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
    """The registers a restore writes, in write order (the lock and access level apart):
    maps/settings.py's restorable()."""
    return settings_desc.restorable(kind)


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


def st_recipe(data: dict, name: str | None = None) -> str:
    """A backup as its settings structure's initial value, declared (maps/settings.py): the
    recipe fields in alphabetical order, ready to paste into a VAR block."""
    kind = data["kind"]
    values = settings_desc.from_raw(kind, {n: e["raw"] for n, e in data["registers"].items()})
    line = data.get("line", {})
    where = f"{data['model']} at {line.get('address', '?')}"
    if line:
        where += (f" on {line.get('port')}, {line.get('baud')} {line.get('format')} "
                  f"{str(line.get('framing', '')).upper()}")
    left = settings_desc.left_out_text(kind)
    head = settings_desc.wrap(f"(* {where.replace('*)', '* )')}, backed up {data.get('saved', '')}"
                              f" by mbcommission. Not in it: {left}. *)", "   ", 96)
    head[0] = head[0].lstrip()
    name = name or f"{kind}_{line.get('address', 0)}_recipe"
    body = settings_desc.st_initial(kind, values).replace("\n", "\n    ")
    return "\n".join(head) + f"\n{name} : {settings_desc.type_name(kind)} :=\n    {body};\n"


def st_kind(text: str) -> str | None:
    """The kind whose settings type an ST text names (None: a bare initial value)."""
    for k in MODELS:
        if settings_desc.type_name(k).upper() in text.upper():
            return k
    return None


def recipe_backup(kind: str, text: str, have: dict) -> dict:
    """What a device would hold with an ST recipe applied: `have` (a backup of it) with the
    recipe's fields over it. SettingError names a field that does not parse or fits no range."""
    raw = settings_desc.to_raw(kind, settings_desc.parse_initial(kind, text))
    regs = {n: dict(e) for n, e in have["registers"].items()}
    fields = settings_desc.by_field(kind)
    for f, r in raw.items():
        regs[fields[f].reg.name]["raw"] = r
    state = {k: v["raw"] for k, v in regs.items() if k in ("DP", "INPT", "ALFN")}
    m = mbmap.load(kind)
    regs = {n: describe(kind, m.reg(n), e["raw"], state) for n, e in regs.items()}
    return {**have, "registers": regs, "from_st": True}
