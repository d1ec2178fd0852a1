#!/usr/bin/env python3
"""mkpackage.py - the v4 library folder next to the .stlib (v4/README.md, "Build").

  mkpackage.py --stlib mbfb.stlib --dir OUT/mbfb --version V --header mbfb_strucpp.hpp
               [--libmodbus LIBMODBUS_SRC_TREE] SHIM_FILES...

- names mbfb_strucpp.hpp in the .stlib manifest's "headers" (STruC++ emits an #include of each
  into the generated header; --compile-lib leaves the list empty);
- OUT/mbfb/src/: the shims' C sources and headers and mbfb_strucpp.hpp, i.e. what Runtime v4's
  scripts/Makefile.strucpp compiles from core/generated/libraries/<name>/src;
- with --libmodbus: libmodbus's src/*.c/*.h (RTU, TCP), its modbus-version.h made from the .in,
  and a config.h for Linux/glibc (what its configure finds there), so the program needs no
  system libmodbus;
- OUT/mbfb/library.properties (name, version, defines=);
- fixes the .stlib for a user's program (STruC++ fb7980f gaps G6..G8, v4/README.md): a FUNCTION's
  locals left out of its manifest parameters (G6), C++ default arguments for the trailing inputs
  that have an initial value (G7), and each enumerator also named unqualified in C++ (G8).
"""
import argparse
import json
import os
import re
import shutil
import sys

CONFIG_H = """/* config.h for libmodbus on Linux/glibc (written by modbus-fb v4/mkpackage.py in place of
   libmodbus's configure: the values its configure.ac finds on Debian/Raspberry Pi OS). */
#define HAVE_ARPA_INET_H 1
#define HAVE_BYTESWAP_H 1
#define HAVE_ERRNO_H 1
#define HAVE_FCNTL_H 1
#define HAVE_LIMITS_H 1
#define HAVE_LINUX_SERIAL_H 1
#define HAVE_NETDB_H 1
#define HAVE_NETINET_IN_H 1
#define HAVE_NETINET_TCP_H 1
#define HAVE_SYS_IOCTL_H 1
#define HAVE_SYS_PARAMS_H 1
#define HAVE_SYS_SOCKET_H 1
#define HAVE_SYS_TIME_H 1
#define HAVE_SYS_TYPES_H 1
#define HAVE_TERMIOS_H 1
#define HAVE_TIME_H 1
#define HAVE_UNISTD_H 1
#define HAVE_ACCEPT4 1
#define HAVE_GETADDRINFO 1
#define HAVE_GETTIMEOFDAY 1
#define HAVE_INET_PTON 1
#define HAVE_INET_NTOP 1
#define HAVE_SELECT 1
#define HAVE_SOCKET 1
#define HAVE_STRERROR 1
#define HAVE_DECL___CYGWIN__ 0
#define HAVE_DECL_TIOCSRS485 1
#define HAVE_DECL_TIOCM_RTS 1
#ifndef _GNU_SOURCE
#define _GNU_SOURCE 1
#endif
"""


def die(msg):
    print(f"mkpackage.py: {msg}", file=sys.stderr)
    sys.exit(2)


def cpp_default(v, enum_of):
    """An ST initial value as a C++ default argument, or None when it has no plain form."""
    if re.fullmatch(r"-?\d+(\.\d+)?", v):
        return v
    if v.upper() in ("TRUE", "FALSE"):
        return v.lower()
    if v.upper() in enum_of:
        return f"{enum_of[v.upper()]}::{v.upper()}"
    return None


