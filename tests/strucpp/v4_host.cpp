// v4_host.cpp - runs one STruC++-compiled ST test program (tests/fb/t_*.st with st_src and
// fbtest.st, translated by v4/translate.py) scan by scan like tests/fb/fb_test_host.cpp does
// for matiec's: one scan of PROGRAM main every 20 ms (the tests' task), the scan's TIME()
// advanced by 20 ms per scan (strucpp::__CURRENT_TIME_NS, what Runtime v4 stamps), a real
// 20 ms sleep between scans so the shims' worker and the bus run. Environment and exit codes
// as fb_host's test mode (MBFB_TEST_PORT, MBFB_SIM_CONTROL, MBFB_MAX_SCANS; 0 = all checks
// passed and T_DONE called). The fbt_* functions, the checks' tally and the end of the run are
// tests/fb/fbtest_hooks.cpp's, the same that fb_test_host.cpp links.
#include "program.hpp"
#include "fbtest.h"

#include <errno.h>
#include <time.h>

static const long long kTickNs = 20000000LL;   // TASK task0(INTERVAL := T#20ms) of every t_*.st

static void sleep_ns(long long ns) {
    struct timespec ts = {(time_t)(ns / 1000000000LL), (long)(ns % 1000000000LL)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {}
}

int main() {
    long max_scans = fbt_host_max_scans();
    static strucpp::Program_MAIN prog;
    long scan;
    for (scan = 0; scan < max_scans && !fbt_host_stop(); scan++) {
        fbt_host_set_scan(scan);
        strucpp::__CURRENT_TIME_NS = (int64_t)scan * kTickNs;
        prog.run();
        sleep_ns(kTickNs);
    }
    mbfb_shutdown();
    return fbt_host_finish(scan);
}
