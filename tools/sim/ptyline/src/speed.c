/* speed.c: exact pty speeds through termios2 (Linux), for bauds without a termios
 * B* constant (a master sets those with BOTHER).  Apart from side.c because
 * <asm/termbits.h> clashes with <termios.h>. */
#include "speed.h"

#include <sys/ioctl.h>

#include <asm/termbits.h>

int pl_speed_get(int fd, long *ispeed, long *ospeed)
{
    struct termios2 t;
    if (ioctl(fd, TCGETS2, &t) != 0)
        return -1;
    *ispeed = (long)t.c_ispeed;
    *ospeed = (long)t.c_ospeed;
    return 0;
}

int pl_speed_set(int fd, long baud)
{
    struct termios2 t;
    if (ioctl(fd, TCGETS2, &t) != 0)
        return -1;
    t.c_cflag &= ~(tcflag_t)(CBAUD | (CBAUD << IBSHIFT));
    t.c_cflag |= BOTHER | (BOTHER << IBSHIFT);
    t.c_ispeed = (speed_t)baud;
    t.c_ospeed = (speed_t)baud;
    return ioctl(fd, TCSETS2, &t);
}

int pl_speed_is_other(unsigned speed)
{
    return speed == (unsigned)BOTHER;
}
