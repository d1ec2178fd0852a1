/*
 * testline.c - the serial line between the test peer and the shims, inside the test's
 * process: its bytes go through a socket pair, its settings through a pty that carries none.
 *
 * Why not a pty alone: a pty's bytes pass from one side to the other in a kernel worker
 * thread at ordinary priority, shared by every pty on the machine. Beside two busy loops and
 * other tests it held bytes for up to 30 s while the test's own threads woke on time, so the
 * scenarios' timings (a reply within its 100 ms timeout, a late reply in the wait for the
 * next) failed for a reason outside the code under test. A socket's bytes are in the
 * reader's queue when write() returns, in the writer's own time.
 *
 * How: the port the shims are given is a plain file (peer_t.link), so the shims find a node
 * with an identity there as on a device (mbfb_bus.c, port_key), and this file's open() hands
 * them their end of the line's socket pair for it. Everything else a port is asked goes to
 * the line's pty, so the kernel answers as it answers for a pty: termios and termios2 set
 * and read back (tcsetattr, TCGETS2, ...), ENOTTY for the modem lines and the RS-485 mode
 * a pty lacks, tcdrain at once. Only three answers are this file's: FIONREAD and TIOCOUTQ
 * count the socket's bytes, tcflush(TCIFLUSH) drops what the socket holds unread, and
 * write() on either end never raises SIGPIPE (a pty's gone peer is EIO; here EPIPE: the shims
 * take both as a lost port).
 * The functions below replace libc's in the whole test program: an executable's definitions
 * come first in symbol lookup, for libmodbus's shared library too (the test programs export
 * them: tests/shims/CMakeLists.txt). Where a name is no line's, each passes the call on.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <pty.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include "testline.h"

#define TL_LINES 64    /* lines open at once in one test program */
#define TL_FDS 1024    /* descriptors this file keeps track of: 0 .. TL_FDS - 1 */

typedef struct {
    int used;          /* a line, open or dropped with descriptors of the shims still open */
    int dropped;       /* tl_drop: the peer is gone (the pty's master closed too)         */
    dev_t dev;         /* the node of its name                                            */
    ino_t ino;
    int shims_end;     /* the socket end each open() of the name duplicates               */
    int peer_end;      /* the peer's                                                      */
    int pty_master, pty_slave; /* the settings: every terminal call goes to pty_slave     */
    int refs;          /* descriptors of the shims' end open (shims_end's own included)   */
} tl_line_t;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static tl_line_t lines[TL_LINES];   /* under lock                                           */
static int n_used;                  /* __atomic: lines in use; 0: every call passes on      */
/* __atomic, per descriptor: 0 none; TL_PEER the peer's end of a line; 1 + i an end of the
 * shims on line i */
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

static void resolve(void)
{
    real_open = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open");
    real_close = (int (*)(int))dlsym(RTLD_NEXT, "close");
    real_write = (ssize_t(*)(int, const void *, size_t))dlsym(RTLD_NEXT, "write");
    real_ioctl = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    real_tcgetattr = (int (*)(int, struct termios *))dlsym(RTLD_NEXT, "tcgetattr");
    real_tcsetattr = (int (*)(int, int, const struct termios *))dlsym(RTLD_NEXT, "tcsetattr");
    real_tcdrain = (int (*)(int))dlsym(RTLD_NEXT, "tcdrain");
    real_tcflush = (int (*)(int, int))dlsym(RTLD_NEXT, "tcflush");
}

static void init(void)
{
    static pthread_once_t once = PTHREAD_ONCE_INIT;
    pthread_once(&once, resolve);
}

/* What fd is: 0, TL_PEER, or 1 + the index of the line whose shims' end it is. */
static int kind(int fd)
{
    return fd >= 0 && fd < TL_FDS ? __atomic_load_n(&fd_line[fd], __ATOMIC_ACQUIRE) : 0;
}

static void mark(int fd, int k)
{
    if (fd >= 0 && fd < TL_FDS)
        __atomic_store_n(&fd_line[fd], k, __ATOMIC_RELEASE);
}

/* Free line i when it is dropped and no descriptor of the shims is left (under lock). */
static void release(int i)
{
    tl_line_t *l = &lines[i];
    if (l->used && l->dropped && l->refs == 0) {
        real_close(l->pty_slave);
        l->used = 0;
        __atomic_fetch_sub(&n_used, 1, __ATOMIC_RELEASE);
    }
}

