// plc_host.h - what OpenPLC v3's runtime gives an iec2c-compiled program, for the hosts that
// run one without it: the project's runner (fb_host.cpp) and the ST test host
// (tests/fb/fb_test_host.cpp). OpenPLC's core/main.cpp calls config_init__(), then
// config_run__(__tick++) and updateTime() every common_ticktime__ ns.
#ifndef PLC_HOST_H
#define PLC_HOST_H

#include "iec_types_all.h"

#ifdef MBFB_PROGRAM_IN_C                 // the program compiled as C (matiec's own headers)
extern "C" {
#endif
extern unsigned long long common_ticktime__;
void config_init__(void);
void config_run__(unsigned long tick);
#ifdef MBFB_PROGRAM_IN_C
}
#endif

/** updateTime() of OpenPLC's core/glueVars.cpp: __CURRENT_TIME += one task period. */
void plc_update_time(void);
/** Sleep ns nanoseconds (EINTR resumed). */
void plc_sleep_ns(unsigned long long ns);

/** t += ns, for struct timespec and matiec's IEC_TIMESPEC alike. */
template <class T> static inline void plc_add_ns(T *t, unsigned long long ns) {
    t->tv_sec += (long)(ns / 1000000000ULL);
    t->tv_nsec += (long)(ns % 1000000000ULL);
    if (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec += 1;
    }
}

#endif
