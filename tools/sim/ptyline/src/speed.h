/* speed.h: exact pty speeds through termios2 (speed.c). */
#ifndef PL_SPEED_H
#define PL_SPEED_H

/* The input and output speed of fd's tty in baud (TCGETS2). 0, or -1 with errno. */
int pl_speed_get(int fd, long *ispeed, long *ospeed);

/* Sets fd's tty to exactly baud, in and out (TCSETS2 with BOTHER). 0, or -1. */
int pl_speed_set(int fd, long baud);

/* 1 if speed (cfgetospeed) is BOTHER: the rate is in termios2 only. */
int pl_speed_is_other(unsigned speed);

#endif
