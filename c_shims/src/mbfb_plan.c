/*
 * mbfb_plan.c - refresh plans: the scan side (open, set, stop, invalidate, take) and
 * the worker's side of the settings and snapshots.
 *
 * Lock-free both ways (see mbfb_internal.h, "plans"): settings in a sequence lock the
 * scan writes and the worker copies (every field accessed with __atomic builtins);
 * snapshots in a single-producer single-consumer triple buffer: each side writes or
 * copies only a buffer it owns (plain memcpy) and hands buffers over with one atomic
 * exchange. The code is the same in C and C++ and ThreadSanitizer sees no data race.
 */
#include <stdlib.h>
#include <string.h>

#include "mbfb_internal.h"

/* Data inside the sequence locks: release stores and acquire loads (plain moves on
 * x86), so that a load that sees a newer value also sees the lock word changed after
 * it; no standalone fences (ThreadSanitizer does not model them). */
#define LD(p) __atomic_load_n((p), __ATOMIC_ACQUIRE)
#define ST(p, v) __atomic_store_n((p), (v), __ATOMIC_RELEASE)

/* The plan of a handle, or NULL. */
static mbfb_plan_t *plan_of(int plan)
{
    if (plan < 0 || plan >= MBFB_MAX_PLANS)
        return NULL;
    return __atomic_load_n(&mbfb_plans[plan], __ATOMIC_ACQUIRE);
}

/* Setup: allocate a plan on the device's bus and publish it. */
int mbfb_plan_open(int dev)
{
    mbfb_dev_t *d;
    mbfb_bus_t *b;
    mbfb_plan_t *p;
    int rc = -MBFB_E_NOMEM, n;

    if (dev < 0 || dev >= MBFB_MAX_DEVICES ||
        (d = __atomic_load_n(&mbfb_devs[dev], __ATOMIC_ACQUIRE)) == NULL ||
        (b = __atomic_load_n(&mbfb_buses[d->bus], __ATOMIC_ACQUIRE)) == NULL)
        return -MBFB_E_BADHANDLE;
    if (d->slave == 0)
        return -MBFB_E_INVAL; /* broadcast: nothing to read */
    pthread_mutex_lock(&mbfb_registry_lock);
    n = b->n_plans;
    for (int i = 0; i < MBFB_MAX_PLANS && n < MBFB_PLANS_PER_BUS; i++) {
        if (mbfb_plans[i] != NULL)
            continue;
        p = (mbfb_plan_t *)calloc(1, sizeof *p);
        if (p == NULL)
            break;
        p->dev = dev;
        p->bus = d->bus;
        p->front = 0; /* triple buffer: the scan holds 0, 1 is in the middle, */
        p->mid = 1;   /* the worker fills 2 (all seq 0: nothing yet)          */
        p->back = 2;
        __atomic_store_n(&b->plans[n], p, __ATOMIC_RELEASE);
        __atomic_store_n(&b->n_plans, n + 1, __ATOMIC_RELEASE);
        __atomic_store_n(&mbfb_plans[i], p, __ATOMIC_RELEASE);
        rc = i;
        break;
    }
    pthread_mutex_unlock(&mbfb_registry_lock);
    return rc;
}

/* Check a plan's items: reads (registers or bits), counts, address range, tiers, words
 * in all (a bit item fills MBFB_BIT_WORDS(count) words). */
static int check_items(const mbfb_plan_item_t *items, int n)
{
    int words = 0;
    if (items == NULL || n < 1 || n > MBFB_PLAN_MAX_ITEMS)
        return MBFB_E_INVAL;
    for (int i = 0; i < n; i++) {
        const mbfb_plan_item_t *it = &items[i];
        if (!mbfb_fc_is_read(it->fc) || it->count < 1 || it->count > mbfb_read_max(it->fc) ||
            it->addr < 0 || it->addr + it->count > MBFB_ADDR_SPACE ||
            it->tier < MBFB_TIER_EVERY || it->tier > MBFB_TIER_FAST)
            return MBFB_E_INVAL;
        words += mbfb_data_words(it->fc, it->count);
    }
    return words > MBFB_PLAN_MAX_WORDS ? MBFB_E_INVAL : MBFB_OK;
}

