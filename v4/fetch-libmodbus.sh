#!/bin/sh
# fetch-libmodbus.sh SOURCE TAG DEST LOG - libmodbus's source at a pinned release (git URL or a
# local git tree/mirror: LIBMODBUS_SOURCE_DIR). Debian's source package and PyPI/npm do not
# carry it in a form we can bundle; its release tarballs need autotools, the git tag does not.
set -eu
src=$1 tag=$2 dest=$3 log=$4
if [ -f "$dest/src/modbus.c" ] && [ "$(cat "$dest/.tag" 2>/dev/null)" = "$tag" ]; then exit 0; fi
rm -rf "$dest"
{
  git clone --quiet "$src" "$dest" &&
  git -C "$dest" -c advice.detachedHead=false checkout --quiet "$tag" &&
  echo "$tag" > "$dest/.tag"
} >"$log" 2>&1 || { echo "fetch-libmodbus.sh: libmodbus $tag from $src failed; see $log" >&2; exit 1; }
