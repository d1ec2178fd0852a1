/*
 * mbfb_bus.c - setup and teardown: the bus and device registry.
 *
 * Setup calls take a mutex (they may allocate and start a thread); the scan-side
 * calls never do: they read the registry through pointers published with release
 * stores, which stay valid until mbfb_shutdown.
 */
#include <limits.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "mbfb_internal.h"

mbfb_bus_t *mbfb_buses[MBFB_MAX_BUSES];
mbfb_dev_t *mbfb_devs[MBFB_MAX_DEVICES];
mbfb_plan_t *mbfb_plans[MBFB_MAX_PLANS];

pthread_mutex_t mbfb_registry_lock = PTHREAD_MUTEX_INITIALIZER;
static uint32_t slot_epoch; /* first generation of a new bus's slots (under the lock) */

/* Start the bus's worker as an ordinary (SCHED_OTHER) thread. A thread created from
 * OpenPLC's scan thread would otherwise inherit its SCHED_FIFO real-time priority, and bus
 * I/O must never compete with the scan: the scan never waits on the worker, while a worker
 * delayed by the scan only leaves a longer gap on the line, which is always allowed. */
static int start_worker(mbfb_bus_t *bus)
{
    pthread_attr_t attr;
    struct sched_param prio;
    int rc;

    memset(&prio, 0, sizeof prio);
    if (pthread_attr_init(&attr) != 0)
        return -1;
    rc = pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED) != 0 ||
         pthread_attr_setschedpolicy(&attr, SCHED_OTHER) != 0 ||
         pthread_attr_setschedparam(&attr, &prio) != 0 ||
         pthread_create(&bus->worker, &attr, mbfb_worker_main, bus) != 0;
    pthread_attr_destroy(&attr);
    return rc ? -1 : 0;
}

/* "tcp://..." ports: Modbus TCP, or RTU over TCP with Framing RTU. */
static int is_tcp(const char *port)
{
    return strncmp(port, "tcp://", 6) == 0;
}

/* Check and normalise a configuration. 0, MBFB_E_INVAL or MBFB_E_BAUD. */
static int normalise(mbfb_bus_config_t *c)
{
    if (c->port == NULL || c->port[0] == 0 || strlen(c->port) > 255)
        return MBFB_E_INVAL;
    if (c->framing < MBFB_FRAMING_RTU || c->framing > MBFB_FRAMING_TCP)
        return MBFB_E_INVAL;
    /* tcp:// carries Modbus TCP or RTU (over TCP); Modbus TCP needs tcp:// */
    if (is_tcp(c->port) ? c->framing != MBFB_FRAMING_TCP && c->framing != MBFB_FRAMING_RTU
                        : c->framing == MBFB_FRAMING_TCP)
        return MBFB_E_INVAL;
    if (c->retries < 0)
        c->retries = MBFB_DEFAULT_RETRIES;
    if (c->retries > MBFB_MAX_RETRIES || c->response_timeout_ms < 0 ||
        c->response_timeout_ms > MBFB_MAX_TIMEOUT_MS)
        return MBFB_E_INVAL;
    if (c->direction < MBFB_DIR_NONE || c->direction > MBFB_DIR_GPIO ||
        (c->direction != MBFB_DIR_NONE && is_tcp(c->port)) || /* the gateway switches */
        c->dir_before_us < 0 || c->dir_before_us > MBFB_DIR_MAX_DELAY_US ||
        c->dir_after_us < 0 || c->dir_after_us > MBFB_DIR_MAX_DELAY_US)
        return MBFB_E_INVAL;
    c->dir_active_low = c->dir_active_low != 0;
    c->gpio_chip[MBFB_GPIO_CHIP_MAX - 1] = 0;
    if (c->direction == MBFB_DIR_GPIO && (c->gpio_chip[0] == 0 || c->gpio_line < 0))
        return MBFB_E_INVAL; /* GPIO needs its chip and line */
    if (c->direction != MBFB_DIR_GPIO) { /* ignored: equal for the conflict check */
        memset(c->gpio_chip, 0, sizeof c->gpio_chip);
        c->gpio_line = 0;
    }
    if (c->direction == MBFB_DIR_NONE)
        c->dir_active_low = c->dir_before_us = c->dir_after_us = 0;
    if (c->baud < 0)
        return MBFB_E_INVAL;
    if (c->parity == 'n' || c->parity == 'e' || c->parity == 'o')
        c->parity = (char)(c->parity - 'a' + 'A');
    if (c->framing == MBFB_FRAMING_TCP) { /* line settings unused; baud only for timing */
        /* unused, but a setting given (not 0) must still be one a line can have */
        if ((c->parity != 0 && c->parity != 'N' && c->parity != 'E' && c->parity != 'O') ||
            (c->stop_bits != 0 && c->stop_bits != 1 && c->stop_bits != 2) ||
            (c->data_bits != 0 && c->data_bits != 8))
            return MBFB_E_INVAL;
        c->baud = c->baud > 0 ? c->baud : 9600;
        c->parity = 'N';
        c->data_bits = 8;
        c->stop_bits = 1;
        return 0;
    }
    if (c->baud == 0 || (c->parity != 'N' && c->parity != 'E' && c->parity != 'O') ||
        (c->stop_bits != 1 && c->stop_bits != 2) ||
        (c->data_bits != 8 && !(c->data_bits == 7 && c->framing == MBFB_FRAMING_ASCII)))
        return MBFB_E_INVAL; /* RTU is binary: 8 data bits */
    if (c->baud > MBFB_MAX_BAUD)
        return MBFB_E_BAUD; /* any other rate is set exactly when the port opens (or 14) */
    return 0;
}

