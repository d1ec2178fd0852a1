/*
 * mbfb_req.c - the scan-side calls (post, post_write, poll, take, cancel, diag) and the
 * worker's side of the request slots.
 *
 * Lock-free: every slot has one state word, (generation << 4) | MBFB_SLOT_*, changed
 * only by __atomic compare-and-swap (GCC/Clang builtins: the same code compiles as C
 * and as C++11, which <stdatomic.h> does not). Producers claim a FREE slot by CAS, so
 * any number of threads may post. The worker is woken with mbfb_wake (mbfb_wake.c),
 * which neither blocks nor allocates. A request handle carries the slot's generation, so a handle
 * that was taken or cancelled is stale and gives -MBFB_E_BADHANDLE.
 *
 * handle - 1 = generation << 10 | bus << 6 | slot
 */
#include <string.h>

#include "mbfb_internal.h"

#define LOAD(p) __atomic_load_n((p), __ATOMIC_ACQUIRE)
#define CAS(p, expect, desired) \
    __atomic_compare_exchange_n((p), &(expect), (desired), 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE)
#define ST(w) ((w) & 15u)
#define GEN(w) ((w) >> 4)
#define WORD(gen, st) (((gen) << 4) | (st))
/* A scan-side call on the bus: the PLC still scans (mbfb_slot_next's stale requests). A
 * relaxed load and store, no locked instruction: two blocks counting at once may count
 * one, and the worker only asks whether the count moved. */
#define SCANNED(bus) \
    __atomic_store_n(&(bus)->scans, __atomic_load_n(&(bus)->scans, __ATOMIC_RELAXED) + 1u, \
                     __ATOMIC_RELAXED)

/* Request handle of a slot. */
static int make_handle(int bus, int slot, uint32_t gen)
{
    return 1 + (int)((gen << 10) | (uint32_t)(bus << 6) | (uint32_t)slot);
}

/* The slot a handle names, and the generation it expects; NULL if malformed. */
static mbfb_slot_t *slot_of(int req, uint32_t *gen, mbfb_bus_t **busp)
{
    mbfb_bus_t *bus;
    uint32_t h;

    if (req <= 0)
        return NULL;
    h = (uint32_t)(req - 1);
    bus = __atomic_load_n(&mbfb_buses[(h >> 6) & (MBFB_MAX_BUSES - 1)], __ATOMIC_ACQUIRE);
    if (bus == NULL)
        return NULL;
    *gen = h >> 10;
    if (busp != NULL)
        *busp = bus;
    return &bus->slots[h & (MBFB_MAX_SLOTS - 1)];
}

/* mbfb_post_write with MBFB_WRITE_IDEMPOTENT (ignored for reads). */
int mbfb_post(int dev, int fc, int addr, int count, const uint16_t *values)
{
    return mbfb_post_write(dev, fc, addr, count, values, MBFB_WRITE_IDEMPOTENT);
}

/* Claim a free slot of the bus by CAS: the slot (CLAIMED, *index, *gen), or NULL when
 * none is free. */
static mbfb_slot_t *claim_slot(mbfb_bus_t *bus, int *index, uint32_t *gen)
{
    for (int i = 0; i < MBFB_MAX_SLOTS; i++) {
        uint32_t w = LOAD(&bus->slots[i].state);
        if (ST(w) != MBFB_SLOT_FREE)
            continue;
        *gen = (GEN(w) + 1) & MBFB_GEN_MASK;
        if (CAS(&bus->slots[i].state, w, WORD(*gen, MBFB_SLOT_CLAIMED))) {
            *index = i;
            return &bus->slots[i];
        }
    }
    return NULL;
}

/* Queue a filled slot behind every request posted so far and wake the worker. */
static void queue_slot(mbfb_bus_t *bus, mbfb_slot_t *s, uint32_t gen)
{
    __atomic_store_n(&s->seq, __atomic_fetch_add(&bus->post_seq, 1u, __ATOMIC_RELAXED),
                     __ATOMIC_RELAXED);
    SCANNED(bus);
    __atomic_store_n(&s->state, WORD(gen, MBFB_SLOT_QUEUED), __ATOMIC_RELEASE);
    mbfb_wake(bus);
}

