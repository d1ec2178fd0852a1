/*
 * mbfb_device.c - a device's protocol state and its transitions, in one place
 * (mbfb_dev_state_t; README "Late replies", "Failures and what the worker does").
 *
 *   IN_STEP      --ATTEMPT_FAILED (serial)-----------------> OUT_OF_STEP
 *   any          --RESYNCED (a resync read answered)-------> IN_STEP
 *   any          --UNANSWERED, MBFB_OFFLINE_AFTER in a row-> BACKOFF      (probe interval)
 *   OUT_OF_STEP  --SHAPES_FULL (no resync read possible)---> SHAPES_FULL  (oldest shape's
 *                                                                          expiry)
 *   BACKOFF, SHAPES_FULL --ANSWERED (or heard)------------> OUT_OF_STEP  (TCP: IN_STEP)
 *
 * A held device (BACKOFF, SHAPES_FULL) gets nothing before next_probe_us, then one
 * attempt: the probe (mbfb_attempt.c). Modbus TCP has no late replies on a new connection,
 * so it knows IN_STEP and BACKOFF only. mbfb_dev_event is the only writer of dev->state;
 * the rest of the worker reads it through mbfb_dev_in_step and mbfb_dev_held.
 */
#include "mbfb_internal.h"

/* A held device is probed once per interval: MBFB_PROBE_SHARE response timeouts, at least
 * MBFB_PROBE_MIN_MS, so a dead device costs at most 1/MBFB_PROBE_SHARE of the line however
 * long it stays dead, and one that comes back is found within one interval. */
static int64_t probe_interval(const mbfb_bus_t *bus)
{
    int64_t interval = (int64_t)MBFB_PROBE_SHARE * bus->timeout_us;
    return interval < MBFB_MS(MBFB_PROBE_MIN_MS) ? MBFB_MS(MBFB_PROBE_MIN_MS) : interval;
}

/* When the oldest outstanding reply shape expires (MBFB_LATE_MAX_MS after its attempt). */
static int64_t oldest_shape_expiry(const mbfb_dev_t *dev, int64_t now)
{
    int64_t t = now;
    for (int i = 0; i < dev->n_outstanding; i++)
        t = dev->outstanding[i].t_us < t ? dev->outstanding[i].t_us : t;
    return t + MBFB_MS(MBFB_LATE_MAX_MS);
}

void mbfb_dev_event(mbfb_bus_t *bus, mbfb_dev_t *dev, mbfb_dev_event_t ev, int64_t t)
{
    mbfb_dev_state_t to = dev->state;

    switch (ev) {
    case MBFB_EV_ATTEMPT_FAILED: /* its reply may still come (a new TCP connection: not) */
        if (dev->state == MBFB_DEV_IN_STEP && bus->be->needs_resync)
            to = MBFB_DEV_OUT_OF_STEP;
        break;
    case MBFB_EV_RESYNCED: /* it serves requests in order: nothing older can follow */
        to = MBFB_DEV_IN_STEP;
        break;
    case MBFB_EV_ANSWERED: /* busy or slow, not gone: its failures count from 0 again */
        dev->fails = 0;
        if (mbfb_dev_held(dev)) /* a probe's answer may be an earlier request's */
            to = bus->be->needs_resync ? MBFB_DEV_OUT_OF_STEP : MBFB_DEV_IN_STEP;
        MBFB_DIAG_SET(dev, offline, 0u);
        break;
    case MBFB_EV_UNANSWERED:
        if (++dev->fails < MBFB_OFFLINE_AFTER)
            break;
        to = MBFB_DEV_BACKOFF; /* the same interval however long it stays silent */
        dev->next_probe_us = t + probe_interval(bus);
        MBFB_DIAG_SET(dev, offline, 1u);
        break;
    case MBFB_EV_SHAPES_FULL: /* nothing was sent: wait, as in back-off, for a shape */
        to = MBFB_DEV_SHAPES_FULL;
        dev->next_probe_us = oldest_shape_expiry(dev, t);
        MBFB_DIAG_SET(dev, offline, 1u);
        break;
    }
    dev->state = to;
}

/* Probes in one MBFB_LATE_MAX_MS, with the failed requests before back-off, must leave
 * reply shapes free: a dead device is probed, never refused for want of a shape. */
typedef char mbfb_probes_leave_shapes_free[
    MBFB_LATE_MAX_MS / MBFB_PROBE_MIN_MS + 1 + MBFB_DEFAULT_RETRIES + MBFB_OFFLINE_AFTER <=
            MBFB_OUTSTANDING_MAX ? 1 : -1]; /* C and C++ alike (no _Static_assert in C++11) */
