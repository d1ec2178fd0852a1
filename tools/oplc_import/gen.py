"""Structured Text of a converted configuration: MB_Poll instances into the located addresses,
writes on change (OPLC_WriteBits / OPLC_WriteWords), each device's status. README.md shows the
shape; readers.py gives the model."""
from __future__ import annotations

import re

from readers import MAX_READ_REGS, Problem

MAX_RANGES = 4                  # MB_Poll's ranges (Fc1..Fc4)

# Written once into every output: a write of bits or words, sent when the values differ from
# what the device was last confirmed to hold (or were never written), not every poll. One text,
# rendered for coils and for registers: ST has no generic block over MB_BITS / MB_REGS.
WRITE_FB = """\
FUNCTION_BLOCK {name}
  VAR_INPUT
    Port : STRING;
    SlaveId : INT := 1;
    Line : MB_LINE;
    Addr : UDINT;
    Count : INT := 1;
    Single : BOOL;               (* {single} of one {unit} instead of {multi} *)
    Retry : TIME := T#1s;
    Values : {values};            (* the output {what} now *)
  END_VAR
  VAR_OUTPUT
    Held : BOOL;
    Busy : BOOL;
    Error : BOOL;
    ErrorID : WORD;
    Writes : UDINT;              (* writes confirmed *)
  END_VAR
  VAR
    one : {one};
    many : {many};
    sent : {values};              (* what the device holds, once written is TRUE *)
    sending : {values};           (* what the write on the wire carries *)
    written : BOOL;
    exec : BOOL;                 (* a write is running: Execute held until Done or Error *)
    changed : BOOL;
    i : INT;
    wait : TON;
  END_VAR
  changed := NOT written;
  i := 0;
  WHILE i < Count DO
    IF Values[i] <> sent[i] THEN
      changed := TRUE;
    END_IF;
    i := i + 1;
  END_WHILE;
  IF exec THEN
    IF (Single AND one.Done) OR (NOT Single AND many.Done) THEN
      sent := sending;
      written := TRUE;
      exec := FALSE;
      Error := FALSE;
      ErrorID := 0;
      Writes := Writes + 1;
    ELSIF Single AND one.Error THEN
      exec := FALSE;
      Error := TRUE;
      ErrorID := one.ErrorID;
    ELSIF NOT Single AND many.Error THEN
      exec := FALSE;
      Error := TRUE;
      ErrorID := many.ErrorID;
    END_IF;
  ELSIF changed AND (NOT Error OR wait.Q) THEN
    sending := Values;
    exec := TRUE;
  END_IF;
  wait(IN := Error AND NOT exec, PT := Retry);
  IF Single THEN
    one(Execute := exec, Port := Port, SlaveId := SlaveId, Line := Line, Addr := Addr,
        Value := sending[0]);
  ELSE
    many(Execute := exec, Port := Port, SlaveId := SlaveId, Line := Line, Addr := Addr,
         Count := Count, Values := sending);
  END_IF;
  Busy := exec;
  Held := written AND NOT changed AND NOT exec;
END_FUNCTION_BLOCK
"""


def write_fb(name: str, doc: str, **kind) -> str:
    """One of the two write blocks: WRITE_FB for one Modbus area (its array types are both
    7 characters: the columns stay aligned)."""
    return doc + WRITE_FB.format(name=name, **kind)


HELPERS = write_fb(
    "OPLC_WriteBits",
    "(* OPLC_WriteBits - coils of a converted OpenPLC master entry: written (FC15, or FC05 when\n"
    "   Single) when Values differ from what the device last confirmed, or were never written;\n"
    "   after a failed write, again after Retry. Held: the device holds Values. *)\n",
    single="FC05", unit="coil", multi="FC15", values="MB_BITS", what="bits",
    one="MB_WriteCoil", many="MB_WriteCoils") + "\n" + write_fb(
    "OPLC_WriteWords",
    "(* OPLC_WriteWords - holding registers of a converted OpenPLC master entry, as OPLC_WriteBits:\n"
    "   FC16, or FC06 when Single. *)\n",
    single="FC06", unit="register", multi="FC16", values="MB_REGS", what="words",
    one="MB_WriteRegister", many="MB_WriteRegisters")


