// fbtest_hooks.cpp - the host functions of the ST test-support blocks (fbtest.h, fbtest.st): the
// one implementation, linked by both test hosts: fb_test_host.cpp (matiec / OpenPLC v3
// programs, in the mbfb_test_host library) and tests/strucpp/v4_host.cpp (STruC++ programs).
// The host's side (fbt_host_*): it tells the scan number, asks whether to stop, and ends the run.
// Test support only: the programs users run never call the fbt_* functions.
#include "fbtest.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <string>
#include <sys/socket.h>
#include <sys/un.h>
#include <termios.h>
#include <unistd.h>

static long g_scan;
static int g_failed, g_passed, g_done;
static int g_sim_fd = -1;
static int g_sim_tty = 0; /* g_sim_fd is the kernel test bed's control line */

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
            const uint8_t *match, int match_len, long *matches, long *at) {
    *ok = 0; *raw = -1; *frames = -1; *matches = 0; *at = -1;
    if (g_sim_fd < 0) {
        const char *path = getenv("MBFB_SIM_CONTROL");
        if (!path) return -1;
        if (strncmp(path, "/dev/", 5) == 0) {
            /* the kernel test bed's control line (tests/kernel/bed.py): a tty whose other end
               relays {"sim": I, ...} to simulator I's control socket */
            struct termios t;
            g_sim_fd = open(path, O_RDWR | O_NOCTTY);
            if (g_sim_fd < 0 || tcgetattr(g_sim_fd, &t) != 0) {
                perror("fbt_sim: control line");
                return -1;
            }
            cfmakeraw(&t);
            t.c_cc[VMIN] = 1;
            t.c_cc[VTIME] = 0;
            tcsetattr(g_sim_fd, TCSANOW, &t);
            g_sim_tty = 1;
        }
    }
    if (g_sim_fd < 0) {
        const char *path = getenv("MBFB_SIM_CONTROL");
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
    if (g_sim_tty && !line.empty() && line[0] == '{')  /* the bed's relay: which simulator */
        line = "{\"sim\": 0, " + line.substr(1);
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
        size_t first = reply.find(m);
        *at = first == std::string::npos ? -1 : (long)first;
        for (size_t p = reply.find(m); p != std::string::npos; p = reply.find(m, p + 1))
            (*matches)++;
    }
    int n = (int)reply.size() < max ? (int)reply.size() : max;
    memcpy(buf, reply.data(), (size_t)n);
    return (int)reply.size();
}

long fbt_host_max_scans(void) {
    const char *m = getenv("MBFB_MAX_SCANS");
    return m ? atol(m) : 6000;
}

void fbt_host_set_scan(long scan) { g_scan = scan; }

int fbt_host_stop(void) { return g_failed || g_done; }

int fbt_host_finish(long scans) {
    if (g_sim_fd >= 0) close(g_sim_fd);
    g_sim_fd = -1;
    printf("%ld scans, %d checks passed, %d failed%s\n", scans, g_passed, g_failed,
           (g_done || g_failed) ? "" : ", program did not finish (scan limit)");
    if (g_failed || !g_done) return 1;
    if (g_passed == 0) {
        printf("FAIL: no check ran\n");
        return 1;
    }
    return 0;
}
