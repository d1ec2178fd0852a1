/*
 * mbfb_worker.c - the one thread per bus that does all its I/O.
 *
 * Work, in this order: posted requests (writes, generic reads) in posting order, then
 * the refresh of the plan due first (ties: round robin); a posted request also goes
 * before each read of a refresh. Otherwise the worker sleeps until the next due time
 * or a post (sem_clockwait on CLOCK_MONOTONIC).
 *
 * One request (a posted one or a plan read) = up to 1 + retries failed attempts:
 *   wait until the line is silent (the gap; a whole response timeout, the settle, after a
 *   failed attempt to another slave), send, receive, validate.
 * In step (README "Late replies"): RTU has no transaction id. After a failed attempt
 * the device is out of step and the reply shape of that attempt is outstanding. While
 * out of step only resync reads go to the device: a read whose reply shape differs from
 * every outstanding one. A good reply to it brings the device back in step (it serves
 * requests in order: nothing older can follow) and clears the outstanding set. A late
 * reply heard in the silence before a request, or in a resync read's wait, retires its
 * shape (retire_heard), and a read whose shape is free is its own resync read: its
 * answer is the request's. A resync read goes right after the failed attempt: no settle.
 * Confirmed writes (README "Confirmed writes"): an echo while in step is DONE; an
 * exception is a definite "not applied"; any other failure leaves the outcome unknown
 * until a read-back (FC03 of the written registers, in step) shows it: equal -> DONE;
 * differs -> MBFB_WRITE_IDEMPOTENT sends it again, MBFB_WRITE_ONCE ends UNCONFIRMED.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* sem_clockwait */
#endif
#include <errno.h>
#include <string.h>

#include "mbfb_internal.h"

/* ---- small helpers -------------------------------------------------------------- */

/* Last error of a device (diag.last_error). */
static void set_error(mbfb_dev_t *dev, int err)
{
    MBFB_DIAG_SET(dev, last_error, (int32_t)err);
}

/* Count a failed attempt in the device diagnostics. */
static void count_failure(mbfb_dev_t *dev, int err)
{
    if (err == MBFB_E_TIMEOUT)
        MBFB_DIAG_INC(dev, timeouts);
    else if (err == MBFB_E_CRC)
        MBFB_DIAG_INC(dev, crc_errors);
    else if (err >= MBFB_E_EXCEPTION_BASE) {
        MBFB_DIAG_INC(dev, exceptions);
        MBFB_DIAG_SET(dev, last_exception, (uint32_t)(err - MBFB_E_EXCEPTION_BASE));
    } else
        MBFB_DIAG_INC(dev, bad_replies);
}

/* Sum the 100 ms buckets of the second before `now` into bus->busy_permille (what the
 * scan reads: one load). Returns when the window will hold no busy time any more (the
 * newest busy bucket leaves it), or INT64_MAX when it holds none now: the idle worker
 * wakes then once to store 0 (worker loop), so a quiet line reads 0 a second after its
 * last attempt without a wake per bucket. */
static int64_t busy_update(mbfb_bus_t *bus, int64_t now)
{
    uint32_t epoch = (uint32_t)(now / 100000), busy = 0, age = MBFB_BUSY_BUCKETS;
    for (int i = 0; i < MBFB_BUSY_BUCKETS; i++) {
        uint32_t a = epoch - __atomic_load_n(&bus->busy_epoch[i], __ATOMIC_RELAXED);
        uint32_t us = __atomic_load_n(&bus->busy_us[i], __ATOMIC_RELAXED);
        if (a < MBFB_BUSY_BUCKETS && us > 0) {
            busy += us;
            age = a < age ? a : age; /* the newest busy bucket */
        }
    }
    __atomic_store_n(&bus->busy_permille, busy / 1000 > 1000 ? 1000u : busy / 1000,
                     __ATOMIC_RELAXED);
    return busy == 0 ? INT64_MAX : (now / 100000 - age + MBFB_BUSY_BUCKETS) * 100000;
}

/* Account `us` of line time in the 100 ms bucket of now (busy_permille). */
static void busy_add(mbfb_bus_t *bus, int64_t now, int64_t us)
{
    uint32_t epoch = (uint32_t)(now / 100000);
    int i = (int)(epoch % MBFB_BUSY_BUCKETS);
    if (us <= 0)
        return;
    if (__atomic_load_n(&bus->busy_epoch[i], __ATOMIC_RELAXED) != epoch) {
        __atomic_store_n(&bus->busy_us[i], 0u, __ATOMIC_RELAXED);
        __atomic_store_n(&bus->busy_epoch[i], epoch, __ATOMIC_RELEASE);
    }
    __atomic_fetch_add(&bus->busy_us[i], (uint32_t)us, __ATOMIC_RELAXED);
    busy_update(bus, now);
}

static void hear_late_replies(mbfb_bus_t *bus);

/* Modbus exception codes that a request draws each time it is sent, as the device's map
 * does not change: illegal function, data address, data value. The others (device
 * failure, acknowledge, busy) may answer any request. */
#define MBFB_EXC_FIXED_MAX 3

/* Could a request of outstanding shape sh be answered with exception `code` (0: any)?
 * Any request of its function may, except a read inside a range that read well
 * (sh->readable): that one draws data or a passing exception, never a fixed one. */
static int exception_fits_shape(const mbfb_shape_t *sh, int fc, int code)
{
    return sh->fc == fc && !(sh->readable && code >= 1 && code <= MBFB_EXC_FIXED_MAX);
}

/* Does a whole, checked reply frame f (slave + PDU, len bytes) fit outstanding shape sh?
 * A read's reply by its byte count, a write's echo by its address and value / count, an
 * exception by its function and code (exception_fits_shape). */
