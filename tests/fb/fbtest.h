/* fbtest.h - host functions the ST test-support blocks (fbtest.st) call from their pragmas.
 * Implemented once in fbtest_hooks.cpp, linked by both test hosts (fb_test_host.cpp,
 * tests/strucpp/v4_host.cpp); force-included into the iec2c output of every test program. */
#ifndef FBTEST_H
#define FBTEST_H
#include <stdint.h>
#ifdef __cplusplus
extern "C" {  /* the program may be C (matiec's own headers) or C++ (OpenPLC's) */
#endif

/** Record a failed check: prints "FAIL scan N: msg"; the host exits 1 after this scan. */
void fbt_fail(const uint8_t *msg, int len);
/** Count a passed check. */
void fbt_pass(void);
/** Print a note with the scan number. */
void fbt_note(const uint8_t *msg, int len);
/** The test program finished: the host exits after this scan (0 if nothing failed). */
void fbt_done(void);
/** Current scan number (0-based). */
long fbt_scan(void);
/** Copy environment variable `name` into buf (at most max bytes); returns its length or -1. */
int fbt_getenv(const char *name, uint8_t *buf, int max);
/** One simulator control request (JSON line) over MBFB_SIM_CONTROL; blocks (tests only).
 *  Copies up to max bytes of the reply into buf and returns its full length, or -1. Also
 *  gives: ok (reply has "ok": true), raw (value of "raw" if present, else -1), frames
 *  (number of frames in a "log" reply) and matches (occurrences of `match` in the reply,
 *  e.g. '"hex": "01 06' counts FC06 frames to slave 1 in a log) and at (where the first
 *  match is in the reply, -1 = none: the order of two frames in a log). */
int fbt_sim(const uint8_t *req, int len, uint8_t *buf, int max, int *ok, long *raw, long *frames,
            const uint8_t *match, int match_len, long *matches, long *at);

/* The host's side (a test host's scan loop; the programs do not call these). */
/** The scan limit of a test run: MBFB_MAX_SCANS, default 6000. */
long fbt_host_max_scans(void);
/** The scan about to run (0-based): what fbt_scan and the FAIL/note lines report. */
void fbt_host_set_scan(long scan);
/** Nonzero once a check failed or the program called fbt_done: run no further scan. */
int fbt_host_stop(void);
/** The end of a test run after `scans` scans: closes the simulator control connection, prints
 *  "N scans, P checks passed, F failed" (and "FAIL: no check ran" when none did); returns the
 *  exit code: 0 when the program called fbt_done, no check failed and one passed, else 1. */
int fbt_host_finish(long scans);
#ifdef __cplusplus
}
#endif
#endif
