// fb_host.cpp - runs one iec2c-compiled ST program the way OpenPLC v3's runtime does
// (core/main.cpp: config_init__(), then config_run__(__tick++) and updateTime() every
// common_ticktime__ ns), linked with the mbfb shims and the program's glue (mkglue.py).
//
// Test mode (no arguments): runs an ST test program in simulated time (one period's sleep per
// scan) and reports the ST checks (fbtest.st; their host functions are in fbtest_hooks.cpp).
// Environment: MBFB_TEST_PORT (device port for the program), MBFB_SIM_CONTROL (simulator
// control socket), MBFB_MAX_SCANS (scan limit, default 6000). Exit: 0 all checks passed and
// the program called T_DONE; 1 a check failed, or the scan limit was reached, or no check ran.
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

// The test hooks (fbt_*, what the test programs call) are in fbtest_hooks.cpp.
static long g_scan;

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

// Test mode: the checks' tally and the end of the run are the hooks' (fbtest_hooks.cpp).
static int run_tests(void) {
    long max_scans = fbt_host_max_scans();
    config_init__();
    for (g_scan = 0; g_scan < max_scans && !fbt_host_stop(); g_scan++) {
        fbt_host_set_scan(g_scan);
        config_run__((unsigned long)g_scan);
        update_time();
        sleep_ns(common_ticktime__);     // like sleep_until(): lets the worker and the bus run
    }
    mbfb_shutdown();
    return fbt_host_finish(g_scan);
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