def located_name(loc: str) -> str:
    """'%IX100.3' -> 'oplc_IX100_3'."""
    return "oplc_" + loc[1:].replace(".", "_")


def located_key(decl: str):
    """Declarations by area, then address: '%IX100.3' -> ('IX', 100, 3)."""
    loc = decl.split(" AT ")[1].split(" ")[0]
    parts = loc[3:].split(".")
    return loc[1:3], int(parts[0]), int(parts[1]) if len(parts) > 1 else 0


def comment(text: str) -> str:
    """Text safe inside (* *)."""
    return text.replace("(*", "( *").replace("*)", "* )")


def st_string(text: str, where: str) -> str:
    if "'" in text or "$" in text or len(text) > 126:
        raise Problem("OI-02", where, f"{text!r} cannot be an ST string (quote, $ or over 126 "
                      "characters)")
    return f"'{text}'"


def pack_polls(dev) -> list[list]:
    """The device's reads in MB_Poll instances: ranges of one period together, at most 4 ranges
    and 125 snapshot words per instance, in their order."""
    polls = []
    for r in dev.reads:
        fit = next((p for p in polls if p[0].period_ms == r.period_ms and len(p) < MAX_RANGES
                    and sum(x.words for x in p) + r.words <= MAX_READ_REGS), None)
        if fit is None:
            polls.append([r])
        else:
            fit.append(r)
    return polls


def line_init(dev) -> str:
    """The device's MB_LINE initialiser (fields in alphabetical order: matiec)."""
    if dev.serial:
        return (f"(Baud := {dev.baud}, DataBits := {dev.data_bits}, Parity := '{dev.parity}', "
                f"StopBits := {dev.stop_bits}, TimeoutMs := {dev.timeout_ms})")
    return f"(TimeoutMs := {dev.timeout_ms})"


def check_located(devices, problems: list):
    """A located address is filled by one entry only."""
    seen = {}
    for dev in devices:
        for r in dev.reads + dev.writes:
            for loc in r.located:
                if loc in seen:
                    problems.append(Problem("OI-10", r.where, f"{loc} is also {seen[loc]}"))
                else:
                    seen[loc] = r.where


def check_ports(devices, problems: list):
    """Devices on one serial port share its line settings (one bus, one setting)."""
    first = {}
    for dev in devices:
        if not dev.serial:
            continue
        key = (dev.baud, dev.parity, dev.data_bits, dev.stop_bits)
        if dev.port in first and first[dev.port][0] != key:
            problems.append(Problem("OI-11", dev.where, f"{dev.port} at {key[0]} "
                                    f"{key[2]}{key[1]}{key[3]}, but {first[dev.port][1]} "
                                    f"set it to {first[dev.port][0][0]} {first[dev.port][0][2]}"
                                    f"{first[dev.port][0][1]}{first[dev.port][0][3]}"))
        first.setdefault(dev.port, (key, dev.where))


