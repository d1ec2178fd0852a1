/* mbfb-ptyline: joins two ptys (M: master side, S: slave side) as one
 * half-duplex RS-485 line paced at a baud rate, and counts what happens on it.
 * Usage and the stats keys: ../README.md.  Hand-written because no library we
 * use simulates a shared serial wire (socat joins ptys but neither paces per
 * character nor models a half-duplex bus). */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "line.h"
#include "report.h"
#include "side.h"

#define QUEUE_BYTES 65536
#define LAST_STRETCH_NS 200000 /* finish waits shorter than this with clock_nanosleep */

typedef struct {
    long baud;
    const char *format;
    int char_bits, paced, turn_lo, turn_hi;
    unsigned long long seed;
    const char *stats, *log, *link[2];
} options;

typedef struct {
    options opt;
    pl_line line;
    pl_side side[2]; /* index = the direction whose bytes it sends: M, S */
    pl_settings settings; /* the line's speed (checked on both sides) and stop bits */
    pl_report_info info;
    FILE *log;
} ptyline;

static volatile sig_atomic_t g_stop, g_dump;

static void on_signal(int sig)
{
    if (sig == SIGUSR1)
        g_dump = 1;
    else
        g_stop = 1;
}

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static struct timespec to_ts(int64_t ns)
{
    struct timespec ts = {.tv_sec = ns / 1000000000, .tv_nsec = ns % 1000000000};
    return ts;
}

static void usage(FILE *f)
{
    fputs("usage: mbfb-ptyline [--baud N] [--format 8N2] [--no-pace]\n"
          "                    [--turnaround-ms LO:HI] [--seed N]\n"
          "                    [--stats PATH] [--log PATH] [--link-m PATH] [--link-s PATH]\n"
          "Prints 'M <pty>' and 'S <pty>' when ready; SIGUSR1 writes --stats;\n"
          "SIGTERM/SIGINT write --stats and exit 0.\n",
          f);
}

static int bad(const char *what, const char *value)
{
    fprintf(stderr, "mbfb-ptyline: bad %s '%s'\n", what, value);
    usage(stderr);
    return -1;
}

static int parse_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

static int parse_options(int argc, char **argv, options *o)
{
    static const struct option longs[] = {
        {"baud", required_argument, 0, 'b'},      {"format", required_argument, 0, 'f'},
        {"no-pace", no_argument, 0, 'n'},         {"turnaround-ms", required_argument, 0, 't'},
        {"seed", required_argument, 0, 'r'},      {"stats", required_argument, 0, 's'},
        {"log", required_argument, 0, 'l'},       {"link-m", required_argument, 0, 'M'},
        {"link-s", required_argument, 0, 'S'},    {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0}};
    *o = (options){.baud = 9600, .format = "8N2", .paced = 1, .seed = 1};
    int c;
    long lo, hi;
    char *colon, *end;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'b':
            if (parse_long(optarg, 50, 4000000, &o->baud) != 0)
                return bad("--baud (50..4000000)", optarg);
            break;
        case 'f': o->format = optarg; break;
        case 'n': o->paced = 0; break;
        case 't':
            colon = strchr(optarg, ':');
            if (colon == NULL || colon - optarg > 15)
                return bad("--turnaround-ms (LO:HI)", optarg);
            char first[16];
            memcpy(first, optarg, (size_t)(colon - optarg));
            first[colon - optarg] = '\0';
            if (parse_long(first, 0, 10000, &lo) != 0 || parse_long(colon + 1, lo, 10000, &hi) != 0)
                return bad("--turnaround-ms (LO:HI, 0 <= LO <= HI <= 10000)", optarg);
            o->turn_lo = (int)lo;
            o->turn_hi = (int)hi;
            break;
        case 'r':
            errno = 0;
            o->seed = strtoull(optarg, &end, 10);
            if (errno != 0 || end == optarg || *end != '\0' || optarg[0] == '-')
                return bad("--seed", optarg);
            break;
        case 's': o->stats = optarg; break;
        case 'l': o->log = optarg; break;
        case 'M': o->link[0] = optarg; break;
        case 'S': o->link[1] = optarg; break;
        case 'h': usage(stdout); exit(0);
        default: usage(stderr); return -1;
        }
    }
    if (optind < argc)
        return bad("argument", argv[optind]);
    o->char_bits = pl_format_bits(o->format);
    if (o->char_bits < 0)
        return bad("--format (data bits 5-8, parity N/E/O, stop bits 1-2, e.g. 8N2)", o->format);
    return 0;
}

