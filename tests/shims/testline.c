/*
 * testline.c - serial lines for the tests whose bytes do not pass through the kernel's pty
 * worker: the bytes go through a socket, the settings through a pty that carries none.
 *
 * Why: a pty's bytes pass from one side to the other in a kernel worker thread at ordinary
 * priority, shared by every pty on the machine. Beside two busy loops and other tests it held
 * bytes for seconds (30 s once) while the tests' own threads woke on time, so timings a
 * test holds against reply timeouts failed for a reason outside the code under test. A
 * socket's bytes are in the reader's queue when write() returns, in the writer's own time.
 *
 * Two kinds of line, one set of answers:
 *  - inside a test program (tests/shims, linked in): tl_make() makes a socket pair and a pty
 *    for its settings; its name is a plain file, so the shims find a node with an identity
 *    there as on a device (mbfb_bus.c, port_key), and open() of that name hands them the
 *    socket's end;
 *  - between processes (built as libmbfb_testline.so, LD_PRELOAD): a pty that the simulator
 *    made and offers as a line (tools/sim/modsim/lineoffer.py: a Unix socket
 *    $MBFB_TESTLINE_DIR/mbfb-line-pts-N beside /dev/pts/N); open() of the pty (by any name)
 *    connects to that socket and keeps the pty for the settings, which the simulator reads
 *    on its side as before. A pty without such a socket stays a pty.
 * Everything else a port is asked goes to the settings pty, so the kernel answers as for a
 * pty: termios and termios2 set and read back (tcsetattr, TCGETS2, ...), ENOTTY for the
 * modem lines and the RS-485 mode a pty lacks, tcdrain at once. Only three answers are this
 * file's: FIONREAD and TIOCOUTQ count the socket's bytes, tcflush(TCIFLUSH) drops what the
 * socket holds unread, and write() on a line never raises SIGPIPE (a pty's gone peer is EIO;
 * here EPIPE: the shims take both as a lost port).
 * The functions below replace libc's: an executable's or a preloaded library's definitions
 * come first in symbol lookup (the test programs export them: tests/shims/CMakeLists.txt).
 * On a descriptor that is no line's each passes the call on.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <pty.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/un.h>
#include <termios.h>
#include <unistd.h>

#include "testline.h"

#define TL_LINES 64          /* lines inside one test program at once                      */
#define TL_FDS 1024          /* descriptors this file keeps track of: 0 .. TL_FDS - 1      */
#define PTS_MAJOR_FIRST 136  /* UNIX98 pty slaves: majors 136..143 (Documentation/admin-  */
#define PTS_MAJOR_LAST 143   /* guide/devices.txt), pty number (major - 136) * 256 + minor */

typedef struct {
    int used;
    dev_t dev;               /* the node of its name                                       */
    ino_t ino;
    int shims_end, peer_end; /* the socket pair; peer_end -1: the peer is another process  */
    int key;                 /* the descriptor tl_drop names it by: peer_end, or shims_end */
    int pty_master, pty_slave; /* the settings                                             */
} tl_line_t;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static tl_line_t lines[TL_LINES]; /* under lock                                            */
static int n_lines;               /* __atomic: lines in use; 0: open() looks up none        */
/* __atomic, per descriptor: 0 none; TL_PEER a peer's end (tl_make); else 1 + the descriptor
 * of the pty that holds its settings (its own: closed with it) */
#define TL_PEER (-1)
static int fd_line[TL_FDS];

static int (*real_open)(const char *, int, ...);
static int (*real_close)(int);
static ssize_t (*real_write)(int, const void *, size_t);
static int (*real_ioctl)(int, unsigned long, ...);
static int (*real_tcgetattr)(int, struct termios *);
static int (*real_tcsetattr)(int, int, const struct termios *);
static int (*real_tcdrain)(int);
static int (*real_tcflush)(int, int);
static const char *companion_dir; /* $MBFB_TESTLINE_DIR, or NULL                             */

static void resolve(void)
{
    const char *dir = getenv("MBFB_TESTLINE_DIR");
    real_open = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open");
    real_close = (int (*)(int))dlsym(RTLD_NEXT, "close");
    real_write = (ssize_t(*)(int, const void *, size_t))dlsym(RTLD_NEXT, "write");
    real_ioctl = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    real_tcgetattr = (int (*)(int, struct termios *))dlsym(RTLD_NEXT, "tcgetattr");
    real_tcsetattr = (int (*)(int, int, const struct termios *))dlsym(RTLD_NEXT, "tcsetattr");
    real_tcdrain = (int (*)(int))dlsym(RTLD_NEXT, "tcdrain");
    real_tcflush = (int (*)(int, int))dlsym(RTLD_NEXT, "tcflush");
    companion_dir = dir != NULL && dir[0] == '/' ? dir : NULL;
}

