/*
 * fuzz_worker.c - the whole shims (public API, worker thread, libmodbus) on a fake line:
 * a pty whose far end is this harness, answering each request with fuzzer-chosen bytes
 * after fuzzer-chosen delays.
 *
 * Input: framing byte (RTU, ASCII, NOCRC), retries byte (0..2), request count byte (1..4),
 * then per request 7 header bytes (fuzz_common.h; slave 1..3, policy bit in the slave
 * byte's top bit), then a script of answers, one per request frame the harness hears:
 *   type%5 == 0  raw:      delay, len, len bytes sent as they are
 *   type%5 == 1  good:     delay; the correct reply (right check bytes)
 *   type%5 == 2  mutated:  delay, pos, xor; the correct reply with one byte changed
 *   type%5 == 3  silence
 *   type%5 == 4  late:     delay*4 ms (up to ~1 s), then the correct reply
 * Invariants: every posted request finishes (bounded time), ends with a result of the one
 * error table, a good read returns exactly its count of registers (bits: FC01/02), and
 * scan-side calls
 * never crash on stale handles. ASan/UBSan watch the worker thread too.
 */

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "fuzz_common.h"

/* weak: the harness also runs against shims older than confirmed writes */
#pragma weak mbfb_post_write

static int master = -1, slave_keep = -1;
static char slave_name[64];

static int64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static void setup(void)
{
    struct termios tio;
    if (master >= 0)
        return;
    if (openpty(&master, &slave_keep, slave_name, NULL, NULL) != 0)
        abort();
    tcgetattr(slave_keep, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave_keep, TCSANOW, &tio);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
}

static const char hexd[] = "0123456789ABCDEF";

/* The correct reply frame (slave + PDU) to a request frame, or 0 if none (broadcast). */
static int good_reply(const uint8_t *q, int qlen, uint8_t *out)
{
    if (qlen < 6 || q[0] == 0)
        return 0;
    memcpy(out, q, 6);
    if (q[1] >= 1 && q[1] <= 4) { /* reads: registers, or bits (ceil(n / 8) bytes) */
        int n = (q[4] << 8 | q[5]) & 0xFF;
        if (n > 125)
            n = 125;
        out[2] = (uint8_t)(q[1] <= 2 ? (n + 7) / 8 : 2 * n);
        for (int i = 0; i < out[2]; i++)
            out[3 + i] = (uint8_t)(q[3] + i);
        return 3 + out[2];
    }
    return 6;
}

/* Frame on the wire in a framing: RTU/NOCRC + CRC, ASCII ':' hex LRC CR LF. */
static int encode(int framing, const uint8_t *fr, int len, uint8_t *out)
{
    int n = 0;
    if (framing == MBFB_FRAMING_ASCII) {
        uint8_t lrc = mbfb_lrc(fr, len);
        out[n++] = ':';
        for (int i = 0; i <= len; i++) {
            uint8_t b = i < len ? fr[i] : lrc;
            out[n++] = (uint8_t)hexd[b >> 4];
            out[n++] = (uint8_t)hexd[b & 15];
        }
        out[n++] = '\r';
        out[n++] = '\n';
        return n;
    }
    uint16_t crc = mbfb_crc16(fr, len);
    memcpy(out, fr, (size_t)len);
    out[len] = (uint8_t)(crc & 0xFF);
    out[len + 1] = (uint8_t)(crc >> 8);
    return len + 2;
}

static int hexval(uint8_t c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    return 0;
}

/* Request frame (slave + PDU) from the bytes heard. */
static int decode(int framing, const uint8_t *raw, int n, uint8_t *out)
{
    if (framing != MBFB_FRAMING_ASCII) {
        if (n < 2)
            return 0;
        memcpy(out, raw, (size_t)(n - 2));
        return n - 2;
    }
    int k = 0;
    for (int i = 1; i + 1 < n && raw[i] != '\r'; i += 2) /* heard bytes may be anything */
        out[k++] = (uint8_t)(hexval(raw[i]) << 4 | hexval(raw[i + 1]));
    return k > 0 ? k - 1 : 0; /* without the LRC */
}

