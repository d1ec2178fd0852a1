/*
 * test_plans.c - refresh plans (mbfb_plan_*) on the test line against the scripted peer (RTU):
 *   snapshot   one refresh = the items back to back, one consistent snapshot; take
 *              returns 0 when nothing is new; bad settings refused
 *   tiers      SLOW in the first refresh and after invalidate (gen), FAST otherwise;
 *              words of items not read are zero
 *   stop       no refresh starts after mbfb_plan_stop
 *   fairness   two plans on one bus both refreshed; a dead device's plan costs (almost)
 *              no bus time
 *   writes     a write posted while plans run goes before the next plan read
 *   diag       diag_seq changes with the diagnostics; bus diag counts plans
 *   refresh diag  refreshes counted, refresh_us against the period and this test's clock,
 *              line_permille while the line is in use and 0 once it has been quiet for
 *              the window (a second), without moving diag_seq
 *   no port    a port that cannot be opened fails every plan of the bus in one pass
 *              (by snapshot numbers), and is tried again every probe interval only
 *   late heard a refresh failed by a late reply is done again as soon as the late reply is
 *              heard on the idle line, not a period later
 *   handover   the snapshot triple buffer under a producer that publishes as fast as it
 *              can: every snapshot taken is whole (all its fields and words from one
 *              publication, never mixed), numbers only go up, a take never returns an
 *              older snapshot than one published before it (not stale), words past the
 *              snapshot's items are left as they were
 */
#include <sched.h>
#include <string.h>

#include "mbfb_internal.h"
#include "mbfb_test.h"

static peer_t P;

static int open_bus(void)
{
    char link[160];
    mbfb_bus_config_t c;
    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, PEER_RTU, peer_answer, NULL) != 0)
        return -1;
    for (int s = 1; s <= 3; s++)
        for (int i = 0; i < 256; i++)
            peer_set_reg(&P, s, i, (uint16_t)(s * 0x1000 + i));
    c = t_cfg(P.link, 38400, MBFB_FRAMING_RTU, 200, 3);
    return mbfb_bus_open(&c);
}

/* Scenario `scenario`: slave 1 on a new bus (*dev) and a plan for it (returned). */
static int open_plan(const char *scenario, int *dev)
{
    t_scenario = scenario;
    *dev = mbfb_dev_open(open_bus(), 1);
    return mbfb_plan_open(*dev);
}

/* Words 0..1 every refresh, 10..12 in the slow tier, 20..21 in the fast one. */
static const mbfb_plan_item_t three_tiers[3] = {{3, 0, 2, MBFB_TIER_EVERY},
                                                {3, 10, 3, MBFB_TIER_SLOW},
                                                {3, 20, 2, MBFB_TIER_FAST}};