/* A post under way: the device, its bus, the slot claimed there, its index and generation. */
typedef struct {
    mbfb_dev_t *d;
    mbfb_bus_t *bus;
    mbfb_slot_t *s;
    int index;
    uint32_t gen;
} mbfb_post_t;

/* Both posts' steps are macros on a local mbfb_post_t, not functions: OpenPLC compiles the
 * shims with the program at -O0, where a helper's arguments cost every post (a shared
 * function: 148 -> 203 instructions a post; always_inline ones: about 40 more).
 * POST_DEVICE: p.d the device `dev`; false when the number names none. */
#define POST_DEVICE(p, dev)                                                                 \
    ((dev) >= 0 && (dev) < MBFB_MAX_DEVICES &&                                            \
     ((p).d = __atomic_load_n(&mbfb_devs[dev], __ATOMIC_ACQUIRE)) != NULL)

/* POST_CLAIM: a free slot of p.d's bus claimed (p.bus, p.s, p.index, p.gen) and the
 * request's header filled (the caller copies the values, then queue_slot); false when
 * none is free. */
#define POST_CLAIM(p, dev_, fc_, addr_, count_, policy_, chain_)                            \
    (((p).bus = __atomic_load_n(&mbfb_buses[(p).d->bus], __ATOMIC_ACQUIRE),                \
      (p).s = claim_slot((p).bus, &(p).index, &(p).gen)) != NULL &&                       \
     ((p).s->dev = (dev_), (p).s->fc = (fc_), (p).s->addr = (addr_),                      \
      (p).s->count = (count_), (p).s->policy = (policy_), (p).s->chain = (chain_),        \
      (p).s->result = 0, __atomic_store_n(&(p).s->nvals, 0, __ATOMIC_RELAXED), 1))

/* Claim a free slot, fill it, queue it and wake the worker. Reads go through here too
 * (policy unused). */
int mbfb_post_write(int dev, int fc, int addr, int count, const uint16_t *values, int policy)
{
    mbfb_post_t p;

    if (!POST_DEVICE(p, dev))
        return -MBFB_E_BADHANDLE;
    if (mbfb_check_args(p.d->slave, fc, addr, count, values) != MBFB_OK ||
        (policy != MBFB_WRITE_IDEMPOTENT && policy != MBFB_WRITE_ONCE))
        return -MBFB_E_INVAL;
    if (!POST_CLAIM(p, dev, fc, addr, count, policy, 0))
        return -MBFB_E_QUEUEFULL;
    if (mbfb_fc_is_write(fc)) /* registers, or coils packed (FC05: one word) */
        memcpy(p.s->values, values, (size_t)mbfb_data_words(fc, count) * sizeof values[0]);
    queue_slot(p.bus, p.s, p.gen);
    return make_handle(p.d->bus, p.index, p.gen);
}

/* A chain: its registers and words copied into one slot (mbfb_internal.h). */
int mbfb_post_chain(int dev, int n, const uint16_t *regs, const uint16_t *words)
{
    mbfb_post_t p;

    if (!POST_DEVICE(p, dev))
        return -MBFB_E_BADHANDLE;
    if (n < 1 || n > MBFB_CHAIN_MAX || regs == NULL || words == NULL || p.d->slave == 0)
        return -MBFB_E_INVAL;
    if (!POST_CLAIM(p, dev, MBFB_FC_WRITE_SINGLE, regs[0], n, MBFB_WRITE_IDEMPOTENT, 1))
        return -MBFB_E_QUEUEFULL;
    memcpy(p.s->values, regs, (size_t)n * sizeof regs[0]);
    memcpy(p.s->values + n, words, (size_t)n * sizeof words[0]);
    queue_slot(p.bus, p.s, p.gen);
    return make_handle(p.d->bus, p.index, p.gen);
}

/* A chain's entries held: the worker's count, read with the slot's state word. */
int mbfb_chain_held(int req)
{
    uint32_t gen, w;
    mbfb_slot_t *s = slot_of(req, &gen, NULL);
    int held;

    if (s == NULL || GEN(w = LOAD(&s->state)) != gen || ST(w) == MBFB_SLOT_FREE ||
        ST(w) == MBFB_SLOT_CLAIMED || !s->chain)
        return -MBFB_E_BADHANDLE;
    held = __atomic_load_n(&s->nvals, __ATOMIC_ACQUIRE);
    /* taken or reused meanwhile: the count may be another request's */
    return LOAD(&s->state) == w ? held : -MBFB_E_BADHANDLE;
}

