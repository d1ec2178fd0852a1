#!/usr/bin/env bash
# Blind time after one late reply, shim level, two versions of c_shims side by side in one
# run (bench/late_blind.c says what is measured):
#   bench/late_blind.sh [BEFORE_REF] [REPEATS]      (default: main, 3)
# "before" is c_shims/ at BEFORE_REF (git archive), "after" the work tree's c_shims/; both
# are compiled with the same bench and peer sources and libmodbus from pkg-config, and run
# alternately, delay by delay, so both see the same machine load.
set -euo pipefail
cd "$(dirname "$0")/.."
ref=${1:-main}
reps=${2:-3}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$tmp/before"
git archive "$ref" c_shims | tar -x -C "$tmp/before"
build() { # $1 out, $2 c_shims dir
    cc -O2 -std=gnu11 -I tests/shims -I "$2/include" -I "$2/src" \
        bench/late_blind.c tests/shims/mbfb_test_peer.c tests/shims/testline.c "$2"/src/*.c \
        $(pkg-config --cflags --libs libmodbus) -lpthread -lutil -lm \
        -Wl,-rpath,"$(pkg-config --variable=libdir libmodbus)" -o "$1"
}
build "$tmp/late_before" "$tmp/before/c_shims"
build "$tmp/late_after" c_shims
echo "before: c_shims at $(git rev-parse --short "$ref"); after: work tree at" \
     "$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- c_shims || echo ' + changes')"
printf '%-6s | %-28s | %-28s\n' delay "before: blind / beyond (ms)" "after: blind / beyond (ms)"
for d in 100 200 500 1000 2000; do
    for k in $(seq "$reps"); do
        b=$(TMPDIR=$tmp "$tmp/late_before" "$d")
        a=$(TMPDIR=$tmp "$tmp/late_after" "$d")
        echo "before $b" >>"$tmp/raw"
        echo "after  $a" >>"$tmp/raw"
    done
done
cat "$tmp/raw"
# medians per delay and version
python3 - "$tmp/raw" <<'EOF'
import sys, statistics as st, collections
rows = collections.defaultdict(list)
period = 50  # late_blind.c PERIOD_MS
for line in open(sys.argv[1]):
    ver, rest = line.split(None, 1)
    kv = dict(x.split('=') for x in rest.split())
    rows[(int(kv['delay']), ver)].append(kv)
print('\n| late by | before: blind (beyond delay + period) | after: blind (beyond delay + period) |'
      ' before: OFFLINE / frames | after: OFFLINE / frames | wrong |')
print('|---|---|---|---|---|---|')
for d in sorted({k[0] for k in rows}):
    cells, extra, wrong = [], [], 0
    for ver in ('before', 'after'):
        r = rows[(d, ver)]
        blind = st.median(float(x['blind']) for x in r)
        cells.append('%.0f ms (%+.0f)' % (blind, blind - d - period))
        extra.append('%s / %s' % (st.median(int(x['offline']) for x in r),
                                  st.median(int(x['frames']) for x in r)))
        wrong += sum(int(x['wrong']) for x in r)
    print('| %d ms | %s | %s | %s | %s | %d |' % (d, cells[0], cells[1], extra[0], extra[1],
                                                 wrong))
EOF