static int reply_fits_shape(const mbfb_shape_t *sh, const uint8_t *f, int len)
{
    if (sh->fc != (f[1] & 0x7F))
        return 0;
    if (f[1] & 0x80)
        return len >= 3 && exception_fits_shape(sh, sh->fc, f[2]);
    if (sh->fc == 3 || sh->fc == 4)
        return len >= 3 && sh->bytes == f[2];
    return len >= 6 && sh->echo[0] == (uint16_t)(f[2] << 8 | f[3]) &&
           sh->echo[1] == (uint16_t)(f[4] << 8 | f[5]);
}

/* The device answered (or was heard): out of back-off, its failures count from 0 again. */
static void end_backoff(mbfb_dev_t *dev)
{
    dev->fails = 0;
    dev->probe_us = 0;
    MBFB_DIAG_SET(dev, offline, 0u);
}

/* A whole, checked reply frame f (slave + PDU) heard outside its request: when a device of
 * this bus has its shape outstanding, retire that shape (the device gives one reply per
 * request, so that one can no longer come) and return 1; else 0. A device heard answering
 * is busy or slow, not gone: its back-off ends (its failures count from 0 again). */
static int retire_heard(mbfb_bus_t *bus, const uint8_t *f, int len)
{
    for (int d = 0; d < MBFB_MAX_DEVICES; d++) {
        mbfb_dev_t *dev = __atomic_load_n(&mbfb_devs[d], __ATOMIC_ACQUIRE);
        int i, fits = 0;
        if (dev == NULL || dev->bus != bus->index || dev->slave != f[0])
            continue;
        for (int k = 0; k < dev->n_outstanding; k++)
            fits += reply_fits_shape(&dev->outstanding[k], f, len);
        /* an exception tells only the function: which of two outstanding requests of it
         * was answered is unknown, so it retires a shape only when it is the only one */
        if (fits == 0 || (fits > 1 && (f[1] & 0x80)))
            return 0;
        for (i = 0; i < dev->n_outstanding; i++)
            if (reply_fits_shape(&dev->outstanding[i], f, len))
                break;
        memmove(&dev->outstanding[i], &dev->outstanding[i + 1],
                (size_t)(dev->n_outstanding - i - 1) * sizeof dev->outstanding[0]);
        dev->n_outstanding--;
        dev->heard = 1;
        if (dev->fails > 0)
            end_backoff(dev);
        return 1;
    }
    return 0;
}

/* Wait for a silent line before an attempt to `slave`: the gap, or, after a failed attempt
 * to another slave, the settle (a response timeout of silence: that slave's late reply
 * would fail this slave's request). The failed slave's own resync read owes no settle: its
 * reply shape differs from every outstanding one, and a late reply that comes in its wait
 * is retired there (send_and_check). A late reply heard meanwhile retires its outstanding
 * shape. 0 or -PORTLOST. */
static int wait_quiet(mbfb_bus_t *bus, int slave)
{
    int silence = bus->timing.gap_us, n;

    if (bus->settle_us > 0 && slave != bus->settle_slave) {
        silence = bus->settle_us > silence ? bus->settle_us : silence;
        bus->settle_us = 0; /* waited for here; the failed slave's own attempts keep it */
    }
    n = bus->be->quiet(bus, silence, silence + MBFB_QUIET_LIMIT_T * bus->timeout_us);
    if (n < 0)
        return n;
    MBFB_STRAY_ADD(bus, n);
    if (bus->be->needs_resync && bus->n_heard > 0)
        hear_late_replies(bus);
    return 0;
}

/* ---- one attempt ---------------------------------------------------------------- */

/* One exchange on the wire: fc 3/4 (values read into out), 6/16 (vals written).
 * Returns MBFB_OK, a positive MBFB_E_* (failure or 128 + exception), or
 * -MBFB_E_PORTLOST. A failure owes the line a settle before an attempt to another slave
 * (wait_quiet) and, on TCP, reconnects. */
