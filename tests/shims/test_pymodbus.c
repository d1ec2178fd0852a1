/*
 * test_pymodbus.c - the shims against an independent slave: pymodbus's serial server
 * (tests/shims/pymodbus_peer.py, RTU and ASCII framers) on a socket:// port (pymodbus listens
 * there), the far end of a test line (testline.h, tl_adopt; not a pty pair: a pty's bytes
 * pass through a kernel worker that a loaded machine held for seconds). Reads, writes read
 * back, an exception, in both framings.
 * Exits 77 (skipped) if the project venv's pymodbus is missing, or fails if
 * MBFB_REQUIRE_TOOLCHAIN=1 (CI).
 */
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include "mbfb_test.h"
#include "testline.h"

#define ACCEPT_MS 20000 /* pymodbus's server listening, on a loaded machine */

static pid_t spawn(char *const argv[], int out_fd)
{
    pid_t pid = fork();
    if (pid == 0) {
        if (out_fd >= 0)
            dup2(out_fd, 1);
        execvp(argv[0], argv);
        _exit(127);
    }
    return pid;
}

/* A free TCP port on 127.0.0.1 (bound once and let go), or -1. */
static int free_port(void)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t n = sizeof a;
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0), port = -1;
    if (fd >= 0 && bind(fd, (struct sockaddr *)&a, sizeof a) == 0 &&
        getsockname(fd, (struct sockaddr *)&a, &n) == 0)
        port = ntohs(a.sin_port);
    if (fd >= 0)
        close(fd);
    return port;
}

/* Connected to 127.0.0.1:port within ACCEPT_MS (the server may still be starting), or -1. */
static int connect_local(int port)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port),
                            .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    for (int64_t end = t_now_us() + (int64_t)ACCEPT_MS * 1000; t_now_us() < end;
         t_sleep_ms(20)) {
        int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (fd >= 0 && connect(fd, (struct sockaddr *)&a, sizeof a) == 0)
            return fd;
        if (fd >= 0)
            close(fd);
    }
    return -1;
}

/* One framing: pymodbus serving pyserial's socket://127.0.0.1:PORT (it listens there), the
 * connection to it the shims' line. */
static void run(const char *framer, int framing)
{
    char link[160], url[64];
    char *py[] = {MBFB_PYTHON, MBFB_PEER_SCRIPT, url, (char *)framer, NULL};
    pid_t p_pid;
    int pipefd[2], bus, dev, rc = -1, port = free_port(), conn;
    char ready[16] = "";
    uint16_t v[4];
    mbfb_bus_config_t c;

    t_scenario = framer;
    snprintf(link, sizeof link, "%s/pm_%s", t_tmpdir(), framer);
    CHECK(port > 0);
    snprintf(url, sizeof url, "socket://127.0.0.1:%d", port);
    if (port <= 0 || pipe(pipefd) != 0)
        return;
    p_pid = spawn(py, pipefd[1]);
    close(pipefd[1]);
    CHECK(read(pipefd[0], ready, 5) == 5 && strncmp(ready, "READY", 5) == 0);
    close(pipefd[0]);
    conn = connect_local(port);
    CHECK(conn >= 0 && tl_adopt(link, conn) == 0);

    c = t_cfg(link, 9600, framing, 500, 3);
    bus = mbfb_bus_open(&c);
    dev = mbfb_dev_open(bus, 1);
    /* the server may take its first bytes a little after the connection: wait for it */
    for (int i = 0; i < 40 && rc != 1; i++)
        rc = t_run(dev, 3, 0, 1, NULL, v, 1);
    CHECK_EQ(rc, 1);
    CHECK_EQ(v[0], 0x3001);
    t_pymodbus_conversation(dev);
    mbfb_shutdown();
    if (conn >= 0)
        tl_drop(link, conn);
    t_stop_child(p_pid);
}

int main(void)
{
    char *probe[] = {MBFB_PYTHON, "-c", "import pymodbus", NULL};
    int st = -1;
    pid_t p;

    signal(SIGPIPE, SIG_IGN);
    if ((p = spawn(probe, -1)) > 0)
        waitpid(p, &st, 0);
    if (st != 0) {
        const char *req = getenv("MBFB_REQUIRE_TOOLCHAIN");
        printf("needs pymodbus in %s (scripts/venv.sh)\n", MBFB_PYTHON);
        return req && strcmp(req, "1") == 0 ? 1 : 77;
    }
    run("rtu", MBFB_FRAMING_RTU);
    run("ascii", MBFB_FRAMING_ASCII);
    return t_done("test_pymodbus");
}
