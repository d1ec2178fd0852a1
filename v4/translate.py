#!/usr/bin/env python3
"""translate.py - the blocks' ST for STruC++ (OpenPLC v4), derived from st_src/*.st.

  translate.py --mode external|strip [--workarounds] -o OUT.st st_src/*.st

--mode external  every matiec pragma {{ ... }} becomes an STruC++ {external ... } block that
                 does the same thing on C mirrors of the variables it names (see
                 mbfb_strucpp.hpp): GetFbVar(X) -> the mirror of X, SetFbVar(X, v) -> the
                 mirror of X assigned, &data__->X.value(.F) -> the mirror's address,
                 data__->X.value(.F) -> the mirror (in a FUNCTION: X itself -> the mirror),
                 __CURRENT_TIME -> mbfb_v4::current_time(), __time_cmp(a, b) (matiec's
                 compare of two TIMEs) -> mbfb_v4::time_cmp(a, b). Mirrors are copied in before and
                 back after the pragma's statements. A pragma using any other form is refused
                 (one line naming file:line and the form, exit 2).
--mode strip     pragmas removed (the blocks compile but never reach the bus): shows what
                 STruC++ accepts of the plain ST.
--workarounds    rewrite the ST constructs STruC++ does not accept today (v4/README.md, "gaps"):
                 G1 a named initialiser in a declaration `x : T := (A := v);` (FB instance
                 or structure) -> plain declaration, `x.A := v;` once, in the first scan
                 (a CONSTANT one becomes a variable: a constant cannot be assigned);
                 G2 a FUNCTION's VAR_INPUT without an initial value -> given its type's
                 default (IEC: an input not given in a call takes its initial value);
                 G4 a '(*' inside a comment (matiec ends a comment at the first '*)', STruC++
                 nests them) -> '( *';
                 G5 TIME_TO_LREAL(t) * 1000.0 (ms under matiec, whose TIME_TO_LREAL gives
                 seconds; STruC++ gives ms) -> TIME_TO_LREAL(t) / TIME_TO_LREAL(T#1ms).
Every workaround applied is printed on stderr (one line each).
"""
import argparse
import re
import sys

PRAGMA = re.compile(r"\{\{(.*?)\}\}", re.S)
ALLOWED = re.compile(r"GetFbVar|SetFbVar|data__")


def die(msg):
    print(f"translate.py: {msg}", file=sys.stderr)
    sys.exit(2)


def st_spans(s):
    """Split ST source into (kind, start, end) spans, kind 'pragma' ({{ }}), 'string', 'comment'
    or 'code' (one character). matiec's rule: a comment ends at the first *) (no nesting), and
    {{ }} pragmas and strings hold none."""
    i, n = 0, len(s)
    while i < n:
        if s.startswith("{{", i):
            j = s.find("}}", i)
            j, kind = (n if j < 0 else j + 2), "pragma"
        elif s[i] == "'":
            j = i + 1
            while j < n and s[j] != "'":
                j += 2 if s[j] == "$" else 1
            j, kind = j + 1, "string"
        elif s.startswith("(*", i):
            j = s.find("*)", i + 2)
            j, kind = (n if j < 0 else j + 2), "comment"
        else:
            j, kind = i + 1, "code"
        yield kind, i, min(j, n)
        i = j


def strip_comments(s):
    """Blank ST comments, keeping offsets (so line numbers stay right)."""
    out = list(s)
    for kind, i, j in st_spans(s):
        if kind == "comment":
            for k in range(i, j):
                if out[k] != "\n":
                    out[k] = " "
    return "".join(out)


def unnest_comments(src, fname, notes):
    """G4: STruC++ nests comments (IEC 61131-3 ed. 3), matiec does not: a '(*' inside a
    comment would open a second level and swallow the code after the first '*)'."""
    out, count = [], 0
    for kind, i, j in st_spans(src):
        if kind == "comment":
            inner = src[i + 2:j - 2]
            count += inner.count("(*")
            out.append("(*" + inner.replace("(*", "( *") + src[j - 2:j])
        else:
            out.append(src[i:j])
    if count:
        notes.append(f"G4 {fname}: {count} '(*' inside a comment (matiec does not nest) -> '( *'")
    return "".join(out)


