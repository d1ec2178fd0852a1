/* side.h: one end of the line, a pty whose slave path a peer opens. */
#ifndef PL_SIDE_H
#define PL_SIDE_H

#include <stddef.h>
#include <stdint.h>

#define PL_SIDE_OUT_MAX 65536 /* bytes waiting for a slow reader before overrun */

typedef struct {
    char name;            /* 'M' or 'S' */
    int fd;               /* pty master, non-blocking */
    char path[64];        /* slave path the peer opens */
    const char *link;     /* optional symlink to path, removed by pl_side_close */
    int up;               /* a peer has the slave open */
    uint64_t opens;       /* times a peer was seen to open it */
    int64_t next_check_ns;
    size_t out_len;
    uint8_t out[PL_SIDE_OUT_MAX];
} pl_side;

/* The character format of the line as a pty can show it: Linux ptys keep the
 * speed and CSTOPB a peer sets but always report CS8 without parity. */
typedef struct {
    int check;            /* 0: no baud given, nothing is checked */
    unsigned speed;       /* speed_t of the baud; 0: no B* constant, set and read with
                             termios2 (BOTHER, speed.c) */
    long baud;            /* the line's baud */
    int stop2;            /* two stop bits */
} pl_settings;

/* Fills `out` for a baud and a format such as "8N2" (stop bits = its last digit). */
void pl_settings_of(long baud, const char *format, pl_settings *out);

/* Creates the pty (raw on both ends, the slave set to the line's speed and stop
 * bits, so a peer that sets nothing is on the line) and the optional symlink.
 * 0, or -1 with errno and a message on stderr. */
int pl_side_open(pl_side *s, char name, const char *link, const pl_settings *line);

/* Does the peer's port (tcgetattr on the pty master reads the slave's termios)
 * match the line?  1 also when nothing can be checked. */
int pl_side_settings_ok(const pl_side *s, const pl_settings *line);

/* Closes the pty and removes the symlink if it still points to it. */
void pl_side_close(pl_side *s);

/* While the side is down, looks (at most every 10 ms unless forced) whether a
 * peer opened the slave; returns 1 if it just came up. */
int pl_side_check_up(pl_side *s, int64_t now_ns, int force);

/* Reads what the peer wrote: > 0 bytes, 0 nothing now, -1 the peer closed (the
 * side is then down). */
long pl_side_read(pl_side *s, uint8_t *buf, size_t max);

/* Marks the side down (its peer is gone) and forgets what was queued for it. */
void pl_side_down(pl_side *s);

/* Queues n bytes for the peer; returns how many did not fit or cannot reach it
 * (down side, overrun): those are lost, as on a real line. */
size_t pl_side_put(pl_side *s, const uint8_t *data, size_t n);

/* Writes queued bytes as far as the pty takes them; returns how many were lost
 * because the peer closed meanwhile. */
size_t pl_side_flush(pl_side *s);

#endif