static void init(void)
{
    static pthread_once_t once = PTHREAD_ONCE_INIT;
    pthread_once(&once, resolve);
}

/* What fd is: 0, TL_PEER, or 1 + its settings' descriptor. */
static int kind(int fd)
{
    return fd >= 0 && fd < TL_FDS ? __atomic_load_n(&fd_line[fd], __ATOMIC_ACQUIRE) : 0;
}

static void mark(int fd, int k)
{
    __atomic_store_n(&fd_line[fd], k, __ATOMIC_RELEASE);
}

static void close_all(int a, int b, int c, int d)
{
    int fds[] = {a, b, c, d};
    for (int i = 0; i < 4; i++)
        if (fds[i] >= 0)
            real_close(fds[i]);
}

/* A line named `link` whose shims' end is `shims_end` and whose peer's end is `peer_end`
 * (-1: in another process); both closed by tl_drop. 0 or -1 (nothing kept). */
static int make(const char *link, int shims_end, int peer_end)
{
    int m = -1, s = -1, fd, i;
    struct stat st;
    struct termios tio;

    init();
    if ((fd = real_open(link, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600)) < 0)
        return -1;
    real_close(fd);
    if (stat(link, &st) != 0 || shims_end >= TL_FDS || peer_end >= TL_FDS ||
        openpty(&m, &s, NULL, NULL, NULL) != 0)
        return -1;
    if (real_tcgetattr(s, &tio) == 0) { /* raw, as a port the shims set */
        cfmakeraw(&tio);
        (void)real_tcsetattr(s, TCSANOW, &tio);
    }
    pthread_mutex_lock(&lock);
    for (i = 0; i < TL_LINES && lines[i].used; i++) {
    }
    if (i < TL_LINES) {
        int key = peer_end >= 0 ? peer_end : shims_end;
        lines[i] = (tl_line_t){1, st.st_dev, st.st_ino, shims_end, peer_end, key, m, s};
        mark(key, TL_PEER);
        __atomic_fetch_add(&n_lines, 1, __ATOMIC_RELEASE);
    }
    pthread_mutex_unlock(&lock);
    if (i == TL_LINES) {
        fprintf(stderr, "testline: more than %d lines at once\n", TL_LINES);
        close_all(m, s, -1, -1);
        return -1;
    }
    return 0;
}

int tl_make(const char *link, int *peer_fd)
{
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0)
        return -1;
    if (make(link, sv[1], sv[0]) != 0) {
        close_all(sv[0], sv[1], -1, -1);
        return -1;
    }
    *peer_fd = sv[0];
    return 0;
}

int tl_adopt(const char *link, int sock)
{
    return make(link, sock, -1);
}

void tl_drop(const char *link, int peer_fd)
{
    pthread_mutex_lock(&lock);
    for (int i = 0; i < TL_LINES; i++) {
        tl_line_t *l = &lines[i];
        if (l->used && l->key == peer_fd) {
            /* the shims' descriptors read EOF, write EPIPE, and their settings EIO */
            mark(l->shims_end, 0);
            if (l->peer_end >= 0)
                mark(l->peer_end, 0);
            close_all(l->shims_end, l->peer_end, l->pty_master, l->pty_slave);
            l->used = 0;
            __atomic_fetch_sub(&n_lines, 1, __ATOMIC_RELEASE);
        }
    }
    pthread_mutex_unlock(&lock);
    unlink(link);
}

/* A descriptor of the line inside this program that `path` names, its settings' descriptor
 * in *settings; -1 when path names none. */
static int open_made(const char *path, int flags, int *settings)
{
    struct stat st;
    int fd = -1, cmd = (flags & O_CLOEXEC) ? F_DUPFD_CLOEXEC : F_DUPFD;
    if (stat(path, &st) != 0)
        return -1;
    pthread_mutex_lock(&lock);
    for (int i = 0; i < TL_LINES; i++) {
        if (lines[i].used && lines[i].ino == st.st_ino && lines[i].dev == st.st_dev) {
            fd = fcntl(lines[i].shims_end, cmd, 0);
            *settings = fd >= 0 ? fcntl(lines[i].pty_slave, F_DUPFD_CLOEXEC, 0) : -1;
            break;
        }
    }
    pthread_mutex_unlock(&lock);
    return fd;
}

