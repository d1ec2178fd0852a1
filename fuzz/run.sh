#!/usr/bin/env bash
# fuzz/run.sh [SECONDS] [HARNESS...] - build the libFuzzer harnesses (cmake target mbfb_fuzz)
# and run each for SECONDS (default 60) from its committed seed corpus (fuzz/corpus/<name>).
# New corpus entries go to a scratch copy that is removed afterwards: the committed corpora
# stay small. A crash, leak, sanitizer report, timeout or failed invariant stops that harness
# with a non-zero status; its input is kept in <build>/fuzz/artifacts/ and the script fails.
# Build dir: $MBFB_BUILD_DIR (default build/). Without clang: skipped (exit 0), or an error
# under MBFB_REQUIRE_TOOLCHAIN=1 (CI).
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-60}
shift || true
case "$secs" in ''|*[!0-9]*) echo "usage: fuzz/run.sh [SECONDS] [HARNESS...]" >&2; exit 2;; esac
harnesses=("$@")
[ ${#harnesses[@]} -gt 0 ] || harnesses=(fuzz_reply fuzz_recv fuzz_worker)
build=${MBFB_BUILD_DIR:-build}

if ! command -v clang >/dev/null 2>&1 && ! ls /usr/bin/clang-[0-9]* >/dev/null 2>&1; then
  if [ "${MBFB_REQUIRE_TOOLCHAIN:-0}" = 1 ]; then
    echo "fuzz: error: clang not found (apt-get install clang)" >&2; exit 1
  fi
  echo "fuzz: skipped: clang not found (apt-get install clang)"; exit 0
fi
if [ ! -f "$build/CMakeCache.txt" ]; then
  gen=(); command -v ninja >/dev/null 2>&1 && gen=(-G Ninja)
  cmake -S . -B "$build" "${gen[@]}" >/dev/null
fi
has_target() { grep -qs 'mbfb_fuzz' "$build/build.ninja" "$build/Makefile"; }
has_target || cmake "$build" >/dev/null    # configured before clang was installed?
if ! has_target; then
  echo "fuzz: error: no target mbfb_fuzz in $build (CMakeLists.txt needs add_subdirectory(fuzz))" >&2
  exit 2
fi
cmake --build "$build" --target mbfb_fuzz -j2

work=$(mktemp -d "${TMPDIR:-/tmp}/mbfb-fuzz-XXXXXX")
trap 'rm -rf "$work"' EXIT
artifacts="$build/fuzz/artifacts"
mkdir -p "$artifacts"
status=0
for h in "${harnesses[@]}"; do
  bin="$build/fuzz/$h"
  [ -x "$bin" ] || { echo "fuzz: error: no harness $h ($bin)" >&2; exit 2; }
  mkdir -p "$work/$h"
  cp fuzz/corpus/"$h"/* "$work/$h"/
  echo "fuzz: $h for ${secs} s"
  if "$bin" -max_total_time="$secs" -timeout=60 -rss_limit_mb=2048 -max_len=4104 \
      -print_final_stats=1 -artifact_prefix="$artifacts/$h-" "$work/$h" \
      > "$work/$h.log" 2>&1; then
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/$h.log")
    echo "fuzz: $h: ok, ${runs:-?} executions, corpus $(ls "$work/$h" | wc -l) inputs"
  else
    status=1
    echo "fuzz: $h: FAILED (input kept in $artifacts/); its last output:" >&2
    tail -n 40 "$work/$h.log" >&2
  fi
done
exit $status
