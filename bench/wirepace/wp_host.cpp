// wp_host.cpp - runs one iec2c-compiled program of bench/wire_pace.py in real time, as
// OpenPLC v3's runtime does (config_run__ every common_ticktime__, sleep until the next
// period, late scans catch up), and measures it:
//   wp_host WARMUP_S SECONDS [TASK_MS]
// TASK_MS replaces the program's tick (common_ticktime__): the programs declare one task with
// INTERVAL T#1ms, which then runs at every tick of TASK_MS, so one build serves every interval.
// After WARMUP_S it measures for SECONDS, then prints one JSON line on stdout:
//   rt (scan thread got SCHED_FIFO 30 + mlockall, as OpenPLC), scans, period_us, scan_us {median, p99, max, mean, sd} (time inside config_run__),
//   start_jitter_us {median, p99, max} (|actual scan start - its schedule|),
//   cpu {main_pct, others_pct} (from /proc/self/task: the scan thread, and all other
//   threads = the shims' bus workers; percent of one core over the window),
//   pubs [n per device] (wp_pub calls in the window);
// and, when the program called wp_mark (bench/write_done.py), the whole run's scans:
//   marks [[what, tag, scan], ...] (every wp_mark call, warm-up included; scan = 0-based
//   index of the scan that made it), scan_ns [CLOCK_MONOTONIC ns of each scan's start],
//   window_ns [start, end] of the measuring window (CLOCK_MONOTONIC ns).
// Exit 0; 2 on bad arguments.
#include "iec_types_all.h"
#include "mbfb.h"
#include "wp_host.h"

#include <algorithm>
#include <dirent.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>
#include <vector>

TIME __CURRENT_TIME;
extern unsigned long long common_ticktime__;
void config_init__(void);
void config_run__(unsigned long tick);

// OpenPLC's TCP blocks are compiled into every program; not used here.
int connect_to_tcp_server(uint8_t *, uint16_t, int) { return -1; }
int send_tcp_message(uint8_t *, size_t, int) { return -1; }
int receive_tcp_message(uint8_t *, size_t, int) { return -1; }

static bool g_measuring;
static std::vector<long> g_pubs;
void wp_pub(int dev) {
    if (!g_measuring || dev < 0 || dev > 100000) return;
    if ((size_t)dev >= g_pubs.size()) g_pubs.resize((size_t)dev + 1, 0);
    g_pubs[(size_t)dev]++;
}

// wp_mark: the scan in which the program saw something (Execute rose, Done rose, ...).
struct wp_mark_t { int what, tag; long scan; };
static std::vector<wp_mark_t> g_marks;
static long g_scan;
void wp_mark(int what, int tag) {
    if (g_marks.size() < 1000000) g_marks.push_back(wp_mark_t{what, tag, g_scan});
}

static long long mono_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (long long)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static double now_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + t.tv_nsec / 1e9;
}

// CPU seconds (utime + stime) of the calling thread (main) and of all other threads.
static void cpu_split(double *main_s, double *others_s) {
    long tick = sysconf(_SC_CLK_TCK);
    long self = (long)syscall(SYS_gettid);
    *main_s = *others_s = 0;
    DIR *d = opendir("/proc/self/task");
    if (!d) return;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.') continue;
        char path[64], buf[1024];
        snprintf(path, sizeof path, "/proc/self/task/%s/stat", e->d_name);
        FILE *f = fopen(path, "r");
        if (!f) continue;
        size_t n = fread(buf, 1, sizeof buf - 1, f);
        fclose(f);
        buf[n] = 0;
        const char *p = strrchr(buf, ')');   // fields after "(comm)"
        if (!p) continue;
        unsigned long ut = 0, st = 0;
        // ") state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt utime stime"
        if (sscanf(p + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &ut, &st) != 2)
            continue;
        double s = (double)(ut + st) / (double)tick;
        if (atol(e->d_name) == self) *main_s += s;
        else *others_s += s;
    }
    closedir(d);
}

static double pct(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    size_t i = (size_t)(q * (double)(v.size() - 1) + 0.5);
    return v[std::min(i, v.size() - 1)];
}

