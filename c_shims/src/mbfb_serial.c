/*
 * mbfb_serial.c - serial-line helpers every serial framing shares: the port's driver and its
 * low-latency mode when the port opens, the watched silence before a request, waiting for
 * input, writing a whole frame.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* ppoll (g++ defines it already) */
#endif
#include <errno.h>
#include <limits.h>
#include <linux/serial.h> /* struct serial_struct, ASYNC_LOW_LATENCY */
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include "mbfb_internal.h"

/* The driver of the serial port fd (the name of its sysfs driver: "serial8250", "serial"
 * for the 8250 on PNP and PCI, "ftdi_sio", "cp210x", ...) and its sysfs device path. */
int mbfb_serial_driver(int fd, char *driver, size_t n, char *devpath, size_t m)
{
    struct stat st;
    char link[128], target[PATH_MAX];
    ssize_t len;
    const char *base;

    if (fstat(fd, &st) != 0 || !S_ISCHR(st.st_mode))
        return -1;
    snprintf(link, sizeof link, "/sys/dev/char/%u:%u/device", major(st.st_rdev),
             minor(st.st_rdev));
    if (realpath(link, target) == NULL || strlen(target) >= m)
        return -1;
    strcpy(devpath, target);
    snprintf(link, sizeof link, "/sys/dev/char/%u:%u/device/driver", major(st.st_rdev),
             minor(st.st_rdev));
    if ((len = readlink(link, target, sizeof target - 1)) <= 0)
        return -1;
    target[len] = '\0';
    base = strrchr(target, '/');
    base = base != NULL ? base + 1 : target;
    if (strlen(base) >= n)
        return -1;
    strcpy(driver, base);
    return 0;
}

/* Low latency where the driver offers it: a USB serial adapter holds received bytes until
 * its buffer fills or its latency timer runs out (ftdi_sio: 16 ms by default), so every reply
 * waits for it; ASYNC_LOW_LATENCY (TIOCSSERIAL, allowed to any user) makes ftdi_sio set the
 * timer to 1 ms. Only on USB adapters: a UART on the board hands its bytes over at its
 * interrupt and has nothing to shorten. Best effort: a driver without TIOCSSERIAL keeps its
 * latency, which the reply and byte timeouts allow for (mbfb_timing.c). Returns 1 when the
 * flag is in force after the call, else 0. */
int mbfb_serial_low_latency(int fd)
{
    struct serial_struct ss;
    char driver[64], devpath[PATH_MAX];

    if (mbfb_serial_driver(fd, driver, sizeof driver, devpath, sizeof devpath) != 0 ||
        strstr(devpath, "/usb") == NULL || ioctl(fd, TIOCGSERIAL, &ss) != 0)
        return 0;
    if (!(ss.flags & ASYNC_LOW_LATENCY)) {
        ss.flags |= ASYNC_LOW_LATENCY;
        if (ioctl(fd, TIOCSSERIAL, &ss) != 0 || ioctl(fd, TIOCGSERIAL, &ss) != 0)
            return 0;
    }
    return (ss.flags & ASYNC_LOW_LATENCY) != 0;
}

/* ppoll for input, EINTR retried. */
int mbfb_fd_wait_input(int fd, int64_t wait_us)
{
    struct pollfd p = {fd, POLLIN, 0};
    struct timespec ts;
    int rc;

    if (wait_us < 0)
        wait_us = 0;
    ts.tv_sec = (time_t)(wait_us / 1000000);
    ts.tv_nsec = (long)(wait_us % 1000000) * 1000;
    while ((rc = ppoll(&p, 1, &ts, NULL)) < 0 && errno == EINTR) {
    }
    return rc < 0 ? -1 : rc > 0;
}

/* Keep the newest bytes heard in the silence wait in bus->heard (late replies). */
static void keep_heard(mbfb_bus_t *bus, const uint8_t *b, int n)
{
    int drop = bus->n_heard + n - MBFB_HEARD_MAX;
    if (n > MBFB_HEARD_MAX) {
        b += n - MBFB_HEARD_MAX;
        n = MBFB_HEARD_MAX;
        drop = bus->n_heard;
    }
    if (drop > 0) {
        memmove(bus->heard, bus->heard + drop, (size_t)(bus->n_heard - drop));
        bus->n_heard -= drop;
    }
    memcpy(bus->heard + bus->n_heard, b, (size_t)n);
    bus->n_heard += n;
}

/* Wait until the line has been silent for silence_us, reading and discarding whatever
 * arrives meanwhile (see mbfb_backend_t.quiet). Written here because libmodbus only
 * flushes, and modbus_flush() on a serial port is tcflush(TCIOFLUSH): it would also drop
 * output not yet on the wire (on a pty: a broadcast the peer has not read) and it cannot
 * tell a finished line from one still carrying a late reply. */
int mbfb_serial_quiet(mbfb_bus_t *bus, int silence_us, int limit_us)
{
    int64_t give_up = mbfb_now_us() + limit_us;
    int stray = 0;

    bus->n_heard = 0;

    for (;;) {
        uint8_t junk[256];
        int64_t end = bus->quiet_from_us + silence_us;
        int64_t wait;
        ssize_t n;
        int rc;

        if (end > give_up)
            end = give_up; /* babbling line: send anyway, the reply check decides */
        /* a long silence (the settle after a failed attempt) ends early when the bus
         * stops: the caller then sends nothing (README "Lifetime") */
        wait = end - mbfb_now_us();
        rc = mbfb_fd_wait_input(bus->fd, wait > MBFB_STOP_SLICE_US ? MBFB_STOP_SLICE_US : wait);
        if (rc == 0 && wait > MBFB_STOP_SLICE_US && !mbfb_stopping(bus))
            continue; /* not silent long enough yet */
        if (rc <= 0)
            return rc < 0 ? -MBFB_E_PORTLOST : stray; /* silent until `end` (or stopping) */
        /* readable: a tty with VMIN = VTIME = 0 returns 0 only when it is gone */
        n = read(bus->fd, junk, sizeof junk);
        if (n > 0) {
            int64_t now = mbfb_now_us();
            stray += (int)n;
            keep_heard(bus, junk, (int)n);
            if (bus->quiet_from_us < now) /* a byte restarts the silence */
                bus->quiet_from_us = now;
            if (now >= give_up)
                return stray;
        } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
            return -MBFB_E_PORTLOST; /* EOF (adapter gone) or EIO */
        }
    }
}

/* Write a whole frame to the non-blocking port. */
int mbfb_fd_write_all(mbfb_bus_t *bus, const uint8_t *buf, int len)
{
    int done = 0;
    while (done < len) {
        ssize_t n = write(bus->fd, buf + done, (size_t)(len - done));
        if (n > 0) {
            done += (int)n;
        } else if (n < 0 && (errno == EAGAIN || errno == EINTR)) {
            struct pollfd p = {bus->fd, POLLOUT, 0};
            if (poll(&p, 1, 1000) == 0)
                return -MBFB_E_PORTLOST; /* output stuck for a second */
        } else {
            return -MBFB_E_PORTLOST;
        }
    }
    return 0;
}
