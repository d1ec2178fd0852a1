/*
 * unload_prog.c - a PLC program as a runtime loads one: a shared object with the shims
 * linked in, dlopen'ed, scanned and dlclose'd by test_unload.c (OpenPLC Runtime v4 does the
 * same on every Stop and Start). It opens one bus with a live and a dead device, runs a plan
 * on each and posts a write when asked; the scan takes the plans' snapshots and polls the
 * write, as the blocks do.
 */
#include <string.h>

#include "mbfb.h"

#define LIVE_SLAVE 1
#define DEAD_SLAVE 9

static int dev[2] = {-1, -1}, plan[2] = {-1, -1}, write_req;
static uint32_t seq[2];
static mbfb_snap_t snap;
static int snaps[2];

/* Open the bus on `port` and start a plan on each device. 0, or a negative -MBFB_E_*. */
int prog_start(const char *port, int timeout_ms, int retries)
{
    mbfb_plan_item_t item = {3, 0, 4, MBFB_TIER_EVERY};
    mbfb_bus_config_t c;
    int bus, rc;

    memset(&c, 0, sizeof c);
    c.port = port;
    c.baud = 115200;
    c.parity = 'N';
    c.data_bits = 8;
    c.stop_bits = 1;
    c.framing = MBFB_FRAMING_RTU;
    c.response_timeout_ms = timeout_ms;
    c.retries = retries;
    if ((bus = mbfb_bus_open(&c)) < 0)
        return bus;
    for (int i = 0; i < 2; i++) {
        if ((dev[i] = mbfb_dev_open(bus, i == 0 ? LIVE_SLAVE : DEAD_SLAVE)) < 0)
            return dev[i];
        if ((plan[i] = mbfb_plan_open(dev[i])) < 0)
            return plan[i];
        if ((rc = mbfb_plan_set(plan[i], &item, 1, 20, 0)) < 0)
            return rc;
    }
    return 0;
}

/* Post a write (FC06) to the live device; its handle. */
int prog_write(uint16_t value)
{
    write_req = mbfb_post_write(dev[0], 6, 10, 1, &value, MBFB_WRITE_ONCE);
    return write_req;
}

/* One scan: each plan's snapshot taken, the write polled. */
void prog_scan(void)
{
    for (int i = 0; i < 2; i++)
        snaps[i] += mbfb_plan_take(plan[i], &seq[i], &snap) == 1;
    if (write_req > 0)
        (void)mbfb_poll(write_req);
}

/* Snapshots taken of plan i (0: the live device, 1: the dead one). */
int prog_snaps(int i)
{
    return snaps[i & 1];
}
