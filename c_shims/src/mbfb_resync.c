/*
 * mbfb_resync.c - the rules of late replies and resync reads (README "Late replies").
 *
 * RTU has no transaction id. After a failed attempt the device is out of step and the
 * reply shape of that attempt is outstanding (mbfb_out_of_step). While out of step only
 * resync reads go to the device: a read whose reply shape differs from every outstanding
 * one (mbfb_pick_resync). A good reply to it brings the device back in step (it serves
 * requests in order: nothing older can follow) and clears the outstanding set
 * (mbfb_in_step). A late reply heard in the silence before a request, or in a resync
 * read's wait, retires its shape (mbfb_retire_heard), and a read whose shape is free is
 * its own resync read: its answer is the request's. A device in back-off is probed with
 * the read of its newest outstanding shape (mbfb_pick_probe).
 * Everything here is the worker's (dev->outstanding, dev->known are worker only).
 */
#include <string.h>

#include "mbfb_internal.h"

/* ---- outstanding reply shapes ------------------------------------------------------ */

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
    if (sh->fc != (f[1] & ~MBFB_EXCEPTION_BIT))
        return 0;
    if (f[1] & MBFB_EXCEPTION_BIT)
        return len >= 3 && exception_fits_shape(sh, sh->fc, f[2]);
    if (mbfb_fc_is_read(sh->fc))
        return len >= 3 && sh->bytes == f[2];
    return len >= 6 && sh->echo[0] == (uint16_t)(f[2] << 8 | f[3]) &&
           sh->echo[1] == (uint16_t)(f[4] << 8 | f[5]);
}

/* A whole, checked reply frame f (slave + PDU) heard outside its request: when a device of
 * this bus has its shape outstanding, retire that shape (the device gives one reply per
 * request, so that one can no longer come) and return 1; else 0. A device heard answering
 * is busy or slow, not gone: its back-off ends (its failures count from 0 again). */
int mbfb_retire_heard(mbfb_bus_t *bus, const uint8_t *f, int len)
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
        if (fits == 0 || (fits > 1 && (f[1] & MBFB_EXCEPTION_BIT)))
            return 0;
        for (i = 0; i < dev->n_outstanding; i++)
            if (reply_fits_shape(&dev->outstanding[i], f, len))
                break;
        memmove(&dev->outstanding[i], &dev->outstanding[i + 1],
                (size_t)(dev->n_outstanding - i - 1) * sizeof dev->outstanding[0]);
        dev->n_outstanding--;
        dev->heard = 1;
        if (dev->fails > 0)
            mbfb_end_backoff(dev);
        return 1;
    }
    return 0;
}

/* Drop outstanding shapes older than MBFB_LATE_MAX_MS. */
static void expire_shapes(mbfb_dev_t *dev, int64_t now)
{
    int k = 0;
    for (int i = 0; i < dev->n_outstanding; i++)
        if (now - dev->outstanding[i].t_us < (int64_t)MBFB_LATE_MAX_MS * 1000)
            dev->outstanding[k++] = dev->outstanding[i];
    dev->n_outstanding = k;
}

/* The index of the outstanding reply shape of a read of `count` registers (bits) with fc,
 * or -1. */
static int read_shape(const mbfb_dev_t *dev, int fc, int count)
{
    for (int i = 0; i < dev->n_outstanding; i++)
        if (dev->outstanding[i].fc == fc &&
            dev->outstanding[i].bytes == mbfb_read_bytes(fc, count))
            return i;
    return -1;
}

/* A read of `count` registers (bits) with fc: is its reply shape outstanding? */
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
 * (mbfb_retire_heard) instead of failing the resync read in whose wait it arrives. */
