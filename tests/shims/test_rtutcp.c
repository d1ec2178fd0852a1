/*
 * test_rtutcp.c - RTU over TCP (Port 'tcp://HOST:PORT', Framing RTU): RTU frames with
 * their CRC on a TCP stream, as to a transparent Ethernet-to-RS-485 gateway.
 *   sim       the simulator (mbsim --rtu-tcp on 127.0.0.1): reads, writes read back, an
 *             exception; drop, bad CRC, wrong slave, truncated reply and noise each absorbed
 *             by a retry with the right value and counted;
 *             a late reply (forwarded on the stream as a gateway does) is never taken
 *             as the answer to another request: every read gives its own register's
 *             value; a dropped connection fails with PORTLOST and a later request
 *             connects again; a refused connection is NOPORT.
 *   pymodbus  pymodbus's RTU framer on a TCP server (a peer we did not write): reads,
 *             writes read back, an exception.
 *   conflict  a Modbus TCP bus and an RTU-over-TCP bus on one host:port conflict;
 *             ASCII and RTU-without-CRC on tcp:// are refused.
 * Exits 77 (skipped) if the project venv's pymodbus is missing, or fails if
 * MBFB_REQUIRE_TOOLCHAIN=1 (CI).
 */
#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include "mbfb_test.h"

static char sock_path[100];
static const int late_ms[] = {500, 700, 900, 1300, 1700};

/* Start argv with stdout on a pipe; read its first line into line. pid or -1. */
static pid_t spawn_ready(char *const argv[], char *line, int n)
{
    int fd[2], k = 0;
    pid_t pid;

    if (pipe(fd) != 0)
        return -1;
    pid = fork();
    if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGTERM); /* a test that dies leaves no peer behind */
        dup2(fd[1], 1);
        close(fd[0]);
        execvp(argv[0], argv);
        _exit(127);
    }
    close(fd[1]);
    while (k < n - 1 && read(fd[0], line + k, 1) == 1 && line[k] != '\n')
        k++;
    line[k] = 0;
    close(fd[0]);
    return pid;
}

/* One request on the simulator's control socket; 1 if it answered ok. */
static int control(const char *json)
{
    struct sockaddr_un a;
    char buf[4096];
    int fd = socket(AF_UNIX, SOCK_STREAM, 0), k = 0, ok;

    memset(&a, 0, sizeof a);
    a.sun_family = AF_UNIX;
    snprintf(a.sun_path, sizeof a.sun_path, "%s", sock_path);
    if (fd < 0 || connect(fd, (struct sockaddr *)&a, sizeof a) != 0 ||
        write(fd, json, strlen(json)) != (ssize_t)strlen(json) || write(fd, "\n", 1) != 1) {
        if (fd >= 0)
            close(fd);
        return 0;
    }
    while (k < (int)sizeof buf - 1 && read(fd, buf + k, 1) == 1 && buf[k] != '\n')
        k++;
    buf[k] = 0;
    close(fd);
    ok = strstr(buf, "\"ok\": true") != NULL;
    if (!ok)
        fprintf(stderr, "control %s -> %s\n", json, buf);
    return ok;
}

/* Open tcp://127.0.0.1:port with framing and the device of slave 1. */
static int open_dev(int port, int framing, int timeout_ms)
{
    char url[64];
    mbfb_bus_config_t c;
    snprintf(url, sizeof url, "tcp://127.0.0.1:%d", port);
    c = t_cfg(url, 9600, framing, timeout_ms, 3);
    c.stop_bits = 2; /* the MV-D94's 8N2; only the timing uses it */
    return mbfb_dev_open(mbfb_bus_open(&c), 1);
}

