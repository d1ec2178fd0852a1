#!/bin/sh
# run.sh PYTEST_ARGS... - one e2e test module against a scratch copy of OpenPLC v3, inside a
# private network namespace. Exits 77 (ctest: skipped) when OpenPLC or the generated library is
# missing, unless MBFB_REQUIRE_TOOLCHAIN=1 (CI), where that is a failure.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
skip() {
    echo "SKIP: $*" >&2
    [ "${MBFB_REQUIRE_TOOLCHAIN:-0}" = 1 ] && { echo "(MBFB_REQUIRE_TOOLCHAIN=1: failing)" >&2; exit 1; }
    exit 77
}
home=${OPENPLC_HOME:-/opt/OpenPLC_v3}
[ -x "$home/webserver/iec2c" ] && [ -x "$home/webserver/core/glue_generator" ] ||
    skip "OpenPLC v3 not found at $home (set OPENPLC_HOME)"
[ -f "${MBFB_DIST:-}/MANIFEST" ] || skip "generated library missing (${MBFB_DIST:-MBFB_DIST unset}): needs st_src/ and iec2c"
case $(basename "$1") in
    test_web.py) [ -x "$home/.venv/bin/python3" ] ||
        skip "OpenPLC's webserver Python ($home/.venv, made by its install.sh) not found" ;;
esac
export OPENPLC_HOME=$home
# OpenPLC's compile_program.sh through ccache, one source at a time (cc/g++ says how)
export PATH="$here/cc:$PATH"
exec "$here/../../tools/openplc/netns.sh" "${MBFB_PYTHON:?}" -m pytest -q -p no:cacheprovider --rootdir "$here" \
    --basetemp "$PWD/pytest-$(basename "$1" .py)" "$@"
