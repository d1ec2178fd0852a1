/*
 * mbfb_backend_lm.c - the backends built on libmodbus: RTU, RTU-without-CRC and TCP,
 * and the serial-port helpers every serial framing shares.
 *
 * libmodbus does: opening and configuring the port (termios), RTU/TCP framing, the
 * CRC of requests and the framing + CRC check of replies (modbus_send_raw_request,
 * modbus_receive_confirmation), flushing a TCP socket.
 * Written here, because libmodbus has no such mode: the RTU-without-CRC request
 * (MT-S9 Type 2 sends 00 00 where the CRC goes; libmodbus always appends a real
 * CRC), written straight to libmodbus's file descriptor. Its reply still carries a
 * real CRC, so it is received and checked by libmodbus like RTU. And the
 * receive-monitored silence before a request on a serial line (mbfb_serial_quiet).
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* ppoll (g++ defines it already) */
#endif
#include <errno.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mbfb_internal.h"

int mbfb_errno_to_err(int err)
{
    switch (err) {
    case ETIMEDOUT:
        return -MBFB_E_TIMEOUT;
    case EMBBADCRC:
        return -MBFB_E_CRC;
    case EMBBADDATA:
    case EMBBADEXC:
    case EMBUNKEXC:
    case EMBMDATA:
        return -MBFB_E_BADREPLY;
    default: /* EIO, ENXIO, ENODEV, EBADF, ECONNRESET (EOF), EPIPE, ... */
        return -MBFB_E_PORTLOST;
    }
}

/* Set up a fresh libmodbus context: no error recovery of its own (the worker does
 * retries and resynchronisation), our byte timeout. */
static int lm_connect(mbfb_bus_t *bus, modbus_t *ctx)
{
    if (ctx == NULL)
        return -MBFB_E_NOPORT;
    modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE);
    if (getenv("MBFB_DEBUG") != NULL) /* libmodbus prints every frame */
        modbus_set_debug(ctx, 1);
    modbus_set_byte_timeout(ctx, (uint32_t)(bus->timing.byte_us / 1000000),
                            (uint32_t)(bus->timing.byte_us % 1000000));
    modbus_set_response_timeout(ctx, 1, 0); /* TCP connect; set per request later */
    if (modbus_connect(ctx) == -1) {
        modbus_free(ctx);
        return -MBFB_E_NOPORT;
    }
    bus->ctx = ctx;
    bus->fd = modbus_get_socket(ctx);
    bus->quiet_from_us = mbfb_now_us();
    return 0;
}

int mbfb_serial_open(mbfb_bus_t *bus)
{
    const mbfb_bus_config_t *c = &bus->cfg;
    return lm_connect(bus, modbus_new_rtu(c->port, c->baud, c->parity, c->data_bits,
                                          c->stop_bits));
}

/* "tcp://host:port" -> modbus_new_tcp_pi(host, port) (getaddrinfo: names and IPv6). */
static int tcp_open(mbfb_bus_t *bus)
{
    char host[256];
    const char *hp = bus->port + 6; /* after "tcp://" */
    const char *colon = strrchr(hp, ':');
    size_t n;

    if (colon == NULL || (n = (size_t)(colon - hp)) == 0 || n >= sizeof host)
        return -MBFB_E_NOPORT;
    memcpy(host, hp, n);
    host[n] = 0;
    if (host[0] == '[' && n > 2 && host[n - 1] == ']') { /* [::1] */
        memmove(host, host + 1, n - 2);
        host[n - 2] = 0;
    }
    return lm_connect(bus, modbus_new_tcp_pi(host, colon + 1));
}

void mbfb_lm_close(mbfb_bus_t *bus)
{
    if (bus->ctx) {
        modbus_close(bus->ctx);
        modbus_free(bus->ctx);
    }
    bus->ctx = NULL;
    bus->fd = -1;
}

/* TCP: libmodbus's flush reads and drops what is pending on the socket (no line to
 * fall silent: the silence is ignored). Returns the bytes it dropped. */
static int tcp_quiet(mbfb_bus_t *bus, int silence_us, int limit_us)
{
    int n = modbus_flush(bus->ctx);
    (void)silence_us, (void)limit_us;
    return n > 0 ? n : 0;
}

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

