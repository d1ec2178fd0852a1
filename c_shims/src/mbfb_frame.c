/*
 * mbfb_frame.c - request frames, reply validation, CRC-16 and LRC.
 *
 * Reply validation lives here once and is shared by every backend: libmodbus's
 * modbus_receive_confirmation() only frames and checks the CRC, and its own
 * check_confirmation() is private to its high-level calls and does not compare the
 * value echoed by FC06.
 */
#include <string.h>

#include "mbfb_internal.h"

/* libmodbus keeps its CRC static; this one is for the ASCII/test peers and tests,
 * verified against every worked frame of the manuals (tests/shims). */
uint16_t mbfb_crc16(const uint8_t *buf, int len)
{
    uint16_t crc = 0xFFFF;
    for (int i = 0; i < len; i++) {
        crc ^= buf[i];
        for (int b = 0; b < 8; b++)
            crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xA001) : (uint16_t)(crc >> 1);
    }
    return crc;
}

/* Modbus ASCII LRC: two's complement of the byte sum. */
uint8_t mbfb_lrc(const uint8_t *buf, int len)
{
    uint8_t sum = 0;
    for (int i = 0; i < len; i++)
        sum = (uint8_t)(sum + buf[i]);
    return (uint8_t)(-sum);
}

/* Big-endian 16-bit value. */
static void put16(uint8_t *p, int v)
{
    p[0] = (uint8_t)((v >> 8) & 0xFF);
    p[1] = (uint8_t)(v & 0xFF);
}

int mbfb_build_request(uint8_t *out, int slave, int fc, int addr, int count,
                       const uint16_t *values)
{
    out[0] = (uint8_t)slave;
    out[1] = (uint8_t)fc;
    put16(out + 2, addr);
    if (fc == MBFB_FC_WRITE_SINGLE) {
        put16(out + 4, values[0]);
        return 6;
    }
    put16(out + 4, count);
    if (fc != MBFB_FC_WRITE_MULTIPLE)
        return 6;
    out[6] = (uint8_t)(2 * count);
    for (int i = 0; i < count; i++)
        put16(out + 7 + 2 * i, values[i]);
    return 7 + 2 * count;
}

/* Length of the good reply frame to a request frame. */
int mbfb_reply_len(const uint8_t *req)
{
    if (mbfb_fc_is_read(req[1]))
        return 3 + 2 * ((req[4] << 8) | req[5]);
    return 6; /* FC06 echo, FC16 address + count */
}

/* Validate a reply frame against its request (see mbfb_internal.h). */
int mbfb_check_reply(const uint8_t *req, const uint8_t *rsp, int len)
{
    int fc = req[1];

    if (len < 3 || rsp[0] != req[0])
        return MBFB_E_BADREPLY;
    if (rsp[1] == (fc | MBFB_EXCEPTION_BIT))
        return (len == 3 && rsp[2] != 0) ? MBFB_E_EXCEPTION_BASE + rsp[2] : MBFB_E_BADREPLY;
    if (rsp[1] != fc || len != mbfb_reply_len(req))
        return MBFB_E_BADREPLY;
    switch (fc) {
    case MBFB_FC_READ_HOLDING:
    case MBFB_FC_READ_INPUT:
        return rsp[2] == len - 3 ? MBFB_OK : MBFB_E_BADREPLY;
    case MBFB_FC_WRITE_SINGLE:   /* echo of address and value */
    case MBFB_FC_WRITE_MULTIPLE: /* echo of address and count */
        return memcmp(rsp + 2, req + 2, 4) == 0 ? MBFB_OK : MBFB_E_BADREPLY;
    default:
        return MBFB_E_BADREPLY;
    }
}

/* Check a request's arguments against the protocol limits. */
int mbfb_check_args(int slave, int fc, int addr, int count, const uint16_t *values)
{
    if (addr < 0 || addr >= MBFB_ADDR_SPACE)
        return MBFB_E_INVAL;
    switch (fc) {
    case MBFB_FC_READ_HOLDING:
    case MBFB_FC_READ_INPUT:
        if (slave == 0 || count < 1 || count > MBFB_MAX_READ)
            return MBFB_E_INVAL; /* broadcast reads get no reply: refused */
        break;
    case MBFB_FC_WRITE_SINGLE:
        if (count != 1 || values == NULL)
            return MBFB_E_INVAL;
        break;
    case MBFB_FC_WRITE_MULTIPLE:
        if (count < 1 || count > MBFB_MAX_WRITE || values == NULL)
            return MBFB_E_INVAL;
        break;
    default:
        return MBFB_E_INVAL;
    }
    return addr + count > MBFB_ADDR_SPACE ? MBFB_E_INVAL : MBFB_OK;
}

/* Value of an upper- or lower-case hex digit, or -1. */
int mbfb_hex_digit(int c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    if (c >= 'a' && c <= 'f')
        return c - 'a' + 10;
    return -1;
}

/* Length of a whole reply frame (slave + PDU + CRC) starting at b (n bytes there), from its
 * function code and byte count; 0 if it is not one or not complete. */
static int rtu_reply_len(const uint8_t *b, int n)
{
    int len;
    if (n < 5)
        return 0;
    if (b[1] & MBFB_EXCEPTION_BIT)
        len = 5;
    else if (mbfb_fc_is_read(b[1]))
        len = 3 + b[2] + 2;
    else if (mbfb_fc_is_write(b[1]))
        len = 8;
    else
        return 0;
    return len <= n ? len : 0;
}

int mbfb_next_reply(int framing, const uint8_t *buf, int n, int *pos, uint8_t *frame)
{
    while (*pos < n) {
        const uint8_t *b = buf + *pos;
        int left = n - *pos, len;
        if (framing == MBFB_FRAMING_ASCII) {
            int k = 1, m = 0;
            if (b[0] != ':') {
                (*pos)++;
                continue;
            }
            while (k + 1 < left && mbfb_hex_digit(b[k]) >= 0 && mbfb_hex_digit(b[k + 1]) >= 0 &&
                   m < MBFB_FRAME_MAX) {
                frame[m++] = (uint8_t)(mbfb_hex_digit(b[k]) << 4 | mbfb_hex_digit(b[k + 1]));
                k += 2;
            }
            if (k + 1 < left && b[k] == '\r' && b[k + 1] == '\n' && m >= 3 &&
                mbfb_lrc(frame, m - 1) == frame[m - 1]) {
                *pos += k + 2;
                return m - 1;
            }
            (*pos)++;
            continue;
        }
        len = rtu_reply_len(b, left);
        if (len > 0 && mbfb_crc16(b, len - 2) == (uint16_t)(b[len - 2] | b[len - 1] << 8)) {
            memcpy(frame, b, (size_t)(len - 2));
            *pos += len;
            return len - 2;
        }
        (*pos)++;
    }
    return 0;
}
