/*
 * test_bus.c - the shims on the test line against a scripted peer: the manuals' frames byte
 * for byte in all three serial framings, broadcast, bad arguments (nothing on the
 * wire), queue full, cancel, stale handles, settings conflicts, a missing port, port
 * loss and reopen, several devices on one bus with one of them dead.
 */
#include <sched.h>
#include <string.h>
#include <unistd.h>

#include "mbfb_internal.h"
#include "mbfb_test.h"

static peer_t P;

static const char *link_path(void)
{
    static char link[160];
    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    return link;
}

static int open_bus(peer_fn fn, int mode, int baud, char parity, int data, int stop,
                    int framing, int timeout_ms, int retries)
{
    mbfb_bus_config_t c;
    if (peer_start(&P, link_path(), mode, fn, NULL) != 0) {
        perror("peer_start");
        return -1;
    }
    c = t_cfg(P.link, baud, framing, timeout_ms, retries);
    c.parity = parity;
    c.data_bits = data;
    c.stop_bits = stop;
    return mbfb_bus_open(&c);
}

static void teardown(void)
{
    mbfb_shutdown();
    peer_stop(&P);
}

/* ---- the manuals' exchanges, byte for byte -------------------------------------- */
typedef struct { const char *req, *rsp; } exchange_t;
static const exchange_t *table;
static int table_ascii;

static int decode_entry(const char *s, uint8_t *out)
{
    if (table_ascii) {
        memcpy(out, s, strlen(s));
        return (int)strlen(s);
    }
    return t_hex(s, out);
}

/* Answer with the manual's reply bytes when the request is the manual's, byte for byte. */
static void manual_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    uint8_t raw[PEER_BUF], want[PEER_BUF];
    int rl = peer_raw(p, n, raw);
    (void)f, (void)len;
    for (int i = 0; table[i].req; i++) {
        int wl = decode_entry(table[i].req, want);
        if (wl == rl && memcmp(raw, want, (size_t)wl) == 0) {
            r->len = decode_entry(table[i].rsp, r->out);
            return;
        }
    }
}

static void check_sent(int i, const char *want)
{
    uint8_t raw[PEER_BUF], w[PEER_BUF];
    int n = peer_raw(&P, i, raw);
    if (table_ascii) {
        CHECK_EQ(n, (int)strlen(want));
        CHECK(n == (int)strlen(want) && memcmp(raw, want, (size_t)n) == 0);
    } else {
        CHECK_HEX(raw, n, want);
    }
    (void)w;
}

static const exchange_t setpro_fdc[] = {
    {"01 03 00 00 00 01 84 0A", "01 03 02 03 E8 B8 FA"},       /* MV-D94 read SV */
    {"01 04 10 00 00 01 35 0A", "01 04 02 00 1B F9 3B"},       /* read PV        */
    {"01 06 00 00 01 F4 89 DD", "01 06 00 00 01 F4 89 DD"},    /* SV = 500       */
    {"01 10 00 00 00 02 04 00 0A 01 02 53 FC", "01 10 00 00 00 02 41 C8"}, /* MT-S9 */
    {"01 06 00 48 68 25 E7 C7", "01 06 00 48 68 25 E7 C7"},    /* FDC Ex3 reset  */
    {"01 03 01 00 00 01 85 F6", "01 83 02 C0 F1"},             /* exception 2    */
    {NULL, NULL}, /* FDC Ex1 is added at run time */
    {NULL, NULL},
};

static void manual_rtu(void)
{
    exchange_t tab[8];
    uint16_t v[60];
    uint8_t b[PEER_BUF];
    int bus, dev;

    memcpy(tab, setpro_fdc, sizeof setpro_fdc);
    tab[6].req = fdc_ex1;
    tab[6].rsp = "01 10 00 00 00 34 C1 DE";
    table = tab;
    table_ascii = 0;
    t_scenario = "manual frames rtu";
    bus = open_bus(manual_peer, PEER_RTU, 9600, 'N', 8, 2, MBFB_FRAMING_RTU, 0, 0);
    dev = mbfb_dev_open(bus, 1);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 1000);
    CHECK_EQ(t_run(dev, 4, 0x1000, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 27);
    v[0] = 500;
    CHECK_EQ(t_run(dev, 6, 0, 1, v, NULL, 0), 0);
    v[0] = 0x000A; /* 16908298, low word first */
    v[1] = 0x0102;
    CHECK_EQ(t_run(dev, 16, 0, 2, v, NULL, 0), 0);
    v[0] = 0x6825;
    CHECK_EQ(t_run(dev, 6, 72, 1, v, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 3, 0x100, 1, NULL, v, 1), -130);
    t_hex(fdc_ex1, b);
    for (int i = 0; i < 52; i++)
        v[i] = (uint16_t)(b[7 + 2 * i] << 8 | b[8 + 2 * i]);
    CHECK_EQ(t_run(dev, 16, 0, 52, v, NULL, 0), 0);
    for (int i = 0; i < 7; i++)
        check_sent(i, tab[i].req);
    CHECK_EQ(peer_count(&P), 7);
    teardown();
}