static void teardown(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

/* Wait (at most 60 s: a loaded machine) for a snapshot newer than *seq that satisfies ok
 * (or any). */
static int wait_snap(int plan, uint32_t *seq, mbfb_snap_t *s, int (*ok)(const mbfb_snap_t *))
{
    int64_t end = t_now_us() + 60000000;
    while (t_now_us() < end) {
        int rc = mbfb_plan_take(plan, seq, s);
        if (rc < 0)
            return rc;
        if (rc == 1 && (ok == NULL || ok(s)))
            return 1;
        t_sleep_ms(1);
    }
    return 0;
}

static void snapshot(void)
{
    mbfb_plan_item_t it[2] = {{3, 0, 4, MBFB_TIER_EVERY}, {4, 20, 3, MBFB_TIER_EVERY}};
    mbfb_plan_item_t bad[2] = {{5, 0, 1, 0}, {3, 0, 126, 0}};
    mbfb_snap_t s;
    uint32_t seq = 0;
    int bus, dev, plan, n0;
    uint8_t raw[PEER_BUF];

    t_scenario = "snapshot";
    bus = open_bus();
    dev = mbfb_dev_open(bus, 1);
    plan = mbfb_plan_open(dev);
    CHECK(plan >= 0);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0); /* not started: nothing */
    CHECK_EQ(mbfb_plan_set(plan, bad, 1, 0, 0), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_plan_set(plan, bad + 1, 1, 0, 0), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_plan_set(plan, it, 0, 0, 0), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_plan_set(plan, it, 2, -2, 0), -MBFB_E_INVAL); /* -1: on demand */
    CHECK_EQ(mbfb_plan_set(999999, it, 2, 0, 0), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_plan_open(mbfb_dev_open(bus, 0)), -MBFB_E_INVAL); /* broadcast */
    CHECK_EQ(peer_count(&P), 0);
    CHECK_EQ(mbfb_plan_set(plan, it, 2, 100000, 0), 0); /* one refresh, then 100 s */
    CHECK_EQ(wait_snap(plan, &seq, &s, NULL), 1);
    CHECK_EQ(s.seq, 1);
    CHECK_EQ(seq, 1);
    CHECK_EQ(s.result, 0);
    CHECK_EQ(s.read_mask, 3);
    for (int i = 0; i < 4; i++)
        CHECK_EQ(s.words[i], 0x1000 + i);
    for (int i = 0; i < 3; i++)
        CHECK_EQ(s.words[4 + i], 0x1000 + 20 + i);
    /* the refresh's two reads went back to back, in item order */
    n0 = peer_count(&P);
    CHECK_EQ(n0, 2);
    CHECK_HEX(raw, peer_raw(&P, 0, raw), "01 03 00 00 00 04 44 09");
    CHECK_EQ(peer_raw(&P, 1, raw) > 1 ? raw[1] : 0, 4);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0); /* nothing new */
    CHECK_EQ(mbfb_plan_take(-1, &seq, &s), -MBFB_E_BADHANDLE);
    CHECK_EQ(t_diag(dev).refreshes, 1);
    /* a new refresh is published with the next number and fresh values */
    peer_set_reg(&P, 1, 2, 0xABCD);
    CHECK_EQ(mbfb_plan_set(plan, it, 2, 0, 0), 0);
    CHECK_EQ(wait_snap(plan, &seq, &s, NULL), 1);
    CHECK(s.seq >= 2);
    CHECK_EQ(s.words[2], 0xABCD);
    teardown();
}

/* The second request is answered 500 ms late, the device deaf meanwhile. */
static void late_second(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    peer_answer_late_deaf(p, n, f, len, r, 1, 500);
}

static int failed(const mbfb_snap_t *s)
{
    return s->result != 0;
}

/* A plan refreshed once a period of 100 s: its second refresh (started at once by new
 * settings) fails, one attempt and no retries, its reply 500 ms late. The idle worker,
 * listening while the device is out of step, hears the late reply, and the failed plan is
 * due at once: the next snapshot is good long before the period (the wait allows 20 s). */
static void late_heard(void)
{
    mbfb_plan_item_t it[1] = {{3, 0, 1, MBFB_TIER_EVERY}};
    mbfb_bus_config_t c;
    mbfb_snap_t s;
    uint32_t seq = 0;
    int bus, plan;
    int64_t end;
    char link[160];

    t_scenario = "late heard";
    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    CHECK_EQ(peer_start(&P, link, PEER_RTU, late_second, NULL), 0);
    peer_set_reg(&P, 1, 0, 0x1234);
    c = t_cfg(P.link, 38400, MBFB_FRAMING_RTU, 200, 0);
    bus = mbfb_bus_open(&c);
    plan = mbfb_plan_open(mbfb_dev_open(bus, 1));
    CHECK_EQ(mbfb_plan_set(plan, it, 1, 100000, 0), 0);
    CHECK_EQ(wait_snap(plan, &seq, &s, NULL), 1);
    CHECK_EQ(s.result, 0);
    CHECK_EQ(mbfb_plan_set(plan, it, 1, 100000, 0), 0); /* new settings: due at once */
    CHECK_EQ(wait_snap(plan, &seq, &s, failed), 1);
    CHECK_EQ(s.result, MBFB_E_TIMEOUT);
    for (end = t_now_us() + 20000000; t_now_us() < end; t_sleep_ms(1))
        if (mbfb_plan_take(plan, &seq, &s) == 1)
            break;
    CHECK_EQ(s.result, 0);              /* the next refresh: well before its period */
    CHECK_EQ(s.words[0], 0x1234);
    CHECK_EQ(peer_count(&P), 3);        /* the read that failed, its late reply heard,
                                           then the read is its own resync read */
    teardown();
}

