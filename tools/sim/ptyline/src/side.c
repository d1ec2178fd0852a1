/* side.c: pty handling.  A Linux pty master reports POLLHUP and read() fails
 * with EIO while no process has its slave open (after the first open), and a
 * write made then is kept for the next opener.  So a side is "down" until a peer
 * opens it; a down side is not polled (that would spin) but checked every 10 ms,
 * and bytes for it are dropped rather than delivered stale. */
#define _GNU_SOURCE
#include "side.h"
#include "speed.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#define CHECK_EVERY_NS 10000000

static int make_raw(int fd, const pl_settings *line)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0)
        return -1;
    cfmakeraw(&t);
    t.c_cflag |= CLOCAL | CREAD;
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    if (line != NULL && line->check && line->speed != 0) {
        cfsetispeed(&t, (speed_t)line->speed);
        cfsetospeed(&t, (speed_t)line->speed);
    }
    if (line != NULL && line->check) {
        if (line->stop2)
            t.c_cflag |= CSTOPB;
        else
            t.c_cflag &= ~(tcflag_t)CSTOPB;
    }
    if (tcsetattr(fd, TCSANOW, &t) != 0)
        return -1;
    return line != NULL && line->check && line->speed == 0 ? pl_speed_set(fd, line->baud) : 0;
}

void pl_settings_of(long baud, const char *format, pl_settings *out)
{
    static const struct { long baud; speed_t speed; } speeds[] = {
        {50, B50}, {75, B75}, {110, B110}, {134, B134}, {150, B150}, {200, B200},
        {300, B300}, {600, B600}, {1200, B1200}, {1800, B1800}, {2400, B2400},
        {4800, B4800}, {9600, B9600}, {19200, B19200}, {38400, B38400}, {57600, B57600},
        {115200, B115200}, {230400, B230400}, {460800, B460800}, {500000, B500000},
        {576000, B576000}, {921600, B921600}, {1000000, B1000000}, {1152000, B1152000},
        {1500000, B1500000}, {2000000, B2000000}, {2500000, B2500000},
        {3000000, B3000000}, {3500000, B3500000}, {4000000, B4000000}};
    *out = (pl_settings){0};
    out->baud = baud;
    out->check = baud > 0; /* a rate without a B* constant: termios2 */
    for (size_t i = 0; i < sizeof speeds / sizeof speeds[0]; i++)
        if (speeds[i].baud == baud) {
            out->check = 1;
            out->speed = (unsigned)speeds[i].speed;
        }
    size_t n = strlen(format);
    out->stop2 = n > 0 && format[n - 1] == '2';
}

int pl_side_settings_ok(const pl_side *s, const pl_settings *line)
{
    struct termios t;
    long ispeed, ospeed;
    if (!line->check || tcgetattr(s->fd, &t) != 0)
        return 1;
    if (line->speed == 0 || pl_speed_is_other((unsigned)cfgetospeed(&t))) /* termios2 */
        return pl_speed_get(s->fd, &ispeed, &ospeed) != 0 ||
               (ispeed == line->baud && ospeed == line->baud);
    /* the speed only: a UART checks the first stop bit alone (8N1 talks to 8N2), and a pty
     * carries no parity to compare */
    return cfgetospeed(&t) == (speed_t)line->speed && cfgetispeed(&t) == (speed_t)line->speed;
}

static int make_link(const pl_side *s)
{
    char old[PATH_MAX];
    if (readlink(s->link, old, sizeof old) >= 0) {
        if (unlink(s->link) != 0)
            return -1;
    } else if (errno != ENOENT) {
        if (errno == EINVAL)
            errno = EEXIST; /* exists and is not a symlink: never clobber a file */
        return -1;
    }
    return symlink(s->path, s->link);
}

