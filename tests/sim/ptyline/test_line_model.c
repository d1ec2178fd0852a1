/* Unit test of the line model (src/line.c) on synthetic clocks: every expected
 * value is derived by hand from the character time, so nothing here depends on
 * how fast the machine is. */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "line.h"

static int failures;
#define CHECK(cond)                                                                 \
    do {                                                                            \
        if (!(cond)) {                                                              \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
            failures++;                                                             \
        }                                                                           \
    } while (0)

#define T0 1000000000LL /* an arbitrary start of the synthetic clock */

static pl_frame logged[16];
static int n_logged;

static void keep_frame(const pl_frame *f, void *user)
{
    (void)user;
    if (n_logged < 16)
        logged[n_logged++] = *f;
}

static void init(pl_line *l, long baud, const char *fmt, int paced, int lo, int hi,
                 uint64_t seed)
{
    n_logged = 0;
    int rc = pl_line_init(l, baud, pl_format_bits(fmt), paced, 64, lo, hi, seed, keep_frame, NULL);
    CHECK(rc == 0);
}

static void send(pl_line *l, int dir, const uint8_t *b, size_t n, int64_t t)
{
    for (size_t i = 0; i < n; i++)
        CHECK(pl_line_send(l, dir, b[i], t) == 0);
}

/* Takes everything due by t from dir; returns the count, bytes in out. */
static size_t drain(pl_line *l, int dir, int64_t t, uint8_t *out)
{
    return pl_line_take_due(l, dir, t, out, 64);
}

static void test_format_bits(void)
{
    CHECK(pl_format_bits("8N2") == 11);
    CHECK(pl_format_bits("8E1") == 11);
    CHECK(pl_format_bits("8O1") == 11);
    CHECK(pl_format_bits("8N1") == 10);
    CHECK(pl_format_bits("7E1") == 10);
    CHECK(pl_format_bits("7N1") == 9);
    const char *bad[] = {"8X1", "9N1", "4N1", "8N3", "8N", "8N21", "", "n81"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        errno = 0;
        CHECK(pl_format_bits(bad[i]) == -1 && errno == EINVAL);
    }
    CHECK(pl_format_bits(NULL) == -1);
}

static void test_pacing(void)
{
    pl_line l;
    init(&l, 9600, "8N2", 1, 0, 0, 1);
    int64_t c = l.char_ns;
    CHECK(c == 1145833); /* 11 bits / 9600 baud */
    CHECK(l.t35_ns == 4010416 && l.t15_ns == 1718750 && l.bits44_ns == 4583333);
    const uint8_t msg[3] = {0x01, 0x03, 0xFF};
    uint8_t out[64];
    send(&l, PL_M2S, msg, 3, T0);
    CHECK(pl_line_next_deadline(&l) == T0 + c);
    CHECK(drain(&l, PL_M2S, T0 + c - 1, out) == 0);
    CHECK(drain(&l, PL_M2S, T0 + c, out) == 1 && out[0] == 0x01);
    CHECK(drain(&l, PL_M2S, T0 + 3 * c, out) == 2 && out[0] == 0x03 && out[1] == 0xFF);
    /* 1 character later: the same frame; a byte arriving while the line still
     * sends queues behind, without a gap. */
    send(&l, PL_M2S, msg, 1, T0 + 4 * c);
    send(&l, PL_M2S, msg, 1, T0 + 4 * c + 10);
    CHECK(drain(&l, PL_M2S, T0 + 6 * c - 1, out) == 1);
    CHECK(drain(&l, PL_M2S, T0 + 6 * c, out) == 1);
    CHECK(l.dir[PL_M2S].frames == 1 && l.dir[PL_M2S].bytes == 5 && l.dir[PL_M2S].intra_gaps == 0);
    CHECK(l.dir[PL_M2S].busy_ns == 5 * c && pl_line_busy_ns(&l) == 5 * c);
    pl_line_free(&l);
}

static void test_no_pace(void)
{
    pl_line l;
    init(&l, 9600, "8N2", 0, 0, 0, 1);
    uint8_t out[64];
    const uint8_t msg[4] = {1, 2, 3, 4};
    send(&l, PL_M2S, msg, 4, T0);
    CHECK(drain(&l, PL_M2S, T0, out) == 4 && memcmp(out, msg, 4) == 0);
    CHECK(l.dir[PL_M2S].busy_ns == 4 * l.char_ns); /* nominal line time */
    send(&l, PL_S2M, msg, 4, T0); /* no wire, so no collision */
    CHECK(l.dir[PL_S2M].collisions == 0 && l.dir[PL_M2S].collided_bytes == 0);
    pl_line_free(&l);
}