static uint32_t want_gen;
static int has_slow(const mbfb_snap_t *s)
{
    return (s->read_mask & 2) && s->gen >= want_gen;
}
static int no_slow(const mbfb_snap_t *s)
{
    return !(s->read_mask & 2);
}

static void tiers(void)
{
    mbfb_snap_t s;
    uint32_t seq = 0;
    int dev, plan, gen;

    plan = open_plan("tiers", &dev);
    CHECK_EQ(mbfb_plan_set(plan, three_tiers, 3, 0, 3600000), 0); /* slow: once an hour */
    CHECK_EQ(wait_snap(plan, &seq, &s, NULL), 1);
    CHECK_EQ(s.seq, 1);
    CHECK_EQ(s.read_mask, 3); /* first refresh: EVERY + SLOW, not FAST */
    CHECK_EQ(s.words[2], 0x100A);
    CHECK_EQ(s.words[4], 0x100C);
    CHECK_EQ(s.words[5], 0); /* FAST not read: zero */
    CHECK_EQ(s.words[6], 0);
    /* the first slow read is owed to the scan until a take reaches it: a refresh that
     * started before the take above may hold the slow tier again; then FAST */
    CHECK_EQ(wait_snap(plan, &seq, &s, no_slow), 1);
    CHECK_EQ(s.read_mask, 5); /* EVERY + FAST */
    CHECK_EQ(s.words[2], 0);  /* SLOW not read: zero */
    CHECK_EQ(s.words[5], 0x1014);
    gen = mbfb_plan_invalidate(plan);
    CHECK(gen > 0);
    want_gen = (uint32_t)gen;
    CHECK_EQ(wait_snap(plan, &seq, &s, has_slow), 1);
    CHECK_EQ(s.read_mask, 3);
    CHECK_EQ(s.gen, (uint32_t)gen);
    CHECK_EQ(wait_snap(plan, &seq, &s, no_slow), 1); /* and then FAST again */
    CHECK_EQ(mbfb_plan_invalidate(plan), gen + 1);
    teardown();
}

/* Refreshes that outpace the scan: the slow read made for an invalidation must not be
 * overwritten by fast-only snapshots before a take copies one (the block would wait a
 * whole slow period for the words it needs to publish). */
static void slow_owed(void)
{
    mbfb_snap_t s;
    uint32_t seq = 0, before;
    int dev, plan, gen;

    plan = open_plan("slow owed", &dev);
    CHECK_EQ(mbfb_plan_set(plan, three_tiers, 3, 0, 3600000), 0); /* back to back; slow hourly */
    CHECK_EQ(wait_snap(plan, &seq, &s, no_slow), 1);
    gen = mbfb_plan_invalidate(plan);
    before = t_diag(dev).refreshes;
    /* no take while several refreshes are published (counted in the diagnostics) */
    for (int i = 0; i < 60000 && t_diag(dev).refreshes < before + 4; i++)
        t_sleep_ms(1);
    CHECK(t_diag(dev).refreshes >= before + 4);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 1); /* the first take after the invalidation */
    CHECK_EQ(s.read_mask, 3);                    /* holds the slow tier... */
    CHECK(s.gen >= (uint32_t)gen);               /* ...read after the invalidation */
    CHECK_EQ(s.words[2], 0x100A);
    CHECK_EQ(wait_snap(plan, &seq, &s, no_slow), 1); /* then FAST again */
    teardown();
}