static void on_frame(const pl_frame *f, void *user)
{
    ptyline *p = user;
    if (p->log != NULL)
        pl_report_frame(p->log, f, p->info.t0_ns);
}

static int dump_stats(ptyline *p, int64_t now)
{
    if (p->log != NULL)
        fflush(p->log);
    if (p->opt.stats == NULL || pl_report_write(&p->line, &p->info, now, p->opt.stats) == 0)
        return 0;
    fprintf(stderr, "mbfb-ptyline: --stats %s: %s\n", p->opt.stats, strerror(errno));
    return -1;
}

/* Hands the bytes whose end has come to their receivers. */
static void deliver(ptyline *p, int64_t now)
{
    uint8_t buf[4096];
    for (int d = 0; d < 2; d++) {
        pl_side *to = &p->side[!d];
        size_t n;
        while ((n = pl_line_take_due(&p->line, d, now, buf, sizeof buf)) > 0) {
            pl_side_check_up(to, now, 1); /* a peer that just opened gets it */
            pl_line_dropped(&p->line, d, pl_side_put(to, buf, n));
        }
        pl_line_dropped(&p->line, d, pl_side_flush(to));
    }
}

/* Puts what side d's peer wrote on the line, stamped with `now`. */
static void receive(ptyline *p, int d, int64_t now)
{
    uint8_t buf[4096];
    for (;;) {
        size_t room = pl_line_room(&p->line, d);
        if (room == 0)
            return; /* the pty keeps the rest until the line has room */
        long n = pl_side_read(&p->side[d], buf, room < sizeof buf ? room : sizeof buf);
        if (n <= 0)
            return;
        /* A sender or receiver whose port is set to another speed than the line gets
         * what a UART gives: framing errors, which a raw Linux tty delivers as NUL
         * bytes (other stop bits do not: a UART checks only the first).  Checked per
         * read, as a peer may change its port. */
        if (!pl_side_settings_ok(&p->side[d], &p->settings) ||
            (p->side[!d].up && !pl_side_settings_ok(&p->side[!d], &p->settings))) {
            memset(buf, 0, (size_t)n);
            p->line.dir[d].format_errors += (uint64_t)n;
        }
        for (long i = 0; i < n; i++)
            pl_line_send(&p->line, d, buf[i], now);
    }
}

/* Waits for pty input or output room until the next deadline; returns the time. */
static int64_t wait_events(ptyline *p, int64_t now)
{
    int64_t deadline = pl_line_next_deadline(&p->line);
    struct pollfd fds[2];
    int idx[2], n = 0;
    for (int d = 0; d < 2; d++) {
        pl_side *s = &p->side[d];
        if (!s->up) {
            if (s->next_check_ns < deadline)
                deadline = s->next_check_ns;
            continue;
        }
        short ev = (pl_line_room(&p->line, d) > 0 ? POLLIN : 0) | (s->out_len > 0 ? POLLOUT : 0);
        fds[n] = (struct pollfd){.fd = s->fd, .events = ev};
        idx[n++] = d;
    }
    if (deadline != PL_NEVER && deadline - now < LAST_STRETCH_NS) {
        struct timespec ts = to_ts(deadline);
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
            ;
        return now_ns();
    }
    sigset_t open_mask;
    sigemptyset(&open_mask);
    struct timespec tmo = to_ts(deadline == PL_NEVER ? 0 : deadline - now - LAST_STRETCH_NS / 2);
    int r = ppoll(fds, (nfds_t)n, deadline == PL_NEVER ? NULL : &tmo, &open_mask);
    now = now_ns();
    for (int i = 0; r > 0 && i < n; i++) {
        int d = idx[i];
        if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) {
            receive(p, d, now);
            if ((fds[i].revents & POLLHUP) && p->side[d].up && pl_line_room(&p->line, d) == 0)
                pl_side_down(&p->side[d]); /* hung up with the line full: the rest is lost */
        }
        if (fds[i].revents & POLLOUT)
            pl_line_dropped(&p->line, !d, pl_side_flush(&p->side[d]));
    }
    return now;
}

