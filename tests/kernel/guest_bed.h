/*
 * guest_bed.h - what the kernel test bed's guest programs (guest_serial.c, guest_gpio.c) share.
 */
#ifndef GUEST_BED_H
#define GUEST_BED_H

/* The guests' response timeout. The derived one (54 ms for a register at 9600) holds against
 * a device with a CPU of its own; here the guest runs under TCG on the host's cores behind a
 * host pty, and beside two busy loops the ARM guests' replies came later (MT-S9 in ASCII and
 * without CRC, VD and FDC on armhf); with 500 ms still a read at 230400 and two RTS requests
 * in the PL011 guest, and 4 of 6 reads in the GPIO guest (where a retry adds a pulse). These
 * tests check the drivers; the timeout rule is tests/shims'. */
#define BED_TIMEOUT_MS 2000

#endif
