/*
 * mbfb_backend_lm.c - the backends built on libmodbus: RTU, RTU-without-CRC and TCP,
 * and the port opening every serial framing shares.
 *
 * libmodbus does: opening and configuring the port (termios), RTU/TCP framing, the
 * CRC of requests and the framing + CRC check of replies (modbus_send_raw_request,
 * modbus_receive_confirmation), flushing a TCP socket.
 * Written here, because libmodbus has no such mode: the RTU-without-CRC request
 * (MT-S9 Type 2 sends 00 00 where the CRC goes; libmodbus always appends a real
 * CRC), written straight to libmodbus's file descriptor. Its reply still carries a
 * real CRC, so it is received and checked by libmodbus like RTU.
 * The libmodbus context is this file's private state (bus->be_priv), as libmodbus
 * keeps its own backend data behind ctx->backend_data.
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

#include "mbfb_internal.h"

/* The context of an open bus. */
static modbus_t *ctx_of(mbfb_bus_t *bus)
{
    return (modbus_t *)bus->be_priv;
}

/* errno of libmodbus / read / write -> -MBFB_E_*. */
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

/* The speeds _modbus_rtu_connect() maps to a termios B* constant on Linux, in
 * libmodbus 3.1.6 and in OpenPLC's 3.1.2-based fork alike; any other value it sets as
 * B9600 without an error, so mbfb_lm_serial_open sets those with termios2 afterwards. */
int mbfb_lm_baud_ok(int baud)
{
    static const int speeds[] = {110,     300,     600,     1200,    2400,    4800,
                                 9600,    19200,   38400,   57600,   115200,  230400,
                                 460800,  500000,  576000,  921600,  1000000, 1152000,
                                 1500000, 2500000, 3000000, 3500000, 4000000};
    for (size_t i = 0; i < sizeof speeds / sizeof speeds[0]; i++)
        if (speeds[i] == baud)
            return 1;
    return 0;
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
    bus->be_priv = ctx;
    bus->fd = modbus_get_socket(ctx);
    bus->quiet_from_us = mbfb_now_us();
    return 0;
}

/* Open and configure the serial port with libmodbus (every serial framing); a baud outside
 * libmodbus's table (which it would silently run at 9600) is then set with termios2 and the
 * rate the driver will run at checked (mbfb_baud.c), low latency asked of a USB adapter
 * (mbfb_serial.c), and the direction control put in place (mbfb_direction.c): a driver that
 * refuses the baud or the direction closes the port again with -MBFB_E_BAUD or
 * -MBFB_E_DIRECTION. */
int mbfb_lm_serial_open(mbfb_bus_t *bus)
{
    const mbfb_bus_config_t *c = &bus->cfg;
    int rc = lm_connect(bus, modbus_new_rtu(c->port, c->baud, c->parity, c->data_bits,
                                            c->stop_bits));
    if (rc == 0)
        rc = mbfb_serial_set_baud(bus, !mbfb_lm_baud_ok(c->baud));
    if (rc == 0) {
        mbfb_serial_low_latency(bus->fd); /* best effort: USB adapters (mbfb_serial.c) */
        rc = mbfb_dir_open(bus); /* -MBFB_E_DIRECTION: closed again before any byte */
    }
    if (rc < 0 && bus->fd >= 0)
        mbfb_lm_close(bus);
    return rc;
}

/* "tcp://host:port" -> modbus_new_tcp_pi(host, port) (getaddrinfo: names and IPv6). */
static int tcp_open(mbfb_bus_t *bus)
{
    char host[256];
    const char *service;

    if (mbfb_tcp_split(bus->port, host, sizeof host, &service) != 0)
        return -MBFB_E_NOPORT;
    return lm_connect(bus, modbus_new_tcp_pi(host, service));
}

