#!/bin/sh
# mkbundle.sh [--dist DIR] PROGRAM.st > BUNDLE.st - one file for OpenPLC's web upload.
#
# For a PLC where you have no shell (so cannot run install.sh): upload BUNDLE.st as the program.
# It holds, in this order:
#   our ST blocks (dist's webserver/lib/mbfb.txt), as program POUs: matiec compiles them itself;
#   PROGRAM.st;
#   (*FILE:path line*) lines: OpenPLC's upload (webserver/openplc.py compile_program) writes each
#     into core/<path>: the shims (mbfb*.h, mbfb_*.cpp); core/c_blocks.h as install.sh writes it
#     into a fresh OpenPLC (OpenPLC's own line, then our marker block including mbfb.h); and
#     core/mbfb_bundle.sha256, the sha256 of each file as the upload writes it (sha256sum -c
#     format): install.sh and uninstall.sh take over the files that still match;
#   (*DBG:...*) lines, only if PROGRAM.st has none: an empty debugger table (debug_stub.cpp).
#     openplc.py strips FILE lines from the program only when DBG lines are present; without
#     them matiec would read C code as ST comments.
# Limits: it replaces core/c_blocks.h (other C blocks kept there are lost), and must not be used
# where install.sh already installed the library (the blocks would be defined twice).
# openplc.py strips each FILE line and drops empty ones; C survives that (it is whitespace-free).
set -eu
prog=mkbundle.sh
here=$(cd "$(dirname "$0")" && pwd)
. "$here/common.sh"

dist=${MBFB_DIST:-$here/../build/plc_lib/dist}
if [ "${1:-}" = --dist ]; then dist=${2:?--dist needs a directory}; shift 2; fi
[ $# -eq 1 ] || die "usage: mkbundle.sh [--dist DIR] PROGRAM.st > BUNDLE.st"
[ -f "$1" ] || die "$1: no such file"
[ -f "$dist/MANIFEST" ] || die "$dist: no generated library (build first: cmake --build, or plc_lib/mkdist.sh DIR)"
if grep -q '^(\*FILE:' "$1"; then die "$1 already carries (*FILE:*) lines"; fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT INT TERM

# flatten SOURCE: what OpenPLC's upload writes from SOURCE's FILE lines (each line trimmed,
# empty lines dropped, joined by newlines, no final newline).
flatten() {
    awk '{ sub(/^[ \t]+/, ""); sub(/[ \t\r]+$/, ""); if ($0 != "") { printf "%s%s", (n++ ? "\n" : ""), $0 } }' "$1"
}
# file_lines NAME SOURCE: SOURCE as FILE lines for core/NAME; records its sha256 as written.
file_lines() {
    flatten "$2" > "$tmp/flat"
    awk -v n="$1" '{ print "(*FILE:" n " " $0 "*)" }' "$tmp/flat"
    printf '%s  webserver/core/%s\n' "$(sha256sum < "$tmp/flat" | cut -c1-64)" "$1" >> "$tmp/sums"
}

cat "$dist/webserver/lib/mbfb.txt"
echo
echo "(* ---- user program: $(basename "$1") ---- *)"
cat "$1"
echo
grep '^webserver/core/' "$dist/MANIFEST" | while read -r f; do
    file_lines "$(basename "$f")" "$dist/$f"
done
printf '%s\n/* %s */\n#include "mbfb.h"\n/* %s */\n' "$OPENPLC_C_BLOCKS" "$MARK_BEGIN" "$MARK_END" > "$tmp/cb"
file_lines c_blocks.h "$tmp/cb"
awk '{ print "(*FILE:" n " " $0 "*)" }' n="${BUNDLE_SUMS#webserver/core/}" "$tmp/sums"
if ! grep -q '^(\*DBG:' "$1"; then
    sed 's/^/(*DBG:/; s/$/*)/' "$here/debug_stub.cpp"
fi
