/* wp_host.h - what the generated ST programs of bench/wire_pace.py call from pragmas. */
#ifndef WP_HOST_H
#define WP_HOST_H
#ifdef __cplusplus
extern "C" {
#endif
/** Device `dev` (0-based, as the program numbers its blocks) published a refresh in this
 *  scan; counted inside the measuring window only. */
void wp_pub(int dev);
/** The program saw `what` (its own code; bench/write_done.py: 1 Execute rose, 2 Done rose,
 *  3 Error rose) about `tag` (there: the value written) in this scan. The host records the
 *  scan (and every scan's CLOCK_MONOTONIC start) and prints them at the end. */
void wp_mark(int what, int tag);
#ifdef __cplusplus
}
#endif
#endif
