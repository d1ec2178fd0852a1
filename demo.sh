#!/usr/bin/env bash
# demo.sh - the example plant, live: the simulator with the heat-treat line's three instruments,
# the ST example running in the real OpenPLC v3 runtime (a scratch copy of $OPENPLC_HOME, in a
# private network namespace), and its values (PV, SV, count, status, alarms) on screen until
# Ctrl-C. Stops everything it started. Options go to examples/heat_treat_st/live.py
# (--time-scale F, --seconds N).
set -euo pipefail
cd "$(dirname "$0")"
scripts/deps.sh
scripts/venv.sh
export OPENPLC_HOME="${OPENPLC_HOME:-/opt/OpenPLC_v3}"
if [ ! -x "$OPENPLC_HOME/webserver/iec2c" ] || [ ! -x "$OPENPLC_HOME/webserver/core/glue_generator" ]; then
    echo "demo.sh: OpenPLC v3 not found at $OPENPLC_HOME (set OPENPLC_HOME; README, Prerequisites)." >&2
    echo "The demo compiles and runs the example with OpenPLC's own matiec and runtime." >&2
    exit 1
fi
exec tests/e2e/netns.sh .venv/bin/python examples/heat_treat_st/live.py "$@"
