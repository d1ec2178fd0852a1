/*
 * mbfb_worker.c - the one thread per bus that does all its I/O.
 *
 * Per request: back-off check, (re)open the port, then up to 1 + retries attempts:
 *   wait until the line is silent (every byte heard is read, discarded and counted,
 *   and restarts the silence), send, receive, validate.
 * Late replies (RTU has no transaction id):
 *   - a retry follows a failed attempt after the usual gap only. A late reply to an
 *     earlier attempt that arrives while the retry waits is taken: it answers the
 *     same question (same slave, function, registers; a write's same value).
 *   - after a transaction with a failed attempt, the NEXT request waits until the
 *     line has been silent for a whole response timeout (bus->settle_us), so a late
 *     reply still on its way is heard and discarded, not taken as that answer.
 *   - TCP reconnects after a failed attempt instead.
 * Write retries re-send the same absolute value, so a write the device applied but
 * whose reply was lost is applied again with the same effect (idempotent).
 */
#include <errno.h>

#include "mbfb_internal.h"

static void set_error(mbfb_dev_t *dev, int err)
{
    MBFB_DIAG_SET(dev, last_error, (int32_t)err);
}

/* Port lost: close it, fail the request and everything queued behind it. The next
 * request reopens the port. */
static void port_lost(mbfb_bus_t *bus, mbfb_dev_t *dev, mbfb_slot_t *s)
{
    bus->be->close(bus);
    set_error(dev, MBFB_E_PORTLOST);
    mbfb_slot_finish(s, MBFB_E_PORTLOST);
    mbfb_slot_fail_queued(bus, MBFB_E_PORTLOST);
}

/* Count a failed attempt in the device diagnostics. */
static void count_failure(mbfb_dev_t *dev, int err)
{
    if (err == MBFB_E_TIMEOUT)
        MBFB_DIAG_INC(dev, timeouts);
    else if (err == MBFB_E_CRC)
        MBFB_DIAG_INC(dev, crc_errors);
    else
        MBFB_DIAG_INC(dev, bad_replies);
}

/* Wait for a silent line before an attempt: the gap, or after a transaction that had
 * a failed attempt, a whole response timeout (first attempt only). 0 or -PORTLOST. */
static int wait_quiet(mbfb_bus_t *bus, int first)
{
    int silence = bus->timing.gap_us, n;

    if (first && bus->settle_us > silence)
        silence = bus->settle_us;
    n = bus->be->quiet(bus, silence, silence + MBFB_QUIET_LIMIT_T * bus->timeout_us);
    if (n < 0)
        return n;
    MBFB_STRAY_ADD(bus, n);
    return 0;
}

/* One transaction with its retries. Returns MBFB_OK, a positive MBFB_E_* code, or
 * -MBFB_E_PORTLOST. *failed counts the attempts that got no valid answer. */
static int transact(mbfb_bus_t *bus, mbfb_dev_t *dev, mbfb_slot_t *s, const uint8_t *req,
                    int len, int attempts, int *failed)
{
    uint8_t rsp[MBFB_FRAME_MAX];
    int err = MBFB_E_TIMEOUT;

    for (int a = 0; a < attempts; a++) {
        int64_t t0;
        int rc;

        if (a > 0)
            MBFB_DIAG_INC(dev, retries);
        if (wait_quiet(bus, a == 0) < 0)
            return -MBFB_E_PORTLOST;
        t0 = mbfb_now_us();
        if (bus->be->send(bus, req, len) < 0)
            return -MBFB_E_PORTLOST;
        if (req[0] == 0) { /* broadcast: no reply; let the slaves process it */
            bus->quiet_from_us = t0 + (int64_t)mbfb_wire_len(bus->cfg.framing, len) *
                                          bus->timing.char_us + MBFB_TURNAROUND_US;
            return MBFB_OK;
        }
        rc = bus->be->recv(bus, req, rsp, (int)sizeof rsp, bus->timeout_us);
        bus->quiet_from_us = mbfb_now_us();
        if (rc == -MBFB_E_PORTLOST)
            return rc;
        err = rc < 0 ? -rc : mbfb_check_reply(req, rsp, rc);
        if (err == MBFB_OK) {
            MBFB_DIAG_INC(dev, good);
            MBFB_DIAG_SET(dev, last_rtt_us, (uint32_t)(bus->quiet_from_us - t0));
            s->nvals = (s->fc == 3 || s->fc == 4) ? s->count : 0;
            for (int i = 0; i < s->nvals; i++)
                s->values[i] = (uint16_t)(rsp[3 + 2 * i] << 8 | rsp[4 + 2 * i]);
            return MBFB_OK;
        }
        if (err >= MBFB_E_EXCEPTION_BASE) { /* a valid answer: no retry */
            MBFB_DIAG_INC(dev, exceptions);
            MBFB_DIAG_SET(dev, last_exception, (uint32_t)(err - MBFB_E_EXCEPTION_BASE));
            return err;
        }
        count_failure(dev, err);
        ++*failed;
        if (bus->be->resync != NULL)
            bus->be->resync(bus);
        if (bus->ctx == NULL)
            return -MBFB_E_PORTLOST; /* TCP reconnect failed */
    }
    return err;
}