def struct_types(text):
    """ST structure types: name -> [(field name, type name)] (upper case), in declaration
    order (the type name: its first word, without an initial value)."""
    types = {}
    for m in re.finditer(r"(\w+)\s*:\s*STRUCT\b(.*?)END_STRUCT", text, re.S | re.I):
        fields = []
        for fm in re.finditer(r"(\w+)\s*:\s*(\w+)[^;]*;", strip_comments(m.group(2))):
            fields.append((fm.group(1).upper(), fm.group(2).upper()))
        types[m.group(1).upper()] = fields
    return types


def mirror(expr, cexpr, t, structs):
    """The C mirror of `expr` of type t, at `cexpr`: its C type (a structure's is a structure
    of its fields' mirrors, nested for a field that is itself a structure), copy-in, copy-out."""
    if t not in structs:
        return (f"::mbfb_v4::ctype_t<decltype({expr})>", [f"::mbfb_v4::to_c({expr}, {cexpr});"],
                [f"::mbfb_v4::from_c({cexpr}, {expr});"])
    members, into, back = [], [], []
    for f, ft in structs[t]:
        ctype, i, b = mirror(f"{expr}.{f}", f"{cexpr}.{f}", ft, structs)
        members.append(f"{ctype} {f};")
        into += i
        back += b
    return "struct { " + " ".join(members) + " }", into, back


def fb_var_types(body):
    """Variables of one POU: NAME -> declared type text (upper case)."""
    out = {}
    for blk in re.finditer(r"\bVAR(?:_INPUT|_OUTPUT|_IN_OUT|_TEMP)?\b(.*?)\bEND_VAR\b", body, re.S | re.I):
        for d in re.finditer(r"([\w\s,]+?)\s*:\s*([^;:=]+?)\s*(?::=[^;]*)?;", blk.group(1)):
            for n in d.group(1).split(","):
                n = n.strip()
                if n and n.upper() not in ("CONSTANT", "RETAIN"):
                    out[n.split()[-1].upper()] = d.group(2).strip().upper()
    return out


def split_args(s, start):
    """s[start] == '(' -> (list of top-level args, index after ')')."""
    depth, i, args, cur = 0, start, [], []
    while i < len(s):
        c = s[i]
        if c == "(":
            depth += 1
            if depth > 1:
                cur.append(c)
        elif c == ")":
            depth -= 1
            if depth == 0:
                args.append("".join(cur))
                return args, i + 1
            cur.append(c)
        elif c == "," and depth == 1:
            args.append("".join(cur))
            cur = []
        else:
            cur.append(c)
        i += 1
    raise ValueError("unbalanced parentheses")


def translate_pragma(code, where, vartypes, structs, function=False):
    names = []  # variables named, in order of first use

    def use(n):
        n = n.upper()
        if n not in vartypes:
            die(f"{where}: pragma names {n}, not a variable of its block")
        if n not in names:
            names.append(n)
        return f"{n}__c"

    out, i = [], 0
    while i < len(code):
        m = re.compile(r"GetFbVar\s*\(|SetFbVar\s*\(|(&\s*)?data__->(\w+)\.value((?:\.\w+)*)"
                       + (r"|\b(" + "|".join(sorted(vartypes, key=len, reverse=True)) + r")\b"
                          if function and vartypes else "")).search(code, i)
        if not m:
            out.append(code[i:])
            break
        out.append(code[i:m.start()])
        tok = m.group(0)
        if "data__" in tok:
            out.append(("&" if m.group(1) else "") + use(m.group(2)) + m.group(3))
            i = m.end()
            continue
        if function and m.lastindex == 4 and m.group(4):
            out.append(use(m.group(4)))  # a FUNCTION's pragma names its variables directly
            i = m.end()
            continue
        args, j = split_args(code, m.end() - 1)
        if tok.startswith("GetFbVar"):
            if len(args) != 1 or not re.fullmatch(r"\s*\w+\s*", args[0]):
                die(f"{where}: GetFbVar({','.join(args)}) is not GetFbVar(NAME)")
            out.append(use(args[0].strip()))
        else:
            if len(args) != 2 or not re.fullmatch(r"\s*\w+\s*", args[0]):
                die(f"{where}: SetFbVar({','.join(args)}) is not SetFbVar(NAME, value)")
            inner = translate_pragma(args[1], where, vartypes, structs, function)[0]
            out.append(f"({use(args[0].strip())} = ({inner}))")
            for n in translate_pragma(args[1], where, vartypes, structs, function)[1]:
                if n not in names:
                    names.append(n)
        i = j
    body = "".join(out).replace("__CURRENT_TIME", "::mbfb_v4::current_time()")
    body = body.replace("__time_cmp", "::mbfb_v4::time_cmp")
    if "data__" in body or "GetFbVar" in body or "SetFbVar" in body:
        die(f"{where}: a form other than GetFbVar(X), SetFbVar(X, v), &data__->X.value")
    return body, names


