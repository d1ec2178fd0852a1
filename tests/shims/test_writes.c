/*
 * test_writes.c - confirmed writes (mbfb_post_write), for each serial framing, against a
 * scripted peer on the test line that counts how often each write was applied:
 *   false_fc16     a false confirmation: the device is busy sending a 600 ms
 *                  late echo of write A and does not hear write B; A's echo must not
 *                  confirm B. Both end DONE only once the device holds them, each
 *                  applied exactly once.
 *   echo_lost      applied, echo lost: DONE (by the read-back), applied once
 *   not_applied    not applied, no echo: IDEMPOTENT is sent again, applied once
 *   once_never_twice  not applied, no echo, MBFB_WRITE_ONCE: UNCONFIRMED, sent once
 *   exception      an exception is a definite "not applied": no read-back, no resend
 */
#include <string.h>

#include "mbfb_test.h"

#define T_MS 200
#define BAUD 38400

static peer_t P;
static int framing;
static int applied;     /* writes applied by the peer (under P.lock via peer fn) */
static int writes_seen; /* write frames received */
static int mode;        /* what the peer does with write number 0 */
enum { M_LATE_DEAF, M_ECHO_LOST, M_NOT_APPLIED, M_EXCEPTION };

/* A device whose write number 0 misbehaves as `mode` says; everything else normal. */
static void write_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    int fc = f[1], first;
    (void)n;
    if (fc != 6 && fc != 16) {
        peer_answer(p, n, f, len, r);
        return;
    }
    first = __atomic_fetch_add(&writes_seen, 1, __ATOMIC_ACQ_REL) == 0;
    if (first && mode == M_NOT_APPLIED)
        return; /* not heard: nothing applied, no echo */
    if (first && mode == M_EXCEPTION) {
        uint8_t e[3] = {f[0], (uint8_t)(fc | 0x80), 3};
        peer_reply_frame(p, r, e, 3);
        return;
    }
    peer_answer(p, n, f, len, r); /* applies it and builds the echo */
    __atomic_fetch_add(&applied, 1, __ATOMIC_ACQ_REL);
    if (first && mode == M_ECHO_LOST)
        r->len = 0;
    if (first && mode == M_LATE_DEAF) {
        r->delay_ms = 600;
        r->deaf = 1;
    }
}

static int setup(int m, int retries)
{
    mode = m;
    __atomic_store_n(&applied, 0, __ATOMIC_RELEASE);
    __atomic_store_n(&writes_seen, 0, __ATOMIC_RELEASE);
    return t_serial_dev(&P, write_peer, framing, BAUD, T_MS, retries);
}

static void teardown(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

static uint16_t peer_reg(int addr)
{
    uint16_t v;
    pthread_mutex_lock(&P.lock);
    v = P.regs[1][addr];
    pthread_mutex_unlock(&P.lock);
    return v;
}

static void false_fc16(void)
{
    uint16_t a[2] = {111, 0}, b[2] = {222, 0};
    int dev = setup(M_LATE_DEAF, 3);

    CHECK_EQ(t_run_write(dev, 16, 0, 2, a, MBFB_WRITE_ONCE), 0); /* read back: applied */
    CHECK_EQ(peer_reg(0), 111);
    CHECK_EQ(t_run_write(dev, 16, 0, 2, b, MBFB_WRITE_ONCE), 0);
    CHECK_EQ(peer_reg(0), 222); /* DONE means the device holds it */
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 2); /* each exactly once */
    CHECK(t_diag(dev).resyncs >= 1);
    teardown();

    /* no retries: A's outcome is unknown and cannot be resolved in its one attempt;
     * B, posted at once, is never confirmed by A's late echo */
    dev = setup(M_LATE_DEAF, 0);
    CHECK_EQ(t_run_write(dev, 16, 0, 2, a, MBFB_WRITE_ONCE), -MBFB_E_UNCONFIRMED);
    int rc = t_run_write(dev, 16, 0, 2, b, MBFB_WRITE_ONCE);
    CHECK(rc != 0 || peer_reg(0) == 222); /* DONE only if the device holds B */
    CHECK(__atomic_load_n(&applied, __ATOMIC_ACQUIRE) <= 2);
    teardown();
}

static void echo_lost(void)
{
    uint16_t v[1] = {0x4242};
    int dev = setup(M_ECHO_LOST, 3);
    CHECK_EQ(t_run_write(dev, 6, 5, 1, v, MBFB_WRITE_IDEMPOTENT), 0);
    CHECK_EQ(peer_reg(5), 0x4242);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 1); /* not applied twice */
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 1);
    teardown();
}

static void not_applied(void)
{
    uint16_t v[2] = {7, 8};
    int dev = setup(M_NOT_APPLIED, 3);
    CHECK_EQ(t_run_write(dev, 16, 3, 2, v, MBFB_WRITE_IDEMPOTENT), 0);
    CHECK_EQ(peer_reg(3), 7);
    CHECK_EQ(peer_reg(4), 8);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 2); /* resent once */
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 1);
    teardown();

    dev = setup(M_NOT_APPLIED, 3); /* mbfb_post's writes are IDEMPOTENT */
    CHECK_EQ(t_run(dev, 6, 9, 1, v, NULL, 0), 0);
    CHECK_EQ(peer_reg(9), 7);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 2);
    teardown();
}

static void once_never_twice(void)
{
    uint16_t v[1] = {0x0301};
    int dev = setup(M_NOT_APPLIED, 3);
    CHECK_EQ(t_run_write(dev, 6, 2, 1, v, MBFB_WRITE_ONCE), -MBFB_E_UNCONFIRMED);
    CHECK_EQ(__atomic_load_n(&writes_seen, __ATOMIC_ACQUIRE), 1); /* never sent twice */
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 0);
    CHECK(strstr(mbfb_strerror(MBFB_E_UNCONFIRMED), "unconfirmed") != NULL);
    CHECK_EQ(mbfb_post_write(dev, 6, 2, 1, v, 7), -MBFB_E_INVAL); /* unknown policy */
    teardown();
}

static void exception_write(void)
{
    uint16_t v[1] = {5};
    int dev = setup(M_EXCEPTION, 3);
    CHECK_EQ(t_run_write(dev, 6, 2, 1, v, MBFB_WRITE_ONCE), -(MBFB_E_EXCEPTION_BASE + 3));
    CHECK_EQ(peer_count(&P), 1); /* a definite answer: no read-back, no resend */
    teardown();
}

int main(void)
{
    static const t_case_t cases[] = {
        {false_fc16, "late echo does not confirm the next write"},
        {echo_lost, "applied, echo lost"},
        {not_applied, "not applied: resent once"},
        {once_never_twice, "ONCE never sent twice"},
        {exception_write, "exception"},
    };
    return t_serial_scenarios("test_writes", &framing, cases,
                              (int)(sizeof cases / sizeof cases[0]));
}
