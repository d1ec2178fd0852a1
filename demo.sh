#!/usr/bin/env bash
# demo.sh - the example plant, live: the simulator with the heat-treat line's three instruments,
# the ST example (examples/heat_treat_st) running in a PLC, and its values (PV, SV, count,
# status, alarms) on screen until Ctrl-C. Stops everything it started; removes its temp files.
#
#   ./demo.sh [--runner | --openplc] [--build-dir DIR] [--time-scale F] [--seconds N]
#
# The PLC is the real OpenPLC v3 runtime when it is installed (OPENPLC_HOME, default
# /opt/OpenPLC_v3: a scratch copy, in a private network namespace), else the project's own
# runner (tools/runner/fb_host.cpp in program mode, built here with CMake in DIR, default build/)
# when matiec is found (MATIEC_HOME, iec2c on PATH, or OpenPLC's). --runner uses the runner even
# where OpenPLC is installed; --openplc insists on OpenPLC. Other options go to
# examples/heat_treat_st/live.py.
set -euo pipefail
cd "$(dirname "$0")"
mode=auto
build=build
args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --runner) mode=runner ;;
        --openplc) mode=openplc ;;
        --build-dir) [ $# -ge 2 ] || { echo "demo.sh: --build-dir needs a directory" >&2; exit 2; }
                     build=$2; shift ;;
        *) args+=("$1") ;;
    esac
    shift
done
scripts/deps.sh
scripts/venv.sh
export OPENPLC_HOME="${OPENPLC_HOME:-/opt/OpenPLC_v3}"

have_openplc() {
    [ -x "$OPENPLC_HOME/webserver/iec2c" ] && [ -x "$OPENPLC_HOME/webserver/core/glue_generator" ]
}
have_matiec() {
    { [ -n "${MATIEC_HOME:-}" ] && [ -x "$MATIEC_HOME/iec2c" ]; } || command -v iec2c >/dev/null ||
        [ -x "$OPENPLC_HOME/webserver/iec2c" ]
}

need() {  # need openplc|matiec|both: say what to install, and stop
    echo "demo.sh: no PLC toolchain found for this demo. Install:" >&2
    [ "$1" = matiec ] || cat >&2 <<MSG
  - OpenPLC v3 (runs the example in OpenPLC's runtime): clone thiagoralves/OpenPLC_v3, run its
    ./install.sh linux, and set OPENPLC_HOME to it (now: $OPENPLC_HOME). README, Prerequisites.
MSG
    [ "$1" = openplc ] || cat >&2 <<MSG
  - matiec, the IEC 61131-3 compiler (runs the example in this project's own runner): build it
    and set MATIEC_HOME to the directory holding iec2c and lib/ (or put iec2c on PATH).
MSG
    exit 1
}
if [ "$mode" = auto ]; then
    if have_openplc; then mode=openplc
    elif have_matiec; then mode=runner
    else need both
    fi
fi
if [ "$mode" = openplc ]; then
    have_openplc || need openplc
    exec tools/openplc/netns.sh .venv/bin/python examples/heat_treat_st/live.py --backend openplc \
        ${args[@]+"${args[@]}"}
fi

# The runner: build the example's program with the project's CMake (tools/runner/CMakeLists.txt).
have_matiec || need matiec
generator=()
[ -f "$build/CMakeCache.txt" ] || generator=(-G Ninja)
echo "building the runner in $build (cmake) ..."
if ! configured=$(cmake -S . -B "$build" ${generator[@]+"${generator[@]}"} 2>&1); then
    echo "$configured" >&2
    echo "demo.sh: cmake could not configure $build" >&2
    exit 1
fi
echo "$configured" | grep -E -- "-- (matiec iec2c|fb):" || true
if ! cmake --build "$build" --target heat_treat_st_runner; then
    echo "demo.sh: could not build the runner (heat_treat_st_runner): see the fb: line above" >&2
    exit 1
fi
exec .venv/bin/python examples/heat_treat_st/live.py --backend runner \
    --runner-exe "$build/tools/runner/heat_treat_st_runner" ${args[@]+"${args[@]}"}
