#!/usr/bin/env bash
# Runs every test: ./test.sh            (all suites)
#                  ./test.sh -L shims   (one label: shims, sim, fb, e2e, editor)
#                  ./test.sh -R crc     (tests whose name matches)
# Extra arguments go to ctest. Configures build/ first and prints the configure summary (which
# compiler toolchain, which libmodbus); after the run, each skipped test with its reason.
# MBFB_BUILD_DIR: the build tree (default build).
set -euo pipefail
cd "$(dirname "$0")"
scripts/deps.sh     # Debian packages (.ci/apt-packages.txt); no-op when all present
scripts/venv.sh     # pinned Python in ./.venv
b=${MBFB_BUILD_DIR:-build}
mkdir -p "$b"
log=$b/configure.log
set +e
cmake -S . -B "$b" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo 2>&1 | tee "$log" |
    grep --line-buffered -E -- '^-- ((toolchain|matiec|OpenPLC v3 runtime|fb|plc_lib):|c_shims: (libmodbus|OpenPLC))|Error'
status=${PIPESTATUS[0]}
set -e
if [ "$status" != 0 ]; then
    tail -n 30 "$log" >&2
    echo "test.sh: cmake could not configure $b (whole output: $log)" >&2
    exit 1
fi
cmake --build "$b" -j"$(nproc)"
set +e
ctest --test-dir "$b" --output-on-failure --timeout 600 "$@" 2>&1 | tee "$b/ctest.log"
status=${PIPESTATUS[0]}
set -e
.venv/bin/python scripts/skipped.py "$b/ctest.log" "$b/Testing/Temporary/LastTest.log" || true
exit $status
