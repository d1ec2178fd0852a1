// fb_host.cpp - the project's own runner where OpenPLC's runtime is missing: runs one
// iec2c-compiled ST program the way OpenPLC v3's runtime does (plc_host.h), linked with the mbfb
// shims and the program's glue (mkglue.py), at its task period in real time:
//   fb_<name> --run [--snapshot FILE] [--control SOCKET] [--set NAME=VALUE]... [--seconds N]
// until SIGINT/SIGTERM/SIGHUP (or N s). --set overrides a variable after initialisation, before
// the first scan (plc_vars.h names, e.g. CONFIG0.RES0.HEATTREAT.BUSPORT=/dev/ttyUSB1). Every
// 200 ms the located variables are written to FILE atomically ({"scan": N, "QW": {"0": 1494},
// "QX": {"0.0": true}, ...}), and SOCKET takes "set %MW0 1500" / "get %QW0" between scans
// (plc_control.h). Exit 0 when stopped, 2 on bad arguments. (The ST test programs run in
// their own host, tests/fb/fb_test_host.cpp.)
#include "mbfb.h"
#include "plc_control.h"
#include "plc_host.h"
#include "plc_vars.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <string>
#include <vector>
#include <time.h>

static long g_scan;

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
        plc_update_time();
        clock_gettime(CLOCK_MONOTONIC, &now);
        if (a.snapshot && (g_scan == 1 || since(&last_snap, &now) >= 0.2)) {
            if (plc_snapshot_write(a.snapshot, (unsigned long)g_scan) != 0 && !snap_errors++)
                fprintf(stderr, "runner: snapshot %s: %s\n", a.snapshot, strerror(errno));
            last_snap = now;
        }
        plc_add_ns(&next, common_ticktime__);   // sleep_until() of OpenPLC's main.cpp: late scans
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
    fprintf(stderr, "runner: %s (usage: %s %s)\n", what.c_str(), prog, USAGE);
    return 2;
}

int main(int argc, char **argv) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    run_args a;
    bool run = false;
    for (int i = 1; i < argc; i++) {
        std::string o = argv[i];
        bool takes_value = o == "--snapshot" || o == "--control" || o == "--set" || o == "--seconds";
        if (o == "--help" || o == "-h") {
            printf("usage: %s %s\n", argv[0], USAGE);
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
