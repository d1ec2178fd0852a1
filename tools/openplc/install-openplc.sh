#!/usr/bin/env bash
# install-openplc.sh [DIR] - clone OpenPLC v3 into DIR and run its own installer
# (`./install.sh linux`: Debian packages, its libmodbus fork in /usr/local, matiec, the runtime
# core and the web server's Python environment; several minutes, needs root or sudo).
# For users who want the real runtime under ./demo.sh and the e2e tests; ./demo.sh
# --install-openplc runs it. Nothing else in the project runs it.
#
# DIR: default $OPENPLC_HOME, else /opt/OpenPLC_v3. It must not exist, or be empty.
# OPENPLC_GIT_URL (default https://github.com/thiagoralves/OpenPLC_v3.git) and OPENPLC_GIT_REF
# (a branch, tag or commit; default: the repository's default branch) choose what is cloned.
# Exit: 0 installed, 1 the clone or the installer failed, 2 bad command line.
set -euo pipefail
die2() { echo "install-openplc.sh: $*" >&2; exit 2; }
case "${1:-}" in
    -h|--help) sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) die2 "unknown option '$1' (usage: install-openplc.sh [DIR])" ;;
esac
[ $# -le 1 ] || die2 "one directory at most (usage: install-openplc.sh [DIR])"
dir=${1:-${OPENPLC_HOME:-/opt/OpenPLC_v3}}
[ -n "$dir" ] || die2 "an empty directory name"
url=${OPENPLC_GIT_URL:-https://github.com/thiagoralves/OpenPLC_v3.git}
ref=${OPENPLC_GIT_REF:-}
if [ -e "$dir" ] && [ -n "$(ls -A "$dir" 2>/dev/null)" ]; then
    if [ -x "$dir/webserver/iec2c" ]; then
        echo "install-openplc.sh: OpenPLC v3 is already installed in $dir (nothing done)"
        exit 0
    fi
    die2 "$dir exists and is not empty: give another directory"
fi
command -v git >/dev/null || { echo "install-openplc.sh: needs git (apt-get install git)" >&2; exit 1; }
echo "cloning $url${ref:+ ($ref)} into $dir ..."
git clone -q "$url" "$dir" || { echo "install-openplc.sh: git clone $url failed" >&2; exit 1; }
if [ -n "$ref" ]; then
    git -C "$dir" -c advice.detachedHead=false checkout -q "$ref" ||
        { echo "install-openplc.sh: no $ref in $url" >&2; exit 1; }
fi
echo "running OpenPLC's installer: (cd $dir && ./install.sh linux) - several minutes ..."
if ! (cd "$dir" && ./install.sh linux); then   # it calls sudo itself where it needs root
    echo "install-openplc.sh: OpenPLC's install.sh failed (its output is above)" >&2
    exit 1
fi
echo "OpenPLC v3 installed in $dir."
[ "$dir" = /opt/OpenPLC_v3 ] || echo "Use it with: export OPENPLC_HOME=$dir"
