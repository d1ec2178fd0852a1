/*
 * mbfb_test_peer.c - assertion helpers and the scripted peer (see mbfb_test.h) on its line
 * (testline.c).
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "mbfb_test.h"
#include "testline.h"

/* 3.10 FDC Example 1: FC16 download of 52 words (113 bytes, CRC 0xC38E sent 8E C3). */
const char *const fdc_ex1 =
    "01 10 00 00 00 34 68 4F19 4E83 4E83 0000 0001 0000 0001 4D6D 51C4 4D6D 6321 4E1F "
    "0002 0000 0064 0064 00FA 0000 0000 4E1F 0001 00B4 00FA 0000 0000 0002 4E1F 0000 "
    "4E1F 0001 00B4 0064 4E1F 0002 5207 0000 0001 0000 0001 0001 0002 0001 0000 0000 "
    "0002 0003 0004 0006 0007 0008 000A 0011 8E C3";

int t_failures;
const char *t_scenario = "";
static peer_t *last_peer;    /* the peer started last: its log is printed on a failure */
static int64_t case_t0;      /* when the scenario began (t_serial_scenarios)            */
static int case_no, dumped_case = -1;

static int64_t lat_max_us;   /* __atomic: the latest a thread of the test was since the
                                scenario began (t_note_late; run_case)                */

/* ---- the tests' priority ------------------------------------------------------------
 * The scenarios hold replies against reply timeouts of 100 ms and more, and the peer
 * stands for a device, which has a CPU of its own: neither side's timing may hang on what
 * else the machine runs (two busy loops beside the suite made threads of these tests up to
 * 3.7 s late). So, as OpenPLC puts its scan thread at SCHED_FIFO, each test asks the
 * kernel for precedence over ordinary processes before any of its threads starts: nice
 * MBFB_TEST_NICE (default T_NICE; every thread started later, the bus workers included,
 * inherits it; "0" leaves the priority alone). Where that is not allowed (no
 * CAP_SYS_NICE), one line says so and the test runs as it is: the latency rerun
 * (t_serial_scenarios) then stands between a loaded machine and a failure. Compare
 * tests/timed.py, the same for the Python tests' processes. */
#define T_NICE (-10)
__attribute__((constructor)) static void t_priority(void)
{
    const char *want = getenv("MBFB_TEST_NICE");
    int nice = want != NULL && want[0] != '\0' ? atoi(want) : T_NICE;
    if (nice != 0 && setpriority(PRIO_PROCESS, 0, nice) != 0)
        fprintf(stderr, "note: nice %d not allowed here (%s): this test's timings share the "
                "machine with everything else\n", nice, strerror(errno));
}

/* ---- assertions ------------------------------------------------------------ */
void t_note_late(int64_t us)
{
    int64_t max = __atomic_load_n(&lat_max_us, __ATOMIC_RELAXED);
    while (us > max && !__atomic_compare_exchange_n(&lat_max_us, &max, us, 0, __ATOMIC_RELAXED,
                                                    __ATOMIC_RELAXED)) {
    }
}

int t_hex(const char *hex, uint8_t *out)
{
    int n = 0, hi = -1;
    for (; *hex; hex++) {
        int c = *hex, v;
        if (c >= '0' && c <= '9')
            v = c - '0';
        else if (c >= 'A' && c <= 'F')
            v = c - 'A' + 10;
        else if (c >= 'a' && c <= 'f')
            v = c - 'a' + 10;
        else
            continue;
        if (hi < 0) {
            hi = v;
        } else {
            out[n++] = (uint8_t)(hi << 4 | v);
            hi = -1;
        }
    }
    return n;
}

void t_check_hex(const char *file, int line, const uint8_t *buf, int len, const char *hex)
{
    uint8_t want[PEER_BUF];
    int n = t_hex(hex, want);
    if (n != len || memcmp(buf, want, (size_t)n) != 0) {
        t_failures++;
        fprintf(stderr, "FAIL %s:%d [%s]: bytes differ\n  got :", file, line, t_scenario);
        for (int i = 0; i < len; i++)
            fprintf(stderr, " %02X", buf[i]);
        fprintf(stderr, "\n  want: %s\n", hex);
    }
}