/* The simulator's socket for the pty slave `pty` (open), connected; -1 when it offers none. */
static int open_offered(int pty, int flags)
{
    struct stat st;
    struct sockaddr_un a = {.sun_family = AF_UNIX};
    int fd, n;
    if (companion_dir == NULL || fstat(pty, &st) != 0 || !S_ISCHR(st.st_mode) ||
        major(st.st_rdev) < PTS_MAJOR_FIRST || major(st.st_rdev) > PTS_MAJOR_LAST)
        return -1;
    n = snprintf(a.sun_path, sizeof a.sun_path, "%s/mbfb-line-pts-%u", companion_dir,
                 (major(st.st_rdev) - PTS_MAJOR_FIRST) * 256 + minor(st.st_rdev));
    if (n >= (int)sizeof a.sun_path || access(a.sun_path, F_OK) != 0)
        return -1;
    fd = socket(AF_UNIX, SOCK_STREAM | ((flags & O_CLOEXEC) ? SOCK_CLOEXEC : 0), 0);
    if (fd >= 0 && connect(fd, (struct sockaddr *)&a, sizeof a) != 0) {
        real_close(fd);
        fd = -1;
    }
    return fd;
}

static int open_any(const char *path, int flags, mode_t mode)
{
    int fd = -1, settings = -1;
    init();
    if (__atomic_load_n(&n_lines, __ATOMIC_ACQUIRE) > 0)
        fd = open_made(path, flags, &settings);
    if (fd < 0) {
        if ((settings = real_open(path, flags, mode)) < 0 || settings >= TL_FDS ||
            (fd = open_offered(settings, flags)) < 0)
            return settings; /* not a line: as it is */
    }
    if (fd >= TL_FDS || settings < 0) {
        close_all(fd, settings, -1, -1);
        errno = EMFILE;
        return -1;
    }
    /* one description for all descriptors of a socket end: O_NONBLOCK (libmodbus asks for
     * it) is set on it for all of them (only the shims use them) */
    if (flags & O_NONBLOCK)
        (void)fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    mark(fd, 1 + settings);
    return fd;
}

/* ---- libc's calls, on a line's descriptors answered as above --------------------- */
static mode_t mode_of(int flags, va_list ap)
{
    return (flags & (O_CREAT | O_TMPFILE)) ? (mode_t)va_arg(ap, int) : 0;
}

int open(const char *path, int flags, ...)
{
    va_list ap;
    va_start(ap, flags);
    mode_t mode = mode_of(flags, ap);
    va_end(ap);
    return open_any(path, flags, mode);
}

int open64(const char *path, int flags, ...)
{
    va_list ap;
    va_start(ap, flags);
    mode_t mode = mode_of(flags, ap);
    va_end(ap);
    return open_any(path, flags | O_LARGEFILE, mode);
}

int close(int fd)
{
    int k = kind(fd);
    init();
    if (k != 0) {
        mark(fd, 0);
        if (k > 0)
            real_close(k - 1);
    }
    return real_close(fd);
}

ssize_t write(int fd, const void *buf, size_t n)
{
    init();
    return kind(fd) != 0 ? send(fd, buf, n, MSG_NOSIGNAL) : real_write(fd, buf, n);
}

/* The descriptor that holds the settings of line descriptor fd, or -1. */
static int settings_of(int fd)
{
    int k = kind(fd);
    return k > 0 ? k - 1 : -1;
}

/* Drop what the line holds unread (TCIFLUSH); 0. */
static int drop_input(int fd)
{
    char junk[256];
    while (recv(fd, junk, sizeof junk, MSG_DONTWAIT) > 0) {
    }
    return 0;
}

int ioctl(int fd, unsigned long req, ...)
{
    va_list ap;
    void *arg;
    int s = settings_of(fd);
    va_start(ap, req);
    arg = va_arg(ap, void *);
    va_end(ap);
    init();
    if (s < 0 || req == FIONREAD || req == TIOCOUTQ)
        return real_ioctl(fd, req, arg);
    if (req == TCFLSH && ((long)arg == TCIFLUSH || (long)arg == TCIOFLUSH))
        return drop_input(fd);
    return real_ioctl(s, req, arg);
}

int tcgetattr(int fd, struct termios *t)
{
    int s = settings_of(fd);
    init();
    return real_tcgetattr(s >= 0 ? s : fd, t);
}

int tcsetattr(int fd, int act, const struct termios *t)
{
    int s = settings_of(fd);
    init();
    return real_tcsetattr(s >= 0 ? s : fd, act, t);
}

int tcdrain(int fd)
{
    int s = settings_of(fd);
    init();
    return real_tcdrain(s >= 0 ? s : fd);
}

int tcflush(int fd, int queue)
{
    int s = settings_of(fd);
    init();
    if (s < 0)
        return real_tcflush(fd, queue);
    return queue == TCIFLUSH || queue == TCIOFLUSH ? drop_input(fd) : 0;
}
