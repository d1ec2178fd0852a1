/*
 * mbfb_gpio.c - one GPIO output line (an RS-485 transceiver's driver-enable) through
 * libgpiod, loaded with dlopen when a bus first asks for it: a program without GPIO needs no
 * libgpiod, and OpenPLC's build no extra library.
 *
 * libgpiod and not the kernel's GPIO character-device ioctls by hand: it is the maintained
 * interface to that device, written with the kernel's GPIO subsystem by its maintainer, and
 * packaged by every distribution; it keeps the uAPI's structures, flags and padding in one
 * place that follows the kernel. Its two incompatible majors are both in the field, so both
 * are spoken, one small table each:
 * - libgpiod 2 (libgpiod.so.3: Debian 13, Raspberry Pi OS trixie): the chip opened by its
 *   path, the line requested through settings, line config and request config objects
 *   (kernel uAPI v2);
 * - libgpiod 1 (libgpiod.so.2: Debian 12, Ubuntu 22.04, Raspberry Pi OS bookworm):
 *   gpiod_chip_open_lookup and gpiod_line_request_output (kernel uAPI v1).
 * Which one: a libgpiod already in the process (the program links one: then the shims use
 * the same), else libgpiod 2, else 1. 2 before 1 because libgpiod 1 speaks uAPI v1, which a
 * kernel may leave out (CONFIG_GPIO_CDEV_V1), and 1 is no longer developed upstream. A
 * library whose soname matches but lacks a function of its API is not used.
 * Levels are physical (1 high) in both: the lines are requested without the active-low flag,
 * and mbfb_direction.c applies dir_active_low.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <ctype.h>
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbfb_gpio.h"

#define GPIO_CONSUMER "mbfb" /* shown by gpioinfo as the line's user */
#define GPIO_DEV_DIR "/dev"  /* where chips are found by name and label */

struct gpiod_chip;
struct gpiod_line;                /* v1 */
struct gpiod_chip_info;           /* v2 */
struct gpiod_line_settings;       /* v2 */
struct gpiod_line_config;         /* v2 */
struct gpiod_request_config;      /* v2 */
struct gpiod_line_request;        /* v2 */

/* libgpiod 2's enum values this file passes (gpiod.h: enum gpiod_line_direction, _value) */
#define GPIOD2_LINE_DIRECTION_OUTPUT 3
#define GPIOD2_LINE_VALUE_INACTIVE 0
#define GPIOD2_LINE_VALUE_ACTIVE 1

struct mbfb_gpio {
    struct gpiod_chip *chip;            /* v1: open while its line is requested        */
    struct gpiod_line *line;            /* v1: the requested line                       */
    struct gpiod_line_request *request; /* v2: the request (needs no open chip)         */
    unsigned int offset;                /* v2: the line's offset in the request         */
};

/* ---- libgpiod 2 (libgpiod.so.3) ------------------------------------------------ */
static struct {
    struct gpiod_chip *(*chip_open)(const char *path);
    void (*chip_close)(struct gpiod_chip *chip);
    bool (*is_gpiochip_device)(const char *path);
    struct gpiod_chip_info *(*chip_get_info)(struct gpiod_chip *chip);
    const char *(*chip_info_get_label)(struct gpiod_chip_info *info);
    void (*chip_info_free)(struct gpiod_chip_info *info);
    struct gpiod_line_settings *(*settings_new)(void);
    void (*settings_free)(struct gpiod_line_settings *s);
    int (*settings_set_direction)(struct gpiod_line_settings *s, int direction);
    int (*settings_set_output_value)(struct gpiod_line_settings *s, int value);
    struct gpiod_line_config *(*line_config_new)(void);
    void (*line_config_free)(struct gpiod_line_config *c);
    int (*line_config_add_line_settings)(struct gpiod_line_config *c, const unsigned int *offsets,
                                         size_t n, struct gpiod_line_settings *s);
    struct gpiod_request_config *(*request_config_new)(void);
    void (*request_config_free)(struct gpiod_request_config *r);
    void (*request_config_set_consumer)(struct gpiod_request_config *r, const char *consumer);
    struct gpiod_line_request *(*chip_request_lines)(struct gpiod_chip *chip,
                                                     struct gpiod_request_config *r,
                                                     struct gpiod_line_config *c);
    int (*request_set_value)(struct gpiod_line_request *req, unsigned int offset, int value);
    void (*request_release)(struct gpiod_line_request *req);
} v2;

