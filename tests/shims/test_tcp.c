/*
 * test_tcp.c - Modbus TCP (a tcp:// gateway) through libmodbus, against libmodbus's own
 * server on 127.0.0.1 (a peer we did not write): reads, writes, coils and discrete inputs
 * (FC01/02/05/15 against its bit tables), exceptions, no reply,
 * a late reply (must not answer the next request: the shims reconnect), a dropped
 * connection (port lost, reopened on the next request).
 */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "mbfb_test.h"

enum { SRV_NORMAL, SRV_SILENT, SRV_LATE, SRV_DROP };
static int srv_mode; /* __atomic: set by the test, read by the server */
static pthread_mutex_t map_lock = PTHREAD_MUTEX_INITIALIZER; /* map: server vs test */
static modbus_t *srv;
static modbus_mapping_t *map;
static int listen_fd;

static void *server_main(void *arg)
{
    uint8_t q[MODBUS_TCP_MAX_ADU_LENGTH];
    (void)arg;
    for (;;) {
        int s = modbus_tcp_accept(srv, &listen_fd);
        if (s < 0)
            return NULL;
        for (;;) {
            int n = modbus_receive(srv, q);
            if (n < 0)
                break; /* client closed: accept the next connection */
            if (n == 0)
                continue;
            int mode = __atomic_exchange_n(&srv_mode, SRV_NORMAL, __ATOMIC_ACQ_REL);
            if (mode == SRV_SILENT) {
                __atomic_store_n(&srv_mode, SRV_SILENT, __ATOMIC_RELEASE);
                continue;
            }
            if (mode == SRV_DROP)
                break;
            if (mode == SRV_LATE)
                t_sleep_ms(500);
            pthread_mutex_lock(&map_lock);
            modbus_reply(srv, q, n, map);
            pthread_mutex_unlock(&map_lock);
        }
        close(s);
    }
}