static void stop(void)
{
    mbfb_plan_item_t it[1] = {{3, 0, 1, MBFB_TIER_EVERY}};
    mbfb_snap_t s;
    uint32_t seq = 0, a, refreshes;
    uint16_t w[1];
    int dev, plan, n;

    plan = open_plan("stop", &dev);
    CHECK_EQ(mbfb_plan_set(plan, it, 1, 0, 0), 0);
    CHECK_EQ(wait_snap(plan, &seq, &s, NULL), 1);
    CHECK_EQ(mbfb_plan_stop(plan), 0);
    n = peer_count(&P);
    while (mbfb_plan_take(plan, &seq, &s) == 1) { /* everything published so far */
    }
    a = seq;
    /* The refresh on the wire when stop was called may finish, however slowly (its one
     * read: up to 1 + retries failed attempts, each maybe followed by a resync read),
     * and publish one snapshot; nothing starts after it. The worker's own order shows it:
     * a read posted now goes after that refresh, and a second read posted once the first
     * is done is the next frame the device hears: a plan still running (period 0, always
     * due) would take its turn between the two. Counted, not timed. */
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, w, 1), 1);
    CHECK(peer_count(&P) <= n + 2 * (1 + 3) + 1);
    n = peer_count(&P);
    refreshes = t_diag(dev).refreshes;
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, w, 1), 1);
    CHECK_EQ(peer_count(&P), n + 1);
    CHECK_EQ(t_diag(dev).refreshes, refreshes);
    while (mbfb_plan_take(plan, &seq, &s) == 1) {
    }
    CHECK(seq - a <= 1u);
    CHECK_EQ(mbfb_plan_stop(-5), -MBFB_E_BADHANDLE);
    teardown();
}

static void fairness(void)
{
    mbfb_plan_item_t it[1] = {{3, 0, 2, MBFB_TIER_EVERY}};
    mbfb_snap_t s;
    mbfb_bus_diag_t bd;
    int bus, d[3], p[3], n1, n2, n3;
    uint32_t seq[3] = {0, 0, 0};
    int64_t t0, end;

    t_scenario = "fairness";
    bus = open_bus();
    peer_set_dead(&P, 3, 1);
    for (int i = 0; i < 3; i++) {
        d[i] = mbfb_dev_open(bus, i + 1);
        p[i] = mbfb_plan_open(d[i]);
        CHECK_EQ(mbfb_plan_set(p[i], it, 1, 0, 0), 0); /* as fast as the line allows */
    }
    /* until both live slaves had a dozen refreshes (~0.1 s on an idle machine; at most
     * 60 s on a loaded one): counted, not timed. The plans are taken meanwhile, as their
     * blocks' scans take them: a plan nobody takes is parked after MBFB_STALE_MIN_MS
     * (slave 3's attempts alone can hold the line 1.6 s first) */
    t0 = t_now_us();
    for (end = t0 + 60000000; t_now_us() < end; t_sleep_ms(10)) {
        for (int i = 0; i < 3; i++)
            (void)mbfb_plan_take(p[i], &seq[i], &s);
        if (peer_slave_count(&P, 1) > 12 && peer_slave_count(&P, 2) > 12)
            break;
    }
    n1 = peer_slave_count(&P, 1);
    n2 = peer_slave_count(&P, 2);
    n3 = peer_slave_count(&P, 3);
    printf("fairness: %d / %d refreshes of slaves 1 / 2, %d frames to the dead slave 3\n",
           n1, n2, n3);
    CHECK(n1 > 10);
    CHECK(n2 > 10);
    CHECK(n1 <= 2 * n2 + 2 && n2 <= 2 * n1 + 2); /* neither starves */
    /* 2 attempts, then no bus time (back-off, no free reply shape) until the shapes
     * expire after MBFB_LATE_MAX_MS; then at most a probe per 0.5 s: a bound that only
     * grows when this machine is slow */
    CHECK(n3 <= 6 + (int)((t_now_us() - t0) / (MBFB_PROBE_MIN_MS * 1000)));
    CHECK_EQ(wait_snap(p[0], &seq[0], &s, NULL), 1);
    CHECK_EQ(s.words[0], 0x1000);
    CHECK_EQ(wait_snap(p[1], &seq[1], &s, NULL), 1);
    CHECK_EQ(s.words[0], 0x2000);
    CHECK_EQ(wait_snap(p[2], &seq[2], &s, NULL), 1); /* the dead one: its error */
    CHECK(s.result != 0);
    CHECK_EQ(s.read_mask, 0);
    CHECK_EQ(mbfb_bus_diag(d[0], &bd), 0);
    CHECK_EQ(bd.plans, 3);
    CHECK(bd.transactions >= (uint32_t)(n1 + n2));
    CHECK(bd.busy_permille > 0 && bd.busy_permille <= 1000);
    CHECK_EQ(mbfb_bus_diag(-1, &bd), -MBFB_E_BADHANDLE);
    CHECK(t_diag(d[0]).refreshes > 10);
    teardown();
}

