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
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "mbfb.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- protocol limits (Modbus application protocol 1.1b3, 6.3 / 6.12; the per-request
 * counts are public: MBFB_MAX_READ, MBFB_MAX_WRITE, MBFB_MAX_READ_BITS, _WRITE_BITS) ---- */
#define MBFB_FRAME_MAX     256  /* slave + PDU (253) + 2 check bytes              */
#define MBFB_MAX_SLAVE     247  /* serial addresses 1..247, 0 = broadcast         */
#define MBFB_MAX_BAUD      4000000 /* the fastest rate a Linux UART driver offers    */
#define MBFB_MAX_UNIT      255  /* Modbus TCP unit identifiers                    */
#define MBFB_ADDR_SPACE    0x10000 /* register addresses 0..0xFFFF                 */
#define MBFB_EXCEPTION_BIT 0x80 /* set in the function code of an exception reply  */

#define MBFB_COIL_ON       0xFF00 /* FC05's value for ON (OFF: 0x0000)              */

/* Sets of function codes as bit masks (bit fc): one test where the scan side asks. */
#define MBFB_FC_BIT(fc) (1u << (fc))
#define MBFB_FCS_BITS  (MBFB_FC_BIT(MBFB_FC_READ_COILS) | MBFB_FC_BIT(MBFB_FC_READ_DISCRETE) | \
                        MBFB_FC_BIT(MBFB_FC_WRITE_COIL) | MBFB_FC_BIT(MBFB_FC_WRITE_COILS))
#define MBFB_FCS_READ  (MBFB_FC_BIT(MBFB_FC_READ_COILS) | MBFB_FC_BIT(MBFB_FC_READ_DISCRETE) | \
                        MBFB_FC_BIT(MBFB_FC_READ_HOLDING) | MBFB_FC_BIT(MBFB_FC_READ_INPUT))
#define MBFB_FCS_WRITE (MBFB_FC_BIT(MBFB_FC_WRITE_COIL) | MBFB_FC_BIT(MBFB_FC_WRITE_SINGLE) | \
                        MBFB_FC_BIT(MBFB_FC_WRITE_COILS) | MBFB_FC_BIT(MBFB_FC_WRITE_MULTIPLE))

/** Does fc read or write bits (coils, discrete inputs: FC01, 02, 05, 15)? */
static inline int mbfb_fc_is_bits(int fc)
{
    return (unsigned)fc < 32 && (MBFB_FCS_BITS >> fc & 1u);
}
/** Is fc a read (FC01, 02, 03, 04)? */
static inline int mbfb_fc_is_read(int fc)
{
    return (unsigned)fc < 32 && (MBFB_FCS_READ >> fc & 1u);
}
/** Is fc a write (FC05, 06, 15, 16)? */
static inline int mbfb_fc_is_write(int fc)
{
    return (unsigned)fc < 32 && (MBFB_FCS_WRITE >> fc & 1u);
}
/** The other read function of the same kind: input registers for holding ones and back,
 *  discrete inputs for coils and back. */
static inline int mbfb_fc_other_read(int fc)
{
    switch (fc) {
    case MBFB_FC_READ_HOLDING:  return MBFB_FC_READ_INPUT;
    case MBFB_FC_READ_COILS:    return MBFB_FC_READ_DISCRETE;
    case MBFB_FC_READ_DISCRETE: return MBFB_FC_READ_COILS;
    default:                    return MBFB_FC_READ_HOLDING;
    }
}
/** The read that shows what a write (fc) left on the device (its read-back): FC01 for
 *  coils, FC03 for registers. */
static inline int mbfb_fc_readback(int fc)
{
    return mbfb_fc_is_bits(fc) ? MBFB_FC_READ_COILS : MBFB_FC_READ_HOLDING;
}
/** Most items a read of fc may ask for (registers or bits). */
static inline int mbfb_read_max(int fc)
{
    return mbfb_fc_is_bits(fc) ? MBFB_MAX_READ_BITS : MBFB_MAX_READ;
}
/** Data bytes of a good reply to a read of `count` items with fc (its byte count). */
static inline int mbfb_read_bytes(int fc, int count)
{
    return mbfb_fc_is_bits(fc) ? (count + 7) / 8 : 2 * count;
}
/** Words the API carries for `count` items of fc: registers, or bits packed. */
static inline int mbfb_data_words(int fc, int count)
{
    return mbfb_fc_is_bits(fc) ? MBFB_BIT_WORDS(count) : count;
}

/* ---- units ------------------------------------------------------------------- */
/** Microseconds (the worker's clock, mbfb_now_us) in `ms` milliseconds. */
#define MBFB_MS(ms) ((int64_t)(ms) * 1000)

/* ---- sizes of this library -------------------------------------------------- */
#define MBFB_MAX_BUSES     16   /* 4 bits of a request handle                     */
#define MBFB_MAX_SLOTS     64   /* request slots per bus; 6 bits of a handle      */
#define MBFB_MAX_DEVICES   256
#define MBFB_PLANS_PER_BUS 64   /* refresh plans per bus (32 devices x 2)         */
#define MBFB_MAX_PLANS     (MBFB_MAX_BUSES * MBFB_PLANS_PER_BUS)
#define MBFB_OUTSTANDING_MAX 32 /* reply shapes of failed attempts kept per device */
#define MBFB_KNOWN_READS   4    /* ranges that read well, remembered per device    */
#define MBFB_HEARD_MAX     520  /* bytes heard before a request kept for late replies:
                                   one ASCII frame of 256 bytes (':', hex, CR LF)    */