int main(int argc, char **argv) {
    if (argc < 3 || argc > 4 || atof(argv[1]) < 0 || atof(argv[2]) <= 0 ||
        (argc == 4 && atoi(argv[3]) <= 0)) {
        fprintf(stderr, "usage: wp_host WARMUP_S SECONDS [TASK_MS]\n");
        return 2;
    }
    double warmup = atof(argv[1]), seconds = atof(argv[2]);
    if (argc == 4) common_ticktime__ = 1000000ULL * (unsigned long long)atoi(argv[3]);
    // As OpenPLC v3's main(): the scan thread at SCHED_FIFO 30 with its memory locked, when the
    // process may (root or CAP_SYS_NICE). The shims start their bus workers at SCHED_OTHER
    // explicitly, so only the scan thread is real-time. "rt" in the JSON says which it was.
    struct sched_param sp;
    sp.sched_priority = 30;
    bool rt = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0 &&
              mlockall(MCL_FUTURE | MCL_CURRENT) == 0;
    config_init__();
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    double t0 = (double)next.tv_sec + next.tv_nsec / 1e9;
    double period = common_ticktime__ / 1e9;
    std::vector<double> dur, late;
    std::vector<long long> starts;    // every scan's start (CLOCK_MONOTONIC ns), for wp_mark
    starts.reserve((size_t)((warmup + seconds) / period) + 1024);
    g_marks.reserve(65536);
    long long wn0 = 0;
    double cm0 = 0, co0 = 0, w0 = 0;
    unsigned long tick = 0;
    for (;;) {
        double sched = (double)next.tv_sec + next.tv_nsec / 1e9;
        long long an = mono_ns();
        double a = (double)an / 1e9;
        if (!g_measuring && a - t0 >= warmup) {
            g_measuring = true;
            cpu_split(&cm0, &co0);
            w0 = a;
            wn0 = an;
        }
        if (g_measuring && a - w0 >= seconds) break;
        g_scan = (long)starts.size();
        config_run__(tick++);
        double b = now_s();
        starts.push_back(an);              // outside the timed part
        __CURRENT_TIME.tv_nsec += (long)common_ticktime__;   // updateTime() of OpenPLC
        while (__CURRENT_TIME.tv_nsec >= 1000000000L) {
            __CURRENT_TIME.tv_nsec -= 1000000000L;
            __CURRENT_TIME.tv_sec++;
        }
        if (g_measuring) {
            dur.push_back((b - a) * 1e6);
            late.push_back(fabs(a - sched) * 1e6);
        }
        next.tv_nsec += (long)common_ticktime__;
        while (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec++;
        }
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR) {}
    }
    long long wn1 = mono_ns();
    double cm1, co1, w1 = (double)wn1 / 1e9;
    cpu_split(&cm1, &co1);
    double mean = 0, sd = 0;
    for (double d : dur) mean += d;
    mean /= dur.empty() ? 1 : (double)dur.size();
    for (double d : dur) sd += (d - mean) * (d - mean);
    sd = dur.size() > 1 ? sqrt(sd / (double)(dur.size() - 1)) : 0;
    printf("{\"rt\": %s, \"scans\": %zu, \"period_us\": %.0f, \"window_s\": %.3f, "
           "\"scan_us\": {\"median\": %.2f, \"p99\": %.2f, \"max\": %.2f, \"mean\": %.2f, \"sd\": %.2f}, "
           "\"start_jitter_us\": {\"median\": %.1f, \"p99\": %.1f, \"max\": %.1f}, "
           "\"cpu\": {\"main_pct\": %.2f, \"others_pct\": %.2f}, \"pubs\": [",
           rt ? "true" : "false", dur.size(), period * 1e6, w1 - w0, pct(dur, 0.5), pct(dur, 0.99), pct(dur, 1.0), mean, sd,
           pct(late, 0.5), pct(late, 0.99), pct(late, 1.0),
           100 * (cm1 - cm0) / (w1 - w0), 100 * (co1 - co0) / (w1 - w0));
    for (size_t i = 0; i < g_pubs.size(); i++) printf("%s%ld", i ? ", " : "", g_pubs[i]);
    printf("]");
    if (!g_marks.empty()) {
        printf(", \"window_ns\": [%lld, %lld], \"marks\": [", wn0, wn1);
        for (size_t i = 0; i < g_marks.size(); i++)
            printf("%s[%d, %d, %ld]", i ? ", " : "", g_marks[i].what, g_marks[i].tag, g_marks[i].scan);
        printf("], \"scan_ns\": [");
        for (size_t i = 0; i < starts.size(); i++) printf("%s%lld", i ? ", " : "", starts[i]);
        printf("]");
    }
    printf("}\n");
    fflush(stdout);
    mbfb_shutdown();
    return 0;
}
