// unload_host.cpp - loads a PLC program (a shared object with the blocks and the shims inside),
// scans it every 20 ms until it says it is done (T_DONE), unloads it, and again: as OpenPLC
// Runtime v4 does on every Start and Stop. Driven by test_unload_program.py over stdin/stdout:
// after each dlclose it prints "UNLOADED <cycle> <dlclose ms>" and waits for a line on stdin
// (the driver checks the simulator heard nothing since) before the next cycle. It links neither
// the shims nor the blocks: everything of them lives in the program.
// Checks per cycle: the program's own checks passed (fbt_host_finish), the object is no longer
// mapped, the thread (/proc/self/task) and descriptor (/proc/self/fd) counts are back to where
// they were before the first dlopen. Exit 0 when every cycle passed.
// Usage: unload_host PROGRAM.so CYCLES
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const long kMaxScans = 3000;            // 60 s of 20 ms scans
static const long long kTickNs = 20000000LL;

static long long now_us() {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static void sleep_ns(long long ns) {
    struct timespec ts = {(time_t)(ns / 1000000000LL), (long)(ns % 1000000000LL)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {}
}

static int count_dir(const char *path) {
    DIR *d = opendir(path);
    int n = 0;
    if (d == NULL) return -1;
    while (struct dirent *e = readdir(d)) n += e->d_name[0] != '.';
    closedir(d);
    return n;
}

static int mapped(const char *path) {
    char line[4096];
    FILE *f = fopen("/proc/self/maps", "r");
    int found = 0;
    if (f == NULL) return -1;
    while (!found && fgets(line, sizeof line, f) != NULL) found = strstr(line, path) != NULL;
    fclose(f);
    return found;
}

template <class F> static F sym(void *h, const char *name) {
    void *s = dlsym(h, name);
    if (s == NULL) {
        printf("FAIL: %s not in the program: %s\n", name, dlerror());
        exit(1);
    }
    F f;
    memcpy(&f, &s, sizeof s);
    return f;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: unload_host PROGRAM.so CYCLES\n");
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    const char *so = argv[1];
    int cycles = atoi(argv[2]), failed = 0;
    int threads = count_dir("/proc/self/task"), fds = count_dir("/proc/self/fd");
    for (int c = 0; c < cycles && !failed; c++) {
        void *h = dlopen(so, RTLD_NOW | RTLD_LOCAL);
        if (h == NULL) {
            printf("FAIL: dlopen: %s\n", dlerror());
            return 1;
        }
        auto init = sym<void (*)(void)>(h, "lt_init");
        auto scan = sym<void (*)(unsigned long)>(h, "lt_scan");
        auto set_scan = sym<void (*)(long)>(h, "fbt_host_set_scan");
        auto stop = sym<int (*)(void)>(h, "fbt_host_stop");
        auto finish = sym<int (*)(long)>(h, "fbt_host_finish");
        long n;
        init();
        for (n = 0; n < kMaxScans && !stop(); n++) {
            set_scan(n);
            scan((unsigned long)n);
            sleep_ns(kTickNs);
        }
        if (finish(n) != 0) {
            printf("FAIL: cycle %d: the program's checks\n", c);
            failed = 1;
        }
        long long t0 = now_us();
        if (dlclose(h) != 0) {
            printf("FAIL: dlclose: %s\n", dlerror());
            return 1;
        }
        long long ms = (now_us() - t0) / 1000;
        if (mapped(so) != 0) {
            printf("FAIL: cycle %d: the program is still mapped after dlclose\n", c);
            failed = 1;
        }
        int t = count_dir("/proc/self/task"), f = count_dir("/proc/self/fd");
        if (t != threads || f != fds) {
            printf("FAIL: cycle %d: %d threads (%d before), %d descriptors (%d before)\n", c, t,
                   threads, f, fds);
            failed = 1;
        }
        printf("UNLOADED %d %lld\n", c, ms);
        char go[16];
        if (fgets(go, sizeof go, stdin) == NULL) break;
    }
    return failed;
}
