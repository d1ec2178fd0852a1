/*
 * fuzz_reply.c - reply validation, mbfb_check_reply(), on every request shape.
 *
 * Input: 7 header bytes (fuzz_common.h: the request) + a reply frame (slave + PDU, check
 * bytes already stripped, as the backends hand it over).
 * Invariants: a reply accepted as good has exactly the length, slave, function, byte count
 * (2 x registers, ceil(bits / 8)) and echo the request implies; every other answer is
 * BADREPLY or 128 + a non-zero exception code from a 3-byte exception frame; the exact
 * correct reply is always accepted. The bits of a good FC01/02 reply unpack into
 * MBFB_BIT_WORDS(count) words with nothing past the count, and pack back into its bytes
 * (padding cleared); an FC15 request carries exactly its count of bits.
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
    FZ_ASSERT(want >= 4 && want <= 3 + 2 * MBFB_MAX_READ);
    FZ_ASSERT(rl == (r.fc == 16 ? 7 + 2 * r.count : r.fc == 15 ? 7 + (r.count + 7) / 8 : 6));
    if (r.fc == 15) { /* the coils sent: v0 + i packed, nothing past the count */
        uint16_t back[MBFB_MAX_WRITE + 1];
        mbfb_bytes_to_bits(req + 7, r.count, back);
        FZ_ASSERT(mbfb_readback_shows(15, r.count, r.values, back));
        if (r.count % 8)
            FZ_ASSERT((req[rl - 1] >> (r.count % 8)) == 0);
    }

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
            else if (r.fc == 1 || r.fc == 2)
                FZ_ASSERT(rsp[2] == (r.count + 7) / 8);
            else
                FZ_ASSERT(memcmp(rsp + 2, req + 2, 4) == 0);
            if (r.fc == 1 || r.fc == 2) { /* unpacked: nothing past the count; packed back */
                uint16_t w[MBFB_MAX_READ + 1];
                uint8_t again[MBFB_FRAME_MAX];
                int nw = MBFB_BIT_WORDS(r.count);
                w[nw] = 0xA5A5;
                mbfb_bytes_to_bits(rsp + 3, r.count, w);
                FZ_ASSERT(w[nw] == 0xA5A5);
                if (r.count % 16)
                    FZ_ASSERT((w[nw - 1] >> (r.count % 16)) == 0);
                mbfb_bits_to_bytes(w, r.count, again);
                for (int j = 0; j < rsp[2]; j++) {
                    int keep = j < rsp[2] - 1 || r.count % 8 == 0 ? 0xFF
                                                                   : (1 << (r.count % 8)) - 1;
                    FZ_ASSERT(again[j] == (rsp[3 + j] & keep));
                }
            }
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
    if (r.fc >= 1 && r.fc <= 4) {
        good[2] = (uint8_t)(r.fc <= 2 ? (r.count + 7) / 8 : 2 * r.count);
        for (int i = 0; i < good[2]; i++)
            good[3 + i] = (uint8_t)(i * 37);
    }
    FZ_ASSERT(mbfb_check_reply(req, good, want) == MBFB_OK);
    /* and one byte short of it is not */
    FZ_ASSERT(mbfb_check_reply(req, good, want - 1) != MBFB_OK);
    return 0;
}
