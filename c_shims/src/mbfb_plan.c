/*
 * mbfb_plan.c - refresh plans: the scan side (open, set, stop, invalidate, take) and
 * the worker's side of the settings and snapshots.
 *
 * Lock-free both ways (see mbfb_internal.h, "plans"): settings in a sequence lock the
 * scan writes and the worker copies; snapshots in a double buffer the worker writes and
 * the scan copies, retrying a copy the worker overwrote meanwhile. Every shared field
 * is accessed with __atomic builtins, so the code is the
 * same in C and C++ and ThreadSanitizer sees no plain data race.
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
        __atomic_store_n(&b->plans[n], p, __ATOMIC_RELEASE);
        __atomic_store_n(&b->n_plans, n + 1, __ATOMIC_RELEASE);
        __atomic_store_n(&mbfb_plans[i], p, __ATOMIC_RELEASE);
        rc = i;
        break;
    }
    pthread_mutex_unlock(&mbfb_registry_lock);
    return rc;
}

/* Check a plan's items: fc 3/4, counts, address range, tiers, words in all. */
static int check_items(const mbfb_plan_item_t *items, int n)
{
    int words = 0;
    if (items == NULL || n < 1 || n > MBFB_PLAN_MAX_ITEMS)
        return MBFB_E_INVAL;
    for (int i = 0; i < n; i++) {
        const mbfb_plan_item_t *it = &items[i];
        if ((it->fc != 3 && it->fc != 4) || it->count < 1 || it->count > MBFB_MAX_READ ||
            it->addr < 0 || it->addr + it->count > MBFB_ADDR_SPACE ||
            it->tier < MBFB_TIER_EVERY || it->tier > MBFB_TIER_FAST)
            return MBFB_E_INVAL;
        words += it->count;
    }
    return words > MBFB_PLAN_MAX_WORDS ? MBFB_E_INVAL : MBFB_OK;
}

/* Write the settings inside the sequence lock (one writer per plan: its block). */
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
    if (check_items(items, n) != MBFB_OK || period_ms < 0 || slow_period_ms < 0)
        return -MBFB_E_INVAL;
    write_cfg(p, items, n, period_ms, slow_period_ms, 1);
    b = __atomic_load_n(&mbfb_buses[p->bus], __ATOMIC_ACQUIRE);
    if (b != NULL)
        sem_post(&b->wake); /* a settings change, not steady state: wake the worker */
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

/* Bump the invalidation generation; the next refresh reads the slow tier. */
int mbfb_plan_invalidate(int plan)
{
    mbfb_plan_t *p = plan_of(plan);
    if (p == NULL)
        return -MBFB_E_BADHANDLE;
    return (int)((__atomic_add_fetch(&p->inval_gen, 1u, __ATOMIC_ACQ_REL)) & 0x7FFFFFFFu);
}

/* One atomic load when nothing is new; else copy the newest snapshot, again if the
 * worker overwrote it meanwhile. */
int mbfb_plan_take(int plan, uint32_t *seq, mbfb_snap_t *out)
{
    mbfb_plan_t *p = plan_of(plan);
    uint32_t s;

    if (p == NULL || seq == NULL || out == NULL)
        return -MBFB_E_BADHANDLE;
    s = __atomic_load_n(&p->pub, __ATOMIC_ACQUIRE);
    if (s == *seq)
        return 0; /* nothing new: one atomic load */
    for (;;) {
        const mbfb_snapbuf_t *b = &p->buf[s & 1];
        int atoms = (int)LD(&b->read_mask) >> 16; /* atoms used: high half, see publish */
        out->result = LD(&b->result);
        out->gen = LD(&b->gen);
        out->read_mask = LD(&b->read_mask) & 0xFFFFu;
        if (atoms > MBFB_SNAP_ATOMS)
            atoms = MBFB_SNAP_ATOMS; /* torn: retried below */
        for (int i = 0; i < atoms - 1; i++) { /* whole atoms: an 8-byte move each */
            uint64_t a = LD(&b->atoms[i]);
            memcpy(&out->words[4 * i], &a, sizeof a);
        }
        if (atoms > 0) { /* the last one: words[] ends at 125 */
            uint64_t a = LD(&b->atoms[atoms - 1]);
            int w = 4 * (atoms - 1);
            memcpy(&out->words[w], &a,
                   (size_t)(MBFB_PLAN_MAX_WORDS - w < 4 ? MBFB_PLAN_MAX_WORDS - w : 4) * 2);
        }
        if (LD(&b->seq) == s)
            break;
        s = __atomic_load_n(&p->pub, __ATOMIC_ACQUIRE); /* overwritten meanwhile: again */
    }
    out->seq = s;
    *seq = s;
    __atomic_store_n(&p->taken, s, __ATOMIC_RELEASE); /* the worker's slow_owed */
    return 1;
}

/* ---- worker side ------------------------------------------------------------ */

int mbfb_plan_read_cfg(mbfb_plan_t *p, mbfb_plan_item_t *items, int *n, int *period_ms,
                       int *slow_ms, uint32_t *cfg_seq)
{
    uint32_t s1, s2;
    int running;
    do {
        s1 = __atomic_load_n(&p->cfg_seq, __ATOMIC_ACQUIRE);
        running = LD(&p->running);
        *n = LD(&p->n);
        if (*n < 0 || *n > MBFB_PLAN_MAX_ITEMS)
            *n = 0; /* torn: retried below */
        for (int i = 0; i < *n; i++) {
            items[i].fc = LD(&p->items[i].fc);
            items[i].addr = LD(&p->items[i].addr);
            items[i].count = LD(&p->items[i].count);
            items[i].tier = LD(&p->items[i].tier);
        }
        *period_ms = LD(&p->period_ms);
        *slow_ms = LD(&p->slow_ms);
        s2 = LD(&p->cfg_seq);
    } while ((s1 & 1) || s1 != s2);
    *cfg_seq = s1;
    return running && *n > 0;
}

/* Fill the buffer the readers are not told about, then publish it. The number of
 * 64-bit atoms used rides in read_mask's high half (items use bits 0..3). */
void mbfb_plan_publish(mbfb_plan_t *p, int result, uint32_t gen, uint32_t read_mask,
                       const uint16_t *words, int nwords)
{
    uint32_t s = p->seq + 1;
    mbfb_snapbuf_t *b;
    int atoms = (nwords + 3) / 4;

    if (s == 0)
        s = 1; /* 0 means "none yet" */
    b = &p->buf[s & 1];
    __atomic_exchange_n(&b->seq, 0u, __ATOMIC_ACQ_REL); /* the stores below stay after */
    ST(&b->result, (int32_t)result);
    ST(&b->gen, gen);
    ST(&b->read_mask, (read_mask & 0xFFFFu) | ((uint32_t)atoms << 16));
    for (int i = 0; i < atoms; i++) {
        uint64_t a = 0;
        int w = 4 * i, k = nwords - w < 4 ? nwords - w : 4;
        memcpy(&a, &words[w], (size_t)k * sizeof words[0]);
        ST(&b->atoms[i], a);
    }
    __atomic_store_n(&b->seq, s, __ATOMIC_RELEASE);
    __atomic_store_n(&p->pub, s, __ATOMIC_RELEASE);
    p->seq = s;
}
