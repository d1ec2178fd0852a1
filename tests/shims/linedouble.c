/*
 * linedouble.c - a test double between the shims and the kernel for RS-485 direction
 * control (LD_PRELOAD), so a pty stands in for a UART with a transceiver.
 *
 * On the port named by $LINEDOUBLE_PORT (resolved like the shims resolve it) it records,
 * each with CLOCK_MONOTONIC microseconds (the shims' clock), into $LINEDOUBLE_LOG:
 *   T write N B0    a write() of N bytes starting with byte B0 (hex), T when it started;
 *                   the bytes go on to the pty
 *   T drain         tcdrain() returned
 *   T read N        a read() that returned N > 0 bytes (a reply, or what the silence wait
 *                   discards)
 *   T rts 0|1       RTS released / asserted (TIOCMBIS, TIOCMBIC, TIOCMSET): a pty has no
 *                   modem lines, so these succeed here without reaching the kernel
 *   T rs485 F B A   TIOCSRS485 with flags F (hex), delay before B and after A (ms); the
 *                   kernel's RS-485 mode, which a pty lacks, is kept here and read back
 *                   by TIOCGRS485
 *   T gpio V        the GPIO line set to V (gpiod_line_set_value, gpiod_line_request_set_value)
 *   T gpioreq U L V A  a GPIO line requested as output by consumer U: offset L, initial V,
 *                   through libgpiod's API A (v1 or v2)
 * It also stands in for libgpiod, built twice: with LINEDOUBLE_GPIOD=1 for libgpiod 1's API
 * (soname libgpiod.so.2), with LINEDOUBLE_GPIOD=2 for libgpiod 2's (soname libgpiod.so.3), so
 * the shims' dlopen of that soname finds this already-loaded library. Chip
 * $LINEDOUBLE_GPIOCHIP exists (v1: by that name; v2: at /dev/$LINEDOUBLE_GPIOCHIP, which is all
 * libgpiod 2 opens, with label $LINEDOUBLE_GPIOLABEL) and has lines 0..31; any other does not.
 * Calls that break the API's rules (a line set that was not requested, a request that is not
 * one output line) fail and are logged as "misuse WHAT".
 * With LINEDOUBLE_GPIOD=0 it has no libgpiod functions; gpiocdev_double.c, linked with it,
 * stands in for the kernel's GPIO character device under the real libgpiod instead.
 * $LINEDOUBLE_REFUSE=rts|rs485 makes that ioctl fail (a driver without it); =polarity keeps
 * the RS-485 mode but drops the RTS polarity flags (a driver that clamps what it cannot do).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/serial.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "linedouble.h"

#ifndef LINEDOUBLE_GPIOD
#define LINEDOUBLE_GPIOD 1 /* which libgpiod API this build stands in for; 0: none */
#endif
#define DOUBLE_LINES 32

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static char port_real[PATH_MAX];
static int log_fd = -1;
static struct serial_rs485 rs485; /* the kernel mode a pty does not have */

static ssize_t (*real_write)(int, const void *, size_t);
static ssize_t (*real_read)(int, void *, size_t);
static int (*real_ioctl)(int, unsigned long, ...);
static int (*real_tcdrain)(int);

