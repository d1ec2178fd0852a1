// fb_host.cpp - runs one iec2c-compiled ST program the way OpenPLC v3's runtime does
// (core/main.cpp: config_init__(), then config_run__(__tick++) and updateTime() every
// common_ticktime__ ns), linked with the mbfb shims and the program's glue (mkglue.py).
//
// Test mode (no arguments): runs an ST test program in simulated time (one period's sleep per
// scan) and reports the ST checks (fbtest.st). Environment: MBFB_TEST_PORT (device port for
// the program), MBFB_SIM_CONTROL (simulator control socket), MBFB_MAX_SCANS (scan limit,
// default 6000). Exit: 0 all checks passed and the program called T_DONE; 1 a check failed,
// or the scan limit was reached, or no check ran.
//
// Program mode, the project's own runner where OpenPLC's runtime is missing:
//   fb_<name> --run [--snapshot FILE] [--control SOCKET] [--set NAME=VALUE]... [--seconds N]
// runs the program at its task period in real time until SIGINT/SIGTERM/SIGHUP (or N s).
// --set overrides a variable after initialisation, before the first scan (plc_vars.h names,
// e.g. CONFIG0.RES0.HEATTREAT.BUSPORT=/dev/ttyUSB1). Every 200 ms the located variables are
// written to FILE atomically ({"scan": N, "QW": {"0": 1494}, "QX": {"0.0": true}, ...}), and
// SOCKET takes "set %MW0 1500" / "get %QW0" between scans (plc_control.h). Exit 0 when
// stopped, 2 on bad arguments.
#include "iec_types_all.h"
#include "mbfb.h"
#include "fbtest.h"
#include "plc_control.h"
#include "plc_vars.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <string>
#include <vector>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

TIME __CURRENT_TIME;                     // OpenPLC: core/glueVars.cpp
#ifdef MBFB_PROGRAM_IN_C                 // the program compiled as C (matiec's own headers)
extern "C" {
#endif
extern unsigned long long common_ticktime__;
void config_init__(void);
void config_run__(unsigned long tick);
#ifdef MBFB_PROGRAM_IN_C
}
#endif

// OpenPLC's TCP blocks (core/lib/communication.h) are compiled into every program; their C
// lives in OpenPLC's client.cpp, which the test programs do not use: fail if ever called.
int connect_to_tcp_server(uint8_t *, uint16_t, int) { return -1; }
int send_tcp_message(uint8_t *, size_t, int) { return -1; }
int receive_tcp_message(uint8_t *, size_t, int) { return -1; }

static long g_scan;
static int g_failed, g_passed, g_done;
static int g_sim_fd = -1;

void fbt_fail(const uint8_t *msg, int len) {
    printf("FAIL scan %ld: %.*s\n", g_scan, len, (const char *)msg);
    fflush(stdout);
    g_failed++;
}
void fbt_pass(void) { g_passed++; }
void fbt_note(const uint8_t *msg, int len) {
    printf("note scan %ld: %.*s\n", g_scan, len, (const char *)msg);
    fflush(stdout);
}
void fbt_done(void) { g_done = 1; }
long fbt_scan(void) { return g_scan; }

int fbt_getenv(const char *name, uint8_t *buf, int max) {
    const char *v = getenv(name);
    if (!v) return -1;
    int n = (int)strlen(v);
    if (n > max) n = max;
    memcpy(buf, v, (size_t)n);
    return n;
}

static long json_long(const std::string &s, const char *key) {
    std::string k = std::string("\"") + key + "\":";
    size_t p = s.find(k);
    if (p == std::string::npos) return -1;
    p += k.size();
    while (p < s.size() && s[p] == ' ') p++;
    return strtol(s.c_str() + p, NULL, 10);
}