class Program:
    """The generated declarations and statements, by part, so they can make a PROGRAM of their
    own or go into the user's program (insert())."""

    def __init__(self, devices, source: str, flavour: str, names: dict | None = None):
        self.devices, self.source, self.flavour = devices, source, flavour
        self.names = names or {}        # located address -> (the user's variable, its type)
        self.located, self.vars, self.status, self.body = [], [], [], []
        self.ports = {}                 # port -> its STRING variable (one per port: change it there)
        for dev in devices:
            if dev.port not in self.ports:
                st_string(dev.port, dev.where)
                self.ports[dev.port] = f"oplc_port{len(self.ports)}"
        for i, dev in enumerate(devices):
            self.device(i, dev)

    def target(self, loc: str) -> tuple[str, str]:
        """(variable, type) a located address is read into / written from."""
        if loc in self.names:
            return self.names[loc]
        typ = "BOOL" if loc[2] == "X" else "WORD"
        self.located.append(f"    {located_name(loc)} AT {loc} : {typ};")
        return located_name(loc), typ

    def device(self, i: int, dev):
        d = f"dev{i}"
        port = self.ports[dev.port]
        kind = f"RTU {dev.port} {dev.baud} {dev.data_bits}{dev.parity}{dev.stop_bits}" \
            if dev.serial else dev.port
        self.vars.append(f"    (* device {i}: {comment(dev.name)}, {comment(kind)}, slave "
                         f"{dev.slave} *)")
        self.vars.append(f"    {d}_line : MB_LINE := {line_init(dev)};")
        self.status.append(f"    {d}_Valid : BOOL;            (* {comment(dev.name)}: every "
                           "read range refreshed and valid *)")
        self.status.append(f"    {d}_ErrorID : WORD;          (* its first read error, 0 = none *)")
        self.status.append(f"    {d}_WriteErrorID : WORD;     (* its last failed write, 0 = none *)")
        common = f"Port := {port}, SlaveId := {dev.slave}, Line := {d}_line"
        self.body.append(f"  (* device {i}: {comment(dev.name)} *)")
        valid, errs = [], []
        for k, poll in enumerate(pack_polls(dev)):
            inst = f"{d}_poll{k}"
            self.vars.append(f"    {inst} : MB_Poll;")
            args = [f"Enable := TRUE", common, f"Period := T#{poll[0].period_ms}ms"]
            for n, r in enumerate(poll, 1):
                args.append(f"Fc{n} := {r.fc}, Addr{n} := {r.addr}, Count{n} := {r.count}")
            self.body.append(f"  {inst}(" + ",\n    ".join(args) + ");")
            nbits = nwords = 0
            for r in poll:
                for j, loc in enumerate(r.located):
                    var, typ = self.target(loc)
                    if r.bits:
                        src = f"{inst}.Bits[{nbits + j}]"
                    else:
                        src = f"{inst}.Words[{nwords + j}]"
                        src = src if typ == "WORD" else f"WORD_TO_{typ}({src})"
                    self.body.append(f"  {var} := {src};")
                if r.bits:
                    nbits += r.count
                else:
                    nwords += r.count
            valid.append(f"{inst}.Valid")
            errs.append(inst)
        for k, w in enumerate(dev.writes):
            inst = f"{d}_write{k}"
            fb = "OPLC_WriteBits" if w.bits else "OPLC_WriteWords"
            self.vars.append(f"    {inst} : {fb};    (* FC{w.fc:02d} {w.addr}+{w.count} from "
                             f"{w.located[0]}.. *)")
            for j, loc in enumerate(w.located):
                var, typ = self.target(loc)
                src = var if typ in ("BOOL", "WORD") else f"{typ}_TO_WORD({var})"
                self.body.append(f"  {inst}.Values[{j}] := {src};")
            single = "TRUE" if w.fc in (5, 6) else "FALSE"
            self.body.append(f"  {inst}({common}, Addr := {w.addr}, Count := {w.count}, "
                             f"Single := {single}, Retry := T#{max(w.period_ms, 100)}ms);")
        self.body.append(f"  {d}_Valid := {' AND '.join(valid) if valid else 'FALSE'};")
        if errs:
            self.body.append(f"  {d}_ErrorID := 0;")
            for inst in reversed(errs):
                self.body.append(f"  IF {inst}.ErrorID <> 0 THEN {d}_ErrorID := {inst}.ErrorID; END_IF;")
        if dev.writes:
            self.body.append(f"  {d}_WriteErrorID := 0;")
            for k in reversed(range(len(dev.writes))):
                self.body.append(f"  IF {d}_write{k}.Error THEN {d}_WriteErrorID := "
                                 f"{d}_write{k}.ErrorID; END_IF;")

    def header(self) -> str:
        return (f"(* Generated by tools/oplc_import from {comment(self.source)} ({self.flavour}):"
                " the same devices polled\n   by MB_Poll into the same located addresses, "
                "outputs written when they change. Run the tool\n   again rather than edit; "
                "tools/oplc_import/README.md. *)\n")

    def var_blocks(self) -> str:
        out = []
        if self.located:
            out += ["  VAR", *sorted(self.located, key=located_key), "  END_VAR"]
        ports = [f"    {var} : STRING := {st_string(port, self.source)};"
                 for port, var in self.ports.items()]
        out += ["  VAR", *ports, *self.vars, "  END_VAR", "  VAR  (* each device's status *)",
                *self.status, "  END_VAR"]
        return "\n".join(out) + "\n"

    def statements(self) -> str:
        return "\n".join(self.body) + "\n"

    def standalone(self, name: str) -> str:
        return (self.header() + "\n" + HELPERS + "\nPROGRAM " + name + "\n" + self.var_blocks()
                + self.statements() + "END_PROGRAM\n")


