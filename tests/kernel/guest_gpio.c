/*
 * guest_gpio.c - the kernel test bed's program for GPIO direction control (tests/kernel,
 * test_gpio.py): runs in the guest, where the bed's setup made a gpio-sim chip (configfs), and
 * drives one of its lines through the shims and the real libgpiod around requests to the
 * simulator on the host end of PORT; the line's level is read back from gpio-sim's sysfs.
 *
 *   guest-gpio PORT SIMDIR CHIP LINE LIB...
 * SIMDIR is the chip's configfs folder (/sys/kernel/config/gpio-sim/NAME; its dev_name and
 * bank0/chip_name give the sysfs folder of the line), CHIP what the bus names it by (its label).
 * For each LIB (a libgpiod's path) and each polarity, a child process with LD_PRELOAD=LIB runs
 * one case (the shims use a libgpiod already loaded, so the case runs on that one):
 *   the line's level before the bus opens; the bus opened with Direction GPIO and one read;
 *   the level at idle and the line's consumer (debugfs); N_READS reads while a thread samples
 *   the level, counting its pulses to the sending level; the bus shut down, and the level and
 *   consumer after the line was released.
 * Lines: "RESULT gpio LIB active_low=A opened=RC reads=OK before=L idle=L consumer=C
 *         pulses=P released=L consumer_after=C mapped=LIBS" (LIBS: the libgpiod files mapped
 *         into the process once the bus was open).
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "guest_bed.h"
#include "mbfb.h"

#define N_READS 6
#define SAMPLE_US 200 /* a 9600-baud request keeps the line up for more than 9 ms */

static char value_path[256];
static int sampling, sampled; /* sampler: run / has taken its first sample */
static int pulses, sending_level;

/* The line's level from gpio-sim's sysfs (sim_gpioN/value), or -1. */
static int level(void)
{
    char b[4] = {0};
    int fd = open(value_path, O_RDONLY), n = fd >= 0 ? (int)read(fd, b, sizeof b - 1) : -1;
    if (fd >= 0)
        close(fd);
    return n > 0 ? b[0] - '0' : -1;
}

/* The first word of a one-line file (configfs attributes), into out. */
static int first_word(const char *dir, const char *name, char *out, size_t n)
{
    char p[256];
    FILE *f;
    snprintf(p, sizeof p, "%s/%s", dir, name);
    if ((f = fopen(p, "r")) == NULL)
        return -1;
    int ok = fscanf(f, "%63s", out) == 1 && strlen(out) < n;
    fclose(f);
    return ok ? 0 : -1;
}

/* The consumer of offset `line` of chip `chip_name` in debugfs ("mbfb"), or "none". The
 * chip's header names its first number: "gpiochip0: GPIOs 512-543, ..."; a requested line:
 * " gpio-529 (                    |mbfb                ) out lo". */
static void consumer_of(const char *chip_name, int line, char *out, size_t n)
{
    char row[256];
    size_t k = strlen(chip_name);
    int base = -1, num;
    FILE *f = fopen("/sys/kernel/debug/gpio", "r");

    snprintf(out, n, "none");
    if (f == NULL)
        return;
    while (fgets(row, sizeof row, f) != NULL) {
        if (strncmp(row, "gpiochip", 8) == 0) {
            base = -1;
            if (strncmp(row, chip_name, k) == 0 && row[k] == ':' &&
                sscanf(row + k + 1, " GPIOs %d", &base) != 1)
                base = -1;
        } else if (base >= 0 && sscanf(row, " gpio-%d", &num) == 1 && num == base + line) {
            char *bar = strchr(row, '|'), *end = bar != NULL ? strchr(bar, ')') : NULL;
            if (end == NULL)
                continue;
            while (end > bar + 1 && end[-1] == ' ')
                end--;
            *end = 0;
            if (bar[1] != 0)
                snprintf(out, n, "%s", bar + 1);
        }
    }
    fclose(f);
}

/* The libgpiod files mapped into this process, comma-separated ("libgpiod.so.3"), or "none". */
static void mapped_libgpiod(char *out, size_t n)
{
    char row[512];
    size_t len = 0;
    FILE *f = fopen("/proc/self/maps", "r");
    out[0] = 0;
    while (f != NULL && fgets(row, sizeof row, f) != NULL) {
        char *name = strrchr(row, '/');
        if (name == NULL || strncmp(name + 1, "libgpiod.so", 11) != 0)
            continue;
        name[strcspn(name, "\n")] = 0;
        if (strstr(out, name + 1) == NULL && len + strlen(name + 1) + 2 < n)
            len += (size_t)snprintf(out + len, n - len, "%s%s", len ? "," : "", name + 1);
    }
    if (f != NULL)
        fclose(f);
    if (out[0] == 0)
        snprintf(out, n, "none");
}

