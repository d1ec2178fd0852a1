/*
 * test_stale.c - a PLC that stops scanning without unloading its program (c_shims README
 * "Lifetime"). Frames are counted at the peer; nothing is asserted on the clock.
 *  - plans: a live and a dead device's plan run while the test "scans" (takes their
 *    snapshots); the scans stop; the line falls silent (the dead device's probes too) within
 *    the bound (10 periods, at least 2 s) plus slack, and stays silent; the scans resume: the
 *    first take of the live plan is the failed snapshot MBFB_E_STOPPED (data from before the
 *    stop are not given as new), then fresh data come and the peer hears frames again.
 *  - a task slower than the bound (a scan every 3 s): the plan polls on between its scans
 *    once the worker has seen one interval (the first gap may park it once).
 *  - queued requests: reads to a slow device keep the worker busy for longer than the bound;
 *    the scans stop (nothing polled or posted); the write queued behind the reads is never
 *    sent and ends MBFB_E_STOPPED, as do the reads still queued; the bus works on at once
 *    when the blocks are scanned again.
 */
#include <string.h>

#include "mbfb_test.h"

#define LIVE 1
#define SLOW 2
#define DEAD 9
#define PERIOD_MS 50
#define BOUND_MS 2000        /* max(10 periods, 2 s) */
#define SLACK_MS 1500        /* a loaded 2-core machine */
#define SLOW_REPLY_MS 400    /* the slow device's answer */

static peer_t P;

/* Slave 1 answers at once, slave 2 after SLOW_REPLY_MS, slave 9 never; FC06 echoed. */
static void stale_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    peer_answer(p, n, f, len, r);
    if (len >= 1 && f[0] == SLOW)
        r->delay_ms = SLOW_REPLY_MS;
}

static int open_bus(int timeout_ms)
{
    char link[160];
    mbfb_bus_config_t c;

    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, PEER_RTU, stale_peer, NULL) != 0) {
        perror("peer_start");
        return -1;
    }
    for (int s = 0; s < 8; s++)
        for (int i = 0; i < 16; i++)
            peer_set_reg(&P, s, i, (uint16_t)(0x100 * s + i));
    peer_set_dead(&P, DEAD, 1);
    c = t_cfg(P.link, 115200, MBFB_FRAMING_RTU, timeout_ms, 1);
    return mbfb_bus_open(&c);
}

/* Wait until the peer has heard nothing for quiet_ms (at most limit_ms); the time waited. */
static int64_t until_quiet(int quiet_ms, int limit_ms)
{
    int64_t t0 = t_now_us(), last = t0;
    int n = peer_count(&P);
    while (t_now_us() - last < (int64_t)quiet_ms * 1000 &&
           t_now_us() - t0 < (int64_t)limit_ms * 1000) {
        t_sleep_ms(10);
        if (peer_count(&P) != n) {
            n = peer_count(&P);
            last = t_now_us();
        }
    }
    return last - t0;
}

static void plans_stop_and_resume(void)
{
    mbfb_plan_item_t item = {3, 0, 4, MBFB_TIER_EVERY};
    int bus = open_bus(100), dev[2], plan[2], got, live, first = -1, fresh = 0;
    uint32_t seq[2] = {0, 0};
    mbfb_snap_t s;
    int64_t silent_after, end;

    t_scenario = "plans";
    CHECK(bus >= 0);
    for (int i = 0; i < 2; i++) {
        dev[i] = mbfb_dev_open(bus, i == 0 ? LIVE : DEAD);
        plan[i] = mbfb_plan_open(dev[i]);
        CHECK_EQ(mbfb_plan_set(plan[i], &item, 1, PERIOD_MS, 0), 0);
    }
    /* scanning: every 20 ms, for a second */
    for (end = t_now_us() + 1000000; t_now_us() < end; t_sleep_ms(20))
        for (int i = 0; i < 2; i++)
            (void)mbfb_plan_take(plan[i], &seq[i], &s);
    live = peer_slave_count(&P, LIVE);
    CHECK(live >= 5);
    CHECK(peer_slave_count(&P, DEAD) >= 1);
    /* the scans stop: silent within the bound (the last frame), and it stays so */
    silent_after = until_quiet(BOUND_MS, 4 * BOUND_MS);
    printf("  plans: last frame %lld ms after the last scan (bound %d ms + one period)\n",
           (long long)(silent_after / 1000), BOUND_MS);
    CHECK(silent_after < (int64_t)(BOUND_MS + SLACK_MS) * 1000);
    got = peer_count(&P);
    t_sleep_ms(1000);
    CHECK_EQ(peer_count(&P), got);
    /* the scans resume: the snapshot left for the block says the plan stopped; then data */
    live = peer_slave_count(&P, LIVE);
    for (end = t_now_us() + 5000000; !fresh && t_now_us() < end; t_sleep_ms(20)) {
        for (int i = 0; i < 2; i++) {
            if (mbfb_plan_take(plan[i], &seq[i], &s) != 1 || i != 0)
                continue;
            if (first < 0)
                first = s.result;
            fresh = s.result == MBFB_OK && s.words[0] == 0x100 * LIVE;
        }
    }
    CHECK_EQ(first, MBFB_E_STOPPED);
    CHECK(fresh);
    CHECK(peer_slave_count(&P, LIVE) > live);
    mbfb_shutdown();
    peer_stop(&P);
}

