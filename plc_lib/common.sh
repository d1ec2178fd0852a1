# common.sh - shared by install.sh, uninstall.sh and mkbundle.sh (sourced, not run).
#
# Our only edits to files OpenPLC owns are marker-delimited blocks:
#   webserver/lib/standard_FB.txt  a block after "{enable code generation}" including mbfb.txt
#   webserver/core/c_blocks.h      a block at the end including mbfb.h
# Every other file we add is listed in webserver/lib/mbfb.manifest, all named mbfb*.

die() { echo "$prog: $*" >&2; exit 1; }
say() { echo "$prog: $*"; }

MARK_BEGIN='mbfb BEGIN: added by modbus-fb plc_lib/install.sh, removed by plc_lib/uninstall.sh'
MARK_END='mbfb END'
MANIFEST=webserver/lib/mbfb.manifest
# What a web-upload bundle (mkbundle.sh) wrote: "SHA256  PATH" per file, as sha256sum writes it.
BUNDLE_SUMS=webserver/core/mbfb_bundle.sha256
# OpenPLC v3's core/c_blocks.h as it ships (one line). A bundle replaces the whole file, so it
# writes this line back above our marker block: install.sh and uninstall.sh then give back the
# file OpenPLC shipped.
OPENPLC_C_BLOCKS='// Empty file'

# check_openplc DIR: DIR looks like an OpenPLC v3 installation we know how to extend.
check_openplc() {
    [ -d "$1" ] || die "$1: no such directory"
    for f in webserver/lib/standard_FB.txt webserver/core/c_blocks.h webserver/core/lib/iec_std_FB.h \
             webserver/scripts/compile_program.sh; do
        [ -f "$1/$f" ] || die "$1 is not an OpenPLC v3 installation (missing $f)"
    done
    grep -q '^{enable code generation}' "$1/webserver/lib/standard_FB.txt" ||
        die "$1/webserver/lib/standard_FB.txt has no '{enable code generation}' line: unknown layout"
    grep -q 'c_blocks.h' "$1/webserver/core/lib/iec_std_FB.h" ||
        die "$1/webserver/core/lib/iec_std_FB.h does not include c_blocks.h: unknown layout"
}

# strip_block FILE: print FILE without our marker block, byte for byte as it was before the
# block went in: if the file had no final newline (or the block records that install added it:
# "[eol]"), the output has none either.
strip_block() {
    if ! grep -qF "$MARK_BEGIN" "$1"; then cat "$1"; return; fi
    if grep -qF "$MARK_BEGIN [eol]" "$1" || [ -n "$(tail -c1 "$1")" ]; then
        join='NR > 1 { printf "\n" } { printf "%s", $0 }'
    else
        join='{ print }'
    fi
    awk -v b="$MARK_BEGIN" -v e="$MARK_END" '
        index($0, b) { skip = 1 } !skip { print } skip && index($0, e) { skip = 0 }' "$1" | awk "$join"
}

# replace_if_changed FILE NEW: move NEW over FILE (keeping FILE's mode) only if they differ.
replace_if_changed() {
    if cmp -s "$1" "$2"; then rm -f "$2"; return 1; fi
    cat "$2" > "$1" && rm -f "$2"
    return 0
}

# bundle_written DIR: print the files a web-upload bundle wrote into the OpenPLC at DIR that
# still hold what it wrote (their sha256 in DIR/$BUNDLE_SUMS); nothing without that file. Refuses
# a BUNDLE_SUMS that is not in the bundle's format (a foreign file).
bundle_written() {
    [ -f "$1/$BUNDLE_SUMS" ] || return 0
    while IFS= read -r line || [ -n "$line" ]; do
        sum=${line%%  *}; f=${line#*  }
        case $sum in *[!0-9a-f]*) sum= ;; esac
        case ${f#webserver/core/} in "$f"|*/*) f= ;; mbfb*|c_blocks.h) ;; *) f= ;; esac
        [ ${#sum} -eq 64 ] && [ -n "$f" ] ||
            die "$1/$BUNDLE_SUMS was not written by a bundle (line '$line'): not taking it over"
        if [ -f "$1/$f" ] && [ "$(sha256sum < "$1/$f" | cut -c1-64)" = "$sum" ]; then echo "$f"; fi
    done < "$1/$BUNDLE_SUMS"
}

# adopt_bundle DIR LIST: make the files in LIST (bundle_written's) install.sh's own: remove the
# shims (install.sh writes its own), give c_blocks.h the final newline that FILE lines cannot
# write (it is then as install.sh writes it), and remove $BUNDLE_SUMS.
adopt_bundle() {
    while read -r f; do
        case $f in
            webserver/core/c_blocks.h) [ -z "$(tail -c1 "$1/$f")" ] || echo >> "$1/$f" ;;
            *) rm -f "$1/$f" ;;
        esac
    done < "$2"
    rm -f "$1/$BUNDLE_SUMS"
}
