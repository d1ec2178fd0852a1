#!/bin/sh
# build-strucpp.sh SOURCE COMMIT DEST LOG - STruC++ from source with npm, at a pinned commit.
# SOURCE: a git URL or a local STruC++ git tree/mirror (STRUCPP_SOURCE_DIR, for offline use).
# DEST gets the checkout, node_modules (npm ci from its package-lock.json) and dist/ (npm run build).
set -eu
src=$1 commit=$2 dest=$3 log=$4
if [ -f "$dest/dist/node/cli.js" ] && [ "$(git -C "$dest" rev-parse HEAD 2>/dev/null)" = "$commit" ]; then
  exit 0
fi
rm -rf "$dest"
{
  git clone --quiet "$src" "$dest" &&
  git -C "$dest" -c advice.detachedHead=false checkout --quiet "$commit" &&
  (cd "$dest" && npm ci --no-audit --no-fund --ignore-scripts && npm run build)
} >"$log" 2>&1 || {
  echo "build-strucpp.sh: building STruC++ $commit from $src failed; see $log" >&2
  exit 1
}