/* Make the slow tier due at once: its generation moves (the one way; see mbfb_slow_t).
 * Returns the new generation. */
static uint32_t slow_invalidate(mbfb_plan_t *p)
{
    return __atomic_add_fetch(&p->slow.gen, 1u, __ATOMIC_ACQ_REL);
}

/* Write the settings inside the sequence lock (one writer per plan: its block). New
 * settings (items != NULL) invalidate the slow tier inside the lock, so the worker copies
 * settings and generation as one. */
static void write_cfg(mbfb_plan_t *p, const mbfb_plan_item_t *items, int n, int period_ms,
                      int slow_ms, int running)
{
    /* odd: being written; acquire: the stores below stay after it */
    uint32_t s = __atomic_fetch_add(&p->cfg_seq, 1u, __ATOMIC_ACQ_REL);
    for (int i = 0; i < n; i++) {
        ST(&p->items[i].fc, items[i].fc);
        ST(&p->items[i].addr, items[i].addr);
        ST(&p->items[i].count, items[i].count);
        ST(&p->items[i].tier, items[i].tier);
    }
    if (items != NULL) {
        ST(&p->n, n);
        ST(&p->period_ms, period_ms);
        ST(&p->slow_ms, slow_ms);
        (void)slow_invalidate(p);
    }
    ST(&p->running, running);
    __atomic_store_n(&p->cfg_seq, s + 2, __ATOMIC_RELEASE);
}

int mbfb_plan_set(int plan, const mbfb_plan_item_t *items, int n, int period_ms,
                  int slow_period_ms)
{
    mbfb_plan_t *p = plan_of(plan);
    mbfb_bus_t *b;

    if (p == NULL)
        return -MBFB_E_BADHANDLE;
    if (check_items(items, n) != MBFB_OK ||
        (period_ms < 0 && period_ms != MBFB_PERIOD_ON_DEMAND) || slow_period_ms < 0)
        return -MBFB_E_INVAL;
    write_cfg(p, items, n, period_ms, slow_period_ms, 1);
    b = __atomic_load_n(&mbfb_buses[p->bus], __ATOMIC_ACQUIRE);
    if (b != NULL)
        mbfb_wake(b); /* a settings change, not steady state: wake the worker */
    return 0;
}

/* Stop a plan: running = 0 inside the sequence lock. */
int mbfb_plan_stop(int plan)
{
    mbfb_plan_t *p = plan_of(plan);
    if (p == NULL)
        return -MBFB_E_BADHANDLE;
    write_cfg(p, NULL, 0, 0, 0, 0);
    return 0;
}

/* A refresh due now: the trigger count moves (the worker compares it with the count it
 * saw when its last refresh of the plan started), and the worker is woken. */
int mbfb_plan_trigger(int plan)
{
    mbfb_plan_t *p = plan_of(plan);
    mbfb_bus_t *b;

    if (p == NULL)
        return -MBFB_E_BADHANDLE;
    __atomic_fetch_add(&p->trigger, 1u, __ATOMIC_RELEASE);
    b = __atomic_load_n(&mbfb_buses[p->bus], __ATOMIC_ACQUIRE);
    if (b != NULL)
        mbfb_wake(b); /* an edge of the block's Trigger, not steady state */
    return 0;
}

/* The slow tier due in the next refresh that starts: its generation moves. */
int mbfb_plan_invalidate(int plan)
{
    mbfb_plan_t *p = plan_of(plan);
    if (p == NULL)
        return -MBFB_E_BADHANDLE;
    return (int)(slow_invalidate(p) & 0x7FFFFFFFu);
}

/* Wake the worker of a plan's bus (the take of a parked plan's snapshot: once a stop).
 * Out of line and cold: the take's steady state pays nothing for it. */
__attribute__((noinline, cold)) static void wake_worker(const mbfb_plan_t *p)
{
    mbfb_bus_t *bus = __atomic_load_n(&mbfb_buses[p->bus], __ATOMIC_ACQUIRE);
    if (bus != NULL)
        mbfb_wake(bus);
}