static void *sampler(void *arg)
{
    int last = level();
    (void)arg;
    __atomic_store_n(&sampled, 1, __ATOMIC_RELEASE);
    while (__atomic_load_n(&sampling, __ATOMIC_ACQUIRE)) {
        int l = level();
        if (l == sending_level && last != sending_level)
            pulses++;
        last = l;
        usleep(SAMPLE_US);
    }
    return NULL;
}

static int finish(int req)
{
    if (req < 0)
        return req;
    while (mbfb_poll(req) == MBFB_REQ_QUEUED || mbfb_poll(req) == MBFB_REQ_ACTIVE)
        usleep(1000);
    int rc = mbfb_take(req, NULL, 0);
    return rc < 0 ? rc : 0;
}

static int one_case(const char *port, const char *simdir, const char *chip, int line,
                    const char *lib, int active_low)
{
    char dev[64], chip_name[64], cons[64], cons_after[64], bank[300], mapped[128];
    mbfb_bus_config_t c;
    pthread_t t;
    int ok = 0, before, idle, released, bus, dev_h, opened;

    snprintf(bank, sizeof bank, "%s/bank0", simdir);
    if (first_word(simdir, "dev_name", dev, sizeof dev) != 0 ||
        first_word(bank, "chip_name", chip_name, sizeof chip_name) != 0) {
        printf("RESULT gpio %s active_low=%d error=no-gpio-sim\n", lib, active_low);
        return 1;
    }
    snprintf(value_path, sizeof value_path, "/sys/devices/platform/%s/%s/sim_gpio%d/value",
             dev, chip_name, line);
    before = level();

    memset(&c, 0, sizeof c);
    c.port = port;
    c.baud = 9600;
    c.parity = 'N';
    c.data_bits = 8;
    c.stop_bits = 2;
    c.framing = MBFB_FRAMING_RTU;
    c.response_timeout_ms = BED_TIMEOUT_MS;
    c.retries = -1;
    c.direction = MBFB_DIR_GPIO;
    c.dir_active_low = active_low;
    snprintf(c.gpio_chip, sizeof c.gpio_chip, "%s", chip);
    c.gpio_line = line;
    bus = mbfb_bus_open(&c);
    dev_h = mbfb_dev_open(bus, 1);
    opened = finish(mbfb_post(dev_h, MBFB_FC_READ_INPUT, 0x1000, 1, NULL)); /* the port opens */
    idle = level();
    consumer_of(chip_name, line, cons, sizeof cons);
    mapped_libgpiod(mapped, sizeof mapped);

    sending_level = !active_low;
    __atomic_store_n(&sampling, 1, __ATOMIC_RELEASE);
    pthread_create(&t, NULL, sampler, NULL);
    while (!__atomic_load_n(&sampled, __ATOMIC_ACQUIRE))
        usleep(100); /* the line at idle seen before the first request */
    for (int i = 0; i < N_READS; i++) {
        ok += finish(mbfb_post(dev_h, MBFB_FC_READ_INPUT, 0x1000, 1, NULL)) == 0;
        usleep(20000); /* the line at rest between requests, for the sampler to see */
    }
    __atomic_store_n(&sampling, 0, __ATOMIC_RELEASE);
    pthread_join(t, NULL);
    mbfb_shutdown();
    released = level();
    consumer_of(chip_name, line, cons_after, sizeof cons_after);
    printf("RESULT gpio %s active_low=%d opened=%d reads=%d before=%d idle=%d consumer=%s "
           "pulses=%d released=%d consumer_after=%s mapped=%s\n",
           lib, active_low, -opened, ok, before, idle, cons, pulses, released, cons_after,
           mapped);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 8 && strcmp(argv[1], "--case") == 0)
        return one_case(argv[2], argv[3], argv[4], atoi(argv[5]), argv[6], atoi(argv[7]));
    if (argc < 6) {
        fprintf(stderr, "usage: guest-gpio PORT SIMDIR CHIP LINE LIB...\n");
        return 2;
    }
    for (int i = 5; i < argc; i++)
        for (int low = 0; low <= 1; low++) {
            pid_t pid;
            fflush(stdout);
            if ((pid = fork()) == 0) {
                char lowarg[4];
                snprintf(lowarg, sizeof lowarg, "%d", low);
                setenv("LD_PRELOAD", argv[i], 1);
                execl("/proc/self/exe", argv[0], "--case", argv[1], argv[2], argv[3], argv[4],
                      argv[i], lowarg, (char *)NULL);
                _exit(127);
            }
            waitpid(pid, NULL, 0);
        }
    return 0;
}
