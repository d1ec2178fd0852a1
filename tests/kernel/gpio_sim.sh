#!/usr/bin/env bash
# Builds the kernel's GPIO simulator (gpio-sim) as a module for the guest kernel of the test bed,
# which Debian builds without it (CONFIG_GPIO_SIM and the IRQ_SIM it selects are not set):
#   tests/kernel/gpio_sim.sh CACHE_DIR RELEASE       (RELEASE: e.g. 6.1.0-56-amd64)
# From Debian's packages of that very kernel, downloaded with `apt-get download` and unpacked
# with `dpkg-deb -x` into CACHE_DIR (never installed): linux-headers-RELEASE and its -common,
# linux-kbuild-6.x and linux-source-6.x at the image's version (or, when the archive no longer
# has them, at another Debian revision of its upstream version). The module is gpio-sim.c with
# kernel/irq/irq_sim.c linked in, out of tree against those headers (Kbuild, the host's gcc: the
# image's compiler on Debian 12), with one change: irq_sim's handler calls
# generic_handle_irq(irq) instead of handle_simple_irq(irq_to_desc(irq)), the same call through
# an exported symbol (irq_to_desc is not exported to modules). Done once: CACHE_DIR/ready.
# MBFB_GPIO_SIM_KO: a gpio-sim.ko for RELEASE to use instead (offline). Prints the module's
# path; exits 3 with the reason on stderr when it cannot be had.
set -euo pipefail
cache=$1
release=$2
if [ -n "${MBFB_GPIO_SIM_KO:-}" ]; then
    [ -f "$MBFB_GPIO_SIM_KO" ] || { echo "MBFB_GPIO_SIM_KO=$MBFB_GPIO_SIM_KO: no such file" >&2; exit 3; }
    echo "$MBFB_GPIO_SIM_KO"
    exit 0
fi
mkdir -p "$cache"
cache=$(cd "$cache" && pwd)
ko="$cache/mod/gpio-sim.ko"
if [ "$(cat "$cache/ready" 2>/dev/null)" = "$release" ] && [ -f "$ko" ]; then
    echo "$ko"
    exit 0
fi
exec 9>"$cache/.lock"
flock 9
if [ "$(cat "$cache/ready" 2>/dev/null)" = "$release" ] && [ -f "$ko" ]; then
    echo "$ko"
    exit 0
fi
fail() { echo "gpio-sim: $*" >&2; exit 3; }
command -v apt-get >/dev/null || fail "no apt-get to download the kernel's headers and source"
command -v make >/dev/null || fail "no make"
version=$(apt-cache show "linux-image-$release" 2>/dev/null | sed -n 's/^Version: //p' | head -n1)
[ -n "$version" ] || fail "apt knows no linux-image-$release (apt-get update?)"
series=$(echo "$release" | sed -n 's/^\([0-9]*\.[0-9]*\)\..*/\1/p')   # 6.1
flavour=${release##*-}                                                # amd64
abi=${release%-"$flavour"}                                            # 6.1.0-56
rm -rf "$cache/deb" "$cache/root" "$cache/mod" "$cache/ready"
mkdir -p "$cache/deb" "$cache/root" "$cache/mod"
# kbuild (the build tools) and source (three files) are the kernel's release, not its ABI:
# when the archive has moved them to another Debian revision of the same upstream version
# (a security upload under way: 6.1.192-3 beside an image still at 6.1.192-2), take that one.
same_release() {   # same_release PACKAGE: $version if the archive has it, else its newest VER-*
    apt-cache madison "$1" 2>/dev/null | awk -F'|' -v v="$version" -v up="${version%-*}-" '
        { gsub(/ /, "", $2) } $2 == v { exact = 1 } index($2, up) == 1 && !any { any = $2 }
        END { if (exact) print v; else if (any) print any }'
}
kbuild=$(same_release "linux-kbuild-$series")
source=$(same_release "linux-source-$series")
[ "${kbuild:-$version}" = "$version" ] && [ "${source:-$version}" = "$version" ] ||
    echo "gpio-sim: linux-kbuild-$series ${kbuild:-?}, linux-source-$series ${source:-?} for the image's $version" >&2
for p in "linux-headers-$release=$version" "linux-headers-$abi-common=$version" \
         "linux-kbuild-$series=${kbuild:-$version}" "linux-source-$series=${source:-$version}"; do
    (cd "$cache/deb" && apt-get download -q "$p" >/dev/null 2>"$cache/apt.err") ||
        fail "apt-get download $p failed: $(tail -n1 "$cache/apt.err")"
done
for d in "$cache"/deb/*.deb; do
    case $d in *linux-source-*) ;; *) dpkg-deb -x "$d" "$cache/root" ;; esac
done
# three files of the source tarball (it is 140 MB of xz: read once, kept nowhere)
src="linux-source-$series"
dpkg-deb --fsys-tarfile "$cache"/deb/linux-source-*.deb |
    tar -xO "./usr/src/linux-source-$series.tar.xz" | xz -dc |
    tar -x -C "$cache" "$src/drivers/gpio/gpio-sim.c" "$src/drivers/gpio/gpiolib.h" \
        "$src/kernel/irq/irq_sim.c" || fail "gpio-sim's source is not in $src"
cp "$cache/$src/drivers/gpio/gpio-sim.c" "$cache/mod/gpio-sim-main.c"
cp "$cache/$src/drivers/gpio/gpiolib.h" "$cache/$src/kernel/irq/irq_sim.c" "$cache/mod/"
sed -i 's/handle_simple_irq(irq_to_desc(irqnum))/generic_handle_irq(irqnum)/' "$cache/mod/irq_sim.c"
grep -q 'generic_handle_irq(irqnum)' "$cache/mod/irq_sim.c" || fail "irq_sim.c is not the one this script knows"
printf 'obj-m := gpio-sim.o\ngpio-sim-y := gpio-sim-main.o irq_sim.o\n' >"$cache/mod/Kbuild"
hdr="$cache/root/usr/src/linux-headers-$release"
# the package's Makefile includes its -common tree by absolute path: point it at ours
sed -i "s#/usr/src/#$cache/root/usr/src/#" "$hdr/Makefile"
make -C "$hdr" M="$cache/mod" modules >"$cache/make.log" 2>&1 ||
    fail "building gpio-sim failed: $(grep -m1 -E 'error|ERROR' "$cache/make.log" || tail -n1 "$cache/make.log")"
rm -rf "$cache/deb" "$cache/$src" "$cache/root"
echo "$release" >"$cache/ready"
echo "$ko"