/* ---- libgpiod 1 (libgpiod.so.2) ------------------------------------------------ */
static struct {
    struct gpiod_chip *(*chip_open_lookup)(const char *descr);
    void (*chip_close)(struct gpiod_chip *chip);
    struct gpiod_line *(*chip_get_line)(struct gpiod_chip *chip, unsigned int offset);
    int (*line_request_output)(struct gpiod_line *line, const char *consumer, int value);
    int (*line_set_value)(struct gpiod_line *line, int value);
    void (*line_release)(struct gpiod_line *line);
} v1;

/* dlsym(h, name) into the function pointer at slot; 0 when missing. (POSIX: a dlsym result
 * converts to a function pointer through memcpy.) */
static int sym(void *h, const char *name, void *slot)
{
    void *f = dlsym(h, name);
    if (f == NULL)
        return 0;
    memcpy(slot, &f, sizeof f);
    return 1;
}

static int load_v2(void *h)
{
    return sym(h, "gpiod_chip_open", &v2.chip_open) &&
           sym(h, "gpiod_chip_close", &v2.chip_close) &&
           sym(h, "gpiod_is_gpiochip_device", &v2.is_gpiochip_device) &&
           sym(h, "gpiod_chip_get_info", &v2.chip_get_info) &&
           sym(h, "gpiod_chip_info_get_label", &v2.chip_info_get_label) &&
           sym(h, "gpiod_chip_info_free", &v2.chip_info_free) &&
           sym(h, "gpiod_line_settings_new", &v2.settings_new) &&
           sym(h, "gpiod_line_settings_free", &v2.settings_free) &&
           sym(h, "gpiod_line_settings_set_direction", &v2.settings_set_direction) &&
           sym(h, "gpiod_line_settings_set_output_value", &v2.settings_set_output_value) &&
           sym(h, "gpiod_line_config_new", &v2.line_config_new) &&
           sym(h, "gpiod_line_config_free", &v2.line_config_free) &&
           sym(h, "gpiod_line_config_add_line_settings", &v2.line_config_add_line_settings) &&
           sym(h, "gpiod_request_config_new", &v2.request_config_new) &&
           sym(h, "gpiod_request_config_free", &v2.request_config_free) &&
           sym(h, "gpiod_request_config_set_consumer", &v2.request_config_set_consumer) &&
           sym(h, "gpiod_chip_request_lines", &v2.chip_request_lines) &&
           sym(h, "gpiod_line_request_set_value", &v2.request_set_value) &&
           sym(h, "gpiod_line_request_release", &v2.request_release);
}

static int load_v1(void *h)
{
    return sym(h, "gpiod_chip_open_lookup", &v1.chip_open_lookup) &&
           sym(h, "gpiod_chip_close", &v1.chip_close) &&
           sym(h, "gpiod_chip_get_line", &v1.chip_get_line) &&
           sym(h, "gpiod_line_request_output", &v1.line_request_output) &&
           sym(h, "gpiod_line_set_value", &v1.line_set_value) &&
           sym(h, "gpiod_line_release", &v1.line_release);
}

/* Request, set and release a line with one API. */
typedef struct gpio_api {
    const char *soname;
    int (*load)(void *h); /* every function of the API found: 1 */
    int (*request)(mbfb_gpio_t *g, const char *chip, unsigned int offset, int value);
    int (*set)(mbfb_gpio_t *g, int value);
    void (*release)(mbfb_gpio_t *g);
} gpio_api_t;

/* v2: the chip named by descr: a path; a number N (/dev/gpiochipN); a name under /dev that
 * is a GPIO chip; else the chip whose label is descr (as libgpiod 1's lookup finds them). */
static struct gpiod_chip *v2_open_lookup(const char *descr)
{
    char path[300];
    const char *p;
    struct gpiod_chip *chip = NULL;
    DIR *dir;
    struct dirent *e;

    if (strchr(descr, '/') != NULL)
        return v2.chip_open(descr);
    for (p = descr; isdigit((unsigned char)*p); p++) {
    }
    if (*p == 0) {
        snprintf(path, sizeof path, GPIO_DEV_DIR "/gpiochip%s", descr);
        return v2.chip_open(path);
    }
    snprintf(path, sizeof path, GPIO_DEV_DIR "/%s", descr);
    if (v2.is_gpiochip_device(path))
        return v2.chip_open(path);
    if ((dir = opendir(GPIO_DEV_DIR)) == NULL)
        return NULL;
    while (chip == NULL && (e = readdir(dir)) != NULL) {
        struct gpiod_chip_info *info;
        snprintf(path, sizeof path, GPIO_DEV_DIR "/%s", e->d_name);
        if (strncmp(e->d_name, "gpiochip", 8) != 0 || !v2.is_gpiochip_device(path) ||
            (chip = v2.chip_open(path)) == NULL)
            continue;
        info = v2.chip_get_info(chip);
        if (info == NULL || strcmp(v2.chip_info_get_label(info), descr) != 0) {
            v2.chip_close(chip);
            chip = NULL;
        }
        if (info != NULL)
            v2.chip_info_free(info);
    }
    closedir(dir);
    if (chip == NULL)
        errno = ENOENT;
    return chip;
}