/* Swap the fresh middle buffer for the one the scan holds (one exchange). The snapshot of
 * a plan parked for want of scans wakes the worker: scanned again, it runs again. Out of
 * line: the take's "nothing new" path keeps its few registers. */
__attribute__((noinline)) static void take_middle(mbfb_plan_t *p)
{
    uint32_t m = __atomic_exchange_n(&p->mid, (uint32_t)p->front, __ATOMIC_ACQ_REL);
    p->front = (int)(m & 3u);
    if (m & MBFB_SNAP_PARKED)
        wake_worker(p);
}

/* Nothing new: one atomic load and a compare. A new snapshot: take the middle buffer
 * (one exchange) and copy it, which only this caller owns now, with memcpy. */
int mbfb_plan_take(int plan, uint32_t *seq, mbfb_snap_t *out)
{
    mbfb_plan_t *p;
    const mbfb_snapbuf_t *b;

    /* plan_of written out: a call costs at -O0, as OpenPLC builds the shims */
    if (plan < 0 || plan >= MBFB_MAX_PLANS || seq == NULL || out == NULL ||
        (p = __atomic_load_n(&mbfb_plans[plan], __ATOMIC_ACQUIRE)) == NULL)
        return -MBFB_E_BADHANDLE;
    /* relaxed: the exchange below is what orders the buffer's contents */
    if (__atomic_load_n(&p->mid, __ATOMIC_RELAXED) & MBFB_SNAP_FRESH)
        take_middle(p);
    b = &p->buf[p->front];
    if (b->snap.seq == *seq)
        return 0; /* nothing newer than the caller's */
    memcpy(out, &b->snap, offsetof(mbfb_snap_t, words) + (size_t)b->nwords * sizeof out->words[0]);
    *seq = b->snap.seq;
    __atomic_store_n(&p->taken, b->snap.seq, __ATOMIC_RELEASE); /* the worker's slow.owed_seq */
    return 1;
}

/* ---- worker side ------------------------------------------------------------ */

int mbfb_plan_read_cfg(mbfb_plan_t *p, mbfb_plan_cfg_t *cfg)
{
    uint32_t s1, s2;
    int running;
    do {
        s1 = __atomic_load_n(&p->cfg_seq, __ATOMIC_ACQUIRE);
        running = LD(&p->running);
        cfg->n = LD(&p->n);
        if (cfg->n < 0 || cfg->n > MBFB_PLAN_MAX_ITEMS)
            cfg->n = 0; /* torn: retried below */
        cfg->nwords = 0;
        for (int i = 0; i < cfg->n; i++) {
            cfg->items[i].fc = LD(&p->items[i].fc);
            cfg->items[i].addr = LD(&p->items[i].addr);
            cfg->items[i].count = LD(&p->items[i].count);
            cfg->items[i].tier = LD(&p->items[i].tier);
            cfg->nwords += mbfb_data_words(cfg->items[i].fc, cfg->items[i].count);
        }
        cfg->period_ms = LD(&p->period_ms);
        cfg->slow_ms = LD(&p->slow_ms);
        cfg->slow_gen = LD(&p->slow.gen);
        s2 = LD(&p->cfg_seq);
    } while ((s1 & 1) || s1 != s2);
    cfg->seq = s1;
    return running && cfg->n > 0;
}

/* Fill the buffer the worker owns and hand it over (mbfb_plan_publish); `bits`: extra
 * bits of mid (MBFB_SNAP_PARKED). Keeps the plan's untaken time: a snapshot published while
 * the previous one was taken starts it; how long the worker's looks saw the previous one
 * waiting is the block's scan interval as far as it can tell (at least that long; a wait
 * over MBFB_SCAN_MAX_MS was a stop). */
static void publish(mbfb_plan_t *p, int result, uint32_t gen, uint32_t read_mask,
                    const uint16_t *words, int nwords, uint32_t bits);