static void writes_first(void)
{
    mbfb_plan_item_t it[2] = {{3, 0, 8, MBFB_TIER_EVERY}, {3, 8, 8, MBFB_TIER_EVERY}};
    uint16_t v[1] = {0x5A5A}, raw_v;
    uint8_t raw[PEER_BUF];
    int dev, plan, c0, c1, h, at = -1, n;
    uint32_t ds;

    plan = open_plan("writes first", &dev);
    CHECK_EQ(mbfb_plan_set(plan, it, 2, 0, 0), 0);
    while (peer_count(&P) < 6)
        t_sleep_ms(1);
    ds = mbfb_dev_diag_seq(dev);
    c0 = peer_count(&P);
    h = mbfb_post(dev, 6, 100, 1, v);
    c1 = peer_count(&P); /* the reads that started before the post: at most c1 + 1 */
    CHECK_EQ(t_wait(h), MBFB_REQ_DONE);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    n = peer_count(&P);
    for (int i = c0; i < n && i < PEER_LOG; i++)
        if (peer_raw(&P, i, raw) > 1 && raw[1] == 6 && at < 0)
            at = i;
    /* at most the read on the wire when it was posted came before it (counted from c1, not
     * c0: a loaded machine may hold this thread between the two while reads go on) */
    CHECK(at >= c0 && at <= c1 + 1);
    pthread_mutex_lock(&P.lock);
    raw_v = P.regs[1][100];
    pthread_mutex_unlock(&P.lock);
    CHECK_EQ(raw_v, 0x5A5A);
    CHECK(mbfb_dev_diag_seq(dev) != ds); /* the diagnostics changed */
    CHECK_EQ(mbfb_dev_diag_seq(-1), 0);
    teardown();
}

/* Wait (at most 60 s) until the device's copy shows line_permille == 0; 1 if it did. */
static int wait_line_quiet(int dev)
{
    for (int64_t end = t_now_us() + 60000000; t_now_us() < end; t_sleep_ms(10))
        if (t_diag(dev).line_permille == 0)
            return 1;
    return 0;
}

/* The achieved refresh rate and the line's use, per device. Every bound holds
 * however slow this machine is (a slow machine only makes the waits longer):
 *  - a refresh starts no earlier than the period after the start of the one before (the
 *    worker's schedule), so refresh_us >= period;
 *  - every refresh started between t0 (before mbfb_plan_set) and t1 (after the plan went
 *    quiet), the other gaps are each >= period: refresh_us <= t1 - t0 - (n - 2) * period;
 *  - a transaction stays in the busy window until its 100 ms bucket is 10 buckets old:
 *    line_permille cannot read 0 earlier than 0.9 s after a read posted at t_post. */
