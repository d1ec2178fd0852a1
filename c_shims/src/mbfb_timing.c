/*
 * mbfb_timing.c - line timing from baud and character format, monotonic clock.
 *
 *   char_bits = 1 start + data bits + (parity ? 1 : 0) + stop bits
 *   char_us   = char_bits * 1e6 / baud                       (rounded up)
 *   gap_us    = max(3.5 * char_us, 44 bit times)             Modbus t3.5; SetPro 5.6
 *               and at least 1750 us above 19200 baud        (Modbus serial guide)
 *   byte_us   = max(20 ms, 4 * char_us)   silence that ends a started reply; USB
 *               adapters deliver bytes in bursts (FTDI latency 16 ms), so t1.5 is
 *               not usable on the master side.
 *   response timeout (time to the first reply byte, unless configured):
 *               T = max(50 ms, 2 * (wire(req) + wire(reply)) * char_us + 2 * 10 ms)
 *               i.e. twice (transmission of both frames + 10 ms device processing,
 *               the SetPro maximum). 9600 8N2, one register: 54 ms (SetPro: >= 50).
 *               Modbus TCP (a gateway to a serial line): the same at 9600 8N1
 *               unless a baud is given, and at least 500 ms.
 *               RTU over TCP: the serial figure at the line's baud + net_us
 *               (MBFB_NET_ALLOWANCE_US, the network leg).
 */
#include <time.h>

#include "mbfb_internal.h"

/* Character time, gap and byte timeout from the line settings (file comment). */
void mbfb_timing_init(mbfb_timing_t *t, int baud, char parity, int data_bits, int stop_bits)
{
    int bits = 1 + data_bits + (parity == 'N' ? 0 : 1) + stop_bits;
    int bit44 = (int)((44LL * 1000000 + baud - 1) / baud);

    t->char_us = (int)(((int64_t)bits * 1000000 + baud - 1) / baud);
    t->gap_us = (7 * t->char_us + 1) / 2;
    if (t->gap_us < bit44)
        t->gap_us = bit44;
    if (baud > 19200 && t->gap_us < 1750)
        t->gap_us = 1750;
    t->byte_us = 4 * t->char_us > 20000 ? 4 * t->char_us : 20000;
    t->net_us = 0;
}

/* Bytes on the wire of a frame in a framing. */
int mbfb_wire_len(int framing, int frame_len)
{
    switch (framing) {
    case MBFB_FRAMING_ASCII:
        return 1 + 2 * (frame_len + 1) + 2; /* ':' hex(frame + LRC) CR LF */
    case MBFB_FRAMING_TCP:
        return 6 + frame_len;               /* MBAP header without the unit id */
    default:
        return frame_len + 2;               /* CRC (or 00 00)                  */
    }
}

int mbfb_response_timeout_us(const mbfb_timing_t *t, int framing, int req_frame_len,
                             int rsp_frame_len)
{
    int wire_framing = framing == MBFB_FRAMING_TCP ? MBFB_FRAMING_RTU : framing;
    int64_t bytes = mbfb_wire_len(wire_framing, req_frame_len) +
                    mbfb_wire_len(wire_framing, rsp_frame_len);
    int64_t us = 2 * (bytes * t->char_us + MBFB_PROCESSING_US);
    int64_t min_us = framing == MBFB_FRAMING_TCP ? 500000 : 50000;

    return (int)(us > min_us ? us : min_us) + t->net_us;
}

/* CLOCK_MONOTONIC in microseconds. */
int64_t mbfb_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}
