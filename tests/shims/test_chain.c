/*
 * test_chain.c - chains (mbfb_post_chain), for each serial framing, against a scripted peer
 * on the test line that logs every request and counts the writes it applies:
 *   order          entries written and read back in order, one write each, all held
 *   not_held       a read-back that differs (the device clamps entry 2): 209, held = 2
 *   exception      an entry refused (exception 3): stops there, later entries not sent
 *   pulled         the device pulled mid-chain: fails at that entry, held = entries before;
 *                  posted again from there, it finishes (nothing written twice)
 *   echo_lost      an entry's echo lost: confirmed by the read-back, applied once
 *   interleave     a plan of another device (period 0) and a write posted mid-chain get
 *                  their turns between entries (a refresh between each two), never
 *                  between a write and its read-back
 *   cancel         cancelled between entries: no later entry is sent
 *   shutdown       mbfb_shutdown mid-chain: no later entry is sent, handles stale
 *   stopped        the PLC stops polling mid-chain: the entry under way ends, the next is
 *                  not sent (MBFB_E_STOPPED), held says how far it got
 *   bad            bad arguments: -MBFB_E_INVAL, nothing sent
 */
#include <string.h>

#include "mbfb_internal.h" /* MBFB_STALE_MIN_MS */
#include "mbfb_test.h"

#define T_MS 200
#define BAUD 38400
#define LOG_MAX 4096
#define N 6          /* entries of the test chains */
#define REG0 20      /* their first register */

static peer_t P;
static int framing;
static int mode;     /* what the peer does (M_*; __atomic) */
static int fault_at; /* the write number (0-based, among writes) it misbehaves on;
                        M_CLAMP: the entry whose register it clamps */
static int writes;   /* writes received (__atomic) */
static int applied;  /* writes applied (__atomic) */
static int nlog;     /* requests logged (under P.lock) */
static struct { int slave, fc, addr; } req_log[LOG_MAX];
enum { M_GOOD, M_CLAMP, M_EXCEPTION, M_PULL, M_ECHO_LOST, M_HOLD, M_SLOW };
#define SLOW_MS 400  /* M_SLOW: every echo this late (the response timeout: 1 s) */

/* A device that logs each request and misbehaves on write number fault_at as `mode` says. */
static void chain_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    int fc = f[1], w = -1, m = __atomic_load_n(&mode, __ATOMIC_ACQUIRE);

    pthread_mutex_lock(&p->lock);
    if (nlog < LOG_MAX) {
        req_log[nlog].slave = f[0];
        req_log[nlog].fc = fc;
        req_log[nlog].addr = f[2] << 8 | f[3];
        nlog++;
    }
    pthread_mutex_unlock(&p->lock);
    if (fc == 6)
        w = __atomic_fetch_add(&writes, 1, __ATOMIC_ACQ_REL);
    if (w == fault_at && m == M_EXCEPTION) {
        uint8_t e[3] = {f[0], (uint8_t)(fc | 0x80), 3};
        peer_reply_frame(p, r, e, 3);
        return;
    }
    if (w == fault_at && m == M_PULL)
        peer_set_dead(p, 1, 1); /* silent from this write on */
    peer_answer(p, n, f, len, r);
    if (w >= 0 && r->len > 0)
        __atomic_fetch_add(&applied, 1, __ATOMIC_ACQ_REL);
    if (fc == 6 && m == M_CLAMP && (f[2] << 8 | f[3]) == REG0 + fault_at)
        peer_set_reg(p, f[0], f[2] << 8 | f[3], 1); /* holds another word than written */
    if (w == fault_at && m == M_ECHO_LOST)
        r->len = 0;
    if (w == fault_at && m == M_HOLD)
        r->hold = 1;
    if (w >= 0 && m == M_SLOW)
        r->delay_ms = SLOW_MS;
}

static int setup_t(int m, int at, int timeout_ms)
{
    __atomic_store_n(&mode, m, __ATOMIC_RELEASE);
    fault_at = at;
    __atomic_store_n(&writes, 0, __ATOMIC_RELEASE);
    __atomic_store_n(&applied, 0, __ATOMIC_RELEASE);
    nlog = 0;
    return t_serial_dev(&P, chain_peer, framing, BAUD, timeout_ms, 3);
}

static int setup(int m, int at)
{
    return setup_t(m, at, T_MS);
}

/* The bus t_serial_dev opened (the same settings join it). */
static int this_bus(void)
{
    mbfb_bus_config_t c = t_cfg(P.link, BAUD, framing, T_MS, 3);
    if (framing == MBFB_FRAMING_ASCII) {
        c.data_bits = 7;
        c.parity = 'E';
    }
    return mbfb_bus_open(&c);
}