static void refresh_diag(void)
{
    mbfb_plan_item_t it[1] = {{3, 0, 2, MBFB_TIER_EVERY}};
    const int period_ms = 20, n_want = 6;
    mbfb_snap_t s;
    mbfb_diag_t d;
    mbfb_bus_diag_t bd;
    uint32_t seq = 0, ds;
    int dev, plan, h, bad = 0;
    int64_t t0, t1, t_post, t_zero;

    plan = open_plan("refresh diag", &dev);
    d = t_diag(dev);
    CHECK_EQ(d.refreshes, 0);
    CHECK_EQ(d.refresh_us, 0);
    CHECK_EQ(d.line_permille, 0);
    t0 = t_now_us();
    CHECK_EQ(mbfb_plan_set(plan, it, 1, period_ms, 0), 0);
    while (seq < (uint32_t)n_want && wait_snap(plan, &seq, &s, NULL) == 1)
        bad += s.result != MBFB_OK;
    CHECK(seq >= (uint32_t)n_want);
    /* while the plan runs the line is in use: a refresh is due every 20 ms, so the window
     * cannot empty while the worker keeps the value */
    d = t_diag(dev);
    CHECK(d.line_permille > 0 && d.line_permille <= 1000);
    CHECK(d.refreshes >= (uint32_t)n_want);
    CHECK(d.refresh_us > 0);
    CHECK_EQ(mbfb_plan_stop(plan), 0);
    /* quiet for the window: no refresh can be on the wire any more */
    CHECK_EQ(wait_line_quiet(dev), 1);
    t1 = t_now_us();
    while (mbfb_plan_take(plan, &seq, &s) == 1)
        bad += s.result != MBFB_OK;
    CHECK_EQ(bad, 0);
    d = t_diag(dev);
    printf("refresh diag: %u refreshes, refresh_us %u (period %d ms), %.1f s\n",
           (unsigned)d.refreshes, (unsigned)d.refresh_us, period_ms, (t1 - t0) / 1e6);
    CHECK_EQ(d.refreshes, seq); /* every published refresh was good, each counted once */
    CHECK(d.refresh_us >= (uint32_t)period_ms * 1000u);
    CHECK((int64_t)d.refresh_us <= t1 - t0 - ((int64_t)seq - 2) * period_ms * 1000);
    CHECK_EQ(d.line_permille, 0);
    CHECK_EQ(mbfb_bus_diag(dev, &bd), 0);
    CHECK_EQ(bd.busy_permille, 0); /* the same value as the bus's */
    /* one read on the quiet line: in use in the copy made after it, 0 again once it has
     * left the window, and the diagnostics' sequence does not move meanwhile */
    t_post = t_now_us();
    h = mbfb_post(dev, 3, 0, 2, NULL);
    CHECK_EQ(t_wait(h), MBFB_REQ_DONE);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    ds = mbfb_dev_diag_seq(dev);
    d = t_diag(dev);
    CHECK(d.line_permille > 0);
    CHECK_EQ(mbfb_bus_diag(dev, &bd), 0);
    CHECK(bd.busy_permille > 0);
    CHECK_EQ(wait_line_quiet(dev), 1);
    t_zero = t_now_us();
    CHECK(t_zero - t_post >= 900000);
    CHECK_EQ(mbfb_dev_diag_seq(dev), ds);
    CHECK_EQ(t_diag(dev).refreshes, seq); /* a posted read is no refresh */
    teardown();
}

/* A port that cannot be opened. The backend's open() is wrapped (the real RTU open,
 * which fails on a missing path) to record, at each try, how many snapshots every plan
 * has published: between two tries each running plan gets exactly one NOPORT snapshot
 * (all the bus's plans fail in the same pass, none waits for its own reopen delay), and
 * the worker tries again only every probe interval (no spinning on open()). Checked by
 * snapshot numbers, not by the clock; the elapsed time only bounds the tries from above. */
#define NP_PLANS 3
#define NP_TRIES 64
static mbfb_backend_t np_be;
static int np_plan[NP_PLANS];
static int np_tries;                          /* atomic: open() calls            */
static uint32_t np_seq[NP_TRIES][NP_PLANS];   /* worker: snapshots published at try k */

/* The worker's own count of published snapshots (p->pub), not a take: a plan has one
 * consumer (mbfb_plan_take is not to be called from two threads), the test's thread. */
static int np_open(struct mbfb_bus *bus)
{
    int k = __atomic_load_n(&np_tries, __ATOMIC_RELAXED);
    if (k < NP_TRIES)
        for (int i = 0; i < NP_PLANS; i++)
            np_seq[k][i] = __atomic_load_n(&mbfb_plans[np_plan[i]]->pub, __ATOMIC_ACQUIRE);
    __atomic_store_n(&np_tries, k + 1, __ATOMIC_RELEASE);
    return mbfb_backend_rtu.open(bus);
}

