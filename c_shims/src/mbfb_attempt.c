/*
 * mbfb_attempt.c - one request of a device, as the worker runs it: back-off, the port,
 * and its attempts, each attempt one step of its own.
 *
 * One request (a posted one or a plan read) = up to 1 + retries failed attempts:
 *   wait until the line is silent (the gap; a whole response timeout, the settle, after a
 *   failed attempt to another slave), send, receive, validate (send_and_check).
 * An attempt is one of four steps, chosen by the device's state and the request's:
 *   probe      the device is in back-off: the read of its newest outstanding shape;
 *   resync     the device is out of step: a read no late reply can answer
 *              (mbfb_resync.c); its answer brings it back in step;
 *   read-back  a write of unknown outcome, in step: FC03 of the written registers (FC01
 *              of the written coils);
 *   send       in step: the request itself.
 * Confirmed writes (README "Confirmed writes"): an echo while in step is DONE; an
 * exception is a definite "not applied"; any other failure leaves the outcome unknown
 * until a read-back (FC03 of the written registers, FC01 of the written coils, in step)
 * shows it: equal -> DONE;
 * differs -> MBFB_WRITE_IDEMPOTENT sends it again, MBFB_WRITE_ONCE ends UNCONFIRMED.
 * Back-off: three failed requests in a row start it; then one probe per interval.
 */
#include <limits.h>
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
int64_t mbfb_busy_update(mbfb_bus_t *bus, int64_t now)
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
    mbfb_busy_update(bus, now);
}

/* The device answered (or was heard): out of back-off, its failures count from 0 again. */
void mbfb_end_backoff(mbfb_dev_t *dev)
{
    dev->fails = 0;
    dev->probe_us = 0;
    MBFB_DIAG_SET(dev, offline, 0u);
}

/* Wait for a silent line before an attempt to `slave`: the gap, or, after a failed attempt
 * to another slave, the settle (a response timeout of silence: that slave's late reply
 * would fail this slave's request). The failed slave's own resync read owes no settle: its
 * reply shape differs from every outstanding one, and a late reply that comes in its wait
 * is retired there (send_and_check). A late reply heard meanwhile retires its outstanding
 * shape. 0 or -PORTLOST. */
int mbfb_wait_quiet(mbfb_bus_t *bus, int slave)
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
        mbfb_hear_late_replies(bus);
    return 0;
}

/* ---- one attempt on the wire ----------------------------------------------------- */

/* Receive the reply to request frame req into rsp: its length, or -MBFB_E_*. A late reply
 * of an outstanding shape that comes first (a resync read's shape differs from every
 * outstanding one; another slave's reply never passes the check) is retired and the wait
 * goes on for this request's own answer, which the device sends after it. */
static int receive(mbfb_bus_t *bus, const uint8_t *req, uint8_t *rsp)
{
    int64_t deadline = mbfb_now_us() + bus->timeout_us;
    int rc = bus->be->recv(bus, req, rsp, MBFB_FRAME_MAX, bus->timeout_us);

    while (rc > 0 && bus->be->needs_resync &&
           mbfb_check_reply(req, rsp, rc) == MBFB_E_BADREPLY &&
           mbfb_retire_heard(bus, rsp, rc)) {
        int64_t left = deadline - mbfb_now_us();
        MBFB_STRAY_ADD(bus, mbfb_wire_len(bus->cfg.framing, rc));
        rc = left > 0 ? bus->be->recv(bus, req, rsp, MBFB_FRAME_MAX, (int)left)
                      : -MBFB_E_TIMEOUT;
    }
    return rc;
}

/* Judge what receive() gave (rc) for request frame req sent at t0: MBFB_OK with the
 * values of a read in out, a positive MBFB_E_* (failure or 128 + exception), or
 * -MBFB_E_PORTLOST. A failure owes the line a settle before an attempt to another slave
 * (mbfb_wait_quiet) and, on TCP, reconnects. */
