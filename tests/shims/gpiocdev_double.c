/*
 * gpiocdev_double.c - the kernel's GPIO character device, as a test double under the real
 * libgpiod (linked into linedouble.c's build with LINEDOUBLE_GPIOD=0, LD_PRELOAD before
 * Debian's libgpiod 1 or a libgpiod 2 built from source): there is no GPIO chip on this
 * machine, and no Debian amd64 kernel builds gpio-sim, so this stands in for the kernel side
 * of the uAPI that libgpiod speaks, and the real library runs end to end above it.
 *
 * Chip $LINEDOUBLE_GPIOCHIP ("gpiochipN") exists at /dev/gpiochipN with 32 lines and label
 * "linedouble"; it answers what libgpiod checks and asks:
 *   lstat / stat of the path: a character device (major GPIOCDEV_MAJOR, minor N);
 *   realpath of /sys/dev/char/MAJ:N/subsystem: /sys/bus/gpio (libgpiod 2's check);
 *   access / open of /sys/bus/gpio/devices/gpiochipN/dev: "MAJ:N\n" (libgpiod 1's check);
 *   the listing of /dev (opendir/readdir, scandir): the chip's name among the entries, for a
 *   lookup by label;
 *   open of the path: a chip descriptor; its ioctls GPIO_GET_CHIPINFO, GPIO_GET_LINEINFO
 *   (uAPI v1), GPIO_GET_LINEHANDLE (v1 request), GPIO_V2_GET_LINE (v2 request), each
 *   request a descriptor of its own taking GPIOHANDLE_SET_LINE_VALUES (v1) or
 *   GPIO_V2_LINE_SET_VALUES (v2); close releases it.
 * It logs, like linedouble.c and in its log:
 *   T gpioreq U L V A  a line requested as an output by consumer U: offset L, initial level V,
 *                      through uAPI A (uapi-v1 or uapi-v2)
 *   T gpio V           the requested line driven to V
 *   T misuse WHAT      anything else asked of it (an input, active-low or biased request, more
 *                      than one line, a line taken twice, a value for another line); the call
 *                      fails as the kernel's would (EINVAL / EBUSY).
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/gpio.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include "linedouble.h"

#define GPIOCDEV_MAJOR 511 /* no real device here has it */
#define GPIOCDEV_LINES 32
#define GPIOCDEV_LABEL "linedouble"
#define MAX_FDS 1024

enum { FD_NONE, FD_CHIP, FD_REQ_V1, FD_REQ_V2 };
static unsigned char fd_kind[MAX_FDS];
static unsigned fd_offset[MAX_FDS];     /* a request's line */
static int line_taken[GPIOCDEV_LINES];

static char chip_path[64];   /* /dev/gpiochipN, empty when $LINEDOUBLE_GPIOCHIP is not one */
static char chip_name[32];   /* gpiochipN */
static char sysfs_dev[96];   /* /sys/bus/gpio/devices/gpiochipN/dev */
static char sysfs_subsys[64]; /* /sys/dev/char/MAJ:N/subsystem */
static unsigned chip_minor;

static int (*real_lstat)(const char *, struct stat *);
static int (*real_stat)(const char *, struct stat *);
static char *(*real_realpath)(const char *, char *);
static int (*real_access)(const char *, int);
static int (*real_open)(const char *, int, ...);
static int (*real_close)(int);
static DIR *(*real_opendir)(const char *);
static struct dirent *(*real_readdir)(DIR *);
static int (*real_closedir)(DIR *);
static int (*real_scandir)(const char *, struct dirent ***, int (*)(const struct dirent *),
                           int (*)(const struct dirent **, const struct dirent **));

static void cdev_init(void)
{
    static int done;
    const char *c;
    if (done)
        return;
    real_lstat = (int (*)(const char *, struct stat *))dlsym(RTLD_NEXT, "lstat");
    real_stat = (int (*)(const char *, struct stat *))dlsym(RTLD_NEXT, "stat");
    real_realpath = (char *(*)(const char *, char *))dlsym(RTLD_NEXT, "realpath");
    real_access = (int (*)(const char *, int))dlsym(RTLD_NEXT, "access");
    real_open = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open");
    real_close = (int (*)(int))dlsym(RTLD_NEXT, "close");
    real_opendir = (DIR * (*)(const char *)) dlsym(RTLD_NEXT, "opendir");
    real_readdir = (struct dirent * (*)(DIR *)) dlsym(RTLD_NEXT, "readdir");
    real_closedir = (int (*)(DIR *))dlsym(RTLD_NEXT, "closedir");
    real_scandir = (int (*)(const char *, struct dirent ***, int (*)(const struct dirent *),
                            int (*)(const struct dirent **, const struct dirent **)))
        dlsym(RTLD_NEXT, "scandir");
    c = getenv("LINEDOUBLE_GPIOCHIP");
    if (c != NULL && sscanf(c, "gpiochip%u", &chip_minor) == 1 && strlen(c) < sizeof chip_name) {
        snprintf(chip_name, sizeof chip_name, "%s", c);
        snprintf(chip_path, sizeof chip_path, "/dev/%s", c);
        snprintf(sysfs_dev, sizeof sysfs_dev, "/sys/bus/gpio/devices/%s/dev", c);
        snprintf(sysfs_subsys, sizeof sysfs_subsys, "/sys/dev/char/%u:%u/subsystem",
                 GPIOCDEV_MAJOR, chip_minor);
    }
    done = 1;
}

