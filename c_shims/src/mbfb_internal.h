/*
 * mbfb_internal.h - internals shared by the c_shims sources (not installed).
 *
 * Every file in this folder includes only flat names ("mbfb.h", "mbfb_internal.h",
 * <modbus.h>) because plc_lib copies them flat into OpenPLC's core/ as .cpp files.
 * Every non-static symbol starts with mbfb_.
 */
#ifndef MBFB_INTERNAL_H
#define MBFB_INTERNAL_H

#include <pthread.h>
#include <semaphore.h>
#include <stdint.h>
#include <time.h>

#include <modbus.h>

#include "mbfb.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- limits -------------------------------------------------------------- */
#define MBFB_MAX_BUSES     16   /* 4 bits of a request handle                     */
#define MBFB_MAX_SLOTS     64   /* request slots per bus; 6 bits of a handle      */
#define MBFB_MAX_DEVICES   256
#define MBFB_MAX_READ      125  /* FC03/FC04 registers per request (Modbus limit) */
#define MBFB_MAX_WRITE     123  /* FC16 registers per request (Modbus limit)      */
#define MBFB_FRAME_MAX     256  /* slave + PDU (253) + 2 check bytes              */
#define MBFB_DEFAULT_RETRIES 3  /* SetPro manual 5.6: retry at least 3 times      */
#define MBFB_OFFLINE_AFTER   3  /* consecutive failed transactions -> back-off    */
#define MBFB_PROBE_FIRST_MS  500
#define MBFB_PROBE_MAX_MS    8000
#define MBFB_TURNAROUND_US   10000 /* after a broadcast: SetPro processing max 10 ms */
#define MBFB_PROCESSING_US   10000 /* device processing time used in timeouts      */
#define MBFB_QUIET_LIMIT_T   3  /* a line that never falls silent is waited for at most
                                   the silence + this many response timeouts         */

/* ---- CRC / LRC / frames (mbfb_frame.c) --------------------------------------
 * A "frame" here is slave id + PDU, without CRC, LRC or MBAP header: the backends
 * add and strip those. Validation of a reply frame lives once, in mbfb_frame.c. */
uint16_t mbfb_crc16(const uint8_t *buf, int len);   /* CRC-16/MODBUS, send low byte first */
uint8_t  mbfb_lrc(const uint8_t *buf, int len);     /* two's complement of the byte sum   */

/** Build the request frame for fc 3/4/6/16 into out (>= 7 + 2*count bytes).
 *  Returns its length. Arguments must already be validated. */
int mbfb_build_request(uint8_t *out, int slave, int fc, int addr, int count,
                       const uint16_t *values);

/** Length of the correct, non-exception reply frame for a request frame. */
int mbfb_reply_len(const uint8_t *req);

/** Check reply frame `rsp` (len bytes) against request frame `req`: slave, function,
 *  byte count, the echo of FC06/FC16, exception. Returns 0 when good (read values
 *  are then at rsp+3), MBFB_E_EXCEPTION_BASE + code for an exception reply, or
 *  MBFB_E_BADREPLY. */
int mbfb_check_reply(const uint8_t *req, const uint8_t *rsp, int len);

/** Validate post arguments; 0 or MBFB_E_INVAL. */
int mbfb_check_args(int slave, int fc, int addr, int count, const uint16_t *values);

/* ---- timing (mbfb_timing.c) ---------------------------------------------- */
typedef struct mbfb_timing {
    int char_us;      /* one character on the line                              */
    int gap_us;       /* silence before every request: max(3.5 char, 44 bits)   */
    int byte_us;      /* max silence inside a reply once it started             */
} mbfb_timing_t;

void mbfb_timing_init(mbfb_timing_t *t, int baud, char parity, int data_bits, int stop_bits);
/** Bytes on the wire for a frame of `frame_len` (slave+PDU) in a framing. */
int mbfb_wire_len(int framing, int frame_len);
/** Derived response timeout (us) for a request/reply pair (see README formula). */
int mbfb_response_timeout_us(const mbfb_timing_t *t, int framing, int req_frame_len,
                             int rsp_frame_len);