/* Request/reply traffic with hand-placed gaps: frames, short gaps, latency. */
static void test_gaps_and_latency(void)
{
    pl_line l;
    init(&l, 9600, "8N2", 1, 0, 0, 1);
    int64_t c = l.char_ns, t = T0;
    const uint8_t req[8] = {1, 3, 0, 0, 0, 1, 0x84, 0x0A}, rep[7] = {1, 3, 2, 0, 0x64, 0xB9, 0xAF};
    /* gap before each request (after the previous reply), in characters * 10 */
    const int gap10[4] = {0, 20, 38, 100};
    for (int i = 0; i < 4; i++) {
        if (i > 0)
            t += gap10[i] * c / 10;
        send(&l, PL_M2S, req, 8, t);
        t += 8 * c + 5 * c; /* reply 5 characters after the request's end */
        send(&l, PL_S2M, rep, 7, t);
        t += 7 * c;
    }
    pl_line_expire(&l, t + l.t35_ns);
    CHECK(l.dir[PL_M2S].frames == 4 && l.dir[PL_S2M].frames == 4);
    CHECK(l.dir[PL_M2S].bytes == 32 && l.dir[PL_S2M].bytes == 28);
    CHECK(l.req_gap.count == 3);                       /* the first request has no gap */
    CHECK(l.short_35 == 1);                            /* 2.0 characters */
    CHECK(l.short_44 == 2);                            /* 2.0 and 3.8 (41.8 bits) */
    CHECK(l.short_gap.count == 1 && l.short_gap.min_ns == 2 * c);
    CHECK(l.req_gap.min_ns == 2 * c && l.req_gap.max_ns == 10 * c);
    CHECK(l.latency.count == 4 && l.latency.min_ns == 5 * c && l.latency.max_ns == 5 * c);
    CHECK(l.dir[PL_M2S].intra_gaps == 0 && l.dir[PL_M2S].collisions == 0);
    /* the log: 8 frames in line order, with their bytes and start times */
    CHECK(n_logged == 8);
    CHECK(logged[0].dir == PL_M2S && logged[0].start_ns == T0 && logged[0].len == 8 &&
          memcmp(logged[0].data, req, 8) == 0 && !logged[0].collided);
    CHECK(logged[1].dir == PL_S2M && logged[1].start_ns == T0 + 13 * c && logged[1].len == 7 &&
          memcmp(logged[1].data, rep, 7) == 0);
    CHECK(logged[2].dir == PL_M2S && logged[2].start_ns == T0 + 20 * c + 2 * c);
    pl_line_free(&l);
}

/* One direction only: t3.5 splits frames; 1.5 < gap < 3.5 is an intra-frame gap. */
static void test_frames_one_way(void)
{
    pl_line l;
    init(&l, 19200, "8E1", 1, 0, 0, 1);
    int64_t c = l.char_ns, t = T0;
    const uint8_t b[2] = {0xAA, 0x55};
    send(&l, PL_M2S, b, 2, t);
    t += 2 * c + c;           /* 1 character: same frame, not counted */
    send(&l, PL_M2S, b, 2, t);
    t += 2 * c + 2 * c;       /* 2 characters: same frame, an intra-frame gap */
    send(&l, PL_M2S, b, 2, t);
    t += 2 * c + l.t35_ns;    /* exactly 3.5 characters: a new frame */
    send(&l, PL_M2S, b, 2, t);
    CHECK(l.dir[PL_M2S].frames == 2 && l.dir[PL_M2S].intra_gaps == 1);
    CHECK(l.req_gap.count == 1 && l.short_35 == 0 && l.req_gap.min_ns >= l.t35_ns);
    CHECK(pl_line_next_deadline(&l) == T0 + c); /* the first byte is due */
    pl_line_expire(&l, t + 2 * c + l.t35_ns - 1);
    CHECK(n_logged == 1 && logged[0].len == 6);
    pl_line_expire(&l, t + 2 * c + l.t35_ns);
    CHECK(n_logged == 2 && logged[1].len == 2);
    pl_line_free(&l);
}