void t_failed(void)
{
    peer_t *p = last_peer;
    if (p == NULL || dumped_case == case_no)
        return;
    dumped_case = case_no;
    pthread_mutex_lock(&p->lock);
    int64_t t0 = case_t0 ? case_t0 : p->t_us[0]; /* outside a scenario: the first request */
    fprintf(stderr, "  the peer's log [%s], ms since the scenario began:\n", t_scenario);
    for (int i = 0; i < p->n && i < PEER_LOG; i++) {
        fprintf(stderr, "    #%d request at %8.1f:", i, (double)(p->t_us[i] - t0) / 1e3);
        for (int k = 0; k < p->raw_len[i] && k < 8; k++)
            fprintf(stderr, " %02X", p->raw[i][k]);
        if (p->t_reply_us[i])
            fprintf(stderr, "%s  reply of %d bytes at %8.1f\n", p->raw_len[i] > 8 ? " .." : "",
                    p->reply_len[i], (double)(p->t_reply_us[i] - t0) / 1e3);
        else
            fprintf(stderr, "%s  no reply (yet)\n", p->raw_len[i] > 8 ? " .." : "");
    }
    pthread_mutex_unlock(&p->lock);
}

int t_done(const char *name)
{
    if (t_failures)
        fprintf(stderr, "%s: %d check(s) FAILED\n", name, t_failures);
    else
        printf("%s: all checks passed\n", name);
    return t_failures ? 1 : 0;
}

/* ---- time ------------------------------------------------------------------ */
int64_t t_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