/* A task slower than the bound (a scan every 3 s, plans at 50 ms): after the first gap,
 * which parks the plan once (its block may have stopped), the worker knows the task's
 * interval and polls on between its scans. */
static void slow_task(void)
{
    mbfb_plan_item_t item = {3, 0, 4, MBFB_TIER_EVERY};
    int bus = open_bus(100), plan, stopped = 0, good = 0, grew = 0;
    uint32_t seq = 0;
    mbfb_snap_t s;

    t_scenario = "slow task";
    CHECK(bus >= 0);
    plan = mbfb_plan_open(mbfb_dev_open(bus, LIVE));
    CHECK_EQ(mbfb_plan_set(plan, &item, 1, PERIOD_MS, 0), 0);
    for (int scan = 0; scan < 5; scan++) {
        int heard = peer_slave_count(&P, LIVE);
        t_sleep_ms(3000);
        grew += scan >= 2 && peer_slave_count(&P, LIVE) > heard + 10;
        if (mbfb_plan_take(plan, &seq, &s) == 1) {
            stopped += s.result == MBFB_E_STOPPED;
            good += scan >= 2 && s.result == MBFB_OK && s.words[0] == 0x100 * LIVE;
        }
    }
    printf("  slow task: %d stopped snapshot(s), %d of the last 3 scans with fresh data\n",
           stopped, good);
    CHECK(stopped <= 1); /* the first gap only */
    CHECK_EQ(good, 3);
    CHECK_EQ(grew, 3); /* polled between the scans */
    mbfb_shutdown();
    peer_stop(&P);
}

static void queued_not_sent_later(void)
{
    int bus = open_bus(SLOW_REPLY_MS + 300), live, slow, reads[8], write, st, n;
    uint16_t v = 0x1234, out[4];
    uint32_t retries;

    t_scenario = "queued";
    CHECK(bus >= 0);
    live = mbfb_dev_open(bus, LIVE);
    slow = mbfb_dev_open(bus, SLOW);
    /* eight reads of SLOW_REPLY_MS each (3.2 s), then a write: posted, then never polled */
    for (int i = 0; i < 8; i++)
        CHECK((reads[i] = mbfb_post(slow, 3, 0, 2, NULL)) > 0);
    CHECK((write = mbfb_post_write(live, 6, 5, 1, &v, MBFB_WRITE_ONCE)) > 0);
    /* the line falls silent: what was still queued after the bound is not sent */
    (void)until_quiet(1000, 8 * BOUND_MS);
    t_sleep_ms(500);
    printf("  queued: %d of 8 slow reads sent before the bound, the write %s\n",
           peer_slave_count(&P, SLOW), peer_slave_count(&P, LIVE) ? "sent" : "not sent");
    CHECK_EQ(peer_slave_count(&P, LIVE), 0); /* the write never went out */
    CHECK(peer_slave_count(&P, SLOW) >= 2);
    CHECK(peer_slave_count(&P, SLOW) < 8);
    /* scanned again: the results; the write's says why it was not sent */
    CHECK_EQ(mbfb_poll(write), MBFB_REQ_FAILED);
    CHECK_EQ(mbfb_take(write, NULL, 0), -MBFB_E_STOPPED);
    CHECK_EQ(mbfb_poll(reads[7]), MBFB_REQ_FAILED);
    CHECK_EQ(mbfb_take(reads[7], NULL, 0), -MBFB_E_STOPPED);
    st = mbfb_poll(reads[0]);
    CHECK_EQ(st, MBFB_REQ_DONE);
    /* and the bus works on at once: the next read is the next frame on the line, answered
     * at its first attempt (nothing owed, no back-off, no resync read before it) */
    n = peer_count(&P);
    retries = t_diag(live).retries;
    CHECK_EQ(t_run(live, 3, 0, 2, NULL, out, 4), 2);
    CHECK_EQ(out[0], 0x100 * LIVE);
    CHECK_EQ(peer_count(&P), n + 1);
    CHECK_EQ(t_diag(live).retries, retries);
    mbfb_shutdown();
    peer_stop(&P);
}

int main(void)
{
    /* each with the latency rerun (t_scenarios): its peer's timings hold only on time */
    static const t_case_t cases[] = {
        T_CASE(plans_stop_and_resume),
        T_CASE(slow_task),
        T_CASE(queued_not_sent_later),
    };
    return t_scenarios("stale", cases, (int)(sizeof cases / sizeof cases[0]));
}