/* ---- monotonic clock helpers (mbfb_timing.c) ------------------------------- */
int64_t mbfb_now_us(void);

/* ---- backends ---------------------------------------------------------------
 * One struct of function pointers per transport, like libmodbus's own backend
 * struct. All return 0 / a length on success, or a negative -MBFB_E_* code:
 * -MBFB_E_TIMEOUT, -MBFB_E_CRC, -MBFB_E_BADREPLY, -MBFB_E_PORTLOST, -MBFB_E_NOPORT. */
struct mbfb_bus;
typedef struct mbfb_backend {
    const char *name;
    int  (*open)(struct mbfb_bus *bus);
    void (*close)(struct mbfb_bus *bus);
    /** Before every attempt: discard pending input and, on a serial line, wait until
     *  the line has been silent for silence_us since bus->quiet_from_us; every byte
     *  heard meanwhile is read, discarded and restarts the silence; after limit_us in
     *  all the wait ends anyway (a babbling line). Returns the bytes discarded (>= 0)
     *  or -MBFB_E_PORTLOST. */
    int  (*quiet)(struct mbfb_bus *bus, int silence_us, int limit_us);
    /** After a failed attempt, or NULL: TCP reconnects (a late reply can only come on
     *  the old connection). Serial lines need nothing here: the worker asks quiet()
     *  for a longer silence before the next request instead. */
    void (*resync)(struct mbfb_bus *bus);
    int  (*send)(struct mbfb_bus *bus, const uint8_t *frame, int len);
    /** Receive one reply frame (slave + PDU, check bytes stripped and verified).
     *  `req` is the request frame (for lengths); timeout_us is for the first byte. */
    int  (*recv)(struct mbfb_bus *bus, const uint8_t *req, uint8_t *frame, int max,
                 int timeout_us);
} mbfb_backend_t;

extern const mbfb_backend_t mbfb_backend_rtu;    /* libmodbus RTU                  */
extern const mbfb_backend_t mbfb_backend_nocrc;  /* libmodbus RTU, 00 00 sent as CRC */
extern const mbfb_backend_t mbfb_backend_ascii;  /* ':' hex LRC CR LF, written here  */
extern const mbfb_backend_t mbfb_backend_tcp;    /* libmodbus TCP                  */

/* serial port helpers shared by the serial backends (mbfb_backend_lm.c): the port is
 * opened and configured by libmodbus (modbus_new_rtu + modbus_connect) for every
 * serial framing, so termios settings are never hand-written. */
int  mbfb_serial_open(struct mbfb_bus *bus);
void mbfb_lm_close(struct mbfb_bus *bus);
int  mbfb_serial_quiet(struct mbfb_bus *bus, int silence_us, int limit_us);
/** Wait up to wait_us (microseconds) for input on fd: 1 readable (or hung up),
 *  0 nothing came, -1 poll failed. */
int  mbfb_fd_wait_input(int fd, int64_t wait_us);
/** write() all of buf on the bus fd (non-blocking fd; waits with poll). */
int  mbfb_fd_write_all(struct mbfb_bus *bus, const uint8_t *buf, int len);
/** Map an errno from libmodbus or read/write to -MBFB_E_*. */
int  mbfb_errno_to_err(int err);

/* ---- request slots ----------------------------------------------------------
 * state word = (generation << 4) | MBFB_SLOT_*; changed only with __atomic CAS.
 * FREE -> CLAIMED (poster fills it) -> QUEUED -> ACTIVE (worker) -> DONE/FAILED
 * -> FREE (mbfb_take / mbfb_cancel). Cancel of ACTIVE -> CANCELLED -> FREE (worker). */
