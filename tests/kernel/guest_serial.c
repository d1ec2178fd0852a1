/*
 * guest_serial.c - the kernel test bed's program for the serial drivers (tests/kernel): runs
 * in the guest on the public shims API (mbfb.h) against the simulator on the host end of each
 * port, and prints one line per finding for test_serial.py to check against QEMU's trace.
 *
 *   guest-serial STEP...   each STEP is  what:port:sim[:arguments,...]
 *     devices:PORT:SIM     the simulator's devices (tests/kernel/test_serial.py starts them:
 *                          MV-D94 1, VD 2, FDC 3, MT-S9 4 in RTU; MT-S9 5 in ASCII, 6 in RTU
 *                          without CRC): each read,
 *                          a set point written (Done) and read back, device 1 pulled and back
 *     bauds:PORT:SIM:B,... one bus per baud: the open's result and one read
 *     kernel:PORT:SIM      Direction KERNEL: the result, and the simulator heard nothing
 *     rts:PORT:SIM:BAUD:BEFORE:AFTER:N   Direction RTS, N reads between marks
 *     rs485:PORT:SIM:BAUD:BEFORE:AFTER:N Direction KERNEL, N reads between marks, and the
 *                          driver's RS-485 settings (TIOCGRS485) while the shims hold the port
 *     fb:NAME:SIM:PORT:BAUD  the fb test program /bin/NAME (tests/fb, cross-built) against
 *                          simulator SIM restarted with NAME's devices (the bed's set NAME):
 *                          its port, the simulator's control through the control line
 *     latency:PORT:SIM     the low-latency flag and ftdi_sio's latency_timer once open
 *     bench:PORT:SIM:N     N one-register reads, the elapsed time (bench/kernel_wire.py)
 *     write:PATH:VALUE     write VALUE to a sysfs file (e.g. a UART's rx_trig_bytes)
 * Lines: "RESULT what port key=value ...". The control line (MBFB_BED_CTL: /dev/ttyS2 on the
 * PC guest, /dev/hvc1 on the ARM ones; bed.py) carries the marks and the simulator requests.
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <linux/serial.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "guest_bed.h"
#include "mbfb.h"
#include "mbfb_test.h" /* t_cfg, t_wait, t_now_us (tests/shims/mbfb_test_peer.c) */

static int ctl_fd = -1;

/* One request on the control line, its answer into reply (may be NULL). */
static int control(const char *req, char *reply, size_t n)
{
    char buf[16384]; /* a simulator's stats of five devices: about 2 KB */
    size_t len = 0;

    if (ctl_fd < 0) {
        struct termios t;
        const char *path = getenv("MBFB_BED_CTL");
        if ((ctl_fd = open(path != NULL && *path ? path : "/dev/ttyS2", O_RDWR | O_NOCTTY)) < 0)
            return -1;
        tcgetattr(ctl_fd, &t);
        cfmakeraw(&t);
        cfsetspeed(&t, B115200);
        t.c_cc[VMIN] = 1;
        t.c_cc[VTIME] = 0;
        tcsetattr(ctl_fd, TCSANOW, &t);
    }
    if (write(ctl_fd, req, strlen(req)) < 0 || write(ctl_fd, "\n", 1) < 0)
        return -1;
    for (;;) { /* the whole line, whatever its length: the next answer starts after it */
        ssize_t r = read(ctl_fd, buf + len, 1);
        if (r <= 0)
            return -1;
        if (buf[len] == '\n')
            break;
        if (len < sizeof buf - 1)
            len++;
    }
    buf[len] = '\0';
    if (reply != NULL && n > 0) {
        size_t k = len < n - 1 ? len : n - 1;
        memcpy(reply, buf, k);
        reply[k] = '\0';
    }
    return 0;
}

static void mark(const char *what, const char *port)
{
    char req[256];
    snprintf(req, sizeof req, "{\"mark\": \"%s %s\"}", what, port);
    control(req, NULL, 0);
}

static void sim_offline(int sim, int addr, int on)
{
    char req[256];
    snprintf(req, sizeof req, "{\"sim\": %d, \"op\": \"offline\", \"addr\": %d, \"on\": %s}", sim,
             addr, on ? "true" : "false");
    control(req, NULL, 0);
}

/* Wait for a request (mbfb_test_peer.c's t_wait): its result (0 or a negative error),
 * values into v. */
static int finish(int req, uint16_t *v, int max)
{
    if (req < 0)
        return req;
    t_wait(req);
    int rc = mbfb_take(req, v, max);
    return rc < 0 ? rc : 0;
}

