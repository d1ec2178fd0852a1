/*
 * mbfb.h - Modbus master shims for IEC 61131-3 function blocks.
 *
 * Public API of c_shims/. Every exported symbol starts with mbfb_ / MBFB_.
 * Compiles as C11 and as C++ (OpenPLC builds its core with g++).
 *
 * Model
 *   bus     one serial port (or tcp:// gateway) with its settings and ONE worker
 *           thread that does all I/O on it. Blocks naming the same port share it.
 *   device  (bus, slave id): owns diagnostics and the offline back-off state.
 *   request one Modbus transaction posted by a block; lives in a preallocated slot.
 *
 * Scan-side calls (mbfb_post, mbfb_post_write, mbfb_post_chain, mbfb_chain_held, mbfb_poll,
 * mbfb_take, mbfb_cancel, mbfb_plan_set/_stop/_invalidate/_trigger/_take, mbfb_dev_diag,
 * mbfb_dev_diag_seq, mbfb_bus_diag, mbfb_strerror) never block and never allocate; the only
 * system call they make is a write() to the bus's eventfd in mbfb_post, mbfb_post_write,
 * mbfb_post_chain, mbfb_plan_set and mbfb_plan_trigger, to wake the worker, and only when it
 * is waiting (none while it is busy),
 * and in the mbfb_plan_take that gets a parked plan's snapshot once the PLC scans again
 * after a stop (README "Lifetime").
 * Setup calls (mbfb_bus_open, mbfb_dev_open) may allocate and start the worker;
 * they do not wait for the port: opening happens on the worker, and a port that
 * cannot be opened makes that bus's requests end with MBFB_E_NOPORT.
 *
 * Errors are errno-style: functions returning int return a negative -MBFB_E_*
 * code on failure. Request results carry the positive code (0 = success).
 * The same numbers are the ErrorID outputs of every function block.
 */
#ifndef MBFB_H
#define MBFB_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- framings ---------------------------------------------------------- */
#define MBFB_FRAMING_RTU       0 /* Modbus RTU via libmodbus                        */
#define MBFB_FRAMING_ASCII     1 /* ':' hex LRC CR LF (written here: not in libmodbus) */
#define MBFB_FRAMING_RTU_NOCRC 2 /* MT-S9 Type 2: sends 00 00 as CRC, checks reply CRC */
#define MBFB_FRAMING_TCP       3 /* Modbus TCP (MBAP) via libmodbus; port "tcp://h:p" */

/* ---- request states (mbfb_poll) ------------------------------------------ */
#define MBFB_REQ_QUEUED 1 /* posted, waiting for the bus          */
#define MBFB_REQ_ACTIVE 2 /* on the wire (or retrying)             */
#define MBFB_REQ_DONE   3 /* finished well; mbfb_take gives data   */
#define MBFB_REQ_FAILED 4 /* finished with an error; mbfb_take says which */

/* ---- error codes: ONE table shared by shims and every function block ------
 * 1..63    communication / shim errors
 * 128+x    the device answered with Modbus exception x (129 = illegal function,
 *          130 = illegal data address, 131 = illegal data value, 132 = device failure)
 * 200..255 function-block input errors, found before anything is sent (st_src/)   */
#define MBFB_OK              0
#define MBFB_E_TIMEOUT       1  /* no reply after all retries                         */
#define MBFB_E_CRC           2  /* reply failed its CRC / LRC check (after retries)   */
#define MBFB_E_BADREPLY      3  /* wrong slave, function, byte count, echo, truncated */
#define MBFB_E_OFFLINE       4  /* device in back-off after repeated failures, or no
                                   resync read possible yet (README): not sent         */
