/*
 * mbfb_baud.c - any baud rate, exactly, on Linux: termios2 with BOTHER.
 *
 * libmodbus configures a serial port with the termios B* constants only and silently uses
 * B9600 for any other rate (the MT-S9's 14400, 28800 and 76800). Linux sets an arbitrary
 * rate with the termios2 ioctls (TCGETS2 / TCSETS2, c_ospeed / c_ispeed with BOTHER), on the
 * usual USB adapters (FTDI, CP210x, PL2303, CH34x) and on-board UARTs; the driver picks the
 * nearest divisor and reports the rate it set, which is read back.
 * <asm/termbits.h> clashes with <termios.h> and <sys/ioctl.h>, so this file includes neither
 * and declares ioctl itself; nothing else in the shims sees termios2.
 */
#include <asm/ioctls.h> /* TCGETS2, TCSETS2 */
#include <asm/termbits.h>
#include <errno.h>

#include "mbfb_internal.h"

#ifdef __cplusplus
extern "C" {
#endif
int ioctl(int fd, unsigned long request, ...) __THROW; /* <sys/ioctl.h> would clash */
#ifdef __cplusplus
}
#endif

/* Set `baud` exactly on the open serial port fd (input and output), then read it back. */
int mbfb_serial_set_baud(int fd, int baud)
{
    struct termios2 t;

    if (ioctl(fd, TCGETS2, &t) != 0)
        return -MBFB_E_BAUD;
    t.c_cflag &= ~(tcflag_t)(CBAUD | (CBAUD << IBSHIFT));
    t.c_cflag |= BOTHER | (BOTHER << IBSHIFT);
    t.c_ospeed = (speed_t)baud;
    t.c_ispeed = (speed_t)baud;
    if (ioctl(fd, TCSETS2, &t) != 0 || ioctl(fd, TCGETS2, &t) != 0)
        return -MBFB_E_BAUD;
    return t.c_ospeed == (speed_t)baud && t.c_ispeed == (speed_t)baud ? 0 : -MBFB_E_BAUD;
}
