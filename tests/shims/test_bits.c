/*
 * test_bits.c - coils and discrete inputs (FC01, FC02, FC05, FC15) in each serial framing,
 * against the scripted peer on the test line (it packs and unpacks bits with its own code):
 *   reads          the Modbus application protocol's examples (6.1, 6.2): the request on
 *                  the wire byte for byte, the bits packed into words (LSB first), the
 *                  take's count in bits, a take into fewer words
 *   writes         FC05 ON / OFF and FC15 (6.5, 6.11) byte for byte; the peer holds them
 *   exception      a read past the peer's bits: exception 2, not retried
 *   bad count      a reply whose byte count is not ceil(n / 8): BADREPLY, never data
 *   echo lost      a coil write applied and its echo lost: DONE by a read-back with FC01 of
 *                  the written coils, applied once; not applied: IDEMPOTENT sent again,
 *                  ONCE ends UNCONFIRMED, sent once
 *   plans          bit items packed into the snapshot beside registers; limits in words
 *   trigger        a refresh now on a plan whose period has not elapsed
 *   on demand      MBFB_PERIOD_ON_DEMAND: one refresh when set, then one per trigger
 */
#include <string.h>

#include "mbfb_test.h"

#define T_MS 200
#define BAUD 38400

static peer_t P;
static int framing;
static int writes_seen, applied; /* __atomic: coil write frames heard / applied */
static int mode; /* __atomic: the test sets it, the peer's thread reads it */
enum { M_NORMAL, M_ECHO_LOST, M_NOT_APPLIED, M_BAD_COUNT };

/* The peer: coil write number 0 misbehaves as `mode` says (M_BAD_COUNT: every FC01 reply
 * has one byte too many, counted in its byte count); everything else peer_answer. */
static void bits_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    int first, m = __atomic_load_n(&mode, __ATOMIC_ACQUIRE);
    if (m == M_BAD_COUNT && f[1] == 1) {
        int cnt = f[4] << 8 | f[5], nb = (cnt + 7) / 8 + 1;
        uint8_t out[300] = {f[0], 1, (uint8_t)nb};
        peer_reply_frame(p, r, out, 3 + nb);
        return;
    }
    if (f[1] != 5 && f[1] != 15) {
        peer_answer(p, n, f, len, r);
        return;
    }
    first = __atomic_fetch_add(&writes_seen, 1, __ATOMIC_ACQ_REL) == 0;
    if (first && m == M_NOT_APPLIED)
        return; /* not heard: nothing applied, no echo */
    peer_answer(p, n, f, len, r);
    __atomic_fetch_add(&applied, 1, __ATOMIC_ACQ_REL);
    if (first && m == M_ECHO_LOST)
        r->len = 0;
}

static int setup(int m, int retries)
{
    __atomic_store_n(&mode, m, __ATOMIC_RELEASE);
    __atomic_store_n(&writes_seen, 0, __ATOMIC_RELEASE);
    __atomic_store_n(&applied, 0, __ATOMIC_RELEASE);
    return t_serial_dev(&P, bits_peer, framing, BAUD, T_MS, retries);
}