/* A device pulled is probed every 10 response timeouts (the shims' MBFB_PROBE_SHARE) once
 * it is back: it answers within this. */
#define BACK_WITHIN_MS (15 * BED_TIMEOUT_MS)

/* The bed's lines: 8N2 (the MV-D94's format), BED_TIMEOUT_MS, the default retries. */
static int open_bus(const char *port, int baud, int framing, int direction, int before,
                    int after)
{
    mbfb_bus_config_t c = t_cfg(port, baud, framing, BED_TIMEOUT_MS, -1);
    c.stop_bits = 2;
    c.direction = direction;
    c.dir_before_us = before;
    c.dir_after_us = after;
    return mbfb_bus_open(&c);
}

/* One device: read `count` from `addr`, write `val` (fc, policy) and read it back. */
static void device_case(const char *port, int bus, const char *name, int slave, int addr,
                        int count, int fc, int policy, const uint16_t *given, int nval)
{
    int dev = mbfb_dev_open(bus, slave);
    uint16_t v[8] = {0}, back[8] = {0}, val[2] = {0, 0};
    int rd = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, addr, count, NULL), v, 8);
    if (given != NULL)
        memcpy(val, given, sizeof val[0] * (size_t)nval);
    else
        val[0] = (uint16_t)(v[0] + 10); /* a set point near the one it holds: in its limits */
    int wr = finish(mbfb_post_write(dev, fc, addr, nval, val, policy), NULL, 0);
    int rb = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, addr, nval, NULL), back, 8);
    printf("RESULT devices %s device=%s slave=%d read=%d first=%u write=%d readback=%d "
           "back=%u asked=%u\n",
           port, name, slave, -rd, v[0], -wr, -rb, back[0], val[0]);
}

static void devices(const char *port, int sim)
{
    static const uint16_t sv[1] = {1234}, preset[2] = {4321, 0};
    int bus = open_bus(port, 9600, MBFB_FRAMING_RTU, MBFB_DIR_NONE, 0, 0);

    device_case(port, bus, "mvd94", 1, 0, 4, MBFB_FC_WRITE_SINGLE, MBFB_WRITE_IDEMPOTENT, sv, 1);
    device_case(port, bus, "vd", 2, 0, 4, MBFB_FC_WRITE_SINGLE, MBFB_WRITE_IDEMPOTENT, sv, 1);
    device_case(port, bus, "fdc100", 3, 0, 4, MBFB_FC_WRITE_SINGLE, MBFB_WRITE_IDEMPOTENT, NULL,
                1);
    device_case(port, bus, "mts9-rtu", 4, 0, 2, MBFB_FC_WRITE_MULTIPLE, MBFB_WRITE_ONCE, preset,
                2);
    /* pulled and back: reads fail while the simulator keeps device 1 silent, then recover */
    int dev = mbfb_dev_open(bus, 1), gone, back = -1;
    sim_offline(sim, 1, 1);
    gone = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0);
    sim_offline(sim, 1, 0);
    int64_t t0 = t_now_us();
    while (t_now_us() - t0 < (int64_t)BACK_WITHIN_MS * 1000 &&
           (back = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0)) != 0)
        usleep(100000);
    printf("RESULT devices %s device=mvd94 pulled=%d back=%d back_ms=%d\n", port, -gone, -back,
           (int)((t_now_us() - t0) / 1000));
    mbfb_shutdown();
    bus = open_bus(port, 9600, MBFB_FRAMING_ASCII, MBFB_DIR_NONE, 0, 0);
    device_case(port, bus, "mts9-ascii", 5, 0, 2, MBFB_FC_WRITE_MULTIPLE, MBFB_WRITE_ONCE,
                preset, 2);
    mbfb_shutdown();
    bus = open_bus(port, 9600, MBFB_FRAMING_RTU_NOCRC, MBFB_DIR_NONE, 0, 0);
    device_case(port, bus, "mts9-nocrc", 6, 0, 2, MBFB_FC_WRITE_MULTIPLE, MBFB_WRITE_ONCE,
                preset, 2);
    mbfb_shutdown();
}

/* The bytes simulator `sim` has heard on its line so far (its line statistics). */
static long sim_rx_bytes(int sim)
{
    char req[128], reply[256];
    const char *p;
    snprintf(req, sizeof req, "{\"sim\": %d, \"op\": \"stats\"}", sim);
    if (control(req, reply, sizeof reply) != 0 || (p = strstr(reply, "\"rx_bytes\": ")) == NULL)
        return -1;
    return atol(p + strlen("\"rx_bytes\": "));
}