int pl_side_open(pl_side *s, char name, const char *link, const pl_settings *line)
{
    memset(s, 0, offsetof(pl_side, out));
    s->name = name;
    s->link = link;
    s->fd = -1;
    s->fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (s->fd < 0 || grantpt(s->fd) != 0 || unlockpt(s->fd) != 0 ||
        ptsname_r(s->fd, s->path, sizeof s->path) != 0 || make_raw(s->fd, NULL) != 0) {
        fprintf(stderr, "mbfb-ptyline: pty %c: %s\n", name, strerror(errno));
        return -1;
    }
    /* Raw slave termios (no echo, no CR/LF mapping) stays for later openers. */
    int slave = open(s->path, O_RDWR | O_NOCTTY);
    if (slave < 0 || make_raw(slave, line) != 0) {
        fprintf(stderr, "mbfb-ptyline: %s: %s\n", s->path, strerror(errno));
        return -1;
    }
    close(slave);
    tcflush(s->fd, TCIOFLUSH);
    int fl = fcntl(s->fd, F_GETFL);
    if (fl < 0 || fcntl(s->fd, F_SETFL, fl | O_NONBLOCK) != 0 || fcntl(s->fd, F_SETFD, FD_CLOEXEC) != 0) {
        fprintf(stderr, "mbfb-ptyline: pty %c: %s\n", name, strerror(errno));
        return -1;
    }
    if (link != NULL && make_link(s) != 0) {
        fprintf(stderr, "mbfb-ptyline: --link-%c %s: %s\n", name == 'M' ? 'm' : 's', link,
                strerror(errno));
        return -1;
    }
    return 0;
}

void pl_side_close(pl_side *s)
{
    char old[PATH_MAX];
    ssize_t n;
    if (s->link != NULL && (n = readlink(s->link, old, sizeof old - 1)) >= 0) {
        old[n] = '\0';
        if (strcmp(old, s->path) == 0)
            unlink(s->link);
    }
    if (s->fd >= 0)
        close(s->fd);
    s->fd = -1;
}

void pl_side_down(pl_side *s)
{
    s->up = 0;
    s->out_len = 0;
    s->next_check_ns = 0;
}

int pl_side_check_up(pl_side *s, int64_t now_ns, int force)
{
    if (s->up || (!force && now_ns < s->next_check_ns))
        return 0;
    s->next_check_ns = now_ns + CHECK_EVERY_NS;
    struct pollfd p = {.fd = s->fd, .events = POLLIN};
    if (poll(&p, 1, 0) < 0 || (p.revents & POLLHUP))
        return 0;
    s->up = 1;
    s->opens++;
    return 1;
}

long pl_side_read(pl_side *s, uint8_t *buf, size_t max)
{
    ssize_t n = read(s->fd, buf, max);
    if (n > 0)
        return (long)n;
    if (n < 0 && (errno == EAGAIN || errno == EINTR))
        return 0;
    pl_side_down(s); /* EIO: the last peer closed its end */
    return -1;
}

size_t pl_side_put(pl_side *s, const uint8_t *data, size_t n)
{
    if (!s->up)
        return n;
    size_t fit = PL_SIDE_OUT_MAX - s->out_len;
    if (fit > n)
        fit = n;
    memcpy(s->out + s->out_len, data, fit);
    s->out_len += fit;
    return n - fit;
}

size_t pl_side_flush(pl_side *s)
{
    struct pollfd p = {.fd = s->fd, .events = POLLOUT};
    if (s->up && s->out_len > 0 && poll(&p, 1, 0) > 0 && (p.revents & POLLHUP)) {
        /* The peer just closed: a write now would reach the next opener, stale.
         * The main loop sees the hangup, reads what is left, and marks it down. */
        size_t lost = s->out_len;
        s->out_len = 0;
        return lost;
    }
    while (s->up && s->out_len > 0) {
        ssize_t n = write(s->fd, s->out, s->out_len);
        if (n > 0) {
            memmove(s->out, s->out + n, s->out_len - (size_t)n);
            s->out_len -= (size_t)n;
        } else if (n < 0 && errno == EINTR) {
            continue;
        } else if (n < 0 && errno == EAGAIN) {
            return 0;
        } else {
            size_t lost = s->out_len;
            pl_side_down(s);
            return lost;
        }
    }
    return 0;
}