#define MBFB_E_NOPORT        5  /* port does not exist / cannot be opened             */
#define MBFB_E_PORTLOST      6  /* port failed during I/O (EIO, adapter pulled)       */
#define MBFB_E_CANCELLED     7  /* cancelled by the block before completion           */
#define MBFB_E_QUEUEFULL     8  /* no free request slot on that bus                   */
#define MBFB_E_CONFLICT      9  /* port already open with other settings              */
#define MBFB_E_INVAL        10  /* bad argument: slave id, count, address, fc, framing */
#define MBFB_E_BADHANDLE    11  /* unknown or stale bus/device/request handle         */
#define MBFB_E_NOMEM        12  /* setup could not allocate / too many buses/devices  */
#define MBFB_E_UNCONFIRMED  13  /* write outcome unknown: no valid reply and the read-back
                                   did not show the value; not repeated (mbfb_post_write) */
#define MBFB_E_BAUD         14  /* baud rate the serial driver cannot set within 1 % (when
                                   the port opens; a stderr line names the rate it would
                                   run at), or above 4000000 (mbfb_bus_open)            */
#define MBFB_E_DIRECTION    15  /* RS-485 direction control refused when the port opens: the
                                   driver has no kernel RS-485 mode, RTS cannot be set, the
                                   GPIO chip or line is missing or busy, or no libgpiod
                                   (2 or 1) is installed; nothing was sent             */
#define MBFB_E_STOPPED      16  /* not done because the PLC stopped scanning the block: no
                                   snapshot taken for 10 periods (the plan's or the task's, at
                                   least 2 s), its plan stopped polling (one failed snapshot,
                                   seen when it is scanned again); no request polled or posted
                                   on the bus for as long, a queued request was not sent   */
#define MBFB_E_EXCEPTION_BASE 128 /* + Modbus exception code                          */
/* Function-block input errors (st_src/): found before anything is sent.              */
#define MBFB_E_BAD_SLAVE     200 /* SlaveId 0 for a read/monitoring block, or refused by
                                     mbfb_dev_check (> 247; > 255 on Modbus TCP)        */
#define MBFB_E_NO_PORT_NAME  201 /* Port empty or only spaces                             */
#define MBFB_E_RANGE         202 /* set point / value out of its range (LOLT..HILT,
                                     SP1L..SP1H, alarm +-1000 counts, MV1 0..100 %,
                                     an MT-S9 set-up value)                             */
#define MBFB_E_UNKNOWN_CODE  203 /* unknown code: alarm number, MT-S9 baud/protocol code;
                                     from the device: DP / Decimal Set outside its table
                                     (the refresh fails)                                */
#define MBFB_E_NOT_ALLOWED   204 /* command not allowed now: FDC MV1 outside manual mode,
                                     an MT-S9 set-up register above the Author level    */
#define MBFB_E_NOT_READY     205 /* the limits/scaling the check needs are not known, or
                                     stale (no valid refresh yet)                       */
#define MBFB_E_BAD_REQUEST   206 /* request invalid: a command's mbfb_post refused with
                                     MBFB_E_INVAL (function not 1/2/3/4/5/6/15/16, count 0
                                     or above 125 registers / 2000 bits (read), 123 (FC16)
                                     / 1968 (FC15), address + count above 65536, a read
                                     from slave 0)                                      */
#define MBFB_E_BAD_LINE      207 /* line settings invalid: mbfb_bus_open refused them with
                                     MBFB_E_INVAL or MBFB_E_BAUD (unknown Parity, Framing or
                                     Direction, TCP framing on a serial port, ASCII/NOCRC on
                                     tcp://, data bits not 8 (7 only with ASCII), stop bits
                                     not 1/2, baud < 0 or above 4000000, timeout outside
                                     0..60000 ms, Retries above 20, a direction delay above
                                     100 ms, GPIO without its chip or line)             */
#define MBFB_E_NOT_ENABLED   208 /* command on a device block whose Enable is FALSE     */
#define MBFB_E_NOT_HELD      209 /* a settings download's read-back shows another word
                                     than the one written (a chain entry: mbfb_post_chain) */
#define MBFB_E_BAD_PLAN      210 /* a block's ranges refused by mbfb_plan_set (MBFB_E_INVAL):
                                     a function not 1/2/3/4, a Count 0 or negative, above
                                     125 registers or 2000 bits, address + count above
                                     65536, or the ranges together above 125 words (bits
                                     packed 16 to a word); MB_Poll                      */