enum {
    MBFB_SLOT_FREE = 0,
    MBFB_SLOT_CLAIMED,
    MBFB_SLOT_QUEUED,
    MBFB_SLOT_ACTIVE,
    MBFB_SLOT_DONE,
    MBFB_SLOT_FAILED,
    MBFB_SLOT_CANCELLED
};
#define MBFB_GEN_BITS 20
#define MBFB_GEN_MASK ((1u << MBFB_GEN_BITS) - 1u)

typedef struct mbfb_slot {
    uint32_t state;         /* atomic: (gen << 4) | MBFB_SLOT_*                   */
    uint32_t seq;           /* post order, FIFO among queued requests             */
    int dev, fc, addr, count;
    int result;             /* MBFB_OK or positive MBFB_E_* (written by worker)  */
    int nvals;              /* registers read                                    */
    uint16_t values[MBFB_MAX_READ]; /* write values in, read values out          */
} mbfb_slot_t;

/* ---- devices ------------------------------------------------------------- */
typedef struct mbfb_dev {
    int bus, slave;          /* set once at mbfb_dev_open, before publication     */
    mbfb_diag_t diag;        /* each field written by the worker with __atomic     */
    /* back-off: worker only */
    int fails;               /* consecutive failed transactions                   */
    int probe_ms;            /* current probe interval                            */
    int64_t next_probe_us;
} mbfb_dev_t;

/* ---- bus ----------------------------------------------------------------- */
typedef struct mbfb_bus {
    char *port;              /* as given (tcp://host:port or a path)              */
    mbfb_bus_config_t cfg;   /* normalised copy; cfg.port points to `port`        */
    const mbfb_backend_t *be;
    mbfb_timing_t timing;
    modbus_t *ctx;           /* libmodbus context while the port is open          */
    int fd;                  /* its file descriptor, -1 when closed               */
    int64_t quiet_from_us;   /* the line is silent from this time on              */
    int timeout_us;          /* response timeout of the current transaction       */
    int settle_us;           /* silence owed before the next request: the response
                                timeout of a transaction that had a failed attempt
                                (its late reply may still come), else 0           */
    uint32_t stray_bytes;    /* atomic: bytes discarded outside replies (diag)     */
    int stop;                /* atomic: worker exits                              */
    uint32_t post_seq;       /* atomic: next sequence number                      */
    sem_t wake;              /* posted by mbfb_post, waited on by the worker      */
    pthread_t worker;
    int index;
    mbfb_slot_t slots[MBFB_MAX_SLOTS];
} mbfb_bus_t;

/* registry (mbfb_bus.c); entries are published with release stores */
extern mbfb_bus_t *mbfb_buses[MBFB_MAX_BUSES];
extern mbfb_dev_t *mbfb_devs[MBFB_MAX_DEVICES];

/* worker side of the slots (mbfb_req.c) */
mbfb_slot_t *mbfb_slot_next(mbfb_bus_t *bus);          /* QUEUED -> ACTIVE, FIFO */
void mbfb_slot_finish(mbfb_slot_t *s, int result);     /* ACTIVE -> DONE/FAILED  */
void mbfb_slot_fail_queued(mbfb_bus_t *bus, int result);

/* the worker (mbfb_worker.c) */
void *mbfb_worker_main(void *arg);

/* diag helpers (worker writes, scan reads, all with __atomic) */
#define MBFB_DIAG_INC(d, f) __atomic_fetch_add(&(d)->diag.f, 1u, __ATOMIC_RELAXED)
#define MBFB_DIAG_SET(d, f, v) __atomic_store_n(&(d)->diag.f, (v), __ATOMIC_RELAXED)
/* bytes heard outside any reply and discarded (bus-wide diag.stray_bytes) */
#define MBFB_STRAY_ADD(b, n) \
    __atomic_fetch_add(&(b)->stray_bytes, (uint32_t)(n), __ATOMIC_RELAXED)

#ifdef __cplusplus
}
#endif

#endif /* MBFB_INTERNAL_H */