static const exchange_t mts9_ascii[] = {
    {":010300000002FA\r\n", ":01030407140714C2\r\n"},
    {":010600000002F7\r\n", ":010600000002F7\r\n"},
    {":01100000000204000A0102DC\r\n", ":011000000002ED\r\n"}, /* manual misprints FA */
    {NULL, NULL},
};

/* The MT-S9 manual's first three exchanges on a line framed `framing`, answered from
 * `tab`: read words 0..1 (into got), write 2 to word 0, write 0x000A 0x0102 to words 0..1.
 * The device. */
static int mts9_manual(const exchange_t *tab, int ascii, const char *scenario, int peer,
                       char parity, int bits, int framing, uint16_t got[2])
{
    uint16_t v[2];
    int dev;
    table = tab;
    table_ascii = ascii;
    t_scenario = scenario;
    dev = mbfb_dev_open(open_bus(manual_peer, peer, 9600, parity, bits, 1, framing, 0, 0), 1);
    CHECK_EQ(t_run(dev, 3, 0, 2, NULL, got, 2), 2);
    v[0] = 2;
    CHECK_EQ(t_run(dev, 6, 0, 1, v, NULL, 0), 0);
    v[0] = 0x000A;
    v[1] = 0x0102;
    CHECK_EQ(t_run(dev, 16, 0, 2, v, NULL, 0), 0);
    return dev;
}

static void manual_ascii(void)
{
    uint16_t v[2];

    mts9_manual(mts9_ascii, 1, "manual frames ascii", PEER_ASCII, 'E', 7, MBFB_FRAMING_ASCII, v);
    CHECK_EQ(v[0], 0x0714);
    CHECK_EQ(v[1], 0x0714);
    for (int i = 0; i < 3; i++)
        check_sent(i, mts9_ascii[i].req);
    teardown();
}

static const exchange_t mts9_nocrc[] = {
    {"01 03 00 00 00 02 00 00", "01 03 04 00 00 00 00 FA 33"}, /* reply as corrected */
    {"01 06 00 00 00 02 00 00", "01 06 00 00 00 02 08 0B"},
    {"01 10 00 00 00 02 04 00 0A 01 02 00 00", "01 10 00 00 00 02 41 C8"},
    {"01 03 00 02 00 02 00 00", "01 03 04 00 00 00 02 FA 33"}, /* as misprinted */
    {NULL, NULL},
};

static void manual_nocrc(void)
{
    uint16_t v[2] = {9, 9};
    int dev = mts9_manual(mts9_nocrc, 0, "manual frames rtu-nocrc", PEER_RTU, 'N', 8,
                          MBFB_FRAMING_RTU_NOCRC, v);
    CHECK_EQ(v[0], 0);
    CHECK_EQ(v[1], 0);
    /* the reply CRC is still checked: the manual's misprinted reply is refused */
    CHECK_EQ(t_run(dev, 3, 2, 2, NULL, v, 2), -MBFB_E_CRC);
    for (int i = 0; i < 4; i++)
        check_sent(i, mts9_nocrc[i].req);
    teardown();
}