void t_sleep_us(long us)
{
    struct timespec ts = {us / 1000000, (us % 1000000) * 1000L};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

void t_sleep_ms(int ms)
{
    t_sleep_us((long)ms * 1000);
}

void t_stop_child(pid_t pid)
{
    if (pid > 0) {
        kill(pid, SIGTERM);
        waitpid(pid, NULL, 0);
    }
}

/* Under $TMPDIR when it is set and short (test.sh points it into the build tree, so a run
 * leaves nothing in /tmp and parallel runs do not meet), else under /tmp. Short, because
 * the links and sockets made in it must fit their buffers (peer_t.link, sun_path). */
#define TMPDIR_MAX 64
static char tmp_dir[TMPDIR_MAX + 32];

/* At exit: remove what the tests put in the temporary directory (lines' names), then it. */
static void remove_tmpdir(void)
{
    DIR *d = opendir(tmp_dir);
    struct dirent *e;
    char path[sizeof tmp_dir + 260];

    if (d != NULL) {
        while ((e = readdir(d)) != NULL) {
            if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
                continue;
            snprintf(path, sizeof path, "%s/%s", tmp_dir, e->d_name);
            unlink(path);
        }
        closedir(d);
    }
    rmdir(tmp_dir);
}

const char *t_tmpdir(void)
{
    if (!tmp_dir[0]) {
        const char *base = getenv("TMPDIR");
        if (base == NULL || base[0] != '/' || strlen(base) > TMPDIR_MAX)
            base = "/tmp";
        snprintf(tmp_dir, sizeof tmp_dir, "%s/mbfb_test_XXXXXX", base);
        if (mkdtemp(tmp_dir) == NULL) {
            perror("mkdtemp");
            exit(2);
        }
        atexit(remove_tmpdir);
    }
    return tmp_dir;
}

/* ---- CRC / LRC (independent of c_shims) ---------------------------------------- */
uint16_t peer_crc16(const uint8_t *buf, int len)
{
    static uint16_t table[256];
    uint16_t crc = 0xFFFF;
    if (table[1] == 0) { /* table-driven, unlike the shims' bitwise one */
        for (int i = 0; i < 256; i++) {
            uint16_t c = (uint16_t)i;
            for (int b = 0; b < 8; b++)
                c = (c & 1) ? (uint16_t)((c >> 1) ^ 0xA001) : (uint16_t)(c >> 1);
            table[i] = c;
        }
    }
    for (int i = 0; i < len; i++)
        crc = (uint16_t)((crc >> 8) ^ table[(crc ^ buf[i]) & 0xFF]);
    return crc;
}

uint8_t peer_lrc(const uint8_t *buf, int len)
{
    unsigned sum = 0;
    for (int i = 0; i < len; i++)
        sum += buf[i];
    return (uint8_t)((0x100 - (sum & 0xFF)) & 0xFF);
}

/* ---- the peer --------------------------------------------------------------- */
static int read_byte(peer_t *p, uint8_t *b, int wait_ms)
{
    struct pollfd pf = {p->line, POLLIN, 0};
    if (poll(&pf, 1, wait_ms) <= 0)
        return 0;
    return read(p->line, b, 1) == 1;
}

/* Read one request: RTU by its length rules, ASCII up to LF. Returns its length,
 * 0 if none started (checks stop every 20 ms). */
static int read_request(peer_t *p, uint8_t *buf)
{
    int n = 0, need = 2;
    while (n == 0) {
        if (__atomic_load_n(&p->stop, __ATOMIC_ACQUIRE))
            return 0;
        if (read_byte(p, buf, 20))
            n = 1;
    }
    while (n < PEER_BUF) {
        if (p->mode == PEER_ASCII && buf[n - 1] == '\n')
            return n;
        if (p->mode == PEER_RTU && n >= need) {
            int fc = buf[1];
            if (fc >= 1 && fc <= 6)
                need = 8;
            else if (fc == 15 || fc == 16)
                need = n >= 7 ? 9 + buf[6] : 7;
            else
                need = PEER_BUF; /* unknown: until silence */
            if (n >= need)
                return n;
        }
        if (!read_byte(p, buf + n, 100))
            return n; /* silence: deliver what came */
        n++;
    }
    return n;
}

static int decode(peer_t *p, const uint8_t *raw, int len, uint8_t *frame)
{
    if (p->mode == PEER_RTU) {
        if (len <= 2)
            return 0;
        memcpy(frame, raw, (size_t)(len - 2));
        return len - 2;
    }
    char hex[PEER_BUF + 1];
    if (len < 5 || raw[0] != ':')
        return 0;
    memcpy(hex, raw + 1, (size_t)(len - 3)); /* between ':' and CR LF */
    hex[len - 3] = 0;
    return t_hex(hex, frame) - 1; /* without the LRC */
}

static void write_all(peer_t *p, const uint8_t *buf, int len)
{
    if (len > 0 && write(p->line, buf, (size_t)len) != len)
        fprintf(stderr, "peer: short write\n");
}

/* Discard what came in while a deaf reply kept the device busy (peer_reply_t.deaf). */
static void discard_input(peer_t *p)
{
    for (;;) {
        uint8_t junk[64];
        struct pollfd pf = {p->line, POLLIN, 0};
        ssize_t k;
        if (poll(&pf, 1, 0) <= 0 || (k = read(p->line, junk, sizeof junk)) <= 0)
            return;
        __atomic_fetch_add(&p->ignored, (long)k, __ATOMIC_RELAXED);
    }
}

/* Send a reply, at once or paced; a request byte waiting before a paced byte goes out
 * means the master talked while this reply was still on the line. A deaf reply discards
 * the input right before each write: the device is busy until its reply is out, and
 * hears what comes after it (a master's next request, sent on hearing the reply, is
 * never thrown away, however late this thread runs). */
static void peer_write(peer_t *p, const peer_reply_t *r)
{
    __atomic_store_n(&p->reply_sent, 0, __ATOMIC_RELEASE);
    if (r->pace_us <= 0) {
        if (r->deaf)
            discard_input(p);
        write_all(p, r->out, r->len);
        __atomic_store_n(&p->reply_sent, r->len, __ATOMIC_RELEASE);
        return;
    }
    for (int i = 0; i < r->len; i++) {
        struct pollfd pf = {p->line, POLLIN, 0};
        if (r->deaf)
            discard_input(p);
        else if (i > 0 && poll(&pf, 1, 0) > 0)
            __atomic_fetch_add(&p->collisions, 1, __ATOMIC_RELAXED);
        write_all(p, r->out + i, 1);
        __atomic_fetch_add(&p->reply_sent, 1, __ATOMIC_RELEASE);
        if (i + 1 < r->len)
            t_sleep_us(r->pace_us);
    }
}

static void *peer_main(void *arg)
{
    peer_t *p = (peer_t *)arg;
    uint8_t raw[PEER_BUF], frame[PEER_BUF];
    while (!__atomic_load_n(&p->stop, __ATOMIC_ACQUIRE)) {
        peer_reply_t r;
        int len = read_request(p, raw), flen, n;
        if (len <= 0)
            continue;
        flen = decode(p, raw, len, frame);
        pthread_mutex_lock(&p->lock);
        n = p->n++;
        p->bytes += len;
        if (flen > 0)
            p->per_slave[frame[0]]++;
        if (n < PEER_LOG) {
            memcpy(p->raw[n], raw, (size_t)len);
            p->raw_len[n] = len;
            p->t_us[n] = t_now_us();
        }
        pthread_mutex_unlock(&p->lock);
        memset(&r, 0, sizeof r);
        if (flen > 0 && p->fn)
            p->fn(p, n, frame, flen, &r);
        int64_t due = t_now_us() + (int64_t)r.delay_ms * 1000; /* when the script writes */
        if (r.delay_ms)
            t_sleep_ms(r.delay_ms);
        for (int i = 0; r.hold && i < 10000 && !__atomic_exchange_n(&p->released, 0,
                                                                    __ATOMIC_ACQ_REL); i++)
            t_sleep_ms(1);
        for (int i = 0; r.until_input && i < 500 && !__atomic_load_n(&p->stop, __ATOMIC_ACQUIRE);
             i++) { /* woken by the input itself: no polling delay a loaded machine stretches */
            struct pollfd pf = {p->line, POLLIN, 0};
            if (poll(&pf, 1, 20) > 0)
                break;
        }
        if (r.hold || r.until_input)
            due = t_now_us();           /* released now: only its pace can be late */
        peer_write(p, &r);
        if (r.len > 0) /* how much later than its script the reply was out */
            t_note_late(t_now_us() - due - (r.pace_us > 0 ? (int64_t)(r.len - 1) * r.pace_us : 0));
        if (r.len > 0 && n < PEER_LOG) {
            pthread_mutex_lock(&p->lock);
            p->t_reply_us[n] = t_now_us();
            p->reply_len[n] = r.len;
            pthread_mutex_unlock(&p->lock);
        }
    }
    return NULL;
}

int peer_start(peer_t *p, const char *link, int mode, peer_fn fn, void *user)
{
    memset(p, 0, sizeof *p);
    snprintf(p->link, sizeof p->link, "%s", link);
    if (tl_make(link, &p->line) != 0)
        return -1;
    p->mode = mode;
    p->fn = fn;
    p->user = user;
    pthread_mutex_init(&p->lock, NULL);
    last_peer = p;
    return pthread_create(&p->th, NULL, peer_main, p) == 0 ? 0 : -1;
}

static void *babble_main(void *arg)
{
    peer_t *p = (peer_t *)arg;
    for (long i = 0; !__atomic_load_n(&p->babble_stop, __ATOMIC_ACQUIRE) &&
                     (p->babble_max == 0 || i < p->babble_max);
         i++) {
        write_all(p, &p->pattern[i % p->pattern_len], 1);
        __atomic_fetch_add(&p->babbled, 1, __ATOMIC_RELEASE);
        t_sleep_us(p->interval_us);
    }
    return NULL;
}

int peer_babble_start(peer_t *p, const uint8_t *pattern, int len, int interval_us, long max)
{
    if (p->babbling || len <= 0 || len > (int)sizeof p->pattern)
        return -1;
    memcpy(p->pattern, pattern, (size_t)len);
    p->pattern_len = len;
    p->interval_us = interval_us;
    p->babble_max = max;
    __atomic_store_n(&p->babbled, 0, __ATOMIC_RELEASE);
    __atomic_store_n(&p->babble_stop, 0, __ATOMIC_RELEASE);
    if (pthread_create(&p->babbler, NULL, babble_main, p) != 0)
        return -1;
    p->babbling = 1;
    return 0;
}

long peer_babble_stop(peer_t *p)
{
    if (p->babbling) {
        if (p->babble_max == 0)
            __atomic_store_n(&p->babble_stop, 1, __ATOMIC_RELEASE);
        pthread_join(p->babbler, NULL);
        p->babbling = 0;
    }
    return peer_babbled(p);
}

long peer_babbled(peer_t *p)
{
    return __atomic_load_n(&p->babbled, __ATOMIC_ACQUIRE);
}

int peer_collisions(peer_t *p)
{
    return __atomic_load_n(&p->collisions, __ATOMIC_RELAXED);
}

int peer_reply_sent(peer_t *p)
{
    return __atomic_load_n(&p->reply_sent, __ATOMIC_ACQUIRE);
}

int peer_pending(peer_t *p)
{
    int n = 0;
    return ioctl(p->line, FIONREAD, &n) == 0 ? n : -1;
}

void peer_release(peer_t *p)
{
    __atomic_store_n(&p->released, 1, __ATOMIC_RELEASE);
}

void peer_stop(peer_t *p)
{
    __atomic_store_n(&p->babble_stop, 1, __ATOMIC_RELEASE);
    peer_babble_stop(p);
    __atomic_store_n(&p->stop, 1, __ATOMIC_RELEASE);
    pthread_join(p->th, NULL);
    tl_drop(p->link, p->line); /* the port disappears, as a pulled USB adapter's node does */
    p->line = -1;
}

/* One of the peer's counters (an int, or else a long), read under its lock. */
static long locked_count(peer_t *p, const int *i, const long *l)
{
    long n;
    pthread_mutex_lock(&p->lock);
    n = i != NULL ? *i : *l;
    pthread_mutex_unlock(&p->lock);
    return n;
}

int peer_count(peer_t *p)
{
    return (int)locked_count(p, &p->n, NULL);
}

int peer_count_reaching(peer_t *p, int n)
{
    for (int64_t end = t_now_us() + 2000000; peer_count(p) < n && t_now_us() < end;)
        t_sleep_ms(1);
    return peer_count(p);
}

long peer_bytes(peer_t *p)
{
    return locked_count(p, NULL, &p->bytes);
}

int peer_slave_count(peer_t *p, int slave)
{
    return (int)locked_count(p, &p->per_slave[slave & 255], NULL);
}

int peer_raw(peer_t *p, int i, uint8_t *out)
{
    int n = 0;
    pthread_mutex_lock(&p->lock);
    if (i >= 0 && i < p->n && i < PEER_LOG) {
        n = p->raw_len[i];
        memcpy(out, p->raw[i], (size_t)n);
    }
    pthread_mutex_unlock(&p->lock);
    return n;
}

int64_t peer_time(peer_t *p, int i)
{
    int64_t t = 0;
    pthread_mutex_lock(&p->lock);
    if (i >= 0 && i < p->n && i < PEER_LOG)
        t = p->t_us[i];
    pthread_mutex_unlock(&p->lock);
    return t;
}

/* ---- replies --------------------------------------------------------------- */
void peer_reply_raw(peer_reply_t *r, const uint8_t *bytes, int len)
{
    if (r->len + len <= PEER_BUF) {
        memcpy(r->out + r->len, bytes, (size_t)len);
        r->len += len;
    }
}

void peer_reply_frame(peer_t *p, peer_reply_t *r, const uint8_t *frame, int len)
{
    uint8_t buf[PEER_BUF];
    int n = 0;
    if (p->mode == PEER_RTU) {
        uint16_t crc = peer_crc16(frame, len);
        memcpy(buf, frame, (size_t)len);
        n = len;
        buf[n++] = (uint8_t)(crc & 0xFF);
        buf[n++] = (uint8_t)(crc >> 8);
    } else {
        uint8_t lrc = peer_lrc(frame, len);
        n = sprintf((char *)buf, ":");
        for (int i = 0; i < len; i++)
            n += sprintf((char *)buf + n, "%02X", frame[i]);
        n += sprintf((char *)buf + n, "%02X\r\n", lrc);
    }
    peer_reply_raw(r, buf, n);
}

void peer_reply_hex(peer_t *p, peer_reply_t *r, const char *frame_hex)
{
    uint8_t f[PEER_BUF];
    peer_reply_frame(p, r, f, t_hex(frame_hex, f));
}

void peer_answer(peer_t *p, int n, const uint8_t *f, int flen, peer_reply_t *r)
{
    int slave = f[0], fc = f[1], addr = f[2] << 8 | f[3], cnt = f[4] << 8 | f[5];
    uint16_t *regs = p->regs[slave & 7];
    uint8_t out[PEER_BUF];
    int k = 0;
    (void)n;
    pthread_mutex_lock(&p->lock); /* the test thread changes regs and dead */
    if (flen < 6 || p->dead[slave] || slave == 0) {
        pthread_mutex_unlock(&p->lock);
        return;
    }
    out[k++] = (uint8_t)slave;
    out[k++] = (uint8_t)fc;
    if ((fc == 1 || fc == 2 || fc == 15) && addr + cnt > 256) {
        out[1] = (uint8_t)(fc | 0x80); /* past its bits */
        out[k++] = 2;
    } else if (fc == 1 || fc == 2) { /* packed here, LSB first (Modbus 1.1b3, 6.1) */
        const uint8_t *bank = fc == 1 ? p->coils[slave & 7] : p->inputs[slave & 7];
        int nbytes = (cnt + 7) / 8;
        out[k++] = (uint8_t)nbytes;
        memset(out + k, 0, (size_t)nbytes);
        for (int i = 0; i < cnt; i++)
            if (bank[addr + i])
                out[k + i / 8] |= (uint8_t)(1 << (i % 8));
        k += nbytes;
    } else if (fc == 5 && (cnt == 0xFF00 || cnt == 0)) {
        p->coils[slave & 7][addr & 255] = cnt == 0xFF00;
        memcpy(out + k, f + 2, 4);
        k += 4;
    } else if (fc == 15) {
        for (int i = 0; i < cnt; i++)
            p->coils[slave & 7][addr + i] = (f[7 + i / 8] >> (i % 8)) & 1;
        memcpy(out + k, f + 2, 4);
        k += 4;
    } else if (fc == 3 || fc == 4) {
        out[k++] = (uint8_t)(2 * cnt);
        for (int i = 0; i < cnt; i++) {
            out[k++] = (uint8_t)(regs[(addr + i) & 255] >> 8);
            out[k++] = (uint8_t)regs[(addr + i) & 255];
        }
    } else if (fc == 6 || fc == 16) {
        if (fc == 6)
            regs[addr & 255] = (uint16_t)cnt;
        else
            for (int i = 0; i < cnt; i++)
                regs[(addr + i) & 255] = (uint16_t)(f[7 + 2 * i] << 8 | f[8 + 2 * i]);
        memcpy(out + k, f + 2, 4);
        k += 4;
    } else {
        out[1] = (uint8_t)(fc | 0x80);
        out[k++] = 1;
    }
    pthread_mutex_unlock(&p->lock);
    peer_reply_frame(p, r, out, k);
}

void peer_answer_late_deaf(peer_t *p, int n, const uint8_t *frame, int flen, peer_reply_t *r,
                           int late_n, int delay_ms)
{
    peer_answer(p, n, frame, flen, r);
    if (n == late_n) {
        r->delay_ms = delay_ms;
        r->deaf = 1; /* written at once: no pause inside it that a loaded machine could
                        stretch into a silence, splitting it into two frames */
    }
}

void peer_set_reg(peer_t *p, int slave, int addr, uint16_t value)
{
    pthread_mutex_lock(&p->lock);
    p->regs[slave & 7][addr & 255] = value;
    pthread_mutex_unlock(&p->lock);
}

void peer_set_bit(peer_t *p, int fc, int slave, int addr, int on)
{
    pthread_mutex_lock(&p->lock);
    (fc == 1 ? p->coils : p->inputs)[slave & 7][addr & 255] = (uint8_t)(on != 0);
    pthread_mutex_unlock(&p->lock);
}

int peer_coil(peer_t *p, int slave, int addr)
{
    int v;
    pthread_mutex_lock(&p->lock);
    v = p->coils[slave & 7][addr & 255];
    pthread_mutex_unlock(&p->lock);
    return v;
}

void peer_set_dead(peer_t *p, int slave, int dead)
{
    pthread_mutex_lock(&p->lock);
    p->dead[slave & 255] = dead;
    pthread_mutex_unlock(&p->lock);
}

/* ---- shim helpers -------------------------------------------------------------- */
int t_wait(int req)
{
    int64_t end = t_now_us() + 30000000;
    int st;
    while ((st = mbfb_poll(req)) == MBFB_REQ_QUEUED || st == MBFB_REQ_ACTIVE) {
        if (t_now_us() > end)
            break;
        t_sleep_ms(1);
    }
    return st;
}

int t_run(int dev, int fc, int addr, int count, const uint16_t *vals, uint16_t *out, int max)
{
    int h = mbfb_post(dev, fc, addr, count, vals);
    if (h < 0)
        return h;
    t_wait(h);
    return mbfb_take(h, out, max);
}

int t_run_write(int dev, int fc, int addr, int count, const uint16_t *vals, int policy)
{
    int h = mbfb_post_write(dev, fc, addr, count, vals, policy);
    if (h < 0)
        return h;
    t_wait(h);
    return mbfb_take(h, NULL, 0);
}

mbfb_bus_config_t t_cfg(const char *port, int baud, int framing, int timeout_ms, int retries)
{
    mbfb_bus_config_t c;
    memset(&c, 0, sizeof c);
    c.port = port;
    c.baud = baud;
    c.parity = 'N';
    c.data_bits = 8;
    c.stop_bits = 1;
    c.framing = framing;
    c.response_timeout_ms = timeout_ms;
    c.retries = retries;
    return c;
}

int t_serial_dev(peer_t *p, peer_fn fn, int framing, int baud, int timeout_ms, int retries)
{
    char link[160];
    mbfb_bus_config_t c;
    int bus;

    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(p, link, framing == MBFB_FRAMING_ASCII ? PEER_ASCII : PEER_RTU, fn,
                   NULL) != 0) {
        perror("peer_start");
        return -1;
    }
    for (int i = 0; i < 256; i++)
        peer_set_reg(p, 1, i, (uint16_t)(0x1000 + i));
    c = t_cfg(p->link, baud, framing, timeout_ms, retries);
    if (framing == MBFB_FRAMING_ASCII) { /* the Modbus ASCII default: 7E1 */
        c.data_bits = 7;
        c.parity = 'E';
    }
    bus = mbfb_bus_open(&c);
    CHECK(bus >= 0);
    return mbfb_dev_open(bus, 1);
}

