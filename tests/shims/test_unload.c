/*
 * test_unload.c - the shims inside a program that is loaded and unloaded again and again,
 * as OpenPLC Runtime v4 does on every Stop and Start (README "Lifetime"). Each cycle: dlopen
 * the program (unload_prog.c, a shared object with the shims linked in), open the bus, run a
 * plan on a live and on a dead device, put a write on the wire that the peer never answers,
 * and dlclose while it is in flight. Then:
 *  - the object is gone from the address space (so a worker left running would crash the
 *    process: this is what the test would show without the library's destructor);
 *  - the process has the threads and file descriptors it had before the first cycle;
 *  - the peer hears no frame after dlclose returned;
 *  - dlclose took about one transaction, not the write's retries (a loose bound: 2 s);
 *  - the next cycle opens the port again and the live device answers;
 *  - after WARMUP cycles, the heap does not grow (mallinfo2, all arenas).
 * Usage: test_unload PROGRAM.so [CYCLES] (default 100, more than WARMUP).
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <dlfcn.h>
#include <malloc.h>
#include <stdlib.h>
#include <string.h>

#include "mbfb_test.h"

#define TIMEOUT_MS 100 /* the bus's response timeout: one transaction */
#define RETRIES 1
#define LIVE_SLAVE 1  /* as unload_prog.c */
#define WARMUP 10     /* cycles before the heap is measured: glibc keeps some caches (the
                         dynamic loader's, the threads' arenas) that grow for a few cycles */
#define HEAP_SLACK 4096 /* bytes the heap may grow by from then to the last cycle */

static peer_t P;
static int writes_heard; /* __atomic: FC06 requests the peer got */

/* Slave 1 answers reads; writes go unanswered (a write in flight until its timeout). */
static void unload_peer(peer_t *p, int n, const uint8_t *f, int len, peer_reply_t *r)
{
    if (len >= 2 && f[1] == 6) {
        __atomic_fetch_add(&writes_heard, 1, __ATOMIC_RELEASE);
        return;
    }
    peer_answer(p, n, f, len, r);
}

/* Entries in a /proc/self directory (threads: task, descriptors: fd). */
static int count_dir(const char *path)
{
    DIR *d = opendir(path);
    struct dirent *e;
    int n = 0;
    if (d == NULL)
        return -1;
    while ((e = readdir(d)) != NULL)
        n += e->d_name[0] != '.';
    closedir(d);
    return n;
}

/* Is `path` mapped into this process? */
static int mapped(const char *path)
{
    char line[4096];
    FILE *f = fopen("/proc/self/maps", "r");
    int found = 0;
    if (f == NULL)
        return -1;
    while (!found && fgets(line, sizeof line, f) != NULL)
        found = strstr(line, path) != NULL;
    fclose(f);
    return found;
}

typedef int (*start_fn)(const char *, int, int);
typedef int (*write_fn)(uint16_t);
typedef void (*scan_fn)(void);
typedef int (*snaps_fn)(int);

/* dlsym into a function pointer (POSIX: through memcpy). */
static void sym(void *h, const char *name, void *fp)
{
    void *s = dlsym(h, name);
    if (s == NULL) {
        fprintf(stderr, "FAIL: %s not in the program: %s\n", name, dlerror());
        exit(1);
    }
    memcpy(fp, &s, sizeof s);
}

/* One load, scan, unload. Returns dlclose's duration (us). */
static int64_t cycle(const char *so, int i)
{
    start_fn start;
    write_fn write;
    scan_fn scan;
    snaps_fn snaps;
    void *h = dlopen(so, RTLD_NOW | RTLD_LOCAL);
    int live0 = peer_slave_count(&P, LIVE_SLAVE), w0, got, rc;
    int64_t t0, t1, end;

    if (h == NULL) {
        fprintf(stderr, "FAIL: dlopen %s: %s\n", so, dlerror());
        exit(1);
    }
    sym(h, "prog_start", &start);
    sym(h, "prog_write", &write);
    sym(h, "prog_scan", &scan);
    sym(h, "prog_snaps", &snaps);
    rc = start(P.link, TIMEOUT_MS, RETRIES);
    CHECK_EQ(rc, 0);
    /* plans running: scans every 20 ms until the live device's plan delivered */
    for (end = t_now_us() + 5000000; snaps(0) < 2 && t_now_us() < end; t_sleep_ms(20))
        scan();
    CHECK(snaps(0) >= 2); /* the port opened (again) and the live device answered */
    /* a write on the wire, never answered: unloaded while it waits for its reply */
    w0 = __atomic_load_n(&writes_heard, __ATOMIC_ACQUIRE);
    CHECK(write((uint16_t)(100 + i)) > 0);
    for (end = t_now_us() + 5000000;
         __atomic_load_n(&writes_heard, __ATOMIC_ACQUIRE) == w0 && t_now_us() < end;
         t_sleep_ms(1))
        scan();
    CHECK(__atomic_load_n(&writes_heard, __ATOMIC_ACQUIRE) > w0);
    CHECK(peer_slave_count(&P, LIVE_SLAVE) > live0);
    t0 = t_now_us();
    CHECK_EQ(dlclose(h), 0);
    t1 = t_now_us();
    CHECK_EQ(mapped(so), 0); /* really unloaded: its code is gone */
    /* nothing after dlclose: what the worker wrote before is read by the peer in a few ms */
    t_sleep_ms(50);
    got = peer_count(&P);
    t_sleep_ms(3 * TIMEOUT_MS);
    CHECK_EQ(peer_count(&P), got);
    return t1 - t0;
}

int main(int argc, char **argv)
{
    const char *so = argc > 1 ? argv[1] : NULL;
    int cycles = argc > 2 ? atoi(argv[2]) : 100, threads, fds;
    int64_t worst = 0;
    size_t heap1 = 0, heap;
    char link[160];

    t_scenario = "unload";
    if (so == NULL || cycles <= WARMUP) {
        fprintf(stderr, "usage: test_unload PROGRAM.so [CYCLES > %d]\n", WARMUP);
        return 2;
    }
    snprintf(link, sizeof link, "%s/port", t_tmpdir());
    if (peer_start(&P, link, PEER_RTU, unload_peer, NULL) != 0) {
        perror("peer_start");
        return 1;
    }
    for (int r = 0; r < 8; r++)
        peer_set_reg(&P, LIVE_SLAVE, r, (uint16_t)(0x1000 + r));
    threads = count_dir("/proc/self/task");
    fds = count_dir("/proc/self/fd");
    for (int i = 0; i < cycles && t_failures == 0; i++) {
        int64_t us = cycle(so, i);
        worst = us > worst ? us : worst;
        CHECK_EQ(count_dir("/proc/self/task"), threads);
        CHECK_EQ(count_dir("/proc/self/fd"), fds);
        heap = mallinfo2().uordblks;
        if (i == WARMUP - 1)
            heap1 = heap;
        else if (i == cycles - 1) {
            printf("heap in use after cycle %d: %zu bytes, after cycle %d: %zu bytes\n", WARMUP,
                   heap1, cycles, heap);
            CHECK(heap <= heap1 + HEAP_SLACK);
        }
    }
    printf("%d cycles; longest dlclose %lld ms (a write in flight: one transaction of %d ms "
           "and the stop slice)\n", cycles, (long long)(worst / 1000), TIMEOUT_MS);
    CHECK(worst < 2000000); /* about one transaction; the retries would take longer */
    peer_stop(&P);
    return t_done("unload");
}
