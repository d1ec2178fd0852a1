#!/usr/bin/env bash
# Runs every test: ./test.sh            (all suites)
#                  ./test.sh -L shims   (one label: maps, shims, sim, fb, strucpp, commission,
#                                        e2e, editor, soak, kernel, cross)
#                  ./test.sh -R crc     (tests whose name matches)
#                  ./test.sh --quick    (the edit loop: the shims in their default flavour, the
#                                        simulator, the maps and one fb test per device block;
#                                        builds only what those need)
# Extra arguments go to ctest. Configures build/ first and prints the configure summary (which
# compiler toolchain, which libmodbus); after the run, each skipped test with its reason.
# MBFB_BUILD_DIR: the build tree (default build).
# MBFB_TEST_JOBS: tests run at once (default 8; the tests mostly wait on timeouts and paced
# lines, so more than the cores). Those that must not share the machine's time say so in
# their CMakeLists.txt (RUN_SERIAL; PROCESSORS for the heavy builds). A -j in the arguments
# wins.
# Temporary files go to $b/tmp (TMPDIR), which the run leaves empty: a test that leaves
# something there is named after the run and fails it.
set -euo pipefail
cd "$(dirname "$0")"
quick=0
if [ "${1:-}" = --quick ]; then
    quick=1
    shift
fi
scripts/deps.sh     # Debian packages (.ci/apt-packages.txt); no-op when all present
scripts/venv.sh     # pinned Python in ./.venv
b=${MBFB_BUILD_DIR:-build}
mkdir -p "$b"
# ccache (Debian's, .ci/apt-packages.txt): a compile whose preprocessed input, flags and compiler
# are those of an earlier one on this machine comes from its cache (CCACHE_DIR, default
# ~/.cache/ccache), in this tree and in every CMake tree the tests make (the launcher variables
# in the environment set their first configure). Paths under this checkout are hashed relative
# to it, so another clone hits the same entries. MBFB_CCACHE=0: no cache.
launcher=""
if [ "${MBFB_CCACHE:-1}" != 0 ] && command -v ccache >/dev/null; then
    launcher=ccache
    export CMAKE_C_COMPILER_LAUNCHER=ccache CMAKE_CXX_COMPILER_LAUNCHER=ccache
    export CCACHE_BASEDIR=$PWD CCACHE_NOHASHDIR=true
else
    unset CMAKE_C_COMPILER_LAUNCHER CMAKE_CXX_COMPILER_LAUNCHER
fi
log=$b/configure.log
set +e
cmake -S . -B "$b" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DCMAKE_C_COMPILER_LAUNCHER="$launcher" -DCMAKE_CXX_COMPILER_LAUNCHER="$launcher" 2>&1 | tee "$log" |
    grep --line-buffered -E -- '^-- ((toolchain|matiec|OpenPLC v3 runtime|fb|plc_lib):|c_shims: (libmodbus|OpenPLC))|Error'
status=${PIPESTATUS[0]}
set -e
if [ "$status" != 0 ]; then
    tail -n 30 "$log" >&2
    echo "test.sh: cmake could not configure $b (whole output: $log)" >&2
    exit 1
fi
if [ "$quick" = 1 ]; then
    # the default flavour of the shims (OpenPLC's fork where it is installed), as the blocks use
    flavours=$(sed -n 's/^MBFB_FLAVOURS:INTERNAL=//p' "$b/CMakeCache.txt")
    case ";$flavours;" in *";lm_openplc;"*) flavour=lm_openplc ;; *) flavour=lm_debian ;; esac
    blocks='fb_(mts9|mvd94|fdc|vd)'   # Counter_MTS9, TempCtrl_MVD94, FDC_Controller, TempCtrl_VD
    # (test_late of Debian's libmodbus is one test per framing: shims_late_lm_debian_rtu, ...)
    quick_re="^(shims_[a-z]+_$flavour(_rtu|_ascii|_rtu_nocrc)?|sim\..*|maps\..*|settings\.types|$blocks)\$"
    # the targets of those tests: each shims and fb test is built as the target of its name
    targets=$(ctest --test-dir "$b" -N -R "$quick_re" | sed -n 's/^ *Test *#[0-9]*: //p' |
              grep -E "^(shims_|fb_)" | sed -E 's/_(rtu|ascii|rtu_nocrc)$//' | sort -u || true)
    cmake --build "$b" -j"$(nproc)" --target mbfb-ptyline ptyline_model_test $targets
    set -- -R "$quick_re" "$@"
else
    # with MBFB_FUZZ_SECONDS (.ci/run) the fuzz harnesses too: test fuzz_smoke runs them
    fuzz=()
    if [ -n "${MBFB_FUZZ_SECONDS:-}" ] && grep -qs 'build mbfb_fuzz:' "$b/build.ninja"; then
        fuzz=(--target all mbfb_fuzz)
    fi
    cmake --build "$b" -j"$(nproc)" ${fuzz[@]+"${fuzz[@]}"}
fi
jobs=(-j "${MBFB_TEST_JOBS:-8}")
for a in "$@"; do
    case $a in -j*|--parallel*) jobs=() ;; esac
done
tmp=$(cd "$b" && pwd)/tmp
rm -rf "$tmp"
mkdir -p "$tmp"
set +e
TMPDIR=$tmp ctest --test-dir "$b" --output-on-failure --timeout 600 ${jobs[@]+"${jobs[@]}"} "$@" 2>&1 |
    tee "$b/ctest.log"
status=${PIPESTATUS[0]}
set -e
left=$(ls -A "$tmp")
if [ -n "$left" ]; then
    echo "test.sh: the tests left these in $tmp (TMPDIR):" >&2
    ls -lA "$tmp" >&2
    [ "$status" != 0 ] || status=1
fi
.venv/bin/python scripts/skipped.py "$b/ctest.log" "$b/Testing/Temporary/LastTest.log" || true
exit $status
