/*
 * mbfb_bench.c - benchmarks of c_shims (not a test; see bench/README.md).
 *
 *   mbfb_bench timing          gap and response timeout the worker uses
 *   mbfb_bench scan N          N steady-state scan cycles (post, poll.., take; post,
 *                              cancel) for callgrind: bench/callgrind.sh divides the
 *                              inclusive instruction counts by the call counts printed
 *   mbfb_bench fps SECONDS     transactions per second over a pty with an unpaced
 *                              peer, RTU / ASCII / RTU-without-CRC side by side
 *                              (interleaved rounds), at 9600 and 115200 baud settings
 *   mbfb_bench plan N          N scan cycles of a block on a refresh plan: diag_seq
 *                              every scan, plan_take (nothing new / a new snapshot,
 *                              told apart by wrappers), a confirmed write every 10th
 *                              snapshot; for callgrind (MODE=plan bench/callgrind.sh)
 *   mbfb_bench fault N         the cost of a fault: N reads of 4 registers at 115200,
 *                              every 10th unanswered; time and attempts per clean and
 *                              per faulted read (response timeout, resync read,
 *                              the read again)
 */
#include <stdlib.h>
#include <string.h>

#include "mbfb_internal.h"
#include "mbfb_test.h"

static peer_t P;

static int open_dev(int framing, int baud)
{
    char link[160];
    mbfb_bus_config_t c;
    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, framing == MBFB_FRAMING_ASCII ? PEER_ASCII : PEER_RTU,
                   peer_answer, NULL) != 0) {
        perror("peer_start");
        exit(1);
    }
    c = t_cfg(P.link, baud, framing, 200, 3);
    return mbfb_dev_open(mbfb_bus_open(&c), 1);
}

static void close_all(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

static void timing(void)
{
    static const int bauds[] = {9600, 19200};
    printf("%-8s %-6s %9s %9s %14s %16s\n", "baud", "format", "char_us", "gap_us",
           "timeout 1 reg", "timeout 125 reg");
    for (int i = 0; i < 2; i++) {
        static const struct { char par; int data, stop; const char *name; } f[] = {
            {'N', 8, 2, "8N2"}, {'E', 8, 1, "8E1"}, {'N', 8, 1, "8N1"}};
        for (int k = 0; k < 3; k++) {
            mbfb_timing_t t;
            mbfb_timing_init(&t, bauds[i], f[k].par, f[k].data, f[k].stop);
            printf("%-8d %-6s %9d %9d %11d us %13d us\n", bauds[i], f[k].name, t.char_us,
                   t.gap_us, mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 5),
                   mbfb_response_timeout_us(&t, MBFB_FRAMING_RTU, 6, 3 + 250));
        }
    }
}

/* Steady state as a block sees it: post, poll every "scan" until done, take; plus a
 * post + cancel. Prints how many calls of each were made. */
static void scan(int n)
{
    long posts = 0, polls = 0, takes = 0, cancels = 0;
    uint16_t v[4];
    int dev = open_dev(MBFB_FRAMING_RTU, 115200);

    for (int i = 0; i < n; i++) {
        int h = mbfb_post(dev, 3, 0, 4, NULL), st;
        posts++;
        while ((st = mbfb_poll(h)) == MBFB_REQ_QUEUED || st == MBFB_REQ_ACTIVE) {
            polls++;
            t_sleep_ms(1); /* the next scan */
        }
        polls++;
        if (mbfb_take(h, v, 4) != 4) {
            fprintf(stderr, "transaction %d failed\n", i);
            exit(1);
        }
        takes++;
        h = mbfb_post(dev, 3, 0, 1, NULL);
        posts++;
        mbfb_cancel(h);
        cancels++;
    }
    close_all();
    printf("calls: mbfb_post %ld mbfb_poll %ld mbfb_take %ld mbfb_cancel %ld\n", posts,
           polls, takes, cancels);
}

/* Scan-side wrappers, so that callgrind tells the two cases of plan_take apart
 * (external: no .isra clone renames them). */
int bench_take_none(int plan, uint32_t *seq, mbfb_snap_t *s);
int bench_take_new(int plan, uint32_t *seq, mbfb_snap_t *s);
__attribute__((noinline)) int bench_take_none(int plan, uint32_t *seq, mbfb_snap_t *s)
{
    int rc = mbfb_plan_take(plan, seq, s);
    __asm__ volatile("# none" ::: "memory"); /* no tail call, no merging: counted here */
    return rc;
}

__attribute__((noinline)) int bench_take_new(int plan, uint32_t *seq, mbfb_snap_t *s)
{
    int rc = mbfb_plan_take(plan, seq, s);
    __asm__ volatile("# new" ::: "memory"); /* no tail call: callgrind counts it here */
    return rc;
}

/* A block on a plan, scan by scan (1 ms). */
static void plan_scan(int n)
{
    static const mbfb_plan_item_t items[2] = {{3, 0, 10, MBFB_TIER_EVERY},
                                              {3, 10, 7, MBFB_TIER_SLOW}};
    long none = 0, fresh = 0, seqs = 0, writes = 0;
    uint32_t seq = 0, dseq = 0;
    mbfb_snap_t snap;
    mbfb_diag_t diag;
    int dev = open_dev(MBFB_FRAMING_RTU, 115200), plan = mbfb_plan_open(dev), h = 0;
    uint16_t v[1] = {0};

    mbfb_plan_set(plan, items, 2, 0, 1000);
    while (fresh < n) {
        uint32_t ds = mbfb_dev_diag_seq(dev);
        seqs++;
        if (ds != dseq) { /* as MB_Device: copy only when they changed */
            mbfb_dev_diag(dev, &diag);
            dseq = ds;
        }
        if (__atomic_load_n(&mbfb_plans[plan]->pub, __ATOMIC_ACQUIRE) == seq) {
            bench_take_none(plan, &seq, &snap);
            none++;
        } else {
            if (bench_take_new(plan, &seq, &snap) == 1)
                fresh++;
            if (fresh % 10 == 0 && h == 0) {
                v[0] = (uint16_t)fresh;
                h = mbfb_post_write(dev, 6, 100, 1, v, MBFB_WRITE_ONCE);
                writes++;
            }
        }
        if (h > 0 && mbfb_poll(h) >= MBFB_REQ_DONE) {
            mbfb_take(h, NULL, 0);
            h = 0;
        }
        t_sleep_ms(1); /* the next scan */
    }
    close_all();
    printf("calls: bench_take_none %ld bench_take_new %ld mbfb_dev_diag_seq %ld "
           "mbfb_post_write %ld\n", none, fresh, seqs, writes);
}