/* Serial: wait until the line has been silent for silence_us, reading and discarding
 * whatever arrives meanwhile (see mbfb_backend_t.quiet). Written here because
 * libmodbus only flushes, and modbus_flush() on a serial port is tcflush(TCIOFLUSH):
 * it would also drop output not yet on the wire (on a pty: a broadcast the peer has
 * not read) and it cannot tell a finished line from one still carrying a late reply. */
int mbfb_serial_quiet(mbfb_bus_t *bus, int silence_us, int limit_us)
{
    int64_t give_up = mbfb_now_us() + limit_us;
    int stray = 0;

    for (;;) {
        uint8_t junk[256];
        int64_t end = bus->quiet_from_us + silence_us;
        ssize_t n;
        int rc;

        if (end > give_up)
            end = give_up; /* babbling line: send anyway, the reply check decides */
        rc = mbfb_fd_wait_input(bus->fd, end - mbfb_now_us());
        if (rc <= 0)
            return rc < 0 ? -MBFB_E_PORTLOST : stray; /* silent until `end` */
        /* readable: a tty with VMIN = VTIME = 0 returns 0 only when it is gone */
        n = read(bus->fd, junk, sizeof junk);
        if (n > 0) {
            int64_t now = mbfb_now_us();
            stray += (int)n;
            if (bus->quiet_from_us < now) /* a byte restarts the silence */
                bus->quiet_from_us = now;
            if (now >= give_up)
                return stray;
        } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
            return -MBFB_E_PORTLOST; /* EOF (adapter gone) or EIO */
        }
    }
}

static void tcp_resync(mbfb_bus_t *bus)
{
    mbfb_lm_close(bus);
    tcp_open(bus); /* on failure the port stays closed; the next request reopens */
}

static int lm_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    uint8_t raw[MBFB_FRAME_MAX]; /* OpenPLC's libmodbus takes a non-const pointer */
    memcpy(raw, frame, (size_t)len);
    return modbus_send_raw_request(bus->ctx, raw, len) == -1 ? mbfb_errno_to_err(errno) : 0;
}

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

static int nocrc_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    uint8_t raw[MBFB_FRAME_MAX];
    memcpy(raw, frame, (size_t)len);
    raw[len] = 0; /* MT-S9 Type 2: "CRC check 0000" */
    raw[len + 1] = 0;
    return mbfb_fd_write_all(bus, raw, len + 2);
}

static int lm_recv(mbfb_bus_t *bus, const uint8_t *req, uint8_t *frame, int max,
                   int timeout_us)
{
    uint8_t adu[MODBUS_TCP_MAX_ADU_LENGTH + 4];
    int hl, cks, n, rc;

    (void)req; /* libmodbus frames the reply by its function code */
    modbus_set_slave(bus->ctx, req[0]);
    modbus_set_response_timeout(bus->ctx, (uint32_t)(timeout_us / 1000000),
                                (uint32_t)(timeout_us % 1000000));
    rc = modbus_receive_confirmation(bus->ctx, adu);
    if (rc == -1)
        return mbfb_errno_to_err(errno);
    if (rc == 0)
        return -MBFB_E_BADREPLY; /* RTU: libmodbus dropped a reply from another slave */
    hl = modbus_get_header_length(bus->ctx);       /* RTU 1, TCP 7 (MBAP + unit) */
    cks = bus->cfg.framing == MBFB_FRAMING_TCP ? 0 : 2;
    n = rc - (hl - 1) - cks;                         /* unit id + PDU             */
    if (n < 2 || n > max)
        return -MBFB_E_BADREPLY;
    memcpy(frame, adu + hl - 1, (size_t)n);
    return n;
}

const mbfb_backend_t mbfb_backend_rtu = {
    "rtu", mbfb_serial_open, mbfb_lm_close, mbfb_serial_quiet, NULL, lm_send, lm_recv};

const mbfb_backend_t mbfb_backend_nocrc = {
    "rtu-nocrc", mbfb_serial_open, mbfb_lm_close, mbfb_serial_quiet, NULL, nocrc_send,
    lm_recv};

const mbfb_backend_t mbfb_backend_tcp = {
    "tcp", tcp_open, mbfb_lm_close, tcp_quiet, tcp_resync, lm_send, lm_recv};