/* ---- broadcast ---------------------------------------------------------------- */
static void broadcast(void)
{
    uint16_t v[2] = {500, 7};
    int bus, bc, dev, h;
    mbfb_diag_t d;

    t_scenario = "broadcast";
    bus = open_bus(peer_answer, PEER_RTU, 9600, 'N', 8, 2, MBFB_FRAMING_RTU, 200, 3);
    bc = mbfb_dev_open(bus, 0);
    dev = mbfb_dev_open(bus, 1);
    CHECK(bc >= 0);
    CHECK_EQ(mbfb_post(bc, 3, 0, 1, NULL), -MBFB_E_INVAL); /* no reply to a read */
    h = mbfb_post(bc, 6, 0, 1, v);
    CHECK_EQ(t_wait(h), MBFB_REQ_DONE);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(t_run(bc, 16, 0, 2, v, NULL, 0), 0); /* done when written: the peer may */
    for (int i = 0; i < 3000 && peer_count(&P) < 3; i++) /* not have read it yet (30 s */
        t_sleep_ms(10);                                   /* at most: a loaded machine) */
    t_sleep_ms(50);
    CHECK_EQ(peer_count(&P), 3); /* sent once each: nothing awaited, nothing retried */
    {
        uint8_t raw[PEER_BUF];
        CHECK_HEX(raw, peer_raw(&P, 0, raw), "00 06 00 00 01 F4 88 0C");
    }
    /* SetPro processing time: >= 10 ms of turnaround after a broadcast (a lower bound
     * with slack for the peer's own scheduling) */
    CHECK(peer_time(&P, 1) - peer_time(&P, 0) >= 8000);
    CHECK_EQ(mbfb_dev_diag(bc, &d), 0);
    CHECK_EQ(d.requests, 2);
    CHECK_EQ(d.timeouts, 0);
    teardown();
}

/* ---- bad arguments: an error code, a message, and nothing on the wire --------------- */
static void bad_args(void)
{
    uint16_t v[130] = {0};
    mbfb_bus_config_t c;
    int bus, dev;

    t_scenario = "bad arguments";
    bus = open_bus(peer_answer, PEER_RTU, 19200, 'E', 8, 1, MBFB_FRAMING_RTU, 200, 3);
    CHECK(bus >= 0);
    c = t_cfg(P.link, 19200, 7, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL); /* unknown framing */
    c = t_cfg(P.link, 0, MBFB_FRAMING_RTU, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg(P.link, 9600, MBFB_FRAMING_RTU, 0, -1);
    c.parity = 'X';
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.parity = 'N';
    c.data_bits = 7; /* RTU is binary */
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.data_bits = 8;
    c.stop_bits = 3;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg("tcp://127.0.0.1:1502", 9600, MBFB_FRAMING_ASCII, 0, -1); /* RTU only */
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg("/dev/ttyUSB0", 9600, MBFB_FRAMING_TCP, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg("", 9600, MBFB_FRAMING_RTU, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    /* Modbus TCP uses no serial settings, but one given must be one a line can have */
    c = t_cfg("tcp://127.0.0.1:1502", -1, MBFB_FRAMING_TCP, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg("tcp://127.0.0.1:1502", 0, MBFB_FRAMING_TCP, 0, -1);
    c.data_bits = 7;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.data_bits = 0;
    c.stop_bits = 3;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.stop_bits = 0;
    c.parity = 'X';
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg(P.link, 9600, MBFB_FRAMING_RTU, 0, 21); /* more than 20 retries */
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c = t_cfg(P.link, 9600, MBFB_FRAMING_RTU, 60001, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    /* the slave check, with or without a bus: 1..247 (0 broadcast), 255 on Modbus TCP */
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_RTU, 248), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_ASCII, -1), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_RTU, 247), 0);
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_RTU, 0), 0);
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_TCP, 255), 0);
    CHECK_EQ(mbfb_dev_check(MBFB_FRAMING_TCP, 256), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_bus_open(NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_dev_open(bus, 248), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_dev_open(bus, -1), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_dev_open(15, 1), -MBFB_E_BADHANDLE);
    dev = mbfb_dev_open(bus, 247);
    CHECK(dev >= 0);
    dev = mbfb_dev_open(bus, 1);
    CHECK_EQ(mbfb_post(dev, 3, 0, 0, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 3, 0, 126, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 4, 65535, 2, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 7, 0, 1, v), -MBFB_E_INVAL); /* not a function of the shims */
    CHECK_EQ(mbfb_post(dev, 5, 0, 1, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 1, 0, 2001, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 15, 0, 1969, v), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 6, 0, 1, NULL), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 16, 0, 124, v), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(dev, 16, -1, 1, v), -MBFB_E_INVAL);
    CHECK_EQ(mbfb_post(999, 3, 0, 1, NULL), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_post(-1, 3, 0, 1, NULL), -MBFB_E_BADHANDLE);
    CHECK(strlen(mbfb_strerror(-MBFB_E_INVAL)) > 0);
    t_sleep_ms(100);
    CHECK_EQ(peer_bytes(&P), 0); /* nothing was sent */
    peer_set_reg(&P, 1, 3, 4242);
    CHECK_EQ(t_run(dev, 3, 3, 1, NULL, v, 1), 1); /* the bus works: exactly one frame */
    CHECK_EQ(v[0], 4242);
    CHECK_EQ(peer_count(&P), 1);
    teardown();
}

