/*
 * test_version.c - the libmodbus actually loaded is the one this flavour was built
 * against (both builds have soname libmodbus.so.5 and ld.so.cache prefers
 * /usr/local, so a wrong RPATH would silently load the other one).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <string.h>

#include <modbus.h>

#include "mbfb_test.h"

int main(void)
{
    /* modbus_enable_rpi exists only in OpenPLC's Raspberry-Pi fork */
    int fork_loaded = dlsym(RTLD_DEFAULT, "modbus_enable_rpi") != NULL;
    Dl_info info;
    const char *path = "?";

    if (dladdr((void *)&modbus_new_rtu, &info) && info.dli_fname)
        path = info.dli_fname;
    t_scenario = MBFB_FLAVOUR;
    printf("flavour %s: loaded libmodbus %u.%u.%u from %s (%s), compiled against %s\n",
           MBFB_FLAVOUR, libmodbus_version_major, libmodbus_version_minor,
           libmodbus_version_micro, path, fork_loaded ? "OpenPLC fork" : "upstream",
           LIBMODBUS_VERSION_STRING);
    CHECK_EQ(libmodbus_version_major, LIBMODBUS_VERSION_MAJOR);
    CHECK_EQ(libmodbus_version_minor, LIBMODBUS_VERSION_MINOR);
    CHECK_EQ(libmodbus_version_micro, LIBMODBUS_VERSION_MICRO);
    if (strcmp(MBFB_FLAVOUR, "lm_debian") == 0) {
        CHECK(!fork_loaded);
        CHECK(strncmp(path, "/usr/lib/", 9) == 0);
    }
    if (strcmp(MBFB_FLAVOUR, "lm_openplc") == 0) {
        CHECK(fork_loaded);
        CHECK(strncmp(path, "/usr/local/lib/", 15) == 0);
    }
    return t_done("test_version");
}
