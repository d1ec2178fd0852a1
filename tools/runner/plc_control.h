/* plc_control.h - the runner's control socket: one Unix stream socket taking one command per
 * line, answered with one line:
 *     set NAME VALUE   ->  "ok"  (NAME as in plc_vars.h: "%MW0", "MW0", "CONFIG0.RES0.P.V")
 *     get NAME         ->  "ok VALUE"  (JSON, as in the snapshot)
 *     anything wrong   ->  "error: why"  (and nothing changes)
 * It is served on the scan thread while the scan loop waits for its next period, so a write
 * lands between two scans, as a Modbus write to OpenPLC's server does.
 * Functions return 0 or -1 with errno set. */
#ifndef PLC_CONTROL_H
#define PLC_CONTROL_H
#include <stddef.h>
#include <time.h>

/** Run one command line (without its newline); writes the answer line (without newline) into
 *  reply. Returns 0 when the command was carried out, -1 when the answer is an error. */
int plc_command(const char *line, char *reply, size_t size);
/** Listen on a new Unix socket at path (it must not exist). */
int plc_control_open(const char *path);
/** Serve commands until the CLOCK_MONOTONIC time deadline (without a socket: just sleep).
 *  Returns 0 at the deadline, -1 with errno EINTR when a signal arrived first. */
int plc_control_serve(const struct timespec *deadline);
/** Close every connection and the socket, and remove its file. */
void plc_control_close(void);

#endif
