/*
 * mbfb_wake.c - how the scan wakes the worker, and how the worker waits.
 *
 * An eventfd: the worker waits on it and, while a device is out of step, on the port in
 * the same ppoll, so it uses no CPU until a post, a byte on the port or its next due time
 * comes (a semaphore cannot be polled beside a file descriptor). Posts count in
 * bus->wake_pending, and only a post that finds the worker waiting (bus->waiting) and no
 * post before it since the worker last looked writes the eventfd: a post while the worker
 * is busy makes no system call. Both sides use sequentially consistent atomics: a poster
 * that sees waiting == 0 has its count seen by the worker's check after it set waiting,
 * so the worker never waits on a post it missed.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* ppoll */
#endif
#include <errno.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "mbfb_internal.h"

int mbfb_wake_open(mbfb_bus_t *bus)
{
    bus->wake_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    return bus->wake_fd < 0 ? -1 : 0;
}

void mbfb_wake_close(mbfb_bus_t *bus)
{
    if (bus->wake_fd >= 0)
        close(bus->wake_fd);
    bus->wake_fd = -1;
}

void mbfb_wake(mbfb_bus_t *bus)
{
    uint64_t one = 1;
    /* also orders the caller's slot or settings stores before the worker's take */
    if (__atomic_fetch_add(&bus->wake_pending, 1u, __ATOMIC_SEQ_CST) == 0 &&
        __atomic_load_n(&bus->waiting, __ATOMIC_SEQ_CST))
        (void)!write(bus->wake_fd, &one, sizeof one); /* non-blocking; never full here */
}

void mbfb_wake_take(mbfb_bus_t *bus)
{
    (void)__atomic_exchange_n(&bus->wake_pending, 0u, __ATOMIC_ACQ_REL);
}

/* The wait itself: ppoll on the eventfd (and the port), drained when it fired. */
static int poll_wake(mbfb_bus_t *bus, int port_fd, int64_t until)
{
    struct pollfd fds[2];

    for (;;) {
        struct timespec ts, *limit = NULL;
        int n;
        if (until != INT64_MAX) {
            int64_t left = until - mbfb_now_us();
            if (left <= 0)
                return 0;
            ts.tv_sec = (time_t)(left / 1000000);
            ts.tv_nsec = (long)(left % 1000000) * 1000;
            limit = &ts;
        }
        fds[0].fd = bus->wake_fd;
        fds[1].fd = port_fd;
        fds[0].events = fds[1].events = POLLIN;
        fds[0].revents = fds[1].revents = 0;
        n = ppoll(fds, port_fd >= 0 ? 2 : 1, limit, NULL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return 0; /* the time has come (or poll failed: the loop looks again) */
        if (fds[0].revents != 0) {
            uint64_t count;
            (void)!read(bus->wake_fd, &count, sizeof count); /* drained: waits again */
        }
        return port_fd >= 0 && fds[1].revents != 0; /* readable or hung up */
    }
}

int mbfb_wake_wait(mbfb_bus_t *bus, int port_fd, int64_t until)
{
    int rc;

    __atomic_store_n(&bus->waiting, 1, __ATOMIC_SEQ_CST);
    rc = __atomic_load_n(&bus->wake_pending, __ATOMIC_SEQ_CST) == 0
             ? poll_wake(bus, port_fd, until)
             : 0; /* a post came since the worker looked: no wait */
    __atomic_store_n(&bus->waiting, 0, __ATOMIC_RELAXED);
    return rc;
}
