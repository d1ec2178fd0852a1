#!/usr/bin/env bash
# fuzz/run.sh [SECONDS] [HARNESS...] - build the libFuzzer harnesses (cmake target mbfb_fuzz)
# and run each for SECONDS (default 60) from its committed seed corpus (fuzz/corpus/<name>).
# New corpus entries go to a scratch copy that is removed afterwards: the committed corpora
# stay small. A crash, leak, sanitizer report, timeout or failed invariant stops that harness
# with a non-zero status; its input is kept in <build>/fuzz/artifacts/ and the script fails.
# Build dir: $MBFB_BUILD_DIR (default build/). Without clang: skipped (exit 0), or an error
# under MBFB_REQUIRE_TOOLCHAIN=1 (CI). MBFB_FUZZ_PARALLEL=1: the harnesses run at the same
# time (SECONDS of wall time for all of them, each with a share of the cores: fewer
# executions each; .ci/run does this), their reports printed in order afterwards.
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
# MBFB_FUZZ_BUILT=1: built already (test fuzz_smoke: test.sh builds them; ctest's other
# tests build in the same tree meanwhile)
[ "${MBFB_FUZZ_BUILT:-0}" = 1 ] || cmake --build "$build" --target mbfb_fuzz -j2

work=$(mktemp -d "${TMPDIR:-/tmp}/mbfb-fuzz-XXXXXX")
trap 'rm -rf "$work"' EXIT
artifacts="$build/fuzz/artifacts"
mkdir -p "$artifacts"
# one harness: run_one NAME (its output in $work/NAME.log, its status in $work/NAME.rc)
run_one() {
  local h=$1 rc=0
  "$build/fuzz/$h" -max_total_time="$secs" -timeout=60 -rss_limit_mb=2048 -max_len=4104 \
      -print_final_stats=1 -artifact_prefix="$artifacts/$h-" "$work/$h" \
      > "$work/$h.log" 2>&1 || rc=$?
  echo "$rc" > "$work/$h.rc"
}
report() {
  local h=$1
  if [ "$(cat "$work/$h.rc")" = 0 ]; then
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/$h.log")
    echo "fuzz: $h: ok, ${runs:-?} executions, corpus $(ls "$work/$h" | wc -l) inputs"
  else
    echo "fuzz: $h: FAILED (input kept in $artifacts/); its last output:" >&2
    tail -n 40 "$work/$h.log" >&2
    return 1
  fi
}
for h in "${harnesses[@]}"; do
  bin="$build/fuzz/$h"
  [ -x "$bin" ] || { echo "fuzz: error: no harness $h ($bin)" >&2; exit 2; }
  mkdir -p "$work/$h"
  cp fuzz/corpus/"$h"/* "$work/$h"/
done
status=0
if [ "${MBFB_FUZZ_PARALLEL:-0}" = 1 ]; then
  echo "fuzz: ${harnesses[*]} at the same time for ${secs} s"
  pids=()
  for h in "${harnesses[@]}"; do
    run_one "$h" &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
  for h in "${harnesses[@]}"; do report "$h" || status=1; done
else
  for h in "${harnesses[@]}"; do
    echo "fuzz: $h for ${secs} s"
    run_one "$h"
    report "$h" || status=1
  done
fi
exit $status
