/*
 * mbfb_worker.c - the one thread per bus that does all its I/O: what it runs when.
 *
 * Work, in this order: the refresh of the plan due first (ties: round robin), the posted
 * requests (writes, generic reads) going before each of its reads, in posting order; with
 * no plan due, the posted requests. A chain (mbfb_post_chain) is a posted request that runs
 * one entry (write and read-back) per turn and is then queued again: one entry before
 * each refresh while plans are due, back to back otherwise. Otherwise the worker waits, using no
 * CPU, until the next due time or a post (mbfb_wake.c), and, while a device is out of
 * step, for input on the port too: a late reply is read the moment it comes.
 * A request's attempts are in mbfb_attempt.c, the rules of late replies and resync reads
 * in mbfb_resync.c.
 */
#include <string.h>

#include "mbfb_internal.h"

/* Every running plan of the bus ends its refresh now with `err` (the port could not be
 * opened: MBFB_E_NOPORT, MBFB_E_BAUD for a rate the driver cannot set, MBFB_E_DIRECTION
 * for a direction mode it refuses): one failed snapshot each, in this one pass, and none
 * is due again before bus->reopen_us, so the bus tries open() once per probe interval
 * whatever the number of plans. */
void mbfb_plans_no_port(mbfb_bus_t *bus, int64_t now, int err)
{
    int n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE);
    uint16_t words[MBFB_PLAN_MAX_WORDS];

    memset(words, 0, sizeof words);
    for (int i = 0; i < n; i++) {
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        mbfb_plan_cfg_t cfg;
        if (p == NULL || !mbfb_plan_read_cfg(p, &cfg))
            continue; /* not running */
        p->last_start_us = now;
        MBFB_DIAG_SET(mbfb_devs[p->dev], last_error, (int32_t)err);
        mbfb_plan_publish(p, err, cfg.slow_gen, 0u, words, cfg.nwords);
    }
}

/* ---- posted requests ---------------------------------------------------------------- */

/* One entry of a chain (slot s, entry i): its write, confirmed as any idempotent write
 * (mbfb_attempt.c), then its read-back. MBFB_OK when the word read is the word written,
 * MBFB_E_NOT_HELD when it is not, else the failed request's MBFB_E_*. */
static int run_chain_entry(mbfb_bus_t *bus, mbfb_slot_t *s, int i)
{
    mbfb_request_t request;
    uint16_t word = s->values[s->count + i], back = 0;
    int rc;

    memset(&request, 0, sizeof request);
    request.devidx = s->dev;
    request.fc = MBFB_FC_WRITE_SINGLE;
    request.addr = s->values[i];
    request.count = 1;
    request.policy = MBFB_WRITE_IDEMPOTENT;
    request.vals = &word;
    if ((rc = mbfb_device_request(bus, &request)) != MBFB_OK)
        return rc;
    request.fc = MBFB_FC_READ_HOLDING;
    request.vals = NULL;
    request.out = &back;
    if ((rc = mbfb_device_request(bus, &request)) != MBFB_OK)
        return rc;
    return back == word ? MBFB_OK : MBFB_E_NOT_HELD;
}

/* A posted request. A chain runs one entry per turn: held with more to come, it is
 * queued again behind what was posted meanwhile (mbfb_slot_requeue), so posted requests
 * and plan reads go between its entries. */
static void run_slot(mbfb_bus_t *bus, mbfb_slot_t *s)
{
    mbfb_request_t request;
    int rc;

    if (s->chain) {
        int held = __atomic_load_n(&s->nvals, __ATOMIC_RELAXED);
        rc = run_chain_entry(bus, s, held);
        if (rc == MBFB_OK)
            __atomic_store_n(&s->nvals, ++held, __ATOMIC_RELEASE);
        if (rc == MBFB_OK && held < s->count)
            mbfb_slot_requeue(bus, s);
        else
            mbfb_slot_finish(s, rc);
        return;
    }
    memset(&request, 0, sizeof request);
    request.devidx = s->dev;
    request.fc = s->fc;
    request.addr = s->addr;
    request.count = s->count;
    request.policy = s->policy;
    request.vals = s->values;
    request.out = s->values; /* reads: the slot's values are free for the result */
    rc = mbfb_device_request(bus, &request);
    s->nvals = rc == MBFB_OK && mbfb_fc_is_read(s->fc) ? s->count : 0;
    mbfb_slot_finish(s, rc);
}

/* Run the requests posted before this call, oldest first, chains' entries only when
 * `chains` (a chain's next entry, queued again meanwhile, waits for the next call); 1 if
 * the worker must stop. */
static int run_posted(mbfb_bus_t *bus, int chains)
{
    uint32_t before = __atomic_load_n(&bus->post_seq, __ATOMIC_ACQUIRE);
    mbfb_slot_t *s;

    while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE)) {
        if ((s = mbfb_slot_next(bus, &before, chains)) == NULL)
            return 0;
        run_slot(bus, s);
    }
    return 1;
}

/* ---- plans ------------------------------------------------------------------------- */

