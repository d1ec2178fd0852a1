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

/* Bits packed in words -> the wire's bytes, LSB first: byte j is the low (j even) or high
 * (j odd) byte of word j / 2; the bits past n are cleared. */
void mbfb_bits_to_bytes(const uint16_t *words, int n, uint8_t *out)
{
    int nbytes = (n + 7) / 8;
    for (int j = 0; j < nbytes; j++)
        out[j] = (uint8_t)(words[j / 2] >> (8 * (j & 1)));
    if (n % 8)
        out[nbytes - 1] &= (uint8_t)((1u << (n % 8)) - 1u);
}

/* The wire's bytes of n bits -> words; the bits past n are cleared (a reply's padding). */
void mbfb_bytes_to_bits(const uint8_t *in, int n, uint16_t *words)
{
    int nbytes = (n + 7) / 8, nwords = MBFB_BIT_WORDS(n);
    for (int w = 0; w < nwords; w++)
        words[w] = 0;
    for (int j = 0; j < nbytes; j++)
        words[j / 2] = (uint16_t)(words[j / 2] | in[j] << (8 * (j & 1)));
    if (n % 16)
        words[nwords - 1] &= (uint16_t)((1u << (n % 16)) - 1u);
}

/* The read-back shows the write: registers word for word, coils bit for bit. */
int mbfb_readback_shows(int fc, int count, const uint16_t *vals, const uint16_t *read)
{
    switch (fc) {
    case MBFB_FC_WRITE_COIL:
        return (read[0] & 1u) == (vals[0] != 0);
    case MBFB_FC_WRITE_COILS:
        for (int w = 0; w < MBFB_BIT_WORDS(count); w++) {
            unsigned mask = (w + 1) * 16 <= count ? 0xFFFFu : (1u << (count % 16)) - 1u;
            if (((vals[w] ^ read[w]) & mask) != 0)
                return 0;
        }
        return 1;
    default:
        return memcmp(vals, read, (size_t)count * sizeof vals[0]) == 0;
    }
}

int mbfb_build_request(uint8_t *out, int slave, int fc, int addr, int count,
                       const uint16_t *values)
{
    out[0] = (uint8_t)slave;
    out[1] = (uint8_t)fc;
    put16(out + 2, addr);
    switch (fc) {
    case MBFB_FC_WRITE_SINGLE:
        put16(out + 4, values[0]);
        return 6;
    case MBFB_FC_WRITE_COIL:
        put16(out + 4, values[0] != 0 ? MBFB_COIL_ON : 0);
        return 6;
    case MBFB_FC_WRITE_MULTIPLE:
        put16(out + 4, count);
        out[6] = (uint8_t)(2 * count);
        for (int i = 0; i < count; i++)
            put16(out + 7 + 2 * i, values[i]);
        return 7 + 2 * count;
    case MBFB_FC_WRITE_COILS:
        put16(out + 4, count);
        out[6] = (uint8_t)((count + 7) / 8);
        mbfb_bits_to_bytes(values, count, out + 7);
        return 7 + out[6];
    default: /* the reads: address and count */
        put16(out + 4, count);
        return 6;
    }
}

/* Length of the good reply frame to a request frame. */
int mbfb_reply_len(const uint8_t *req)
{
    if (mbfb_fc_is_read(req[1]))
        return 3 + mbfb_read_bytes(req[1], (req[4] << 8) | req[5]);
    return 6; /* FC05/06 echo, FC15/16 address + count */
}

/* Validate a reply frame against its request (see mbfb_internal.h). The bits past the
 * count in an FC01/02 reply's last byte ("padded with zeros", 6.1) are not checked: they
 * are cleared when the reply is read (mbfb_bytes_to_bits). */
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
    case MBFB_FC_READ_COILS:
    case MBFB_FC_READ_DISCRETE:
    case MBFB_FC_READ_HOLDING:
    case MBFB_FC_READ_INPUT:
        return rsp[2] == len - 3 ? MBFB_OK : MBFB_E_BADREPLY;
    case MBFB_FC_WRITE_COIL:     /* echo of address and value (FF 00 / 00 00) */
    case MBFB_FC_WRITE_SINGLE:   /* echo of address and value */
    case MBFB_FC_WRITE_COILS:    /* echo of address and count */
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
    case MBFB_FC_READ_COILS:
    case MBFB_FC_READ_DISCRETE:
    case MBFB_FC_READ_HOLDING:
    case MBFB_FC_READ_INPUT:
        if (slave == 0 || count < 1 || count > mbfb_read_max(fc))
            return MBFB_E_INVAL; /* broadcast reads get no reply: refused */
        break;
    case MBFB_FC_WRITE_COIL:
    case MBFB_FC_WRITE_SINGLE:
        if (count != 1 || values == NULL)
            return MBFB_E_INVAL;
        break;
    case MBFB_FC_WRITE_COILS:
        if (count < 1 || count > MBFB_MAX_WRITE_BITS || values == NULL)
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

/* Bytes on the wire of an RTU reply from its header (mbfb_internal.h). */
int mbfb_rtu_reply_wire_len(const uint8_t *b, int got)
{
    if (got < 2)
        return -1;
    if (b[1] & MBFB_EXCEPTION_BIT)
        return 5; /* slave, fc | MBFB_EXCEPTION_BIT, code, CRC */
    if (mbfb_fc_is_read(b[1]))
        return got < 3 ? -1 : 3 + b[2] + 2; /* slave, fc, byte count, data, CRC */
    if (mbfb_fc_is_write(b[1]))
        return 8; /* slave, fc, address, value / count, CRC */
    return 0;
}

/* Length of a whole reply frame (slave + PDU + CRC) starting at b (n bytes there); 0 if it
 * is not one or not complete. */
static int rtu_reply_len(const uint8_t *b, int n)
{
    int len = n < 5 ? 0 : mbfb_rtu_reply_wire_len(b, n);
    return len > 0 && len <= n ? len : 0;
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
