#!/bin/sh
# uninstall.sh OPENPLC_PATH - remove what plc_lib/install.sh added to an OpenPLC v3 installation.
# Removes the files listed in webserver/lib/mbfb.manifest and our marker blocks in
# standard_FB.txt and c_blocks.h, restoring those two files byte for byte. Idempotent.
# Also removes what a web-upload bundle (mkbundle.sh) wrote, where it still holds what the bundle
# wrote: c_blocks.h is then OpenPLC's shipped one again.
# Programs that use the blocks no longer compile afterwards.
set -eu
prog=uninstall.sh
here=$(cd "$(dirname "$0")" && pwd)
. "$here/common.sh"

[ $# -eq 1 ] || die "usage: uninstall.sh OPENPLC_PATH"
oplc=$(cd "$1" 2>/dev/null && pwd) || die "$1: no such directory"
check_openplc "$oplc"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT INT TERM

changed=0
if [ -f "$oplc/$BUNDLE_SUMS" ]; then
    bundle_written "$oplc" > "$tmp/bundled"
    adopt_bundle "$oplc" "$tmp/bundled"
    changed=1
fi
for f in webserver/lib/standard_FB.txt webserver/core/c_blocks.h; do
    strip_block "$oplc/$f" > "$tmp/x"
    if replace_if_changed "$oplc/$f" "$tmp/x"; then changed=1; fi
done
if [ -f "$oplc/$MANIFEST" ]; then
    while read -r f; do
        case $f in webserver/lib/mbfb*|webserver/core/mbfb*) ;; *) die "bad manifest entry $f" ;; esac
        if [ -e "$oplc/$f" ] && [ "$f" != "$MANIFEST" ]; then rm -f "$oplc/$f"; changed=1; fi
    done < "$oplc/$MANIFEST"
    rm -f "$oplc/$MANIFEST"; changed=1
fi
if [ $changed = 1 ]; then say "removed from $oplc"; else say "not installed in $oplc (nothing changed)"; fi