int tl_make(const char *link, int *peer_fd)
{
    int sv[2], m, s, fd, i;
    struct stat st;
    struct termios tio;

    init();
    if ((fd = real_open(link, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600)) < 0)
        return -1;
    real_close(fd);
    if (stat(link, &st) != 0 || socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0)
        return -1;
    if (sv[0] >= TL_FDS || sv[1] >= TL_FDS || openpty(&m, &s, NULL, NULL, NULL) != 0) {
        real_close(sv[0]);
        real_close(sv[1]);
        return -1;
    }
    if (real_tcgetattr(s, &tio) == 0) { /* raw, as a port the shims set */
        cfmakeraw(&tio);
        (void)real_tcsetattr(s, TCSANOW, &tio);
    }
    pthread_mutex_lock(&lock);
    for (i = 0; i < TL_LINES && lines[i].used; i++) {
    }
    if (i == TL_LINES) {
        pthread_mutex_unlock(&lock);
        fprintf(stderr, "testline: more than %d lines at once\n", TL_LINES);
        real_close(sv[0]), real_close(sv[1]), real_close(m), real_close(s);
        return -1;
    }
    lines[i] = (tl_line_t){.used = 1, .dev = st.st_dev, .ino = st.st_ino, .shims_end = sv[1],
                           .peer_end = sv[0], .pty_master = m, .pty_slave = s, .refs = 1};
    mark(sv[0], TL_PEER);
    mark(sv[1], 1 + i);
    __atomic_fetch_add(&n_used, 1, __ATOMIC_RELEASE);
    pthread_mutex_unlock(&lock);
    *peer_fd = sv[0];
    return 0;
}

void tl_drop(const char *link, int peer_fd)
{
    pthread_mutex_lock(&lock);
    for (int i = 0; i < TL_LINES; i++) {
        tl_line_t *l = &lines[i];
        if (l->used && !l->dropped && l->peer_end == peer_fd) {
            l->dropped = 1; /* the shims' descriptors now read EOF and write EPIPE */
            real_close(l->pty_master);
            mark(l->shims_end, 0);
            real_close(l->shims_end);
            l->refs--;
            release(i);
            break;
        }
    }
    pthread_mutex_unlock(&lock);
    unlink(link);
    mark(peer_fd, 0);
    real_close(peer_fd);
}

/* The line whose name is path: its index, or -1 (under lock). */
static int line_named(const char *path)
{
    struct stat st;
    if (stat(path, &st) != 0)
        return -1;
    for (int i = 0; i < TL_LINES; i++)
        if (lines[i].used && !lines[i].dropped && lines[i].ino == st.st_ino &&
            lines[i].dev == st.st_dev)
            return i;
    return -1;
}

static int open_any(const char *path, int flags, mode_t mode)
{
    int fd = -1, i;
    init();
    if (__atomic_load_n(&n_used, __ATOMIC_ACQUIRE) == 0)
        return real_open(path, flags, mode);
    pthread_mutex_lock(&lock);
    if ((i = line_named(path)) < 0) {
        pthread_mutex_unlock(&lock);
        return real_open(path, flags, mode);
    }
    /* one description for all the shims' descriptors of a line (a socket cannot be opened
     * again): O_NONBLOCK, which libmodbus asks for, is set on it for all of them */
    fd = fcntl(lines[i].shims_end, (flags & O_CLOEXEC) ? F_DUPFD_CLOEXEC : F_DUPFD, 0);
    if (fd >= 0 && (flags & O_NONBLOCK))
        (void)fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    if (fd >= TL_FDS) {
        real_close(fd);
        fd = -1;
        errno = EMFILE;
    }
    if (fd >= 0) {
        lines[i].refs++;
        mark(fd, 1 + i);
    }
    pthread_mutex_unlock(&lock);
    return fd;
}

/* ---- libc's calls, on a line's descriptors answered as above --------------------- */
int open(const char *path, int flags, ...)
{
    mode_t mode = 0;
    if (flags & (O_CREAT | O_TMPFILE)) {
        va_list ap;
        va_start(ap, flags);
        mode = (mode_t)va_arg(ap, int);
        va_end(ap);
    }
    return open_any(path, flags, mode);
}

int open64(const char *path, int flags, ...)
{
    mode_t mode = 0;
    if (flags & (O_CREAT | O_TMPFILE)) {
        va_list ap;
        va_start(ap, flags);
        mode = (mode_t)va_arg(ap, int);
        va_end(ap);
    }
    return open_any(path, flags | O_LARGEFILE, mode);
}

int close(int fd)
{
    int k = kind(fd);
    init();
    if (k > 0) {
        pthread_mutex_lock(&lock);
        if (kind(fd) == k) {
            mark(fd, 0);
            lines[k - 1].refs--;
            release(k - 1);
        }
        pthread_mutex_unlock(&lock);
    }
    return real_close(fd);
}

ssize_t write(int fd, const void *buf, size_t n)
{
    init();
    return kind(fd) != 0 ? send(fd, buf, n, MSG_NOSIGNAL) : real_write(fd, buf, n);
}

/* The pty that holds the settings of the line whose shims' end fd is, or -1 (then fd is
 * passed on as it is). */
static int settings_of(int fd)
{
    int k = kind(fd), s = -1;
    if (k > 0) {
        pthread_mutex_lock(&lock);
        s = lines[k - 1].pty_slave;
        pthread_mutex_unlock(&lock);
    }
    return s;
}

/* Drop what the shims' end holds unread (TCIFLUSH); 0. */
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
    int s;
    va_start(ap, req);
    arg = va_arg(ap, void *);
    va_end(ap);
    init();
    if ((s = settings_of(fd)) < 0 || req == FIONREAD || req == TIOCOUTQ)
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
