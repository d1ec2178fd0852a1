/*
 * mbfb_backend_lm.c - the backends built on libmodbus: RTU, RTU-without-CRC and TCP,
 * and the serial-port helpers every serial framing shares.
 *
 * libmodbus does: opening and configuring the port (termios), RTU/TCP framing, the
 * CRC of requests and the framing + CRC check of replies (modbus_send_raw_request,
 * modbus_receive_confirmation), flushing.
 * Written here, because libmodbus has no such mode: the RTU-without-CRC request
 * (MT-S9 Type 2 sends 00 00 where the CRC goes; libmodbus always appends a real
 * CRC), written straight to libmodbus's file descriptor. Its reply still carries a
 * real CRC, so it is received and checked by libmodbus like RTU.
 */
#include <errno.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
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

/* TCP: libmodbus's flush reads and drops what is pending on the socket. */
static void tcp_flush(mbfb_bus_t *bus)
{
    modbus_flush(bus->ctx);
}

/* Serial: drop unread input only. Written here because modbus_flush() does
 * tcflush(TCIOFLUSH), which also discards output not yet on the wire (on a pty: a
 * request the peer has not read yet, e.g. a broadcast). */
void mbfb_serial_flush(mbfb_bus_t *bus)
{
    tcflush(bus->fd, TCIFLUSH);
}

/* As libmodbus's own protocol recovery: wait out a late reply, then flush it. */
void mbfb_serial_resync(mbfb_bus_t *bus)
{
    mbfb_sleep_until_us(mbfb_now_us() + bus->timeout_us);
    mbfb_serial_flush(bus);
    bus->quiet_from_us = mbfb_now_us();
}

/* TCP: a late reply can only come on the old connection, so open a new one. */
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
    "rtu", mbfb_serial_open, mbfb_lm_close, mbfb_serial_flush, mbfb_serial_resync,
    lm_send, lm_recv};

const mbfb_backend_t mbfb_backend_nocrc = {
    "rtu-nocrc", mbfb_serial_open, mbfb_lm_close, mbfb_serial_flush, mbfb_serial_resync,
    nocrc_send, lm_recv};

const mbfb_backend_t mbfb_backend_tcp = {
    "tcp", tcp_open, mbfb_lm_close, tcp_flush, tcp_resync, lm_send, lm_recv};
