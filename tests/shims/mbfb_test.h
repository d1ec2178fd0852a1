/*
 * mbfb_test.h - assertion helpers and a scripted Modbus peer on a serial line inside the
 * test program (testline.h), for the c_shims tests. The peer is written independently of
 * c_shims (its own CRC, LRC and framing), so the shims are checked against bytes, not
 * against themselves.
 */
#ifndef MBFB_TEST_H
#define MBFB_TEST_H

#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/types.h>

#include "mbfb.h"

/* ---- assertions ------------------------------------------------------------ */
extern int t_failures;
extern const char *t_scenario;

#define CHECK(cond)                                                                     \
    do {                                                                                \
        if (!(cond)) {                                                                  \
            t_failures++;                                                               \
            fprintf(stderr, "FAIL %s:%d [%s]: %s\n", __FILE__, __LINE__, t_scenario,    \
                    #cond);                                                             \
            t_failed();                                                                 \
        }                                                                               \
    } while (0)

#define CHECK_EQ(a, b)                                                                  \
    do {                                                                                \
        long long a_ = (long long)(a), b_ = (long long)(b);                             \
        if (a_ != b_) {                                                                 \
            t_failures++;                                                               \
            fprintf(stderr, "FAIL %s:%d [%s]: %s == %lld, expected %s == %lld\n",       \
                    __FILE__, __LINE__, t_scenario, #a, a_, #b, b_);                    \
            t_failed();                                                                 \
        }                                                                               \
    } while (0)

/** A thread of the test was `us` later than it meant to be (the peer's replies, the latency
 *  monitor): the most of these since a scenario began decides whether its failure counts
 *  (t_serial_scenarios). */
void t_note_late(int64_t us);

/** After a failed check: the first one of a scenario prints the log of the peer started
 *  last (each request and reply, its time in the scenario), to tell a race from a bug. */
void t_failed(void);

/** Compare bytes with a hex string like "01 03 00 00" (spaces ignored). */
#define CHECK_HEX(buf, len, hex) t_check_hex(__FILE__, __LINE__, (buf), (len), (hex))
void t_check_hex(const char *file, int line, const uint8_t *buf, int len, const char *hex);
/** Parse "01 03 ..." into out; returns the byte count. */
int t_hex(const char *hex, uint8_t *out);
/** Print the result and return the process exit code. */
int t_done(const char *name);

/** The FDC manual's Example 1, FC16 of 52 words with its CRC (113 bytes). */
extern const char *const fdc_ex1;

/* ---- scripted peer ----------------------------------------------------------- */
#define PEER_LOG 256
#define PEER_BUF 600

enum { PEER_RTU, PEER_ASCII }; /* how the peer frames (RTU also for RTU-without-CRC) */

typedef struct peer_reply {
    uint8_t out[PEER_BUF];
    int len;                  /* bytes to write; 0 = stay silent */
    int delay_ms;             /* wait this long before writing     */
    int pace_us;              /* > 0: one byte, then this pause (a slow line) */
    int hold;                 /* wait for peer_release() (at most 10 s) before writing */
    int until_input;          /* wait until the master sends again (at most 10 s), then
                                 write: late, in the wait of the master's next frame,
                                 with no timer between the two                      */
    int deaf;                 /* busy until this reply is out: requests that came in
                                 before it was written are discarded (a half-duplex
                                 device); what comes after it is heard             */
} peer_reply_t;

struct peer;
/** Called for each request. n = index of the request (0-based); frame = slave + PDU
 *  (check bytes removed, ASCII decoded); raw = bytes as received. */
typedef void (*peer_fn)(struct peer *p, int n, const uint8_t *frame, int flen,
                        peer_reply_t *r);

typedef struct peer {
    int line;                 /* the peer's end of the line (testline.h)          */
    int mode;                 /* PEER_RTU / PEER_ASCII                            */
    char link[128];           /* the port's name, which the shims open            */
    peer_fn fn;
    void *user;
    int stop;                 /* __atomic */
    pthread_t th;
    pthread_mutex_t lock;
    /* log (under lock) */
    int n;                    /* requests received                                */
    long bytes;               /* bytes received                                   */
    int per_slave[256];
    uint8_t raw[PEER_LOG][PEER_BUF];
    int raw_len[PEER_LOG];
    int64_t t_us[PEER_LOG];   /* time the request was complete                    */
    int64_t t_reply_us[PEER_LOG]; /* time its reply was written (0: none)         */
    int reply_len[PEER_LOG];  /* bytes of that reply                               */
    /* a tiny register bank for peer_answer(); slaves 0..7, registers 0..255 */
    uint16_t regs[8][256];
    uint8_t coils[8][256];    /* ... coils (0/1, one byte each: packed only on the wire,
                                 by the peer's own code), slaves 0..7, 0..255         */
    uint8_t inputs[8][256];   /* ... and discrete inputs; bits past 255: exception 2   */
    int dead[256];            /* peer_answer stays silent for these slaves        */
    int collisions;           /* __atomic: request bytes came in while a paced reply
                                 was still going out (a collision on RS-485)       */
    int reply_sent;           /* __atomic: bytes of the current reply written (a
                                 paced one byte by byte, another all at once)      */
    int released;             /* __atomic: set by peer_release, taken by a held reply */
    long ignored;             /* __atomic: bytes discarded by a deaf reply           */
    /* babbler: a second talker on the line (noise, another master, a broken unit) */
    pthread_t babbler;
    int babbling, babble_stop;                 /* babble_stop: __atomic            */
    uint8_t pattern[64];
    int pattern_len, interval_us;
    long babble_max;                           /* 0 = until stopped                */
    long babbled;                              /* __atomic: bytes written          */
} peer_t;

/** Start a peer on a new line (testline.h) named `link` (replaced if present). */
int peer_start(peer_t *p, const char *link, int mode, peer_fn fn, void *user);
/** Stop the thread and drop the line: its name disappears (the shims' port is gone). */
void peer_stop(peer_t *p);
int peer_count(peer_t *p);
/** The peer's count of requests once it has read `n` of them, at most 2 s: its thread may
 *  lag behind requests that it leaves unanswered or that failed fast (e.g. on garbage). */
int peer_count_reaching(peer_t *p, int n);
long peer_bytes(peer_t *p);
int peer_slave_count(peer_t *p, int slave);
/** Copy request i as received; returns its length. */
int peer_raw(peer_t *p, int i, uint8_t *out);
int64_t peer_time(peer_t *p, int i);

/** Reply helpers: encode frame (slave + PDU) for the peer's mode with a correct
 *  CRC / LRC; or raw bytes. They append to r. */
void peer_reply_frame(peer_t *p, peer_reply_t *r, const uint8_t *frame, int len);
void peer_reply_hex(peer_t *p, peer_reply_t *r, const char *frame_hex);
void peer_reply_raw(peer_reply_t *r, const uint8_t *bytes, int len);
/** Change the register bank / silence a slave while the peer runs. */
void peer_set_reg(peer_t *p, int slave, int addr, uint16_t value);
void peer_set_dead(peer_t *p, int slave, int dead);
/** A coil (fc 1) or discrete input (fc 2) of the peer's bank; and read a coil. */
void peer_set_bit(peer_t *p, int fc, int slave, int addr, int on);
int peer_coil(peer_t *p, int slave, int addr);
/** Start writing `pattern` over and over, one byte every interval_us, `max` bytes in
 *  all (0 = until peer_babble_stop). */
int peer_babble_start(peer_t *p, const uint8_t *pattern, int len, int interval_us, long max);
/** Wait for the babbler to finish (max reached) or stop it; returns bytes written. */
long peer_babble_stop(peer_t *p);
long peer_babbled(peer_t *p);
int peer_collisions(peer_t *p);
/** Bytes of the reply being written (or last written) so far. */
int peer_reply_sent(peer_t *p);
/** Bytes the shims have written that the peer has not read yet (FIONREAD). */
int peer_pending(peer_t *p);
/** Let a held reply (peer_reply_t.hold) go out. */
void peer_release(peer_t *p);
/** A well-behaved device from the register bank. */
void peer_answer(peer_t *p, int n, const uint8_t *frame, int flen, peer_reply_t *r);
/** peer_answer, but request `late_n` is answered `delay_ms` late by a device deaf
 *  meanwhile (busy: what it hears is discarded), the reply written at once. */
void peer_answer_late_deaf(peer_t *p, int n, const uint8_t *frame, int flen, peer_reply_t *r,
                           int late_n, int delay_ms);

/* independent check functions of the peer */
uint16_t peer_crc16(const uint8_t *buf, int len);
uint8_t peer_lrc(const uint8_t *buf, int len);

/* ---- shim helpers ------------------------------------------------------------ */
/** Poll a request until it finishes (DONE/FAILED), at most 30 s. Returns the state. */
int t_wait(int req);
/** post + wait + take. Returns mbfb_take's result (or the post error). */
int t_run(int dev, int fc, int addr, int count, const uint16_t *vals, uint16_t *out,
          int max);
/** mbfb_post_write + wait + take. Returns mbfb_take's result (or the post error). */
int t_run_write(int dev, int fc, int addr, int count, const uint16_t *vals, int policy);
/** Bus config helper. */
mbfb_bus_config_t t_cfg(const char *port, int baud, int framing, int timeout_ms,
                        int retries);
/** Start peer p on t_tmpdir()/port in the framing's mode (ASCII: the bus is 7E1, the
 *  Modbus ASCII default), registers of slave 1 = 0x1000 + address, open a bus with
 *  t_cfg(baud, framing, timeout_ms, retries). Returns the device handle of slave 1. */
int t_serial_dev(peer_t *p, peer_fn fn, int framing, int baud, int timeout_ms, int retries);
/** mbfb_dev_diag with a CHECK that it worked. */
mbfb_diag_t t_diag(int dev);
/** Bytes on the wire of a reply to a read of `nregs` registers in a serial framing. */
int t_read_reply_bytes(int framing, int nregs);

/** A named test scenario; run for each serial framing by t_serial_scenarios. */
typedef struct t_case {
    void (*fn)(void);
    const char *name;
} t_case_t;
/** A case named by its function (the function sets t_scenario to its own words). */
#define T_CASE(fn) {fn, #fn}
/** Run every case for RTU, ASCII and RTU-without-CRC in turn (setting *framing and
 *  t_scenario first), printing each one's time; returns t_done(test).
 *  MBFB_TEST_ROTATE=k (set by tests/shims/CMakeLists.txt for every flavour but Debian's
 *  libmodbus): each case runs in one framing only, case c in framing (c + k) mod 3, so every
 *  case and every framing still run in that flavour without repeating the long waits that
 *  the default flavour runs in full. MBFB_TEST_CASE=text (by hand, to repeat one case; and
 *  "rtu:", "ascii:", "rtu-nocrc:" for one framing, tests/last.cmake): only the cases whose
 *  "framing: name" contains text. A case that fails while a thread of the test was
 *  more than MBFB_TEST_LATENCY_MS (default 20) late (t_note_late) runs again, its checks
 *  taken back, at most 3 runs in all (mbfb_test_peer.c: the machine's latency during a scenario). */
int t_serial_scenarios(const char *test, int *framing, const t_case_t *cases, int n);
/** The same for cases that are not run per framing (each sets t_scenario itself): every
 *  case once, with the latency rerun; returns t_done(test). */
int t_scenarios(const char *test, const t_case_t *cases, int n);
void t_sleep_ms(int ms);
/** A child process the test started: SIGTERM, then reaped (nothing when pid <= 0). */
void t_stop_child(pid_t pid);
void t_sleep_us(long us);
int64_t t_now_us(void);
/** Reads and writes of every function against pymodbus_peer.py (its registers: holding
 *  0x3000 + i, input 0x4000 + i; its coils and discrete inputs: T_PM_COIL, T_PM_INPUT),
 *  checked, ending with an exception past its map. */
void t_pymodbus_conversation(int dev);
/** pymodbus_peer.py's bits at PDU address a (its blocks are 1-based: index a + 1). */
#define T_PM_COIL(a) (((a) + 1) % 3 == 0)
#define T_PM_INPUT(a) (((a) + 1) % 5 < 2)
/** A fresh temporary directory for the lines' names; returns path (static). */
const char *t_tmpdir(void);

#endif