/* State of a request from its slot's state word. */
int mbfb_poll(int req)
{
    uint32_t gen, w;
    mbfb_bus_t *bus = NULL;
    mbfb_slot_t *s = slot_of(req, &gen, &bus);

    if (s == NULL || GEN(w = LOAD(&s->state)) != gen)
        return -MBFB_E_BADHANDLE;
    SCANNED(bus);
    switch (ST(w)) {
    case MBFB_SLOT_QUEUED: return MBFB_REQ_QUEUED;
    case MBFB_SLOT_ACTIVE: return MBFB_REQ_ACTIVE;
    case MBFB_SLOT_DONE:   return MBFB_REQ_DONE;
    case MBFB_SLOT_FAILED: return MBFB_REQ_FAILED;
    default:               return -MBFB_E_BADHANDLE;
    }
}

/* Copy out a finished request and free its slot (CAS: one taker wins). */
int mbfb_take(int req, uint16_t *values, int max)
{
    uint32_t gen, w;
    mbfb_slot_t *s = slot_of(req, &gen, NULL);
    int rc;

    if (s == NULL || GEN(w = LOAD(&s->state)) != gen)
        return -MBFB_E_BADHANDLE;
    if (ST(w) == MBFB_SLOT_FAILED) {
        rc = -s->result;
    } else if (ST(w) == MBFB_SLOT_DONE) {
        int words = mbfb_data_words(s->fc, s->nvals); /* FC01/02: nvals bits, packed */
        words = values == NULL || max < 0 ? 0 : (words < max ? words : max);
        if (words > 0)
            memcpy(values, s->values, (size_t)words * sizeof values[0]);
        rc = words; /* registers copied; bits copied: */
        if (mbfb_fc_is_bits(s->fc))
            rc = 16 * words < s->nvals ? 16 * words : s->nvals;
    } else {
        return -MBFB_E_BADHANDLE; /* not finished (or already taken) */
    }
    /* free the slot; fails only if another thread took or cancelled it meanwhile */
    return CAS(&s->state, w, WORD(gen, MBFB_SLOT_FREE)) ? rc : -MBFB_E_BADHANDLE;
}

/* Free a queued/finished slot, or mark one on the wire for the worker to free. */
int mbfb_cancel(int req)
{
    uint32_t gen, w, next;
    mbfb_slot_t *s = slot_of(req, &gen, NULL);

    if (s == NULL)
        return -MBFB_E_BADHANDLE;
    for (;;) {
        w = LOAD(&s->state);
        if (GEN(w) != gen)
            return -MBFB_E_BADHANDLE;
        switch (ST(w)) {
        case MBFB_SLOT_QUEUED:
        case MBFB_SLOT_DONE:
        case MBFB_SLOT_FAILED:
            next = WORD(gen, MBFB_SLOT_FREE);
            break;
        case MBFB_SLOT_ACTIVE: /* on the wire: the worker frees it when done */
            next = WORD(gen, MBFB_SLOT_CANCELLED);
            break;
        default:
            return -MBFB_E_BADHANDLE;
        }
        if (CAS(&s->state, w, next))
            return 0;
    }
}

/* The device of a handle, or NULL. */
static mbfb_dev_t *dev_of(int dev)
{
    if (dev < 0 || dev >= MBFB_MAX_DEVICES)
        return NULL;
    return __atomic_load_n(&mbfb_devs[dev], __ATOMIC_ACQUIRE);
}

/* Copy the diagnostics field by field: every field is 32 bits, written by the worker
 * with __atomic stores and read here with one relaxed load each. Written out, not a
 * loop: OpenPLC compiles the shims at -O0, where a 16-pass loop costs twice as many
 * instructions as the 16 loads (st_src/README.md, "Scan cost"). */