static void teardown(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

static uint16_t peer_reg(int slave, int addr)
{
    uint16_t v;
    pthread_mutex_lock(&P.lock);
    v = P.regs[slave][addr];
    pthread_mutex_unlock(&P.lock);
    return v;
}

/* The test chain: N registers from REG0, words 0x100 + i (the peer holds 0x1000 + addr). */
static void chain_of(uint16_t *regs, uint16_t *words)
{
    for (int i = 0; i < N; i++) {
        regs[i] = (uint16_t)(REG0 + i);
        words[i] = (uint16_t)(0x100 + i);
    }
}

/* Post the test chain from entry `from`, wait for it; *held and the take's result. */
static int run_chain(int dev, int from, int *held)
{
    uint16_t regs[N], words[N];
    int h;

    chain_of(regs, words);
    h = mbfb_post_chain(dev, N - from, regs + from, words + from);
    if (h < 0)
        return h;
    t_wait(h);
    *held = mbfb_chain_held(h);
    return mbfb_take(h, NULL, 0);
}

/* Requests of slave 1 in the log: the chain's, as (fc, addr) pairs must come. */
static int slave1_requests(int *fc, int *addr, int max)
{
    int k = 0;
    pthread_mutex_lock(&P.lock);
    for (int i = 0; i < nlog && k < max; i++)
        if (req_log[i].slave == 1) {
            fc[k] = req_log[i].fc;
            addr[k++] = req_log[i].addr;
        }
    pthread_mutex_unlock(&P.lock);
    return k;
}

static void order(void)
{
    int dev = setup(M_GOOD, -1), held = -1, fc[LOG_MAX], addr[LOG_MAX], n, next = 0;

    CHECK_EQ(run_chain(dev, 0, &held), 0);
    CHECK_EQ(held, N);
    n = slave1_requests(fc, addr, LOG_MAX);
    /* entry i: its write, then its read-back before the next entry's write; between them
     * nothing but reads of slave 1 (a write whose echo came too late on a loaded machine is
     * resolved by a resync read and a read-back: mbfb_attempt.c) */
    for (int i = 0; i < n; i++) {
        int j = i + 1;
        if (fc[i] != 6) {
            CHECK_EQ(fc[i], 3);
            continue;
        }
        CHECK_EQ(addr[i], REG0 + next);
        next++;
        while (j < n && fc[j] == 3 && addr[j] != addr[i])
            j++;
        CHECK(j < n && fc[j] == 3 && addr[j] == addr[i]);
    }
    CHECK_EQ(next, N); /* one write each */
    for (int i = 0; i < N; i++)
        CHECK_EQ(peer_reg(1, REG0 + i), 0x100 + i);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), N);
    teardown();
}

static void not_held(void)
{
    int dev = setup(M_CLAMP, 2), held = -1;

    CHECK_EQ(run_chain(dev, 0, &held), -MBFB_E_NOT_HELD);
    CHECK_EQ(held, 2);
    /* entry 2 written (once; again only if its echo came too late and the confirmation
     * read showed the clamped word: an idempotent write not applied), none after it */
    CHECK(__atomic_load_n(&writes, __ATOMIC_ACQUIRE) >= 3);
    CHECK_EQ(peer_reg(1, REG0 + 3), 0x1000 + REG0 + 3);
    teardown();
}

static void exception_entry(void)
{
    int dev = setup(M_EXCEPTION, 3), held = -1;

    CHECK_EQ(run_chain(dev, 0, &held), -(MBFB_E_EXCEPTION_BASE + 3));
    CHECK_EQ(held, 3);
    CHECK_EQ(__atomic_load_n(&writes, __ATOMIC_ACQUIRE), 4); /* refused, not sent again */
    CHECK_EQ(peer_reg(1, REG0 + 4), 0x1000 + REG0 + 4);
    teardown();
}

static void pulled(void)
{
    int dev = setup(M_PULL, 2), held = -1, rc, fc[LOG_MAX], addr[LOG_MAX], n;

    rc = run_chain(dev, 0, &held);
    CHECK(rc == -MBFB_E_TIMEOUT || rc == -MBFB_E_UNCONFIRMED);
    CHECK_EQ(held, 2);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), 2);
    n = slave1_requests(fc, addr, LOG_MAX);
    for (int i = 0; i < n; i++) /* nothing written past the entry that failed */
        CHECK(fc[i] != 6 || addr[i] <= REG0 + 2);
    /* plugged in again: posted from the entry that failed, it finishes (the first posts may
     * fail while the device is in back-off or its resync read is not answered in time) */
    peer_set_dead(&P, 1, 0);
    __atomic_store_n(&mode, M_GOOD, __ATOMIC_RELEASE);
    for (int from = held, tries = 0; tries < 10; tries++) {
        t_sleep_ms(300);
        rc = run_chain(dev, from, &held);
        from += held > 0 ? held : 0;
        if (rc == 0) {
            CHECK_EQ(from, N);
            break;
        }
    }
    CHECK_EQ(rc, 0);
    for (int i = 0; i < N; i++)
        CHECK_EQ(peer_reg(1, REG0 + i), 0x100 + i);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), N); /* each applied once */
    teardown();
}

