/*
 * testline.h - the test peer's serial line, kept inside the test's process (testline.c).
 */
#ifndef TESTLINE_H
#define TESTLINE_H

/** Make a line named `link` (a plain file made there; the shims open that name): 0 and
 *  *peer_fd the peer's end (read, write, poll, FIONREAD), or -1. */
int tl_make(const char *link, int *peer_fd);
/** A line named `link` whose bytes go through `sock`, connected to a peer in another process
 *  (pymodbus on a socket:// port: tests/shims/test_pymodbus.c): 0, or -1. */
int tl_adopt(const char *link, int sock);
/** The peer is gone (peer_fd: tl_make's, or tl_adopt's sock): the shims' descriptors of the line read EOF from now on, and `link`
 *  disappears, as a pulled USB adapter's node does. Closes peer_fd. */
void tl_drop(const char *link, int peer_fd);

#endif
