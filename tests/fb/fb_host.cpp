// fb_host.cpp - runs one iec2c-compiled ST test program the way OpenPLC v3's runtime does
// (core/main.cpp: config_init__(), then config_run__(__tick++) and updateTime() every
// common_ticktime__ ns), linked with the mbfb shims, and reports the ST checks (fbtest.st).
// Environment: MBFB_TEST_PORT (device port for the program), MBFB_SIM_CONTROL (simulator
// control socket), MBFB_MAX_SCANS (scan limit, default 6000).
// Exit: 0 all checks passed and the program called T_DONE; 1 a check failed, or the scan
// limit was reached, or no check ran.
#include "iec_types_all.h"
#include "mbfb.h"
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

TIME __CURRENT_TIME;                     // OpenPLC: core/glueVars.cpp
extern unsigned long long common_ticktime__;
void config_init__(void);
void config_run__(unsigned long tick);

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

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    const char *m = getenv("MBFB_MAX_SCANS");
    long max_scans = m ? atol(m) : 6000;
    config_init__();
    for (g_scan = 0; g_scan < max_scans && !g_failed && !g_done; g_scan++) {
        config_run__((unsigned long)g_scan);
        // updateTime() of core/glueVars.cpp
        __CURRENT_TIME.tv_sec += common_ticktime__ / 1000000000ULL;
        __CURRENT_TIME.tv_nsec += common_ticktime__ % 1000000000ULL;
        if (__CURRENT_TIME.tv_nsec >= 1000000000L) {
            __CURRENT_TIME.tv_nsec -= 1000000000L;
            __CURRENT_TIME.tv_sec += 1;
        }
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
