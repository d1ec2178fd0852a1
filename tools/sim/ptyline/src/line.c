/* line.c: the half-duplex line model (see line.h).  Pure logic, unit-tested
 * with synthetic clocks in test_line_model.c. */
#include "line.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

int pl_format_bits(const char *f)
{
    if (f == NULL || strlen(f) != 3 || f[0] < '5' || f[0] > '8' ||
        strchr("NEO", f[1]) == NULL || (f[2] != '1' && f[2] != '2')) {
        errno = EINVAL;
        return -1;
    }
    return 1 + (f[0] - '0') + (f[1] != 'N') + (f[2] - '0');
}

/* splitmix64: small, seedable, good enough for turnaround jitter. */
static uint64_t next_random(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static void span_add(pl_span *s, int64_t v)
{
    if (s->count == 0 || v < s->min_ns)
        s->min_ns = v;
    if (s->count == 0 || v > s->max_ns)
        s->max_ns = v;
    s->count++;
    s->sum_ns += (double)v;
}

int pl_line_init(pl_line *line, long baud, int char_bits, int paced, int queue_cap,
                 int turn_lo_ms, int turn_hi_ms, uint64_t seed,
                 pl_frame_cb on_frame, void *user)
{
    if (baud <= 0 || char_bits < 7 || char_bits > 12 || queue_cap <= 0 ||
        turn_lo_ms < 0 || turn_hi_ms < turn_lo_ms) {
        errno = EINVAL;
        return -1;
    }
    memset(line, 0, sizeof(*line));
    line->baud = baud;
    line->char_bits = char_bits;
    line->paced = paced;
    line->char_ns = (int64_t)char_bits * 1000000000 / baud;
    line->t15_ns = (int64_t)char_bits * 1500000000 / baud;
    line->t35_ns = (int64_t)char_bits * 3500000000 / baud;
    line->bits44_ns = (int64_t)44 * 1000000000 / baud;
    line->turn_lo_ns = (int64_t)turn_lo_ms * 1000000;
    line->turn_hi_ns = (int64_t)turn_hi_ms * 1000000;
    line->rng = seed;
    line->on_frame = on_frame;
    line->user = user;
    for (int d = 0; d < 2; d++) {
        line->q[d].buf = calloc((size_t)queue_cap, sizeof(pl_byte));
        line->q[d].cap = (size_t)queue_cap;
        if (line->q[d].buf == NULL) {
            pl_line_free(line);
            errno = ENOMEM;
            return -1;
        }
    }
    return 0;
}

void pl_line_free(pl_line *line)
{
    for (int d = 0; d < 2; d++) {
        free(line->q[d].buf);
        line->q[d].buf = NULL;
    }
}

size_t pl_line_room(const pl_line *line, int dir)
{
    return line->q[dir].cap - line->q[dir].len;
}

static pl_byte *q_at(const pl_queue *q, size_t i)
{
    return &q->buf[(q->head + i) % q->cap];
}

/* Does a byte of dir starting at t begin a new frame?  Yes after t3.5 of its own
 * silence, or when the other side started a frame since dir's last byte ended. */
static int starts_frame(const pl_line *line, int dir, int64_t t)
{
    int other = !dir;
    if (!line->have_byte[dir] || t - line->last_end[dir] >= line->t35_ns)
        return 1;
    return line->have_frame[other] && line->frame_start[other] >= line->last_end[dir];
}

static void emit_frame(pl_line *line, int dir)
{
    if (!line->frame_open[dir])
        return;
    line->frame_open[dir] = 0;
    if (line->on_frame)
        line->on_frame(&line->cur[dir], line->user);
}

/* End of the newest byte of dir that started before t (queued or delivered). */
static int64_t end_before(const pl_line *line, int dir, int64_t t, int *found)
{
    const pl_queue *q = &line->q[dir];
    for (size_t i = q->len; i-- > 0;) {
        const pl_byte *b = q_at(q, i);
        if (b->start_ns < t) {
            *found = 1;
            return b->end_ns;
        }
    }
    *found = line->have_popped[dir];
    return line->popped_end[dir];
}

/* Statistics of a frame of dir that starts at t (before its first byte is queued). */
static void count_frame_start(pl_line *line, int dir, int64_t t)
{
    int other = !dir;
    if (dir == PL_M2S) {
        int found_m = line->have_byte[PL_M2S], found_s = 0;
        int64_t prev = found_m ? line->last_end[PL_M2S] : 0;
        int64_t prev_s = end_before(line, PL_S2M, t, &found_s);
        if (found_s && (!found_m || prev_s > prev))
            prev = prev_s;
        if (found_m || found_s) {
            int64_t gap = t > prev ? t - prev : 0; /* overlap: no silence at all */
            span_add(&line->req_gap, gap);
            if (gap < line->t35_ns) {
                line->short_35++;
                span_add(&line->short_gap, gap);
            }
            if (gap < line->bits44_ns)
                line->short_44++;
        }
    } else if (line->have_frame[other] && line->have_byte[other] &&
               (!line->have_frame[dir] || line->frame_start[other] > line->frame_start[dir]) &&
               t >= line->last_end[other]) {
        span_add(&line->latency, t - line->last_end[other]);
    }
    emit_frame(line, dir);
    if (line->frame_open[other] && line->last_end[other] <= t)
        emit_frame(line, other); /* the line was handed over */
    line->dir[dir].frames++;
    line->have_frame[dir] = 1;
    line->frame_start[dir] = t;
    line->frame_open[dir] = 1;
    memset(&line->cur[dir], 0, offsetof(pl_frame, data));
    line->cur[dir].dir = dir;
    line->cur[dir].start_ns = t;
}

/* Marks the overlap of byte b (of dir) with the queued bytes of the other side. */
static void collide(pl_line *line, int dir, pl_byte *b)
{
    int other = !dir;
    pl_queue *q = &line->q[other];
    int hit = 0;
    int64_t until = b->end_ns;
    for (size_t i = q->len; i-- > 0;) {
        pl_byte *o = q_at(q, i);
        if (o->end_ns <= b->start_ns)
            break;
        if (o->start_ns >= b->end_ns)
            continue;
        int64_t lo = o->start_ns > b->start_ns ? o->start_ns : b->start_ns;
        int64_t hi = o->end_ns < b->end_ns ? o->end_ns : b->end_ns;
        line->overlap_ns += hi - lo;
        /* Wired-AND: a driven 0 wins; both receivers get the same garbled byte. */
        b->wire &= o->sent;
        o->wire &= b->sent;
        if (!o->collided) {
            o->collided = 1;
            line->dir[other].collided_bytes++;
            line->cur[other].collided = 1;
        }
        if (o->end_ns > until)
            until = o->end_ns;
        hit = 1;
    }
    if (!hit)
        return;
    b->collided = 1;
    line->dir[dir].collided_bytes++;
    line->cur[dir].collided = 1;
    if (b->start_ns >= line->collision_until) {
        /* A new collision: blame the side whose frame started last. */
        int culprit = line->frame_start[dir] >= line->frame_start[other] ? dir : other;
        line->dir[culprit].collisions++;
    }
    if (until > line->collision_until)
        line->collision_until = until;
}

int pl_line_send(pl_line *line, int dir, uint8_t byte, int64_t arrival_ns)
{
    pl_queue *q = &line->q[dir];
    if (q->len == q->cap) {
        errno = ENOBUFS;
        return -1;
    }
    int fresh = starts_frame(line, dir, arrival_ns);
    int64_t t = arrival_ns;
    if (fresh && dir == PL_S2M && line->turn_hi_ns > 0) {
        uint64_t range = (uint64_t)(line->turn_hi_ns - line->turn_lo_ns) / 1000 + 1;
        t += line->turn_lo_ns + (int64_t)(next_random(&line->rng) % range) * 1000;
    }
    if (line->have_byte[dir] && t < line->last_end[dir])
        t = line->last_end[dir];
    if (fresh) {
        count_frame_start(line, dir, t);
    } else if (t - line->last_end[dir] > line->t15_ns) {
        line->dir[dir].intra_gaps++;
    }
    pl_byte *b = q_at(q, q->len);
    b->sent = b->wire = byte;
    b->collided = 0;
    b->start_ns = t;
    b->end_ns = t + (line->paced ? line->char_ns : 0);
    q->len++;
    collide(line, dir, b);
    pl_frame *f = &line->cur[dir];
    if (f->len < PL_FRAME_LOG_MAX)
        f->data[f->len] = byte;
    f->len++;
    line->have_byte[dir] = 1;
    line->last_end[dir] = b->end_ns;
    line->dir[dir].bytes++;
    line->dir[dir].busy_ns += line->char_ns;
    return 0;
}

size_t pl_line_take_due(pl_line *line, int dir, int64_t now_ns, uint8_t *out, size_t max)
{
    pl_queue *q = &line->q[dir];
    size_t n = 0;
    while (n < max && q->len > 0 && q->buf[q->head].end_ns <= now_ns) {
        out[n++] = q->buf[q->head].wire;
        line->popped_end[dir] = q->buf[q->head].end_ns;
        line->have_popped[dir] = 1;
        q->head = (q->head + 1) % q->cap;
        q->len--;
    }
    return n;
}

void pl_line_dropped(pl_line *line, int dir, size_t n)
{
    line->dir[dir].dropped_bytes += n;
}

void pl_line_expire(pl_line *line, int64_t now_ns)
{
    for (int d = 0; d < 2; d++) {
        if (line->frame_open[d] &&
            (now_ns == PL_NEVER || line->last_end[d] + line->t35_ns <= now_ns))
            emit_frame(line, d);
    }
}

int64_t pl_line_next_deadline(const pl_line *line)
{
    int64_t t = PL_NEVER;
    for (int d = 0; d < 2; d++) {
        if (line->q[d].len > 0 && line->q[d].buf[line->q[d].head].end_ns < t)
            t = line->q[d].buf[line->q[d].head].end_ns;
        if (line->frame_open[d] && line->last_end[d] + line->t35_ns < t)
            t = line->last_end[d] + line->t35_ns;
    }
    return t;
}

int64_t pl_line_busy_ns(const pl_line *line)
{
    return line->dir[0].busy_ns + line->dir[1].busy_ns - line->overlap_ns;
}