static int judge_reply(mbfb_bus_t *bus, mbfb_dev_t *dev, const uint8_t *req,
                       const uint8_t *rsp, int rc, int64_t t0, uint16_t *out)
{
    int err = rc < 0 ? -rc : mbfb_check_reply(req, rsp, rc);

    if (rc == -MBFB_E_PORTLOST)
        return rc;
    if (err == MBFB_OK) {
        MBFB_DIAG_INC(dev, good);
        MBFB_DIAG_SET(dev, last_rtt_us, (uint32_t)(bus->quiet_from_us - t0));
        if (mbfb_fc_is_bits(req[1]) && mbfb_fc_is_read(req[1]) && out != NULL)
            mbfb_bytes_to_bits(rsp + 3, req[4] << 8 | req[5], out); /* packed, LSB first */
        else if (mbfb_fc_is_read(req[1]) && out != NULL)
            for (int i = 0; i < rsp[2] / 2; i++)
                out[i] = (uint16_t)(rsp[3 + 2 * i] << 8 | rsp[4 + 2 * i]);
        return MBFB_OK;
    }
    count_failure(dev, err);
    if (err >= MBFB_E_EXCEPTION_BASE)
        return err;
    bus->settle_us = bus->timeout_us; /* its reply may still come: let it pass before */
    bus->settle_slave = dev->slave;   /* another slave's request (mbfb_wait_quiet)     */
    if (!bus->be->needs_resync) {
        bus->be->reconnect(bus);
        if (bus->fd < 0)
            return -MBFB_E_PORTLOST; /* TCP reconnect failed */
    }
    return err;
}

/* One exchange on the wire: a read (values read into out) or a write (vals written).
 * Returns MBFB_OK, a positive MBFB_E_* (failure or 128 + exception), or
 * -MBFB_E_PORTLOST. */
static int send_and_check(mbfb_bus_t *bus, mbfb_dev_t *dev, int fc, int addr, int count,
                          const uint16_t *vals, uint16_t *out)
{
    uint8_t req[MBFB_FRAME_MAX], rsp[MBFB_FRAME_MAX];
    int len = mbfb_build_request(req, dev->slave, fc, addr, count, vals), rc;
    int64_t t0;

    bus->timeout_us = bus->cfg.response_timeout_ms > 0
                          ? bus->cfg.response_timeout_ms * 1000
                          : mbfb_response_timeout_us(&bus->timing, bus->cfg.framing, len,
                                                     mbfb_reply_len(req));
    if (mbfb_wait_quiet(bus, dev->slave) < 0)
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
    rc = receive(bus, req, rsp);
    bus->quiet_from_us = mbfb_now_us();
    busy_add(bus, bus->quiet_from_us, bus->quiet_from_us - t0 + bus->timing.gap_us);
    return judge_reply(bus, dev, req, rsp, rc, t0, out);
}

/* ---- the steps of a request ------------------------------------------------------- */

/* A request's attempts and what they have shown so far (worker only). */
typedef struct attempts {
    mbfb_request_t *req;
    mbfb_dev_t *dev;
    int budget;               /* failed attempts allowed                               */
    int failures;             /* failed attempts so far                                */
    int err;                  /* the failure reported when the budget runs out          */
    int unknown;              /* the write went out without a valid echo: applied or not
                                 is unknown until a read-back shows it                  */
    int probe;                /* the device is in back-off: its first attempt probes it */
    int answered;             /* a valid reply (or exception) came from the device      */
    int sent;                 /* attempts put on the wire                              */
    uint16_t words[MBFB_MAX_READ]; /* what a probe, resync read or read-back read        */
} attempts_t;

/* A step's result when the request goes on with its next attempt. */
#define STEP_AGAIN INT_MIN

/* Put one attempt on the wire (a retry when it is not the request's first). */
static int attempt(mbfb_bus_t *bus, attempts_t *a, int fc, int addr, int count,
                   const uint16_t *vals, uint16_t *out)
{
    if (a->sent++ > 0)
        MBFB_DIAG_INC(a->dev, retries);
    return send_and_check(bus, a->dev, fc, addr, count, vals, out);
}