/* When a plan is due (monotonic us); INT64_MAX if it is not running, or runs on demand
 * and is not triggered. New settings or a trigger (mbfb_plan_trigger): now. A device in
 * back-off is due at its next probe only; a port that could not be opened, once the probe
 * interval has passed (then the first plan due tries to open it, and a failure fails all
 * of them at once: mbfb_plans_no_port). */
static int64_t plan_due(mbfb_bus_t *bus, mbfb_plan_t *p)
{
    mbfb_dev_t *dev = mbfb_devs[p->dev];
    int period = __atomic_load_n(&p->period_ms, __ATOMIC_RELAXED);
    int64_t due;
    if (!__atomic_load_n(&p->running, __ATOMIC_ACQUIRE))
        return INT64_MAX;
    if (mbfb_plan_parked(p, mbfb_now_us()))
        return INT64_MAX; /* its block is not scanned: stopped until it is (mbfb_plan.c) */
    if (p->last_start_us == 0 || __atomic_load_n(&p->cfg_seq, __ATOMIC_ACQUIRE) != p->cfg_seen ||
        __atomic_load_n(&p->trigger, __ATOMIC_ACQUIRE) != p->trigger_seen)
        due = 0;
    else if (period == MBFB_PERIOD_ON_DEMAND)
        return INT64_MAX; /* refreshed once when set, then on a trigger only */
    else
        due = p->last_start_us + (int64_t)period * 1000;
    if (p->failed && dev->heard && period != MBFB_PERIOD_ON_DEMAND)
        due = 0; /* its device was heard: it can answer again now */
    if (dev->probe_us > 0 && dev->next_probe_us > due)
        due = dev->next_probe_us;
    if (bus->fd < 0 && bus->reopen_us > due)
        due = bus->reopen_us;
    return due;
}

/* Is sequence number a older than b (modulo 2^32: refresh numbers wrap)? */
static int seq_before(uint32_t a, uint32_t b)
{
    return (int32_t)(a - b) < 0;
}

/* Is the slow tier read in a refresh starting at `start` under settings cfg? *owed: a
 * new generation makes a debt to the scan (the first slow read, one made for an
 * invalidation): until a take reaches that snapshot (refreshes may outpace scans), every
 * refresh reads the slow tier again, so whichever snapshot a take copies holds it. */
static int slow_due(const mbfb_plan_t *p, const mbfb_plan_cfg_t *cfg, int64_t start,
                    int *owed)
{
    *owed = cfg->slow_gen != p->slow.read_gen;
    return *owed || start >= p->slow.next_us ||
           (p->slow.owed_seq != 0 && /* an old debt: no take has reached it yet */
            seq_before(__atomic_load_n(&p->taken, __ATOMIC_ACQUIRE), p->slow.owed_seq));
}

/* Is an item of `tier` read in a refresh with (slow) or without the slow tier? */
static int tier_read(int tier, int slow)
{
    return slow ? tier != MBFB_TIER_FAST : tier != MBFB_TIER_SLOW;
}

/* A refresh ended without a snapshot of its own: the worker must stop, or the port did
 * not open (every plan of the bus has published that, mbfb_plans_no_port). */
#define REFRESH_ABANDONED (-1)

/* Read a refresh's items of its tiers back to back, posted requests before each (and a
 * chain's entry before the first: one per refresh), into words (item i at its offset) and
 * *mask. MBFB_OK, the MBFB_E_* of the read that failed, or REFRESH_ABANDONED. */
static int read_items(mbfb_bus_t *bus, const mbfb_plan_t *p, const mbfb_plan_cfg_t *cfg,
                      int slow, int64_t start, uint16_t *words, uint32_t *mask)
{
    int offset = 0, first = 1;

    for (int i = 0; i < cfg->n;
         offset += mbfb_data_words(cfg->items[i].fc, cfg->items[i].count), i++) {
        mbfb_request_t request;
        int rc;
        if (!tier_read(cfg->items[i].tier, slow))
            continue;
        if (run_posted(bus, first))
            return REFRESH_ABANDONED;
        first = 0;
        if (bus->fd < 0 && bus->reopen_us > start)
            return REFRESH_ABANDONED; /* a posted request could not open the port */
        memset(&request, 0, sizeof request);
        request.devidx = p->dev;
        request.fc = cfg->items[i].fc;
        request.addr = cfg->items[i].addr;
        request.count = cfg->items[i].count;
        request.out = words + offset;
        rc = mbfb_device_request(bus, &request);
        if (rc == MBFB_E_NOPORT || rc == MBFB_E_BAUD || rc == MBFB_E_DIRECTION)
            return REFRESH_ABANDONED;
        if (rc != MBFB_OK)
            return rc;
        *mask |= 1u << i;
    }
    return MBFB_OK;
}

/* Publish a finished refresh (result: MBFB_OK or the failed read's MBFB_E_*, which
 * publishes no word), and keep the slow tier's and the device's books. */