#define MBFB_E_OVERLAP       211 /* two ranges of the same function overlap on the device
                                     (MB_Poll)                                          */
#define MBFB_E_NO_RANGE      212 /* no range to read: every Fc is 0 (MB_Poll)             */

/* ---- RS-485 direction control (README "Direction control") ------------------
 * A half-duplex transceiver (MAX485 and the like) must drive the line while the master
 * sends and release it before the device answers. Who switches it: */
#define MBFB_DIR_NONE   0 /* the adapter or transceiver switches by itself (default)      */
#define MBFB_DIR_KERNEL 1 /* the UART driver's RS-485 mode (TIOCSRS485): the kernel drives
                             RTS around each frame, with the delays below (rounded up to ms) */
#define MBFB_DIR_RTS    2 /* the worker asserts RTS before each request and releases it
                             once the last bit has left (the UART's transmitter-empty bit
                             after the frame's wire time; tcdrain + one character where
                             the driver has none, as on USB adapters)                    */
#define MBFB_DIR_GPIO   3 /* the same with a GPIO line (Linux GPIO character device, through
                             libgpiod 2 or 1, loaded at run time)                         */
#define MBFB_DIR_MAX_DELAY_US 100000 /* dir_before_us / dir_after_us at most 100 ms        */
#define MBFB_GPIO_CHIP_MAX 32        /* gpio_chip[] size, with its NUL                     */

/* ---- setup ---------------------------------------------------------------- */

#define MBFB_DEFAULT_RETRIES 3 /* retries < 0: SetPro manual 5.6, retry at least 3 times */

/** Bus settings. Zero-initialise, then fill what you need. */
typedef struct mbfb_bus_config {
    const char *port;         /* "/dev/ttyUSB0", a pty path, or "tcp://127.0.0.1:1502" */
    int baud;                 /* e.g. 9600; ignored for TCP                            */
    char parity;              /* 'N', 'E' or 'O'                                       */
    int data_bits;            /* 7 or 8                                               */
    int stop_bits;            /* 1 or 2                                               */
    int framing;              /* MBFB_FRAMING_*                                         */
    int response_timeout_ms;  /* 0 = derived from frame lengths and baud               */
    int retries;              /* extra attempts after the first; <0 = default
                                 (MBFB_DEFAULT_RETRIES)                              */
    int direction;            /* MBFB_DIR_*: who switches an RS-485 transceiver (serial) */
    int dir_active_low;       /* 1: RTS released / the GPIO low while sending (the line's
                                 idle level is the other one); 0: asserted / high       */
    int dir_before_us;        /* line switched this long before the first bit           */
    int dir_after_us;         /* and held this long after the last bit has left         */
    char gpio_chip[MBFB_GPIO_CHIP_MAX]; /* MBFB_DIR_GPIO: "gpiochip0", "/dev/gpiochip0",
                                 a chip number or label (as libgpiod 1's lookup)          */
    int gpio_line;            /* MBFB_DIR_GPIO: the line's offset on that chip          */
} mbfb_bus_config_t;

/** Open (or join) the bus on cfg->port. A serial port is identified by the device it
 *  opens (realpath, then st_rdev of the node), so '/dev/serial/by-id/...', '//dev/x' or a
 *  symlink join the same bus. Returns a bus handle >= 0, or -MBFB_E_CONFLICT if that port
 *  is already open with other settings, -MBFB_E_BAUD for a baud above 4000000, -MBFB_E_INVAL
 *  for other bad settings. Any other baud is set exactly when the worker opens the port
 *  (termios2 where libmodbus has no constant); a driver that cannot set it ends the bus's
 *  requests and plans with MBFB_E_BAUD. */
int mbfb_bus_open(const mbfb_bus_config_t *cfg);

/** Same as mbfb_bus_open with flat arguments; port need not be NUL-terminated
 *  (port_len bytes are used), as an IEC STRING's body is not. parity: 0=N 1=E 2=O
 *  or the character 'N'/'E'/'O'. For calls from ST pragmas. */
int mbfb_bus_open_args(const char *port, int port_len, int baud, int parity, int data_bits,
                       int stop_bits, int framing, int response_timeout_ms, int retries);

