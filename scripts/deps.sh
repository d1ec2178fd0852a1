#!/usr/bin/env bash
# Installs the Debian packages listed in .ci/apt-packages.txt (needs root or sudo); a no-op when
# every one is installed. A name is checked for this machine's own architecture (or `all`):
# on a machine with foreign architectures enabled a multiarch package (libmodbus-dev) may be
# installed for several, and `dpkg -s NAME` is then ambiguous. `NAME:ARCH` in the list asks for
# that architecture (the cross-build's libmodbus-dev:arm64); the architecture is enabled
# (`dpkg --add-architecture`) only when such a package is missing and it is not enabled yet.
set -euo pipefail
cd "$(dirname "$0")/.."
native=$(dpkg --print-architecture)

pkgs=$(grep -v '^\s*#' .ci/apt-packages.txt | xargs)
# what dpkg holds for these names, one "NAME ARCH STATUS" line per installed instance (one
# query: an unknown name only makes it exit 1)
held=$(dpkg-query -W -f='${Package} ${Architecture} ${db:Status-Status}\n' \
    $(for p in $pkgs; do echo "${p%%:*}"; done | sort -u) 2>/dev/null || true)
# NAME[:ARCH] is installed for ARCH (default: this machine's architecture), or for `all`
installed() {
    local name=${1%%:*} arch=$native
    [ "$name" = "$1" ] || arch=${1#*:}
    grep -Fxq -e "$name $arch installed" -e "$name all installed" <<<"$held"
}
missing=$(for p in $pkgs; do installed "$p" || echo "$p"; done | xargs)
[ -z "$missing" ] && exit 0
SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
enabled=" $native $(dpkg --print-foreign-architectures | xargs) "
for p in $missing; do
    case $p in
    *:*)
        arch=${p#*:}
        if [[ $enabled != *" $arch "* ]]; then
            $SUDO dpkg --add-architecture "$arch"
            enabled="$enabled$arch "
        fi
        ;;
    esac
done
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q $missing