static void no_port(void)
{
    mbfb_plan_item_t it[2] = {{3, 0, 1, MBFB_TIER_EVERY}, {4, 10, 2, MBFB_TIER_EVERY}};
    mbfb_bus_config_t c = t_cfg("/nonexistent/ttyPLAN0", 9600, MBFB_FRAMING_RTU, 0, -1);
    mbfb_snap_t s;
    uint32_t seq[NP_PLANS] = {0};
    int bus, tries, first = -1, passes = 0;
    int64_t t0, end;

    t_scenario = "no port";
    bus = mbfb_bus_open(&c);
    CHECK(bus >= 0);
    if (bus < 0)
        return;
    np_be = *mbfb_buses[bus]->be;
    np_be.open = np_open;
    /* before any plan exists: the worker reads bus->be only for a plan published after
     * this store (release/acquire on bus->plans) */
    mbfb_buses[bus]->be = &np_be;
    for (int i = 0; i < NP_PLANS; i++) {
        np_plan[i] = mbfb_plan_open(mbfb_dev_open(bus, 1 + i));
        CHECK(np_plan[i] >= 0);
    }
    t0 = t_now_us();
    for (int i = 0; i < NP_PLANS; i++)
        CHECK_EQ(mbfb_plan_set(np_plan[i], it, 1 + i % 2, 0, 0), 0);
    /* wait (at most 60 s: a loaded machine) for 3 passes after the one in which every plan
     * had been started and had failed once, scanning meanwhile (a plan not scanned for 2 s
     * stops: c_shims README "Lifetime"): every snapshot NOPORT, nothing valid */
    end = t0 + 60000000;
    while (t_now_us() < end) {
        for (int i = 0; i < NP_PLANS; i++)
            while (mbfb_plan_take(np_plan[i], &seq[i], &s) == 1) {
                CHECK_EQ(s.result, MBFB_E_NOPORT);
                CHECK_EQ(s.read_mask, 0u);
                CHECK_EQ(s.words[0], 0);
            }
        tries = __atomic_load_n(&np_tries, __ATOMIC_ACQUIRE);
        for (int k = first < 0 ? 0 : first; first < 0 && k < tries && k < NP_TRIES; k++) {
            int all = 1;
            for (int i = 0; i < NP_PLANS; i++)
                all &= np_seq[k][i] >= 1;
            if (all)
                first = k;
        }
        if (first >= 0 && tries - first > 3)
            break;
        t_sleep_ms(10);
    }
    for (int i = 0; i < NP_PLANS; i++) { /* every snapshot: NOPORT, nothing valid */
        while (mbfb_plan_take(np_plan[i], &seq[i], &s) == 1) {
            CHECK_EQ(s.result, MBFB_E_NOPORT);
            CHECK_EQ(s.read_mask, 0u);
            CHECK_EQ(s.words[0], 0);
        }
        CHECK(seq[i] >= 1);
    }
    mbfb_shutdown(); /* joins the worker: np_* are stable */
    tries = __atomic_load_n(&np_tries, __ATOMIC_ACQUIRE);
    CHECK(first >= 0 && tries - first > 3);
    for (int k = first; first >= 0 && k + 1 < tries && k + 1 < NP_TRIES; k++, passes++)
        for (int i = 0; i < NP_PLANS; i++)
            CHECK_EQ(np_seq[k + 1][i] - np_seq[k][i], 1u); /* one pass: every plan */
    CHECK(passes >= 3);
    /* no spinning: at most one try per 0.5 s (+ the first), however slow this machine */
    CHECK(tries <= 2 + (int)((t_now_us() - t0) / (MBFB_PROBE_MIN_MS * 1000)));
}

/* The snapshot handover (mbfb_plan_publish, worker side; mbfb_plan_take, scan side),
 * with this test's thread as the producer in place of the worker (the plan is never
 * started, so the bus's worker never publishes on it). Snapshot k: result k, gen 3k,
 * read_mask k & 15, nwords 1 + k % 125, word i = k * 31 + i; a take that mixed two
 * publications shows it in one of them. Under the TSan flavour this is also the data
 * race check of the handover. */
#define HO_SNAPS 200000u
#define HO_MEETS 3u /* the producer waits for a take at 3 points of its run */
static int ho_done;      /* atomic: the producer has published its last snapshot */
static uint32_t ho_took; /* atomic: the number of the consumer's last snapshot taken */
static uint32_t ho_words(uint32_t k) { return 1u + k % MBFB_PLAN_MAX_WORDS; }

/* The producer. At HO_MEETS points of its run it waits until the consumer has taken the
 * snapshot just published, so that takes happen while it runs however the scheduler
 * places the two threads: on one core (or a loaded machine), the whole run otherwise fit
 * in one time slice and the consumer's first take was the last snapshot. */
