/*
 * mbfb_busy.c - the line's use over the last second (busy_permille, mbfb_bus_diag_t and
 * mbfb_diag_t.line_permille): every attempt's line time (request, turnaround, reply, the
 * gap owed) in MBFB_BUSY_BUCKETS buckets of MBFB_BUSY_BUCKET_US, summed by the worker so
 * that the scan reads one word.
 */
#include <stdint.h>

#include "mbfb_internal.h"

/* The bucket epoch (its number since the clock's start) of a time. */
static uint32_t epoch_of(int64_t now)
{
    return (uint32_t)(now / MBFB_BUSY_BUCKET_US);
}

/* Sum the buckets of the second before `now` into bus->busy_permille (what the scan reads:
 * one load). Returns when the window will hold no busy time any more (the newest busy
 * bucket leaves it), or INT64_MAX when it holds none now: the idle worker wakes then once
 * to store 0 (worker loop), so a quiet line reads 0 a second after its last attempt without
 * a wake per bucket. */
int64_t mbfb_busy_update(mbfb_bus_t *bus, int64_t now)
{
    uint32_t epoch = epoch_of(now), busy = 0, age = MBFB_BUSY_BUCKETS;
    for (int i = 0; i < MBFB_BUSY_BUCKETS; i++) {
        uint32_t a = epoch - __atomic_load_n(&bus->busy_epoch[i], __ATOMIC_RELAXED);
        uint32_t us = __atomic_load_n(&bus->busy_us[i], __ATOMIC_RELAXED);
        if (a < MBFB_BUSY_BUCKETS && us > 0) {
            busy += us;
            age = a < age ? a : age; /* the newest busy bucket */
        }
    }
    /* busy us in one second: / 1000 is per mille */
    __atomic_store_n(&bus->busy_permille, busy / 1000 > 1000 ? 1000u : busy / 1000,
                     __ATOMIC_RELAXED);
    return busy == 0 ? INT64_MAX
                     : (now / MBFB_BUSY_BUCKET_US - age + MBFB_BUSY_BUCKETS) * MBFB_BUSY_BUCKET_US;
}

/* Account `us` of line time in the bucket of now. */
void mbfb_busy_add(mbfb_bus_t *bus, int64_t now, int64_t us)
{
    uint32_t epoch = epoch_of(now);
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

/* the window is one second: its busy microseconds / 1000 are per mille */
typedef char mbfb_busy_window_is_a_second[
    (int64_t)MBFB_BUSY_BUCKETS * MBFB_BUSY_BUCKET_US == 1000000 ? 1 : -1];