static int is(const char *path, const char *ours)
{
    cdev_init();
    return path != NULL && ours[0] != 0 && strcmp(path, ours) == 0;
}

static int misuse(const char *what, int err)
{
    ld_record("misuse %s", what);
    errno = err;
    return -1;
}

static int chardev_stat(struct stat *st)
{
    memset(st, 0, sizeof *st);
    st->st_mode = S_IFCHR | 0600;
    st->st_rdev = makedev(GPIOCDEV_MAJOR, chip_minor);
    return 0;
}

int lstat(const char *path, struct stat *st)
{
    if (is(path, chip_path))
        return chardev_stat(st);
    return real_lstat(path, st);
}

int stat(const char *path, struct stat *st)
{
    if (is(path, chip_path))
        return chardev_stat(st);
    return real_stat(path, st);
}

char *realpath(const char *path, char *resolved)
{
    static const char gpio_bus[] = "/sys/bus/gpio";
    if (is(path, sysfs_subsys)) {
        if (resolved == NULL)
            return strdup(gpio_bus);
        return strcpy(resolved, gpio_bus);
    }
    return real_realpath(path, resolved);
}

int access(const char *path, int mode)
{
    if (is(path, sysfs_dev))
        return 0;
    return real_access(path, mode);
}

/* ---- /dev's listing, with the chip in it ---- */
static DIR *dev_dir;       /* the one open listing of /dev that gets the chip */
static int dev_dir_listed; /* the chip's entry given */

static int is_dev(const char *path)
{
    cdev_init();
    return chip_name[0] != 0 && path != NULL &&
           (strcmp(path, "/dev") == 0 || strcmp(path, "/dev/") == 0);
}

static void chip_entry(struct dirent *e)
{
    memset(e, 0, sizeof *e);
    e->d_type = DT_CHR;
    e->d_reclen = sizeof *e;
    snprintf(e->d_name, sizeof e->d_name, "%s", chip_name);
}

DIR *opendir(const char *path)
{
    DIR *d;
    cdev_init();
    d = real_opendir(path);
    if (d != NULL && is_dev(path)) {
        dev_dir = d;
        dev_dir_listed = 0;
    }
    return d;
}

struct dirent *readdir(DIR *d)
{
    static struct dirent chip;
    struct dirent *e;
    cdev_init();
    e = real_readdir(d);
    if (e == NULL && d == dev_dir && !dev_dir_listed) {
        dev_dir_listed = 1;
        chip_entry(&chip);
        return &chip;
    }
    return e;
}

int closedir(DIR *d)
{
    cdev_init();
    if (d == dev_dir)
        dev_dir = NULL;
    return real_closedir(d);
}

int scandir(const char *path, struct dirent ***list, int (*filter)(const struct dirent *),
            int (*cmp)(const struct dirent **, const struct dirent **))
{
    int n;
    struct dirent *e, **more;
    cdev_init();
    n = real_scandir(path, list, filter, cmp);
    if (n < 0 || !is_dev(path) || (e = (struct dirent *)malloc(sizeof *e)) == NULL)
        return n;
    chip_entry(e);
    if ((filter != NULL && !filter(e)) ||
        (more = (struct dirent **)realloc(*list, (size_t)(n + 1) * sizeof *more)) == NULL) {
        free(e);
        return n;
    }
    more[n++] = e;
    *list = more;
    if (cmp != NULL)
        qsort(more, (size_t)n, sizeof *more, (int (*)(const void *, const void *))cmp);
    return n;
}

/* a descriptor of kind k (a real one, on /dev/null, so that the number is ours) */
static int new_fd(int k, unsigned offset)
{
    int fd = real_open("/dev/null", O_RDWR | O_CLOEXEC);
    if (fd < 0 || fd >= MAX_FDS) {
        if (fd >= 0)
            real_close(fd);
        errno = EMFILE;
        return -1;
    }
    fd_kind[fd] = (unsigned char)k;
    fd_offset[fd] = offset;
    return fd;
}

int open(const char *path, int flags, ...)
{
    va_list ap;
    int mode;
    va_start(ap, flags);
    mode = (flags & (O_CREAT | O_TMPFILE)) ? va_arg(ap, int) : 0;
    va_end(ap);
    if (is(path, chip_path))
        return new_fd(FD_CHIP, 0);
    if (is(path, sysfs_dev)) {
        char text[32];
        int fd = memfd_create("gpiochip-dev", MFD_CLOEXEC);
        int n = snprintf(text, sizeof text, "%u:%u\n", GPIOCDEV_MAJOR, chip_minor);
        if (fd >= 0 && (pwrite(fd, text, (size_t)n, 0) != n)) {
            real_close(fd);
            return -1;
        }
        return fd;
    }
    return real_open(path, flags, mode);
}

