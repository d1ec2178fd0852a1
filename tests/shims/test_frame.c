/*
 * test_frame.c - CRC-16, LRC and request frames against every worked frame of the
 * manuals (as the maps keep them: maps/<device>.json, "frames") and the Modbus application
 * protocol's coil and discrete-input examples, reply validation, bits packed into words,
 * argument checks, timing values, error texts. No I/O.
 */
#include <string.h>

#include "mbfb_internal.h"
#include "mbfb_test.h"

/* Every RTU frame with its CRC, as printed (or derived) in the manuals. */
static const char *const rtu_frames[] = {
    /* 1.9 SetPro MV-D94 / VD, printed in both manuals */
    "01 03 00 00 00 01 84 0A", "01 03 02 03 E8 B8 FA", "01 04 10 00 00 01 35 0A",
    "01 04 02 00 1B F9 3B", "01 06 00 00 01 F4 89 DD",
    /* 1.9 derived */
    "01 03 00 00 00 22 C5 D3", "01 06 00 0F 00 0C B9 CC", "01 06 00 0F 00 17 F9 C7",
    "01 06 00 01 FF F6 19 BC", "00 06 00 00 01 F4 88 0C", "01 83 02 C0 F1",
    "01 85 01 83 50",
    /* 2.8 MT-S9 RTU, printed */
    "01 03 00 00 00 02 C4 0B", "01 03 04 00 00 00 02 7B F2", "01 06 00 00 00 02 08 0B",
    "01 10 00 00 00 02 04 00 0A 01 02 53 FC", "01 10 00 00 00 02 41 C8",
    /* 2.8 no-CRC reply as corrected (FA 33 belongs to data 0000 0000), derived */
    "01 03 04 00 00 00 00 FA 33", "01 03 00 00 00 0A C5 CD", "01 03 00 02 00 02 65 CB",
    /* 3.12 FDC (address 01 assumed; CRCs computed, the manual prints none) */
    "01 10 00 00 00 34 C1 DE", "01 03 00 80 00 04 45 E1", "01 03 00 40 00 04 45 DD",
    "01 06 00 48 68 25 E7 C7", "01 06 00 48 68 28 26 02", "01 06 00 48 68 27 66 06",
    "01 03 00 00 00 50 45 F6", "01 03 00 00 00 4F 04 3E", "01 06 00 48 68 2D E6 01",
    "01 86 03 02 61", "01 81 01 81 90",
    /* coils and discrete inputs: the Modbus application protocol's examples (1.1b3, 6.1,
     * 6.2, 6.5, 6.11) on slave 0x11, as the Modicon / Simply Modbus RTU examples print them */
    "11 01 00 13 00 25 0E 84", "11 01 05 CD 6B B2 0E 1B 45 E6", "11 02 00 C4 00 16 BA A9",
    "11 02 03 AC DB 35 20 18", "11 05 00 AC FF 00 4E 8B", "11 0F 00 13 00 0A 02 CD 01 BF 0B",
    "11 0F 00 13 00 0A 26 99",
};


/* 2.5 / 4: MT-S9 ASCII frames; the FC16 query is printed with FA, DC is correct. */
static const char *const ascii_frames[][2] = {
    {":010300000002FA\r\n", "FA"},
    {":01030407140714C2\r\n", "C2"},
    {":010600000002F7\r\n", "F7"},
    {":01100000000204000A0102DC\r\n", "DC"},
    {":011000000002ED\r\n", "ED"},
};

static void test_crc(void)
{
    uint8_t f[PEER_BUF];
    t_scenario = "crc";
    CHECK_EQ(mbfb_crc16((const uint8_t *)"123456789", 9), 0x4B37); /* catalogue check */
    for (size_t i = 0; i < sizeof rtu_frames / sizeof rtu_frames[0]; i++) {
        int n = t_hex(rtu_frames[i], f);
        uint16_t crc = mbfb_crc16(f, n - 2);
        if ((crc & 0xFF) != f[n - 2] || (crc >> 8) != f[n - 1]) {
            t_failures++;
            fprintf(stderr, "FAIL crc of %s: computed %02X %02X\n", rtu_frames[i],
                    crc & 0xFF, crc >> 8);
        }
        CHECK_EQ(peer_crc16(f, n - 2), crc); /* the test peer's CRC agrees */
    }
    int n = t_hex(fdc_ex1, f);
    CHECK_EQ(n, 113);
    CHECK_EQ(mbfb_crc16(f, n - 2), 0xC38E);
    /* 2.3: the high-word-first candidate gives D3 94, not the printed 53 FC */
    n = t_hex("01 10 00 00 00 02 04 01 02 00 0A", f);
    CHECK_EQ(mbfb_crc16(f, n), 0x94D3);
}