static void teardown(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

/* Request i as the peer heard it equals frame (slave + PDU, hex) in this framing, its
 * check bytes made by the peer's own CRC / LRC (RTU without CRC: 00 00). */
static void check_wire(int i, const char *frame_hex)
{
    uint8_t f[PEER_BUF], want[PEER_BUF], got[PEER_BUF];
    int n = t_hex(frame_hex, f), w = 0, g = peer_raw(&P, i, got);
    static const char hx[] = "0123456789ABCDEF";

    if (framing == MBFB_FRAMING_ASCII) {
        uint8_t lrc = peer_lrc(f, n);
        want[w++] = ':';
        for (int k = 0; k <= n; k++) {
            uint8_t b = k < n ? f[k] : lrc;
            want[w++] = (uint8_t)hx[b >> 4];
            want[w++] = (uint8_t)hx[b & 15];
        }
        want[w++] = '\r';
        want[w++] = '\n';
    } else {
        uint16_t crc = framing == MBFB_FRAMING_RTU ? peer_crc16(f, n) : 0;
        memcpy(want, f, (size_t)n);
        want[n] = (uint8_t)(crc & 0xFF);
        want[n + 1] = (uint8_t)(crc >> 8);
        w = n + 2;
    }
    CHECK_EQ(g, w);
    CHECK(g == w && memcmp(got, want, (size_t)w) == 0);
}

/* Set the peer's bits addr.. from the wire's bytes (hex), LSB first. */
static void set_bits(int fc, int addr, int n, const char *bytes_hex)
{
    uint8_t b[PEER_BUF];
    t_hex(bytes_hex, b);
    for (int i = 0; i < n; i++)
        peer_set_bit(&P, fc, 1, addr + i, (b[i / 8] >> (i % 8)) & 1);
}

static void reads(void)
{
    uint16_t v[8];
    int dev = setup(M_NORMAL, 1), h;

    set_bits(1, 0x13, 37, "CD 6B B2 0E 1B");
    set_bits(2, 0xC4, 22, "AC DB 35");
    memset(v, 0xAA, sizeof v);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 0x13, 37, NULL, v, 8), 37);
    check_wire(0, "01 01 00 13 00 25");
    CHECK_EQ(v[0], 0x6BCD);
    CHECK_EQ(v[1], 0x0EB2);
    CHECK_EQ(v[2], 0x001B);
    CHECK_EQ(v[3], 0xAAAA); /* 3 words taken, no more */
    CHECK_EQ(t_run(dev, MBFB_FC_READ_DISCRETE, 0xC4, 22, NULL, v, 8), 22);
    check_wire(1, "01 02 00 C4 00 16");
    CHECK_EQ(v[0], 0xDBAC);
    CHECK_EQ(v[1], 0x0035);
    /* a take into one word gets 16 of the 22 bits */
    h = mbfb_post(dev, MBFB_FC_READ_DISCRETE, 0xC4, 22, NULL);
    CHECK(h > 0);
    t_wait(h);
    v[1] = 0x5555;
    CHECK_EQ(mbfb_take(h, v, 1), 16);
    CHECK_EQ(v[0], 0xDBAC);
    CHECK_EQ(v[1], 0x5555);
    /* all the peer's 256 coils, taken into 8 words: 128 bits */
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 0, 256, NULL, v, 8), 128);
    CHECK_EQ(mbfb_post(dev, MBFB_FC_READ_COILS, 0, MBFB_MAX_READ_BITS + 1, NULL),
             -MBFB_E_INVAL);
    CHECK_EQ(peer_count(&P), 4);
    CHECK_EQ(t_diag(dev).retries, 0);
    teardown();
}

static void writes(void)
{
    uint16_t v[2];
    int dev = setup(M_NORMAL, 1);

    v[0] = 1;
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COIL, 0xAC, 1, v, MBFB_WRITE_ONCE), 0);
    check_wire(0, "01 05 00 AC FF 00");
    CHECK_EQ(peer_coil(&P, 1, 0xAC), 1);
    v[0] = 0;
    CHECK_EQ(t_run(dev, MBFB_FC_WRITE_COIL, 0xAC, 1, v, NULL, 0), 0);
    check_wire(1, "01 05 00 AC 00 00");
    CHECK_EQ(peer_coil(&P, 1, 0xAC), 0);
    v[0] = 0xFDCD; /* 10 coils 1011 0011 10: the bits past them are not sent */
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COILS, 0x13, 10, v, MBFB_WRITE_IDEMPOTENT), 0);
    check_wire(2, "01 0F 00 13 00 0A 02 CD 01");
    for (int i = 0; i < 10; i++)
        CHECK_EQ(peer_coil(&P, 1, 0x13 + i), (0x01CD >> i) & 1);
    CHECK_EQ(peer_coil(&P, 1, 0x13 + 10), 0);
    CHECK_EQ(peer_count(&P), 3); /* echoes: no read-back */
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 3);
    teardown();
}

static void exception_read(void)
{
    uint16_t v[2];
    int dev = setup(M_NORMAL, 3);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 250, 10, NULL, v, 2), -(MBFB_E_EXCEPTION_BASE + 2));
    CHECK_EQ(t_run(dev, MBFB_FC_WRITE_COILS, 250, 10, v, NULL, 0),
             -(MBFB_E_EXCEPTION_BASE + 2));
    CHECK_EQ(peer_count(&P), 2); /* definite answers: not retried */
    CHECK_EQ(t_diag(dev).exceptions, 2);
    teardown();
}