int close(int fd)
{
    cdev_init();
    if (fd >= 0 && fd < MAX_FDS && fd_kind[fd] != FD_NONE) {
        if (fd_kind[fd] != FD_CHIP)
            line_taken[fd_offset[fd]] = 0;
        fd_kind[fd] = FD_NONE;
    }
    return real_close(fd);
}

/* One output line, not active-low, no bias or drive flags, at a free offset. */
static int take_line(unsigned n, unsigned offset, int output_only)
{
    if (n != 1)
        return misuse("lines", EINVAL);
    if (!output_only)
        return misuse("flags", EINVAL);
    if (offset >= GPIOCDEV_LINES) {
        errno = EINVAL;
        return -1;
    }
    if (line_taken[offset])
        return misuse("busy", EBUSY);
    line_taken[offset] = 1;
    return 0;
}

static int v2_request(struct gpio_v2_line_request *r)
{
    unsigned long long flags = r->config.flags;
    int value = 0, fd;
    for (unsigned i = 0; i < r->config.num_attrs && i < GPIO_V2_LINE_NUM_ATTRS_MAX; i++) {
        const struct gpio_v2_line_config_attribute *a = &r->config.attrs[i];
        if (!(a->mask & 1))
            continue;
        if (a->attr.id == GPIO_V2_LINE_ATTR_ID_FLAGS)
            flags = a->attr.flags;
        else if (a->attr.id == GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES)
            value = (int)(a->attr.values & 1);
    }
    if (take_line(r->num_lines, r->offsets[0], flags == GPIO_V2_LINE_FLAG_OUTPUT) != 0)
        return -1;
    if ((fd = new_fd(FD_REQ_V2, r->offsets[0])) < 0) {
        line_taken[r->offsets[0]] = 0;
        return -1;
    }
    r->fd = fd;
    ld_record("gpioreq %.32s %u %d uapi-v2", r->consumer, r->offsets[0], value);
    return 0;
}

static int v1_request(struct gpiohandle_request *r)
{
    int fd;
    if (take_line(r->lines, r->lineoffsets[0], r->flags == GPIOHANDLE_REQUEST_OUTPUT) != 0)
        return -1;
    if ((fd = new_fd(FD_REQ_V1, r->lineoffsets[0])) < 0) {
        line_taken[r->lineoffsets[0]] = 0;
        return -1;
    }
    r->fd = fd;
    ld_record("gpioreq %.32s %u %d uapi-v1", r->consumer_label, r->lineoffsets[0],
              r->default_values[0] != 0);
    return 0;
}

int gpiocdev_ioctl(int fd, unsigned long req, void *arg, int *rc)
{
    cdev_init();
    if (fd < 0 || fd >= MAX_FDS || fd_kind[fd] == FD_NONE)
        return 0;
    *rc = 0;
    switch (fd_kind[fd] * 0x10000UL + (req & 0xffff)) {
    case FD_CHIP * 0x10000UL + (GPIO_GET_CHIPINFO_IOCTL & 0xffff): {
        struct gpiochip_info *ci = (struct gpiochip_info *)arg;
        memset(ci, 0, sizeof *ci);
        snprintf(ci->name, sizeof ci->name, "%s", chip_name);
        snprintf(ci->label, sizeof ci->label, "%s", GPIOCDEV_LABEL);
        ci->lines = GPIOCDEV_LINES;
        return 1;
    }
    case FD_CHIP * 0x10000UL + (GPIO_GET_LINEINFO_IOCTL & 0xffff): {
        struct gpioline_info *li = (struct gpioline_info *)arg;
        unsigned off = li->line_offset;
        if (off >= GPIOCDEV_LINES) {
            *rc = -1;
            errno = EINVAL;
            return 1;
        }
        memset(li, 0, sizeof *li);
        li->line_offset = off;
        li->flags = line_taken[off] ? GPIOLINE_FLAG_KERNEL | GPIOLINE_FLAG_IS_OUT : 0;
        return 1;
    }
    case FD_CHIP * 0x10000UL + (GPIO_V2_GET_LINE_IOCTL & 0xffff):
        *rc = v2_request((struct gpio_v2_line_request *)arg);
        return 1;
    case FD_CHIP * 0x10000UL + (GPIO_GET_LINEHANDLE_IOCTL & 0xffff):
        *rc = v1_request((struct gpiohandle_request *)arg);
        return 1;
    case FD_REQ_V2 * 0x10000UL + (GPIO_V2_LINE_SET_VALUES_IOCTL & 0xffff): {
        struct gpio_v2_line_values *v = (struct gpio_v2_line_values *)arg;
        if (v->mask != 1)
            *rc = misuse("set-mask", EINVAL);
        else
            ld_record("gpio %d", (int)(v->bits & 1));
        return 1;
    }
    case FD_REQ_V1 * 0x10000UL + (GPIOHANDLE_SET_LINE_VALUES_IOCTL & 0xffff):
        ld_record("gpio %d", ((struct gpiohandle_data *)arg)->values[0] != 0);
        return 1;
    default:
        *rc = misuse("ioctl", ENOTTY);
        return 1;
    }
}