static int send_and_check(mbfb_bus_t *bus, mbfb_dev_t *dev, int fc, int addr, int count,
                          const uint16_t *vals, uint16_t *out)
{
    uint8_t req[MBFB_FRAME_MAX], rsp[MBFB_FRAME_MAX];
    int len = mbfb_build_request(req, dev->slave, fc, addr, count, vals), rc, err;
    int64_t t0, deadline;

    bus->timeout_us = bus->cfg.response_timeout_ms > 0
                          ? bus->cfg.response_timeout_ms * 1000
                          : mbfb_response_timeout_us(&bus->timing, bus->cfg.framing, len,
                                                     mbfb_reply_len(req));
    if (wait_quiet(bus, dev->slave) < 0)
        return -MBFB_E_PORTLOST;
    if (mbfb_stopping(bus))
        return MBFB_E_CANCELLED; /* shutting down: no new attempt (README "Lifetime") */
    t0 = mbfb_now_us();
    if (bus->be->send(bus, req, len) < 0)
        return -MBFB_E_PORTLOST;
    __atomic_fetch_add(&bus->transactions, 1u, __ATOMIC_RELAXED);
    if (req[0] == 0) { /* broadcast: no reply; let the slaves process it */
        bus->quiet_from_us = t0 + (int64_t)mbfb_wire_len(bus->cfg.framing, len) *
                                      bus->timing.char_us + MBFB_TURNAROUND_US;
        busy_add(bus, t0, bus->quiet_from_us - t0 + bus->timing.gap_us);
        return MBFB_OK;
    }
    deadline = mbfb_now_us() + bus->timeout_us;
    rc = bus->be->recv(bus, req, rsp, (int)sizeof rsp, bus->timeout_us);
    /* a late reply of an outstanding shape came first (a resync read's shape differs from
     * every outstanding one; another slave's reply never passes the check): its shape is
     * retired and the wait goes on for this request's own answer, which the device sends
     * after it */
    while (rc > 0 && bus->be->needs_resync &&
           mbfb_check_reply(req, rsp, rc) == MBFB_E_BADREPLY && retire_heard(bus, rsp, rc)) {
        int64_t left = deadline - mbfb_now_us();
        MBFB_STRAY_ADD(bus, mbfb_wire_len(bus->cfg.framing, rc));
        rc = left > 0 ? bus->be->recv(bus, req, rsp, (int)sizeof rsp, (int)left)
                      : -MBFB_E_TIMEOUT;
    }
    bus->quiet_from_us = mbfb_now_us();
    busy_add(bus, bus->quiet_from_us, bus->quiet_from_us - t0 + bus->timing.gap_us);
    if (rc == -MBFB_E_PORTLOST)
        return rc;
    err = rc < 0 ? -rc : mbfb_check_reply(req, rsp, rc);
    if (err == MBFB_OK) {
        MBFB_DIAG_INC(dev, good);
        MBFB_DIAG_SET(dev, last_rtt_us, (uint32_t)(bus->quiet_from_us - t0));
        if ((fc == 3 || fc == 4) && out != NULL)
            for (int i = 0; i < count; i++)
                out[i] = (uint16_t)(rsp[3 + 2 * i] << 8 | rsp[4 + 2 * i]);
        return MBFB_OK;
    }
    count_failure(dev, err);
    if (err >= MBFB_E_EXCEPTION_BASE)
        return err;
    bus->settle_us = bus->timeout_us; /* its reply may still come: let it pass before */
    bus->settle_slave = dev->slave;   /* another slave's request (wait_quiet)          */
    if (!bus->be->needs_resync) {
        bus->be->reconnect(bus);
        if (bus->fd < 0)
            return -MBFB_E_PORTLOST; /* TCP reconnect failed */
    }
    return err;
}

/* ---- resynchronisation ------------------------------------------------------------ */

/* Drop outstanding shapes older than MBFB_LATE_MAX_MS. */
static void expire_shapes(mbfb_dev_t *dev, int64_t now)
{
    int k = 0;
    for (int i = 0; i < dev->n_outstanding; i++)
        if (now - dev->outstanding[i].t_us < (int64_t)MBFB_LATE_MAX_MS * 1000)
            dev->outstanding[k++] = dev->outstanding[i];
    dev->n_outstanding = k;
}

/* The index of the outstanding reply shape of a read of `count` registers with fc, or -1. */
static int read_shape(const mbfb_dev_t *dev, int fc, int count)
{
    for (int i = 0; i < dev->n_outstanding; i++)
        if (dev->outstanding[i].fc == fc && dev->outstanding[i].bytes == 2 * count)
            return i;
    return -1;
}

/* A read of `count` registers with fc: is its reply shape outstanding? */
static int shape_taken(const mbfb_dev_t *dev, int fc, int count)
{
    return read_shape(dev, fc, count) >= 0;
}

/* Is the read (fc, addr, count) inside a range that read well on the device? */
static int known_readable(const mbfb_dev_t *dev, int fc, int addr, int count)
{
    for (int i = 0; i < dev->n_known; i++)
        if (dev->known[i].fc == fc && addr >= dev->known[i].addr &&
            addr + count <= dev->known[i].addr + dev->known[i].count)
            return 1;
    return 0;
}

/* After a failed attempt: out of step (serial lines); the attempt's reply shape becomes
 * outstanding: a read's (fc, byte count), a write's echo (fc, address, value / count).
 * Only reads are sent out of step, so a write's echo is never taken for an answer; its
 * shape is kept so that the echo, when it comes, is known for what it is and retired
 * (retire_heard) instead of failing the resync read in whose wait it arrives. */
static void out_of_step(mbfb_bus_t *bus, mbfb_dev_t *dev, int fc, int addr, int count,
                        const uint16_t *vals, int64_t t)
{
    mbfb_shape_t sh;
    if (!bus->be->needs_resync)
        return; /* TCP: the new connection is in step */
    dev->in_step = 0;
    memset(&sh, 0, sizeof sh);
    sh.fc = fc;
    sh.t_us = t;
    if (fc == 3 || fc == 4) {
        int readable = known_readable(dev, fc, addr, count);
        int same = read_shape(dev, fc, count);
        if (same >= 0) {
            dev->outstanding[same].readable &= readable; /* either may be answered */
            dev->outstanding[same].t_us = t;             /* a probe sent it again   */
            return;
        }
        sh.bytes = 2 * count;
        sh.addr = addr;
        sh.readable = readable;
    } else {
        sh.echo[0] = (uint16_t)addr;
        sh.echo[1] = fc == 6 ? vals[0] : (uint16_t)count;
        for (int i = 0; i < dev->n_outstanding; i++)
            if (dev->outstanding[i].fc == fc && dev->outstanding[i].echo[0] == sh.echo[0] &&
                dev->outstanding[i].echo[1] == sh.echo[1])
                return;
    }
    if (dev->n_outstanding < MBFB_OUTSTANDING_MAX)
        dev->outstanding[dev->n_outstanding++] = sh;
}

/* A good reply to a resync read: in step, nothing can be late any more (and no other
 * slave need wait for a late reply of it: the settle it owed is void). */
static void in_step(mbfb_bus_t *bus, mbfb_dev_t *dev)
{
    dev->in_step = 1;
    dev->n_outstanding = 0;
    if (bus->settle_slave == dev->slave)
        bus->settle_us = 0;
}

