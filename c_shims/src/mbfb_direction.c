/*
 * mbfb_direction.c - RS-485 direction control: who drives a half-duplex transceiver's
 * driver-enable while the master sends (README "Direction control").
 *
 * One small table per mode, like the backends: open (when the port opens; a port or
 * driver that refuses the mode closes it again with -MBFB_E_DIRECTION, before any byte),
 * drive (switch the line; NULL where the adapter or the kernel does it) and close. The
 * mode's state is this file's (bus->dir_priv).
 * - MBFB_DIR_KERNEL: the UART driver's RS-485 mode (TIOCSRS485, read back with
 *   TIOCGRS485); the kernel switches RTS around every frame, so drive is NULL.
 * - MBFB_DIR_RTS: TIOCMBIS / TIOCMBIC of TIOCM_RTS by the worker.
 * - MBFB_DIR_GPIO: a line of a GPIO chip through libgpiod 2 or 1, loaded at run time
 *   (mbfb_gpio.c).
 * For RTS and GPIO the worker switches the line on, waits dir_before_us, sends, waits until
 * the frame has left the UART, waits dir_after_us and switches it off. "Has left": never
 * before the frame's own time on the wire from when the write returned (it cannot have begun
 * earlier than the write began); from then on the UART's transmitter-empty
 * bit (TIOCSERGETLSR, every serial_core UART: FIFO and shift register both empty), polled
 * every quarter character, so the line drops within a fraction of a character of the last
 * stop bit. Where the driver has no such ioctl, and on USB adapters (lsr_usable), tcdrain(),
 * and one character more when it had to wait (many drivers report the FIFO empty while the
 * last character is still going out).
 * tcdrain() alone is not used on a UART: the kernel's uart_wait_until_sent sleeps in whole
 * jiffies (4 ms at HZ=250), longer than the t3.5 after which an instrument may answer.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <errno.h>
#include <linux/serial.h> /* struct serial_rs485 */
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <time.h>

#include "mbfb_gpio.h"
#include "mbfb_internal.h"

/* ---- the modes -------------------------------------------------------------- */
typedef struct dir_state {
    struct serial_rs485 saved;  /* KERNEL: the driver's RS-485 settings before ours   */
    int lsr;                    /* RTS, GPIO: the port's transmitter-empty bit can be
                                   polled (a UART on the board, not a USB adapter)     */
    mbfb_gpio_t *gpio;          /* GPIO: the requested line                         */
} dir_state_t;

typedef struct dir_mode {
    /** Put the port into the mode, line idle (receiving). 0 or -MBFB_E_DIRECTION. */
    int (*open)(mbfb_bus_t *bus, dir_state_t *st);
    /** Drive the line: sending 1 before a frame, 0 after it. 0 or -MBFB_E_PORTLOST.
     *  NULL: the adapter or the kernel switches. */
    int (*drive)(mbfb_bus_t *bus, dir_state_t *st, int sending);
    /** Leave the mode (the port is still open). */
    void (*close)(mbfb_bus_t *bus, dir_state_t *st);
} dir_mode_t;

/* Kernel RS-485 mode: RTS at the polarity asked for while sending, the delays in ms. */
static int kernel_open(mbfb_bus_t *bus, dir_state_t *st)
{
    const mbfb_bus_config_t *c = &bus->cfg;
    struct serial_rs485 rs, back;

    if (ioctl(bus->fd, TIOCGRS485, &st->saved) != 0)
        return -MBFB_E_DIRECTION; /* no RS-485 support in this driver */
    memset(&rs, 0, sizeof rs);
    rs.flags = SER_RS485_ENABLED |
               (c->dir_active_low ? SER_RS485_RTS_AFTER_SEND : SER_RS485_RTS_ON_SEND);
    rs.delay_rts_before_send = (uint32_t)(c->dir_before_us + 999) / 1000;
    rs.delay_rts_after_send = (uint32_t)(c->dir_after_us + 999) / 1000;
    if (ioctl(bus->fd, TIOCSRS485, &rs) != 0 || ioctl(bus->fd, TIOCGRS485, &back) != 0)
        return -MBFB_E_DIRECTION;
    /* a driver may clamp what it cannot do: the mode and polarity must be as asked */
    if ((back.flags & (SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND)) !=
        rs.flags) {
        ioctl(bus->fd, TIOCSRS485, &st->saved);
        return -MBFB_E_DIRECTION;
    }
    return 0;
}

static void kernel_close(mbfb_bus_t *bus, dir_state_t *st)
{
    ioctl(bus->fd, TIOCSRS485, &st->saved);
}

/* RTS: asserted while sending (TIOCM_RTS set), or released with dir_active_low. */
static int rts_drive(mbfb_bus_t *bus, dir_state_t *st, int sending)
{
    int bit = TIOCM_RTS, on = sending != bus->cfg.dir_active_low;
    (void)st;
    return ioctl(bus->fd, on ? TIOCMBIS : TIOCMBIC, &bit) == 0 ? 0 : -MBFB_E_PORTLOST;
}

static int rts_open(mbfb_bus_t *bus, dir_state_t *st)
{
    return rts_drive(bus, st, 0) == 0 ? 0 : -MBFB_E_DIRECTION; /* a pty cannot */
}

/* GPIO: high while sending, or low with dir_active_low; requested as an output at idle. */
static int gpio_drive(mbfb_bus_t *bus, dir_state_t *st, int sending)
{
    int on = sending != bus->cfg.dir_active_low;
    return mbfb_gpio_set(st->gpio, on) == 0 ? 0 : -MBFB_E_PORTLOST;
}

static void gpio_close(mbfb_bus_t *bus, dir_state_t *st)
{
    (void)bus;
    mbfb_gpio_close(st->gpio);
    st->gpio = NULL;
}