static void sim(void)
{
    char port_arg[] = "127.0.0.1:0", ready[128] = "";
    char *argv[] = {MBFB_PYTHON, MBFB_SIM_SCRIPT, "--rtu-tcp", port_arg, "--device",
                    "mvd94:1", "--control", sock_path, NULL};
    uint16_t v[4];
    int port = 0, dev, rc, right = 0, late_seen;
    pid_t pid;
    mbfb_diag_t d;

    t_scenario = "sim";
    snprintf(sock_path, sizeof sock_path, "%s/sim.sock", t_tmpdir());
    pid = spawn_ready(argv, ready, sizeof ready);
    CHECK(sscanf(ready, "RTU-TCP 127.0.0.1:%d", &port) == 1);
    dev = open_dev(port, MBFB_FRAMING_RTU, 200);
    CHECK(dev >= 0);

    /* reads of values set on the device, writes read back; the MV-D94 has no FC16:
     * exception 1 */
    CHECK(control("{\"op\":\"set\",\"addr\":1,\"reg\":\"A1SP\",\"raw\":301}"));
    CHECK(control("{\"op\":\"set\",\"addr\":1,\"reg\":\"A2SP\",\"raw\":302}"));
    CHECK_EQ(t_run(dev, 3, 3, 2, NULL, v, 2), 2);
    CHECK_EQ(v[0], 301);
    CHECK_EQ(v[1], 302);
    v[0] = 123;
    CHECK_EQ(t_run(dev, 6, 0, 1, v, NULL, 0), 0);
    v[0] = 11, v[1] = 12;
    CHECK_EQ(t_run(dev, 16, 3, 2, v, NULL, 0), -(MBFB_E_EXCEPTION_BASE + 1));
    CHECK_EQ(t_run(dev, 6, 3, 1, v, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 6, 4, 1, v + 1, NULL, 0), 0);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 123);
    CHECK_EQ(t_run(dev, 3, 3, 2, NULL, v, 2), 2);
    CHECK_EQ(v[0], 11);
    CHECK_EQ(v[1], 12);

    /* one fault per read, each absorbed by the retries: the right value, counted */
    {
        static const struct { const char *kind; int what; } faults[] = {
            {"\"drop\"", 0}, {"\"bad_crc\"", 1}, {"\"wrong_slave\",\"slave\":7", 2},
            {"\"truncate\"", 0}, {"\"noise\",\"where\":\"before\",\"bytes\":3", 3}};
        for (int k = 0; k < (int)(sizeof faults / sizeof faults[0]); k++) {
            char fault[160];
            mbfb_diag_t b = t_diag(dev);
            snprintf(fault, sizeof fault, "{\"op\":\"fault\",\"addr\":1,\"kind\":%s,\"count\":1}",
                     faults[k].kind);
            CHECK(control(fault));
            v[0] = 0;
            CHECK_EQ(t_run(dev, 3, 3, 1, NULL, v, 1), 1);
            CHECK_EQ(v[0], 11);
            d = t_diag(dev);
            switch (faults[k].what) {
            case 0: CHECK(d.timeouts > b.timeouts); break;
            case 1: CHECK(d.crc_errors > b.crc_errors); break;
            case 2: CHECK(d.bad_replies > b.bad_replies); break;
            default: CHECK(d.bad_replies + d.crc_errors + d.timeouts >
                           b.bad_replies + b.crc_errors + b.timeouts);
            }
            /* out of step until a resync read: OFFLINE meanwhile is not a wrong value */
            for (int i = 0; i < 400 && (rc = t_run(dev, 3, 4, 1, NULL, v, 1)) != 1; i++)
                t_sleep_ms(50);
            CHECK_EQ(rc, 1);
            CHECK_EQ(v[0], 12);
        }
    }

    /* late replies: reads of one shape from two registers; each value is its own. The
     * delays put the late reply into the retries of its own request, into the silence
     * before an attempt, and into the first attempts of the next request (T = 200 ms:
     * attempts and silences alternate, T each). */
    CHECK(control("{\"op\":\"set\",\"addr\":1,\"reg\":\"A1SP\",\"raw\":301}"));
    CHECK(control("{\"op\":\"set\",\"addr\":1,\"reg\":\"A2SP\",\"raw\":302}"));
    for (int k = 0; k < (int)(sizeof late_ms / sizeof late_ms[0]); k++) {
        char fault[128];
        snprintf(fault, sizeof fault,
                 "{\"op\":\"fault\",\"addr\":1,\"kind\":\"late\",\"count\":1,"
                 "\"delay_ms\":%d}", late_ms[k]);
        CHECK(control(fault));
        /* until 4 good reads: a device out of step may stay OFFLINE until the reply
         * shapes it used expire (MBFB_LATE_MAX_MS) */
        for (int i = 0, good = 0; good < 4 && i < 400; i++) {
            int reg = 3 + (i & 1);
            v[0] = 0;
            rc = t_run(dev, 3, reg, 1, NULL, v, 1);
            if (rc == 1) {
                CHECK_EQ(v[0], 300 + reg - 2);
                good++;
                right++;
            } else {
                CHECK(rc < 0); /* a failed read: never a wrong value */
                t_sleep_ms(50);
            }
        }
    }
    d = t_diag(dev);
    late_seen = d.stray_bytes >= 7; /* late replies (7 bytes) were heard and dropped */
    CHECK(late_seen);
    CHECK_EQ(right, 4 * (int)(sizeof late_ms / sizeof late_ms[0])); /* the bus goes on */
    CHECK_EQ(t_run(dev, 3, 4, 1, NULL, v, 1), 1); /* in step at the end */
    CHECK_EQ(v[0], 302);

    /* a dropped connection: PORTLOST, then a later request connects again */
    CHECK(control("{\"op\":\"reopen_port\",\"down_ms\":300}"));
    CHECK_EQ(t_run(dev, 3, 3, 1, NULL, v, 1), -MBFB_E_PORTLOST);
    rc = 0;
    for (int i = 0; i < 100 && rc != 1; i++) {
        rc = t_run(dev, 3, 3, 1, NULL, v, 1);
        CHECK(rc == 1 || rc == -MBFB_E_NOPORT || rc == -MBFB_E_OFFLINE);
        if (rc != 1)
            t_sleep_ms(50);
    }
    CHECK_EQ(rc, 1);
    CHECK_EQ(v[0], 301);
    mbfb_shutdown();

    /* nothing listens: connection refused = NOPORT */
    t_stop_child(pid);
    dev = open_dev(port, MBFB_FRAMING_RTU, 0);
    CHECK_EQ(t_run(dev, 3, 3, 1, NULL, v, 1), -MBFB_E_NOPORT);
    mbfb_shutdown();
}

