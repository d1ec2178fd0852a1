// plc_host.cpp - the parts of OpenPLC v3's runtime a program links against (plc_host.h).
#include "plc_host.h"

#include <errno.h>
#include <stdint.h>
#include <stddef.h>
#include <time.h>

TIME __CURRENT_TIME;                     // OpenPLC: core/glueVars.cpp

// OpenPLC's TCP blocks (core/lib/communication.h) are compiled into every program; their C
// lives in OpenPLC's client.cpp, which these hosts do not have: fail if ever called.
int connect_to_tcp_server(uint8_t *, uint16_t, int) { return -1; }
int send_tcp_message(uint8_t *, size_t, int) { return -1; }
int receive_tcp_message(uint8_t *, size_t, int) { return -1; }

void plc_update_time(void) { plc_add_ns(&__CURRENT_TIME, common_ticktime__); }

void plc_sleep_ns(unsigned long long ns) {
    struct timespec ts = {(time_t)(ns / 1000000000ULL), (long)(ns % 1000000000ULL)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {}
}