/* ---- queue full, cancel, stale handles ----------------------------------------- */
static void silent(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    (void)p, (void)n, (void)f, (void)len, (void)r;
}

static void queue_cancel_handles(void)
{
    int h[80], bus, dev, n = 0, rc, a = 0;
    int64_t t_found, t_cancelled;
    uint16_t v[2];

    t_scenario = "queue full, cancel, handles";
    bus = open_bus(silent, PEER_RTU, 38400, 'N', 8, 1, MBFB_FRAMING_RTU, 400, 0);
    dev = mbfb_dev_open(bus, 1);
    while ((rc = mbfb_post(dev, 3, n, 1, NULL)) > 0 && n < 80)
        h[n++] = rc;
    CHECK_EQ(rc, -MBFB_E_QUEUEFULL);
    CHECK_EQ(n, 64);
    /* the request the worker has on the wire (h[0] unless this machine held the test
     * back past a 400 ms timeout): not finished, so take refuses it and it stays alive */
    for (int64_t end = t_now_us() + 30000000; t_now_us() < end; t_sleep_ms(1)) {
        for (a = 0; a < n && mbfb_poll(h[a]) != MBFB_REQ_ACTIVE; a++) {
        }
        if (a < n)
            break;
    }
    t_found = t_now_us();
    CHECK(a < n - 1);
    if (a >= n - 1)
        a = 0;
    CHECK_EQ(mbfb_take(h[a], v, 1), -MBFB_E_BADHANDLE); /* not finished */
    rc = mbfb_poll(h[a]);                                /* ...and still alive */
    CHECK(rc == MBFB_REQ_ACTIVE || rc == MBFB_REQ_FAILED);
    rc = mbfb_poll(h[n - 1]);
    CHECK(rc == MBFB_REQ_QUEUED);
    for (int i = 0; i < n; i++)
        CHECK_EQ(mbfb_cancel(h[i]), 0);
    t_cancelled = t_now_us();
    for (int i = 0; i < n; i++) {
        CHECK_EQ(mbfb_poll(h[i]), -MBFB_E_BADHANDLE);
        CHECK_EQ(mbfb_cancel(h[i]), -MBFB_E_BADHANDLE);
    }
    rc = mbfb_post(dev, 3, 0, 1, NULL); /* slots were freed */
    CHECK(rc > 0);
    CHECK_EQ(t_wait(rc), MBFB_REQ_FAILED);
    CHECK_EQ(mbfb_take(rc, v, 1), -MBFB_E_TIMEOUT);
    CHECK_EQ(mbfb_take(rc, v, 1), -MBFB_E_BADHANDLE); /* taken: stale */
    CHECK_EQ(mbfb_poll(rc), -MBFB_E_BADHANDLE);
    /* every request started put exactly one frame on the wire (no retries), and the
     * cancelled ones that had not started never did: the slots were free at once (the
     * post above) and the last request came after the one active at cancel time only
     * (on an idle machine: 2 frames, h[0] and the last) */
    CHECK_EQ(peer_count(&P), (int)t_diag(dev).requests);
    if (t_cancelled - t_found < 400000) /* not held back longer than one timeout: at */
        CHECK(peer_count(&P) <= a + 3);  /* most one more request started meanwhile  */
    CHECK_EQ(mbfb_poll(0), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_poll(-7), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_poll(0x7FFFFFFF), -MBFB_E_BADHANDLE);
    CHECK_EQ(mbfb_take(12345, v, 1), -MBFB_E_BADHANDLE);
    teardown();
}

