/* wp_lm.c - the plain libmodbus master of bench/wire_pace.py: modbus_read_registers (or
 * _input_registers) back to back, nothing between a reply and the next request, until
 * SIGTERM/SIGINT. Prints "ok N err M" at exit.
 *   wp_lm PORT BAUD FORMAT SLAVE FC ADDR COUNT      (FORMAT like 8N2; FC 3 or 4)
 * Built against the system's libmodbus (Debian's), as any application would use it. */
#include <errno.h>
#include <modbus.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static volatile sig_atomic_t g_stop;
static void on_stop(int s) { (void)s; g_stop = 1; }

int main(int argc, char **argv) {
    if (argc != 8 || strlen(argv[3]) != 3) {
        fprintf(stderr, "usage: wp_lm PORT BAUD FORMAT SLAVE FC ADDR COUNT\n");
        return 2;
    }
    int baud = atoi(argv[2]), slave = atoi(argv[4]), fc = atoi(argv[5]);
    int addr = atoi(argv[6]), count = atoi(argv[7]);
    const char *f = argv[3];
    if (baud <= 0 || (fc != 3 && fc != 4) || count < 1 || count > 125) {
        fprintf(stderr, "wp_lm: bad arguments\n");
        return 2;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_stop;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    modbus_t *ctx = modbus_new_rtu(argv[1], baud, f[1], f[0] - '0', f[2] - '0');
    if (!ctx || modbus_set_slave(ctx, slave) != 0 || modbus_connect(ctx) != 0) {
        fprintf(stderr, "wp_lm: %s: %s\n", argv[1], modbus_strerror(errno));
        return 1;
    }
    modbus_set_response_timeout(ctx, 0, 500000);
    uint16_t regs[125];
    long ok = 0, err = 0;
    while (!g_stop) {
        int n = fc == 3 ? modbus_read_registers(ctx, addr, count, regs)
                        : modbus_read_input_registers(ctx, addr, count, regs);
        if (n == count) ok++;
        else err++;
    }
    printf("ok %ld err %ld\n", ok, err);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
