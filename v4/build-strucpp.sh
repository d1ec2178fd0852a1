#!/bin/sh
# build-strucpp.sh SOURCE COMMIT DEST LOG - STruC++ from source with npm, at a pinned commit.
# SOURCE: a git URL or a local STruC++ git tree/mirror (STRUCPP_SOURCE_DIR, for offline use).
# A build is the checkout, node_modules (npm ci from its package-lock.json) and dist/ (npm run
# build). It is kept in the tool cache, MBFB_TOOL_CACHE (default ${XDG_CACHE_HOME:-~/.cache}/mbfb;
# set it empty for none), as strucpp-COMMIT, and DEST is a link to it: another build tree (a
# fresh clone in CI) finds the same commit built. Without a cache DEST holds the build itself.
set -eu
src=$1 commit=$2 dest=$3 log=$4
built() { [ -f "$1/dist/node/cli.js" ] && [ "$(git -C "$1" rev-parse HEAD 2>/dev/null)" = "$commit" ]; }
build() {
  {
    git clone --quiet "$src" "$1" &&
    git -C "$1" -c advice.detachedHead=false checkout --quiet "$commit" &&
    (cd "$1" && npm ci --no-audit --no-fund --ignore-scripts && npm run build)
  } >"$log" 2>&1 || {
    echo "build-strucpp.sh: building STruC++ $commit from $src failed; see $log" >&2
    rm -rf "$1"
    exit 1
  }
}
built "$dest" && exit 0
rm -rf "$dest"
cache=${MBFB_TOOL_CACHE-${XDG_CACHE_HOME:-$HOME/.cache}/mbfb}
if [ -z "$cache" ] || ! mkdir -p "$cache" 2>/dev/null; then
  build "$dest"
  exit 0
fi
kept=$cache/strucpp-$commit
if ! built "$kept"; then
  # built beside it and renamed: a build tree that runs this at the same time sees either no
  # build or a whole one
  tmp=$(mktemp -d "$kept.XXXXXX")
  rmdir "$tmp"
  build "$tmp"
  rm -rf "$kept.old"
  [ ! -e "$kept" ] || built "$kept" || mv "$kept" "$kept.old"
  mv -T "$tmp" "$kept" 2>/dev/null || rm -rf "$tmp"   # another made it meanwhile: theirs
  rm -rf "$kept.old"
fi
ln -s "$kept" "$dest"