/* The path with '//' collapsed and '.' segments removed (a port that does not exist
 * yet cannot be resolved). */
static void normal_path(const char *in, char *out, size_t n)
{
    size_t k = 0;
    while (*in && k + 1 < n) {
        if (in[0] == '/' && (in[1] == '/' || (in[1] == '.' && (in[2] == '/' || !in[2])))) {
            in += in[1] == '/' ? 1 : 2;
            continue;
        }
        out[k++] = *in++;
    }
    if (k > 1 && out[k - 1] == '/')
        k--;
    out[k] = 0;
}

/* Identity of a port (README "Port identity"): the node it opens. A character device
 * by its device number, another file by device + inode, a path that does not resolve
 * by its normalised text, tcp:// by its text. */
static void port_key(const char *port, char *key, size_t n)
{
    char real[PATH_MAX], norm[PATH_MAX];
    struct stat st;

    if (is_tcp(port)) {
        snprintf(key, n, "%s", port);
    } else if (realpath(port, real) != NULL && stat(real, &st) == 0) {
        if (S_ISCHR(st.st_mode))
            snprintf(key, n, "chr:%llu", (unsigned long long)st.st_rdev);
        else
            snprintf(key, n, "ino:%llu:%llu", (unsigned long long)st.st_dev,
                     (unsigned long long)st.st_ino);
    } else {
        normal_path(port, norm, sizeof norm);
        snprintf(key, n, "path:%s", norm);
    }
}

/* Same line settings (the port is compared by key). */
static int same_settings(const mbfb_bus_config_t *a, const mbfb_bus_config_t *b)
{
    return a->baud == b->baud && a->parity == b->parity && a->data_bits == b->data_bits &&
           a->stop_bits == b->stop_bits && a->framing == b->framing &&
           a->response_timeout_ms == b->response_timeout_ms && a->retries == b->retries &&
           a->direction == b->direction && a->dir_active_low == b->dir_active_low &&
           a->dir_before_us == b->dir_before_us && a->dir_after_us == b->dir_after_us &&
           strcmp(a->gpio_chip, b->gpio_chip) == 0 && a->gpio_line == b->gpio_line;
}

/* The backend table of a framing on a port. */
static const mbfb_backend_t *backend_for(int framing, const char *port)
{
    if (framing == MBFB_FRAMING_RTU && is_tcp(port))
        return &mbfb_backend_rtutcp;
    switch (framing) {
    case MBFB_FRAMING_ASCII:     return &mbfb_backend_ascii;
    case MBFB_FRAMING_RTU_NOCRC: return &mbfb_backend_nocrc;
    case MBFB_FRAMING_TCP:       return &mbfb_backend_tcp;
    default:                     return &mbfb_backend_rtu;
    }
}

/* Free a bus (its worker has stopped). */
static void bus_free(mbfb_bus_t *bus)
{
    mbfb_wake_close(bus);
    free(bus->port);
    free(bus->key);
    free(bus);
}