static void bad_count(void)
{
    uint16_t v[4] = {0x1111, 0x2222, 0x3333, 0x4444};
    int dev = setup(M_BAD_COUNT, 1);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 0x13, 37, NULL, v, 4), -MBFB_E_BADREPLY);
    CHECK_EQ(v[0], 0x1111); /* nothing delivered */
    CHECK_EQ(t_diag(dev).bad_replies, 2); /* the request and its one retry (a resync read) */
    CHECK_EQ(t_diag(dev).good, 0);
    __atomic_store_n(&mode, M_NORMAL, __ATOMIC_RELEASE); /* the device answers right again: the next read is its own */
    CHECK_EQ(t_run(dev, MBFB_FC_READ_DISCRETE, 0xC4, 22, NULL, v, 4), 22);
    teardown();
}

static void echo_lost(void)
{
    uint16_t v[2] = {1, 0};
    uint8_t raw[PEER_BUF], fr[8];
    int dev = setup(M_ECHO_LOST, 3);

    /* FC05 applied, echo lost: the read-back (FC01 of that coil) shows it */
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COIL, 40, 1, v, MBFB_WRITE_ONCE), 0);
    CHECK_EQ(peer_coil(&P, 1, 40), 1);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 1);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 1); /* never sent twice */
    CHECK_EQ(peer_count(&P), 2);
    check_wire(1, "01 01 00 28 00 01");
    CHECK_EQ(t_diag(dev).resyncs, 1);
    teardown();

    /* FC15 ONCE applied, echo lost: DONE by FC01 of the 10 coils */
    dev = setup(M_ECHO_LOST, 3);
    v[0] = 0x0235;
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COILS, 100, 10, v, MBFB_WRITE_ONCE), 0);
    for (int i = 0; i < 10; i++)
        CHECK_EQ(peer_coil(&P, 1, 100 + i), (0x0235 >> i) & 1);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 1);
    CHECK_EQ(peer_count(&P), 2);
    check_wire(1, "01 01 00 64 00 0A");
    teardown();

    /* FC15 ONCE not applied: the read-back shows the old coils -> UNCONFIRMED, sent once */
    dev = setup(M_NOT_APPLIED, 3);
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COILS, 100, 10, v, MBFB_WRITE_ONCE),
             -MBFB_E_UNCONFIRMED);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 1);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 0);
    teardown();

    /* FC05 IDEMPOTENT not applied: read back OFF -> sent again, applied once */
    dev = setup(M_NOT_APPLIED, 3);
    v[0] = 1;
    CHECK_EQ(t_run_write(dev, MBFB_FC_WRITE_COIL, 7, 1, v, MBFB_WRITE_IDEMPOTENT), 0);
    CHECK_EQ(peer_coil(&P, 1, 7), 1);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 2);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 1);
    /* the second FC05 is the last request the peer heard */
    CHECK(peer_raw(&P, peer_count(&P) - 1, raw) > 0);
    t_hex("01 05 00 07 FF 00", fr);
    CHECK(framing == MBFB_FRAMING_ASCII || memcmp(raw, fr, 6) == 0);
    teardown();
}

/* Wait (at most 10 s) for a snapshot newer than *seq; 1 when one came. */
static int wait_snap(int plan, uint32_t *seq, mbfb_snap_t *s)
{
    for (int64_t end = t_now_us() + 10000000; t_now_us() < end; t_sleep_ms(1))
        if (mbfb_plan_take(plan, seq, s) == 1)
            return 1;
    return 0;
}

