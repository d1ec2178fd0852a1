/*
 * mbfb_backend_rtutcp.c - RTU over TCP: RTU frames with their CRC on a TCP stream to a
 * transparent Ethernet-to-RS-485 gateway (Port 'tcp://HOST:PORT', Framing RTU).
 *
 * Written here because libmodbus cannot speak it: its TCP backend always frames with
 * an MBAP header and its RTU backend opens a serial port only. The socket is this
 * file's own (bus->fd, nothing behind bus->be_priv).
 *
 * A gateway forwards whatever its serial line carries, late replies included, and
 * has no transaction id, so the stream is treated as a serial line: needs_resync = 1,
 * the watched silence before a request (mbfb_serial_quiet reads the socket like a
 * tty; EOF there is MBFB_E_PORTLOST), the gap at the line's baud. A reply is framed
 * by its own header like libmodbus frames RTU (exception 5 bytes, FC01-04 by the byte
 * count, FC05/06/15/16 8 bytes: mbfb_rtu_reply_wire_len); only those bytes are read,
 * anything after them is left for the next silence to discard. A connection that closes
 * or resets is MBFB_E_PORTLOST: the worker closes the port and the next request connects
 * again.
 */
#include <errno.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "mbfb_internal.h"

/* "tcp://host:port" -> host (brackets of [::1] removed) and the port text. */
int mbfb_tcp_split(const char *port, char *host, size_t n, const char **service)
{
    const char *hp = port + 6; /* after "tcp://" */
    const char *colon = strrchr(hp, ':');
    size_t len;

    if (strncmp(port, "tcp://", 6) != 0 || colon == NULL || (len = (size_t)(colon - hp)) == 0 ||
        len >= n || colon[1] == 0)
        return -1;
    memcpy(host, hp, len);
    host[len] = 0;
    if (host[0] == '[' && len > 2 && host[len - 1] == ']') { /* [::1] */
        memmove(host, host + 1, len - 2);
        host[len - 2] = 0;
    }
    *service = colon + 1;
    return 0;
}

/* Connect one address without blocking longer than MBFB_CONNECT_MS. fd or -1. */
static int connect_one(const struct addrinfo *ai)
{
    int fd = socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC,
                    ai->ai_protocol);
    int one = 1, err = 0;
    socklen_t len = sizeof err;

    if (fd < 0)
        return -1;
    if (connect(fd, ai->ai_addr, ai->ai_addrlen) != 0) {
        struct pollfd p = {fd, POLLOUT, 0};
        int rc;
        if (errno != EINPROGRESS) {
            close(fd);
            return -1;
        }
        while ((rc = poll(&p, 1, MBFB_CONNECT_MS)) < 0 && errno == EINTR) {
        }
        if (rc <= 0 || getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len) != 0 || err != 0) {
            close(fd);
            return -1;
        }
    }
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one); /* a request is one write */
    return fd;
}

/* Connect to the gateway (getaddrinfo: names, IPv4, IPv6). -MBFB_E_NOPORT when it
 * cannot be reached (refused, no such host, no answer within MBFB_CONNECT_MS). */
static int rtutcp_open(mbfb_bus_t *bus)
{
    char host[256];
    const char *service;
    struct addrinfo hints, *res = NULL;

    if (mbfb_tcp_split(bus->port, host, sizeof host, &service) != 0)
        return -MBFB_E_NOPORT;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    if (getaddrinfo(host, service, &hints, &res) != 0)
        return -MBFB_E_NOPORT;
    for (struct addrinfo *ai = res; ai != NULL && bus->fd < 0; ai = ai->ai_next)
        bus->fd = connect_one(ai);
    freeaddrinfo(res);
    if (bus->fd < 0)
        return -MBFB_E_NOPORT;
    bus->quiet_from_us = mbfb_now_us();
    return 0;
}

/* Close the connection. */
static void rtutcp_close(mbfb_bus_t *bus)
{
    if (bus->fd >= 0)
        close(bus->fd);
    bus->fd = -1;
}