/* Late replies heard in the silence before a request (bus->heard): a whole, checked
 * reply of a device of this bus whose shape is outstanding retires that shape, since the
 * device gives one reply per request. Its next request then need not avoid that shape: a
 * read can be its own resync read (pick_resync). An exception retires an outstanding
 * shape of its function. The device stays out of step until a resync read is answered. */
static void hear_late_replies(mbfb_bus_t *bus)
{
    uint8_t f[MBFB_FRAME_MAX];
    int pos = 0, len;

    while ((len = mbfb_next_reply(bus->cfg.framing, bus->heard, bus->n_heard, &pos, f)) > 0)
        retire_heard(bus, f, len);
    bus->n_heard = 0;
}

/* Remember a range that read well (most recent first). */
static void remember_read(mbfb_dev_t *dev, int fc, int addr, int count)
{
    int i, n = dev->n_known;
    for (i = 0; i < n; i++)
        if (dev->known[i].fc == fc && dev->known[i].addr == addr &&
            dev->known[i].count == count)
            break;
    if (i == n && n < MBFB_KNOWN_READS)
        dev->n_known = ++n;
    if (i == n)
        i = n - 1;
    memmove(&dev->known[1], &dev->known[0], (size_t)i * sizeof dev->known[0]);
    dev->known[0].fc = fc;
    dev->known[0].addr = addr;
    dev->known[0].count = count;
}

/* Could an outstanding request still be answered with exception `code` (0: any) of fc? */
static int exception_outstanding(const mbfb_dev_t *dev, int fc, int code)
{
    for (int i = 0; i < dev->n_outstanding; i++)
        if (exception_fits_shape(&dev->outstanding[i], fc, code))
            return 1;
    return 0;
}

/* The shortest read of fc inside the readable window (addr, count) whose reply shape is
 * free, into *best if shorter than what it holds. */
static void shortest_free_in_window(const mbfb_dev_t *dev, int fc, int addr, int count,
                                    mbfb_range_t *best)
{
    for (int k = 1; k <= count && (best->count == 0 || k < best->count); k++)
        if (!shape_taken(dev, fc, k)) {
            best->fc = fc;
            best->addr = addr;
            best->count = k;
            return;
        }
}

/* The shortest read of fc from addr on, of any count, whose reply shape is free (not known
 * to be readable: the device may answer an exception), into *best if shorter. */
static void shortest_free_from(const mbfb_dev_t *dev, int fc, int addr, mbfb_range_t *best)
{
    for (int k = 1; k <= MBFB_MAX_READ && (best->count == 0 || k < best->count); k++)
        if (!shape_taken(dev, fc, k)) {
            best->fc = fc;
            best->addr = addr + k > MBFB_ADDR_SPACE ? MBFB_ADDR_SPACE - k : addr;
            best->count = k;
            return;
        }
}

/* Choose the resync read for a device, the first of:
 *  1. the request itself if a read, or the written range of a write of unknown outcome
 *     (`readback`), when its shape is free: its answer is the data or the read-back too;
 *  2. the shortest read inside a window known to be readable (the request's window, the
 *     written range, the device's plan items, ranges that read well) whose shape is free;
 *  3. a read with a function none of whose requests is outstanding (3 <-> 4): any answer,
 *     data or exception, can only be the answer to it (one register at the request's
 *     address: the shortest);
 *  4. the shortest read of any count from the request's address whose shape is free,
 *     first of a function whose outstanding reads all lie inside ranges that read well:
 *     a data reply proves it, and so does an exception no outstanding request can give
 *     (a read past the device's map answered "illegal data address" while the earlier
 *     attempts were reads inside it).
 * So a read is found while fewer than MBFB_OUTSTANDING_MAX shapes are outstanding: a
 * window's shapes running out never refuses a request. Returns 1 with *r, or 0 when the
 * outstanding set is full. */
static int pick_resync(mbfb_bus_t *bus, int devidx, int fc, int addr, int count,
                       int readback, mbfb_range_t *r)
{
    mbfb_dev_t *dev = mbfb_devs[devidx];
    int write = fc == 6 || fc == 16, n, read_fc = write ? 3 : fc, other_fc = 7 - read_fc;

    expire_shapes(dev, mbfb_now_us());
    if (dev->n_outstanding >= MBFB_OUTSTANDING_MAX)
        return 0;
    if ((readback || !write) && !shape_taken(dev, read_fc, count)) {
        r->fc = read_fc, r->addr = addr, r->count = count;
        return 1;
    }
    r->count = 0;
    shortest_free_in_window(dev, read_fc, addr, count, r);
    n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE);
    for (int i = 0; i < n; i++) {
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        mbfb_plan_item_t items[MBFB_PLAN_MAX_ITEMS];
        int ni, per, slow;
        uint32_t cs;
        if (p == NULL || p->dev != devidx)
            continue;
        mbfb_plan_read_cfg(p, items, &ni, &per, &slow, &cs);
        for (int k = 0; k < ni; k++)
            shortest_free_in_window(dev, items[k].fc, items[k].addr, items[k].count, r);
    }
    for (int i = 0; i < dev->n_known; i++)
        shortest_free_in_window(dev, dev->known[i].fc, dev->known[i].addr,
                                dev->known[i].count, r);
    if (r->count == 0 && !exception_outstanding(dev, other_fc, 0))
        shortest_free_from(dev, other_fc, addr, r); /* one register */
    /* any count: a function a fixed exception would prove first (one whose outstanding
     * reads are all inside ranges that read well: a read past the device's map then
     * proves the step by its exception), then either */
    for (int pass = 0; pass < 2 && r->count == 0; pass++)
        for (int k = 0; k < 2; k++) {
            int f = k == 0 ? read_fc : other_fc;
            if (pass == 1 || !exception_outstanding(dev, f, MBFB_EXC_FIXED_MAX))
                shortest_free_from(dev, f, addr, r);
        }
    return r->count > 0;
}

