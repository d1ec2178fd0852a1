/* wp_shims.c - c_shims through their public API (mbfb.h), for bench/wire_pace.py.
 *   wp_shims post PORT BAUD FORMAT SLAVE FC ADDR COUNT
 *       mbfb_post, mbfb_poll every 0.2 ms until finished, mbfb_take, post again at once:
 *       one transaction after the other, as fast as the worker runs them.
 *   wp_shims plan PORT BAUD FORMAT SLAVE FC ADDR COUNT   (when mbfb.h has plans)
 *       one plan with that read and period 0; mbfb_plan_take every 1 ms.
 * Runs until SIGTERM/SIGINT; prints "ok N err M" (transactions, or refreshes) at exit. */
#include "mbfb.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static volatile sig_atomic_t g_stop;
static void on_stop(int s) { (void)s; g_stop = 1; }

static void sleep_us(long us) {
    struct timespec ts = {us / 1000000, (us % 1000000) * 1000};
    nanosleep(&ts, NULL);
}

int main(int argc, char **argv) {
    if (argc != 9 || strlen(argv[4]) != 3) {
        fprintf(stderr, "usage: wp_shims post|plan PORT BAUD FORMAT SLAVE FC ADDR COUNT\n");
        return 2;
    }
    const char *mode = argv[1], *f = argv[4];
    int slave = atoi(argv[5]), fc = atoi(argv[6]), addr = atoi(argv[7]), count = atoi(argv[8]);
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_stop;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    mbfb_bus_config_t cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.port = argv[2];
    cfg.baud = atoi(argv[3]);
    cfg.data_bits = f[0] - '0';
    cfg.parity = f[1];
    cfg.stop_bits = f[2] - '0';
    cfg.framing = MBFB_FRAMING_RTU;
    cfg.retries = -1;
    /* RS-485 direction control (bench/direction.py): MBFB_WP_DIRECTION = the MBFB_DIR_*
       number, MBFB_WP_DIR_BEFORE_US / _AFTER_US its delays; unset: none */
    const char *dir = getenv("MBFB_WP_DIRECTION"), *before = getenv("MBFB_WP_DIR_BEFORE_US"),
               *after = getenv("MBFB_WP_DIR_AFTER_US");
    cfg.direction = dir ? atoi(dir) : MBFB_DIR_NONE;
    cfg.dir_before_us = before ? atoi(before) : 0;
    cfg.dir_after_us = after ? atoi(after) : 0;
    int bus = mbfb_bus_open(&cfg);
    int dev = bus < 0 ? bus : mbfb_dev_open(bus, slave);
    if (dev < 0) {
        fprintf(stderr, "wp_shims: %s: %s\n", argv[2], mbfb_strerror(-dev));
        return 1;
    }
    long ok = 0, err = 0;
    uint16_t regs[125];
    if (strcmp(mode, "post") == 0) {
        while (!g_stop) {
            int r = mbfb_post(dev, fc, addr, count, NULL);
            if (r < 0) {
                err++;
                sleep_us(1000);
                continue;
            }
            int st;
            while ((st = mbfb_poll(r)) == MBFB_REQ_QUEUED || st == MBFB_REQ_ACTIVE) {
                if (g_stop) break;
                sleep_us(200);
            }
            if (g_stop) break;
            if (mbfb_take(r, regs, 125) == count) ok++;
            else err++;
        }
#ifdef MBFB_PLAN_MAX_ITEMS
    } else if (strcmp(mode, "plan") == 0) {
        mbfb_plan_item_t item = {fc, addr, count, MBFB_TIER_EVERY};
        int plan = mbfb_plan_open(dev);
        int rc = plan < 0 ? plan : mbfb_plan_set(plan, &item, 1, 0, 0);
        if (rc < 0) {
            fprintf(stderr, "wp_shims: plan: %s\n", mbfb_strerror(-rc));
            return 1;
        }
        static mbfb_snap_t snap;
        uint32_t seq = 0, last = 0;
        while (!g_stop) {
            if (mbfb_plan_take(plan, &seq, &snap) == 1) {
                if (snap.result == MBFB_OK) ok += seq - last;   /* refreshes, also unseen ones */
                else err++;
                last = seq;
            }
            sleep_us(1000);
        }
#endif
    } else {
        fprintf(stderr, "wp_shims: unknown mode '%s'\n", mode);
        return 2;
    }
    printf("ok %ld err %ld\n", ok, err);
    mbfb_shutdown();
    return 0;
}