static void init(void)
{
    static int done;
    if (done)
        return;
    real_write = (ssize_t(*)(int, const void *, size_t))dlsym(RTLD_NEXT, "write");
    real_read = (ssize_t(*)(int, void *, size_t))dlsym(RTLD_NEXT, "read");
    real_ioctl = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    real_tcdrain = (int (*)(int))dlsym(RTLD_NEXT, "tcdrain");
    const char *p = getenv("LINEDOUBLE_PORT"), *l = getenv("LINEDOUBLE_LOG");
    if (p == NULL || realpath(p, port_real) == NULL)
        port_real[0] = 0;
    if (l != NULL)
        log_fd = open(l, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    done = 1;
}

static long long now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

/* Is fd the port? (readlink of /proc/self/fd: cheap enough for a test) */
static int is_port(int fd)
{
    char link[64], target[PATH_MAX];
    ssize_t n;
    if (port_real[0] == 0 || fd < 0)
        return 0;
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    n = readlink(link, target, sizeof target - 1);
    if (n <= 0)
        return 0;
    target[n] = 0;
    return strcmp(target, port_real) == 0;
}

static void record(long long t, const char *fmt, ...)
{
    char line[160];
    int n = snprintf(line, sizeof line, "%lld ", t);
    va_list ap;
    va_start(ap, fmt);
    n += vsnprintf(line + n, sizeof line - (size_t)n, fmt, ap);
    va_end(ap);
    line[n++] = '\n';
    if (log_fd >= 0)
        real_write(log_fd, line, (size_t)n);
}

void ld_record(const char *fmt, ...)
{
    char text[128];
    va_list ap;
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    record(now_us(), "%s", text);
}

static int refused(const char *what)
{
    const char *r = getenv("LINEDOUBLE_REFUSE");
    return r != NULL && strcmp(r, what) == 0;
}

ssize_t write(int fd, const void *buf, size_t n)
{
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    if (!is_port(fd))
        return real_write(fd, buf, n);
    long long t = now_us();
    ssize_t rc = real_write(fd, buf, n);
    if (rc > 0)
        record(t, "write %zd %02x", rc, ((const unsigned char *)buf)[0]);
    return rc;
}

ssize_t read(int fd, void *buf, size_t n)
{
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    ssize_t rc = real_read(fd, buf, n);
    if (rc > 0 && is_port(fd))
        record(now_us(), "read %zd", rc);
    return rc;
}

int tcdrain(int fd)
{
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    int rc = real_tcdrain(fd);
    if (is_port(fd))
        record(now_us(), "drain");
    return rc;
}

int ioctl(int fd, unsigned long req, ...)
{
    va_list ap;
    void *arg;
    va_start(ap, req);
    arg = va_arg(ap, void *);
    va_end(ap);
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    if (is_port(fd)) {
        long long t = now_us();
        int bits = arg != NULL ? *(int *)arg : 0;
        switch (req) {
        case TIOCMBIS:
        case TIOCMBIC:
        case TIOCMSET:
            if (refused("rts")) {
                errno = ENOTTY;
                return -1;
            }
            if (bits & TIOCM_RTS)
                record(t, "rts %d", req != TIOCMBIC);
            else if (req == TIOCMSET)
                record(t, "rts 0");
            return 0;
        case TIOCSRS485:
            if (refused("rs485")) {
                errno = ENOTTY;
                return -1;
            }
            memcpy(&rs485, arg, sizeof rs485);
            if (refused("polarity")) /* a driver that clamps the RTS polarity it cannot do */
                rs485.flags &= ~(unsigned)(SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND);
            record(t, "rs485 %x %u %u", rs485.flags, rs485.delay_rts_before_send,
                   rs485.delay_rts_after_send);
            return 0;
        case TIOCGRS485:
            if (refused("rs485")) {
                errno = ENOTTY;
                return -1;
            }
            memcpy(arg, &rs485, sizeof rs485);
            return 0;
        default:
            break;
        }
    }
#if LINEDOUBLE_GPIOD == 0
    {
        int rc;
        if (gpiocdev_ioctl(fd, req, arg, &rc))
            return rc;
    }
#endif
    return real_ioctl(fd, req, arg);
}


#if LINEDOUBLE_GPIOD == 0
/* no libgpiod here: gpiocdev_double.c is the kernel under the real one */
#else
static int misuse(const char *what, int err)
{
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    record(now_us(), "misuse %s", what);
    errno = err;
    return -1;
}

#endif

#if LINEDOUBLE_GPIOD == 1
/* ---- libgpiod 1, the functions the shims use --------------------------------- */
struct gpiod_chip {
    int unused;
};
struct gpiod_line {
    unsigned offset;
    int requested;
};
static struct gpiod_chip the_chip;
static struct gpiod_line lines[DOUBLE_LINES];

struct gpiod_chip *gpiod_chip_open_lookup(const char *name)
{
    const char *ours = getenv("LINEDOUBLE_GPIOCHIP");
    if (ours == NULL || name == NULL || strcmp(name, ours) != 0) {
        errno = ENOENT;
        return NULL;
    }
    return &the_chip;
}

void gpiod_chip_close(struct gpiod_chip *chip)
{
    (void)chip;
}

struct gpiod_line *gpiod_chip_get_line(struct gpiod_chip *chip, unsigned int offset)
{
    if (chip != &the_chip) {
        misuse("chip", EINVAL);
        return NULL;
    }
    if (offset >= DOUBLE_LINES) {
        errno = EINVAL;
        return NULL;
    }
    lines[offset].offset = offset;
    return &lines[offset];
}

int gpiod_line_request_output(struct gpiod_line *line, const char *consumer, int value)
{
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    if (line->requested)
        return misuse("request-twice", EBUSY);
    line->requested = 1;
    record(now_us(), "gpioreq %s %u %d v1", consumer, line->offset, value);
    return 0;
}

int gpiod_line_set_value(struct gpiod_line *line, int value)
{
    if (!line->requested)
        return misuse("set-unrequested", EPERM);
    record(now_us(), "gpio %d", value);
    return 0;
}

void gpiod_line_release(struct gpiod_line *line)
{
    line->requested = 0;
}
#elif LINEDOUBLE_GPIOD == 2
/* ---- libgpiod 2, the functions the shims use --------------------------------- */
#include <stdbool.h>
#define DIRECTION_OUTPUT 3 /* enum gpiod_line_direction */
struct gpiod_chip {
    int unused;
};
struct gpiod_chip_info {
    int unused;
};
struct gpiod_line_settings {
    int direction, value;
};
struct gpiod_line_config {
    unsigned offset;
    int n, direction, value;
};
struct gpiod_request_config {
    char consumer[32];
};
struct gpiod_line_request {
    unsigned offset;
};
static struct gpiod_chip the_chip;
static struct gpiod_chip_info the_info;

bool gpiod_is_gpiochip_device(const char *path)
{
    const char *ours = getenv("LINEDOUBLE_GPIOCHIP");
    return ours != NULL && path != NULL && strncmp(path, "/dev/", 5) == 0 &&
           strcmp(path + 5, ours) == 0;
}

struct gpiod_chip *gpiod_chip_open(const char *path)
{
    if (!gpiod_is_gpiochip_device(path)) {
        errno = ENOENT;
        return NULL;
    }
    return &the_chip;
}

void gpiod_chip_close(struct gpiod_chip *chip)
{
    if (chip != &the_chip)
        misuse("chip", EINVAL);
}

struct gpiod_chip_info *gpiod_chip_get_info(struct gpiod_chip *chip)
{
    return chip == &the_chip ? &the_info : NULL;
}

const char *gpiod_chip_info_get_label(struct gpiod_chip_info *info)
{
    const char *l = getenv("LINEDOUBLE_GPIOLABEL");
    (void)info;
    return l != NULL ? l : "linedouble";
}

void gpiod_chip_info_free(struct gpiod_chip_info *info)
{
    (void)info;
}

struct gpiod_line_settings *gpiod_line_settings_new(void)
{
    return (struct gpiod_line_settings *)calloc(1, sizeof(struct gpiod_line_settings));
}

void gpiod_line_settings_free(struct gpiod_line_settings *s)
{
    free(s);
}

int gpiod_line_settings_set_direction(struct gpiod_line_settings *s, int direction)
{
    if (direction < 1 || direction > 3)
        return misuse("direction", EINVAL);
    s->direction = direction;
    return 0;
}

int gpiod_line_settings_set_output_value(struct gpiod_line_settings *s, int value)
{
    if (value != 0 && value != 1)
        return misuse("value", EINVAL);
    s->value = value;
    return 0;
}

struct gpiod_line_config *gpiod_line_config_new(void)
{
    return (struct gpiod_line_config *)calloc(1, sizeof(struct gpiod_line_config));
}

void gpiod_line_config_free(struct gpiod_line_config *c)
{
    free(c);
}

int gpiod_line_config_add_line_settings(struct gpiod_line_config *c, const unsigned int *offsets,
                                        size_t n, struct gpiod_line_settings *s)
{
    if (n != 1 || c->n != 0)
        return misuse("lines", EINVAL);
    c->offset = offsets[0];
    c->direction = s->direction;
    c->value = s->value;
    c->n = 1;
    return 0;
}

struct gpiod_request_config *gpiod_request_config_new(void)
{
    return (struct gpiod_request_config *)calloc(1, sizeof(struct gpiod_request_config));
}

void gpiod_request_config_free(struct gpiod_request_config *r)
{
    free(r);
}

void gpiod_request_config_set_consumer(struct gpiod_request_config *r, const char *consumer)
{
    snprintf(r->consumer, sizeof r->consumer, "%s", consumer);
}

struct gpiod_line_request *gpiod_chip_request_lines(struct gpiod_chip *chip,
                                                    struct gpiod_request_config *r,
                                                    struct gpiod_line_config *c)
{
    struct gpiod_line_request *req;
    pthread_mutex_lock(&lock);
    init();
    pthread_mutex_unlock(&lock);
    if (chip != &the_chip || c->n != 1 || c->direction != DIRECTION_OUTPUT) {
        misuse("request", EINVAL);
        return NULL;
    }
    if (c->offset >= DOUBLE_LINES) {
        errno = EINVAL;
        return NULL;
    }
    if ((req = (struct gpiod_line_request *)calloc(1, sizeof *req)) == NULL)
        return NULL;
    req->offset = c->offset;
    record(now_us(), "gpioreq %s %u %d v2", r->consumer[0] ? r->consumer : "?", c->offset,
           c->value);
    return req;
}

int gpiod_line_request_set_value(struct gpiod_line_request *req, unsigned int offset, int value)
{
    if (offset != req->offset)
        return misuse("set-offset", EINVAL);
    if (value != 0 && value != 1)
        return misuse("value", EINVAL);
    record(now_us(), "gpio %d", value);
    return 0;
}

void gpiod_line_request_release(struct gpiod_line_request *req)
{
    free(req);
}
#endif
