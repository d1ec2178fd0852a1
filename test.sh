#!/usr/bin/env bash
# Runs every test: ./test.sh            (all suites)
#                  ./test.sh -L shims   (one label: shims, sim, fb, e2e, editor)
#                  ./test.sh -R crc     (tests whose name matches)
# Extra arguments go to ctest.
set -euo pipefail
cd "$(dirname "$0")"
scripts/deps.sh     # Debian packages (.ci/apt-packages.txt); no-op when all present
scripts/venv.sh     # pinned Python in ./.venv
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build -j"$(nproc)"
exec ctest --test-dir build --output-on-failure --timeout 600 "$@"