int fbt_sim(const uint8_t *req, int len, uint8_t *buf, int max, int *ok, long *raw, long *frames,
            const uint8_t *match, int match_len, long *matches) {
    *ok = 0; *raw = -1; *frames = -1; *matches = 0;
    if (g_sim_fd < 0) {
        const char *path = getenv("MBFB_SIM_CONTROL");
        if (!path) return -1;
        struct sockaddr_un sa;
        memset(&sa, 0, sizeof sa);
        sa.sun_family = AF_UNIX;
        strncpy(sa.sun_path, path, sizeof sa.sun_path - 1);
        g_sim_fd = socket(AF_UNIX, SOCK_STREAM, 0);
        if (g_sim_fd < 0 || connect(g_sim_fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
            perror("fbt_sim: connect");
            if (g_sim_fd >= 0) close(g_sim_fd);
            g_sim_fd = -1;
            return -1;
        }
    }
    std::string line((const char *)req, (size_t)len);
    line += "\n";
    if (write(g_sim_fd, line.data(), line.size()) != (ssize_t)line.size()) return -1;
    std::string reply;
    char c;
    for (;;) {
        ssize_t n = read(g_sim_fd, &c, 1);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return -1;
        if (c == '\n') break;
        reply += c;
    }
    *ok = reply.find("\"ok\": true") != std::string::npos || reply.find("\"ok\":true") != std::string::npos;
    *raw = json_long(reply, "raw");
    long count = 0;
    for (size_t p = reply.find("\"dir\""); p != std::string::npos; p = reply.find("\"dir\"", p + 1))
        count++;
    *frames = reply.find("\"frames\"") != std::string::npos ? count : -1;
    if (match_len > 0) {
        std::string m((const char *)match, (size_t)match_len);
        for (size_t p = reply.find(m); p != std::string::npos; p = reply.find(m, p + 1))
            (*matches)++;
    }
    int n = (int)reply.size() < max ? (int)reply.size() : max;
    memcpy(buf, reply.data(), (size_t)n);
    return (int)reply.size();
}

static void sleep_ns(unsigned long long ns) {
    struct timespec ts = {(time_t)(ns / 1000000000ULL), (long)(ns % 1000000000ULL)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {}
}

// t += ns, for struct timespec and matiec's IEC_TIMESPEC alike.
template <class T> static void add_ns(T *t, unsigned long long ns) {
    t->tv_sec += (long)(ns / 1000000000ULL);
    t->tv_nsec += (long)(ns % 1000000000ULL);
    if (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec += 1;
    }
}

// updateTime() of core/glueVars.cpp
static void update_time(void) { add_ns(&__CURRENT_TIME, common_ticktime__); }

static int run_tests(void) {
    const char *m = getenv("MBFB_MAX_SCANS");
    long max_scans = m ? atol(m) : 6000;
    config_init__();
    for (g_scan = 0; g_scan < max_scans && !g_failed && !g_done; g_scan++) {
        config_run__((unsigned long)g_scan);
        update_time();
        sleep_ns(common_ticktime__);     // like sleep_until(): lets the worker and the bus run
    }
    mbfb_shutdown();
    if (g_sim_fd >= 0) close(g_sim_fd);
    printf("%ld scans, %d checks passed, %d failed%s\n", g_scan, g_passed, g_failed,
           (g_done || g_failed) ? "" : ", program did not finish (scan limit)");
    if (g_failed || !g_done) return 1;
    if (g_passed == 0) {
        printf("FAIL: no check ran\n");
        return 1;
    }
    return 0;
}

struct run_args {
    const char *snapshot = NULL, *control = NULL;
    std::vector<std::string> sets;
    double seconds = 0;
};

static volatile sig_atomic_t g_stop;
static void on_stop(int) { g_stop = 1; }

static double since(const struct timespec *a, const struct timespec *b) {
    return (double)(b->tv_sec - a->tv_sec) + (b->tv_nsec - a->tv_nsec) / 1e9;
}

// --set NAME=VALUE, after config_init__() and before the first scan.
static int apply_set(const std::string &arg) {
    size_t eq = arg.find('=');
    std::string line = eq == std::string::npos ? arg : "set " + arg.substr(0, eq) + " " + arg.substr(eq + 1);
    char reply[512];
    if (eq == std::string::npos || plc_command(line.c_str(), reply, sizeof reply) != 0) {
        fprintf(stderr, "runner: --set %s: %s\n", arg.c_str(),
                eq == std::string::npos ? "expected NAME=VALUE" : reply + 7);
        return -1;
    }
    return 0;
}

static int run_program(const run_args &a) {
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_stop;   // no SA_RESTART: the wait between scans ends at once
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
    config_init__();
    for (const std::string &s : a.sets)
        if (apply_set(s) != 0) return 2;
    if (a.control && plc_control_open(a.control) != 0) {
        fprintf(stderr, "runner: control socket %s: %s\n", a.control, strerror(errno));
        return 2;
    }
    fprintf(stderr, "runner: %d variables, scan every %.1f ms%s%s%s%s\n", plc_nvars,
            common_ticktime__ / 1e6, a.snapshot ? ", snapshot " : "", a.snapshot ? a.snapshot : "",
            a.control ? ", control " : "", a.control ? a.control : "");
    struct timespec start, next, now, last_snap = {0, 0};
    clock_gettime(CLOCK_MONOTONIC, &start);
    next = start;
    int snap_errors = 0;
    while (!g_stop && !(a.seconds > 0 && since(&start, &next) >= a.seconds)) {
        config_run__((unsigned long)g_scan++);
        update_time();
        clock_gettime(CLOCK_MONOTONIC, &now);
        if (a.snapshot && (g_scan == 1 || since(&last_snap, &now) >= 0.2)) {
            if (plc_snapshot_write(a.snapshot, (unsigned long)g_scan) != 0 && !snap_errors++)
                fprintf(stderr, "runner: snapshot %s: %s\n", a.snapshot, strerror(errno));
            last_snap = now;
        }
        add_ns(&next, common_ticktime__);   // sleep_until() of OpenPLC's main.cpp: late scans
        while (plc_control_serve(&next) != 0 && !g_stop) {}   // catch up, none is skipped
    }
    plc_control_close();
    mbfb_shutdown();
    fprintf(stderr, "runner: stopped after %ld scans\n", g_scan);
    return 0;
}

static const char *USAGE = "--run [--snapshot FILE] [--control SOCKET] [--set NAME=VALUE]... [--seconds N]";

// A command-line error: one line, exit 2.
static int usage_error(const char *prog, const std::string &what) {
    fprintf(stderr, "runner: %s (usage: %s %s; no arguments: test mode)\n", what.c_str(), prog, USAGE);
    return 2;
}

int main(int argc, char **argv) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (argc == 1) return run_tests();
    run_args a;
    bool run = false;
    for (int i = 1; i < argc; i++) {
        std::string o = argv[i];
        bool takes_value = o == "--snapshot" || o == "--control" || o == "--set" || o == "--seconds";
        if (o == "--help" || o == "-h") {
            printf("usage: %s %s\n       %s   (test mode: an ST test program, see fb_host.cpp)\n",
                   argv[0], USAGE, argv[0]);
            return 0;
        }
        if (o == "--run") { run = true; continue; }
        if (!takes_value) return usage_error(argv[0], "unknown option '" + o + "'");
        if (i + 1 >= argc) return usage_error(argv[0], o + " needs a value");
        const char *v = argv[++i];
        if (!*v) return usage_error(argv[0], o + " needs a non-empty value");
        if (o == "--snapshot") a.snapshot = v;
        else if (o == "--control") a.control = v;
        else if (o == "--set") a.sets.push_back(v);
        else {
            char *end;
            errno = 0;
            a.seconds = strtod(v, &end);
            if (*end || errno || !(a.seconds >= 0) || a.seconds > 1e9)
                return usage_error(argv[0], "--seconds wants a number of seconds >= 0, not '" + std::string(v) + "'");
        }
    }
    if (!run) return usage_error(argv[0], "--run missing");
    return run_program(a);
}
