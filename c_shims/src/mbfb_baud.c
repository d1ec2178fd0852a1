/*
 * mbfb_baud.c - any baud rate on Linux (termios2 with BOTHER), and the rate the UART will
 * really run at.
 *
 * libmodbus configures a serial port with the termios B* constants only and silently uses
 * B9600 for any other rate (the MT-S9's 14400, 28800 and 76800). Linux sets an arbitrary
 * rate with the termios2 ioctls (TCGETS2 / TCSETS2, c_ospeed / c_ispeed with BOTHER).
 * What the driver then programs is not always what termios2 reads back: the 8250 driver
 * rounds to the nearest divisor of its clock and reports the rate asked (asked 76800, a
 * 16550 at 1.8432 MHz runs at 57600), ftdi_sio programs the nearest eighth of its divisor
 * and reports the rate asked too. So the rate the port will run at is worked out here with
 * the driver's own divisor rule for the drivers known to round silently (the 8250 family
 * with integer divisors, ftdi_sio), and read back from termios2 for the others (cp210x,
 * pl2303, ch341 write the rate they set back into termios). A rate more than
 * MBFB_BAUD_TOLERANCE_PERMILLE off is refused with MBFB_E_BAUD and one line on stderr
 * naming the rate the port would run at.
 * <asm/termbits.h> clashes with <termios.h> and <sys/ioctl.h>, so this file includes neither
 * and declares ioctl itself; nothing else in the shims sees termios2.
 */
#include <asm/ioctls.h> /* TCGETS2, TCSETS2, TIOCGSERIAL */
#include <asm/termbits.h>
#include <errno.h>
#include <linux/serial.h> /* struct serial_struct */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbfb_internal.h"

#ifdef __cplusplus
extern "C" {
#endif
int ioctl(int fd, unsigned long request, ...) __THROW; /* <sys/ioctl.h> would clash */
#ifdef __cplusplus
}
#endif

/* The error accepted between the rate asked and the rate the UART runs at: 1 %. A UART
 * samples each bit in its middle, so over an 11-bit character (start, 8 data, parity or a
 * second stop bit, stop) both ends together may drift about 4 % before the stop bit is
 * misread; 1 % on the master's side leaves the rest to the instrument's own oscillator.
 * The FTDI rates (76800 -> 76677, 0.16 %) pass; a 16550's 57600 for 76800 (25 %) does not. */
#define MBFB_BAUD_TOLERANCE_PERMILLE 10

/* DIV_ROUND_CLOSEST of the kernel for positive numbers. */
static long div_closest(long a, long b)
{
    return (a + b / 2) / b;
}

/* ftdi_sio's divisor rule (drivers/usb/serial/ftdi_sio.c): the BM/R/X chips divide 3 MHz in
 * eighths (ftdi_232bm_baud_base_to_divisor), the H chips (FT2232H, FT4232H, FT232H) 12 MHz
 * in eighths (ftdi_2232h_baud_to_divisor) from 1200 baud up. `bcd`: the chip's bcdDevice. */
static long ftdi_rate(long baud, unsigned bcd)
{
    int h = bcd == 0x0700 || bcd == 0x0800 || bcd == 0x0900;
    long eighths;

    if (h && baud >= 1200) {
        eighths = div_closest(8L * 120000000, 10 * baud);
        return eighths > 0 ? 96000000L / eighths : baud;
    }
    eighths = div_closest(48000000L, 2 * baud);
    if (eighths == 8 || eighths == 12) /* divisors 1.0 and 1.5: the chip's special cases */
        return eighths == 8 ? 3000000 : 2000000;
    return eighths > 0 ? 24000000L / eighths : baud;
}

/* The 8250 family with an integer divisor of baud_base (16550 and alike on PCs, PNP, PCI,
 * device-tree "ns16550a", DesignWare): the nearest divisor (serial8250_get_divisor). */
