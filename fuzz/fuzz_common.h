/*
 * fuzz_common.h - helpers shared by the libFuzzer harnesses of fuzz/ (not a test).
 *
 * The harnesses drive the shims through their public API (mbfb.h) and the few internal
 * entry points that parse bytes from the wire: mbfb_check_reply() and the backends' recv()
 * (mbfb_internal.h). A harness input starts with a small header that chooses the request the
 * bytes are an answer to; the rest is what the line carries.
 */
#ifndef FUZZ_COMMON_H
#define FUZZ_COMMON_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbfb.h"
#include "mbfb_internal.h"

/* Reads bytes off the front of the input; 0 once it is exhausted. */
typedef struct fz {
    const uint8_t *p;
    size_t n;
} fz_t;

static inline int fz_u8(fz_t *f)
{
    if (f->n == 0)
        return 0;
    f->n--;
    return *f->p++;
}

static inline int fz_u16(fz_t *f)
{
    int hi = fz_u8(f);
    return hi << 8 | fz_u8(f);
}

/* A request the shims accept, from 7 header bytes:
 *   slave, fc selector (3/4/6/16/1/2/5/15: its low 3 bits), address (2), count (registers
 *   or bits), first value (2); value i = v0 + i (FC15: coils packed in those words).
 * Returns the request frame's length (slave + PDU) in req, or 0 if the shims would refuse
 * the arguments (then nothing is sent and there is no reply to parse). */
typedef struct fz_req {
    int slave, fc, addr, count;
    uint16_t values[MBFB_MAX_WRITE];
} fz_req_t;

static inline int fz_request(fz_t *f, fz_req_t *r, uint8_t *req)
{
    static const int fcs[8] = {3, 4, 6, 16, 1, 2, 5, 15};
    int v0;
    r->slave = fz_u8(f);
    r->fc = fcs[fz_u8(f) & 7];
    r->addr = fz_u16(f);
    r->count = fz_u8(f);
    v0 = fz_u16(f);
    if (r->fc == 6 || r->fc == 5)
        r->count = 1;
    if (r->count < 1)
        r->count = 1;
    for (int i = 0; i < MBFB_MAX_WRITE; i++)
        r->values[i] = (uint16_t)(v0 + i);
    if (mbfb_check_args(r->slave, r->fc, r->addr, r->count, r->values) != MBFB_OK)
        return 0;
    return mbfb_build_request(req, r->slave, r->fc, r->addr, r->count, r->values);
}

/* Every result a request can end with is in the one error table. */
static inline int fz_known_result(int code)
{
    return (code >= MBFB_OK && code <= MBFB_E_BAUD) ||
           (code > MBFB_E_EXCEPTION_BASE && code <= MBFB_E_EXCEPTION_BASE + 255);
}

#define FZ_ASSERT(cond)                                                                  \
    do {                                                                                 \
        if (!(cond)) {                                                                   \
            fprintf(stderr, "%s:%d: invariant failed: %s\n", __FILE__, __LINE__, #cond);  \
            abort();                                                                     \
        }                                                                                \
    } while (0)

#endif