/** mbfb_bus_open_args with the direction control (MBFB_DIR_*, see mbfb_bus_config_t);
 *  gpio_chip need not be NUL-terminated (gpio_chip_len bytes are used, trailing blanks
 *  trimmed). A direction mode other than NONE on tcp:// or with out-of-range delays or
 *  GPIO settings is -MBFB_E_INVAL. For calls from ST pragmas (MB_LINE). */
int mbfb_bus_open_line(const char *port, int port_len, int baud, int parity, int data_bits,
                       int stop_bits, int framing, int response_timeout_ms, int retries,
                       int direction, int dir_active_low, int dir_before_us, int dir_after_us,
                       const char *gpio_chip, int gpio_chip_len, int gpio_line);

/** Device handle for slave id `slave` on `bus` (0 = broadcast: writes only).
 *  Returns a device handle >= 0 or a negative error (-MBFB_E_INVAL for slave > 247). */
int mbfb_dev_open(int bus, int slave);

/** 0 if `slave` can be a device on a bus of `framing` (MBFB_FRAMING_*): 1..247, 0 =
 *  broadcast, up to 255 on Modbus TCP; else -MBFB_E_INVAL. mbfb_dev_open's check, callable
 *  before a bus is opened (a block refuses its SlaveId without claiming the port). */
int mbfb_dev_check(int framing, int slave);

/* ---- scan side: never block, never allocate ------------------------------- */

/* The Modbus functions a request or plan item carries (fc of mbfb_post, mbfb_post_write,
 * mbfb_plan_item_t); the ST blocks' MB_FUNCTION_CODES mirrors them. */
#define MBFB_FC_READ_COILS      1 /* bits, read/write on the device                     */
#define MBFB_FC_READ_DISCRETE   2 /* discrete inputs: bits, read-only                   */
#define MBFB_FC_READ_HOLDING    3
#define MBFB_FC_READ_INPUT      4
#define MBFB_FC_WRITE_COIL      5 /* one coil: ON is FF 00 on the wire, OFF 00 00        */
#define MBFB_FC_WRITE_SINGLE    6
#define MBFB_FC_WRITE_COILS    15
#define MBFB_FC_WRITE_MULTIPLE 16

/* Protocol limits per request (Modbus application protocol 1.1b3, 6.1 - 6.12), named once. */
#define MBFB_MAX_READ         125 /* FC03/FC04 registers                                 */
#define MBFB_MAX_WRITE        123 /* FC16 registers                                      */
#define MBFB_MAX_READ_BITS   2000 /* FC01/FC02 coils or inputs                           */
#define MBFB_MAX_WRITE_BITS  1968 /* FC15 coils                                          */

/* Bits are carried packed into words wherever this API carries them (values of mbfb_post,
 * mbfb_take, a plan snapshot's words): bit i of a range is bit (i % 16) of word (i / 16),
 * least significant first, as on the wire. A range of n bits fills MBFB_BIT_WORDS(n) words;
 * the bits past n in the last word are 0 in what the shims return and ignored in what they
 * are given. */
#define MBFB_BIT_WORDS(n) (((n) + 15) / 16)

/** Post a transaction. fc: 3, 4 (read `count` registers from `addr`), 6 (write values[0]
 *  to `addr`, count 1), 16 (write `count` values from `addr`); 1, 2 (read `count` bits,
 *  1..MBFB_MAX_READ_BITS, coils or discrete inputs), 5 (write one coil: ON when values[0]
 *  != 0, count 1), 15 (write `count` coils, 1..MBFB_MAX_WRITE_BITS, packed in values as
 *  MBFB_BIT_WORDS says). Values are copied. Returns a request handle > 0, or a negative
 *  error; nothing is sent on error (-MBFB_E_INVAL: function, count, address range, a read
 *  from slave 0). */
int mbfb_post(int dev, int fc, int addr, int count, const uint16_t *values);

/** State of a request: MBFB_REQ_QUEUED/ACTIVE/DONE/FAILED, or -MBFB_E_BADHANDLE. */
int mbfb_poll(int req);