def fix_stlib(arch):
    """The .stlib as a user's program needs it (STruC++ fb7980f, v4/README.md G6..G8).
    G6: the manifest lists a FUNCTION's VAR locals as inputs (required ones, without an initial
    value): a call then asks for them. Only the parameters of its C++ signature stay.
    G7: a program's call of a library FUNCTION that leaves out an input with an initial value
    passes the remaining arguments as written (no default filled in): the C++ declaration gets
    default arguments for its trailing inputs that have one.
    G8: an enumerator in a program's initialiser is emitted unqualified (MB_ORDER_CDAB, not
    MB_ORDER::MB_ORDER_CDAB): each enumerator is also declared as a constexpr of its type."""
    chunks = {c["name"]: c for c in arch["chunks"]}
    enum_of = {}
    for c in arch["chunks"]:
        m = re.match(r"enum class (\w+) \{([^}]*)\};", c["header"]) if c["kind"] == "type" else None
        if m:
            names = [n.strip() for n in m.group(2).split(",") if n.strip()]
            enum_of.update({n.upper(): m.group(1) for n in names})
            c["header"] += "".join(f"constexpr {m.group(1)} {n} = {m.group(1)}::{n};\n" for n in names)
    for fn in arch["manifest"]["functions"]:
        c = chunks.get(fn["name"])
        m = re.fullmatch(r"(.*?\w+\()(.*)\);\s*", c["header"], re.S) if c else None
        if not m:
            die(f"{fn['name']}: no C++ declaration in the .stlib")
        sig = [p.strip() for p in m.group(2).split(",") if p.strip()]
        cnames = [p.split()[-1].lstrip("&*") for p in sig]
        fn["parameters"] = [p for p in fn["parameters"] if p["name"].upper() in cnames]
        by = {p["name"].upper(): p for p in fn["parameters"]}
        for i in range(len(sig) - 1, -1, -1):
            p = by.get(cnames[i])
            d = cpp_default(p["initialValue"], enum_of) if p and p["direction"] == "input" \
                and "initialValue" in p and "=" not in sig[i] else None
            if d is None:
                break
            sig[i] += f" = {d}"
        c["header"] = m.group(1) + ", ".join(sig) + ");"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--stlib", required=True)
    ap.add_argument("--dir", required=True)
    ap.add_argument("--version", required=True)
    ap.add_argument("--header", required=True)
    ap.add_argument("--libmodbus")
    ap.add_argument("shims", nargs="+")
    a = ap.parse_args()
    try:
        with open(a.stlib, encoding="utf-8") as f:
            arch = json.load(f)
    except (OSError, ValueError) as e:
        die(f"cannot read {a.stlib}: {e}")
    arch["manifest"]["headers"] = [os.path.basename(a.header)]
    fix_stlib(arch)
    with open(a.stlib, "w", encoding="utf-8") as f:
        json.dump(arch, f)
    src = os.path.join(a.dir, "src")
    os.makedirs(src, exist_ok=True)
    for p in a.shims + [a.header]:
        shutil.copy(p, src)
    if a.libmodbus:
        lm = os.path.join(a.libmodbus, "src")
        names = [n for n in os.listdir(lm) if re.fullmatch(r"modbus[\w-]*\.[ch]", n)]
        if "modbus.c" not in names:
            die(f"{a.libmodbus}: not a libmodbus source tree (no src/modbus.c)")
        for n in names:
            shutil.copy(os.path.join(lm, n), src)
        ac = open(os.path.join(a.libmodbus, "configure.ac"), encoding="utf-8").read()
        ver = {k: re.search(r"m4_define\(\[libmodbus_version_%s\], \[(\d+)\]\)" % k, ac).group(1)
               for k in ("major", "minor", "micro")}
        vin = open(os.path.join(lm, "modbus-version.h.in"), encoding="utf-8").read()
        for k, v in ver.items():
            vin = vin.replace(f"@LIBMODBUS_VERSION_{k.upper()}@", v)
        vin = vin.replace("@LIBMODBUS_VERSION@", ".".join(ver.values()))
        open(os.path.join(src, "modbus-version.h"), "w").write(vin)
        open(os.path.join(src, "config.h"), "w").write(CONFIG_H)
    with open(os.path.join(a.dir, "library.properties"), "w") as f:
        f.write(f"name=mbfb\nversion={a.version}\n"
                "sentence=Modbus instrument function blocks (modbus-fb) with their C shims\n"
                f"defines=_GNU_SOURCE{',HAVE_CONFIG_H' if a.libmodbus else ''}\n")


if __name__ == "__main__":
    main()
