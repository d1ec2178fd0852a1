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
- OUT/mbfb/library.properties (name, version, defines=).
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