int mbfb_plan_parked(mbfb_plan_t *p, int64_t now)
{
    uint32_t mid = __atomic_load_n(&p->mid, __ATOMIC_ACQUIRE);
    uint32_t cfg = __atomic_load_n(&p->cfg_seq, __ATOMIC_ACQUIRE);
    int period = __atomic_load_n(&p->period_ms, __ATOMIC_RELAXED);
    int64_t every = period > 0 ? (int64_t)period * 1000 : 0; /* on demand: the scan's */
    mbfb_plan_cfg_t c;
    uint16_t words[MBFB_PLAN_MAX_WORDS];

    if (p->parked) {
        if ((mid & MBFB_SNAP_PARKED) && cfg == p->parked_cfg)
            return 1; /* not scanned since (its snapshot is in the middle), same settings */
        p->parked = 0;
        p->seen_us = 0;
        if (mid & MBFB_SNAP_PARKED) { /* set again: untaken from now */
            p->untaken_us = now;
            return 0;
        }
        /* scanned again (that take woke us): a slow task's interval, or a stop */
        if (now - p->untaken_us <= (int64_t)MBFB_SCAN_MAX_MS * 1000)
            p->scan_us = now - p->untaken_us;
        p->untaken_us = 0;
        return 0;
    }
    if (mid & MBFB_SNAP_FRESH)
        p->seen_us = now;
    if (p->scan_us > every)
        every = p->scan_us;
    p->stale_us = MBFB_STALE_PERIODS * every;
    if (p->stale_us < (int64_t)MBFB_STALE_MIN_MS * 1000)
        p->stale_us = (int64_t)MBFB_STALE_MIN_MS * 1000;
    if (!(mid & MBFB_SNAP_FRESH) || now - p->untaken_us <= p->stale_us)
        return 0; /* everything published was taken, or not long ago */
    p->parked = 1;
    p->parked_cfg = cfg;
    if (!mbfb_plan_read_cfg(p, &c))
        c.nwords = 0;
    memset(words, 0, sizeof words);
    publish(p, MBFB_E_STOPPED, __atomic_load_n(&p->slow.gen, __ATOMIC_ACQUIRE), 0u, words,
            c.nwords, MBFB_SNAP_PARKED);
    return 1;
}

/* Fill the buffer the worker owns (plain stores: nobody else can hold it), then swap
 * it with the middle one; the buffer it gets back is the next one to fill (never the
 * one the scan holds). A snapshot the scan has not taken is replaced by the newer. */
void mbfb_plan_publish(mbfb_plan_t *p, int result, uint32_t gen, uint32_t read_mask,
                       const uint16_t *words, int nwords)
{
    publish(p, result, gen, read_mask, words, nwords, 0u);
}

static void publish(mbfb_plan_t *p, int result, uint32_t gen, uint32_t read_mask,
                    const uint16_t *words, int nwords, uint32_t bits)
{
    uint32_t s = p->seq + 1, m;
    mbfb_snapbuf_t *b = &p->buf[p->back];
    int64_t now;

    if (s == 0)
        s = 1; /* 0 means "none yet" */
    b->snap.seq = s;
    b->snap.result = (int32_t)result;
    b->snap.gen = gen;
    b->snap.read_mask = read_mask;
    if (nwords < 0)
        nwords = 0;
    if (nwords > MBFB_PLAN_MAX_WORDS)
        nwords = MBFB_PLAN_MAX_WORDS;
    if (nwords > 0)
        memcpy(b->snap.words, words, (size_t)nwords * sizeof words[0]);
    b->nwords = nwords;
    m = __atomic_exchange_n(&p->mid, (uint32_t)p->back | MBFB_SNAP_FRESH | bits,
                            __ATOMIC_ACQ_REL);
    p->back = (int)(m & 3u);
    __atomic_store_n(&p->pub, s, __ATOMIC_RELEASE);
    p->seq = s;
    if (!(m & MBFB_SNAP_FRESH)) { /* the previous one was taken (or there was none) */
        now = mbfb_now_us();
        if (p->untaken_us != 0) /* the scan interval: at least how long it was seen waiting */
            p->scan_us = p->seen_us > p->untaken_us &&
                                 p->seen_us - p->untaken_us <= (int64_t)MBFB_SCAN_MAX_MS * 1000
                             ? p->seen_us - p->untaken_us
                             : 0;
        p->untaken_us = now;
        p->seen_us = 0;
    }
}
