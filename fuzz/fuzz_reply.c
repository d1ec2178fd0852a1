/*
 * fuzz_reply.c - reply validation, mbfb_check_reply(), on every request shape.
 *
 * Input: 7 header bytes (fuzz_common.h: the request) + a reply frame (slave + PDU, check
 * bytes already stripped, as the backends hand it over).
 * Invariants: a reply accepted as good has exactly the length, slave, function, byte count
 * and echo the request implies; every other answer is BADREPLY or 128 + a non-zero
 * exception code from a 3-byte exception frame; the exact correct reply is always accepted.
 */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fz_t f = {data, size};
    fz_req_t r;
    uint8_t req[MBFB_FRAME_MAX], good[MBFB_FRAME_MAX];
    int rl, want, rc;

    if (size < 7 || (rl = fz_request(&f, &r, req)) == 0)
        return 0;
    want = mbfb_reply_len(req);
    FZ_ASSERT(want >= 5 && want <= 3 + 2 * MBFB_MAX_READ);
    FZ_ASSERT(rl == (r.fc == 16 ? 7 + 2 * r.count : 6));

    /* the fuzzed reply: exactly f.n bytes on the heap, so ASan sees any over-read */
    {
        uint8_t *rsp = (uint8_t *)malloc(f.n ? f.n : 1);
        int len = (int)f.n;
        memcpy(rsp, f.p, f.n);
        rc = mbfb_check_reply(req, rsp, len);
        if (rc == MBFB_OK) {
            FZ_ASSERT(len == want && rsp[0] == req[0] && rsp[1] == req[1]);
            if (r.fc == 3 || r.fc == 4)
                FZ_ASSERT(rsp[2] == 2 * r.count);
            else
                FZ_ASSERT(memcmp(rsp + 2, req + 2, 4) == 0);
        } else if (rc > MBFB_E_EXCEPTION_BASE) {
            FZ_ASSERT(len == 3 && rsp[0] == req[0] && rsp[1] == (req[1] | 0x80) && rsp[2] != 0 &&
                      rc == MBFB_E_EXCEPTION_BASE + rsp[2]);
        } else {
            FZ_ASSERT(rc == MBFB_E_BADREPLY);
        }
        free(rsp);
    }

    /* the correct reply to this request is accepted */
    memcpy(good, req, 6);
    if (r.fc == 3 || r.fc == 4) {
        good[2] = (uint8_t)(2 * r.count);
        for (int i = 0; i < 2 * r.count; i++)
            good[3 + i] = (uint8_t)(i * 37);
    }
    FZ_ASSERT(mbfb_check_reply(req, good, want) == MBFB_OK);
    /* and one byte short of it is not */
    FZ_ASSERT(mbfb_check_reply(req, good, want - 1) != MBFB_OK);
    return 0;
}