static void echo_lost(void)
{
    int dev = setup(M_ECHO_LOST, 1), held = -1;

    CHECK_EQ(run_chain(dev, 0, &held), 0);
    CHECK_EQ(held, N);
    CHECK_EQ(__atomic_load_n(&applied, __ATOMIC_ACQUIRE), N); /* not applied twice */
    CHECK_EQ(__atomic_load_n(&writes, __ATOMIC_ACQUIRE), N);
    teardown();
}

static void interleave(void)
{
    int dev = setup(M_HOLD, 1), dev2, plan, h, w, held = -1, between = 0, first = -1, last = -1;
    int w1 = -1, wpost = -1;
    mbfb_plan_item_t item = {MBFB_FC_READ_HOLDING, 0, 2, MBFB_TIER_EVERY};
    uint16_t regs[N], words[N], one = 0x4711;

    chain_of(regs, words);
    dev2 = mbfb_dev_open(this_bus(), 2);
    CHECK(dev2 >= 0);
    plan = mbfb_plan_open(dev2);
    CHECK_EQ(mbfb_plan_set(plan, &item, 1, 0, 60000), 0);
    h = mbfb_post_chain(dev, N, regs, words);
    CHECK(h > 0);
    while (__atomic_load_n(&writes, __ATOMIC_ACQUIRE) < 2) /* entry 1's write held */
        t_sleep_ms(2);
    w = mbfb_post(dev, 6, 100, 1, &one); /* posted mid-chain */
    peer_release(&P);
    t_wait(h);
    held = mbfb_chain_held(h);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    CHECK_EQ(held, N);
    CHECK_EQ(t_wait(w), MBFB_REQ_DONE);
    CHECK_EQ(mbfb_take(w, NULL, 0), 0);
    pthread_mutex_lock(&P.lock);
    for (int i = 0; i < nlog; i++) {
        if (req_log[i].slave == 1 && req_log[i].fc == 6 && req_log[i].addr == REG0 + 1)
            w1 = i;
        if (req_log[i].slave == 1 && req_log[i].fc == 6 && req_log[i].addr == 100)
            wpost = i;
        if (req_log[i].slave == 1 && req_log[i].fc == 6 && req_log[i].addr == REG0 + 2)
            first = i;
        if (req_log[i].slave == 1 && req_log[i].fc == 3 && req_log[i].addr == REG0 + N - 1)
            last = i;
        /* a write and its read-back: only reads of slave 1 between them (resync reads) */
        if (req_log[i].slave == 1 && req_log[i].fc == 6 && req_log[i].addr >= REG0 &&
            req_log[i].addr < REG0 + N) {
            int j = i + 1;
            while (j < nlog && req_log[j].slave == 1 && req_log[j].fc == 3 &&
                   req_log[j].addr != req_log[i].addr)
                j++;
            CHECK(j < nlog && req_log[j].slave == 1 && req_log[j].fc == 3 &&
                  req_log[j].addr == req_log[i].addr);
        }
    }
    for (int i = first; first >= 0 && i < last; i++)
        between += req_log[i].slave == 2;
    pthread_mutex_unlock(&P.lock);
    /* the write posted mid-chain goes after entry 1, before entry 2 */
    CHECK(w1 >= 0 && wpost > w1 && first > wpost);
    /* entries 2..N-1: the plan (always due) reads between each two of them (one entry
     * per refresh while plans are due) */
    CHECK(first >= 0 && last > first);
    CHECK(between >= N - 3);
    teardown();
}

/* A chain posted to a peer that holds its replies, once its entry 1 is on the wire: the
 * chain's handle. */
static int chain_at_entry_1(void)
{
    int dev = setup(M_HOLD, 1), h;
    uint16_t regs[N], words[N];

    chain_of(regs, words);
    h = mbfb_post_chain(dev, N, regs, words);
    while (__atomic_load_n(&writes, __ATOMIC_ACQUIRE) < 2)
        t_sleep_ms(2);
    return h;
}