/* a field added to mbfb_diag_t must be added below: a compile error until it is */
typedef char mbfb_diag_has_16_fields[sizeof(mbfb_diag_t) == 16 * sizeof(uint32_t) ? 1 : -1];
#define DIAG_LD(f) (out->f = __atomic_load_n(&g->f, __ATOMIC_RELAXED))
int mbfb_dev_diag(int dev, mbfb_diag_t *out)
{
    mbfb_dev_t *d;
    mbfb_bus_t *b;
    const mbfb_diag_t *g;

    if (out == NULL || dev < 0 || dev >= MBFB_MAX_DEVICES ||
        (d = __atomic_load_n(&mbfb_devs[dev], __ATOMIC_ACQUIRE)) == NULL)
        return -MBFB_E_BADHANDLE;
    g = &d->diag;
    DIAG_LD(requests);
    DIAG_LD(good);
    DIAG_LD(timeouts);
    DIAG_LD(crc_errors);
    DIAG_LD(bad_replies);
    DIAG_LD(exceptions);
    DIAG_LD(retries);
    DIAG_LD(last_exception);
    DIAG_LD(last_rtt_us);
    DIAG_LD(offline);
    DIAG_LD(last_error);
    DIAG_LD(resyncs);
    DIAG_LD(refreshes);
    DIAG_LD(refresh_us);
    /* stray bytes belong to the line, not to one device: the bus's count; and the
     * line's share of the last second, as the worker keeps it (one load each) */
    b = __atomic_load_n(&mbfb_buses[d->bus], __ATOMIC_ACQUIRE);
    out->stray_bytes = b ? __atomic_load_n(&b->stray_bytes, __ATOMIC_RELAXED) : 0;
    out->line_permille = b ? __atomic_load_n(&b->busy_permille, __ATOMIC_RELAXED) : 0;
    return 0;
}
#undef DIAG_LD

/* The device's diag_seq plus its bus's stray-byte count (shown in every device's
 * diagnostics): two atomic loads, no system call. 0 for an unknown handle. */
uint32_t mbfb_dev_diag_seq(int dev)
{
    mbfb_dev_t *d;
    mbfb_bus_t *b;

    /* dev_of written out: a call costs at -O0, as OpenPLC builds the shims */
    if (dev < 0 || dev >= MBFB_MAX_DEVICES ||
        (d = __atomic_load_n(&mbfb_devs[dev], __ATOMIC_ACQUIRE)) == NULL)
        return 0;
    b = __atomic_load_n(&mbfb_buses[d->bus], __ATOMIC_ACQUIRE);
    return __atomic_load_n(&d->diag_seq, __ATOMIC_ACQUIRE) +
           (b ? __atomic_load_n(&b->stray_bytes, __ATOMIC_RELAXED) : 0u);
}

/* Bus diagnostics; busy_permille is the worker's sum of the 100 ms buckets of the last
 * second (kept up to date by the worker: no clock read here). */
int mbfb_bus_diag(int dev, mbfb_bus_diag_t *out)
{
    mbfb_dev_t *d = dev_of(dev);
    mbfb_bus_t *b;
    uint32_t plans = 0;
    int n;

    if (out == NULL || d == NULL ||
        (b = __atomic_load_n(&mbfb_buses[d->bus], __ATOMIC_ACQUIRE)) == NULL)
        return -MBFB_E_BADHANDLE;
    n = __atomic_load_n(&b->n_plans, __ATOMIC_ACQUIRE);
    for (int i = 0; i < n; i++) {
        mbfb_plan_t *p = __atomic_load_n(&b->plans[i], __ATOMIC_ACQUIRE);
        plans += p != NULL && __atomic_load_n(&p->running, __ATOMIC_RELAXED);
    }
    out->transactions = __atomic_load_n(&b->transactions, __ATOMIC_RELAXED);
    out->busy_permille = __atomic_load_n(&b->busy_permille, __ATOMIC_RELAXED);
    out->plans = plans;
    out->stray_bytes = __atomic_load_n(&b->stray_bytes, __ATOMIC_RELAXED);
    return 0;
}

/* ---- worker side ---------------------------------------------------------- */