static int v2_request(mbfb_gpio_t *g, const char *descr, unsigned int offset, int value)
{
    struct gpiod_chip *chip = v2_open_lookup(descr);
    struct gpiod_line_settings *s = NULL;
    struct gpiod_line_config *lc = NULL;
    struct gpiod_request_config *rc = NULL;

    if (chip != NULL && (s = v2.settings_new()) != NULL &&
        (lc = v2.line_config_new()) != NULL && (rc = v2.request_config_new()) != NULL &&
        v2.settings_set_direction(s, GPIOD2_LINE_DIRECTION_OUTPUT) == 0 &&
        v2.settings_set_output_value(s, value ? GPIOD2_LINE_VALUE_ACTIVE
                                              : GPIOD2_LINE_VALUE_INACTIVE) == 0 &&
        v2.line_config_add_line_settings(lc, &offset, 1, s) == 0) {
        v2.request_config_set_consumer(rc, GPIO_CONSUMER);
        g->request = v2.chip_request_lines(chip, rc, lc);
        g->offset = offset;
    }
    if (rc != NULL)
        v2.request_config_free(rc);
    if (lc != NULL)
        v2.line_config_free(lc);
    if (s != NULL)
        v2.settings_free(s);
    if (chip != NULL)
        v2.chip_close(chip); /* the request keeps its own file descriptor */
    return g->request != NULL ? 0 : -1;
}

static int v2_set(mbfb_gpio_t *g, int value)
{
    return v2.request_set_value(g->request, g->offset,
                                value ? GPIOD2_LINE_VALUE_ACTIVE : GPIOD2_LINE_VALUE_INACTIVE);
}

static void v2_release(mbfb_gpio_t *g)
{
    v2.request_release(g->request);
}

static int v1_request(mbfb_gpio_t *g, const char *descr, unsigned int offset, int value)
{
    if ((g->chip = v1.chip_open_lookup(descr)) == NULL)
        return -1;
    if ((g->line = v1.chip_get_line(g->chip, offset)) == NULL ||
        v1.line_request_output(g->line, GPIO_CONSUMER, value) != 0) {
        v1.chip_close(g->chip);
        return -1;
    }
    return 0;
}

static int v1_set(mbfb_gpio_t *g, int value)
{
    return v1.line_set_value(g->line, value);
}

static void v1_release(mbfb_gpio_t *g)
{
    v1.line_release(g->line);
    v1.chip_close(g->chip);
}

/* in the order tried */
static const gpio_api_t apis[] = {
    {"libgpiod.so.3", load_v2, v2_request, v2_set, v2_release},
    {"libgpiod.so.2", load_v1, v1_request, v1_set, v1_release},
};
#define N_APIS (sizeof apis / sizeof apis[0])

static const gpio_api_t *api; /* the one loaded; NULL: none */
static pthread_once_t api_once = PTHREAD_ONCE_INIT;

/* Find the library: one already loaded first, then each installed one in order. */
static void api_load(void)
{
    static const int flags[2] = {RTLD_NOW | RTLD_LOCAL | RTLD_NOLOAD, RTLD_NOW | RTLD_LOCAL};
    for (int pass = 0; pass < 2; pass++)
        for (size_t i = 0; i < N_APIS; i++) {
            void *h = dlopen(apis[i].soname, flags[pass]);
            if (h == NULL)
                continue;
            if (apis[i].load(h)) {
                api = &apis[i];
                return;
            }
            dlclose(h);
        }
}

mbfb_gpio_t *mbfb_gpio_open(const char *chip, unsigned int offset, int value)
{
    mbfb_gpio_t *g;

    pthread_once(&api_once, api_load);
    if (api == NULL || chip == NULL || (g = (mbfb_gpio_t *)calloc(1, sizeof *g)) == NULL)
        return NULL;
    if (api->request(g, chip, offset, value) != 0) {
        free(g);
        return NULL;
    }
    return g;
}

int mbfb_gpio_set(mbfb_gpio_t *g, int value)
{
    return api->set(g, value != 0) == 0 ? 0 : -1;
}

void mbfb_gpio_close(mbfb_gpio_t *g)
{
    if (g == NULL)
        return;
    api->release(g);
    free(g);
}