/* Every 10th request gets no reply. */
static void drop_tenth(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    static int reads; /* the peer's thread only */
    if (f[1] == 3 && len >= 6 && ((f[4] << 8) | f[5]) == 4 && ++reads % 10 == 0)
        return;
    peer_answer(p, n, f, len, r);
}

/* The cost of one fault in bus time and attempts (derived response timeout). */
static void fault_cost(int n)
{
    char link[160];
    mbfb_bus_config_t c;
    mbfb_bus_diag_t bd;
    mbfb_diag_t d;
    int64_t t_clean = 0, t_fault = 0;
    long clean = 0, fault = 0, dev;
    uint16_t v[4];

    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, PEER_RTU, drop_tenth, NULL) != 0)
        exit(1);
    c = t_cfg(P.link, 115200, MBFB_FRAMING_RTU, 0, 3);
    dev = mbfb_dev_open(mbfb_bus_open(&c), 1);
    for (int i = 0; i < n; i++) {
        uint32_t before = (mbfb_dev_diag(dev, &d), d.timeouts);
        int64_t t0 = t_now_us();
        int rc = t_run(dev, 3, 0, 4, NULL, v, 4);
        int64_t dt = t_now_us() - t0;
        if (rc != 4) {
            fprintf(stderr, "read %d failed: %d\n", i, rc);
            exit(1);
        }
        mbfb_dev_diag(dev, &d);
        if (d.timeouts != before)
            t_fault += dt, fault++;
        else
            t_clean += dt, clean++;
    }
    mbfb_bus_diag(dev, &bd);
    printf("115200 8N1, FC03 x 4 registers, derived timeout, every 10th unanswered:\n");
    printf("  clean read   %6.2f ms (%ld)\n", clean ? t_clean / 1000.0 / clean : 0.0, clean);
    printf("  faulted read %6.2f ms (%ld): timeout + resync read + read again\n",
           fault ? t_fault / 1000.0 / fault : 0.0, fault);
    printf("  attempts %u for %ld reads; resync reads %u; timeouts %u\n", bd.transactions,
           (long)n, d.resyncs, d.timeouts);
    close_all();
}

/* Transactions completed back to back during `ms` milliseconds. */
static long run_for(int dev, int ms)
{
    int64_t end = t_now_us() + (int64_t)ms * 1000;
    long n = 0;
    uint16_t v[1];
    while (t_now_us() < end) {
        int h = mbfb_post(dev, 3, 0, 1, NULL), st;
        do /* spin: measure the bus, not the scan period */
            st = mbfb_poll(h);
        while (st == MBFB_REQ_QUEUED || st == MBFB_REQ_ACTIVE);
        n += mbfb_take(h, v, 1) == 1;
    }
    return n;
}

static void fps(int seconds)
{
    static const struct { int framing; const char *name; } fr[] = {
        {MBFB_FRAMING_RTU, "RTU (libmodbus)"},
        {MBFB_FRAMING_ASCII, "ASCII (ours)"},
        {MBFB_FRAMING_RTU_NOCRC, "RTU-without-CRC"}};
    static const int bauds[] = {9600, 115200};
    long count[2][3] = {{0}};
    int rounds = seconds * 2, round_ms = 250;

    /* interleave short rounds so that machine noise hits every framing alike */
    for (int r = 0; r < rounds; r++)
        for (int b = 0; b < 2; b++)
            for (int f = 0; f < 3; f++) {
                int dev = open_dev(fr[f].framing, bauds[b]);
                count[b][f] += run_for(dev, round_ms);
                close_all();
            }
    printf("%-18s %12s %12s   (pty, unpaced peer, FC03 1 register, %d x %d ms each)\n",
           "framing", "9600 set", "115200 set", rounds, round_ms);
    for (int f = 0; f < 3; f++)
        printf("%-18s %8.0f f/s %8.0f f/s\n", fr[f].name,
               count[0][f] * 1000.0 / (rounds * round_ms),
               count[1][f] * 1000.0 / (rounds * round_ms));
}

int main(int argc, char **argv)
{
    if (argc >= 2 && strcmp(argv[1], "timing") == 0)
        timing();
    else if (argc >= 3 && strcmp(argv[1], "scan") == 0)
        scan(atoi(argv[2]));
    else if (argc >= 3 && strcmp(argv[1], "fps") == 0)
        fps(atoi(argv[2]));
    else if (argc >= 3 && strcmp(argv[1], "plan") == 0)
        plan_scan(atoi(argv[2]));
    else if (argc >= 3 && strcmp(argv[1], "fault") == 0)
        fault_cost(atoi(argv[2]));
    else {
        fprintf(stderr, "usage: mbfb_bench timing | scan N | fps SECONDS | plan N | fault N\n");
        return 2;
    }
    return 0;
}