def mirror_code(names, vartypes, structs):
    """Declarations + copy-in, and copy-out, of the C mirrors of `names`."""
    decl, back = [], []
    for n in names:
        t = vartypes[n]
        if t in structs and n in (f for f, _ in structs[t]):
            die(f"{n} : {t} names one of its own fields (the C mirror's member would hide it)")
        ctype, into, out = mirror(n, f"{n}__c", t, structs)
        decl.append(f"{ctype} {n}__c;")
        if t in structs:   # zeroed first: a mirror's padding is compared too (mbfb_st.h, MBFB_SETTINGS_SAME's memcmp of Line)
            decl.append(f"std::memset(&{n}__c, 0, sizeof {n}__c);")
        decl += into
        back += out
    return decl, back


def pou_spans(text):
    """(start, end, body) of every FUNCTION_BLOCK / FUNCTION / PROGRAM."""
    for m in re.finditer(r"\b(FUNCTION_BLOCK|FUNCTION|PROGRAM)\b(.*?)\bEND_\1\b", text, re.S):
        yield m.start(), m.end(), m.group(0)


def to_external(src, clean, fname, structs):
    out, last = [], 0
    for start, end, pou in pou_spans(clean):
        vartypes = fb_var_types(clean[start:end])
        function = pou.startswith("FUNCTION") and not pou.startswith("FUNCTION_BLOCK")
        for m in PRAGMA.finditer(src, start, end):
            line = src.count("\n", 0, m.start()) + 1
            code, names = translate_pragma(m.group(1), f"{fname}:{line}", vartypes, structs, function)
            decl, back = mirror_code(names, vartypes, structs)
            nl = "\n" if "\n" in m.group(1) else " "
            td = "typedef ::mbfb_v4::mstring STRING; " if re.search(r"\bSTRING\b", code) else ""
            if re.search(r"\((?:BOOL|S?U?[SDL]?INT|U?INT|BYTE|[DL]?WORD|L?REAL)\)", code):
                td += "using namespace ::mbfb_v4::matiec_types; "
            new = ("{external { " + td + " ".join(decl) + nl
                   + code.strip("\n") + nl + " ".join(back) + " } }")
            out.append(src[last:m.start()])
            out.append(new)
            last = m.end()
    out.append(src[last:])
    res = "".join(out)
    if "{{" in strip_comments(res):
        die(f"{fname}: a pragma outside a POU")
    return res


TYPE_DEFAULT = {"BOOL": "FALSE", "STRING": "''", "TIME": "T#0s", "REAL": "0.0", "LREAL": "0.0"}