static void bauds(const char *port, int sim, const char *list)
{
    char *copy = strdup(list), *save = NULL;
    for (char *b = strtok_r(copy, ",", &save); b != NULL; b = strtok_r(NULL, ",", &save)) {
        int baud = atoi(b);
        char what[64];
        snprintf(what, sizeof what, "baud %d", baud);
        long heard = sim_rx_bytes(sim);
        mark(what, port);
        int bus = open_bus(port, baud, MBFB_FRAMING_RTU, MBFB_DIR_NONE, 0, 0);
        int rc = finish(mbfb_post(mbfb_dev_open(bus, 1), MBFB_FC_READ_HOLDING, 0, 1, NULL),
                        NULL, 0);
        usleep(100000); /* anything sent has reached the simulator by now */
        printf("RESULT bauds %s asked=%d rc=%d sim_heard=%ld\n", port, baud, -rc,
               sim_rx_bytes(sim) - heard);
        fflush(stdout);
        mbfb_shutdown();
    }
    mark("baud end", port);
    free(copy);
}

static void kernel_mode(const char *port, int sim)
{
    long heard = sim_rx_bytes(sim);
    mark("kernel", port);
    int bus = open_bus(port, 9600, MBFB_FRAMING_RTU, MBFB_DIR_KERNEL, 0, 0);
    int rc = finish(mbfb_post(mbfb_dev_open(bus, 1), MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0);
    usleep(200000); /* anything sent would have reached the simulator by now */
    printf("RESULT kernel %s rc=%d sim_heard=%ld\n", port, -rc, sim_rx_bytes(sim) - heard);
    mbfb_shutdown();
    mark("kernel-end", port);
}

static void rts(const char *port, int baud, int before, int after, int n)
{
    int bus = open_bus(port, baud, MBFB_FRAMING_RTU, MBFB_DIR_RTS, before, after);
    int dev = mbfb_dev_open(bus, 1), good = 0, rc;
    rc = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0); /* opened */
    mark("rts", port);
    for (int i = 0; i < n; i++)
        good += finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0) == 0;
    mark("rts-end", port);
    printf("RESULT rts %s baud=%d before=%d after=%d open=%d good=%d of=%d\n", port, baud,
           before, after, -rc, good, n);
    mbfb_shutdown();
}

static void rs485(const char *port, int baud, int before, int after, int n)
{
    int bus = open_bus(port, baud, MBFB_FRAMING_RTU, MBFB_DIR_KERNEL, before, after);
    int dev = mbfb_dev_open(bus, 1), good = 0, rc;
    rc = finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0); /* opened */
    /* a second descriptor on the same tty sees the driver's settings */
    struct serial_rs485 rs;
    int fd = open(port, O_RDWR | O_NOCTTY | O_NONBLOCK), got = -1;
    memset(&rs, 0, sizeof rs);
    if (fd >= 0) {
        got = ioctl(fd, TIOCGRS485, &rs);
        close(fd);
    }
    mark("rs485", port);
    for (int i = 0; i < n; i++)
        good += finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0) == 0;
    mark("rs485-end", port);
    printf("RESULT rs485 %s baud=%d before=%d after=%d open=%d good=%d of=%d ioctl=%d "
           "enabled=%d on_send=%d after_send=%d delay_before_ms=%u delay_after_ms=%u\n",
           port, baud, before, after, -rc, good, n, got, (rs.flags & SER_RS485_ENABLED) != 0,
           (rs.flags & SER_RS485_RTS_ON_SEND) != 0, (rs.flags & SER_RS485_RTS_AFTER_SEND) != 0,
           rs.delay_rts_before_send, rs.delay_rts_after_send);
    mbfb_shutdown();
}

/* An fb test program (tests/fb/fbtest.h's hooks): the simulator restarted with its devices,
 * the program run to its end with its port and the control line, its exit status. */
static void fb_program(const char *name, int sim, const char *port, const char *baud)
{
    char req[256], reply[256], path[128];
    const char *ctl = getenv("MBFB_BED_CTL");
    snprintf(req, sizeof req, "{\"restart\": %d, \"set\": \"%s\"}", sim, name);
    int ok = control(req, reply, sizeof reply) == 0 && strstr(reply, "\"ok\": true") != NULL;
    snprintf(path, sizeof path, "/bin/%s", name);
    int64_t t0 = t_now_us();
    pid_t pid = ok ? fork() : -1;
    if (pid == 0) {
        setenv("MBFB_TEST_PORT", port, 1);
        setenv("MBFB_SIM_CONTROL", ctl != NULL && *ctl ? ctl : "/dev/ttyS2", 1);
        setenv("MBFB_TEST_BAUD", baud, 1);
        execl(path, path, (char *)NULL);
        _exit(127);
    }
    int status = 0, rc = -1;
    if (pid > 0 && waitpid(pid, &status, 0) == pid && WIFEXITED(status))
        rc = WEXITSTATUS(status);
    printf("RESULT fb %s program=%s restarted=%d rc=%d ms=%lld\n", port, name, ok, rc,
           (long long)((t_now_us() - t0) / 1000));
}