/* ---- settings conflicts, flat-argument open ------------------------------------- */
static void conflicts(void)
{
    mbfb_bus_config_t c;
    char port[200];
    int bus, dev;

    t_scenario = "conflicts";
    bus = open_bus(peer_answer, PEER_RTU, 9600, 'N', 8, 2, MBFB_FRAMING_RTU, 0, -1);
    c = t_cfg(P.link, 9600, MBFB_FRAMING_RTU, 0, 3);
    c.stop_bits = 2;
    CHECK_EQ(mbfb_bus_open(&c), bus); /* same settings (retries -1 = 3): joined */
    c.baud = 19200;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_CONFLICT);
    c.baud = 9600;
    c.framing = MBFB_FRAMING_RTU_NOCRC;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_CONFLICT);
    /* an IEC STRING body: not NUL-terminated, parity as 0/1/2 */
    size_t n = strlen(P.link);
    memcpy(port, P.link, n);
    memcpy(port + n, "XYZ", 3);
    CHECK_EQ(mbfb_bus_open_args(port, (int)n, 9600, 0, 8, 2, MBFB_FRAMING_RTU, 0, -1), bus);
    CHECK_EQ(mbfb_bus_open_args(port, (int)n, 9600, 1, 8, 2, MBFB_FRAMING_RTU, 0, -1),
             -MBFB_E_CONFLICT);
    CHECK_EQ(mbfb_bus_open_args(port, 0, 9600, 0, 8, 2, 0, 0, -1), -MBFB_E_INVAL);
    dev = mbfb_dev_open(bus, 5);
    CHECK_EQ(mbfb_dev_open(bus, 5), dev); /* blocks on one device share it */
    CHECK_EQ(peer_bytes(&P), 0);
    teardown();
}

/* ---- a port that does not exist -------------------------------------------------- */
static void no_port(void)
{
    mbfb_bus_config_t c = t_cfg("/nonexistent/ttyUSB9", 9600, MBFB_FRAMING_RTU, 0, -1);
    mbfb_diag_t d;
    int bus, dev;
    uint16_t v[1];

    t_scenario = "no port";
    bus = mbfb_bus_open(&c);
    CHECK(bus >= 0);
    dev = mbfb_dev_open(bus, 1);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), -MBFB_E_NOPORT);
    CHECK_EQ(mbfb_dev_diag(dev, &d), 0);
    CHECK_EQ(d.last_error, MBFB_E_NOPORT);
    CHECK_EQ(d.requests, 0);
    CHECK(strstr(mbfb_strerror(-MBFB_E_NOPORT), "port") != NULL);
    c = t_cfg("tcp://127.0.0.1:1", 9600, MBFB_FRAMING_TCP, 0, 0); /* nobody listens */
    dev = mbfb_dev_open(mbfb_bus_open(&c), 1);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), -MBFB_E_NOPORT);
    mbfb_shutdown();
}

/* ---- the worker does not inherit a real-time scan thread's priority --------------- */
static void *open_bus_from_rt(void *arg)
{
    mbfb_bus_config_t c = t_cfg("/nonexistent/ttyRT0", 9600, MBFB_FRAMING_RTU, 0, -1);
    *(int *)arg = mbfb_bus_open(&c);
    return NULL;
}

static void worker_priority(void)
{
    pthread_attr_t attr;
    struct sched_param prio = {0}, got = {0};
    pthread_t scan;
    int bus = -1, policy = -1;

    t_scenario = "worker priority";
    /* OpenPLC's scan thread runs SCHED_FIFO; open a bus from such a thread */
    prio.sched_priority = 30;
    pthread_attr_init(&attr);
    pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
    pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
    pthread_attr_setschedparam(&attr, &prio);
    if (pthread_create(&scan, &attr, open_bus_from_rt, &bus) != 0) {
        printf("worker priority: no permission for SCHED_FIFO here, not checked\n");
        pthread_attr_destroy(&attr);
        return;
    }
    pthread_join(scan, NULL);
    pthread_attr_destroy(&attr);
    CHECK(bus >= 0);
    if (bus >= 0) {
        CHECK_EQ(pthread_getschedparam(mbfb_buses[bus]->worker, &policy, &got), 0);
        CHECK_EQ(policy, SCHED_OTHER);
        CHECK_EQ(got.sched_priority, 0);
    }
    mbfb_shutdown();
}

/* ---- port lost (USB adapter pulled) and back ------------------------------------- */
static int mute; /* __atomic */
static void mutable_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    if (!__atomic_load_n(&mute, __ATOMIC_ACQUIRE))
        peer_answer(p, n, f, len, r);
}

