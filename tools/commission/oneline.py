"""The scan's declarations for one port: one MB_LINE that every block on the port uses, or, where
the instruments found disagree (baud, framing, character format), what to change on which
instrument so that they can share one line.

Why: the blocks on one port share one bus and one set of line settings (a block that opens the
port with other settings gets ErrorID 9), and Modbus allows one transmission mode per line.
What can change comes from the maps (maps/*.json "line"): the bauds, formats and framings a model
speaks, its baud register, its framing register (MT-S9 Type), its format registers (FDC DATA,
PARI, STOP), and the access level a write needs (MT-S9 table AUTHOR).
Stop bits need not agree: a UART checks the first stop bit only, so the line takes the most any
instrument wants and the others hear it.
"""
from __future__ import annotations

import os
import re

import instruments as ins


def key(setting, f) -> tuple:
    """(baud, framing, data bits, parity) an instrument speaks; stop bits apart."""
    baud, fmt, _ = setting
    fmt = f.format or fmt
    return baud, f.framing, int(fmt[0]), fmt[1]


def show(k, stop=None) -> str:
    baud, framing, data, parity = k
    return f"{baud} {data}{parity}{stop or ''} {framing.upper()}"


def changes(kind: str, have: tuple, want: tuple) -> list | None:
    """What to set on an instrument of `kind` speaking `have` so it speaks `want`: a list of
    sentences (empty: nothing), or None when the model cannot speak `want`."""
    m = ins.maps()[kind]
    line = m.line
    out = []
    author = ins.AUTHOR.get(kind)
    levels = m.tables.get("AUTHOR", {}).get("codes", {})

    def register(name, code, label):
        r = m.reg(name)
        need = levels.get(r.name)
        extra = f" (with {author[0]} ({m.reg(author[0]).addr}) >= {need} first)" if need else ""
        return f"{r.name} ({r.addr}) := {code} ({label}){extra}"
    if want[0] != have[0]:
        code = m.bauds().get(want[0])
        if code is None:
            return None
        out.append(register(line["baud_register"], code, want[0]))
    if want[1] != have[1]:
        if want[1] not in line["framings"] or "framing_register" not in line:
            return None
        out.append(register(line["framing_register"], m.code("TYPE", want[1]), want[1].upper()))
    if want[2:] != have[2:]:
        fmts = line.get("formats")
        if fmts is not None and not any(f[:2] == f"{want[2]}{want[3]}" for f in fmts):
            return None
        regs = line.get("format_registers")
        if regs:
            data, parity = regs[0], regs[1]
            out.append(register(data, m.code(data, str(want[2])), f"{want[2]} data bits"))
            out.append(register(parity, m.code(parity, want[3]), f"parity {want[3]}"))
        else:
            out.append(f"character format {want[2]}{want[3]} (no register: in its menu)")
    return out


def line_name(port: str) -> str:
    base = re.sub(r"\W", "_", os.path.basename(port.rstrip("/")) or port)
    return f"line_{base}".rstrip("_")


def mb_line(k, stop: int) -> str:
    baud, framing, data, parity = k
    fields = [f"Baud := {baud}"]
    if data != 8:
        fields.append(f"DataBits := {data}")
    if framing != "rtu":
        fields.append(f"Framing := '{framing.upper()}'")
    fields += [f"Parity := '{parity}'", f"StopBits := {stop}"]
    return f"MB_LINE := ({', '.join(fields)})"


def plan(found: list):
    """(target key, stop bits, members [(setting, Found)], others [(Found, key, changes or
    None)]) for the known instruments found on one port; None when none is known."""
    known = [(s, f) for s, f in found if f.kind in ins.MODELS]
    if not known:
        return None
    keys = []
    for s, f in known:
        if key(s, f) not in keys:
            keys.append(key(s, f))
    best = None
    for k in keys:          # the line most instruments speak now and the others can move to
        members = [(s, f) for s, f in known if key(s, f) == k]
        others = [(f, key(s, f), changes(f.kind, key(s, f), k)) for s, f in known
                  if key(s, f) != k]
        score = (all(c is not None for _, _, c in others), len(members))
        if best is None or score > best[0]:
            best = (score, k, members, others)
    _, k, members, others = best
    stop = max(int((f.format or s[1])[2]) for s, f in members)
    return k, stop, members, others


def declarations(found: list, port: str) -> str:
    """The text after the scan's table: one MB_LINE and the blocks that use it; before it, when
    the instruments disagree, which line they cannot share and what to change."""
    p = plan(found)
    out = []
    unknown = [f for _, f in found if f.kind not in ins.MODELS]
    if unknown:
        out.append("no block for " + ", ".join(f"the unknown device at {f.address}"
                                               for f in unknown))
    if p is None:
        return "\n".join(out)
    k, stop, members, others = p
    name = line_name(port)
    if others:
        groups, stops = {}, {}
        for s, f in [(s, f) for s, f in found if f.kind in ins.MODELS]:
            groups.setdefault(key(s, f), []).append(f"{f.model} at {f.address}")
            stops[key(s, f)] = max(stops.get(key(s, f), 1), int((f.format or s[1])[2]))
        out.append(f"\nThe instruments on {port} do not share one line setting. The blocks on one "
                   "port share one MB_LINE (another one gives ErrorID 9), and Modbus allows one "
                   "transmission mode per line:")
        out += [f"  at {show(g, stops[g])}: {', '.join(ws)}" for g, ws in groups.items()]
        movable = [(f, c) for f, _, c in others if c is not None]
        stuck = [(f, have) for f, have, c in others if c is None]
        if movable:
            out.append(f"To put them on {show(k, stop)} (the line of {len(members)} of "
                       f"{len(members) + len(others)}), set (a register write from a master on the "
                       "instrument's present line, or the instrument's menu):")
            out += [f"  {f.model} at {f.address}: " + "; ".join(c) for f, c in movable]
        for f, have in stuck:
            out.append(f"  {f.model} at {f.address} cannot speak {show(k, stop)} (it speaks "
                       f"{show(have)}): give it a port of its own")
        out.append(f"then scan again. The declarations below are for {show(k, stop)}: the "
                   f"instruments on it now ({len(members)}), the others left out.")
    out.append(f"\n(* {port}: {show(k, stop)} *)\nVAR\n  {name} : {mb_line(k, stop)};")
    for s, f in members:
        out.append(f"  {f.kind}_{f.address} : {ins.BLOCKS[f.kind]};")
    out.append("END_VAR")
    for s, f in members:
        out.append(f"{f.kind}_{f.address}(Enable := TRUE, Port := '{port}', "
                   f"SlaveId := {f.address}, Line := {name});")
    return "\n".join(out)