/* Close the port and free the libmodbus context. */
void mbfb_lm_close(mbfb_bus_t *bus)
{
    mbfb_dir_close(bus);
    if (bus->be_priv) {
        modbus_close(ctx_of(bus));
        modbus_free(ctx_of(bus));
    }
    bus->be_priv = NULL;
    bus->fd = -1;
}

/* TCP: libmodbus's flush reads and drops what is pending on the socket (no line to
 * fall silent: the silence is ignored). Returns the bytes it dropped. */
static int tcp_quiet(mbfb_bus_t *bus, int silence_us, int limit_us)
{
    int n = modbus_flush(ctx_of(bus));
    (void)silence_us, (void)limit_us;
    return n > 0 ? n : 0;
}

/* TCP after a failed attempt: a new connection, on which no late reply can come. */
static void tcp_reconnect(mbfb_bus_t *bus)
{
    mbfb_lm_close(bus);
    tcp_open(bus); /* on failure the port stays closed; the next request reopens */
}

/* Send a frame with libmodbus's framing (RTU CRC or MBAP header), the direction switched
 * around it on a serial line. */
static int lm_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    uint8_t raw[MBFB_FRAME_MAX]; /* OpenPLC's libmodbus takes a non-const pointer */
    int rc;

    memcpy(raw, frame, (size_t)len);
    if ((rc = mbfb_dir_begin(bus)) != 0)
        return rc;
    rc = modbus_send_raw_request(ctx_of(bus), raw, len) == -1 ? mbfb_errno_to_err(errno) : 0;
    return mbfb_dir_end(bus, len, rc);
}

/* MT-S9 Type 2: the frame and 00 00 where the CRC goes, written to the port. */
static int nocrc_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    uint8_t raw[MBFB_FRAME_MAX];
    int rc;

    memcpy(raw, frame, (size_t)len);
    raw[len] = 0; /* "CRC check 0000" */
    raw[len + 1] = 0;
    if ((rc = mbfb_dir_begin(bus)) != 0)
        return rc;
    return mbfb_dir_end(bus, len, mbfb_fd_write_all(bus, raw, len + 2));
}

/* Receive and check (framing, CRC) one reply with libmodbus; strip header and CRC
 * with the lengths of the bus's backend table. */
static int lm_recv(mbfb_bus_t *bus, const uint8_t *req, uint8_t *frame, int max,
                   int timeout_us)
{
    uint8_t adu[MODBUS_TCP_MAX_ADU_LENGTH + 4];
    modbus_t *ctx = ctx_of(bus);
    int hl = bus->be->header_len, n, rc;

    modbus_set_slave(ctx, req[0]); /* libmodbus frames the reply by its function code */
    modbus_set_response_timeout(ctx, (uint32_t)(timeout_us / 1000000),
                                (uint32_t)(timeout_us % 1000000));
    rc = modbus_receive_confirmation(ctx, adu);
    if (rc == -1)
        return mbfb_errno_to_err(errno);
    if (rc == 0)
        return -MBFB_E_BADREPLY; /* RTU: libmodbus dropped a reply from another slave */
    n = rc - hl - bus->be->check_len; /* unit id + PDU */
    if (n < 2 || n > max)
        return -MBFB_E_BADREPLY;
    memcpy(frame, adu + hl, (size_t)n);
    return n;
}

/* header, check, needs_resync, open, close, quiet, reconnect, send, recv */
const mbfb_backend_t mbfb_backend_rtu = {
    0, 2, 1, mbfb_lm_serial_open, mbfb_lm_close, mbfb_serial_quiet, NULL, lm_send, lm_recv};

const mbfb_backend_t mbfb_backend_nocrc = {
    0, 2, 1, mbfb_lm_serial_open, mbfb_lm_close, mbfb_serial_quiet, NULL, nocrc_send,
    lm_recv};

const mbfb_backend_t mbfb_backend_tcp = {
    6, 0, 0, tcp_open, mbfb_lm_close, tcp_quiet, tcp_reconnect, lm_send, lm_recv};
