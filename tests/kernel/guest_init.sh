#!/bin/sh
# The kernel test bed's init (tests/kernel/bed.py): load the modules, run the setup lines, wait
# for the ports, run the test program with its output kept in memory, print it, power off.
/bin/busybox --install -s /bin
export PATH=/bin
mkdir -p /proc /sys /dev
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
mkdir -p /tmp && mount -t tmpfs tmp /tmp
for m in $(cat /etc/bed/modules); do
    insmod "/lib/modules/$m.ko" || echo "BED: insmod $m failed"
done
# the console on a device that a module brings (virtio-console on the ARM guests): what init
# prints goes there once it exists; the program finds the control line in MBFB_BED_CTL
if [ -s /etc/bed/console ]; then
    con=$(cat /etc/bed/console)
    # wait until it opens, not only until it exists: a redirection that fails on `exec` ends
    # this shell, and init with it (a kernel panic, "Attempted to kill init", seen once in CI
    # 3 s into an aarch64 boot; cause not proven)
    n=0
    until { [ -e "$con" ] && true >>"$con"; } 2>/dev/null || [ $n -ge 200 ]; do
        sleep 0.05; n=$((n + 1))
    done
    if { [ -e "$con" ] && true >>"$con"; } 2>/dev/null; then
        exec >>"$con" 2>&1
    else
        echo "BED: console $con cannot be opened"
    fi
fi
export MBFB_BED_CTL="$(cat /etc/bed/ctl)"
sh /etc/bed/setup || echo "BED: setup failed"
for d in $(cat /etc/bed/wait); do
    n=0
    while [ ! -e "$d" ] && [ $n -lt 200 ]; do sleep 0.05; n=$((n + 1)); done
    [ -e "$d" ] || echo "BED: $d did not appear"
done
/bin/test-program $(cat /etc/bed/args) >/tmp/out 2>&1
rc=$?
echo "BED: output begin"
cat /tmp/out
echo "BED: output end"
echo "BED: exit $rc"
poweroff -f