# ----- into the user's program: its own names for the located addresses -----
DECL_RE = re.compile(r"\b([A-Za-z_]\w*)\s+AT\s+(%[IQM][XBWDL][\d.]+)\s*:\s*([A-Za-z_]\w*)",
                     re.IGNORECASE)
POU_RE = re.compile(r"\bPROGRAM\s+([A-Za-z_]\w*)(.*?)\bEND_PROGRAM\b", re.IGNORECASE | re.DOTALL)
WORD_TYPES = ("WORD", "INT", "UINT")


def strip_comments(text: str) -> str:
    """Comments blanked (same length), so positions stay those of the text."""
    return re.sub(r"\(\*.*?\*\)", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text,
                  flags=re.DOTALL)


def user_names(text: str, served: set, where: str) -> tuple[dict, str | None, list]:
    """{located: (name, type)} of the served addresses the user's program declares, the one
    PROGRAM that declares them, and problems (declared in two POUs, or of a type a Modbus bit or
    register cannot fill)."""
    clean = strip_comments(text)
    names, owners, problems = {}, set(), []
    for pou in POU_RE.finditer(clean):
        for m in DECL_RE.finditer(pou.group(2)):
            name, loc, typ = m.group(1), m.group(2).upper(), m.group(3).upper()
            if loc not in served:
                continue
            ok = typ == "BOOL" if loc[2] == "X" else typ in WORD_TYPES
            if not ok:
                problems.append(Problem("OI-12", where, f"{name} AT {loc} : {typ}: a Modbus "
                                        f"{'bit' if loc[2] == 'X' else 'register'} fills "
                                        f"{'BOOL' if loc[2] == 'X' else 'WORD, INT or UINT'}"))
                continue
            names[loc] = (name, typ)
            owners.add(pou.group(1))
    inside = [(m.start(2), m.end(2)) for m in POU_RE.finditer(clean)]
    for m in DECL_RE.finditer(clean):
        loc = m.group(2).upper()
        if loc in served and not any(a <= m.start() < b for a, b in inside):
            problems.append(Problem("OI-12", where, f"{m.group(1)} AT {loc} is declared outside "
                                    "a PROGRAM (VAR_GLOBAL?): the converted part fills the "
                                    "addresses a PROGRAM declares"))
    if len(owners) > 1:
        problems.append(Problem("OI-12", where, f"the served addresses are declared in several "
                                f"programs ({', '.join(sorted(owners))}): the converted part "
                                "goes into one"))
    return names, (owners.pop() if len(owners) == 1 else None), problems


def insert(text: str, prog: Program, pou_name: str | None) -> str:
    """The user's file with the helpers before its first POU, the converted declarations and
    statements in the program `pou_name` (the first PROGRAM if None): its declarations after
    its last VAR block, its statements first in its body."""
    clean = strip_comments(text)
    pous = [m for m in POU_RE.finditer(clean)
            if pou_name is None or m.group(1).upper() == pou_name.upper()]
    if not pous:
        raise Problem("OI-12", "--into", f"no PROGRAM {pou_name or ''} in the file".replace("  ", " "))
    pou = pous[0]
    body = pou.group(2)
    ends = [m.end() for m in re.finditer(r"\bEND_VAR\b", body, re.IGNORECASE)]
    at = pou.start(2) + (ends[-1] if ends else 0)
    first = re.search(r"\b(FUNCTION_BLOCK|FUNCTION|PROGRAM|TYPE)\b", clean, re.IGNORECASE)
    top = first.start() if first else 0
    return (text[:top] + prog.header() + HELPERS + "\n" + text[top:at] + "\n"
            + prog.var_blocks().rstrip("\n") + "\n" + prog.statements().rstrip("\n")
            + "\n  (* end of the converted part *)" + text[at:])