/* The probe of a device in back-off: the read of its newest outstanding read shape, so
 * the probes of a long outage use up no more shapes (a dead device would otherwise take
 * every shape its map allows, and once back it could find no read that proves the step).
 * Any answer shows the device is back; its data is not used: it may be an earlier
 * request's. Returns 1 with *r, or 0 when no read shape is outstanding. */
static int pick_probe(const mbfb_dev_t *dev, mbfb_range_t *r)
{
    const mbfb_shape_t *newest = NULL;
    for (int i = 0; i < dev->n_outstanding; i++) {
        const mbfb_shape_t *sh = &dev->outstanding[i];
        if ((sh->fc == 3 || sh->fc == 4) && (newest == NULL || sh->t_us > newest->t_us))
            newest = sh;
    }
    if (newest == NULL)
        return 0;
    r->fc = newest->fc;
    r->addr = newest->addr;
    r->count = newest->bytes / 2;
    return 1;
}

/* ---- one request with its retries, resyncs and read-backs ------------------------ */

typedef struct request {
    int devidx, fc, addr, count, policy;
    const uint16_t *vals;     /* writes */
    uint16_t *out;            /* reads: count registers */
    int budget;               /* failed attempts allowed                               */
    int probe;                /* the device is in back-off: its first attempt probes it */
    int answered;             /* out: a valid reply (or exception) came from the device */
    int sent;                 /* out: attempts put on the wire                         */
    int write_sent;           /* out: the write itself went on the wire (maybe applied) */
} request_t;

/* Count an attempt beyond the first of this request. */
static void next_attempt(mbfb_dev_t *dev, request_t *request)
{
    if (request->sent++ > 0)
        MBFB_DIAG_INC(dev, retries);
}

/* Run one request (see the file comment). Returns MBFB_OK, a positive MBFB_E_*, or
 * -MBFB_E_PORTLOST. MBFB_E_OFFLINE: no resync read was possible, nothing was sent. */
static int run_attempts(mbfb_bus_t *bus, request_t *request)
{
    mbfb_dev_t *dev = mbfb_devs[request->devidx];
    int write = request->fc == 6 || request->fc == 16;
    int failures = 0, err = MBFB_E_TIMEOUT, unknown = 0, rc;
    uint16_t resync_words[MBFB_MAX_READ];
    mbfb_range_t r;

    for (;;) {
        if (mbfb_stopping(bus)) /* shutting down: the attempt on the wire was the last */
            return request->write_sent ? MBFB_E_UNCONFIRMED : MBFB_E_CANCELLED;
        if (failures >= request->budget)
            return unknown ? MBFB_E_UNCONFIRMED : err;
        if (!dev->in_step) { /* only a resync read may go */
            int resync_is_readback, resync_is_request;
            /* listen first: a late reply heard now frees its shape for the choice */
            if (wait_quiet(bus, dev->slave) < 0)
                return -MBFB_E_PORTLOST;
            if (request->probe && pick_probe(dev, &r)) {
                request->probe = 0;
                next_attempt(dev, request);
                MBFB_DIAG_INC(dev, resyncs);
                rc = send_and_check(bus, dev, r.fc, r.addr, r.count, NULL, resync_words);
                if (rc == -MBFB_E_PORTLOST)
                    return rc;
                out_of_step(bus, dev, r.fc, r.addr, r.count, NULL, mbfb_now_us());
                failures++;
                if (rc == MBFB_OK || rc >= MBFB_E_EXCEPTION_BASE) {
                    /* back: out of back-off, and one resync read may follow */
                    request->answered = 1;
                    end_backoff(dev);
                    request->budget = failures + 1;
                } else {
                    err = rc;
                }
                continue;
            }
            if (!pick_resync(bus, request->devidx, request->fc, request->addr, request->count,
                             unknown, &r))
                return unknown ? MBFB_E_UNCONFIRMED : (request->sent ? err : MBFB_E_OFFLINE);
            resync_is_readback =
                unknown && r.fc == 3 && r.addr == request->addr && r.count == request->count;
            resync_is_request =
                !write && r.fc == request->fc && r.addr == request->addr &&
                r.count == request->count;
            next_attempt(dev, request);
            MBFB_DIAG_INC(dev, resyncs);
            rc = send_and_check(bus, dev, r.fc, r.addr, r.count, NULL, resync_words);
            if (rc == -MBFB_E_PORTLOST)
                return rc;
            /* an exception no earlier request of the device can still give is the answer */
            if (rc >= MBFB_E_EXCEPTION_BASE &&
                !exception_outstanding(dev, r.fc, rc - MBFB_E_EXCEPTION_BASE)) {
                request->answered = 1;
                in_step(bus, dev);
                if (resync_is_readback)
                    return MBFB_E_UNCONFIRMED; /* the read-back is refused */
                if (resync_is_request)
                    return rc; /* the request's own answer */
                continue;
            }
            if (rc != MBFB_OK) { /* this exception may be a late one: still out of step */
                request->answered |= rc >= MBFB_E_EXCEPTION_BASE;
                out_of_step(bus, dev, r.fc, r.addr, r.count, NULL, mbfb_now_us());
                failures++;
                /* an exception to a resync read of other registers is not the request's */
                if (rc < MBFB_E_EXCEPTION_BASE || resync_is_request || resync_is_readback)
                    err = rc;
                continue;
            }
            request->answered = 1;
            in_step(bus, dev);
            remember_read(dev, r.fc, r.addr, r.count);
            if (resync_is_request) { /* the resync read was the request: its answer */
                if (request->out != NULL)
                    memcpy(request->out, resync_words,
                           (size_t)request->count * sizeof request->out[0]);
                return MBFB_OK;
            }
            if (!resync_is_readback)
                continue;
        } else if (unknown) { /* in step: read the written registers back */
            next_attempt(dev, request);
            rc = send_and_check(bus, dev, 3, request->addr, request->count, NULL, resync_words);
            if (rc == -MBFB_E_PORTLOST)
                return rc;
            if (rc >= MBFB_E_EXCEPTION_BASE) {
                request->answered = 1;
                return MBFB_E_UNCONFIRMED; /* no read-back possible */
            }
            if (rc != MBFB_OK) {
                out_of_step(bus, dev, 3, request->addr, request->count, NULL, mbfb_now_us());
                failures++;
                err = rc;
                continue;
            }
            request->answered = 1;
        }
        if (unknown) { /* resync_words holds the read-back */
            if (memcmp(resync_words, request->vals,
                       (size_t)request->count * sizeof request->vals[0]) == 0)
                return MBFB_OK; /* applied (once) */
            if (request->policy == MBFB_WRITE_ONCE)
                return MBFB_E_UNCONFIRMED; /* not applied: never sent twice */
            unknown = 0;                   /* not applied: send it again */
            if (failures >= request->budget)
                return err;
        }
        next_attempt(dev, request);
        request->write_sent |= write;
        rc = send_and_check(bus, dev, request->fc, request->addr, request->count, request->vals,
                            request->out);
        if (rc == -MBFB_E_PORTLOST)
            return rc;
        if (rc == MBFB_OK || rc >= MBFB_E_EXCEPTION_BASE) {
            request->answered = 1;
            if (rc == MBFB_OK && !write && dev->slave != 0)
                remember_read(dev, request->fc, request->addr, request->count);
            return rc;
        }
        out_of_step(bus, dev, request->fc, request->addr, request->count, request->vals,
                    mbfb_now_us());
        failures++;
        err = rc;
        unknown = write && dev->slave != 0;
    }
}