static void publish_refresh(mbfb_plan_t *p, const mbfb_plan_cfg_t *cfg, int result,
                            int slow, int owed, int64_t start, uint16_t *words,
                            uint32_t mask)
{
    mbfb_dev_t *dev = mbfb_devs[p->dev];

    p->failed = result != MBFB_OK;
    if (result != MBFB_OK) {
        memset(words, 0, MBFB_PLAN_MAX_WORDS * sizeof words[0]);
        mask = 0;
    } else {
        if (slow) {
            p->slow.read_gen = cfg->slow_gen;
            p->slow.next_us = start + (int64_t)cfg->slow_ms * 1000;
        }
        MBFB_DIAG_INC(dev, refreshes);
        if (dev->last_refresh_us != 0)
            MBFB_DIAG_SET(dev, refresh_us, (uint32_t)(start - dev->last_refresh_us));
        dev->last_refresh_us = start;
    }
    mbfb_plan_publish(p, result, cfg->slow_gen, mask, words, cfg->nwords);
    if (result == MBFB_OK && owed)
        p->slow.owed_seq = p->seq; /* the first snapshot of the debt: every later one
                                      holds the slow tier too until a take reaches it */
}

/* One refresh of a plan: the settings copied once, its items of this refresh's tiers
 * read, published as one snapshot. */
static void run_refresh(mbfb_bus_t *bus, mbfb_plan_t *p)
{
    mbfb_plan_cfg_t cfg;
    uint16_t words[MBFB_PLAN_MAX_WORDS];
    uint32_t mask = 0;
    int64_t start = mbfb_now_us();
    int slow, owed, result;

    p->last_start_us = start;
    /* triggers until now are served by this refresh; a later one makes another */
    p->trigger_seen = __atomic_load_n(&p->trigger, __ATOMIC_ACQUIRE);
    if (!mbfb_plan_read_cfg(p, &cfg))
        return;
    p->cfg_seen = cfg.seq;
    slow = slow_due(p, &cfg, start, &owed);
    mbfb_devs[p->dev]->heard = 0;
    memset(words, 0, sizeof words);
    result = read_items(bus, p, &cfg, slow, start, words, &mask);
    if (result != REFRESH_ABANDONED)
        publish_refresh(p, &cfg, result, slow, owed, start, words, mask);
}

/* The plan due first (ties: round robin after the last one run). Returns it when it
 * is due now; else NULL and *wake_at (INT64_MAX: no plan running). */
static mbfb_plan_t *next_plan(mbfb_bus_t *bus, int64_t now, int64_t *wake_at)
{
    int n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE), best_i = -1;
    int64_t best_due = INT64_MAX;
    mbfb_plan_t *best = NULL;

    for (int k = 0; k < n; k++) {
        int i = (bus->rr + 1 + k) % n;
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        int64_t due;
        if (p == NULL || (due = plan_due(bus, p)) == INT64_MAX)
            continue;
        if (best == NULL || due < best_due) {
            best = p;
            best_due = due;
            best_i = i;
        }
    }
    *wake_at = best_due;
    if (best == NULL || best_due > now)
        return NULL;
    bus->rr = best_i;
    return best;
}

/* Is a device of this bus out of step, a late reply of it still possible? */
static int bus_out_of_step(const mbfb_bus_t *bus)
{
    if (bus->fd < 0 || !bus->be->needs_resync)
        return 0;
    for (int d = 0; d < MBFB_MAX_DEVICES; d++) {
        mbfb_dev_t *dev = __atomic_load_n(&mbfb_devs[d], __ATOMIC_ACQUIRE);
        if (dev != NULL && dev->bus == bus->index && dev->n_outstanding > 0)
            return 1;
    }
    return 0;
}

/* Idle with a device out of step: listen to the port until `until`, a post, or a late
 * reply, which is read and retires its shape at once (a plan whose refresh failed is
 * then due: its device can answer again, and need not wait for its next period). */
static void listen_until(mbfb_bus_t *bus, int64_t until)
{
    if (mbfb_wake_wait(bus, bus->fd, until) == 1)
        (void)mbfb_wait_quiet(bus, bus->settle_slave); /* a lost port shows in the next attempt */
}

/* The worker loop: the plan due (posted requests before each of its reads), else the
 * posted requests, else wait (file comment). A chain's next entry waits for the next turn
 * of run_posted: one entry per refresh while plans are due, back to back otherwise. */
void *mbfb_worker_main(void *arg)
{
    mbfb_bus_t *bus = (mbfb_bus_t *)arg;

    while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE)) {
        mbfb_plan_t *p;
        int64_t wake_at, now, empty_at;
        mbfb_wake_take(bus); /* the checks below see every post */
        now = mbfb_now_us();
        p = next_plan(bus, now, &wake_at);
        if (p != NULL) {
            run_refresh(bus, p); /* the posts go before each of its reads */
            continue;
        }
        if (run_posted(bus, 1))
            break;
        /* idle: busy_permille as of now, and one wake when the window empties */
        empty_at = mbfb_busy_update(bus, now);
        if (empty_at < wake_at)
            wake_at = empty_at;
        if (bus_out_of_step(bus))
            listen_until(bus, wake_at);
        else
            mbfb_wake_wait(bus, -1, wake_at);
    }
    if (bus->fd >= 0)
        bus->be->close(bus);
    return NULL;
}