static int is_8250(const char *driver)
{
    static const char *const names[] = {"serial8250", "serial", "of_serial", "dw-apb-uart"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (strcmp(driver, names[i]) == 0)
            return 1;
    return 0;
}

/* The rate the port will run at for `baud`, as far as this file knows its driver. */
static long rate_in_force(int fd, long baud, const char *driver, const char *devpath)
{
    if (is_8250(driver)) {
        struct serial_struct ss;
        if (ioctl(fd, TIOCGSERIAL, &ss) == 0 && ss.baud_base > 0) {
            long div = div_closest(ss.baud_base, baud);
            return ss.baud_base / (div > 0 ? div : 1);
        }
    } else if (strcmp(driver, "ftdi_sio") == 0) {
        /* devpath: .../<usb device>/<interface>/ttyUSBn; bcdDevice is the device's */
        char path[512];
        unsigned bcd = 0;
        const char *cut = strrchr(devpath, '/');
        int n = cut != NULL ? (int)(cut - devpath) : 0;
        while (n > 0 && devpath[n - 1] != '/')
            n--;
        if (n > 0 && snprintf(path, sizeof path, "%.*sbcdDevice", n, devpath) <
                         (int)sizeof path) {
            FILE *f = fopen(path, "r");
            if (f != NULL) {
                if (fscanf(f, "%x", &bcd) != 1)
                    bcd = 0;
                fclose(f);
            }
        }
        return ftdi_rate(baud, bcd);
    }
    return baud;
}

/* Set `baud` on the open port fd of `bus` (termios2, only when `set`: libmodbus has set the
 * rates of its table) and check the rate the driver will run at: 0, or -MBFB_E_BAUD when
 * the driver refuses the rate or runs more than MBFB_BAUD_TOLERANCE_PERMILLE off it (one
 * line on stderr, once per bus, names the rate). */
int mbfb_serial_set_baud(mbfb_bus_t *bus, int set)
{
    struct termios2 t;
    long baud = bus->cfg.baud, got;
    char driver[64], devpath[512];

    if (ioctl(bus->fd, TCGETS2, &t) != 0)
        return -MBFB_E_BAUD;
    if (set) {
        t.c_cflag &= ~(tcflag_t)(CBAUD | (CBAUD << IBSHIFT));
        t.c_cflag |= BOTHER | (BOTHER << IBSHIFT);
        t.c_ospeed = (speed_t)baud;
        t.c_ispeed = (speed_t)baud;
        if (ioctl(bus->fd, TCSETS2, &t) != 0 || ioctl(bus->fd, TCGETS2, &t) != 0)
            return -MBFB_E_BAUD;
    }
    got = (long)t.c_ospeed; /* the rate the driver says it set (some round it here) */
    if (got > 0 && mbfb_serial_driver(bus->fd, driver, sizeof driver, devpath,
                                      sizeof devpath) == 0)
        got = rate_in_force(bus->fd, got, driver, devpath);
    else
        strcpy(driver, "serial");
    /* in 64 bits: |got - baud| * 1000 passes 2^31 at 2.1 Mbaud off, and long has 32 bits on
     * armhf (3000000 asked, 9600 in force passed as 0 % off there: tests/kernel pl011) */
    if (got > 0 &&
        llabs((long long)got - baud) * 1000 <= (long long)baud * MBFB_BAUD_TOLERANCE_PERMILLE &&
        (!set || t.c_ispeed == t.c_ospeed))
        return 0;
    if (!bus->baud_said) {
        bus->baud_said = 1;
        fprintf(stderr,
                "mbfb: %s: %ld baud asked, the %s driver would run at %ld (%+.2f %%, more "
                "than %d.%d %% off): ErrorID %d, %s\n",
                bus->port, baud, driver, got, got > 0 ? 100.0 * (got - baud) / baud : -100.0,
                MBFB_BAUD_TOLERANCE_PERMILLE / 10, MBFB_BAUD_TOLERANCE_PERMILLE % 10,
                MBFB_E_BAUD, mbfb_strerror(MBFB_E_BAUD));
    }
    return -MBFB_E_BAUD;
}