/* ftdi_sio's latency timer in ms (sysfs), -1 where the port has none. */
static int latency_timer(const char *port)
{
    char path[128];
    int timer = -1;
    snprintf(path, sizeof path, "/sys/bus/usb-serial/devices/%s/latency_timer",
             strrchr(port, '/') + 1);
    FILE *f = fopen(path, "r");
    if (f != NULL) {
        if (fscanf(f, "%d", &timer) != 1)
            timer = -1;
        fclose(f);
    }
    return timer;
}

static void latency(const char *port)
{
    int before = latency_timer(port);
    int bus = open_bus(port, 9600, MBFB_FRAMING_RTU, MBFB_DIR_NONE, 0, 0);
    int rc = finish(mbfb_post(mbfb_dev_open(bus, 1), MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0);
    /* a second descriptor on the same tty sees the driver's settings */
    int fd = open(port, O_RDWR | O_NOCTTY | O_NONBLOCK), low = -1;
    struct serial_struct ss;
    if (fd >= 0 && ioctl(fd, TIOCGSERIAL, &ss) == 0)
        low = (ss.flags & ASYNC_LOW_LATENCY) != 0;
    printf("RESULT latency %s read=%d low_latency=%d latency_timer_ms=%d before_open_ms=%d\n",
           port, -rc, low, latency_timer(port), before);
    if (fd >= 0)
        close(fd);
    mbfb_shutdown();
}

static void bench(const char *port, int n)
{
    int bus = open_bus(port, 9600, MBFB_FRAMING_RTU, MBFB_DIR_NONE, 0, 0);
    int dev = mbfb_dev_open(bus, 1), good = 0;
    finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0); /* opened */
    int64_t t0 = t_now_us();
    for (int i = 0; i < n; i++)
        good += finish(mbfb_post(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL), NULL, 0) == 0;
    printf("RESULT bench %s n=%d good=%d elapsed_us=%lld\n", port, n, good,
           (long long)(t_now_us() - t0));
    mbfb_shutdown();
}

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    for (int i = 1; i < argc; i++) {
        char *save = NULL, *what = strtok_r(argv[i], ":", &save);
        char *port = strtok_r(NULL, ":", &save), *simno = strtok_r(NULL, ":", &save);
        char *a[5] = {NULL};
        for (int k = 0; k < 5; k++)
            a[k] = strtok_r(NULL, ":", &save);
        if (what == NULL || port == NULL || simno == NULL) {
            fprintf(stderr, "guest-serial: bad step %s\n", argv[i]);
            return 2;
        }
        if (strcmp(what, "write") == 0) { /* write:PATH:VALUE */
            FILE *f = fopen(port, "w");
            int ok = f != NULL && fputs(simno, f) >= 0;
            if (f != NULL && fclose(f) != 0)
                ok = 0;
            printf("RESULT write %s value=%s ok=%d\n", port, simno, ok);
            continue;
        }
        int sim = atoi(simno);
        if (strcmp(what, "devices") == 0)
            devices(port, sim);
        else if (strcmp(what, "bauds") == 0 && a[0])
            bauds(port, sim, a[0]);
        else if (strcmp(what, "kernel") == 0)
            kernel_mode(port, sim);
        else if (strcmp(what, "rts") == 0 && a[3])
            rts(port, atoi(a[0]), atoi(a[1]), atoi(a[2]), atoi(a[3]));
        else if (strcmp(what, "rs485") == 0 && a[3])
            rs485(port, atoi(a[0]), atoi(a[1]), atoi(a[2]), atoi(a[3]));
        else if (strcmp(what, "fb") == 0 && a[1])
            fb_program(port, sim, a[0], a[1]);
        else if (strcmp(what, "latency") == 0)
            latency(port);
        else if (strcmp(what, "bench") == 0 && a[0])
            bench(port, atoi(a[0]));
        else {
            fprintf(stderr, "guest-serial: unknown step %s\n", what);
            return 2;
        }
    }
    return 0;
}