/** Collect a finished request and free its slot. Copies up to `max` words read into
 *  `values` (may be NULL for writes): registers, or for FC01/02 the bits packed
 *  (MBFB_BIT_WORDS(count) words). Returns, when it succeeded, the number of registers
 *  copied, or for FC01/02 the number of bits copied (count when max holds them all), >= 0;
 *  else the negative error it failed with (e.g. -(128+2) for exception 2).
 *  Returns -MBFB_E_BADHANDLE if the request is unknown or not finished yet. */
int mbfb_take(int req, uint16_t *values, int max);

/** Cancel a request: frees the slot now if queued or finished; a request on the wire
 *  finishes its transaction and is discarded by the worker. Returns 0 or an error. */
int mbfb_cancel(int req);

/* ---- confirmed writes -------------------------------------------------------
 * A write is DONE only when the device is known to hold it: a correct echo to a request
 * no earlier request's late reply can match (the device is "in step", see README), or,
 * when the outcome is unknown (no valid echo), a read-back once the device is in step
 * again: FC03 of the written registers (FC06/16), FC01 of the written coils (FC05/15).
 * Never sent again while it may have been applied. */
#define MBFB_WRITE_IDEMPOTENT 0 /* absolute value (set points): read-back differs -> the
                                   write was not applied -> sent again (retries allow)    */
#define MBFB_WRITE_ONCE       1 /* command / counter preset: read-back shows it -> DONE;
                                   else MBFB_E_UNCONFIRMED, never sent twice              */

/** Post a write (fc 5, 6, 15 or 16, arguments as mbfb_post) with a confirmation policy
 *  (MBFB_WRITE_*). mbfb_post's writes are MBFB_WRITE_IDEMPOTENT. Returns a request handle
 *  > 0 or a negative error. */
int mbfb_post_write(int dev, int fc, int addr, int count, const uint16_t *values, int policy);

/* ---- chains: settings written in order, each confirmed and read back -------------
 * A chain is one request holding a list of single-register writes (a recipe). The worker
 * runs its entries in order at the wire's pace: each is written (FC06, confirmed as
 * MBFB_WRITE_IDEMPOTENT) and read back (FC03, one word), and is held only when the word
 * read is the word written. Posted requests and the bus's plan refreshes get their turn
 * between two entries (never between a write and its read-back), so a chain does not hold
 * the line. It stops at the first entry not held: the request FAILED with that entry's
 * error (MBFB_E_NOT_HELD when the read-back differs) and mbfb_chain_held tells how many
 * entries, from the first, are held. A chain between two entries is QUEUED: mbfb_cancel
 * ends it there (the entries held stay held), and the lifetime rules of a queued request
 * hold for it (MBFB_E_STOPPED, mbfb_shutdown). */
#define MBFB_CHAIN_MAX 62 /* entries per chain: its registers and words fill one slot */

/** Post a chain of n (1..MBFB_CHAIN_MAX) entries: entry i writes words[i] to holding
 *  register regs[i]. Both arrays are copied. Returns a request handle > 0 (mbfb_poll,
 *  mbfb_take, mbfb_cancel as for any request) or a negative error, nothing sent:
 *  -MBFB_E_INVAL for n out of range or a broadcast device (no read-back). */
int mbfb_post_chain(int dev, int n, const uint16_t *regs, const uint16_t *words);

/** Entries of chain `req` held so far, from the first (all of them once it is DONE; those
 *  before the entry that failed once it is FAILED): >= 0, or -MBFB_E_BADHANDLE for an
 *  unknown or taken handle or a request that is not a chain. Read it before mbfb_take. */
int mbfb_chain_held(int req);

