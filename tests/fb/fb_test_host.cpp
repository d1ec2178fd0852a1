// fb_test_host.cpp - the host of the ST test programs (tests/fb/t_*.st with fbtest.st): runs one
// iec2c-compiled program as OpenPLC v3's runtime does (tools/runner/plc_host.h), in simulated
// time (one period's sleep per scan, so the bus worker runs), and reports the ST checks (their
// host functions: fbtest_hooks.cpp). Test code only: the project's runner (tools/runner) links
// none of it.
// Environment: MBFB_TEST_PORT (device port for the program), MBFB_SIM_CONTROL (simulator
// control socket), MBFB_MAX_SCANS (scan limit, default 6000). Exit: 0 all checks passed and the
// program called T_DONE; 1 a check failed, or the scan limit was reached, or no check ran.
#include "fbtest.h"
#include "mbfb.h"
#include "plc_host.h"

#include <stdio.h>

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    long max_scans = fbt_host_max_scans(), scan;
    config_init__();
    for (scan = 0; scan < max_scans && !fbt_host_stop(); scan++) {
        fbt_host_set_scan(scan);
        config_run__((unsigned long)scan);
        plc_update_time();
        plc_sleep_ns(common_ticktime__);     // like sleep_until(): lets the worker and the bus run
    }
    mbfb_shutdown();
    return fbt_host_finish(scan);
}
