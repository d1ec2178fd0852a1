#!/usr/bin/env bash
# Instructions per scan-side call in steady state, under callgrind.
# usage: [MODE=scan|plan] bench/callgrind.sh [BUILD_DIR] [N] [BENCH]  (default build-shims, 2000 cycles,
#        mbfb_bench; mbfb_bench_lm_debian for Debian's libmodbus)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build-shims}
n=${2:-2000}
bench=${3:-mbfb_bench}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
valgrind --tool=callgrind --callgrind-out-file="$out/cg.out" \
    "$build/bench/$bench" "${MODE:-scan}" "$n" >"$out/calls.txt" 2>"$out/valgrind.txt"
cat "$out/calls.txt"
callgrind_annotate --inclusive=yes --threshold=100 "$out/cg.out" >"$out/annotate.txt"
# "calls: mbfb_post 4000 mbfb_poll 9000 ..." -> per-call inclusive instructions
read -r _ p1 c1 p2 c2 p3 c3 p4 c4 <"$out/calls.txt"
for pair in "$p1 $c1" "$p2 $c2" "$p3 $c3" "$p4 $c4"; do
    set -- $pair
    ir=$(grep -E "[[:space:]]\S*:$1 " "$out/annotate.txt" | head -1 | awk '{gsub(",","",$1); print $1}')
    printf '%-12s %8d calls %12s Ir incl.  %6d Ir/call\n' "$1" "$2" "$ir" $((ir / $2))
done
