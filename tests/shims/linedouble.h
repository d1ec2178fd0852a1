/*
 * linedouble.h - what linedouble.c shares with gpiocdev_double.c (the kernel's GPIO
 * character device, linked in when LINEDOUBLE_GPIOD is 0).
 */
#ifndef LINEDOUBLE_H
#define LINEDOUBLE_H

/** Append "T <fmt...>" to $LINEDOUBLE_LOG, T the shims' clock (CLOCK_MONOTONIC, us). */
void ld_record(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/** An ioctl on one of the GPIO double's descriptors: 1 and *rc set; 0 when fd is not one. */
int gpiocdev_ioctl(int fd, unsigned long req, void *arg, int *rc);

#endif
