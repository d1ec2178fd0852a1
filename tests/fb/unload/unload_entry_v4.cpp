// unload_entry_v4.cpp - the entry points of a STruC++ program built as a shared object for
// test_unload_program.py (as tests/strucpp/v4_host.cpp runs one: PROGRAM main every 20 ms, its
// TIME() advanced by 20 ms per scan), under names the host (unload_host.cpp) finds with dlsym.
#include "program.hpp"

static const long long kTickNs = 20000000LL;   // TASK task0(INTERVAL := T#20ms)
static strucpp::Program_MAIN prog;              // constructed by dlopen, destroyed by dlclose

extern "C" void lt_init(void) {}

extern "C" void lt_scan(unsigned long tick) {
    strucpp::__CURRENT_TIME_NS = (int64_t)tick * kTickNs;
    prog.run();
}