def workarounds(src, fname, enums, notes):
    clean = strip_comments(src)
    # G1: named initialisers in declarations (FB instance or structure): `x : T := (A := v);`
    pat = re.compile(r"(\w+)\s*:\s*(\w+)\s*:=\s*\(((?:\s*\w+\s*:=\s*[^,();]+,?)+)\)\s*;")
    # A CONSTANT one (a recipe pasted from `mbcommission backup --st`) cannot be assigned: it
    # leaves its CONSTANT section for the POU's added VAR section (a variable, assigned once).
    sections = list(re.finditer(r"\bVAR(?:_\w+)?\b(\s+CONSTANT\b)?", clean))
    edits = []
    for m in pat.finditer(clean):
        params = [tuple(x.split(":=", 1)) for x in m.group(3).split(",") if x.strip()]
        head = [x for x in sections if x.start() < m.start()]
        const = bool(head and head[-1].group(1))
        edits.append((m.start(), m.end(), "" if const else f"{m.group(1)} : {m.group(2)};",
                      m.group(1), params, f" {m.group(1)} : {m.group(2)};" if const else ""))
        notes.append(f"G1 {fname}:{clean.count(chr(10), 0, m.start()) + 1}: "
                     f"{m.group(1)} : {m.group(2)} := (...) -> assigned once, in the first scan"
                     + (" (a variable: a CONSTANT cannot be assigned)" if const else ""))
    # group by POU: one flag and one block of first-scan assignments per POU
    by_pou = {}
    for e in edits:
        pou_end = re.compile(r"\bEND_FUNCTION_BLOCK\b|\bEND_PROGRAM\b").search(clean, e[1])
        if not pou_end:
            die(f"{fname}: a named initialiser outside a FUNCTION_BLOCK or PROGRAM")
        by_pou.setdefault(pou_end.start(), []).append(e)
    for pe in sorted(by_pou, reverse=True):
        es = by_pou[pe]
        last_end_var = [x.end() for x in re.finditer(r"\bEND_VAR\b", clean[:pe])][-1]
        assigns = "".join(f"    {inst}.{p.strip()} := {v.strip()};\n"
                          for _, _, _, inst, params, _ in es for p, v in params)
        moved = "".join(e[5] for e in es)
        block = (f"\n  VAR mbfb_v4_init : BOOL;{moved} END_VAR\n"
                 "  IF NOT mbfb_v4_init THEN\n    mbfb_v4_init := TRUE;\n" + assigns + "  END_IF;\n")
        src = src[:last_end_var] + block + src[last_end_var:]
        for s_, e_, rep, _, _, _ in sorted(es, reverse=True):
            src = src[:s_] + rep + src[e_:]
    clean = strip_comments(src)
    # G5: TIME_TO_LREAL gives seconds in matiec, milliseconds in STruC++ (CODESYS): a count
    # of milliseconds written TIME_TO_LREAL(t) * 1000.0 becomes a ratio both agree on
    def g5(m):
        notes.append(f"G5 {fname}:{src.count(chr(10), 0, m.start()) + 1}: TIME_TO_LREAL({m.group(1)}) * 1000.0"
                     f" -> TIME_TO_LREAL({m.group(1)}) / TIME_TO_LREAL(T#1ms)")
        return f"(TIME_TO_LREAL({m.group(1)}) / TIME_TO_LREAL(T#1ms))"
    src = re.sub(r"TIME_TO_LREAL\((\w+)\)\s*\*\s*1000\.0", g5, src)
    # G2: FUNCTION inputs without initial values
    def fix_fn(m):
        head, blk = m.group(1), m.group(2)

        def fix_decl(d):
            name, typ = d.group(1), d.group(2).strip()
            u = typ.upper()
            if u in TYPE_DEFAULT:
                val = TYPE_DEFAULT[u]
            elif u in enums:
                val = enums[u]
            elif re.fullmatch(r"S?U?[SDL]?INT|INT|U?INT|BYTE|[DL]?WORD", u):
                val = "0"
            else:
                return d.group(0)
            notes.append(f"G2 {fname}: FUNCTION {head.split()[1]} input {name} : {typ} -> := {val}")
            return f"{name} : {typ} := {val};"
        return head + re.sub(r"(\w+)\s*:\s*(\w+)\s*;", fix_decl, blk)
    src = re.sub(r"(FUNCTION\s+\w+\s*:\s*\w+\s*VAR_INPUT)(.*?END_VAR)", fix_fn, src, flags=re.S)
    return src


def main():
    ap = argparse.ArgumentParser(description="st_src for STruC++")
    ap.add_argument("--mode", choices=("external", "strip"), required=True)
    ap.add_argument("--workarounds", action="store_true")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("sources", nargs="+")
    a = ap.parse_args()
    texts = []
    for f in a.sources:
        try:
            texts.append((f, open(f, encoding="utf-8").read()))
        except OSError as e:
            die(f"cannot read {f}: {e.strerror}")
    alltext = strip_comments("\n".join(t for _, t in texts))
    structs = struct_types(alltext)
    enums = {m.group(1).upper(): m.group(2).split(",")[0].strip()
             for m in re.finditer(r"(\w+)\s*:\s*\(([\w\s,]+)\)\s*;", alltext)}
    notes, out = [], []
    for f, src in texts:
        name = f.rsplit("/", 1)[-1]
        if a.workarounds:
            src = unnest_comments(src, name, notes)
            src = workarounds(src, name, enums, notes)
        if a.mode == "strip":
            src = PRAGMA.sub("", src)
        else:
            src = to_external(src, strip_comments(src), name, structs)
        out.append(f"(* ---- {name} ---- *)\n{src}\n")
    with open(a.output, "w", encoding="utf-8") as fh:
        fh.write("".join(out))
    for n in notes:
        print(f"translate.py: workaround {n}", file=sys.stderr)


if __name__ == "__main__":
    main()