/* ---- refresh plans: a device's whole refresh, run by the worker ----------------
 * A plan is the list of reads that make one refresh of a device. The worker runs a
 * plan's reads back to back at the wire's pace, every period (0 = as often as the line
 * allows, shared fairly with the bus's other plans; MBFB_PERIOD_ON_DEMAND = only when
 * triggered, mbfb_plan_trigger), and publishes each finished refresh as one snapshot.
 * Posted requests (writes) go before the next read of any plan.
 * Scan side: mbfb_plan_take costs one atomic load when nothing is new; no system call,
 * no lock, no allocation. mbfb_plan_set / _stop / _invalidate are scan-safe too. A plan
 * whose snapshot stays untaken for 10 periods (its own or its block's scan interval, at
 * least 2 s) stops polling until the next take (README "Lifetime"), which gets one
 * snapshot with result MBFB_E_STOPPED.
 * One consumer per plan: a plan's snapshots are handed over in a triple buffer whose
 * reading end mbfb_plan_take holds, so call it for one plan from one thread at a time
 * (the block that opened the plan); other plans, devices and buses are independent. */
#define MBFB_PLAN_MAX_ITEMS 4   /* reads per refresh                                   */
#define MBFB_PLAN_MAX_WORDS 125 /* all items' words together (one IEC MB_REGS)         */
#define MBFB_PERIOD_ON_DEMAND -1 /* period_ms of mbfb_plan_set: a refresh when set and
                                   then only when triggered (mbfb_plan_trigger)        */
#define MBFB_TIER_EVERY 0       /* read in every refresh                               */
#define MBFB_TIER_SLOW  1       /* read when the slow tier is due: every slow period,
                                   in the first refresh, and after mbfb_plan_invalidate */
#define MBFB_TIER_FAST  2       /* read only in refreshes without the slow tier        */

typedef struct mbfb_plan_item {
    int fc;     /* 3, 4 (registers) or 1, 2 (coils, discrete inputs)                 */
    int addr;
    int count;  /* registers 1..MBFB_MAX_READ, or bits 1..MBFB_MAX_READ_BITS filling
                   MBFB_BIT_WORDS(count) words; all items' words together at most
                   MBFB_PLAN_MAX_WORDS                                               */
    int tier;   /* MBFB_TIER_* */
} mbfb_plan_item_t;

/** One finished refresh. words[] holds item i at offset sum(words of items < i), where an
 *  item of registers has `count` words and one of bits MBFB_BIT_WORDS(count), packed; an
 *  item not read in this refresh (read_mask bit clear) has its words zeroed. */
typedef struct mbfb_snap {
    uint32_t seq;        /* refresh number, 1, 2, ... (0: none yet)                     */
    int32_t  result;     /* MBFB_OK, or the MBFB_E_* of the read that failed (then no
                            word is valid)                                              */
    uint32_t gen;        /* the slow tier's generation (mbfb_plan_invalidate; moved by
                            mbfb_plan_set too) when this refresh started: slow items
                            read in it were read after that call                       */
    uint32_t read_mask;  /* bit i: item i was read (and checked) in this refresh        */
    uint16_t words[MBFB_PLAN_MAX_WORDS];
} mbfb_snap_t;

/** Open a plan on device `dev` (setup call: may allocate). Not started until
 *  mbfb_plan_set. Returns a plan handle >= 0 or a negative error. */
int mbfb_plan_open(int dev);

/** Set a plan's reads, its period and slow period (ms) and start it (again); the slow tier
 *  is due in the first refresh under them (its generation moves, as with
 *  mbfb_plan_invalidate). period_ms >= 0, or MBFB_PERIOD_ON_DEMAND: one refresh now, then
 *  one per mbfb_plan_trigger (the lifetime rule then counts the block's scan interval).
 *  A refresh on the wire finishes under the old settings. Returns 0 or -MBFB_E_INVAL (bad
 *  item, too many words, bad period), -MBFB_E_BADHANDLE. */
int mbfb_plan_set(int plan, const mbfb_plan_item_t *items, int n, int period_ms,
                  int slow_period_ms);

/** Stop a plan: no refresh starts after this call (Enable FALSE). 0 or an error. */
int mbfb_plan_stop(int plan);

/** Make the plan's next refresh due now: one refresh starts as soon as the line allows
 *  (the device's back-off and the port's reopening still hold it back), whether or not its
 *  period has elapsed, and a snapshot from after this call follows. Triggers before that
 *  refresh starts make one. Scan-safe (wakes the worker as mbfb_plan_set does). 0, or
 *  -MBFB_E_BADHANDLE. */
