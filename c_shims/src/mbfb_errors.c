/*
 * mbfb_errors.c - texts of the one error table (mbfb.h) shared by shims and blocks.
 */
#include "mbfb.h"

/* Static text of any code (positive or negative). */
const char *mbfb_strerror(int code)
{
    static const char *const text[] = {
        "no error",
        "timeout: no reply after all retries",
        "CRC/LRC error in the reply",
        "bad reply: wrong slave, function, byte count or echo, or truncated",
        "device offline (back-off after repeated failures): not sent",
        "port does not exist or cannot be opened",
        "port lost during I/O",
        "cancelled",
        "request queue full",
        "port already open with other settings",
        "invalid argument",
        "unknown or stale handle",
        "out of memory or too many buses/devices",
        "write unconfirmed: no valid echo and the read-back did not show the value; "
        "not repeated",
        "baud rate the serial driver cannot set within 1 % (see the stderr line for the rate)",
        "RS-485 direction control refused by the port, driver or GPIO line: nothing sent",
        "not done: the PLC stopped scanning the block (plan stopped, queued request not sent)",
    };
    static const char *const exc[] = {
        "Modbus exception",
        "Modbus exception 1: illegal function",
        "Modbus exception 2: illegal data address",
        "Modbus exception 3: illegal data value",
        "Modbus exception 4: slave device failure",
        "Modbus exception 5: acknowledge",
        "Modbus exception 6: slave device busy",
    };

    if (code < 0)
        code = -code;
    if (code < (int)(sizeof text / sizeof text[0]))
        return text[code];
    if (code > MBFB_E_EXCEPTION_BASE && code < MBFB_E_EXCEPTION_BASE + 7)
        return exc[code - MBFB_E_EXCEPTION_BASE];
    if (code > MBFB_E_EXCEPTION_BASE && code < 200)
        return exc[0];
    static const char *const input[] = {
        "bad slave id: 0 is broadcast (writes only), the maximum is 247",
        "port name empty",
        "value out of its documented range: not sent",
        "unknown code: not sent",
        "command not allowed in the device's current mode: not sent",
        "not ready: limits or scaling not yet read from the device",
        "invalid register request (function, count or address)",
        "invalid line settings (data bits, stop bits, baud or timeout)",
        "block not enabled",
        "setting not held: its read-back shows another value than written",
    };
    if (code >= MBFB_E_BAD_SLAVE && code <= MBFB_E_NOT_HELD)
        return input[code - MBFB_E_BAD_SLAVE];
    if (code > MBFB_E_NOT_HELD && code <= 255)
        return "function block input error (see the block's documentation)";
    return "unknown error";
}