static void test_lrc(void)
{
    uint8_t f[PEER_BUF], lrc[1];
    char hex[PEER_BUF];
    t_scenario = "lrc";
    for (size_t i = 0; i < sizeof ascii_frames / sizeof ascii_frames[0]; i++) {
        size_t len = strlen(ascii_frames[i][0]);
        memcpy(hex, ascii_frames[i][0] + 1, len - 5); /* drop ':', LRC, CR LF */
        hex[len - 5] = 0;
        int n = t_hex(hex, f);
        t_hex(ascii_frames[i][1], lrc);
        CHECK_EQ(mbfb_lrc(f, n), lrc[0]);
        CHECK_EQ(peer_lrc(f, n), lrc[0]);
    }
    /* the manual's misprint: FA is not the LRC of the FC16 query */
    CHECK(mbfb_lrc(f, t_hex("01 10 00 00 00 02 04 00 0A 01 02", f)) != 0xFA);
}

/* mbfb_build_request + CRC reproduces the manuals' request frames byte for byte. */
static void check_request(const char *want, int slave, int fc, int addr, int count,
                          const uint16_t *vals)
{
    uint8_t f[PEER_BUF];
    int n = mbfb_build_request(f, slave, fc, addr, count, vals);
    uint16_t crc = mbfb_crc16(f, n);
    f[n++] = (uint8_t)(crc & 0xFF);
    f[n++] = (uint8_t)(crc >> 8);
    CHECK_HEX(f, n, want);
}

static void test_requests(void)
{
    uint16_t v[MBFB_MAX_READ];
    uint8_t b[PEER_BUF];
    t_scenario = "requests";
    check_request("01 03 00 00 00 01 84 0A", 1, 3, 0, 1, NULL);
    check_request("01 04 10 00 00 01 35 0A", 1, 4, 0x1000, 1, NULL);
    v[0] = 500;
    check_request("01 06 00 00 01 F4 89 DD", 1, 6, 0, 1, v);
    check_request("00 06 00 00 01 F4 88 0C", 0, 6, 0, 1, v);
    v[0] = (uint16_t)-10;
    check_request("01 06 00 01 FF F6 19 BC", 1, 6, 1, 1, v);
    v[0] = 16908298u & 0xFFFF; /* MT-S9: low word first */
    v[1] = 16908298u >> 16;
    check_request("01 10 00 00 00 02 04 00 0A 01 02 53 FC", 1, 16, 0, 2, v);
    v[0] = 0x6825;
    check_request("01 06 00 48 68 25 E7 C7", 1, 6, 72, 1, v);
    check_request("01 03 00 00 00 50 45 F6", 1, 3, 0, 80, NULL);
    int n = t_hex(fdc_ex1, b);
    for (int i = 0; i < 52; i++)
        v[i] = (uint16_t)(b[7 + 2 * i] << 8 | b[8 + 2 * i]);
    check_request(fdc_ex1, 1, 16, 0, 52, v);
    CHECK_EQ(n, 113);

    /* coils and discrete inputs (the printed frames above) */
    check_request("11 01 00 13 00 25 0E 84", 0x11, MBFB_FC_READ_COILS, 0x13, 37, NULL);
    check_request("11 02 00 C4 00 16 BA A9", 0x11, MBFB_FC_READ_DISCRETE, 0xC4, 22, NULL);
    v[0] = 1;
    check_request("11 05 00 AC FF 00 4E 8B", 0x11, MBFB_FC_WRITE_COIL, 0xAC, 1, v);
    v[0] = 0x8000; /* any value but 0 is ON */
    check_request("11 05 00 AC FF 00 4E 8B", 0x11, MBFB_FC_WRITE_COIL, 0xAC, 1, v);
    v[0] = 0;
    n = mbfb_build_request(b, 0x11, MBFB_FC_WRITE_COIL, 0xAC, 1, v);
    CHECK_HEX(b, n, "11 05 00 AC 00 00");
    v[0] = 0x01CD; /* 10 coils: 1 0 1 1 0 0 1 1, 1 0 (6.11) */
    check_request("11 0F 00 13 00 0A 02 CD 01 BF 0B", 0x11, MBFB_FC_WRITE_COILS, 0x13, 10, v);
    v[0] = 0xFDCD; /* bits past the count are not sent */
    check_request("11 0F 00 13 00 0A 02 CD 01 BF 0B", 0x11, MBFB_FC_WRITE_COILS, 0x13, 10, v);
    v[0] = 0x6BCD, v[1] = 0x0EB2, v[2] = 0x001B; /* 37 coils: byte j is byte j % 2 of word j / 2 */
    n = mbfb_build_request(b, 1, MBFB_FC_WRITE_COILS, 0, 37, v);
    CHECK_HEX(b, n, "01 0F 00 00 00 25 05 CD 6B B2 0E 1B");
    for (int i = 0; i < 125; i++)
        v[i] = 0xFFFF;
    CHECK_EQ(mbfb_build_request(b, 1, MBFB_FC_WRITE_COILS, 0, MBFB_MAX_WRITE_BITS, v),
             7 + 246); /* the longest FC15: 246 data bytes, a 253-byte PDU */
    CHECK_EQ(b[6], 246);
}