mbfb_diag_t t_diag(int dev)
{
    mbfb_diag_t d;
    memset(&d, 0xEE, sizeof d);
    CHECK_EQ(mbfb_dev_diag(dev, &d), 0);
    return d;
}

void t_pymodbus_conversation(int dev)
{
    uint16_t v[4];
    CHECK_EQ(t_run(dev, 3, 10, 3, NULL, v, 4), 3);
    CHECK_EQ(v[0], 0x300B);
    CHECK_EQ(v[2], 0x300D);
    CHECK_EQ(t_run(dev, 4, 20, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 0x4015);
    v[0] = 0xBEEF;
    CHECK_EQ(t_run(dev, 6, 5, 1, v, NULL, 0), 0);
    v[0] = 0x1234, v[1] = 0x5678;
    CHECK_EQ(t_run(dev, 16, 30, 2, v, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 3, 5, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 0xBEEF);
    CHECK_EQ(t_run(dev, 3, 30, 2, NULL, v, 2), 2);
    CHECK_EQ(v[0], 0x1234);
    CHECK_EQ(v[1], 0x5678);
    CHECK_EQ(t_run(dev, 3, 1000, 1, NULL, v, 1), -(MBFB_E_EXCEPTION_BASE + 2));
    /* coils and discrete inputs: read, written (FC05, FC15), read back */
    CHECK_EQ(t_run(dev, 1, 3, 37, NULL, v, 4), 37);
    for (int i = 0; i < 37; i++)
        CHECK_EQ((v[i / 16] >> (i % 16)) & 1, T_PM_COIL(3 + i));
    CHECK_EQ(v[2] >> 5, 0); /* the bits past the count are 0 */
    CHECK_EQ(t_run(dev, 2, 10, 22, NULL, v, 2), 22);
    for (int i = 0; i < 22; i++)
        CHECK_EQ((v[i / 16] >> (i % 16)) & 1, T_PM_INPUT(10 + i));
    v[0] = 1; /* ON */
    CHECK_EQ(t_run(dev, 5, 40, 1, v, NULL, 0), 0);
    v[0] = 0x01CD, v[1] = 0xFFFF; /* 10 coils: CD 01 on the wire; v[1] beyond them */
    CHECK_EQ(t_run(dev, 15, 20, 10, v, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 1, 20, 21, NULL, v, 2), 21);
    CHECK_EQ(v[0] & 0x3FF, 0x01CD);
    CHECK_EQ((v[1] >> 4) & 1, 1); /* coil 40 */
    /* past its coils pymodbus 3.8 answers "01 01 00": a byte count of 0 for 8 coils, which
     * the shims refuse (a later pymodbus may answer exception 2); never data */
    v[0] = 0x5555;
    int rc = t_run(dev, 1, 1000, 8, NULL, v, 1);
    CHECK(rc == -MBFB_E_BADREPLY || rc == -(MBFB_E_EXCEPTION_BASE + 2));
    CHECK_EQ(v[0], 0x5555);
    CHECK_EQ(t_run(dev, 1, 0, 1, NULL, v, 1), 1); /* and the line goes on */
}

int t_read_reply_bytes(int framing, int nregs)
{
    int frame = 3 + 2 * nregs; /* slave, function, byte count, data */
    return framing == MBFB_FRAMING_ASCII ? 1 + 2 * (frame + 1) + 2 : frame + 2;
}

/* ---- the machine's latency during a scenario -------------------------------------
 * The scenarios' timings (reply timeouts of 100 ms and more, late replies, pauses) hold only
 * while the process's threads run when they wake (the line's bytes are the process's own:
 * testline.c). A monitor thread sleeps LAT_TICK_US at a time and notes how much it overslept
 * (as cyclictest measures scheduling latency); the peer notes how much later than its
 * script each reply was out, a paced one included (many short sleeps, each a little late,
 * add up). A scenario that failed while one of them was later than MBFB_TEST_LATENCY_MS
 * (default LAT_LIMIT_MS) ran on a machine that did not give it the time its premises need:
 * its checks are taken back and it runs again, at most LAT_RUNS times in all; the last run
 * counts whatever the latency. A failure with the latency within the limit counts at once. */
#define LAT_TICK_US 2000
#define LAT_LIMIT_MS 20
#define LAT_RUNS 3
static void *lat_main(void *arg)
{
    (void)arg;
    for (;;) {
        int64_t t0 = t_now_us();
        t_sleep_us(LAT_TICK_US);
        t_note_late(t_now_us() - t0 - LAT_TICK_US);
    }
    return NULL;
}

/* One run of a scenario; 1 when it is to run again (failed while the machine was late). */
static int run_case(const t_case_t *c, int run)
{
    int failures = t_failures;
    __atomic_store_n(&lat_max_us, 0, __ATOMIC_RELAXED);
    case_t0 = t_now_us();
    case_no++;
    c->fn();
    int64_t late = __atomic_load_n(&lat_max_us, __ATOMIC_RELAXED);
    const char *limit = getenv("MBFB_TEST_LATENCY_MS");
    long limit_ms = limit != NULL && limit[0] != '\0' ? atol(limit) : LAT_LIMIT_MS;
    if (t_failures == failures || late <= limit_ms * 1000 || run + 1 >= LAT_RUNS)
        return 0;
    fprintf(stderr, "  [%s] run %d of %d: the checks above are taken back: a thread of this "
            "test was up to %.1f ms late during it (the "
            "scenarios' timings allow %ld ms: MBFB_TEST_LATENCY_MS); run again\n", t_scenario,
            run + 1, LAT_RUNS, (double)late / 1e3, limit_ms);
    t_failures = failures;
    return 1;
}

/* Start the latency monitor (once per process); 0, or 1 when no thread could be made. */
static int lat_start(const char *test)
{
    static int lat_started;
    pthread_t lat_thread;
    if (!lat_started) {
        if (pthread_create(&lat_thread, NULL, lat_main, NULL) != 0) {
            fprintf(stderr, "%s: no latency monitor thread\n", test);
            return 1;
        }
        pthread_detach(lat_thread);
        lat_started = 1;
    }
    return 0;
}

/* Run a case under `name` until a run counts (run_case), and print its time. */
static void run_named(const t_case_t *c, const char *name)
{
    int64_t t0 = t_now_us();
    t_scenario = name;
    for (int run = 0; run_case(c, run); run++) {
    }
    printf("  %-60s %6.1f s\n", name, (double)(t_now_us() - t0) / 1e6);
    fflush(stdout);
}

int t_scenarios(const char *test, const t_case_t *cases, int n)
{
    if (lat_start(test))
        return 1;
    for (int c = 0; c < n; c++)
        run_named(&cases[c], cases[c].name);
    return t_done(test);
}

int t_serial_scenarios(const char *test, int *framing, const t_case_t *cases, int n)
{
    if (lat_start(test))
        return 1;
    static const struct { int framing; const char *name; } framings[] = {
        {MBFB_FRAMING_RTU, "rtu"},
        {MBFB_FRAMING_ASCII, "ascii"},
        {MBFB_FRAMING_RTU_NOCRC, "rtu-nocrc"},
    };
    enum { NF = (int)(sizeof framings / sizeof framings[0]) };
    static char name[96];
    const char *rot = getenv("MBFB_TEST_ROTATE");
    const char *only = getenv("MBFB_TEST_CASE");
    int rotate = rot != NULL && rot[0] != '\0';
    int k = rotate ? ((atoi(rot) % NF) + NF) % NF : 0;

    if (only != NULL && only[0] != '\0')
        printf("%s: MBFB_TEST_CASE=%s: only the cases whose \"framing: name\" holds it\n", test,
               only);
    if (rotate)
        printf("%s: MBFB_TEST_ROTATE=%d: each case in one framing (every case and every "
               "framing run; the plain flavours run them all in every framing)\n", test, k);
    for (int f = 0; f < NF; f++) {
        *framing = framings[f].framing;
        for (int c = 0; c < n; c++) {
            /* rotated: case c in framing (c + k) mod 3; with fewer cases than framings,
             * framing f also gets case (f + k) mod n so that every framing runs */
            if (rotate && (c + k) % NF != f && (n >= NF || (f + k) % n != c))
                continue;
            snprintf(name, sizeof name, "%s: %s", framings[f].name, cases[c].name);
            if (only != NULL && only[0] != '\0' && strstr(name, only) == NULL)
                continue;
            run_named(&cases[c], name);
        }
    }
    return t_done(test);
}