/* ---- back-off ---------------------------------------------------------------------- */

/* Back-off bookkeeping after a request that put something on the wire: three failed
 * requests in a row start it; then one probe per interval (MBFB_PROBE_MIN_MS, or
 * MBFB_PROBE_SHARE of the request's response timeout if longer), the same however long
 * the device stays silent: it is found again within one interval of its return. */
static void update_backoff(mbfb_bus_t *bus, mbfb_dev_t *dev, int answered)
{
    int64_t interval = (int64_t)MBFB_PROBE_SHARE * bus->timeout_us;

    if (answered) {
        end_backoff(dev);
        return;
    }
    if (++dev->fails < MBFB_OFFLINE_AFTER)
        return;
    if (interval < (int64_t)MBFB_PROBE_MIN_MS * 1000)
        interval = (int64_t)MBFB_PROBE_MIN_MS * 1000;
    dev->probe_us = interval;
    dev->next_probe_us = mbfb_now_us() + dev->probe_us;
    MBFB_DIAG_SET(dev, offline, 1u);
}

/* Probes in one MBFB_LATE_MAX_MS, with the failed requests before back-off, must leave
 * reply shapes free: a dead device is probed, never refused for want of a shape. */
typedef char mbfb_probes_leave_shapes_free[
    MBFB_LATE_MAX_MS / MBFB_PROBE_MIN_MS + 1 + MBFB_DEFAULT_RETRIES + MBFB_OFFLINE_AFTER <=
            MBFB_OUTSTANDING_MAX ? 1 : -1]; /* C and C++ alike (no _Static_assert in C++11) */

/* Port lost: close it and end everything queued. The next request reopens it. */
static void port_lost(mbfb_bus_t *bus, mbfb_dev_t *dev)
{
    bus->be->close(bus);
    set_error(dev, MBFB_E_PORTLOST);
    mbfb_slot_fail_queued(bus, MBFB_E_PORTLOST);
}

/* The port could not be opened (`err`: MBFB_E_NOPORT, MBFB_E_BAUD for a rate the
 * driver cannot set, MBFB_E_DIRECTION for a direction mode it refuses): every running
 * plan of the bus ends its refresh now with `err` (one failed snapshot each, in this one
 * pass), and none is due again before bus->reopen_us, so the bus tries open() once per
 * probe interval whatever the number of plans. */
static void plans_no_port(mbfb_bus_t *bus, int64_t now, int err)
{
    int n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE);
    uint16_t words[MBFB_PLAN_MAX_WORDS];

    memset(words, 0, sizeof words);
    for (int i = 0; i < n; i++) {
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        mbfb_plan_item_t items[MBFB_PLAN_MAX_ITEMS];
        int ni, per, slow, nwords = 0;
        uint32_t cs;
        if (p == NULL || !mbfb_plan_read_cfg(p, items, &ni, &per, &slow, &cs))
            continue; /* not running */
        for (int k = 0; k < ni; k++)
            nwords += items[k].count;
        p->last_start_us = now;
        set_error(mbfb_devs[p->dev], err);
        mbfb_plan_publish(p, err, __atomic_load_n(&p->inval_gen, __ATOMIC_ACQUIRE),
                          0u, words, nwords);
    }
}