static int gpio_open(mbfb_bus_t *bus, dir_state_t *st)
{
    const mbfb_bus_config_t *c = &bus->cfg;

    st->gpio = mbfb_gpio_open(c->gpio_chip, (unsigned)c->gpio_line, c->dir_active_low);
    return st->gpio != NULL ? 0 : -MBFB_E_DIRECTION;
}

/* indexed by MBFB_DIR_* */
static const dir_mode_t dir_modes[] = {
    {NULL, NULL, NULL},                  /* NONE   */
    {kernel_open, NULL, kernel_close},   /* KERNEL */
    {rts_open, rts_drive, NULL},         /* RTS    */
    {gpio_open, gpio_drive, gpio_close}, /* GPIO   */
};

static const dir_mode_t *mode_of(const mbfb_bus_t *bus)
{
    return &dir_modes[bus->cfg.direction];
}

/* ---- the backends' side ------------------------------------------------------ */

/* 1 when the port's transmitter-empty bit can be polled: TIOCSERGETLSR answers and the
 * port is not on USB. ftdi_sio answers it from the status bytes of the chip's last bulk-in
 * packet, which can be older than the frame just written (and QEMU's FT232 never sets TEMT
 * in them); tcdrain() asks the chip itself (GET_MODEM_STATUS). */
static int lsr_usable(int fd)
{
    char driver[64], devpath[512];
    unsigned int lsr;

    return ioctl(fd, TIOCSERGETLSR, &lsr) == 0 &&
           mbfb_serial_driver(fd, driver, sizeof driver, devpath, sizeof devpath) == 0 &&
           strstr(devpath, "/usb") == NULL;
}

/* Put the freshly opened port into the bus's mode. */
int mbfb_dir_open(mbfb_bus_t *bus)
{
    const dir_mode_t *m = mode_of(bus);
    dir_state_t *st;
    int rc;

    if (m->open == NULL)
        return 0;
    if ((st = (dir_state_t *)calloc(1, sizeof *st)) == NULL)
        return -MBFB_E_NOMEM;
    if ((rc = m->open(bus, st)) != 0) {
        free(st);
        return rc;
    }
    st->lsr = lsr_usable(bus->fd);
    bus->dir_priv = st;
    return 0;
}

/* Leave the mode before the port closes. */
void mbfb_dir_close(mbfb_bus_t *bus)
{
    const dir_mode_t *m = mode_of(bus);
    dir_state_t *st = (dir_state_t *)bus->dir_priv;

    if (st == NULL)
        return;
    if (m->close != NULL)
        m->close(bus, st);
    free(st);
    bus->dir_priv = NULL;
}

/* Sleep until the monotonic time `t_us` (mbfb_now_us's clock). */
static void sleep_until(int64_t t_us)
{
    struct timespec ts;
    ts.tv_sec = (time_t)(t_us / 1000000);
    ts.tv_nsec = (long)(t_us % 1000000) * 1000;
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
    }
}

/* Switch the line to sending and wait dir_before_us. */
int mbfb_dir_begin(mbfb_bus_t *bus)
{
    const dir_mode_t *m = mode_of(bus);
    int rc;

    if (m->drive == NULL || bus->dir_priv == NULL)
        return 0;
    if ((rc = m->drive(bus, (dir_state_t *)bus->dir_priv, 1)) != 0)
        return rc;
    if (bus->cfg.dir_before_us > 0)
        sleep_until(mbfb_now_us() + bus->cfg.dir_before_us);
    return 0;
}

/* Wait until the frame of wire_bytes written when `written` (the write returned) has left
 * the UART (file comment); returns the time it had. */
static int64_t wait_sent(mbfb_bus_t *bus, int64_t written, int wire_bytes)
{
    int64_t char_us = bus->timing.char_us, now;
    int64_t on_wire = written + (int64_t)wire_bytes * char_us;
    int64_t step = char_us / 4 > 20 ? char_us / 4 : 20;
    int64_t limit = on_wire + (int64_t)wire_bytes * char_us + MBFB_STUCK_UART_US;
    unsigned int lsr;

    sleep_until(on_wire);
    for (;;) {
        if (!((dir_state_t *)bus->dir_priv)->lsr || ioctl(bus->fd, TIOCSERGETLSR, &lsr) != 0)
            break; /* no transmitter-empty bit to read: tcdrain below */
        now = mbfb_now_us();
        if (lsr & TIOCSER_TEMT)
            return now;
        if (now > limit)
            break;
        sleep_until(now + step);
    }
    now = mbfb_now_us();
    while (tcdrain(bus->fd) != 0 && errno == EINTR) {
    }
    /* drained at once: the driver had nothing left to send when the frame's time was up;
     * else it was still sending then, and its "drained" may be the FIFO's: one character
     * more for the shift register */
    if (mbfb_now_us() - now <= step)
        return now > on_wire ? now : on_wire;
    return mbfb_now_us() + char_us;
}

/* The frame of frame_len (slave + PDU) just written, with result sent_rc: wait until it
 * has left the UART, then dir_after_us, and switch the line back to receiving. */
int mbfb_dir_end(mbfb_bus_t *bus, int frame_len, int sent_rc)
{
    const dir_mode_t *m = mode_of(bus);
    int64_t written = mbfb_now_us();
    int rc;

    if (m->drive == NULL || bus->dir_priv == NULL)
        return sent_rc;
    sleep_until(wait_sent(bus, written, mbfb_wire_len(bus->cfg.framing, frame_len)) +
                bus->cfg.dir_after_us);
    rc = m->drive(bus, (dir_state_t *)bus->dir_priv, 0);
    return sent_rc != 0 ? sent_rc : rc;
}