static void pymodbus(void)
{
    char *argv[] = {MBFB_PYTHON, MBFB_PEER_SCRIPT, "rtu-tcp", NULL};
    char ready[64] = "";
    uint16_t v[4];
    int port = 0, dev;
    pid_t pid;

    t_scenario = "pymodbus";
    pid = spawn_ready(argv, ready, sizeof ready);
    CHECK(sscanf(ready, "READY %d", &port) == 1);
    dev = open_dev(port, MBFB_FRAMING_RTU, 0); /* derived timeout: 9600 8N2 + network */
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 0x3001);
    t_pymodbus_conversation(dev);
    mbfb_shutdown();
    t_stop_child(pid);
}

static void conflict(void)
{
    mbfb_bus_config_t c = t_cfg("tcp://127.0.0.1:1502", 9600, MBFB_FRAMING_TCP, 0, 3);
    int bus;

    t_scenario = "conflict";
    bus = mbfb_bus_open(&c);
    CHECK(bus >= 0);
    c.framing = MBFB_FRAMING_RTU;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_CONFLICT);
    c.port = "tcp://127.0.0.1:1503";
    c.framing = MBFB_FRAMING_ASCII;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.framing = MBFB_FRAMING_RTU_NOCRC;
    CHECK_EQ(mbfb_bus_open(&c), -MBFB_E_INVAL);
    c.framing = MBFB_FRAMING_RTU;
    c.baud = 28800; /* a gateway's line: the baud only times the requests */
    CHECK(mbfb_bus_open(&c) >= 0);
    mbfb_shutdown();
}

int main(void)
{
    char *probe[] = {MBFB_PYTHON, "-c", "import pymodbus", NULL};
    int st = -1;
    pid_t p;

    if ((p = fork()) == 0) {
        execvp(probe[0], probe);
        _exit(127);
    }
    if (p > 0)
        waitpid(p, &st, 0);
    if (st != 0) {
        const char *req = getenv("MBFB_REQUIRE_TOOLCHAIN");
        printf("needs pymodbus in %s (scripts/venv.sh)\n", MBFB_PYTHON);
        return req && strcmp(req, "1") == 0 ? 1 : 77;
    }
    conflict();
    sim();
    pymodbus();
    return t_done("test_rtutcp");
}