/* The frame and its CRC (low byte first), written whole. send(MSG_NOSIGNAL): a peer that
 * has gone must give PORTLOST, not SIGPIPE to the PLC process. */
static int rtutcp_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    uint8_t raw[MBFB_FRAME_MAX];
    uint16_t crc = mbfb_crc16(frame, len);
    int done = 0;

    memcpy(raw, frame, (size_t)len);
    raw[len] = (uint8_t)(crc & 0xFF);
    raw[len + 1] = (uint8_t)(crc >> 8);
    len += 2;
    while (done < len) {
        ssize_t n = send(bus->fd, raw + done, (size_t)(len - done), MSG_NOSIGNAL);
        if (n > 0) {
            done += (int)n;
        } else if (n < 0 && (errno == EAGAIN || errno == EINTR)) {
            struct pollfd p = {bus->fd, POLLOUT, 0};
            if (poll(&p, 1, MBFB_CONNECT_MS) == 0)
                return -MBFB_E_PORTLOST; /* the gateway takes nothing any more */
        } else {
            return -MBFB_E_PORTLOST;
        }
    }
    return 0;
}

/* Read until `want` bytes are in buf or `deadline` (monotonic us) passes. Returns the
 * bytes held, or -MBFB_E_PORTLOST on EOF or a socket error. */
static int read_until(mbfb_bus_t *bus, uint8_t *buf, int got, int want, int64_t deadline)
{
    while (got < want) {
        int rc = mbfb_fd_wait_input(bus->fd, deadline - mbfb_now_us());
        ssize_t n;
        if (rc < 0)
            return -MBFB_E_PORTLOST;
        if (rc == 0)
            return got;
        n = recv(bus->fd, buf + got, (size_t)(want - got), 0);
        if (n > 0)
            got += (int)n;
        else if (n == 0 || (errno != EAGAIN && errno != EINTR))
            return -MBFB_E_PORTLOST; /* the gateway closed or reset the connection */
    }
    return got;
}

/* Receive one reply: the first byte within timeout_us, the rest within the reply's time
 * on the line plus the byte timeout and MBFB_NET_ALLOWANCE_US; CRC checked and stripped. */
static int rtutcp_recv(mbfb_bus_t *bus, const uint8_t *req, uint8_t *frame, int max,
                       int timeout_us)
{
    uint8_t buf[MBFB_FRAME_MAX + 8];
    int64_t first;
    int got, want = 3;

    (void)req; /* the reply frames itself; mbfb_check_reply compares it with req */
    got = read_until(bus, buf, 0, 1, mbfb_now_us() + timeout_us);
    if (got <= 0)
        return got < 0 ? got : -MBFB_E_TIMEOUT;
    first = mbfb_now_us();
    for (;;) {
        int len = mbfb_rtu_reply_wire_len(buf, got);
        if (len == 0)
            return -MBFB_E_BADREPLY; /* unknown function: the next silence drops the rest */
        if (len > 0)
            want = len;
        if (got >= want)
            break;
        got = read_until(bus, buf, got, want,
                         first + (int64_t)want * bus->timing.char_us + bus->timing.byte_us +
                             MBFB_NET_ALLOWANCE_US);
        if (got < 0)
            return got;
        if (got < want) /* read_until stopped at its deadline */
            return -MBFB_E_TIMEOUT; /* a reply cut short */
    }
    if (mbfb_crc16(buf, want - 2) != (uint16_t)(buf[want - 2] | buf[want - 1] << 8))
        return -MBFB_E_CRC;
    if (want - 2 > max)
        return -MBFB_E_BADREPLY;
    memcpy(frame, buf, (size_t)(want - 2));
    return want - 2;
}

/* header, check, needs_resync, open, close, quiet, reconnect, send, recv */
const mbfb_backend_t mbfb_backend_rtutcp = {
    0, 2, 1, rtutcp_open, rtutcp_close, mbfb_serial_quiet, NULL, rtutcp_send, rtutcp_recv};
