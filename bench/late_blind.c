/*
 * late_blind.c - blind time after ONE late reply, at the shim level.
 *
 * One device (the scripted peer of tests/shims on a pty, at 9600 8N2, derived response
 * timeout, default retries) is read every PERIOD_MS: FC03 of one register at 0, one
 * request at a time as a block has it. After WARM good reads, the peer answers one request
 * DELAY ms late and is deaf meanwhile (busy: a half-duplex device discards what it hears),
 * then answers everything at once again. Printed per delay (one line, key=value):
 *   blind    ms from the post of the faulted read to the next good reply
 *   beyond   blind - delay: what the master adds to the device's own delay
 *   offline  requests refused MBFB_E_OFFLINE (not sent) in between
 *   failed   requests that ended with another error in between
 *   frames   request frames the device received in between (deaf ones not counted)
 * The values read are checked (register 0 holds 0x1000): a wrong one is printed as wrong=1.
 * Built and run against two versions of c_shims by bench/late_blind.sh.
 *
 * Usage: late_blind DELAY_MS [REPEATS]
 */
#include <stdlib.h>
#include <string.h>

#include "mbfb_test.h"

#define PERIOD_MS 50
#define WARM      10

static peer_t P;
static int late_at = -1, late_ms;

static void late_once(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    peer_answer(p, n, f, len, r);
    if (n == late_at) {
        r->delay_ms = late_ms;
        r->deaf = 1;
    }
}

static int open_dev(void)
{
    char link[160];
    mbfb_bus_config_t c;
    int bus;

    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, PEER_RTU, late_once, NULL) != 0)
        return -1;
    peer_set_reg(&P, 1, 0, 0x1000);
    c = t_cfg(P.link, 9600, MBFB_FRAMING_RTU, 0, -1); /* derived timeout, 3 retries */
    c.stop_bits = 2;
    bus = mbfb_bus_open(&c);
    return bus < 0 ? -1 : mbfb_dev_open(bus, 1);
}

/* One run: returns 0, prints one line. */
static int run(int delay)
{
    int dev = open_dev(), i, offline = 0, failed = 0, wrong = 0, frames0 = 0;
    int64_t t_fault = 0, t_good = 0, next;

    if (dev < 0)
        return -1;
    late_ms = delay;
    late_at = -1;
    next = t_now_us();
    for (i = 0; i < 100000; i++) {
        uint16_t v = 0;
        int64_t t_post;
        int rc;
        while (t_now_us() < next)
            t_sleep_ms(1);
        next += PERIOD_MS * 1000;
        if (i == WARM) {
            frames0 = peer_count(&P);
            late_at = frames0; /* the next request the peer hears */
        }
        t_post = t_now_us();
        rc = t_run(dev, 3, 0, 1, NULL, &v, 1);
        if (i == WARM)
            t_fault = t_post;
        if (rc == 1 && v != 0x1000)
            wrong++;
        if (i < WARM)
            continue;
        if (rc == 1 && i > WARM) {
            t_good = t_now_us();
            break;
        }
        if (rc == -MBFB_E_OFFLINE)
            offline++;
        else if (rc != 1)
            failed++;
        if (t_now_us() - t_fault > 60000000)
            break; /* never back: reported as blind=-1 */
    }
    printf("delay=%d blind=%.0f beyond=%.0f offline=%d failed=%d frames=%d wrong=%d\n", delay,
           t_good ? (t_good - t_fault) / 1000.0 : -1.0,
           t_good ? (t_good - t_fault) / 1000.0 - delay : -1.0, offline, failed,
           peer_count(&P) - frames0, wrong);
    fflush(stdout);
    mbfb_shutdown();
    peer_stop(&P);
    return 0;
}

int main(int argc, char **argv)
{
    int delay = argc > 1 ? atoi(argv[1]) : 200, reps = argc > 2 ? atoi(argv[2]) : 1;
    t_scenario = "late_blind";
    for (int k = 0; k < reps; k++)
        if (run(delay) != 0) {
            fprintf(stderr, "late_blind: setup failed\n");
            return 2;
        }
    return 0;
}
