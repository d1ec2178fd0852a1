/*
 * mbfb_backend_ascii.c - Modbus ASCII framing: ':' + hex(frame + LRC) + CR LF.
 *
 * Written here because libmodbus has no ASCII mode. The serial port itself is still
 * opened and configured by libmodbus (mbfb_backend_lm.c); only the framing is ours
 * (the silence before a request: mbfb_serial.c).
 * A ':' always starts a new frame, so noise before it is skipped; a line that never
 * stops talking still ends the wait (first byte by the response timeout, the frame
 * within the longest frame's time after that).
 */
#include <errno.h>
#include <unistd.h>

#include "mbfb_internal.h"

static const char hexd[] = "0123456789ABCDEF";

/* Send ':' + hex(frame + LRC) + CR LF, the direction switched around it. */
static int ascii_send(mbfb_bus_t *bus, const uint8_t *frame, int len)
{
    char out[1 + 2 * (MBFB_FRAME_MAX + 1) + 2];
    uint8_t lrc = mbfb_lrc(frame, len);
    int n = 0, rc;

    out[n++] = ':';
    for (int i = 0; i <= len; i++) {
        uint8_t b = i < len ? frame[i] : lrc;
        out[n++] = hexd[b >> 4];
        out[n++] = hexd[b & 15];
    }
    out[n++] = '\r';
    out[n++] = '\n';
    if ((rc = mbfb_dir_begin(bus)) != 0)
        return rc;
    return mbfb_dir_end(bus, len, mbfb_fd_write_all(bus, (const uint8_t *)out, n));
}

enum { A_IDLE, A_HEX, A_CR };

/* Receive one ASCII frame (see the file comment); returns its binary length. */
static int ascii_recv(mbfb_bus_t *bus, const uint8_t *req, uint8_t *frame, int max,
                      int timeout_us)
{
    int64_t start_by = mbfb_now_us() + timeout_us; /* a ':' must come by then       */
    int64_t end_by = start_by + bus->timing.byte_us +   /* and its frame end by then */
                     (int64_t)mbfb_wire_len(MBFB_FRAMING_ASCII, MBFB_FRAME_MAX) *
                         bus->timing.char_us;
    int state = A_IDLE, nhex = 0, got_any = 0, hi = 0, skipped = 0;
    uint8_t bin[MBFB_FRAME_MAX + 1];

    (void)req;
    for (;;) {
        uint8_t chunk[1]; /* one byte a read: what follows the frame stays in the port for
                             the next receive (a late reply, then this request's answer) */
        int64_t now = mbfb_now_us(), limit = state == A_IDLE ? start_by : end_by;
        int64_t wait = got_any ? bus->timing.byte_us : limit - now;
        ssize_t n;

        if (wait > limit - now) /* noise never prolongs the wait */
            wait = limit - now;
        if (wait <= 0 || mbfb_fd_wait_input(bus->fd, wait) <= 0)
            return got_any ? -MBFB_E_BADREPLY : -MBFB_E_TIMEOUT; /* truncated / none */
        n = read(bus->fd, chunk, sizeof chunk);
        if (n < 0 && (errno == EAGAIN || errno == EINTR))
            continue;
        if (n <= 0)
            return -MBFB_E_PORTLOST;
        got_any = 1;
        for (ssize_t i = 0; i < n; i++) {
            int c = chunk[i] & 0x7F, v;
            if (c == ':') {            /* a colon always starts a frame */
                if (state != A_IDLE)   /* an unfinished one is dropped */
                    skipped += 1 + nhex + (state == A_CR);
                state = A_HEX;
                nhex = 0;
            } else if (state == A_HEX && c == '\r') {
                state = A_CR;
            } else if (state == A_HEX && (v = mbfb_hex_digit(c)) >= 0) {
                if (nhex / 2 >= (int)sizeof bin)
                    return -MBFB_E_BADREPLY;
                if (nhex & 1)
                    bin[nhex / 2] = (uint8_t)(hi << 4 | v);
                hi = v;
                nhex++;
            } else if (state == A_CR && c == '\n') {
                int len = nhex / 2 - 1; /* without the LRC */
                if ((nhex & 1) || len < 2 || len > max)
                    return -MBFB_E_BADREPLY;
                if (mbfb_lrc(bin, len) != bin[len])
                    return -MBFB_E_CRC;
                for (int k = 0; k < len; k++)
                    frame[k] = bin[k];
                MBFB_STRAY_ADD(bus, skipped); /* noise before it: discarded */
                return len;
            } else if (state != A_IDLE) {
                return -MBFB_E_BADREPLY; /* garbage inside a frame */
            } else {
                skipped++;
            }
        }
    }
}

/* header 0 (the ':' is framing), check: the LRC byte (two hex characters on the
 * wire), no transaction id: resynchronised like RTU. */
const mbfb_backend_t mbfb_backend_ascii = {
    0, 1, 1, mbfb_lm_serial_open, mbfb_lm_close, mbfb_serial_quiet, NULL, ascii_send,
    ascii_recv};