int mbfb_plan_trigger(int plan);

/** Make the slow tier due in the next refresh that starts after this call (after a
 *  command, a scaling change). Returns the new generation (compare with mbfb_snap.gen),
 *  or a negative error. */
int mbfb_plan_invalidate(int plan);

/** If a refresh newer than *seq has finished, copy the newest one into *out (its header
 *  and its items' words; words past them are left as they were), set *seq to its number
 *  and return 1; return 0 when nothing is new (one atomic load); or a negative error.
 *  A copy is always one whole refresh: the buffer copied belongs to the caller until its
 *  next take (the worker writes only buffers no take holds). */
int mbfb_plan_take(int plan, uint32_t *seq, mbfb_snap_t *out);

/** Per-device diagnostics. */
typedef struct mbfb_diag {
    uint32_t requests;        /* transactions started (retries count separately below) */
    uint32_t good;            /* valid replies                                        */
    uint32_t timeouts;        /* attempts without a reply                             */
    uint32_t crc_errors;      /* replies with a bad CRC / LRC                         */
    uint32_t bad_replies;     /* malformed / wrong slave / wrong echo                 */
    uint32_t exceptions;      /* exception replies                                    */
    uint32_t retries;         /* attempts beyond the first                            */
    uint32_t last_exception;  /* last exception code (1..255), 0 if none              */
    uint32_t last_rtt_us;     /* round trip of the last good reply, microseconds     */
    uint32_t offline;         /* 1 while the device is in back-off                    */
    int32_t  last_error;      /* last MBFB_E_* code on this device (0 = none)         */
    uint32_t stray_bytes;     /* bytes heard on this device's BUS outside any reply
                                 (late replies, noise), read and discarded; the same
                                 count for every device of the bus                    */
    uint32_t resyncs;         /* requests sent only to get back in step after a failed
                                 attempt (README, "Late replies")                      */
    uint32_t refreshes;       /* plan refreshes finished well on this device          */
    uint32_t refresh_us;      /* time between the starts of its last two refreshes    */
    uint32_t line_permille;   /* its bus's busy_permille (mbfb_bus_diag_t) when copied */
} mbfb_diag_t;

/** Copy the device's diagnostics into *out. Returns 0 or -MBFB_E_BADHANDLE. */
int mbfb_dev_diag(int dev, mbfb_diag_t *out);

/** A number that changes whenever the device's diagnostics change (one atomic load): copy
 *  them with mbfb_dev_diag only when it differs from the last one seen. line_permille
 *  does not move it: a copy holds the line's use as of that copy (a line gone quiet
 *  reads 0 in a copy made a second later, not in the last one made). */
uint32_t mbfb_dev_diag_seq(int dev);

/** Bus diagnostics (shared line). */
typedef struct mbfb_bus_diag_s { /* tag differs from the function (C++ -Wshadow) */
    uint32_t transactions;    /* requests put on the wire (every attempt)               */
    uint32_t busy_permille;   /* line in use (request, turnaround, reply, gaps owed) over
                                 the last second, 0..1000, as the worker keeps it (after
                                 each attempt and when it goes idle; 0 a second after the
                                 last attempt)                                          */
    uint32_t plans;           /* plans running                                          */
    uint32_t stray_bytes;     /* as mbfb_diag_t                                         */
} mbfb_bus_diag_t;

/** Copy the diagnostics of the bus of device `dev`. Returns 0 or -MBFB_E_BADHANDLE. */
int mbfb_bus_diag(int dev, mbfb_bus_diag_t *out);

/** Static text for an error code (positive or negative). Never NULL. */
const char *mbfb_strerror(int code);

/* ---- teardown (tests, program unload) ------------------------------------- */

/** Stop every worker, close every port, free everything. Handles become invalid. Each
 *  worker ends the attempt on the wire and starts no other. The library's destructor calls
 *  it too (dlclose of the program that holds the shims, process exit): README "Lifetime". */
void mbfb_shutdown(void);

#ifdef __cplusplus
}
#endif

#endif /* MBFB_H */