/* Run one request of a device: back-off, port, attempts. Returns its result. */
static int device_request(mbfb_bus_t *bus, request_t *request)
{
    mbfb_dev_t *dev = mbfb_devs[request->devidx];
    int offline = dev->probe_us > 0, rc;

    /* back-off: no bus time; but a late reply of the device waiting in the port is heard
     * first (the silence wait reads it), and retiring its shape ends the wait */
    if (offline && mbfb_now_us() < dev->next_probe_us && bus->fd >= 0 &&
        bus->be->needs_resync && mbfb_fd_wait_input(bus->fd, 0) == 1)
        (void)wait_quiet(bus, dev->slave); /* a lost port shows in the next attempt */
    offline = dev->probe_us > 0;
    if (offline && mbfb_now_us() < dev->next_probe_us) {
        set_error(dev, MBFB_E_OFFLINE);
        return MBFB_E_OFFLINE;
    }
    if (mbfb_stopping(bus))
        return MBFB_E_CANCELLED; /* shutting down: no port opened, nothing sent */
    if (bus->fd < 0 && (rc = bus->be->open(bus)) < 0) {
        /* plans try again only after a probe interval: no spinning on open() */
        int64_t now = mbfb_now_us();
        int err = rc == -MBFB_E_BAUD || rc == -MBFB_E_DIRECTION ? -rc : MBFB_E_NOPORT;
        bus->reopen_us = now + (int64_t)MBFB_PROBE_MIN_MS * 1000;
        set_error(dev, err);
        plans_no_port(bus, now, err); /* the caller's plan included: it publishes nothing */
        return err;
    }
    if (!bus->be->needs_resync)
        dev->in_step = 1;
    MBFB_DIAG_INC(dev, requests);
    /* One attempt (a probe) for a device in back-off, and for one still out of step
     * because its previous request ran out of attempts: each failed resync read uses
     * up a reply shape for MBFB_LATE_MAX_MS, which a dead device must not exhaust. */
    request->budget = offline || !dev->in_step ? 1 : 1 + bus->cfg.retries;
    request->probe = offline;
    request->answered = 0;
    request->sent = 0;
    request->write_sent = 0;
    rc = run_attempts(bus, request);
    if (rc == -MBFB_E_PORTLOST) {
        port_lost(bus, dev);
        /* a write that went out may have been applied before the port went: its outcome
         * is unknown, not failed (a read-back needs the port) */
        rc = request->write_sent ? MBFB_E_UNCONFIRMED : MBFB_E_PORTLOST;
        set_error(dev, rc);
        return rc;
    }
    if (request->sent > 0) {
        update_backoff(bus, dev, request->answered);
    } else if (rc == MBFB_E_OFFLINE) { /* outstanding set full: wait for the oldest */
        int64_t t = dev->n_outstanding > 0 ? dev->outstanding[0].t_us : mbfb_now_us();
        for (int i = 1; i < dev->n_outstanding; i++)
            t = dev->outstanding[i].t_us < t ? dev->outstanding[i].t_us : t;
        if (dev->probe_us <= 0)
            dev->probe_us = (int64_t)MBFB_PROBE_MIN_MS * 1000;
        dev->next_probe_us = t + (int64_t)MBFB_LATE_MAX_MS * 1000;
        MBFB_DIAG_SET(dev, offline, 1u);
    }
    set_error(dev, rc);
    return rc;
}

/* A posted request. */
static void run_slot(mbfb_bus_t *bus, mbfb_slot_t *s)
{
    request_t request;
    int rc;

    memset(&request, 0, sizeof request);
    request.devidx = s->dev;
    request.fc = s->fc;
    request.addr = s->addr;
    request.count = s->count;
    request.policy = s->policy;
    request.vals = s->values;
    request.out = s->values; /* reads: the slot's values are free for the result */
    rc = device_request(bus, &request);
    s->nvals = rc == MBFB_OK && (s->fc == 3 || s->fc == 4) ? s->count : 0;
    mbfb_slot_finish(s, rc);
}

/* Run every posted request; 1 if the worker must stop. */
static int run_posted(mbfb_bus_t *bus)
{
    mbfb_slot_t *s;
    while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE)) {
        if ((s = mbfb_slot_next(bus)) == NULL)
            return 0;
        run_slot(bus, s);
    }
    return 1;
}

/* ---- plans ------------------------------------------------------------------------- */

/* When a plan is due (monotonic us); INT64_MAX if it is not running. New settings:
 * now. A device in back-off is due at its next probe only; a port that could not be
 * opened, once the probe interval has passed (then the first plan due tries to open
 * it, and a failure fails all of them at once: plans_no_port). */
static int64_t plan_due(mbfb_bus_t *bus, mbfb_plan_t *p)
{
    mbfb_dev_t *dev = mbfb_devs[p->dev];
    int64_t due;
    if (!__atomic_load_n(&p->running, __ATOMIC_ACQUIRE))
        return INT64_MAX;
    if (p->last_start_us == 0 || __atomic_load_n(&p->cfg_seq, __ATOMIC_ACQUIRE) != p->cfg_seen)
        due = 0;
    else
        due = p->last_start_us +
              (int64_t)__atomic_load_n(&p->period_ms, __ATOMIC_RELAXED) * 1000;
    if (p->failed && dev->heard)
        due = 0; /* its device was heard: it can answer again now */
    if (dev->probe_us > 0 && dev->next_probe_us > due)
        due = dev->next_probe_us;
    if (bus->fd < 0 && bus->reopen_us > due)
        due = bus->reopen_us;
    return due;
}

/* One refresh of a plan: its items of this refresh's tiers back to back (posted
 * requests before each), published as one snapshot. */