void mbfb_out_of_step(mbfb_bus_t *bus, mbfb_dev_t *dev, int fc, int addr, int count,
                      const uint16_t *vals, int64_t t)
{
    mbfb_shape_t sh;
    if (!bus->be->needs_resync)
        return; /* TCP: the new connection is in step */
    dev->in_step = 0;
    memset(&sh, 0, sizeof sh);
    sh.fc = fc;
    sh.t_us = t;
    if (mbfb_fc_is_read(fc)) {
        int readable = known_readable(dev, fc, addr, count);
        int same = read_shape(dev, fc, count);
        if (same >= 0) {
            dev->outstanding[same].readable &= readable; /* either may be answered */
            dev->outstanding[same].t_us = t;             /* a probe sent it again   */
            return;
        }
        sh.bytes = mbfb_read_bytes(fc, count);
        sh.addr = addr;
        sh.count = count;
        sh.readable = readable;
    } else {
        uint8_t req[MBFB_FRAME_MAX]; /* the echo is the request's words 2..5 */
        mbfb_build_request(req, dev->slave, fc, addr, count, vals);
        sh.echo[0] = (uint16_t)(req[2] << 8 | req[3]);
        sh.echo[1] = (uint16_t)(req[4] << 8 | req[5]);
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
void mbfb_in_step(mbfb_bus_t *bus, mbfb_dev_t *dev)
{
    dev->in_step = 1;
    dev->n_outstanding = 0;
    if (bus->settle_slave == dev->slave)
        bus->settle_us = 0;
}

/* Late replies heard in the silence before a request (bus->heard): a whole, checked
 * reply of a device of this bus whose shape is outstanding retires that shape, since the
 * device gives one reply per request. Its next request then need not avoid that shape: a
 * read can be its own resync read (mbfb_pick_resync). An exception retires an outstanding
 * shape of its function. The device stays out of step until a resync read is answered. */
void mbfb_hear_late_replies(mbfb_bus_t *bus)
{
    uint8_t f[MBFB_FRAME_MAX];
    int pos = 0, len;

    while ((len = mbfb_next_reply(bus->cfg.framing, bus->heard, bus->n_heard, &pos, f)) > 0)
        mbfb_retire_heard(bus, f, len);
    bus->n_heard = 0;
}


/* Remember a range that read well (most recent first). */
void mbfb_remember_read(mbfb_dev_t *dev, int fc, int addr, int count)
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
int mbfb_exception_outstanding(const mbfb_dev_t *dev, int fc, int code)
{
    for (int i = 0; i < dev->n_outstanding; i++)
        if (exception_fits_shape(&dev->outstanding[i], fc, code))
            return 1;
    return 0;
}

/* ---- choosing a resync read or a probe --------------------------------------------- */

/* The next count to try after k for fc: the least count whose reply is one byte longer
 * (registers: k + 1; bits: the next multiple of 8, plus 1). */
static int next_count(int fc, int k)
{
    return mbfb_fc_is_bits(fc) ? k + 8 : k + 1;
}

/* Is a read of k items with fc shorter on the wire than *best (none yet: yes)? */
static int shorter(int fc, int k, const mbfb_range_t *best)
{
    return best->count == 0 ||
           mbfb_read_bytes(fc, k) < mbfb_read_bytes(best->fc, best->count);
}

/* The shortest read of fc inside the readable window (addr, count) whose reply shape is
 * free, into *best if shorter than what it holds. */
static void shortest_free_in_window(const mbfb_dev_t *dev, int fc, int addr, int count,
                                    mbfb_range_t *best)
{
    for (int k = 1; k <= count && shorter(fc, k, best); k = next_count(fc, k))
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
    for (int k = 1; k <= mbfb_read_max(fc) && shorter(fc, k, best); k = next_count(fc, k))
        if (!shape_taken(dev, fc, k)) {
            best->fc = fc;
            best->addr = addr + k > MBFB_ADDR_SPACE ? MBFB_ADDR_SPACE - k : addr;
            best->count = k;
            return;
        }
}

/* The shortest read with a free shape inside a window known to be readable, into *r:
 * the request's own window (read_fc, addr, count), the device's plan items, the ranges
 * that read well. */
static void shortest_free_in_windows(mbfb_bus_t *bus, int devidx, int read_fc, int addr,
                                     int count, mbfb_range_t *r)
{
    mbfb_dev_t *dev = mbfb_devs[devidx];
    int n = __atomic_load_n(&bus->n_plans, __ATOMIC_ACQUIRE);

    shortest_free_in_window(dev, read_fc, addr, count, r);
    for (int i = 0; i < n; i++) {
        mbfb_plan_t *p = __atomic_load_n(&bus->plans[i], __ATOMIC_ACQUIRE);
        mbfb_plan_cfg_t cfg;
        if (p == NULL || p->dev != devidx)
            continue;
        mbfb_plan_read_cfg(p, &cfg);
        for (int k = 0; k < cfg.n; k++)
            shortest_free_in_window(dev, cfg.items[k].fc, cfg.items[k].addr,
                                    cfg.items[k].count, r);
    }
    for (int i = 0; i < dev->n_known; i++)
        shortest_free_in_window(dev, dev->known[i].fc, dev->known[i].addr,
                                dev->known[i].count, r);
}

/* Choose the resync read for a device, the first of:
 *  1. the request itself if a read, or the written range of a write of unknown outcome
 *     (`readback`), when its shape is free: its answer is the data or the read-back too;
 *  2. the shortest read inside a window known to be readable (the request's window, the
 *     written range, the device's plan items, ranges that read well) whose shape is free;
 *  3. a read with the other read function, none of whose requests is outstanding: any answer,
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
int mbfb_pick_resync(mbfb_bus_t *bus, int devidx, int fc, int addr, int count,
                     int readback, mbfb_range_t *r)
{
    mbfb_dev_t *dev = mbfb_devs[devidx];
    int read_fc = mbfb_fc_is_write(fc) ? mbfb_fc_readback(fc) : fc;
    int other_fc = mbfb_fc_other_read(read_fc);

    expire_shapes(dev, mbfb_now_us());
    if (dev->n_outstanding >= MBFB_OUTSTANDING_MAX)
        return 0;
    if ((readback || !mbfb_fc_is_write(fc)) && !shape_taken(dev, read_fc, count)) {
        r->fc = read_fc, r->addr = addr, r->count = count; /* 1. */
        return 1;
    }
    r->count = 0;
    shortest_free_in_windows(bus, devidx, read_fc, addr, count, r); /* 2. */
    if (r->count == 0 && !mbfb_exception_outstanding(dev, other_fc, 0))
        shortest_free_from(dev, other_fc, addr, r); /* 3. one register */
    /* 4. any count: a function a fixed exception would prove first (one whose outstanding
     * reads are all inside ranges that read well: a read past the device's map then
     * proves the step by its exception), then either */
    for (int pass = 0; pass < 2 && r->count == 0; pass++)
        for (int k = 0; k < 2; k++) {
            int f = k == 0 ? read_fc : other_fc;
            if (pass == 1 || !mbfb_exception_outstanding(dev, f, MBFB_EXC_FIXED_MAX))
                shortest_free_from(dev, f, addr, r);
        }
    return r->count > 0;
}

/* The probe of a device in back-off: the read of its newest outstanding read shape, so
 * the probes of a long outage use up no more shapes (a dead device would otherwise take
 * every shape its map allows, and once back it could find no read that proves the step).
 * Any answer shows the device is back; its data is not used: it may be an earlier
 * request's. Returns 1 with *r, or 0 when no read shape is outstanding. */
int mbfb_pick_probe(const mbfb_dev_t *dev, mbfb_range_t *r)
{
    const mbfb_shape_t *newest = NULL;
    for (int i = 0; i < dev->n_outstanding; i++) {
        const mbfb_shape_t *sh = &dev->outstanding[i];
        if (mbfb_fc_is_read(sh->fc) && (newest == NULL || sh->t_us > newest->t_us))
            newest = sh;
    }
    if (newest == NULL)
        return 0;
    r->fc = newest->fc;
    r->addr = newest->addr;
    r->count = newest->count;
    return 1;
}

