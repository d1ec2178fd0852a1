#!/usr/bin/env bash
# Makes ./.venv with the pinned requirements (requirements.txt), again only when they or
# python3 change. The venv is kept in the tool cache (MBFB_TOOL_CACHE, default ~/.cache/mbfb)
# as venv-<hash of requirements.txt and python3's version> and ./.venv links to it: another
# clone with the same pins has it at once (a fresh clone spent 11 s in pip). A venv cannot
# move, so it is made where it is kept, under a lock. MBFB_TOOL_CACHE empty: ./.venv itself.
set -euo pipefail
cd "$(dirname "$0")/.."
want=$({ cat requirements.txt; python3 --version; } | sha256sum | cut -c1-16)
ready() { [ -x "$1/bin/python" ] && [ "$(cat "$1/.requirements.sha" 2>/dev/null)" = "$want" ]; }
make_venv() {
    rm -rf "$1"
    python3 -m venv "$1"
    "$1/bin/python" -m pip install -q --disable-pip-version-check -r requirements.txt
    echo "$want" > "$1/.requirements.sha"
}
cache=${MBFB_TOOL_CACHE-${XDG_CACHE_HOME:-$HOME/.cache}/mbfb}
if [ -z "$cache" ]; then
    [ ! -L .venv ] || rm .venv
    ready .venv || make_venv .venv
    exit 0
fi
kept=$cache/venv-$want
if ! ready "$kept"; then
    mkdir -p "$cache"
    exec 9>"$kept.lock"
    flock 9
    ready "$kept" || make_venv "$kept"
fi
if [ "$(readlink .venv 2>/dev/null)" != "$kept" ]; then
    rm -rf .venv
    ln -s "$kept" .venv
fi