int main(void)
{
    struct sockaddr_in a;
    socklen_t alen = sizeof a;
    pthread_t th;
    char port[64];
    uint16_t v[4];
    mbfb_bus_config_t c;
    mbfb_diag_t d;
    int bus, dev;

    t_scenario = "tcp";
    srv = modbus_new_tcp("127.0.0.1", 0); /* port 0: the kernel picks one */
    map = modbus_mapping_new(100, 100, 100, 100);
    listen_fd = modbus_tcp_listen(srv, 1);
    if (srv == NULL || map == NULL || listen_fd < 0 ||
        getsockname(listen_fd, (struct sockaddr *)&a, &alen) != 0) {
        perror("libmodbus server");
        return 1;
    }
    for (int i = 0; i < 100; i++)
        map->tab_registers[i] = (uint16_t)(0x2000 + i);
    map->tab_input_registers[7] = 0x0707;
    for (int i = 0; i < 37; i++) /* the application protocol's 6.1: CD 6B B2 0E 1B */
        map->tab_bits[20 + i] = (uint8_t)((0x1B0EB26BCDull >> i) & 1);
    for (int i = 0; i < 22; i++) /* 6.2: AC DB 35 */
        map->tab_input_bits[60 + i] = (uint8_t)((0x35DBACu >> i) & 1);
    pthread_create(&th, NULL, server_main, NULL);
    pthread_detach(th);

    snprintf(port, sizeof port, "tcp://127.0.0.1:%d", ntohs(a.sin_port));
    c = t_cfg(port, 0, MBFB_FRAMING_TCP, 400, 1);
    bus = mbfb_bus_open(&c);
    CHECK(bus >= 0);
    dev = mbfb_dev_open(bus, 1);
    CHECK_EQ(mbfb_dev_open(bus, 255), mbfb_dev_open(bus, 255)); /* TCP unit ids to 255 */

    CHECK_EQ(t_run(dev, 3, 10, 3, NULL, v, 4), 3);
    CHECK_EQ(v[0], 0x200A);
    CHECK_EQ(v[2], 0x200C);
    CHECK_EQ(t_run(dev, 4, 7, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 0x0707);
    v[0] = 0xABCD;
    CHECK_EQ(t_run(dev, 6, 5, 1, v, NULL, 0), 0);
    pthread_mutex_lock(&map_lock);
    CHECK_EQ(map->tab_registers[5], 0xABCD);
    pthread_mutex_unlock(&map_lock);
    v[0] = 1, v[1] = 2;
    CHECK_EQ(t_run(dev, 16, 98, 2, v, NULL, 0), 0);
    pthread_mutex_lock(&map_lock);
    CHECK_EQ(map->tab_registers[99], 2);
    pthread_mutex_unlock(&map_lock);
    CHECK_EQ(t_run(dev, 3, 99, 2, NULL, v, 2), -(MBFB_E_EXCEPTION_BASE + 2));

    /* coils and discrete inputs, packed LSB first into words */
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 20, 37, NULL, v, 4), 37);
    CHECK_EQ(v[0], 0x6BCD);
    CHECK_EQ(v[1], 0x0EB2);
    CHECK_EQ(v[2], 0x001B);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_DISCRETE, 60, 22, NULL, v, 4), 22);
    CHECK_EQ(v[0], 0xDBAC);
    CHECK_EQ(v[1], 0x0035);
    v[0] = 1;
    CHECK_EQ(t_run(dev, MBFB_FC_WRITE_COIL, 5, 1, v, NULL, 0), 0);
    v[0] = 0x01CD;
    CHECK_EQ(t_run(dev, MBFB_FC_WRITE_COILS, 80, 10, v, NULL, 0), 0);
    pthread_mutex_lock(&map_lock);
    CHECK_EQ(map->tab_bits[5], 1);
    for (int i = 0; i < 10; i++)
        CHECK_EQ(map->tab_bits[80 + i], (0x01CD >> i) & 1);
    pthread_mutex_unlock(&map_lock);
    v[0] = 0;
    int h = mbfb_post_write(dev, MBFB_FC_WRITE_COIL, 5, 1, v, MBFB_WRITE_ONCE);
    CHECK(h > 0);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 0, 16, NULL, v, 1), 16);
    CHECK_EQ(v[0] & (1 << 5), 0); /* the ONCE write, posted first, went first */
    CHECK_EQ(t_wait(h), MBFB_REQ_DONE);
    CHECK_EQ(mbfb_take(h, NULL, 0), 0);
    CHECK_EQ(t_run(dev, MBFB_FC_READ_COILS, 95, 10, NULL, v, 1), -(MBFB_E_EXCEPTION_BASE + 2));
    CHECK_EQ(t_run(dev, MBFB_FC_WRITE_COILS, 95, 10, v, NULL, 0), -(MBFB_E_EXCEPTION_BASE + 2));

    __atomic_store_n(&srv_mode, SRV_SILENT, __ATOMIC_RELEASE);
    CHECK_EQ(t_run(dev, 3, 0, 1, NULL, v, 1), -MBFB_E_TIMEOUT);
    CHECK_EQ(mbfb_dev_diag(dev, &d), 0);
    CHECK_EQ(d.timeouts, 2);
    __atomic_store_n(&srv_mode, SRV_NORMAL, __ATOMIC_RELEASE);

    mbfb_shutdown(); /* again without retries */
    c.retries = 0;
    dev = mbfb_dev_open(mbfb_bus_open(&c), 1);
    pthread_mutex_lock(&map_lock);
    map->tab_registers[1] = 0x1111;
    map->tab_registers[2] = 0x2222;
    pthread_mutex_unlock(&map_lock);
    /* the reply comes after the timeout, on the old connection */
    __atomic_store_n(&srv_mode, SRV_LATE, __ATOMIC_RELEASE);
    CHECK_EQ(t_run(dev, 3, 1, 1, NULL, v, 1), -MBFB_E_TIMEOUT);
    CHECK_EQ(t_run(dev, 3, 2, 1, NULL, v, 1), 1);
    CHECK_EQ(v[0], 0x2222);

    __atomic_store_n(&srv_mode, SRV_DROP, __ATOMIC_RELEASE); /* the gateway drops */
    CHECK_EQ(t_run(dev, 3, 2, 1, NULL, v, 1), -MBFB_E_PORTLOST);
    CHECK_EQ(t_run(dev, 3, 3, 1, NULL, v, 1), 1); /* reconnected */
    CHECK_EQ(v[0], 0x2003);
    mbfb_shutdown();
    return t_done("test_tcp");
}