/* Allocate a bus and start its worker. Called with the registry lock held. */
static int bus_create(int index, const mbfb_bus_config_t *c, const char *key)
{
    mbfb_bus_t *bus = (mbfb_bus_t *)calloc(1, sizeof *bus);
    size_t n = strlen(c->port) + 1, kn = strlen(key) + 1;

    if (bus == NULL || (bus->port = (char *)malloc(n)) == NULL ||
        (bus->key = (char *)malloc(kn)) == NULL) {
        if (bus != NULL)
            free(bus->port);
        free(bus);
        return -MBFB_E_NOMEM;
    }
    memcpy(bus->port, c->port, n);
    memcpy(bus->key, key, kn);
    bus->cfg = *c;
    bus->cfg.port = bus->port;
    bus->be = backend_for(c->framing, c->port);
    mbfb_timing_init(&bus->timing, c->baud, c->parity, c->data_bits, c->stop_bits);
    if (c->framing == MBFB_FRAMING_TCP)
        bus->timing.gap_us = 0; /* the gateway paces its serial line */
    else if (is_tcp(c->port))
        bus->timing.net_us = MBFB_NET_ALLOWANCE_US; /* RTU over TCP: the network leg */
    bus->fd = -1;
    bus->wake_fd = -1;
    bus->index = index;
    slot_epoch += 4096; /* handles from before a shutdown stay stale */
    for (int i = 0; i < MBFB_MAX_SLOTS; i++)
        bus->slots[i].state = (slot_epoch & MBFB_GEN_MASK) << 4;
    if (mbfb_wake_open(bus) != 0 || start_worker(bus) != 0) {
        bus_free(bus);
        return -MBFB_E_NOMEM;
    }
    __atomic_store_n(&mbfb_buses[index], bus, __ATOMIC_RELEASE);
    return index;
}

/* Open or join the bus of cfg->port (by identity); see mbfb.h. */
int mbfb_bus_open(const mbfb_bus_config_t *cfg)
{
    mbfb_bus_config_t c;
    char key[PATH_MAX + 32];
    int rc = -MBFB_E_NOMEM, free_index = -1;

    if (cfg == NULL)
        return -MBFB_E_INVAL;
    c = *cfg;
    if ((rc = normalise(&c)) != 0)
        return -rc;
    rc = -MBFB_E_NOMEM;
    port_key(c.port, key, sizeof key);
    pthread_mutex_lock(&mbfb_registry_lock);
    for (int i = 0; i < MBFB_MAX_BUSES; i++) {
        mbfb_bus_t *b = mbfb_buses[i];
        if (b == NULL) {
            if (free_index < 0)
                free_index = i;
        } else if (strcmp(b->key, key) == 0) {
            rc = same_settings(&b->cfg, &c) ? i : -MBFB_E_CONFLICT;
            free_index = -2;
            break;
        }
    }
    if (free_index >= 0)
        rc = bus_create(free_index, &c, key);
    pthread_mutex_unlock(&mbfb_registry_lock);
    return rc;
}

/* An IEC STRING's body (not NUL-terminated, trailing blanks trimmed) into buf[n]. 0, or
 * -1 when it does not fit. */
static int iec_string(const char *body, int len, char *buf, int n)
{
    int k = 0;
    if (body == NULL || len < 0 || len >= n)
        return -1;
    while (k < len && body[k] != 0)
        buf[k] = body[k], k++;
    while (k > 0 && buf[k - 1] == ' ')
        k--;
    buf[k] = 0;
    return 0;
}

/* mbfb_bus_open with IEC STRINGs and the direction control (MB_LINE). */
int mbfb_bus_open_line(const char *port, int port_len, int baud, int parity, int data_bits,
                       int stop_bits, int framing, int response_timeout_ms, int retries,
                       int direction, int dir_active_low, int dir_before_us, int dir_after_us,
                       const char *gpio_chip, int gpio_chip_len, int gpio_line)
{
    static const char parities[] = {'N', 'E', 'O'};
    char buf[256];
    mbfb_bus_config_t c;

    memset(&c, 0, sizeof c);
    if (port_len <= 0 || iec_string(port, port_len, buf, (int)sizeof buf) != 0 ||
        iec_string(gpio_chip, gpio_chip_len, c.gpio_chip, MBFB_GPIO_CHIP_MAX) != 0)
        return -MBFB_E_INVAL;
    c.port = buf;
    c.baud = baud;
    c.parity = (char)(parity >= 0 && parity <= 2 ? parities[parity] : parity);
    c.data_bits = data_bits;
    c.stop_bits = stop_bits;
    c.framing = framing;
    c.response_timeout_ms = response_timeout_ms;
    c.retries = retries;
    c.direction = direction;
    c.dir_active_low = dir_active_low;
    c.dir_before_us = dir_before_us;
    c.dir_after_us = dir_after_us;
    c.gpio_line = gpio_line;
    return mbfb_bus_open(&c);
}