/* An attempt failed: its reply shape is outstanding, one failure more. */
static void attempt_failed(mbfb_bus_t *bus, attempts_t *a, int fc, int addr, int count,
                           const uint16_t *vals)
{
    mbfb_out_of_step(bus, a->dev, fc, addr, count, vals, mbfb_now_us());
    a->failures++;
}

/* The read-back of a write of unknown outcome is in a->words: equal -> applied (once);
 * else MBFB_WRITE_ONCE ends unconfirmed and MBFB_WRITE_IDEMPOTENT sends it again. */
static int judge_readback(attempts_t *a)
{
    if (mbfb_readback_shows(a->req->fc, a->req->count, a->req->vals, a->words))
        return MBFB_OK;
    if (a->req->policy == MBFB_WRITE_ONCE)
        return MBFB_E_UNCONFIRMED; /* not applied: never sent twice */
    a->unknown = 0;                /* not applied: send it again */
    return STEP_AGAIN;
}

/* Probe step: the device in back-off is probed with the read r of its newest outstanding
 * shape, which stays outstanding (the answer may be an earlier request's). Any answer
 * ends the back-off, and one resync read may follow. */
static int probe_step(mbfb_bus_t *bus, attempts_t *a, const mbfb_range_t *r)
{
    int rc;

    a->probe = 0;
    MBFB_DIAG_INC(a->dev, resyncs);
    rc = attempt(bus, a, r->fc, r->addr, r->count, NULL, a->words);
    if (rc == -MBFB_E_PORTLOST)
        return rc;
    attempt_failed(bus, a, r->fc, r->addr, r->count, NULL);
    if (rc == MBFB_OK || rc >= MBFB_E_EXCEPTION_BASE) {
        a->answered = 1;
        mbfb_end_backoff(a->dev);
        a->budget = a->failures + 1;
    } else {
        a->err = rc;
    }
    return STEP_AGAIN;
}

/* Resync step: the device is out of step; a read no late reply can answer goes
 * (mbfb_pick_resync). It may be the request itself (its answer is the request's) or the
 * read-back of a write of unknown outcome. */
static int resync_step(mbfb_bus_t *bus, attempts_t *a)
{
    mbfb_request_t *q = a->req;
    int rc, is_readback, is_request, exc;
    mbfb_range_t r;

    if (!mbfb_pick_resync(bus, q->devidx, q->fc, q->addr, q->count, a->unknown, &r))
        return a->unknown ? MBFB_E_UNCONFIRMED : (a->sent ? a->err : MBFB_E_OFFLINE);
    is_readback = a->unknown && r.fc == mbfb_fc_readback(q->fc) && r.addr == q->addr &&
                  r.count == q->count;
    is_request = !mbfb_fc_is_write(q->fc) && r.fc == q->fc && r.addr == q->addr &&
                 r.count == q->count;
    MBFB_DIAG_INC(a->dev, resyncs);
    rc = attempt(bus, a, r.fc, r.addr, r.count, NULL, a->words);
    if (rc == -MBFB_E_PORTLOST)
        return rc;
    exc = rc >= MBFB_E_EXCEPTION_BASE;
    /* an exception no earlier request of the device can still give is the answer */
    if (exc && !mbfb_exception_outstanding(a->dev, r.fc, rc - MBFB_E_EXCEPTION_BASE)) {
        a->answered = 1;
        mbfb_in_step(bus, a->dev);
        if (is_readback)
            return MBFB_E_UNCONFIRMED; /* the read-back is refused */
        return is_request ? rc : STEP_AGAIN; /* the request's own answer, or the next */
    }
    if (rc != MBFB_OK) { /* this exception may be a late one: still out of step */
        a->answered |= exc;
        attempt_failed(bus, a, r.fc, r.addr, r.count, NULL);
        /* an exception to a resync read of other registers is not the request's */
        if (!exc || is_request || is_readback)
            a->err = rc;
        return STEP_AGAIN;
    }
    a->answered = 1;
    mbfb_in_step(bus, a->dev);
    mbfb_remember_read(a->dev, r.fc, r.addr, r.count);
    if (is_request && q->out != NULL)
        memcpy(q->out, a->words, (size_t)mbfb_data_words(q->fc, q->count) * sizeof q->out[0]);
    if (is_request)
        return MBFB_OK;
    return is_readback ? judge_readback(a) : STEP_AGAIN;
}