/* ---- policy ----------------------------------------------------------------- */
/* A PLC that stops scanning (README "Lifetime"): a plan whose block has not taken a
 * snapshot for MBFB_STALE_PERIODS periods (its own, or its block's scan interval if
 * longer), and at least MBFB_STALE_MIN_MS, stops polling until its block is scanned
 * again; a queued request is not sent once nothing has been posted or polled on its bus
 * for as long (the longest of its plans' bounds, at least MBFB_STALE_MIN_MS). */
#define MBFB_STALE_PERIODS   10
#define MBFB_STALE_MIN_MS    2000
#define MBFB_MAX_RETRIES     20 /* mbfb_bus_config_t.retries at most                */
#define MBFB_MAX_TIMEOUT_MS  60000 /* response_timeout_ms at most (a minute)         */
#define MBFB_SCAN_MAX_MS     60000 /* a longer gap between takes is a stop, not a task's
                                      interval (the bound does not learn from it)     */
#define MBFB_OFFLINE_AFTER   3  /* consecutive failed transactions -> back-off    */
/* A device in back-off is probed (one attempt) once per probe interval: at least
 * MBFB_PROBE_MIN_MS, and MBFB_PROBE_SHARE response timeouts, so a dead device costs at
 * most 1/MBFB_PROBE_SHARE of the line however long it stays dead, and a device that
 * comes back is found within one interval (mbfb_device.c; README "Failures and what the
 * worker does"). A port that could not be opened is tried again after MBFB_PROBE_MIN_MS. */
#define MBFB_PROBE_MIN_MS    500
#define MBFB_PROBE_SHARE     10
#define MBFB_TURNAROUND_US   10000 /* after a broadcast: SetPro processing max 10 ms */
#define MBFB_PROCESSING_US   10000 /* device processing time used in timeouts      */
#define MBFB_QUIET_LIMIT_T   3  /* a line that never falls silent is waited for at most
                                   the silence + this many response timeouts         */
/* A reply later than this after its request is assumed impossible: an outstanding
 * reply shape older than this may be used again (README "Late replies"). The three
 * instruments answer within 10 ms of processing (SetPro) to ~100 ms (FDC EEPROM
 * writes); 10 s is 100 times the worst, and longer than the simulator's and the
 * soak's 5 s late replies. */
#define MBFB_LATE_MAX_MS     10000
/* RTU over TCP (README "RTU over TCP"): the network leg and the gateway's own framing
 * of its serial line, added to the response timeout the line's baud gives and to the
 * time a started reply may take. A configured TimeoutMs replaces the whole timeout. */