/* Back-off bookkeeping after a transaction that reached the device's turn. */
static void update_backoff(mbfb_dev_t *dev, int result)
{
    if (result == MBFB_OK || result >= MBFB_E_EXCEPTION_BASE) { /* it answered */
        dev->fails = 0;
        dev->probe_ms = 0;
        MBFB_DIAG_SET(dev, offline, 0u);
        return;
    }
    dev->fails++;
    if (dev->probe_ms > 0) /* a probe failed: probe less often */
        dev->probe_ms = dev->probe_ms * 2 > MBFB_PROBE_MAX_MS ? MBFB_PROBE_MAX_MS
                                                               : dev->probe_ms * 2;
    else if (dev->fails >= MBFB_OFFLINE_AFTER)
        dev->probe_ms = MBFB_PROBE_FIRST_MS;
    if (dev->probe_ms > 0) {
        dev->next_probe_us = mbfb_now_us() + (int64_t)dev->probe_ms * 1000;
        MBFB_DIAG_SET(dev, offline, 1u);
    }
}

static void run_request(mbfb_bus_t *bus, mbfb_slot_t *s)
{
    mbfb_dev_t *dev = mbfb_devs[s->dev];
    uint8_t req[MBFB_FRAME_MAX];
    int len, rc, failed = 0, offline = dev->probe_ms > 0;

    if (offline && mbfb_now_us() < dev->next_probe_us) { /* back-off: no bus time */
        set_error(dev, MBFB_E_OFFLINE);
        mbfb_slot_finish(s, MBFB_E_OFFLINE);
        return;
    }
    if (bus->ctx == NULL && bus->be->open(bus) < 0) {
        set_error(dev, MBFB_E_NOPORT);
        mbfb_slot_finish(s, MBFB_E_NOPORT);
        return;
    }
    len = mbfb_build_request(req, dev->slave, s->fc, s->addr, s->count, s->values);
    bus->timeout_us = bus->cfg.response_timeout_ms > 0
                          ? bus->cfg.response_timeout_ms * 1000
                          : mbfb_response_timeout_us(&bus->timing, bus->cfg.framing, len,
                                                     mbfb_reply_len(req));
    MBFB_DIAG_INC(dev, requests);
    /* an offline device gets a single-attempt probe */
    rc = transact(bus, dev, s, req, len, offline ? 1 : 1 + bus->cfg.retries, &failed);
    bus->settle_us = failed > 0 ? bus->timeout_us : 0;
    if (rc == -MBFB_E_PORTLOST) {
        port_lost(bus, dev, s);
        return;
    }
    update_backoff(dev, rc);
    set_error(dev, rc);
    mbfb_slot_finish(s, rc);
}

void *mbfb_worker_main(void *arg)
{
    mbfb_bus_t *bus = (mbfb_bus_t *)arg;

    while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE)) {
        mbfb_slot_t *s;
        while (sem_wait(&bus->wake) != 0 && errno == EINTR) {
        }
        while (!__atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE) &&
               (s = mbfb_slot_next(bus)) != NULL)
            run_request(bus, s);
    }
    if (bus->ctx != NULL)
        bus->be->close(bus);
    return NULL;
}
