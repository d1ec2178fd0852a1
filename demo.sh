#!/usr/bin/env bash
# demo.sh - the example plant, live: the simulator with the heat-treat line's three instruments,
# the ST example (examples/heat_treat_st) running in a PLC, and its values on screen until
# Ctrl-C. Stops everything it started; removes its temp files. ./demo.sh --help for the options.
set -euo pipefail
cd "$(dirname "$0")"

usage() {
    cat <<'EOF'
usage: ./demo.sh [--runner | --openplc] [--build-dir DIR] [--time-scale F] [--seconds N]
       ./demo.sh --install-openplc [DIR]

Runs the heat-treat example (examples/heat_treat_st) against the device simulator and shows
its live values (PV, SV, part count, status, alarms, a trend) until Ctrl-C.

The PLC, unless chosen:
  - OpenPLC v3's runtime where it is installed (OPENPLC_HOME, default /opt/OpenPLC_v3): a
    scratch copy compiles the program with OpenPLC's own scripts and runs it in a private
    network namespace (needs root);
  - else the project's own runner (tools/runner), built here with CMake. Its compiler, matiec,
    is OpenPLC's, MATIEC_HOME's or iec2c on PATH; where there is none, it is built from source
    into the build tree once: from MATIEC_SOURCE_DIR (a local matiec source tree), or fetched
    from github.com/beremiz/matiec at a pinned commit (needs network; MATIEC_GIT_URL,
    MATIEC_GIT_COMMIT override it).

options:
  --runner            use the project's own runner even where OpenPLC v3 is installed
  --openplc           use OpenPLC v3's runtime (fails if it is not installed)
  --build-dir DIR     CMake build tree for the runner (default: build)
  --time-scale F      simulated plant seconds per real second, F > 0 (default 20)
  --seconds N         stop after N seconds (default 0: run until Ctrl-C)
  --install-openplc [DIR]
                      clone OpenPLC v3 into DIR (default: $OPENPLC_HOME or /opt/OpenPLC_v3)
                      and run its own installer (tools/openplc/install-openplc.sh); only this
  -h, --help          this text
Exit status: 0 stopped, 1 could not start, 2 bad command line.
EOF
}
die() {  # a command-line error: one line, exit 2
    echo "demo.sh: $* (./demo.sh --help lists the options)" >&2
    exit 2
}
is_number() { [[ $1 =~ ^[0-9]+(\.[0-9]*)?$|^\.[0-9]+$ ]]; }

mode=auto
build=build
time_scale=20
seconds=0
while [ $# -gt 0 ]; do
    opt=$1 val=
    case "$opt" in --*=*) val=${opt#*=}; opt=${opt%%=*}; set -- "$opt" "$val" "${@:2}" ;; esac
    case "$opt" in
        -h|--help) usage; exit 0 ;;
        --runner|--openplc)
            m=${opt#--}
            [ "$mode" = auto ] || [ "$mode" = "$m" ] || die "--runner and --openplc exclude each other"
            mode=$m ;;
        --build-dir|--time-scale|--seconds)
            [ $# -ge 2 ] || die "$opt needs a value"
            val=$2; shift
            [ -n "$val" ] || die "$opt needs a non-empty value"
            case "$opt" in
                --build-dir) build=$val ;;
                --time-scale)
                    is_number "$val" && awk -v v="$val" 'BEGIN { exit !(v > 0 && v <= 10000) }' ||
                        die "--time-scale wants a number > 0 (up to 10000), not '$val'"
                    time_scale=$val ;;
                --seconds)
                    is_number "$val" || die "--seconds wants a number of seconds >= 0, not '$val'"
                    seconds=$val ;;
            esac ;;
        --install-openplc)
            shift
            [ $# -le 1 ] || die "--install-openplc takes at most one directory and no other option"
            exec tools/openplc/install-openplc.sh "$@" ;;
        *) die "unknown option '$opt'" ;;
    esac
    shift
done

scripts/deps.sh
scripts/venv.sh
export OPENPLC_HOME="${OPENPLC_HOME:-/opt/OpenPLC_v3}"
have_openplc() {
    [ -x "$OPENPLC_HOME/webserver/iec2c" ] && [ -x "$OPENPLC_HOME/webserver/core/glue_generator" ]
}
live=(.venv/bin/python examples/heat_treat_st/live.py --time-scale "$time_scale" --seconds "$seconds")

if [ "$mode" = auto ]; then
    if have_openplc; then mode=openplc; else mode=runner; fi
fi
if [ "$mode" = openplc ]; then
    if ! have_openplc; then
        echo "demo.sh: no OpenPLC v3 runtime at $OPENPLC_HOME (webserver/iec2c, webserver/core/glue_generator)." >&2
        echo "  Set OPENPLC_HOME, install it with ./demo.sh --install-openplc, or drop --openplc to use the runner." >&2
        exit 1
    fi
    exec tools/openplc/netns.sh "${live[@]}" --backend openplc
fi

# The runner: the example's program built with the project's CMake (tools/runner).
generator=()
[ -f "$build/CMakeCache.txt" ] || generator=(-G Ninja)
mkdir -p "$build"
log=$build/demo-configure.log
echo "configuring $build (cmake; the whole output: $log) ..."
set +e
cmake -S . -B "$build" ${generator[@]+"${generator[@]}"} 2>&1 | tee "$log" |
    grep --line-buffered -E -- '^-- (toolchain|matiec|OpenPLC v3 runtime|fb):'
status=${PIPESTATUS[0]}
set -e
if [ "$status" != 0 ]; then
    tail -n 20 "$log" >&2
    echo "demo.sh: cmake could not configure $build (see $log)" >&2
    exit 1
fi
if grep -q -- '^-- fb: ST tests and runner not built' "$log"; then
    cat >&2 <<EOF
demo.sh: the runner cannot be built (the reason is on the fb: line above). Any one of:
  - OpenPLC v3: ./demo.sh --install-openplc, or OPENPLC_HOME=<your OpenPLC_v3> ./demo.sh
  - a matiec source tree (offline machines): MATIEC_SOURCE_DIR=<matiec source> ./demo.sh
  - network access to github.com: matiec is then fetched at its pinned commit and built here
  - a matiec build: MATIEC_HOME=<dir with iec2c, lib/> ./demo.sh
EOF
    exit 1
fi
echo "building the runner (heat_treat_st_runner) ..."
if ! cmake --build "$build" --target heat_treat_st_runner; then
    echo "demo.sh: could not build the runner (heat_treat_st_runner) in $build" >&2
    exit 1
fi
exec "${live[@]}" --backend runner --runner-exe "$build/tools/runner/heat_treat_st_runner"