static void plans(void)
{
    mbfb_plan_item_t it[4] = {{MBFB_FC_READ_COILS, 0x13, 37, MBFB_TIER_EVERY},
                              {MBFB_FC_READ_HOLDING, 0, 2, MBFB_TIER_EVERY},
                              {MBFB_FC_READ_DISCRETE, 0xC4, 22, MBFB_TIER_EVERY},
                              {MBFB_FC_READ_COILS, 0, MBFB_MAX_READ_BITS, MBFB_TIER_EVERY}};
    mbfb_snap_t s;
    uint32_t seq = 0;
    int dev = setup(M_NORMAL, 1), plan = mbfb_plan_open(dev);

    set_bits(1, 0x13, 37, "CD 6B B2 0E 1B");
    set_bits(2, 0xC4, 22, "AC DB 35");
    peer_set_reg(&P, 1, 0, 0x1234);
    peer_set_reg(&P, 1, 1, 0x5678);
    /* limits in words: 2000 bits are 125 words, one more item is too many */
    CHECK_EQ(mbfb_plan_set(plan, &it[3], 1, 60000, 0), 0);
    CHECK_EQ(mbfb_plan_stop(plan), 0);
    CHECK_EQ(mbfb_plan_set(plan, &it[1], 3, -2, 0), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_plan_set(plan, &it[2], 2, 60000, 0), -MBFB_E_INVAL); /* 2 + 125 */
    it[3].count = MBFB_MAX_READ_BITS + 1;
    CHECK_EQ(mbfb_plan_set(plan, &it[3], 1, 60000, 0), -MBFB_E_INVAL);
    it[3].count = 16 * (MBFB_PLAN_MAX_WORDS - 3 - 2 - 2); /* the rest exactly */
    CHECK_EQ(mbfb_plan_set(plan, it, 4, 60000, 0), 0);
    CHECK_EQ(mbfb_plan_stop(plan), 0);
    /* a mixed plan: words 0..2 coils, 3..4 registers, 5..6 inputs (a refresh begun under
     * the settings above, past the peer's bits, may publish its exception first) */
    CHECK_EQ(mbfb_plan_set(plan, it, 3, 0, 0), 0);
    while (wait_snap(plan, &seq, &s) && s.result != MBFB_OK) {
    }
    CHECK_EQ(s.result, MBFB_OK);
    CHECK_EQ(s.read_mask, 7);
    CHECK_EQ(s.words[0], 0x6BCD);
    CHECK_EQ(s.words[1], 0x0EB2);
    CHECK_EQ(s.words[2], 0x001B);
    CHECK_EQ(s.words[3], 0x1234);
    CHECK_EQ(s.words[4], 0x5678);
    CHECK_EQ(s.words[5], 0xDBAC);
    CHECK_EQ(s.words[6], 0x0035);
    CHECK_EQ(mbfb_plan_stop(plan), 0);
    teardown();
}

static void trigger(void)
{
    mbfb_plan_item_t it = {MBFB_FC_READ_COILS, 0x13, 37, MBFB_TIER_EVERY};
    mbfb_snap_t s;
    uint32_t seq = 0;
    int dev = setup(M_NORMAL, 1), plan = mbfb_plan_open(dev), n;

    CHECK_EQ(mbfb_plan_trigger(-1), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_plan_set(plan, &it, 1, 60000, 0), 0); /* due again in a minute */
    CHECK(wait_snap(plan, &seq, &s));
    CHECK_EQ(seq, 1);
    n = peer_count(&P);
    set_bits(1, 0x13, 8, "5A");
    CHECK_EQ(mbfb_plan_trigger(plan), 0);
    CHECK(wait_snap(plan, &seq, &s)); /* long before the minute */
    CHECK_EQ(seq, 2);
    CHECK_EQ(s.words[0] & 0xFF, 0x5A); /* read after the trigger */
    CHECK_EQ(peer_count(&P), n + 1);
    teardown();
}

static void on_demand(void)
{
    mbfb_plan_item_t it = {MBFB_FC_READ_DISCRETE, 0xC4, 22, MBFB_TIER_EVERY};
    mbfb_snap_t s;
    uint32_t seq = 0;
    uint16_t v[2];
    int dev = setup(M_NORMAL, 1), plan = mbfb_plan_open(dev);

    CHECK_EQ(mbfb_plan_set(plan, &it, 1, MBFB_PERIOD_ON_DEMAND, 0), 0);
    CHECK(wait_snap(plan, &seq, &s)); /* once when set */
    CHECK_EQ(seq, 1);
    /* the worker runs the plan due first: requests served after it show it is not due */
    for (int i = 0; i < 3; i++)
        CHECK_EQ(t_run(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0);
    CHECK_EQ(peer_count(&P), 4);
    set_bits(2, 0xC4, 8, "C3");
    CHECK_EQ(mbfb_plan_trigger(plan), 0);
    CHECK(wait_snap(plan, &seq, &s));
    CHECK_EQ(seq, 2);
    CHECK_EQ(s.words[0] & 0xFF, 0xC3);
    for (int i = 0; i < 2; i++)
        CHECK_EQ(t_run(dev, MBFB_FC_READ_HOLDING, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0);
    CHECK_EQ(peer_count(&P), 7);
    teardown();
}

int main(void)
{
    static const t_case_t cases[] = {
        {reads, "reads"},
        {writes, "writes"},
        {exception_read, "exception"},
        {bad_count, "bad byte count"},
        {echo_lost, "coil write: echo lost, not applied"},
        {plans, "plans"},
        {trigger, "trigger"},
        {on_demand, "on demand"},
    };
    return t_serial_scenarios("test_bits", &framing, cases,
                              (int)(sizeof cases / sizeof cases[0]));
}
