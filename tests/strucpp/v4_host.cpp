// v4_host.cpp - runs one STruC++-compiled ST test program (tests/fb/t_*.st with st_src and
// fbtest.st, translated by v4/translate.py) scan by scan like tools/runner/fb_host.cpp does
// for matiec's: one scan of PROGRAM main every 20 ms (the tests' task), the scan's TIME()
// advanced by 20 ms per scan (strucpp::__CURRENT_TIME_NS, what Runtime v4 stamps), a real
// 20 ms sleep between scans so the shims' worker and the bus run. Environment and exit codes
// as fb_host's test mode (MBFB_TEST_PORT, MBFB_SIM_CONTROL, MBFB_MAX_SCANS; 0 = all checks
// passed and T_DONE called). The fbt_* functions are those of fb_host.cpp.
#include "program.hpp"
#include "fbtest.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <string>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

static const long long kTickNs = 20000000LL;   // TASK task0(INTERVAL := T#20ms) of every t_*.st
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

static void sleep_ns(long long ns) {
    struct timespec ts = {(time_t)(ns / 1000000000LL), (long)(ns % 1000000000LL)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {}
}

int main() {
    const char *m = getenv("MBFB_MAX_SCANS");
    long max_scans = m ? atol(m) : 6000;
    static strucpp::Program_MAIN prog;
    for (g_scan = 0; g_scan < max_scans && !g_failed && !g_done; g_scan++) {
        strucpp::__CURRENT_TIME_NS = (int64_t)g_scan * kTickNs;
        prog.run();
        sleep_ns(kTickNs);
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
