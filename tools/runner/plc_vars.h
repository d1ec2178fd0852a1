/* plc_vars.h - the runner's view of one program's variables, by name, as text.
 *
 * mkglue.py generates, per iec2c output, a table of every located variable (by IEC address,
 * "%QW0", "%QX0.1", "%MW0": OpenPLC's glue_generator binds the same ones to its buffers) and
 * every elementary variable of the program instances (by matiec's name,
 * "CONFIG0.RES0.HEATTREAT.BUSPORT", as in VARIABLES.csv). Located entries come first, sorted
 * by area/size then address, so a snapshot groups them as {"QW": {...}, "QX": {...}}.
 * Functions return 0 or -1 with errno set (EINVAL bad text, ERANGE out of range).
 * Not thread safe: call them between scans, on the scan thread. */
#ifndef PLC_VARS_H
#define PLC_VARS_H
#include <stddef.h>
#ifdef __cplusplus
extern "C" {  /* the table is generated in the program's language, C or C++ */
#endif

typedef enum {
    PLC_BOOL, PLC_SINT, PLC_INT, PLC_DINT, PLC_LINT, PLC_USINT, PLC_UINT, PLC_UDINT, PLC_ULINT,
    PLC_BYTE, PLC_WORD, PLC_DWORD, PLC_LWORD, PLC_REAL, PLC_LREAL, PLC_TIME, PLC_STRING
} plc_type_t;

typedef struct {
    const char *name;   /* "%QW0" (located) or "CONFIG0.RES0.PROG.VAR" */
    plc_type_t type;
    void *ptr;          /* the IEC_<type> value itself */
} plc_var_t;

/* Generated per program (mkglue.py). */
extern const plc_var_t plc_vars[];
extern const int plc_nvars;

/** IEC name of a type ("INT"). */
const char *plc_type_name(plc_type_t type);
/** The variable called name (case-insensitive; the % of an address may be left out), or NULL. */
const plc_var_t *plc_var_find(const char *name);
/** Write the value as JSON (number, true/false, string; TIME in ms) into buf; returns the
 *  length it needed (like snprintf). */
int plc_var_format(const plc_var_t *v, char *buf, size_t size);
/** Set the variable from text: TRUE/FALSE/1/0, a number (0x.. for integers), TIME in ms,
 *  STRING as is (one pair of surrounding single quotes is removed). Nothing changes on error. */
int plc_var_parse(const plc_var_t *v, const char *text);
/** Write every located variable as one JSON object, {"scan": N, "QW": {"0": 1494, ...},
 *  "QX": {"0.0": true, ...}, ...}, to path atomically (a temp file renamed over it). */
int plc_snapshot_write(const char *path, unsigned long scan);

#ifdef __cplusplus
}
#endif
#endif