/* Has nothing been posted or polled on the bus for MBFB_STALE_MIN_MS, or the longest
 * stale bound of its plans (a slow task), on the worker's clock? Then the PLC has stopped
 * scanning the blocks that post here: what they queued is not sent (README "Lifetime"). */
static int bus_unscanned(mbfb_bus_t *bus)
{
    int64_t now = mbfb_now_us(), bound = (int64_t)MBFB_STALE_MIN_MS * 1000;
    uint32_t scans = __atomic_load_n(&bus->scans, __ATOMIC_RELAXED);
    int n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE);

    if (scans != bus->scans_seen || bus->scanned_us == 0) {
        bus->scans_seen = scans;
        bus->scanned_us = now;
    }
    for (int i = 0; i < n; i++) { /* their bounds: kept by this worker (mbfb_plan_parked) */
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        if (p != NULL && p->stale_us > bound)
            bound = p->stale_us;
    }
    return now - bus->scanned_us > bound;
}

/* The oldest queued request (posted before *before, if given; a chain only if `chains`),
 * made ACTIVE; NULL if none. Requests queued by a PLC that has stopped scanning
 * (bus_unscanned) end MBFB_E_STOPPED, not sent. */
mbfb_slot_t *mbfb_slot_next(mbfb_bus_t *bus, const uint32_t *before, int chains)
{
    for (;;) {
        mbfb_slot_t *best = NULL;
        uint32_t best_w = 0, best_seq = 0;
        for (int i = 0; i < MBFB_MAX_SLOTS; i++) {
            uint32_t w = LOAD(&bus->slots[i].state), seq;
            if (ST(w) != MBFB_SLOT_QUEUED)
                continue;
            seq = __atomic_load_n(&bus->slots[i].seq, __ATOMIC_RELAXED);
            if (before != NULL && (int32_t)(seq - *before) >= 0)
                continue; /* queued after the caller's bound: its next turn */
            if (!chains && bus->slots[i].chain)
                continue; /* not between two reads of one refresh */
            if (best == NULL || (int32_t)(seq - best_seq) < 0) {
                best = &bus->slots[i];
                best_w = w;
                best_seq = seq;
            }
        }
        if (best == NULL)
            return NULL;
        /* looked at after the slot: its post's count is seen (posted before it was queued) */
        if (CAS(&best->state, best_w, WORD(GEN(best_w), MBFB_SLOT_ACTIVE))) {
            if (!bus_unscanned(bus))
                return best;
            mbfb_slot_finish(best, MBFB_E_STOPPED);
        }
        /* cancelled meanwhile, or not sent: look again */
    }
}

/* ACTIVE -> QUEUED with a new sequence number (behind every post so far), or CANCELLED ->
 * FREE; the worker is woken so that it does not wait while the entry is queued. */
void mbfb_slot_requeue(mbfb_bus_t *bus, mbfb_slot_t *s)
{
    uint32_t w = LOAD(&s->state);

    __atomic_store_n(&s->seq, __atomic_fetch_add(&bus->post_seq, 1u, __ATOMIC_RELAXED),
                     __ATOMIC_RELAXED);
    for (;;) {
        uint32_t next = WORD(GEN(w), ST(w) == MBFB_SLOT_CANCELLED ? MBFB_SLOT_FREE
                                                                   : MBFB_SLOT_QUEUED);
        if (CAS(&s->state, w, next))
            break;
    }
    mbfb_wake(bus);
}

/* ACTIVE -> DONE/FAILED, or CANCELLED -> FREE. */
void mbfb_slot_finish(mbfb_slot_t *s, int result)
{
    uint32_t w = LOAD(&s->state);
    s->result = result;
    for (;;) {
        uint32_t next = WORD(GEN(w), ST(w) == MBFB_SLOT_CANCELLED
                                         ? MBFB_SLOT_FREE
                                         : (result == MBFB_OK ? MBFB_SLOT_DONE : MBFB_SLOT_FAILED));
        if (CAS(&s->state, w, next))
            return;
    }
}

/* End every queued request with `result` (port lost). */
void mbfb_slot_fail_queued(mbfb_bus_t *bus, int result)
{
    mbfb_slot_t *s;
    while ((s = mbfb_slot_next(bus, NULL, 1)) != NULL)
        mbfb_slot_finish(s, result);
}