static void run_refresh(mbfb_bus_t *bus, mbfb_plan_t *p)
{
    mbfb_plan_item_t items[MBFB_PLAN_MAX_ITEMS];
    uint16_t words[MBFB_PLAN_MAX_WORDS];
    mbfb_dev_t *dev = mbfb_devs[p->dev];
    int n, period, slow_ms, slow, owed, nwords = 0, result = MBFB_OK;
    uint32_t cfg, gen, mask = 0;
    int64_t start = mbfb_now_us();

    if (!mbfb_plan_read_cfg(p, items, &n, &period, &slow_ms, &cfg)) {
        p->last_start_us = start;
        return;
    }
    if (cfg != p->cfg_seen) { /* new settings: the slow tier again */
        p->cfg_seen = cfg;
        p->slow_done = 0;
    }
    gen = __atomic_load_n(&p->inval_gen, __ATOMIC_ACQUIRE);
    /* The first slow read and one made for an invalidation are owed to the scan: until a
     * take reaches that snapshot (refreshes may outpace scans), every refresh reads the
     * slow tier again, so whichever snapshot a take copies holds it. */
    owed = !p->slow_done || gen != p->slow_gen; /* a new debt */
    slow = owed || start >= p->next_slow_us ||
           (p->slow_owed != 0 && /* an old one: no take has reached it yet */
            (int32_t)(__atomic_load_n(&p->taken, __ATOMIC_ACQUIRE) - p->slow_owed) < 0);
    p->last_start_us = start;
    dev->heard = 0;
    memset(words, 0, sizeof words);
    for (int i = 0; i < n; i++) {
        request_t request;
        int rc;
        if ((items[i].tier == MBFB_TIER_SLOW && !slow) ||
            (items[i].tier == MBFB_TIER_FAST && slow)) {
            nwords += items[i].count;
            continue;
        }
        if (run_posted(bus))
            return;
        if (bus->fd < 0 && bus->reopen_us > start)
            return; /* a posted request could not open the port: plans_no_port ran */
        memset(&request, 0, sizeof request);
        request.devidx = p->dev;
        request.fc = items[i].fc;
        request.addr = items[i].addr;
        request.count = items[i].count;
        request.out = words + nwords;
        rc = device_request(bus, &request);
        if (rc == MBFB_E_NOPORT || rc == MBFB_E_BAUD || rc == MBFB_E_DIRECTION)
            return; /* the port did not open: published with every plan (plans_no_port) */
        if (rc != MBFB_OK) {
            result = rc;
            break;
        }
        mask |= 1u << i;
        nwords += items[i].count;
    }
    p->failed = result != MBFB_OK;
    if (result != MBFB_OK) {
        memset(words, 0, sizeof words);
        mask = 0;
    } else {
        if (slow) {
            p->slow_done = 1;
            p->slow_gen = gen;
            p->next_slow_us = start + (int64_t)slow_ms * 1000;
        }
        MBFB_DIAG_INC(dev, refreshes);
        if (dev->last_refresh_us != 0)
            MBFB_DIAG_SET(dev, refresh_us, (uint32_t)(start - dev->last_refresh_us));
        dev->last_refresh_us = start;
    }
    nwords = 0;
    for (int i = 0; i < n; i++)
        nwords += items[i].count;
    mbfb_plan_publish(p, result, gen, mask, words, nwords);
    if (result == MBFB_OK && owed)
        p->slow_owed = p->seq; /* the first snapshot of the debt: every later one holds
                                  the slow tier too until a take reaches it */
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

/* Sleep until `until` (monotonic us; INT64_MAX: no limit) or a sem_post. */
static void sleep_until(mbfb_bus_t *bus, int64_t until)
{
    if (until == INT64_MAX) {
        while (sem_wait(&bus->wake) != 0 && errno == EINTR) {
        }
        return;
    }
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 30))
    {
        struct timespec ts;
        ts.tv_sec = (time_t)(until / 1000000);
        ts.tv_nsec = (long)(until % 1000000) * 1000;
        while (sem_clockwait(&bus->wake, CLOCK_MONOTONIC, &ts) != 0 && errno == EINTR) {
        }
    }
#else /* sem_timedwait counts on CLOCK_REALTIME: convert the delay */
    {
        struct timespec ts;
        int64_t d = until - mbfb_now_us(), r;
        clock_gettime(CLOCK_REALTIME, &ts);
        r = (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000 + (d > 0 ? d : 0);
        ts.tv_sec = (time_t)(r / 1000000);
        ts.tv_nsec = (long)(r % 1000000) * 1000;
        while (sem_timedwait(&bus->wake, &ts) != 0 && errno == EINTR) {
        }
    }
#endif
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
    for (;;) {
        int64_t now = mbfb_now_us(), slice = until - now;
        if (slice <= 0 || sem_trywait(&bus->wake) == 0)
            return;
        if (slice > MBFB_LISTEN_SLICE_US)
            slice = MBFB_LISTEN_SLICE_US;
        if (mbfb_fd_wait_input(bus->fd, slice) == 1) {
            (void)wait_quiet(bus, bus->settle_slave); /* a lost port shows in the next attempt */
            return;
        }
    }
}

/* The worker loop: posted requests, the plan due, else sleep (file comment). */
void *mbfb_worker_main(void *arg)
{
    mbfb_bus_t *bus = (mbfb_bus_t *)arg;

    while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE)) {
        mbfb_plan_t *p;
        int64_t wake_at, now, empty_at;
        while (sem_trywait(&bus->wake) == 0) { /* the checks below see every post */
        }
        if (run_posted(bus))
            break;
        now = mbfb_now_us();
        p = next_plan(bus, now, &wake_at);
        if (p != NULL) {
            run_refresh(bus, p);
            continue;
        }
        /* idle: busy_permille as of now, and one wake when the window empties */
        empty_at = busy_update(bus, now);
        if (empty_at < wake_at)
            wake_at = empty_at;
        if (bus_out_of_step(bus))
            listen_until(bus, wake_at);
        else
            sleep_until(bus, wake_at);
    }
    if (bus->fd >= 0)
        bus->be->close(bus);
    return NULL;
}