/* mbfb_bus_open_line without direction control (the adapter switches). */
int mbfb_bus_open_args(const char *port, int port_len, int baud, int parity, int data_bits,
                       int stop_bits, int framing, int response_timeout_ms, int retries)
{
    return mbfb_bus_open_line(port, port_len, baud, parity, data_bits, stop_bits, framing,
                              response_timeout_ms, retries, MBFB_DIR_NONE, 0, 0, 0, "", 0, 0);
}

/* Modbus serial: 1..247, 0 = broadcast; TCP unit identifiers go to 255. */
int mbfb_dev_check(int framing, int slave)
{
    return slave < 0 || slave > (framing == MBFB_FRAMING_TCP ? MBFB_MAX_UNIT : MBFB_MAX_SLAVE)
               ? -MBFB_E_INVAL
               : 0;
}

/* Device handle for (bus, slave): found or allocated under the registry lock. */
int mbfb_dev_open(int bus, int slave)
{
    mbfb_bus_t *b;
    int rc = -MBFB_E_NOMEM;

    if (bus < 0 || bus >= MBFB_MAX_BUSES ||
        (b = __atomic_load_n(&mbfb_buses[bus], __ATOMIC_ACQUIRE)) == NULL)
        return -MBFB_E_BADHANDLE;
    if (mbfb_dev_check(b->cfg.framing, slave) != 0)
        return -MBFB_E_INVAL;
    pthread_mutex_lock(&mbfb_registry_lock);
    for (int i = 0; i < MBFB_MAX_DEVICES; i++) {
        mbfb_dev_t *d = mbfb_devs[i];
        if (d != NULL && d->bus == bus && d->slave == slave) {
            rc = i; /* blocks on one device share it (and its diagnostics) */
            break;
        }
        if (d == NULL) {
            d = (mbfb_dev_t *)calloc(1, sizeof *d);
            if (d != NULL) {
                d->bus = bus;
                d->slave = slave;
                d->state = MBFB_DEV_IN_STEP; /* nothing sent yet: nothing can be late */
                __atomic_store_n(&mbfb_devs[i], d, __ATOMIC_RELEASE);
                rc = i;
            }
            break;
        }
    }
    pthread_mutex_unlock(&mbfb_registry_lock);
    return rc;
}

/* Stop every worker, then free buses, plans and devices. All workers are told first and
 * joined after, so the bound (the attempt on the wire, then at most MBFB_STOP_SLICE_US) is
 * that of the slowest bus, not their sum. Each worker closes its port (and releases its
 * direction line) before it returns. */
void mbfb_shutdown(void)
{
    pthread_mutex_lock(&mbfb_registry_lock);
    for (int i = 0; i < MBFB_MAX_BUSES; i++) {
        mbfb_bus_t *b = mbfb_buses[i];
        if (b != NULL) {
            __atomic_store_n(&b->stop, 1, __ATOMIC_RELEASE);
            mbfb_wake(b);
        }
    }
    for (int i = 0; i < MBFB_MAX_BUSES; i++) {
        mbfb_bus_t *b = mbfb_buses[i];
        if (b == NULL)
            continue;
        pthread_join(b->worker, NULL);
        __atomic_store_n(&mbfb_buses[i], (mbfb_bus_t *)NULL, __ATOMIC_RELEASE);
        bus_free(b);
    }
    for (int i = 0; i < MBFB_MAX_PLANS; i++) {
        free(mbfb_plans[i]);
        __atomic_store_n(&mbfb_plans[i], (mbfb_plan_t *)NULL, __ATOMIC_RELEASE);
    }
    for (int i = 0; i < MBFB_MAX_DEVICES; i++) {
        free(mbfb_devs[i]);
        __atomic_store_n(&mbfb_devs[i], (mbfb_dev_t *)NULL, __ATOMIC_RELEASE);
    }
    pthread_mutex_unlock(&mbfb_registry_lock);
}

/* The library's own end (README "Lifetime"): run when the object holding the shims is
 * unloaded (dlclose of a PLC program's .so: OpenPLC Runtime v4's Stop) or the process
 * exits. The workers' code lives in that object: they must have returned before it is
 * unmapped, or they run on in freed pages (SIGSEGV). Joined here, they have: dlclose
 * returns after this. The host has stopped calling into the library by then (Runtime
 * v4 joins its scan threads before dlclose); one that calls exit() must not leave
 * another thread in the blocks, as with any library's destructors. */
__attribute__((destructor)) static void mbfb_unload(void)
{
    mbfb_shutdown();
}