/* Bits between the wire's bytes and the API's words (LSB first), and the read-back rule. */
static void test_bits(void)
{
    uint8_t q[PEER_BUF], by[PEER_BUF];
    uint16_t w[8], vals[8];
    t_scenario = "bits";
    t_hex("CD 6B B2 0E 1B", by); /* 6.1's 37 coils 20..56 (of 11 01 05 ...) */
    memset(w, 0xAA, sizeof w);
    mbfb_bytes_to_bits(by, 37, w);
    CHECK_EQ(w[0], 0x6BCD);
    CHECK_EQ(w[1], 0x0EB2);
    CHECK_EQ(w[2], 0x001B);
    CHECK_EQ(w[3], 0xAAAA); /* nothing written past MBFB_BIT_WORDS(37) = 3 words */
    CHECK_EQ(MBFB_BIT_WORDS(37), 3);
    t_hex("CD 6B FD", by); /* 19 coils; padding bits set by a sloppy device: cleared */
    mbfb_bytes_to_bits(by, 19, w);
    CHECK_EQ(w[0], 0x6BCD);
    CHECK_EQ(w[1], 0x0005);
    t_hex("AC DB 35", by); /* 6.2's 22 inputs 197..218 */
    mbfb_bytes_to_bits(by, 22, w);
    CHECK_EQ(w[0], 0xDBAC);
    CHECK_EQ(w[1], 0x0035);
    w[0] = 0x1234, w[1] = 0xFF56;
    mbfb_bits_to_bytes(w, 20, by);
    CHECK_HEX(by, 3, "34 12 06");
    /* the read-back shows a write: coils bit for bit, only the written ones */
    vals[0] = 0x01CD;
    w[0] = 0xFDCD;
    CHECK(mbfb_readback_shows(MBFB_FC_WRITE_COILS, 10, vals, w));
    w[0] = 0x01CC;
    CHECK(!mbfb_readback_shows(MBFB_FC_WRITE_COILS, 10, vals, w));
    vals[0] = 0xFFFF, vals[1] = 0x0001, w[0] = 0xFFFF, w[1] = 0xFFF1;
    CHECK(mbfb_readback_shows(MBFB_FC_WRITE_COILS, 17, vals, w));
    w[1] = 0;
    CHECK(!mbfb_readback_shows(MBFB_FC_WRITE_COILS, 17, vals, w));
    vals[0] = 0x8000, w[0] = 1;
    CHECK(mbfb_readback_shows(MBFB_FC_WRITE_COIL, 1, vals, w));
    vals[0] = 0;
    CHECK(!mbfb_readback_shows(MBFB_FC_WRITE_COIL, 1, vals, w));
    vals[0] = 7, w[0] = 7;
    CHECK(mbfb_readback_shows(MBFB_FC_WRITE_SINGLE, 1, vals, w));
    w[0] = 6;
    CHECK(!mbfb_readback_shows(MBFB_FC_WRITE_SINGLE, 1, vals, w));
    /* reply lengths, and the framing of a reply we read ourselves (late replies, RTU over
     * TCP) from its header */
    t_hex("11 01 00 13 00 25", q);
    CHECK_EQ(mbfb_reply_len(q), 3 + 5);
    t_hex("11 02 00 C4 00 16", q);
    CHECK_EQ(mbfb_reply_len(q), 3 + 3);
    t_hex("11 0F 00 13 00 0A 02 CD 01", q);
    CHECK_EQ(mbfb_reply_len(q), 6);
    t_hex("11 01 05", by);
    CHECK_EQ(mbfb_rtu_reply_wire_len(by, 3), 3 + 5 + 2);
    CHECK_EQ(mbfb_rtu_reply_wire_len(by, 2), -1);
    t_hex("11 05 00", by);
    CHECK_EQ(mbfb_rtu_reply_wire_len(by, 2), 8);
    t_hex("11 8F 02", by);
    CHECK_EQ(mbfb_rtu_reply_wire_len(by, 2), 5);
    t_hex("11 07", by);
    CHECK_EQ(mbfb_rtu_reply_wire_len(by, 2), 0);
}

