/*
 * mbfb_st.h - what the ST blocks' pragmas ({{ }} in st_src/) use beside the shims' API:
 * TIME arithmetic and a device block's compare of its settings, as C macros over the
 * variables as matiec (or v4/translate.py's mirrors under STruC++) lays them out.
 *
 * Not part of the shims' API (c_shims/include/mbfb.h): it names ST variables and
 * structure fields (MB_SETTINGS_GIVEN, MB_Types.st). Included only where the blocks'
 * generated code is compiled: OpenPLC's core/c_blocks.h (plc_lib/install.sh, mkbundle.sh),
 * the runner's program builds (tools/runner, force-included) and the STruC++ layer
 * (v4/mbfb_strucpp.hpp).
 */
#ifndef MBFB_ST_H
#define MBFB_ST_H

#include <string.h>

#include "mbfb.h"

/* ---- TIME in the blocks' pragmas -------------------------------------------- */
/* matiec's TIME is {tv_sec, tv_nsec}, always normalised; STruC++'s an integer
 * (v4/mbfb_strucpp.hpp defines these two for it before including this header). */
#ifndef MBFB_TIME_EQ
#define MBFB_TIME_EQ(a, b) ((a).tv_sec == (b).tv_sec && (a).tv_nsec == (b).tv_nsec)
#endif
/* res := a - b for a >= b (MB_Validity's Age: the scan's time less an earlier one's):
 * matiec's __time_sub and __normalize_timespec (iec_std_lib.h: two calls, about 50
 * instructions at -O0) inline; with both normalised, a borrow is all the normalising. */
#ifndef MBFB_TIME_SUB
#define MBFB_TIME_SUB(res, a, b)                                                           \
    do {                                                                                   \
        (res).tv_sec = (a).tv_sec - (b).tv_sec;                                            \
        (res).tv_nsec = (a).tv_nsec - (b).tv_nsec;                                         \
        if ((res).tv_nsec < 0) {                                                           \
            (res).tv_sec--;                                                                \
            (res).tv_nsec += 1000000000L;                                                  \
        }                                                                                  \
    } while (0)
#endif

/* ---- a device block's settings: compare and copy ------------------------------ */
/* A device block hands its link and plan settings on to its MB_Device only when one changed
 * (MB_Device's Unchanged): it keeps them as it handed them last in `given`, an
 * MB_SETTINGS_GIVEN (MB_Types.st; the fields as matiec and v4/translate.py name them), and
 * compares them in one pragma:
 *   {{ SetFbVar(SAME, MBFB_SETTINGS_SAME(GetFbVar(GIVEN), GetFbVar(PORT), GetFbVar(LINE),
 *        GetFbVar(SLAVEID), GetFbVar(ENABLE), GetFbVar(PERIOD), GetFbVar(STALETIME),
 *        GetFbVar(SETTINGSPERIOD))); }}
 * 1 when every one equals its copy (Port by its length and characters: the body after len
 * is what a longer string left; Line, an MB_LINE, byte for byte; a TIME by MBFB_TIME_EQ),
 * else 0 after copying all of them into `given` (and the first time: Handed FALSE). A block
 * without a settings tier passes GetFbVar(GIVEN).SETTINGSPERIOD as settingsPeriod. A macro,
 * not a function: the types are the pragma's (matiec's C types, or STruC++'s C mirrors of
 * them), the code is compiled as C (the runner's demo build) and as C++ (OpenPLC, STruC++),
 * and it costs what the compare costs (at -O0: the Port and Line memcmp, the rest inline). */
#define MBFB_STRING_EQ(a, b) ((a).len == (b).len && memcmp((a).body, (b).body, (size_t)(b).len) == 0)
#define MBFB_SETTINGS_SAME(given, port, line, slave, enable, period, staleTime, settingsPeriod) \
    (((given).HANDED && (given).SLAVEID == (slave) && (given).ENABLE == (enable)                \
      && MBFB_TIME_EQ((given).PERIOD, period) && MBFB_TIME_EQ((given).STALETIME, staleTime)     \
      && MBFB_TIME_EQ((given).SETTINGSPERIOD, settingsPeriod)                                   \
      && MBFB_STRING_EQ((given).PORT, port)                                                     \
      && memcmp(&(given).LINE, &(line), sizeof(line)) == 0)                                     \
         ? 1                                                                                    \
         : ((given).PORT = (port), memcpy(&(given).LINE, &(line), sizeof(line)),                \
            (given).SLAVEID = (slave), (given).ENABLE = (enable), (given).PERIOD = (period),    \
            (given).STALETIME = (staleTime), (given).SETTINGSPERIOD = (settingsPeriod),         \
            (given).HANDED = 1, 0))

#endif /* MBFB_ST_H */
