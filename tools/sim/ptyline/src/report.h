/* report.h: the stats JSON and the frame log of mbfb-ptyline. */
#ifndef PL_REPORT_H
#define PL_REPORT_H

#include <stdint.h>
#include <stdio.h>

#include "line.h"
#include "side.h"

typedef struct {
    const char *format;
    uint64_t seed;
    int turn_lo_ms, turn_hi_ms;
    int64_t t0_ns;              /* when the line became ready */
    const pl_side *side[2];     /* M, S */
} pl_report_info;

/* Writes the statistics as one JSON object to path, atomically (temp file +
 * rename).  0, or -1 with errno. */
int pl_report_write(const pl_line *line, const pl_report_info *info, int64_t now_ns,
                    const char *path);

/* Writes one frame as "t_start_us dir hex..." (dir M>S or S>M, with a trailing
 * '*' if some byte of it collided). */
void pl_report_frame(FILE *log, const pl_frame *f, int64_t t0_ns);

#endif
