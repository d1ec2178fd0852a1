// unload_entry.cpp - the entry points of a matiec (iec2c) program built as a shared object for
// test_unload_program.py: what OpenPLC's runtime calls (tools/runner/plc_host.h), under names the
// host (unload_host.cpp) finds with dlsym.
#include "plc_host.h"

extern "C" void lt_init(void) { config_init__(); }

extern "C" void lt_scan(unsigned long tick) {
    config_run__(tick);
    plc_update_time();
}