static void test_collision(void)
{
    pl_line l;
    init(&l, 9600, "8N2", 1, 0, 0, 1);
    int64_t c = l.char_ns;
    uint8_t m[10], out[64];
    memset(m, 0xF0, sizeof m);
    const uint8_t s = 0x3C;
    send(&l, PL_M2S, m, 10, T0);
    send(&l, PL_S2M, &s, 1, T0 + 35 * c / 10); /* S talks into bytes 3 and 4 of M */
    CHECK(l.dir[PL_S2M].collisions == 1 && l.dir[PL_M2S].collisions == 0);
    CHECK(l.dir[PL_S2M].collided_bytes == 1 && l.dir[PL_M2S].collided_bytes == 2);
    CHECK(l.overlap_ns == c && pl_line_busy_ns(&l) == 10 * c);
    /* S's second byte (into M's 4 and 5) continues the same collision */
    send(&l, PL_S2M, &s, 1, T0 + 35 * c / 10 + 1);
    CHECK(l.dir[PL_S2M].collisions == 1 && l.dir[PL_S2M].collided_bytes == 2);
    CHECK(l.dir[PL_M2S].collided_bytes == 3 && pl_line_busy_ns(&l) == 10 * c);
    CHECK(drain(&l, PL_M2S, T0 + 10 * c, out) == 10);
    CHECK(out[2] == 0xF0 && out[3] == 0x30 && out[4] == 0x30 && out[5] == 0x30 &&
          out[6] == 0xF0); /* wired-AND of 0xF0 and 0x3C */
    CHECK(drain(&l, PL_S2M, T0 + 10 * c, out) == 2 && out[0] == 0x30 && out[1] == 0x30);
    /* a new S frame well after the line went quiet is no collision */
    send(&l, PL_S2M, &s, 1, T0 + 20 * c);
    CHECK(l.dir[PL_S2M].collisions == 1 && l.dir[PL_S2M].collided_bytes == 2);
    pl_line_expire(&l, PL_NEVER);
    CHECK(n_logged == 3 && logged[0].collided && logged[1].collided && !logged[2].collided);
    CHECK(l.latency.count == 0); /* a reply into the request is not a latency */
    pl_line_free(&l);
}

static void test_turnaround(void)
{
    pl_line a, b;
    init(&a, 9600, "8N2", 1, 1, 10, 42);
    init(&b, 9600, "8N2", 1, 1, 10, 42);
    int64_t c = a.char_ns, t = T0, lo = -1, hi = -1;
    const uint8_t q = 0x11, r[3] = {1, 2, 3};
    for (int i = 0; i < 50; i++) {
        send(&a, PL_M2S, &q, 1, t);
        send(&b, PL_M2S, &q, 1, t);
        t += c; /* the simulator answers the instant the request has arrived */
        send(&a, PL_S2M, r, 3, t);
        send(&b, PL_S2M, r, 3, t);
        pl_byte *first = &a.q[PL_S2M].buf[(a.q[PL_S2M].head + a.q[PL_S2M].len - 3) % 64];
        int64_t d = first->start_ns - t;
        CHECK(d >= 1000000 && d <= 10000000);
        CHECK(first->end_ns == first->start_ns + c);
        lo = (lo < 0 || d < lo) ? d : lo;
        hi = d > hi ? d : hi;
        uint8_t out[64];
        t = first->start_ns + 3 * c + 20 * c;
        drain(&a, PL_M2S, t, out);
        drain(&a, PL_S2M, t, out);
        drain(&b, PL_M2S, t, out);
        drain(&b, PL_S2M, t, out);
    }
    CHECK(hi - lo > 3000000); /* the delays spread over the range */
    CHECK(a.latency.count == 50 && a.latency.min_ns == b.latency.min_ns &&
          a.latency.max_ns == b.latency.max_ns && a.latency.sum_ns == b.latency.sum_ns);
    CHECK(a.latency.min_ns >= 1000000 && a.latency.max_ns <= 10000000);
    CHECK(a.dir[PL_S2M].frames == 50 && a.dir[PL_S2M].intra_gaps == 0);
    pl_line_free(&a);
    pl_line_free(&b);
}

static void test_limits(void)
{
    pl_line l;
    CHECK(pl_line_init(&l, 0, 11, 1, 64, 0, 0, 1, NULL, NULL) == -1 && errno == EINVAL);
    CHECK(pl_line_init(&l, 9600, 11, 1, 64, 5, 2, 1, NULL, NULL) == -1 && errno == EINVAL);
    init(&l, 9600, "8N2", 1, 0, 0, 1);
    const uint8_t b = 0;
    for (int i = 0; i < 64; i++)
        CHECK(pl_line_send(&l, PL_M2S, b, T0) == 0);
    CHECK(pl_line_room(&l, PL_M2S) == 0 && pl_line_room(&l, PL_S2M) == 64);
    errno = 0;
    CHECK(pl_line_send(&l, PL_M2S, b, T0) == -1 && errno == ENOBUFS);
    pl_line_dropped(&l, PL_M2S, 5);
    CHECK(l.dir[PL_M2S].dropped_bytes == 5);
    pl_line_free(&l);
}

int main(void)
{
    test_format_bits();
    test_pacing();
    test_no_pace();
    test_gaps_and_latency();
    test_frames_one_way();
    test_collision();
    test_turnaround();
    test_limits();
    if (failures == 0)
        printf("line model: all checks passed\n");
    return failures == 0 ? 0 : 1;
}
