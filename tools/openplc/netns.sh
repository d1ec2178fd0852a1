#!/bin/sh
# netns.sh CMD [ARGS...] - run CMD in a new, private network namespace with only loopback up.
# The OpenPLC runtime's Modbus TCP and interactive servers bind every interface; inside this
# namespace nothing they open is reachable from outside the machine (or from the host).
# Needs root (or unprivileged user namespaces: then add -r). Exits 77 if namespaces are refused.
set -eu
[ $# -ge 1 ] || { echo "usage: netns.sh CMD [ARGS...]" >&2; exit 2; }
if ! unshare -n true 2>/dev/null; then
    echo "netns.sh: cannot create a network namespace (need root / CAP_SYS_ADMIN)" >&2
    [ "${MBFB_REQUIRE_TOOLCHAIN:-0}" = 1 ] && exit 1
    exit 77
fi
exec unshare -n -- sh -c 'ip link set lo up && exec "$@"' netns "$@"