static void drain(void)
{
    uint8_t junk[512];
    while (read(master, junk, sizeof junk) > 0) {
    }
}

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const int framings[3] = {MBFB_FRAMING_RTU, MBFB_FRAMING_ASCII,
                                    MBFB_FRAMING_RTU_NOCRC};
    fz_t f = {data, size};
    int framing, retries, nreq, bus, devs[4] = {-1, -1, -1, -1};
    int handles[4], counts[4], fcs[4];
    uint8_t rx[1024];
    int rxn = 0;
    int64_t last_rx = 0, deadline;

    if (size < 10 || size > 2048)
        return 0;
    setup();
    framing = framings[fz_u8(&f) % 3];
    retries = fz_u8(&f) % 3;
    nreq = 1 + fz_u8(&f) % 4;
    drain();
    bus = mbfb_bus_open_args(slave_name, (int)strlen(slave_name), 115200, 'N', 8, 1, framing,
                             20, retries);
    FZ_ASSERT(bus >= 0);
    for (int i = 0; i < nreq; i++) {
        fz_req_t r;
        uint8_t req[MBFB_FRAME_MAX];
        int sb = f.n ? f.p[0] : 0, policy = sb >> 7, slave = 1 + (sb & 0x7F) % 3;
        handles[i] = 0;
        fz_request(&f, &r, req);
        if (mbfb_check_args(slave, r.fc, r.addr, r.count, r.values) != MBFB_OK)
            continue; /* refused arguments: covered by the tests */
        if (devs[slave] < 0)
            devs[slave] = mbfb_dev_open(bus, slave);
        FZ_ASSERT(devs[slave] >= 0);
        counts[i] = r.count;
        fcs[i] = r.fc;
        if (r.fc >= 1 && r.fc <= 4)
            handles[i] = mbfb_post(devs[slave], r.fc, r.addr, r.count, r.values);
        else if (mbfb_post_write != NULL) /* shims with confirmed writes */
            handles[i] = mbfb_post_write(devs[slave], r.fc, r.addr, r.count, r.values, policy);
        else
            handles[i] = mbfb_post(devs[slave], r.fc, r.addr, r.count, r.values);
        FZ_ASSERT(handles[i] > 0 || handles[i] == -MBFB_E_INVAL);
        if (handles[i] < 0)
            handles[i] = 0;
    }

    /* the far end: hear a request (bytes then 3 ms of silence), answer from the script */
    deadline = now_ms() + 8000;
    for (;;) {
        int pending = 0;
        for (int i = 0; i < nreq; i++) {
            if (handles[i] > 0) {
                int st = mbfb_poll(handles[i]);
                FZ_ASSERT(st >= MBFB_REQ_QUEUED && st <= MBFB_REQ_FAILED);
                pending += st == MBFB_REQ_QUEUED || st == MBFB_REQ_ACTIVE;
            }
        }
        if (!pending)
            break;
        FZ_ASSERT(now_ms() < deadline); /* a request that never finishes is a bug */
        struct pollfd p = {master, POLLIN, 0};
        if (poll(&p, 1, 1) > 0) {
            ssize_t n = read(master, rx + rxn, sizeof rx - (size_t)rxn);
            if (n > 0) {
                rxn += (int)n;
                last_rx = now_ms();
                if (rxn == (int)sizeof rx)
                    rxn = 0;
            }
            continue;
        }
        if (rxn == 0 || now_ms() - last_rx < 3)
            continue;
        /* one request heard: answer it */
        uint8_t q[MBFB_FRAME_MAX + 8], fr[MBFB_FRAME_MAX + 8], wire[2 * MBFB_FRAME_MAX + 8];
        int qlen = decode(framing, rx, rxn > MBFB_FRAME_MAX ? MBFB_FRAME_MAX : rxn, q);
        int type = fz_u8(&f) % 5, delay = fz_u8(&f) % 32, len = 0, w = 0;
        rxn = 0;
        if (type == 0) {
            len = fz_u8(&f);
            if ((size_t)len > f.n)
                len = (int)f.n;
            memcpy(wire, f.p, (size_t)len);
            f.p += len, f.n -= (size_t)len;
            w = len;
        } else if (type != 3) {
            len = good_reply(q, qlen, fr);
            if (len > 0 && type == 2) {
                int pos = fz_u8(&f), x = fz_u8(&f);
                fr[pos % len] ^= (uint8_t)(x ? x : 1);
            }
            w = len > 0 ? encode(framing, fr, len, wire) : 0;
            if (type == 4)
                delay *= 32;
        }
        if (delay) {
            sleep_ms(delay);
            deadline += delay; /* the harness's own waiting does not count */
        }
        for (int done = 0; done < w;) {
            ssize_t n = write(master, wire + done, (size_t)(w - done));
            if (n > 0)
                done += (int)n;
            else
                sleep_ms(1);
        }
    }
    for (int i = 0; i < nreq; i++) {
        uint16_t vals[MBFB_MAX_READ];
        int rc;
        if (handles[i] <= 0)
            continue;
        rc = mbfb_take(handles[i], vals, MBFB_MAX_READ);
        if (rc >= 0)
            FZ_ASSERT(rc == ((fcs[i] >= 1 && fcs[i] <= 4) ? counts[i] : 0)); /* regs or bits */
        else
            FZ_ASSERT(fz_known_result(-rc) && rc != -MBFB_E_BADHANDLE);
        FZ_ASSERT(mbfb_take(handles[i], vals, MBFB_MAX_READ) == -MBFB_E_BADHANDLE);
    }
    mbfb_shutdown();
    return 0;
}
