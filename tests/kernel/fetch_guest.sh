#!/usr/bin/env bash
# Fetches the guest kernel for the kernel test bed into a cache folder of the build tree:
#   tests/kernel/fetch_guest.sh CACHE_DIR [ARCH]
# Downloads the packages of .ci/guest-packages.txt for ARCH (default amd64: the names without
# a suffix; arm64, armhf: the names ending in :ARCH, which need that architecture enabled, as
# scripts/deps.sh does) with `apt-get download` (a metapackage is
# followed to the versioned package it depends on) and unpacks them with `dpkg-deb -x`, once:
# a second call finds CACHE_DIR/ready and prints the same answer. MBFB_GUEST_KERNEL_DEB: a
# .deb to use instead of downloading (offline). Prints the kernel release (e.g.
# 6.1.0-56-amd64); exits 3 with the reason on stderr when the package cannot be had.
set -euo pipefail
here=$(cd "$(dirname "$0")/../.." && pwd)
cache=$1
arch=${2:-amd64}
mkdir -p "$cache"
cache=$(cd "$cache" && pwd)
if [ -f "$cache/ready" ]; then
    cat "$cache/ready"
    exit 0
fi
lock="$cache/.lock"
exec 9>"$lock"
flock 9
if [ -f "$cache/ready" ]; then
    cat "$cache/ready"
    exit 0
fi
rm -rf "$cache/deb" "$cache/root"
mkdir -p "$cache/deb" "$cache/root"
if [ -n "${MBFB_GUEST_KERNEL_DEB:-}" ]; then
    cp "$MBFB_GUEST_KERNEL_DEB" "$cache/deb/"
else
    command -v apt-get >/dev/null || { echo "no apt-get to download the guest kernel" >&2; exit 3; }
    # a metapackage (linux-image-amd64) -> the versioned image it depends on
    resolve() {
        local dep
        dep=$(apt-cache depends "$1" 2>/dev/null |
            sed -n 's/^ *Depends: \(linux-image-[0-9].*\)$/\1/p' | head -n1)
        echo "${dep:-$1}"
    }
    updated=0
    if [ "$arch" = amd64 ]; then
        pkgs=$(grep -v '^\s*#' "$here/.ci/guest-packages.txt" | grep -v : | xargs)
    else
        pkgs=$(grep -v '^\s*#' "$here/.ci/guest-packages.txt" | grep ":$arch\s*$" | xargs)
    fi
    [ -n "$pkgs" ] || { echo "no guest packages for $arch in .ci/guest-packages.txt" >&2; exit 3; }
    for p in $pkgs; do
        until (cd "$cache/deb" && apt-get download -q "$(resolve "$p")" >/dev/null 2>"$cache/apt.err"); do
            # the package lists may be missing or stale (a fresh container): update once
            if [ "$updated" = 1 ] || [ "$(id -u)" != 0 ]; then
                echo "apt-get download $(resolve "$p") failed: $(tail -n1 "$cache/apt.err")" >&2
                exit 3
            fi
            apt-get update -q >/dev/null 2>&1 || true
            updated=1
        done
    done
fi
for d in "$cache"/deb/*.deb; do
    dpkg-deb -x "$d" "$cache/root"
done
vmlinuz=$(ls "$cache"/root/boot/vmlinuz-* 2>/dev/null | head -n1)
[ -n "$vmlinuz" ] || { echo "no vmlinuz in the guest kernel package" >&2; exit 3; }
release=${vmlinuz##*/vmlinuz-}
# keep the kernel and the modules; drop the rest of the package (firmware lists, docs)
rm -rf "$cache/deb"
echo "$release" >"$cache/ready"
cat "$cache/ready"