static int check_reply_hex(const char *req_hex, const char *rsp_hex)
{
    uint8_t q[PEER_BUF], r[PEER_BUF];
    t_hex(req_hex, q);
    return mbfb_check_reply(q, r, t_hex(rsp_hex, r));
}

static void test_validation(void)
{
    t_scenario = "validation";
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 03 02 03 E8"), MBFB_OK);
    CHECK_EQ(check_reply_hex("01 04 10 00 00 01", "01 04 02 00 1B"), MBFB_OK);
    CHECK_EQ(check_reply_hex("01 06 00 00 01 F4", "01 06 00 00 01 F4"), MBFB_OK);
    CHECK_EQ(check_reply_hex("01 10 00 00 00 02 04 00 0A 01 02", "01 10 00 00 00 02"),
             MBFB_OK);
    /* wrong slave, wrong function, byte count, length, echoes */
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "02 03 02 03 E8"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 04 02 03 E8"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 02", "01 03 02 03 E8"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 03 04 03 E8"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 03 02 03"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 06 00 00 01 F4", "01 06 00 00 01 F5"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 06 00 00 01 F4", "01 06 00 01 01 F4"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 10 00 00 00 02 04 00 0A 01 02", "01 10 00 00 00 03"),
             MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 10 00 00 00 02 04 00 0A 01 02", "01 10 00 00 00"),
             MBFB_E_BADREPLY);
    /* exceptions (SetPro and FDC manuals) */
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 83 02"), 130);
    CHECK_EQ(check_reply_hex("01 06 00 48 68 25", "01 86 03"), 131);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 86 03"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 83 02 00"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("01 03 00 00 00 01", "01 83 00"), MBFB_E_BADREPLY);

    /* coils and discrete inputs */
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 01 05 CD 6B B2 0E 1B"), MBFB_OK);
    CHECK_EQ(check_reply_hex("11 02 00 C4 00 16", "11 02 03 AC DB 35"), MBFB_OK);
    CHECK_EQ(check_reply_hex("11 05 00 AC FF 00", "11 05 00 AC FF 00"), MBFB_OK);
    CHECK_EQ(check_reply_hex("11 05 00 AC 00 00", "11 05 00 AC 00 00"), MBFB_OK);
    CHECK_EQ(check_reply_hex("11 0F 00 13 00 0A 02 CD 01", "11 0F 00 13 00 0A"), MBFB_OK);
    /* byte count: ceil(37 / 8) = 5, not 2 x 37, not 4 or 6 */
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 01 04 CD 6B B2 0E 1B"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 01 06 CD 6B B2 0E 1B"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 01 05 CD 6B B2 0E"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 01 05 CD 6B B2 0E 1B 00"),
             MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 02 00 C4 00 16", "11 01 03 AC DB 35"), MBFB_E_BADREPLY);
    /* echoes: FC05 value (FF 00 asked, 00 00 echoed), FC15 address and count */
    CHECK_EQ(check_reply_hex("11 05 00 AC FF 00", "11 05 00 AC 00 00"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 05 00 AC FF 00", "11 05 00 AD FF 00"), MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 0F 00 13 00 0A 02 CD 01", "11 0F 00 13 00 0B"),
             MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 0F 00 13 00 0A 02 CD 01", "11 0F 00 14 00 0A"),
             MBFB_E_BADREPLY);
    CHECK_EQ(check_reply_hex("11 01 00 13 00 25", "11 81 02"), 130);
    CHECK_EQ(check_reply_hex("11 0F 00 13 00 0A 02 CD 01", "11 8F 04"), 132);
    CHECK_EQ(check_reply_hex("11 05 00 AC FF 00", "11 8F 02"), MBFB_E_BADREPLY);
}