static void port_lost(void)
{
    int bus, dev, h[3];
    uint16_t v[1], wval[1] = {33};

    t_scenario = "port lost";
    __atomic_store_n(&mute, 0, __ATOMIC_RELEASE);
    bus = open_bus(mutable_peer, PEER_RTU, 38400, 'N', 8, 1, MBFB_FRAMING_RTU, 2000, 3);
    dev = mbfb_dev_open(bus, 1);
    peer_set_reg(&P, 1, 0, 11);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 11);
    __atomic_store_n(&mute, 1, __ATOMIC_RELEASE); /* the next request stays on the wire... */
    h[0] = mbfb_post(dev, 6, 0, 1, wval); /* a write: it may be applied before the port goes */
    for (int i = 1; i < 3; i++)
        h[i] = mbfb_post(dev, 3, 0, 1, NULL);
    for (int i = 0; i < 30000 && mbfb_poll(h[0]) == MBFB_REQ_QUEUED; i++)
        t_sleep_ms(1); /* until the worker has it (4 x 2 s of attempts follow) */
    CHECK_EQ(mbfb_poll(h[0]), MBFB_REQ_ACTIVE);
    peer_stop(&P); /* ...when the port goes away */
    for (int i = 0; i < 3; i++) { /* in flight and queued: all end, none silently; the */
        CHECK_EQ(t_wait(h[i]), MBFB_REQ_FAILED); /* write on the wire is not "failed": */
        CHECK_EQ(mbfb_take(h[i], v, 1), i == 0 ? -MBFB_E_UNCONFIRMED : -MBFB_E_PORTLOST);
    }
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), -MBFB_E_NOPORT); /* still gone */
    __atomic_store_n(&mute, 0, __ATOMIC_RELEASE);
    peer_start(&P, link_path(), PEER_RTU, mutable_peer, NULL); /* plugged back */
    peer_set_reg(&P, 1, 0, 22);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1); /* reopened on the next request */
    CHECK_EQ(v[0], 22);
    teardown();
}

/* ---- several devices, one dead: back-off keeps the bus for the others -------------- */
static void dead_device(void)
{
    int bus, d1, d2, d3, good1 = 0, good3 = 0, offline2 = 0, iters = 40, extra;
    int64_t end, t0;
    mbfb_diag_t dg;
    uint16_t v[1];

    t_scenario = "dead device";
    bus = open_bus(peer_answer, PEER_RTU, 38400, 'N', 8, 1, MBFB_FRAMING_RTU, 200, 3);
    d1 = mbfb_dev_open(bus, 1);
    d2 = mbfb_dev_open(bus, 2);
    d3 = mbfb_dev_open(bus, 3);
    peer_set_dead(&P, 2, 1);
    t0 = t_now_us();
    for (int i = 0; i < iters; i++) {
        int h1 = mbfb_post(d1, 3, 0, 1, NULL), h2 = mbfb_post(d2, 3, 0, 1, NULL),
            h3 = mbfb_post(d3, 3, 0, 1, NULL);
        t_wait(h1), t_wait(h2), t_wait(h3);
        good1 += mbfb_take(h1, v, 1) == 1;
        offline2 += mbfb_take(h2, v, 1) == -MBFB_E_OFFLINE;
        good3 += mbfb_take(h3, v, 1) == 1;
    }
    CHECK_EQ(good1, iters);
    CHECK_EQ(good3, iters);
    CHECK_EQ(peer_slave_count(&P, 1), iters); /* the healthy ones never needed a retry */
    CHECK_EQ(peer_slave_count(&P, 3), iters);
    /* without back-off slave 2 would have had iters * 4 = 160 frames; with it: the
     * request and one resync read (FC04: the only other reply shape of a one-register
     * window); then no reply shape is left that its late reply could not match, so it
     * gets no bus time for MBFB_LATE_MAX_MS (new behaviour, README "Late replies") */
    /* (the rounds take milliseconds; if this machine stretched them past
     * MBFB_LATE_MAX_MS, the shapes expired and a few more probes were due: allowed) */
    extra = 4 * (int)((t_now_us() - t0) / ((int64_t)MBFB_LATE_MAX_MS * 1000));
    CHECK(peer_slave_count(&P, 2) <= 3 * 4 + 4 + extra);
    CHECK(peer_slave_count(&P, 2) >= 2);
    CHECK(offline2 >= iters - 3 - 4 - extra);
    CHECK_EQ(mbfb_dev_diag(d2, &dg), 0);
    CHECK_EQ(dg.offline, 1);
    CHECK_EQ(dg.good, 0);
    printf("dead device: %d frames to the dead slave over %d rounds (%d without back-off)\n",
           peer_slave_count(&P, 2), iters, iters * 4);
    /* it comes back by itself when it answers again */
    peer_set_dead(&P, 2, 0);
    peer_set_reg(&P, 2, 0, 77);
    end = t_now_us() + 30000000;
    while (t_now_us() < end && t_run(d2, 3, 0, 1, NULL, v, 1) != 1)
        t_sleep_ms(50);
    CHECK_EQ(v[0], 77);
    CHECK_EQ(mbfb_dev_diag(d2, &dg), 0);
    CHECK_EQ(dg.offline, 0);
    /* 3: the probe (its newest outstanding shape read again: the answer shows it is back,
     * its data is not used), a resync read of a free shape, then the request; 1 or 2 on a
     * machine so slow that its shapes had expired (no probe shape is left: the request is
     * its own resync read, or a resync read of another shape goes first) */
    CHECK(dg.good >= 1 && dg.good <= 3);
    CHECK_EQ(t_run(d2, 3, 0, 1, NULL, v, 1), 1);
    teardown();
}

