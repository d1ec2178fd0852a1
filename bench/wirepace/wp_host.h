/* wp_host.h - what the generated ST programs of bench/wire_pace.py call from pragmas. */
#ifndef WP_HOST_H
#define WP_HOST_H
#ifdef __cplusplus
extern "C" {
#endif
/** Device `dev` (0-based, as the program numbers its blocks) published a refresh in this
 *  scan; counted inside the measuring window only. */
void wp_pub(int dev);
#ifdef __cplusplus
}
#endif
#endif
