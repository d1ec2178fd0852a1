/* line.h: the half-duplex RS-485 line model of mbfb-ptyline (no I/O here).
 *
 * Every byte a side sends is given a place on the wire, [start, end), on one
 * monotonic nanosecond clock: start = max(arrival, end of the sender's previous
 * byte) (plus a turnaround delay for the first byte of an S->M frame), end =
 * start + one character time when paced, = start when not paced.  The receiver
 * gets the byte at `end`.  All statistics are computed from these wire times.
 */
#ifndef PL_LINE_H
#define PL_LINE_H

#include <stddef.h>
#include <stdint.h>

#define PL_M2S 0 /* master side -> slave side */
#define PL_S2M 1 /* slave side -> master side */
#define PL_NEVER INT64_MAX
#define PL_FRAME_LOG_MAX 1024 /* bytes kept per frame for the log */

typedef struct {
    uint8_t sent;      /* the byte as its sender wrote it */
    uint8_t wire;      /* the byte as the receiver gets it (wired-AND on collision) */
    uint8_t collided;  /* overlapped a byte of the other direction */
    int64_t start_ns, end_ns;
} pl_byte;

typedef struct {
    pl_byte *buf;
    size_t cap, head, len;
} pl_queue;

/* Counters of one direction (and, summed, of the whole line). */
typedef struct {
    uint64_t frames, bytes, collisions, collided_bytes, dropped_bytes, intra_gaps;
    uint64_t format_errors; /* bytes garbled: a side's port settings differ from the line */
    int64_t busy_ns;
} pl_counts;

/* Running min / mean / max of a duration. */
typedef struct {
    uint64_t count;
    int64_t min_ns, max_ns;
    double sum_ns;
} pl_span;

/* A frame as the log sees it. */
typedef struct {
    int dir;
    int64_t start_ns;
    size_t len;      /* bytes in the frame (may exceed PL_FRAME_LOG_MAX) */
    int collided;
    uint8_t data[PL_FRAME_LOG_MAX];
} pl_frame;

typedef void (*pl_frame_cb)(const pl_frame *frame, void *user);

typedef struct {
    /* configuration (pl_line_init) */
    long baud;
    int char_bits, paced;
    int64_t char_ns, t15_ns, t35_ns, bits44_ns;
    int64_t turn_lo_ns, turn_hi_ns; /* turnaround of S->M frames; hi == 0: none */
    uint64_t rng;
    pl_frame_cb on_frame;
    void *user;

    /* wire state */
    pl_queue q[2];
    int have_byte[2];        /* a byte was ever sent in this direction */
    int64_t last_end[2];     /* end of the newest scheduled byte */
    int have_popped[2];
    int64_t popped_end[2];   /* end of the newest byte already handed out */
    int have_frame[2];
    int64_t frame_start[2];  /* start of the newest frame */
    int frame_open[2];       /* newest frame not yet logged */
    int64_t collision_until; /* end of the current collision episode */
    pl_frame cur[2];

    /* statistics */
    pl_counts dir[2];
    int64_t overlap_ns;      /* busy time counted in both directions */
    pl_span req_gap;         /* silence before each M->S frame */
    pl_span short_gap;       /* those of them shorter than 3.5 characters */
    uint64_t short_35, short_44;
    pl_span latency;         /* end of M->S frame -> first byte of the S->M frame */
} pl_line;

/* Character bits (start + data + parity + stop) of a format such as "8N2";
 * -1 with errno = EINVAL if the format is malformed. */
int pl_format_bits(const char *format);

/* Sets up a line; queue_cap bytes may wait per direction.  turn_lo_ms..turn_hi_ms
 * (both 0: none) delays each S->M frame, drawn from `seed`.  0, or -1 with errno. */
int pl_line_init(pl_line *line, long baud, int char_bits, int paced, int queue_cap,
                 int turn_lo_ms, int turn_hi_ms, uint64_t seed,
                 pl_frame_cb on_frame, void *user);

/* Frees the queues. */
void pl_line_free(pl_line *line);

/* Room (bytes) left in the queue of direction dir. */
size_t pl_line_room(const pl_line *line, int dir);

/* Puts one byte, read from its sender at arrival_ns, on the wire.  The caller
 * checks pl_line_room first; returns -1 with errno = ENOBUFS if full. */
int pl_line_send(pl_line *line, int dir, uint8_t byte, int64_t arrival_ns);

/* Takes out, in order, the bytes of direction dir whose end is <= now_ns (their
 * wire values, at most max); returns how many. */
size_t pl_line_take_due(pl_line *line, int dir, int64_t now_ns, uint8_t *out, size_t max);

/* Counts n bytes of direction dir that reached no receiver. */
void pl_line_dropped(pl_line *line, int dir, size_t n);

/* Logs the frames that have been silent for t3.5 by now_ns (all if now_ns == PL_NEVER). */
void pl_line_expire(pl_line *line, int64_t now_ns);

/* The next time something is due (a byte's end or a frame's t3.5), or PL_NEVER. */
int64_t pl_line_next_deadline(const pl_line *line);

/* Busy time of the whole line (overlaps counted once). */
int64_t pl_line_busy_ns(const pl_line *line);

#endif