static void test_args(void)
{
    uint16_t v[130] = {0};
    t_scenario = "args";
    CHECK_EQ(mbfb_check_args(1, 3, 0, 1, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 3, 0, 125, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 3, 0, 126, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 4, 0, 0, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(0, 3, 0, 1, NULL), MBFB_E_INVAL); /* broadcast read */
    CHECK_EQ(mbfb_check_args(0, 6, 0, 1, v), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 6, 0, 1, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 6, 0, 2, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 16, 0, 123, v), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 16, 0, 124, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 7, 0, 1, v), MBFB_E_INVAL);
    /* bits: FC01/02 1..2000, FC05 one coil with its value, FC15 1..1968 */
    CHECK_EQ(mbfb_check_args(1, 1, 0, 1, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 1, 0, MBFB_MAX_READ_BITS, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 2, 0, 2000, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 2, 0, 2001, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 1, 0, 0, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(0, 1, 0, 8, NULL), MBFB_E_INVAL); /* broadcast read */
    CHECK_EQ(mbfb_check_args(1, 2, 65535, 1, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 2, 65535, 2, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 5, 0, 1, v), MBFB_OK);
    CHECK_EQ(mbfb_check_args(0, 5, 0, 1, v), MBFB_OK); /* broadcast write */
    CHECK_EQ(mbfb_check_args(1, 5, 0, 1, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 5, 0, 2, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 15, 0, MBFB_MAX_WRITE_BITS, v), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 15, 0, 1969, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 15, 0, 0, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 15, 0, 8, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 15, 65530, 7, v), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 3, 65535, 1, NULL), MBFB_OK);
    CHECK_EQ(mbfb_check_args(1, 3, 65535, 2, NULL), MBFB_E_INVAL);
    CHECK_EQ(mbfb_check_args(1, 3, -1, 1, NULL), MBFB_E_INVAL);
}

static void test_timing(void)
{
    mbfb_timing_t t;
    t_scenario = "timing";
    mbfb_timing_init(&t, 9600, 'N', 8, 2); /* SetPro 8N2: 11 bits */
    CHECK_EQ(t.char_us, 1146);
    CHECK_EQ(t.gap_us, 4584);   /* 44 bit times > 3.5 chars (4011 us) */
    CHECK_EQ(mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 5), 54380);
    CHECK(mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 253) > 600000);
    mbfb_timing_init(&t, 2400, 'N', 8, 2);
    CHECK(mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 5) >= 150000);
    mbfb_timing_init(&t, 19200, 'E', 8, 1);
    CHECK_EQ(t.char_us, 573);
    CHECK_EQ(t.gap_us, 2292);
    CHECK_EQ(mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 5), 50000);
    mbfb_timing_init(&t, 115200, 'N', 8, 1);
    CHECK_EQ(t.gap_us, 1750); /* Modbus: fixed 1.75 ms above 19200 baud */
    mbfb_timing_init(&t, 9600, 'E', 7, 1);   /* ASCII 7E1: 10 bits */
    CHECK_EQ(t.char_us, 1042);
    CHECK_EQ(mbfb_wire_len(MBFB_FRAMING_ASCII, 6), 17); /* ":010300000002FA\r\n" */
    CHECK_EQ(mbfb_wire_len(MBFB_FRAMING_RTU_NOCRC, 6), 8);
}

static void test_strerror(void)
{
    t_scenario = "strerror";
    for (int i = 0; i <= MBFB_E_NOMEM; i++) {
        CHECK(mbfb_strerror(i) != NULL && mbfb_strerror(i)[0] != 0);
        CHECK(strcmp(mbfb_strerror(i), mbfb_strerror(-i)) == 0);
        if (i > 0)
            CHECK(strcmp(mbfb_strerror(i), mbfb_strerror(i - 1)) != 0);
    }
    CHECK(strstr(mbfb_strerror(-130), "illegal data address") != NULL);
    CHECK(strstr(mbfb_strerror(210), "input") != NULL);
    /* the block input errors each have their own text */
    for (int i = MBFB_E_BAD_SLAVE; i <= MBFB_E_NOT_HELD; i++)
        CHECK(i == MBFB_E_BAD_SLAVE || strcmp(mbfb_strerror(i), mbfb_strerror(i - 1)) != 0);
    CHECK(strstr(mbfb_strerror(MBFB_E_BAD_SLAVE), "247") != NULL);
    CHECK(strstr(mbfb_strerror(-MBFB_E_RANGE), "range") != NULL);
    CHECK(mbfb_strerror(99999) != NULL);
}

int main(void)
{
    test_crc();
    test_lrc();
    test_requests();
    test_validation();
    test_bits();
    test_args();
    test_timing();
    test_strerror();
    return t_done("test_frame");
}
