/*
 * test_pymodbus.c - the shims against an independent slave: pymodbus's serial server
 * (tests/shims/pymodbus_peer.py, RTU and ASCII framers) on the far end of a socat pty
 * pair. Reads, writes read back, an exception, in both framings.
 * Exits 77 (skipped) if socat or the project venv's pymodbus is missing, or fails if
 * MBFB_REQUIRE_TOOLCHAIN=1 (CI).
 */
#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "mbfb_test.h"

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

static int wait_path(const char *path)
{
    struct stat st;
    for (int i = 0; i < 500; i++, t_sleep_ms(10))
        if (stat(path, &st) == 0)
            return 0;
    return -1;
}

/* One framing: socat pair a <-> b, pymodbus on a, the shims on b. */
static void run(const char *framer, int framing)
{
    char a[160], b[160], pa[200], pb[200];
    char *socat[] = {"socat", pa, pb, NULL};
    char *py[] = {MBFB_PYTHON, MBFB_PEER_SCRIPT, a, (char *)framer, NULL};
    pid_t s_pid, p_pid;
    int pipefd[2], bus, dev, rc = -1;
    char ready[16] = "";
    uint16_t v[4];
    mbfb_bus_config_t c;

    t_scenario = framer;
    snprintf(a, sizeof a, "%s/pm_%s_a", t_tmpdir(), framer);
    snprintf(b, sizeof b, "%s/pm_%s_b", t_tmpdir(), framer);
    snprintf(pa, sizeof pa, "PTY,raw,echo=0,link=%s", a);
    snprintf(pb, sizeof pb, "PTY,raw,echo=0,link=%s", b);
    s_pid = spawn(socat, -1);
    CHECK(wait_path(a) == 0 && wait_path(b) == 0);
    if (pipe(pipefd) != 0)
        return;
    p_pid = spawn(py, pipefd[1]);
    close(pipefd[1]);
    CHECK(read(pipefd[0], ready, 5) == 5 && strncmp(ready, "READY", 5) == 0);
    close(pipefd[0]);

    c = t_cfg(b, 9600, framing, 500, 3);
    bus = mbfb_bus_open(&c);
    dev = mbfb_dev_open(bus, 1);
    /* the server opens its port after READY (pyserial flushes on open): wait for it */
    for (int i = 0; i < 40 && rc != 1; i++)
        rc = t_run(dev, 3, 0, 1, NULL, v, 1);
    CHECK_EQ(rc, 1);
    CHECK_EQ(v[0], 0x3001);
    t_pymodbus_conversation(dev);
    mbfb_shutdown();
    t_stop_child(p_pid);
    t_stop_child(s_pid);
}

int main(void)
{
    char *probe[] = {MBFB_PYTHON, "-c", "import pymodbus", NULL};
    char *socat[] = {"socat", "-V", NULL};
    int st1 = -1, st2 = -1;
    pid_t p;

    signal(SIGPIPE, SIG_IGN);
    if ((p = spawn(probe, -1)) > 0)
        waitpid(p, &st1, 0);
    if ((p = spawn(socat, open("/dev/null", O_WRONLY))) > 0)
        waitpid(p, &st2, 0);
    if (st1 != 0 || st2 != 0) {
        const char *req = getenv("MBFB_REQUIRE_TOOLCHAIN");
        printf("needs socat and pymodbus in %s (scripts/venv.sh)\n", MBFB_PYTHON);
        return req && strcmp(req, "1") == 0 ? 1 : 77;
    }
    run("rtu", MBFB_FRAMING_RTU);
    run("ascii", MBFB_FRAMING_ASCII);
    return t_done("test_pymodbus");
}