static int run(ptyline *p)
{
    int64_t now = now_ns();
    while (!g_stop) {
        deliver(p, now);
        pl_line_expire(&p->line, now);
        if (g_dump) {
            g_dump = 0;
            dump_stats(p, now);
        }
        for (int d = 0; d < 2; d++)
            pl_side_check_up(&p->side[d], now, 0);
        now = wait_events(p, now);
    }
    deliver(p, now);
    pl_line_expire(&p->line, PL_NEVER);
    return dump_stats(p, now);
}

static int setup_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigset_t block;
    sigemptyset(&block);
    int sigs[] = {SIGTERM, SIGINT, SIGUSR1};
    for (size_t i = 0; i < sizeof sigs / sizeof sigs[0]; i++) {
        sigaddset(&block, sigs[i]);
        if (sigaction(sigs[i], &sa, NULL) != 0)
            return -1;
    }
    signal(SIGPIPE, SIG_IGN);
    /* Signals arrive only inside ppoll, so no system call is cut short elsewhere. */
    return sigprocmask(SIG_BLOCK, &block, NULL);
}

int main(int argc, char **argv)
{
    static ptyline p;
    if (parse_options(argc, argv, &p.opt) != 0)
        return 2;
    if (pl_line_init(&p.line, p.opt.baud, p.opt.char_bits, p.opt.paced, QUEUE_BYTES,
                     p.opt.turn_lo, p.opt.turn_hi, p.opt.seed, on_frame, &p) != 0) {
        fprintf(stderr, "mbfb-ptyline: %s\n", strerror(errno));
        return 1;
    }
    if (p.opt.log != NULL && (p.log = fopen(p.opt.log, "w")) == NULL) {
        fprintf(stderr, "mbfb-ptyline: --log %s: %s\n", p.opt.log, strerror(errno));
        return 1;
    }
    if (p.log != NULL)
        setvbuf(p.log, NULL, _IOLBF, 0);
    if (setup_signals() != 0) {
        fprintf(stderr, "mbfb-ptyline: signals: %s\n", strerror(errno));
        return 1;
    }
    int rc = 1;
    p.side[0].fd = p.side[1].fd = -1;
    pl_settings_of(p.opt.baud, p.opt.format, &p.settings);
    if (pl_side_open(&p.side[0], 'M', p.opt.link[0], &p.settings) == 0 &&
        pl_side_open(&p.side[1], 'S', p.opt.link[1], &p.settings) == 0) {
        p.info = (pl_report_info){.format = p.opt.format, .seed = p.opt.seed,
                                  .turn_lo_ms = p.opt.turn_lo, .turn_hi_ms = p.opt.turn_hi,
                                  .t0_ns = now_ns(), .side = {&p.side[0], &p.side[1]}};
        printf("M %s\nS %s\n", p.side[0].path, p.side[1].path);
        fflush(stdout);
        rc = run(&p) == 0 ? 0 : 1;
    }
    pl_side_close(&p.side[0]);
    pl_side_close(&p.side[1]);
    if (p.log != NULL)
        fclose(p.log);
    pl_line_free(&p.line);
    return rc;
}