#define MBFB_NET_ALLOWANCE_US 100000
#define MBFB_CONNECT_MS      1000 /* TCP connect of RTU over TCP; a stuck send          */
#define MBFB_STUCK_UART_US   100000 /* a UART that has not sent a frame this long after its
                                       wire time is stuck (direction control's drain)  */

/* ---- CRC / LRC / frames (mbfb_frame.c) --------------------------------------
 * A "frame" here is slave id + PDU, without CRC, LRC or MBAP header: the backends
 * add and strip those. Validation of a reply frame lives once, in mbfb_frame.c. */
uint16_t mbfb_crc16(const uint8_t *buf, int len);   /* CRC-16/MODBUS, send low byte first */
uint8_t  mbfb_lrc(const uint8_t *buf, int len);     /* two's complement of the byte sum   */

/** Build the request frame for fc 1/2/3/4/5/6/15/16 into out (at most 7 + 2 * 123 bytes:
 *  FC16; FC15 7 + ceil(count / 8)). Returns its length. Arguments must already be
 *  validated (mbfb_check_args). */
int mbfb_build_request(uint8_t *out, int slave, int fc, int addr, int count,
                       const uint16_t *values);

/** Length of the correct, non-exception reply frame for a request frame. */
int mbfb_reply_len(const uint8_t *req);

/** Check reply frame `rsp` (len bytes) against request frame `req`: slave, function,
 *  byte count (2 x registers, ceil(bits / 8)), the echo of FC05/06/15/16, exception.
 *  Returns 0 when good (read values, or bytes of bits, are then at rsp+3),
 *  MBFB_E_EXCEPTION_BASE + code for an exception reply, or MBFB_E_BADREPLY. */
int mbfb_check_reply(const uint8_t *req, const uint8_t *rsp, int len);

/** The next whole, checked reply frame in bytes heard on the line (buf[*pos..n)): a
 *  frame with a good CRC (RTU, RTU without CRC: replies carry one) or a ':' hex LRC CR LF
 *  frame (ASCII). Copies it (slave + PDU) into frame, moves *pos past it and returns its
 *  length; 0 when there is none (*pos = n). */
int mbfb_next_reply(int framing, const uint8_t *buf, int n, int *pos, uint8_t *frame);

/** Value of an upper- or lower-case hex digit (ASCII framing), or -1. */
int mbfb_hex_digit(int c);

/** Validate post arguments; 0 or MBFB_E_INVAL. */
int mbfb_check_args(int slave, int fc, int addr, int count, const uint16_t *values);

/** Bytes on the wire (slave + PDU + CRC) of the RTU reply whose first `got` bytes are at b,
 *  from its function code and byte count: > 0, -1 when more bytes are needed to tell (the
 *  byte count), or 0 when its function code gives no length. The one rule for framing a
 *  reply ourselves (late replies heard, RTU over TCP); libmodbus has its own. */
int mbfb_rtu_reply_wire_len(const uint8_t *b, int got);

/** Bits packed in words (MBFB_BIT_WORDS) -> the wire's bytes of `n` bits (FC15, FC01/02
 *  replies), LSB first; the bits past n in the last byte are 0. */
void mbfb_bits_to_bytes(const uint16_t *words, int n, uint8_t *out);
/** The wire's bytes of `n` bits -> MBFB_BIT_WORDS(n) words; the bits past n are 0. */
void mbfb_bytes_to_bits(const uint8_t *in, int n, uint16_t *words);
/** Does `read` (its read-back, mbfb_fc_readback) show what write (fc, count, vals) wrote?
 *  Registers word for word, coils bit for bit (FC05: ON when vals[0] != 0). */
int mbfb_readback_shows(int fc, int count, const uint16_t *vals, const uint16_t *read);

/* ---- timing (mbfb_timing.c) ---------------------------------------------- */
typedef struct mbfb_timing {
    int char_us;      /* one character on the line                              */
    int gap_us;       /* silence before every request: max(3.5 char, 44 bits)   */
    int byte_us;      /* max silence inside a reply once it started             */
    int net_us;       /* added to every response timeout (RTU over TCP), else 0 */
} mbfb_timing_t;

/** Derive the line timing from baud and character format (README "Timing"). */
void mbfb_timing_init(mbfb_timing_t *t, int baud, char parity, int data_bits, int stop_bits);
/** Bytes on the wire for a frame of `frame_len` (slave+PDU) in a framing. */
int mbfb_wire_len(int framing, int frame_len);
/** Derived response timeout (us) for a request/reply pair (see README formula). */
int mbfb_response_timeout_us(const mbfb_timing_t *t, int framing, int req_frame_len,
                             int rsp_frame_len);
/** Monotonic clock in microseconds. */
int64_t mbfb_now_us(void);

/* ---- backends ---------------------------------------------------------------
 * One struct per transport, like libmodbus's own backend struct: transport data and
 * function pointers. Functions return 0 / a length on success, or a negative
 * -MBFB_E_* code: -MBFB_E_TIMEOUT, -MBFB_E_CRC, -MBFB_E_BADREPLY, -MBFB_E_PORTLOST,
 * -MBFB_E_NOPORT. A backend keeps its own state (the libmodbus context) behind
 * bus->be_priv; the worker sees only bus->fd. */
struct mbfb_bus;
typedef struct mbfb_backend {
    int header_len;   /* bytes before the slave id on the wire (TCP MBAP: 6)          */
    int check_len;    /* check bytes after the frame (CRC 2, LRC 1 (hex: 2), TCP 0)   */
    int needs_resync; /* 1: no transaction id; after a failed attempt the device is out
                         of step until a resync read is answered (serial lines).
                         0: a failed attempt reconnects (TCP), which is in step.      */
    /** Open the port (the worker, on the first request or after a loss). */
    int  (*open)(struct mbfb_bus *bus);
    /** Close the port; bus->fd becomes -1. */
    void (*close)(struct mbfb_bus *bus);
    /** Before every attempt: discard pending input and, on a serial line, wait until
     *  the line has been silent for silence_us since bus->quiet_from_us; every byte
     *  heard meanwhile is read, discarded and restarts the silence; after limit_us in
     *  all the wait ends anyway (a babbling line). Returns the bytes discarded (>= 0)
     *  or -MBFB_E_PORTLOST. */
    int  (*quiet)(struct mbfb_bus *bus, int silence_us, int limit_us);
    /** After a failed attempt when !needs_resync: reconnect (a late reply can only
     *  come on the old connection). NULL for serial lines. */
    void (*reconnect)(struct mbfb_bus *bus);
    /** Send one request frame (slave + PDU); the backend adds header and check bytes. */
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
extern const mbfb_backend_t mbfb_backend_rtutcp; /* RTU frames on TCP, written here */

/** "tcp://host:port" -> host (without the brackets of [::1]) and the port text
 *  (mbfb_backend_rtutcp.c). 0, or -1 when it has no host or port. */
int  mbfb_tcp_split(const char *port, char *host, size_t n, const char **service);

/* libmodbus helpers (mbfb_backend_lm.c): every serial framing's port is opened and
 * configured by libmodbus (modbus_new_rtu + modbus_connect), so termios settings are
 * never hand-written; the context lives in bus->be_priv. */
int  mbfb_lm_serial_open(struct mbfb_bus *bus);
void mbfb_lm_close(struct mbfb_bus *bus);
/** Map an errno from libmodbus or read/write to -MBFB_E_*. */
int  mbfb_errno_to_err(int err);
/** 1 if libmodbus's RTU backend sets `baud` exactly (its speed table), else 0. */
int  mbfb_lm_baud_ok(int baud);
/** Set bus->cfg.baud on the open port with termios2/BOTHER (when `set`: a rate outside
 *  libmodbus's table) and check the rate the driver will run at (mbfb_baud.c): 0, or
 *  -MBFB_E_BAUD when the driver refuses it or runs more than 1 % off (one stderr line per
 *  bus names the rate). */
int  mbfb_serial_set_baud(struct mbfb_bus *bus, int set);
/** The sysfs driver name and device path of the serial port fd (mbfb_serial.c): 0 or -1. */
int  mbfb_serial_driver(int fd, char *driver, size_t n, char *devpath, size_t m);
/** ASYNC_LOW_LATENCY on a USB serial adapter (ftdi_sio: latency timer 1 ms instead of 16):
 *  1 when in force after the call, else 0 (mbfb_serial.c). */
int  mbfb_serial_low_latency(int fd);

/* RS-485 direction control (mbfb_direction.c); the serial backends call these. With
 * MBFB_DIR_NONE (and KERNEL, where the kernel switches) begin and end do nothing. */
/** After the port opened: put it into bus->cfg.direction's mode, line idle. 0, or
 *  -MBFB_E_DIRECTION when the port, driver or GPIO refuses it. */
int  mbfb_dir_open(struct mbfb_bus *bus);
/** Before the port closes: leave the mode, release the GPIO line. */
void mbfb_dir_close(struct mbfb_bus *bus);
/** Before a request's first byte: line to sending, dir_before_us waited.
 *  0 or -MBFB_E_PORTLOST. */
int  mbfb_dir_begin(struct mbfb_bus *bus);
/** Right after writing the frame (frame_len: slave + PDU; sent_rc: the write's result):
 *  wait until it has left the UART and dir_after_us, then line to receiving. Returns
 *  sent_rc when it is an error, else 0 or -MBFB_E_PORTLOST. */
int  mbfb_dir_end(struct mbfb_bus *bus, int frame_len, int sent_rc);

/* serial helpers (mbfb_serial.c) */
/** The watched silence of every serial framing (see mbfb_backend_t.quiet). */
int  mbfb_serial_quiet(struct mbfb_bus *bus, int silence_us, int limit_us);
/** Wait up to wait_us (microseconds) for input on fd: 1 readable (or hung up),
 *  0 nothing came, -1 poll failed. */
int  mbfb_fd_wait_input(int fd, int64_t wait_us);
/** write() all of buf on the bus fd (non-blocking fd; waits with poll). */
int  mbfb_fd_write_all(struct mbfb_bus *bus, const uint8_t *buf, int len);

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
    int policy;             /* MBFB_WRITE_* for writes                           */
    int chain;              /* 1: a chain (mbfb_post_chain) of `count` entries: registers
                               in values[0..count), words in values[count..2 count)   */
    int result;             /* MBFB_OK or positive MBFB_E_* (written by worker)  */
    int nvals;              /* registers read (bits: FC01/02); a chain: entries held
                               (atomic: worker writes, mbfb_chain_held reads)      */
    uint16_t values[MBFB_MAX_READ]; /* write values in, read values out          */
} mbfb_slot_t;
/* a chain's registers and words fit in one slot, and so do the most bits a request carries */
typedef char mbfb_chain_fits_a_slot[2 * MBFB_CHAIN_MAX <= MBFB_MAX_READ ? 1 : -1];
typedef char mbfb_bits_fit_a_slot[MBFB_BIT_WORDS(MBFB_MAX_READ_BITS) <= MBFB_MAX_READ &&
                                  MBFB_BIT_WORDS(MBFB_MAX_READ_BITS) <= MBFB_PLAN_MAX_WORDS
                                  ? 1 : -1];

/* ---- devices ------------------------------------------------------------- */
/** Reply shape of a failed attempt whose reply may still come (README "Late replies"):
 *  what a late reply to it would look like. A read's reply is told by (fc, byte count); a
 *  write's echo by fc and its first two words (address, and value (FC05/06) or count
 *  (FC15/16)). */
typedef struct mbfb_shape {
    int fc;                  /* function code of the request                      */
    int bytes;               /* reads: the reply's byte count (mbfb_read_bytes)   */
    int addr, count;         /* reads: the range (a probe reads it again)          */
    uint16_t echo[2];        /* writes: the echo's address and value / count (the request's
                                words 2..5, mbfb_build_request)                      */
    int64_t t_us;            /* when that attempt was sent                         */
    int readable;            /* reads: inside a range that read well, so never answered
                                with a fixed exception (mbfb_resync.c)              */
} mbfb_shape_t;

/** A read range known to be readable on the device (plan items, good reads). */
typedef struct mbfb_range {
    int fc, addr, count;
} mbfb_range_t;

/** A device's protocol state (README "Late replies"; mbfb_device.c: its transitions, the
 *  only place that writes it). Serial lines (and RTU over TCP) have no transaction id, so a
 *  failed attempt leaves the device out of step; Modbus TCP reconnects instead and knows
 *  only IN_STEP and BACKOFF. */
typedef enum mbfb_dev_state {
    MBFB_DEV_IN_STEP = 0,    /* no reply of an earlier request can still come: a request
                                goes as it is (zero: a new device)                   */
    MBFB_DEV_OUT_OF_STEP,    /* a failed attempt's reply may still come: only resync
                                reads go, until one is answered                      */
    MBFB_DEV_BACKOFF,        /* MBFB_OFFLINE_AFTER requests in a row unanswered: nothing
                                goes before next_probe_us, then one probe            */
    MBFB_DEV_SHAPES_FULL     /* out of step with every reply shape outstanding: nothing
                                goes until the oldest expires (next_probe_us), then one
                                probe                                                */
} mbfb_dev_state_t;

/** What happens to a device (mbfb_dev_event). */
typedef enum mbfb_dev_event {
    MBFB_EV_ATTEMPT_FAILED,  /* an attempt got no valid reply (its reply may come late)  */
    MBFB_EV_RESYNCED,        /* a resync read was answered: nothing older can follow     */
    MBFB_EV_ANSWERED,        /* the device answered a request, or was heard answering     */
    MBFB_EV_UNANSWERED,      /* a request that put attempts on the wire got no answer     */
    MBFB_EV_SHAPES_FULL      /* no resync read possible: every reply shape outstanding    */
} mbfb_dev_event_t;

typedef struct mbfb_dev {
    int bus, slave;          /* set once at mbfb_dev_open, before publication     */
    mbfb_diag_t diag;        /* each field written by the worker with __atomic     */
    uint32_t diag_seq;       /* atomic: bumped after every diag change            */
    /* protocol state: worker only, written by mbfb_dev_event alone */
    mbfb_dev_state_t state;
    int fails;               /* requests unanswered in a row (MBFB_OFFLINE_AFTER)  */
    int64_t next_probe_us;   /* BACKOFF, SHAPES_FULL: nothing goes before then     */
    /* resynchronisation: worker only (mbfb_resync.c) */
    int n_outstanding;       /* reply shapes of failed attempts that may still come */
    mbfb_shape_t outstanding[MBFB_OUTSTANDING_MAX];
    int n_known;             /* ranges that read well, most recent first          */
    mbfb_range_t known[MBFB_KNOWN_READS];
    /* refreshes: worker only */
    int64_t last_refresh_us;
    int heard;               /* a late reply of it was heard since its last refresh:
                                a plan whose refresh failed is due again at once     */
} mbfb_dev_t;

/* ---- plans ------------------------------------------------------------------
 * Settings are written by the scan (mbfb_plan_set) field by field with __atomic
 * stores inside a sequence lock (cfg_seq odd while writing) and copied by the worker
 * at the start of a refresh. Snapshots go the other way in a triple buffer with one
 * producer (the worker) and one consumer (the block that owns the plan): at any time
 * the worker owns buf[back], the scan owns buf[front], and buf[mid & 3] is the one in
 * between. The worker fills its buffer with plain stores and swaps it with the middle
 * one (atomic exchange, acq_rel, MBFB_SNAP_FRESH set); the scan swaps its buffer with
 * the middle one only when FRESH is set and then copies the buffer it owns with
 * memcpy. A buffer is written only by the thread that owns it and handed over by an
 * acq_rel exchange, so there is no data race (C11) and no copy can be torn. */
#define MBFB_SNAP_FRESH 4u  /* in mid: the middle buffer holds a snapshot not taken yet */
#define MBFB_SNAP_PARKED 8u /* in mid: ... the failed snapshot of a plan parked for want of
                               scans: the take that gets it wakes the worker           */

typedef struct mbfb_snapbuf {
    mbfb_snap_t snap;        /* plain: owned by whoever holds the buffer's index   */
    int nwords;              /* words[0..nwords) written (the items' words)       */
} mbfb_snapbuf_t;

/** The slow tier of a plan (MBFB_TIER_SLOW items: a device's settings). It is due every
 *  slow period, and whenever its generation moves: the one way to make it due at once,
 *  taken by mbfb_plan_invalidate and mbfb_plan_set. A slow read made for a new generation
 *  is owed to the scan: every refresh reads it again until a take reaches a snapshot
 *  holding it (refreshes may outpace scans). */
typedef struct mbfb_slow {
    uint32_t gen;            /* atomic: bumped by mbfb_plan_invalidate and, inside the
                                settings' sequence lock, by mbfb_plan_set             */
    /* worker only */
    uint32_t read_gen;       /* gen of the last refresh that read the slow tier      */
    uint32_t owed_seq;       /* seq of the first snapshot of a read owed to the scan,
                                0 = none                                             */
    int64_t next_us;         /* when the slow period makes it due again              */
} mbfb_slow_t;

typedef struct mbfb_plan {
    int dev, bus;            /* set once at mbfb_plan_open                         */
    /* settings (scan writes, worker reads; all atomic) */
    uint32_t cfg_seq;        /* sequence lock: odd while plan_set writes          */
    int running;             /* 1 after mbfb_plan_set, 0 after mbfb_plan_stop      */
    int n, period_ms, slow_ms; /* period_ms: >= 0 or MBFB_PERIOD_ON_DEMAND           */
    mbfb_plan_item_t items[MBFB_PLAN_MAX_ITEMS];
    uint32_t taken;          /* atomic: seq of the snapshot mbfb_plan_take copied last */
    uint32_t trigger;        /* atomic: bumped by mbfb_plan_trigger (scan)          */
    uint32_t trigger_seen;   /* worker only: `trigger` when the last refresh started:
                                a refresh is due at once while they differ          */
    mbfb_slow_t slow;        /* the slow tier (gen: scan; the rest: worker)        */
    /* worker only */
    uint32_t cfg_seen;       /* cfg_seq of the settings of the last refresh        */
    int64_t last_start_us;
    int failed;              /* the last refresh failed                           */
    uint32_t seq;            /* refreshes published                               */
    /* a block that stops scanning (mbfb_plan_parked), worker only: the scan side writes
       nothing for it; a snapshot still FRESH in the middle buffer is one not taken */
    int64_t untaken_us;      /* when the oldest snapshot not taken yet was published
                                (0: after an unpark, no scan interval to learn from it) */
    int64_t seen_us;         /* when a look last saw it still untaken                  */
    int64_t scan_us;         /* the block's scan interval as the worker saw it: how long
                                the last snapshot taken was seen untaken              */
    int64_t stale_us;        /* a snapshot untaken this long parks the plan:
                                MBFB_STALE_PERIODS x the longer of period and scan
                                interval, at least MBFB_STALE_MIN_MS                 */
    int parked;              /* 1: parked, until its MBFB_SNAP_PARKED snapshot is taken
                                or its settings change (parked_cfg)                   */
    uint32_t parked_cfg;     /* cfg_seq when it parked                               */
    int back;                /* worker only: the buffer it fills next (0..2)      */
    /* snapshots */
    uint32_t pub;            /* atomic: number of the newest published refresh (for
                                benchmarks and tests; the scan reads mid)           */
    uint32_t mid;            /* atomic: index of the middle buffer | MBFB_SNAP_FRESH
                                | MBFB_SNAP_PARKED                                   */
    int front;               /* consumer only: the buffer mbfb_plan_take holds     */
    mbfb_snapbuf_t buf[3];
} mbfb_plan_t;

/* ---- bus ----------------------------------------------------------------- */
#define MBFB_BUSY_BUCKETS 10  /* busy_permille: 10 buckets of 100 ms */
#define MBFB_BUSY_BUCKET_US 100000

typedef struct mbfb_bus {
    char *port;              /* as given (tcp://host:port or a path)              */
    char *key;               /* identity of the port (README "Port identity")     */
    mbfb_bus_config_t cfg;   /* normalised copy; cfg.port points to `port`        */
    const mbfb_backend_t *be;
    void *be_priv;           /* the backend's state (libmodbus context)           */
    void *dir_priv;          /* the direction mode's state (mbfb_direction.c)     */
    mbfb_timing_t timing;
    int fd;                  /* the port's file descriptor, -1 when closed        */
    int baud_said;           /* worker: the baud refusal was printed (once per bus) */
    int64_t quiet_from_us;   /* the line is silent from this time on              */
    int64_t reopen_us;       /* worker: plans try to open the port again from then */
    int timeout_us;          /* response timeout of the current attempt           */
    int settle_us;           /* silence owed before the next attempt to another slave:
                                the response timeout of a failed attempt (its late reply
                                may still come and would fail that slave's request);
                                a resync read to the failed slave itself owes none     */
    int settle_slave;        /* the slave whose attempt failed (settle_us)          */
    uint32_t stray_bytes;    /* atomic: bytes discarded outside replies (diag)     */
    uint8_t heard[MBFB_HEARD_MAX]; /* worker: the last bytes heard during the silence
                                wait before this attempt (mbfb_serial_quiet), for late
                                replies (mbfb_resync.c, mbfb_hear_late_replies)      */
    int n_heard;
    uint32_t transactions;   /* atomic: attempts put on the wire                   */
    uint32_t busy_epoch[MBFB_BUSY_BUCKETS]; /* atomic: 100 ms period of the bucket */
    uint32_t busy_us[MBFB_BUSY_BUCKETS];    /* atomic: line busy in that period   */
    uint32_t busy_permille;  /* atomic: the buckets of the last second summed, 0..1000;
                                kept by the worker (after each attempt, when it goes idle,
                                and once when the window empties), so the scan reads it
                                with one load (mbfb_dev_diag, mbfb_bus_diag)          */
    int stop;                /* atomic: set by mbfb_shutdown (the library's unload): the
                                worker ends the attempt on the wire, starts no other,
                                closes the port and returns (README "Lifetime")      */
    uint32_t post_seq;       /* atomic: next sequence number                      */
    int wake_fd;             /* eventfd the worker waits on (mbfb_wake.c), -1: none */
    uint32_t wake_pending;   /* atomic: posts since the worker last looked            */
    int waiting;             /* atomic: the worker waits on wake_fd: the first post since
                                it looked writes wake_fd (mbfb_wake.c)               */
    uint32_t scans;          /* atomic: bumped by mbfb_post_write and mbfb_poll: the PLC is
                                still scanning the blocks that post to this bus      */
    uint32_t scans_seen;     /* worker only: `scans` at its last look (mbfb_slot_next), */
    int64_t scanned_us;      /* and when it saw it change                            */
    pthread_t worker;
    int index;
    int n_plans;             /* atomic: plans[0..n_plans) published               */
    mbfb_plan_t *plans[MBFB_PLANS_PER_BUS]; /* atomic pointers                   */
    int rr;                  /* worker: round robin position among plans          */
    mbfb_slot_t slots[MBFB_MAX_SLOTS];
} mbfb_bus_t;

/* registry (mbfb_bus.c); entries are published with release stores */
extern mbfb_bus_t *mbfb_buses[MBFB_MAX_BUSES];
extern mbfb_dev_t *mbfb_devs[MBFB_MAX_DEVICES];
extern mbfb_plan_t *mbfb_plans[MBFB_MAX_PLANS];
/** The registry mutex of the setup calls (never taken by the scan or the worker). */
extern pthread_mutex_t mbfb_registry_lock;

/* worker side of the slots (mbfb_req.c) */
/** The oldest queued request posted (or queued again: a chain's next entry) before
 *  sequence number *before (NULL: any), chains only when `chains`, made ACTIVE; NULL if
 *  none. */
mbfb_slot_t *mbfb_slot_next(mbfb_bus_t *bus, const uint32_t *before, int chains);
/** A chain's entry held and more to come: ACTIVE -> QUEUED again, behind every request
 *  posted so far (cancelled meanwhile: FREE). */
void mbfb_slot_requeue(mbfb_bus_t *bus, mbfb_slot_t *s);
void mbfb_slot_finish(mbfb_slot_t *s, int result);     /* ACTIVE -> DONE/FAILED  */
void mbfb_slot_fail_queued(mbfb_bus_t *bus, int result);

/* worker side of the plans (mbfb_plan.c) */
/** A plan's settings as the worker copies them at the start of a refresh. */
typedef struct mbfb_plan_cfg {
    mbfb_plan_item_t items[MBFB_PLAN_MAX_ITEMS];
    int n, period_ms, slow_ms;
    int nwords;              /* the items' words in all (a snapshot's length)       */
    uint32_t seq;            /* cfg_seq of this copy                                */
    uint32_t slow_gen;       /* the slow tier's generation, read inside the lock    */
} mbfb_plan_cfg_t;

/** Copy a plan's settings (sequence lock); 0 if it is not running. */
int  mbfb_plan_read_cfg(mbfb_plan_t *p, mbfb_plan_cfg_t *cfg);
/** Has the plan's block stopped taking snapshots (one untaken for p->stale_us, kept here,
 *  on the worker's clock `now`)? Then it is parked: 1, and once, when it parks, a failed
 *  snapshot (MBFB_E_STOPPED) replaces the one the block has not taken, so data from before
 *  the stop are never taken as new. The take of that snapshot, or new settings, unpark it. */
int  mbfb_plan_parked(mbfb_plan_t *p, int64_t now);
/** Publish refresh number p->seq + 1 (words: the items' words in order). */
void mbfb_plan_publish(mbfb_plan_t *p, int result, uint32_t gen, uint32_t read_mask,
                       const uint16_t *words, int nwords);
/** Every running plan of the bus ends its refresh now with `err` (the port could not be
 *  opened); none is due again before bus->reopen_us. */
void mbfb_plans_no_port(mbfb_bus_t *bus, int64_t now, int err);

/* the worker (mbfb_worker.c) */
void *mbfb_worker_main(void *arg);

/* waking the worker (mbfb_wake.c): an eventfd, so that the idle worker waits on the port
 * and on posts in one ppoll and uses no CPU until one of them comes */
/** Create bus->wake_fd. 0, or -1 when the system has no eventfd left. */
int  mbfb_wake_open(mbfb_bus_t *bus);
/** Close bus->wake_fd (the worker has stopped). */
void mbfb_wake_close(mbfb_bus_t *bus);
/** Scan side (post, plan_set, shutdown): wake the worker. Never blocks; a write() only
 *  when the worker waits and no post before this one since it looked has woken it. */
void mbfb_wake(mbfb_bus_t *bus);
/** Worker: take the posts made so far (the checks after this call see each of them). */
void mbfb_wake_take(mbfb_bus_t *bus);
/** Worker: wait until `until` (monotonic us; INT64_MAX: no limit) or a wake, or, with
 *  port_fd >= 0, input on the port. 1 when the port has input, else 0. */
int  mbfb_wake_wait(mbfb_bus_t *bus, int port_fd, int64_t until);

/* one request of a device (mbfb_attempt.c) */
/** Request of a device as the worker runs it: a posted one or a plan read. */
typedef struct mbfb_request {
    int devidx, fc, addr, count, policy;
    const uint16_t *vals;    /* writes                                               */
    uint16_t *out;           /* reads: count registers, or count bits packed          */
    int write_sent;          /* out: the write itself went on the wire (maybe applied) */
} mbfb_request_t;
/** Run one request: back-off, the port, its attempts (mbfb_attempt.c). Returns MBFB_OK or
 *  a positive MBFB_E_*; MBFB_E_NOPORT, _BAUD, _DIRECTION: the port did not open and every
 *  plan of the bus has published that (mbfb_plans_no_port). */
int  mbfb_device_request(mbfb_bus_t *bus, mbfb_request_t *request);
/** Wait for a silent line before an attempt to `slave`, hearing late replies meanwhile.
 *  0 or -MBFB_E_PORTLOST. */
int  mbfb_wait_quiet(mbfb_bus_t *bus, int slave);

/* a device's protocol state (mbfb_device.c) */
/** The one writer of dev->state: the transition `ev` makes (t: when, for the hold of
 *  BACKOFF and SHAPES_FULL), with the device's fails, next_probe_us and diag.offline. */
void mbfb_dev_event(mbfb_bus_t *bus, mbfb_dev_t *dev, mbfb_dev_event_t ev, int64_t t);
/** Is the device held back (BACKOFF, SHAPES_FULL): nothing before next_probe_us, then one
 *  probe? */
static inline int mbfb_dev_held(const mbfb_dev_t *dev)
{
    return dev->state == MBFB_DEV_BACKOFF || dev->state == MBFB_DEV_SHAPES_FULL;
}
/** May a request go to the device as it is (no late reply of it possible)? Always on
 *  Modbus TCP, whose failed attempts reconnect. */
static inline int mbfb_dev_in_step(const struct mbfb_bus *bus, const mbfb_dev_t *dev)
{
    return dev->state == MBFB_DEV_IN_STEP || !bus->be->needs_resync;
}

/* the line's use (mbfb_busy.c): busy_permille over the last second, in 100 ms buckets */
/** Sum the line's busy time of the last second into bus->busy_permille; returns when the
 *  window holds no busy time any more (INT64_MAX: none now). */
int64_t mbfb_busy_update(mbfb_bus_t *bus, int64_t now);
/** Account `us` of line time in the bucket of `now` (an attempt: request, turnaround,
 *  reply, the gap owed). */
void mbfb_busy_add(mbfb_bus_t *bus, int64_t now, int64_t us);

/* late replies and resync reads (mbfb_resync.c) */
/** Modbus exception codes a request draws each time it is sent, as the device's map does
 *  not change: illegal function, data address, data value. The others (device failure,
 *  acknowledge, busy) may answer any request. */
#define MBFB_EXC_FIXED_MAX 3
/** A whole, checked reply frame f heard outside its request: retire the outstanding
 *  shape of a device of this bus that it fits; 1 if one was retired, else 0. */
int  mbfb_retire_heard(mbfb_bus_t *bus, const uint8_t *f, int len);
/** Late replies among the bytes heard in the silence before a request (bus->heard). */
void mbfb_hear_late_replies(mbfb_bus_t *bus);
/** After a failed attempt (fc, addr, count, vals) sent at t: out of step (serial lines,
 *  MBFB_EV_ATTEMPT_FAILED), its reply shape outstanding. */
void mbfb_out_of_step(mbfb_bus_t *bus, mbfb_dev_t *dev, int fc, int addr, int count,
                      const uint16_t *vals, int64_t t);
/** A resync read was answered: in step (MBFB_EV_RESYNCED), nothing outstanding, no settle
 *  owed for it. */
void mbfb_in_step(mbfb_bus_t *bus, mbfb_dev_t *dev);
/** Remember a range that read well (most recent first). */
void mbfb_remember_read(mbfb_dev_t *dev, int fc, int addr, int count);
/** Could an outstanding request still be answered with exception `code` (0: any) of fc? */
int  mbfb_exception_outstanding(const mbfb_dev_t *dev, int fc, int code);
/** The resync read for a request (fc, addr, count; readback: a write of unknown outcome)
 *  of device devidx: 1 with *r, or 0 when the outstanding set is full. */
int  mbfb_pick_resync(mbfb_bus_t *bus, int devidx, int fc, int addr, int count,
                      int readback, mbfb_range_t *r);
/** The probe of a device in back-off: 1 with *r, or 0 when no read shape is outstanding. */
int  mbfb_pick_probe(const mbfb_dev_t *dev, mbfb_range_t *r);

/** The bus is being shut down (mbfb_shutdown, the library's unload): no new attempt. */
static inline int mbfb_stopping(const mbfb_bus_t *bus)
{
    return __atomic_load_n(&bus->stop, __ATOMIC_ACQUIRE);
}
/* Long waits of the worker outside an attempt look at the stop flag this often. */
#define MBFB_STOP_SLICE_US 20000

/* diag helpers (worker writes, scan reads, all with __atomic); every change bumps
 * the device's diag_seq (release) after the field */
#define MBFB_DIAG_TOUCH(d) __atomic_fetch_add(&(d)->diag_seq, 1u, __ATOMIC_RELEASE)
#define MBFB_DIAG_INC(d, f) \
    (__atomic_fetch_add(&(d)->diag.f, 1u, __ATOMIC_RELAXED), MBFB_DIAG_TOUCH(d))
#define MBFB_DIAG_SET(d, f, v) \
    (__atomic_store_n(&(d)->diag.f, (v), __ATOMIC_RELAXED), MBFB_DIAG_TOUCH(d))
/* bytes heard outside any reply and discarded (bus-wide diag.stray_bytes) */
#define MBFB_STRAY_ADD(b, n) \
    __atomic_fetch_add(&(b)->stray_bytes, (uint32_t)(n), __ATOMIC_RELAXED)

#ifdef __cplusplus
}
#endif

#endif /* MBFB_INTERNAL_H */
