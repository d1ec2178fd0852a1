// plc_control.cpp - the runner's control socket (plc_control.h). Hand-written: a few lines of
// poll() around a Unix socket; nothing in the project's libraries serves one between PLC scans.
#include "plc_control.h"
#include "plc_vars.h"

#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <string>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

enum { MAX_CLIENTS = 8, MAX_LINE = 1024 };

static int g_listen = -1;
static std::string g_path;
static int g_client[MAX_CLIENTS];
static std::string g_inbuf[MAX_CLIENTS];
static int g_nclients;

int plc_command(const char *line, char *reply, size_t size) {
    char verb[8], name[256];
    int used = 0;
    if (sscanf(line, "%7s %255s %n", verb, name, &used) < 2) {
        snprintf(reply, size, "error: expected 'set NAME VALUE' or 'get NAME'");
        return -1;
    }
    const plc_var_t *v = plc_var_find(name);
    if (!v) {
        snprintf(reply, size, "error: no variable %s", name);
        return -1;
    }
    const char *value = line + used;
    if (strcmp(verb, "set") == 0 && *value) {
        if (plc_var_parse(v, value) != 0) {
            snprintf(reply, size, "error: %s %s for %s %s", errno == ERANGE ? "out of range" :
                     "not a value", value, plc_type_name(v->type), v->name);
            return -1;
        }
        snprintf(reply, size, "ok");
        return 0;
    }
    if (strcmp(verb, "get") == 0 && !*value) {
        int n = snprintf(reply, size, "ok ");
        plc_var_format(v, reply + n, size - (size_t)n);
        return 0;
    }
    snprintf(reply, size, "error: expected 'set NAME VALUE' or 'get NAME'");
    return -1;
}

int plc_control_open(const char *path) {
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    if (strlen(path) >= sizeof sa.sun_path) {
        errno = ENAMETOOLONG;
        return -1;
    }
    strcpy(sa.sun_path, path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) return -1;
    if (bind(fd, (struct sockaddr *)&sa, sizeof sa) != 0 || listen(fd, MAX_CLIENTS) != 0) {
        int e = errno;
        close(fd);
        errno = e;
        return -1;
    }
    g_listen = fd;
    g_path = path;
    return 0;
}

static void drop(int i) {
    close(g_client[i]);
    g_nclients--;
    g_client[i] = g_client[g_nclients];
    g_inbuf[i].swap(g_inbuf[g_nclients]);
    g_inbuf[g_nclients].clear();
}

static void answer(int fd, const char *text) {
    std::string line = std::string(text) + "\n";  // a short line on a local socket: fits
    if (send(fd, line.data(), line.size(), MSG_NOSIGNAL | MSG_DONTWAIT) < 0)
        perror("plc_control: reply");
}

// Read what client i sent and answer every complete line; false when it is to be dropped.
static bool serve_client(int i) {
    char buf[512];
    ssize_t n = recv(g_client[i], buf, sizeof buf, MSG_DONTWAIT);
    if (n < 0 && (errno == EAGAIN || errno == EINTR)) return true;
    if (n <= 0) return false;
    std::string &in = g_inbuf[i];
    in.append(buf, (size_t)n);
    size_t nl;
    while ((nl = in.find('\n')) != std::string::npos) {
        std::string line = in.substr(0, nl);
        in.erase(0, nl + 1);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        char reply[MAX_LINE];
        plc_command(line.c_str(), reply, sizeof reply);
        answer(g_client[i], reply);
    }
    if (in.size() > MAX_LINE) {
        answer(g_client[i], "error: line too long");
        return false;
    }
    return true;
}

static void accept_clients(void) {
    int fd;
    while ((fd = accept4(g_listen, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC)) >= 0) {
        if (g_nclients == MAX_CLIENTS) {
            answer(fd, "error: too many connections");
            close(fd);
            continue;
        }
        g_client[g_nclients++] = fd;
    }
}

int plc_control_serve(const struct timespec *deadline) {
    for (;;) {
        struct timespec now, left;
        clock_gettime(CLOCK_MONOTONIC, &now);
        long long ns = (deadline->tv_sec - now.tv_sec) * 1000000000LL + (deadline->tv_nsec - now.tv_nsec);
        if (ns <= 0) return 0;
        if (g_listen < 0) {  // nothing to serve: sleep_until(), as OpenPLC's scan loop
            if (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, deadline, NULL) == EINTR) {
                errno = EINTR;
                return -1;
            }
            return 0;
        }
        left.tv_sec = (time_t)(ns / 1000000000LL);
        left.tv_nsec = (long)(ns % 1000000000LL);
        struct pollfd fds[MAX_CLIENTS + 1];
        fds[0].fd = g_listen;
        fds[0].events = POLLIN;
        for (int i = 0; i < g_nclients; i++) {
            fds[i + 1].fd = g_client[i];
            fds[i + 1].events = POLLIN;
        }
        int nfds = g_nclients + 1;
        int r = ppoll(fds, (nfds_t)nfds, &left, NULL);
        if (r < 0) return -1;  // EINTR: a signal, the caller decides
        for (int i = nfds - 2; i >= 0; i--)  // backwards: drop() moves the last one into i
            if (fds[i + 1].revents && !serve_client(i)) drop(i);
        if (fds[0].revents) accept_clients();
    }
}

void plc_control_close(void) {
    while (g_nclients) drop(g_nclients - 1);
    if (g_listen >= 0) {
        close(g_listen);
        unlink(g_path.c_str());
        g_listen = -1;
    }
}