/* Read-back step: in step again after a write of unknown outcome, FC03 of the written
 * registers (FC01 of the written coils) shows whether it was applied. */
static int readback_step(mbfb_bus_t *bus, attempts_t *a)
{
    mbfb_request_t *q = a->req;
    int fc = mbfb_fc_readback(q->fc);
    int rc = attempt(bus, a, fc, q->addr, q->count, NULL, a->words);

    if (rc == -MBFB_E_PORTLOST)
        return rc;
    if (rc >= MBFB_E_EXCEPTION_BASE) {
        a->answered = 1;
        return MBFB_E_UNCONFIRMED; /* no read-back possible */
    }
    if (rc != MBFB_OK) {
        attempt_failed(bus, a, fc, q->addr, q->count, NULL);
        a->err = rc;
        return STEP_AGAIN;
    }
    a->answered = 1;
    return judge_readback(a);
}

/* Send step: in step, the request itself. A write that fails without an exception leaves
 * its outcome unknown (a broadcast's is never known: it has no reply). */
static int send_step(mbfb_bus_t *bus, attempts_t *a)
{
    mbfb_request_t *q = a->req;
    int write = mbfb_fc_is_write(q->fc), rc;

    q->write_sent |= write;
    rc = attempt(bus, a, q->fc, q->addr, q->count, q->vals, q->out);
    if (rc == -MBFB_E_PORTLOST)
        return rc;
    if (rc == MBFB_OK || rc >= MBFB_E_EXCEPTION_BASE) {
        a->answered = 1;
        if (rc == MBFB_OK && !write && a->dev->slave != 0)
            mbfb_remember_read(a->dev, q->fc, q->addr, q->count);
        return rc;
    }
    attempt_failed(bus, a, q->fc, q->addr, q->count, q->vals);
    a->err = rc;
    a->unknown = write && a->dev->slave != 0;
    return STEP_AGAIN;
}

/* Run a request's attempts, one step each, until one ends it or the budget runs out.
 * Returns MBFB_OK, a positive MBFB_E_*, or -MBFB_E_PORTLOST. MBFB_E_OFFLINE: no resync
 * read was possible, nothing was sent. */
