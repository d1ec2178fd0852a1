/* report.c: stats JSON (keys documented in ../README.md) and the frame log. */
#define _GNU_SOURCE
#include "report.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

static double us(int64_t ns) { return (double)ns / 1000.0; }

static void put_counts(FILE *f, const char *name, const pl_counts *c, int64_t busy_ns,
                       int64_t elapsed_ns)
{
    fprintf(f,
            "  \"%s\": {\"frames\": %llu, \"bytes\": %llu, \"busy_us\": %.3f, "
            "\"utilisation\": %.6f, \"collisions\": %llu, \"collided_bytes\": %llu, "
            "\"dropped_bytes\": %llu, \"intra_gaps_over_1_5\": %llu, \"format_errors\": %llu},\n",
            name, (unsigned long long)c->frames, (unsigned long long)c->bytes, us(busy_ns),
            elapsed_ns > 0 ? (double)busy_ns / (double)elapsed_ns : 0.0,
            (unsigned long long)c->collisions, (unsigned long long)c->collided_bytes,
            (unsigned long long)c->dropped_bytes, (unsigned long long)c->intra_gaps,
            (unsigned long long)c->format_errors);
}

/* "<pre>min_us": x, "<pre>avg_us": y, "<pre>max_us": z (null when empty) */
static void put_span(FILE *f, const char *name, const pl_span *s)
{
    if (s->count == 0) {
        fprintf(f, "\"%smin_us\": null, \"%savg_us\": null, \"%smax_us\": null", name,
                name, name);
        return;
    }
    fprintf(f, "\"%smin_us\": %.3f, \"%savg_us\": %.3f, \"%smax_us\": %.3f", name,
            us(s->min_ns), name, s->sum_ns / 1000.0 / (double)s->count, name, us(s->max_ns));
}

static void put_side(FILE *f, const pl_side *s, const char *tail)
{
    fprintf(f, "    \"%c\": {\"path\": \"%s\", \"open\": %s, \"opens\": %llu}%s\n",
            s->name == 'M' ? 'm' : 's', s->path, s->up ? "true" : "false",
            (unsigned long long)s->opens, tail);
}

static void put_all(FILE *f, const pl_line *l, const pl_report_info *in, int64_t now_ns)
{
    int64_t elapsed = now_ns - in->t0_ns;
    pl_counts t = l->dir[0];
    const pl_counts *s = &l->dir[1];
    t.frames += s->frames;
    t.bytes += s->bytes;
    t.collisions += s->collisions;
    t.collided_bytes += s->collided_bytes;
    t.dropped_bytes += s->dropped_bytes;
    t.intra_gaps += s->intra_gaps;
    t.format_errors += s->format_errors;

    fprintf(f, "{\n  \"version\": 1, \"baud\": %ld, \"format\": \"%s\", \"char_bits\": %d, "
               "\"paced\": %s,\n",
            l->baud, in->format, l->char_bits, l->paced ? "true" : "false");
    fprintf(f, "  \"char_us\": %.3f, \"t15_us\": %.3f, \"t35_us\": %.3f, \"bits44_us\": %.3f,\n",
            us(l->char_ns), us(l->t15_ns), us(l->t35_ns), us(l->bits44_ns));
    if (in->turn_hi_ms > 0)
        fprintf(f, "  \"turnaround_ms\": [%d, %d], ", in->turn_lo_ms, in->turn_hi_ms);
    else
        fprintf(f, "  \"turnaround_ms\": null, ");
    fprintf(f, "\"seed\": %llu, \"elapsed_us\": %.3f,\n", (unsigned long long)in->seed,
            us(elapsed));
    put_counts(f, "m2s", &l->dir[0], l->dir[0].busy_ns, elapsed);
    put_counts(f, "s2m", &l->dir[1], l->dir[1].busy_ns, elapsed);
    put_counts(f, "total", &t, pl_line_busy_ns(l), elapsed);
    fprintf(f, "  \"requests\": {\"count\": %llu, ", (unsigned long long)l->req_gap.count);
    put_span(f, "gap_", &l->req_gap);
    fprintf(f, ",\n    \"short_3_5\": %llu, \"short_44bit\": %llu, ",
            (unsigned long long)l->short_35, (unsigned long long)l->short_44);
    if (l->short_gap.count > 0)
        fprintf(f, "\"short_min_us\": %.3f},\n", us(l->short_gap.min_ns));
    else
        fprintf(f, "\"short_min_us\": null},\n");
    fprintf(f, "  \"reply_latency\": {\"count\": %llu, ", (unsigned long long)l->latency.count);
    put_span(f, "", &l->latency);
    fprintf(f, "},\n  \"sides\": {\n");
    put_side(f, in->side[0], ",");
    put_side(f, in->side[1], "");
    fprintf(f, "  }\n}\n");
}

int pl_report_write(const pl_line *line, const pl_report_info *info, int64_t now_ns,
                    const char *path)
{
    char tmp[4096];
    if (snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid()) >= (int)sizeof tmp) {
        errno = ENAMETOOLONG;
        return -1;
    }
    FILE *f = fopen(tmp, "w");
    if (f == NULL)
        return -1;
    put_all(f, line, info, now_ns);
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        int e = errno;
        unlink(tmp);
        errno = e ? e : EIO;
        return -1;
    }
    if (rename(tmp, path) != 0) {
        int e = errno;
        unlink(tmp);
        errno = e;
        return -1;
    }
    return 0;
}

void pl_report_frame(FILE *log, const pl_frame *f, int64_t t0_ns)
{
    fprintf(log, "%lld %s%s", (long long)((f->start_ns - t0_ns) / 1000),
            f->dir == PL_M2S ? "M>S" : "S>M", f->collided ? "*" : "");
    size_t shown = f->len < PL_FRAME_LOG_MAX ? f->len : PL_FRAME_LOG_MAX;
    for (size_t i = 0; i < shown; i++)
        fprintf(log, " %02X", f->data[i]);
    if (shown < f->len)
        fprintf(log, " ...(%zu bytes)", f->len);
    fputc('\n', log);
}
