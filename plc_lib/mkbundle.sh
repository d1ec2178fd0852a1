#!/bin/sh
# mkbundle.sh [--dist DIR] PROGRAM.st > BUNDLE.st - one file for OpenPLC's web upload.
#
# For a PLC where you have no shell (so cannot run install.sh): upload BUNDLE.st as the program.
# It holds, in this order:
#   our ST blocks (dist's webserver/lib/mbfb.txt), as program POUs: matiec compiles them itself;
#   PROGRAM.st;
#   (*FILE:path line*) lines: OpenPLC's upload (webserver/openplc.py compile_program) writes each
#     into core/<path>: the shims (mbfb*.h, mbfb_*.cpp) and core/c_blocks.h = #include "mbfb_st.h";
#   (*DBG:...*) lines, only if PROGRAM.st has none: an empty debugger table (debug_stub.cpp).
#     openplc.py strips FILE lines from the program only when DBG lines are present; without
#     them matiec would read C code as ST comments.
# Limits: it replaces core/c_blocks.h (other C blocks kept there are lost), and must not be used
# where install.sh already installed the library (the blocks would be defined twice).
# openplc.py strips each FILE line and drops empty ones; C survives that (it is whitespace-free).
set -eu
prog=mkbundle.sh
here=$(cd "$(dirname "$0")" && pwd)
die() { echo "$prog: $*" >&2; exit 1; }

dist=${MBFB_DIST:-$here/../build/plc_lib/dist}
if [ "${1:-}" = --dist ]; then dist=${2:?--dist needs a directory}; shift 2; fi
[ $# -eq 1 ] || die "usage: mkbundle.sh [--dist DIR] PROGRAM.st > BUNDLE.st"
[ -f "$1" ] || die "$1: no such file"
[ -f "$dist/MANIFEST" ] || die "$dist: no generated library (build first: cmake --build, or plc_lib/mkdist.sh DIR)"
if grep -q '^(\*FILE:' "$1"; then die "$1 already carries (*FILE:*) lines"; fi

file_lines() { # file_lines NAME SOURCE: SOURCE as FILE lines for core/NAME
    awk -v n="$1" '{ sub(/^[ \t]+/, ""); sub(/[ \t\r]+$/, ""); if ($0 != "") print "(*FILE:" n " " $0 "*)" }' "$2"
}

cat "$dist/webserver/lib/mbfb.txt"
echo
echo "(* ---- user program: $(basename "$1") ---- *)"
cat "$1"
echo
grep '^webserver/core/' "$dist/MANIFEST" | while read -r f; do
    file_lines "$(basename "$f")" "$dist/$f"
done
echo '#include "mbfb_st.h"' | file_lines c_blocks.h -
if ! grep -q '^(\*DBG:' "$1"; then
    sed 's/^/(*DBG:/; s/$/*)/' "$here/debug_stub.cpp"
fi