static int run_attempts(mbfb_bus_t *bus, attempts_t *a)
{
    int rc = STEP_AGAIN;

    while (rc == STEP_AGAIN) {
        mbfb_range_t r;
        if (mbfb_stopping(bus)) /* shutting down: the attempt on the wire was the last */
            return a->req->write_sent ? MBFB_E_UNCONFIRMED : MBFB_E_CANCELLED;
        if (a->failures >= a->budget)
            return a->unknown ? MBFB_E_UNCONFIRMED : a->err;
        if (a->dev->in_step) {
            rc = a->unknown ? readback_step(bus, a) : send_step(bus, a);
            continue;
        }
        /* only a probe or a resync read may go; listen first: a late reply heard now
         * frees its shape for the choice */
        if (mbfb_wait_quiet(bus, a->dev->slave) < 0)
            return -MBFB_E_PORTLOST;
        rc = a->probe && mbfb_pick_probe(a->dev, &r) ? probe_step(bus, a, &r)
                                                      : resync_step(bus, a);
    }
    return rc;
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
        mbfb_end_backoff(dev);
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

/* A device in back-off before its next probe: no bus time (MBFB_E_OFFLINE); but a late
 * reply of the device waiting in the port is heard first (the silence wait reads it), and
 * retiring its shape ends the back-off. 0 when the request may go. */
static int held_back(mbfb_bus_t *bus, mbfb_dev_t *dev)
{
    if (dev->probe_us > 0 && mbfb_now_us() < dev->next_probe_us && bus->fd >= 0 &&
        bus->be->needs_resync && mbfb_fd_wait_input(bus->fd, 0) == 1)
        (void)mbfb_wait_quiet(bus, dev->slave); /* a lost port shows in the next attempt */
    if (dev->probe_us > 0 && mbfb_now_us() < dev->next_probe_us) {
        set_error(dev, MBFB_E_OFFLINE);
        return MBFB_E_OFFLINE;
    }
    return 0;
}

/* Open the port if it is closed. A failure fails every plan of the bus, which tries again
 * only after a probe interval: no spinning on open(). 0 or the MBFB_E_* of the failure. */
static int open_port(mbfb_bus_t *bus, mbfb_dev_t *dev)
{
    int64_t now;
    int rc, err;

    if (bus->fd >= 0 || (rc = bus->be->open(bus)) >= 0)
        return 0;
    now = mbfb_now_us();
    err = rc == -MBFB_E_BAUD || rc == -MBFB_E_DIRECTION ? -rc : MBFB_E_NOPORT;
    bus->reopen_us = now + (int64_t)MBFB_PROBE_MIN_MS * 1000;
    set_error(dev, err);
    mbfb_plans_no_port(bus, now, err); /* the caller's plan included: it publishes nothing */
    return err;
}

/* The outstanding set is full (nothing was sent): the device waits, as in back-off, until
 * its oldest shape expires. */
static void wait_for_shapes(mbfb_dev_t *dev)
{
    int64_t t = dev->n_outstanding > 0 ? dev->outstanding[0].t_us : mbfb_now_us();

    for (int i = 1; i < dev->n_outstanding; i++)
        t = dev->outstanding[i].t_us < t ? dev->outstanding[i].t_us : t;
    if (dev->probe_us <= 0)
        dev->probe_us = (int64_t)MBFB_PROBE_MIN_MS * 1000;
    dev->next_probe_us = t + (int64_t)MBFB_LATE_MAX_MS * 1000;
    MBFB_DIAG_SET(dev, offline, 1u);
}

/* Run one request of a device: back-off, port, attempts. Returns its result. */
int mbfb_device_request(mbfb_bus_t *bus, mbfb_request_t *request)
{
    mbfb_dev_t *dev = mbfb_devs[request->devidx];
    attempts_t a;
    int rc;

    if ((rc = held_back(bus, dev)) != 0)
        return rc;
    if (mbfb_stopping(bus))
        return MBFB_E_CANCELLED; /* shutting down: no port opened, nothing sent */
    if ((rc = open_port(bus, dev)) != 0)
        return rc;
    if (!bus->be->needs_resync)
        dev->in_step = 1;
    MBFB_DIAG_INC(dev, requests);
    memset(&a, 0, sizeof a);
    a.req = request;
    a.dev = dev;
    a.err = MBFB_E_TIMEOUT;
    /* One attempt (a probe) for a device in back-off, and for one still out of step
     * because its previous request ran out of attempts: each failed resync read uses
     * up a reply shape for MBFB_LATE_MAX_MS, which a dead device must not exhaust. */
    a.probe = dev->probe_us > 0;
    a.budget = a.probe || !dev->in_step ? 1 : 1 + bus->cfg.retries;
    request->write_sent = 0;
    rc = run_attempts(bus, &a);
    if (rc == -MBFB_E_PORTLOST) {
        port_lost(bus, dev);
        /* a write that went out may have been applied before the port went: its outcome
         * is unknown, not failed (a read-back needs the port) */
        rc = request->write_sent ? MBFB_E_UNCONFIRMED : MBFB_E_PORTLOST;
    } else if (a.sent > 0) {
        update_backoff(bus, dev, a.answered);
    } else if (rc == MBFB_E_OFFLINE) {
        wait_for_shapes(dev);
    }
    set_error(dev, rc);
    return rc;
}