/* ---- one physical port, one bus; bauds the driver cannot set ------------------- */
static void port_identity(void)
{
    char alias[200], slashes[220], dotted[220];
    mbfb_bus_config_t c;
    int bus;

    t_scenario = "port identity";
    bus = open_bus(peer_answer, PEER_RTU, 9600, 'N', 8, 1, MBFB_FRAMING_RTU, 0, -1);
    CHECK(bus >= 0);
    snprintf(alias, sizeof alias, "%s/alias", t_tmpdir()); /* a by-id style symlink */
    unlink(alias);
    CHECK_EQ(symlink(P.link, alias), 0);
    snprintf(slashes, sizeof slashes, "/%s", P.link); /* //tmp/... */
    snprintf(dotted, sizeof dotted, "%s/./port", t_tmpdir());
    const char *names[] = {alias, slashes, dotted};
    for (int i = 0; i < 3; i++) {
        c = t_cfg(names[i], 9600, MBFB_FRAMING_RTU, 0, -1);
        CHECK_EQ(mbfb_bus_open(&c), bus); /* same node: same bus */
        c.baud = 19200;
        CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_CONFLICT);
    }
    /* a port that does not exist yet: its normalised path */
    c = t_cfg("/nonexistent//ttyX0", 9600, MBFB_FRAMING_RTU, 0, -1);
    bus = mbfb_bus_open(&c);
    c.port = "/nonexistent/./ttyX0";
    CHECK_EQ(mbfb_bus_open(&c), bus);
    /* a rate no Linux UART driver offers is refused before anything opens; the others
     * (also those outside libmodbus's table, set with termios2: test_baud.py) are accepted */
    c = t_cfg(P.link, 4000001, MBFB_FRAMING_RTU, 0, -1);
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_BAUD);
    CHECK_EQ(mbfb_bus_open_args("/dev/ttyS9", 10, 4000001, 0, 8, 1, 0, 0, -1), -MBFB_E_BAUD);
    CHECK(mbfb_bus_open_args("/dev/ttyS9", 10, 28800, 0, 8, 1, 0, 0, -1) >= 0);
    CHECK(strstr(mbfb_strerror(-MBFB_E_BAUD), "baud") != NULL);
    CHECK(strstr(mbfb_strerror(MBFB_E_UNCONFIRMED), "unconfirmed") != NULL);
    unlink(alias);
    CHECK_EQ(peer_bytes(&P), 0);
    teardown();
}

int main(void)
{
    /* each with the latency rerun (t_scenarios): its peer's timings hold only on time */
    static const t_case_t cases[] = {
        T_CASE(port_identity),
        T_CASE(manual_rtu),
        T_CASE(manual_ascii),
        T_CASE(manual_nocrc),
        T_CASE(broadcast),
        T_CASE(bad_args),
        T_CASE(queue_cancel_handles),
        T_CASE(conflicts),
        T_CASE(no_port),
        T_CASE(worker_priority),
        T_CASE(port_lost),
        T_CASE(dead_device),
    };
    return t_scenarios("test_bus", cases, (int)(sizeof cases / sizeof cases[0]));
}
