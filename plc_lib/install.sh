#!/bin/sh
# install.sh [--dist DIR] OPENPLC_PATH - add the mbfb blocks to an OpenPLC v3 installation.
#
# Afterwards every program OpenPLC compiles (web upload, compile_program.sh) can use the blocks;
# the files live in OpenPLC's library and core folders, so recompiling programs keeps them.
# What it changes, and nothing else:
#   adds   webserver/lib/mbfb.txt, webserver/lib/mbfb.manifest, webserver/core/mbfb*.{h,cpp}
#   edits  webserver/lib/standard_FB.txt and webserver/core/c_blocks.h: one marker-delimited block
# Idempotent: running it again changes nothing (or updates to the current sources).
# After a web-upload bundle (mkbundle.sh) it takes over the files the bundle wrote that still
# hold what it wrote (webserver/core/mbfb_bundle.sha256); any other existing mbfb* file that
# differs from ours stops it, with nothing changed.
# Without --dist it generates the files first (plc_lib/mkdist.sh) with that OpenPLC's own iec2c.
# Undo with plc_lib/uninstall.sh OPENPLC_PATH.
set -eu
prog=install.sh
here=$(cd "$(dirname "$0")" && pwd)
. "$here/common.sh"

dist=
if [ "${1:-}" = --dist ]; then dist=${2:?--dist needs a directory}; shift 2; fi
[ $# -eq 1 ] || die "usage: install.sh [--dist DIR] OPENPLC_PATH"
oplc=$(cd "$1" 2>/dev/null && pwd) || die "$1: no such directory"
check_openplc "$oplc"

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT INT TERM
if [ -z "$dist" ]; then
    IEC2C=$oplc/webserver/iec2c IEC_LIB=$oplc/webserver/lib "$here/mkdist.sh" "$tmp/dist" >/dev/null
    dist=$tmp/dist
fi
[ -f "$dist/MANIFEST" ] || die "$dist has no MANIFEST (make it with plc_lib/mkdist.sh)"

# Refuse to overwrite a file we did not install (not in our manifest) or a bundle did not write
# (bundle_written), unless it is identical.
old=$oplc/$MANIFEST
bundle_written "$oplc" > "$tmp/bundled"
while read -r f; do
    case $f in webserver/lib/mbfb*|webserver/core/mbfb*) ;; *) die "bad manifest entry $f" ;; esac
    if [ -e "$oplc/$f" ] && ! grep -qxF "$f" "$old" 2>/dev/null && ! grep -qxF "$f" "$tmp/bundled" &&
            ! cmp -s "$dist/$f" "$oplc/$f"; then
        die "$oplc/$f exists and was not installed by us: not overwriting it"
    fi
done < "$dist/MANIFEST"

changed=0
if [ -f "$oplc/$BUNDLE_SUMS" ]; then
    adopt_bundle "$oplc" "$tmp/bundled"
    changed=1
    say "took over the $(wc -l < "$tmp/bundled") files a web-upload bundle wrote; from now on upload your program itself, not its bundle (the blocks would be defined twice)"
fi
# Files a previous version installed that this one no longer has.
if [ -f "$old" ]; then
    while read -r f; do
        [ "$f" = "$MANIFEST" ] && continue
        if ! grep -qxF "$f" "$dist/MANIFEST"; then rm -f "$oplc/$f"; changed=1; fi
    done < "$old"
fi
while read -r f; do
    if ! cmp -s "$dist/$f" "$oplc/$f"; then
        cp "$dist/$f" "$oplc/$f.mbfb-new" && chmod 644 "$oplc/$f.mbfb-new" && mv -f "$oplc/$f.mbfb-new" "$oplc/$f"
        changed=1
    fi
done < "$dist/MANIFEST"
{ cat "$dist/MANIFEST"; echo "$MANIFEST"; } > "$tmp/manifest"
if [ ! -f "$old" ]; then cp "$tmp/manifest" "$old"; chmod 644 "$old"; changed=1
elif replace_if_changed "$old" "$tmp/manifest"; then changed=1; fi

# standard_FB.txt: include our library right after "{enable code generation}", so matiec
# generates our blocks' C into each program (see mkdist.sh for why not under "disable").
f=$oplc/webserver/lib/standard_FB.txt
strip_block "$f" | awk -v b="$MARK_BEGIN" -v e="$MARK_END" '
    { print }
    /^{enable code generation}/ && !done {
        print "(* " b " *)"; print "{#include \"mbfb.txt\" }"; print "(* " e " *)"; done = 1 }' > "$tmp/std"
if replace_if_changed "$f" "$tmp/std"; then changed=1; fi

# c_blocks.h (included at the end of iec_std_FB.h by every program): declare the shims for the
# blocks' pragmas.
f=$oplc/webserver/core/c_blocks.h
strip_block "$f" > "$tmp/cb"
eol=
if [ -s "$tmp/cb" ] && [ -n "$(tail -c1 "$tmp/cb")" ]; then eol=' [eol]'; echo >> "$tmp/cb"; fi
printf '/* %s%s */\n#include "mbfb.h"\n/* %s */\n' "$MARK_BEGIN" "$eol" "$MARK_END" >> "$tmp/cb"
if replace_if_changed "$f" "$tmp/cb"; then changed=1; fi

if [ $changed = 1 ]; then say "installed into $oplc"; else say "already installed in $oplc (nothing changed)"; fi