static void cancel(void)
{
    int h = chain_at_entry_1();

    CHECK_EQ(mbfb_cancel(h), 0); /* entry 1 on the wire: it ends, nothing after it */
    peer_release(&P);
    /* the worker frees the cancelled chain's slot once entry 1's transaction is over (until
     * then mbfb_poll says stale already, mbfb_chain_held still counts) */
    for (int64_t end = t_now_us() + 30000000;
         mbfb_chain_held(h) != -MBFB_E_BADHANDLE && t_now_us() < end;)
        t_sleep_ms(2);
    CHECK_EQ(mbfb_poll(h), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_chain_held(h), -MBFB_E_BADHANDLE);
    CHECK_EQ(__atomic_load_n(&writes, __ATOMIC_ACQUIRE), 2);
    CHECK_EQ(peer_reg(1, REG0 + 2), 0x1000 + REG0 + 2);
    teardown();
}

static void shutdown_mid(void)
{
    int h = chain_at_entry_1();

    peer_release(&P);
    mbfb_shutdown(); /* ends the attempt on the wire, starts no other */
    /* the worker is gone: whatever it wrote is on the line; the peer reads all of it */
    for (int64_t end = t_now_us() + 10000000; peer_pending(&P) > 0 && t_now_us() < end;)
        t_sleep_ms(2);
    CHECK(__atomic_load_n(&writes, __ATOMIC_ACQUIRE) <= 3);
    CHECK_EQ(mbfb_poll(h), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_chain_held(h), -MBFB_E_BADHANDLE);
    peer_stop(&P);
}

static void stopped(void)
{
    enum { LONG = 12 }; /* entries of about SLOW_MS each: longer than the stale bound */
    int dev = setup_t(M_SLOW, -1, 1000), h, held, w;
    uint16_t regs[LONG], words[LONG];

    for (int i = 0; i < LONG; i++) {
        regs[i] = (uint16_t)(REG0 + i);
        words[i] = (uint16_t)(0x100 + i);
    }
    h = mbfb_post_chain(dev, LONG, regs, words);
    CHECK(h > 0);
    /* no poll, no post: the PLC stopped; the entry under way ends, the next is not sent */
    t_sleep_ms(MBFB_STALE_MIN_MS + 2 * SLOW_MS + 300);
    CHECK_EQ(mbfb_poll(h), MBFB_REQ_FAILED);
    held = mbfb_chain_held(h);
    CHECK_EQ(mbfb_take(h, NULL, 0), -MBFB_E_STOPPED);
    w = __atomic_load_n(&writes, __ATOMIC_ACQUIRE);
    CHECK(held >= 2 && held < LONG);
    CHECK_EQ(w, held); /* the entry it stopped at was not sent */
    for (int i = 0; i < LONG; i++)
        CHECK_EQ(peer_reg(1, REG0 + i), i < held ? 0x100 + i : 0x1000 + REG0 + i);
    teardown();
}

static void bad(void)
{
    int dev = setup(M_GOOD, -1), bcast, h;
    uint16_t regs[MBFB_CHAIN_MAX + 1], words[MBFB_CHAIN_MAX + 1];

    memset(regs, 0, sizeof regs);
    memset(words, 0, sizeof words);
    CHECK_EQ(mbfb_post_chain(dev, 0, regs, words), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post_chain(dev, MBFB_CHAIN_MAX + 1, regs, words), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post_chain(dev, 1, NULL, words), -MBFB_E_INVAL);
    bcast = mbfb_dev_open(0, 0);
    CHECK_EQ(mbfb_post_chain(bcast, 1, regs, words), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post_chain(-1, 1, regs, words), -MBFB_E_BADHANDLE);
    h = mbfb_post(dev, 3, 0, 1, NULL); /* not a chain */
    CHECK_EQ(mbfb_chain_held(h), -MBFB_E_BADHANDLE);
    t_wait(h);
    CHECK_EQ(peer_count(&P), 1); /* the read only: nothing of the refused chains was sent */
    CHECK_EQ(mbfb_chain_held(h), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    teardown();
}

int main(void)
{
    static const t_case_t cases[] = {
        {order, "entries in order, each written and read back once"},
        {not_held, "read-back differs: 209, held before it"},
        {exception_entry, "an entry refused: stops there"},
        {pulled, "device pulled mid-chain, finished by posting the rest"},
        {echo_lost, "echo lost: confirmed by the read-back, applied once"},
        {interleave, "plan reads and posts between entries"},
        {cancel, "cancelled between entries"},
        {shutdown_mid, "shutdown mid-chain"},
        {stopped, "the PLC stops polling mid-chain"},
        {bad, "bad arguments"},
    };
    return t_serial_scenarios("test_chain", &framing, cases,
                              (int)(sizeof cases / sizeof cases[0]));
}