static void *ho_producer(void *arg)
{
    mbfb_plan_t *p = (mbfb_plan_t *)arg;
    uint16_t w[MBFB_PLAN_MAX_WORDS];
    for (uint32_t k = 1; k <= HO_SNAPS; k++) {
        for (uint32_t i = 0; i < ho_words(k); i++)
            w[i] = (uint16_t)(k * 31u + i);
        mbfb_plan_publish(p, (int)k, 3u * k, k & 15u, w, (int)ho_words(k));
        if (k % (HO_SNAPS / (HO_MEETS + 1)) == 0 && k < HO_SNAPS)
            while (__atomic_load_n(&ho_took, __ATOMIC_ACQUIRE) < k)
                sched_yield();
    }
    __atomic_store_n(&ho_done, 1, __ATOMIC_RELEASE);
    return NULL;
}

static void handover(void)
{
    mbfb_bus_config_t c = t_cfg("/nonexistent/ttyPLAN1", 9600, MBFB_FRAMING_RTU, 0, -1);
    mbfb_snap_t s;
    uint32_t seq = 0, last = 0, bad = 0, stale = 0, takes = 0, none = 0;
    pthread_t th;
    mbfb_plan_t *p;
    int plan;

    t_scenario = "handover";
    plan = mbfb_plan_open(mbfb_dev_open(mbfb_bus_open(&c), 1));
    CHECK(plan >= 0);
    if (plan < 0)
        return;
    p = mbfb_plans[plan];
    memset(&s, 0xEE, sizeof s);
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0); /* nothing published yet */
    CHECK_EQ(s.words[0], 0xEEEE);                /* and nothing copied */
    CHECK_EQ(pthread_create(&th, NULL, ho_producer, p), 0);
    for (int fin = 0; !fin;) { /* until a take that began after the last publication */
        uint32_t pub, k, n;
        int rc;
        fin = __atomic_load_n(&ho_done, __ATOMIC_ACQUIRE);
        pub = __atomic_load_n(&p->pub, __ATOMIC_ACQUIRE);
        memset(s.words, 0xEE, sizeof s.words);
        rc = mbfb_plan_take(plan, &seq, &s);
        if (rc == 0) {
            none++;
            stale += seq < pub; /* published before this take, not delivered */
            continue;
        }
        CHECK_EQ(rc, 1);
        takes++;
        k = s.seq;
        n = ho_words(k);
        stale += k < pub;
        if (k <= last || seq != k)
            bad++;
        if (s.result != (int32_t)k || s.gen != 3u * k || s.read_mask != (k & 15u))
            bad++;
        for (uint32_t i = 0; i < n; i++)
            bad += s.words[i] != (uint16_t)(k * 31u + i);
        for (uint32_t i = n; i < MBFB_PLAN_MAX_WORDS; i++) /* past the items: untouched, */
            bad += s.words[i] != 0xEEEE; /* no word of an older, longer snapshot */
        last = k;
        __atomic_store_n(&ho_took, k, __ATOMIC_RELEASE);
    }
    pthread_join(th, NULL);
    CHECK_EQ(bad, 0u);
    CHECK_EQ(stale, 0u);
    CHECK_EQ(last, HO_SNAPS);
    CHECK(takes >= HO_MEETS + 1); /* taken while the producer ran, and its last one */
    CHECK_EQ(mbfb_plan_take(plan, &seq, &s), 0); /* all taken: nothing new */
    printf("handover: %u snapshots published, %u taken, %u takes with nothing new\n",
           HO_SNAPS, takes, none);
    mbfb_shutdown();
}

int main(void)
{
    /* each with the latency rerun (t_scenarios): its peer's timings hold only on time */
    static const t_case_t cases[] = {
        T_CASE(no_port),
        T_CASE(handover),
        T_CASE(snapshot),
        T_CASE(tiers),
        T_CASE(slow_owed),
        T_CASE(stop),
        T_CASE(fairness),
        T_CASE(writes_first),
        T_CASE(refresh_diag),
        T_CASE(late_heard),
    };
    return t_scenarios("test_plans", cases, (int)(sizeof cases / sizeof cases[0]));
}
