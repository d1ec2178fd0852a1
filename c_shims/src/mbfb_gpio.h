/*
 * mbfb_gpio.h - one GPIO output line through libgpiod, loaded at run time (mbfb_gpio.c);
 * used by RS-485 direction control (mbfb_direction.c).
 */
#ifndef MBFB_GPIO_H
#define MBFB_GPIO_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct mbfb_gpio mbfb_gpio_t;

/** Request line `offset` of `chip` (a number, a path, a name under /dev or a chip label)
 *  as an output at the physical level `value`, consumer "mbfb". NULL when no libgpiod
 *  (2 or 1) is installed, or the chip or line is missing or taken. */
mbfb_gpio_t *mbfb_gpio_open(const char *chip, unsigned int offset, int value);
/** Drive the line to the physical level `value`. 0, or -1 (errno set by libgpiod). */
int mbfb_gpio_set(mbfb_gpio_t *g, int value);
/** Release the line (it keeps its level, as the kernel leaves it) and free g; NULL is fine. */
void mbfb_gpio_close(mbfb_gpio_t *g);

#ifdef __cplusplus
}
#endif
#endif
