/*
 * fuzz_recv.c - the backends' receive paths on fuzzed line bytes: the ASCII decoder
 * (written in c_shims), and RTU, RTU-without-CRC and TCP framing through libmodbus's
 * modbus_receive_confirmation() (mbfb_backend_lm.c), each followed by mbfb_check_reply()
 * as the worker does. The line is a socketpair whose peer end holds the fuzzed bytes and
 * is then shut down (end of file), so every call returns at once.
 *
 * Input: 1 framing byte (RTU, ASCII, NOCRC, TCP), 7 header bytes (fuzz_common.h: the
 * request), then the bytes on the line.
 * Invariants: recv returns a frame length 2..max, or a negative documented error; a frame
 * it returns is what check_reply then judges; nothing outside the buffers is touched.
 */
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "fuzz_common.h"

static mbfb_bus_t bus; /* only the fields a backend's recv reads: be, be_priv, fd, timing */
static modbus_t *rtu_ctx, *tcp_ctx;

static void setup(void)
{
    if (rtu_ctx != NULL)
        return;
    /* contexts are never connected: the fuzzed socket is set as their file descriptor */
    rtu_ctx = modbus_new_rtu("/dev/null", 115200, 'N', 8, 1);
    tcp_ctx = modbus_new_tcp("127.0.0.1", 1502);
    if (rtu_ctx == NULL || tcp_ctx == NULL)
        abort();
    modbus_set_error_recovery(rtu_ctx, MODBUS_ERROR_RECOVERY_NONE);
    modbus_set_error_recovery(tcp_ctx, MODBUS_ERROR_RECOVERY_NONE);
    modbus_set_byte_timeout(rtu_ctx, 0, 2000);
    modbus_set_byte_timeout(tcp_ctx, 0, 2000);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const int framings[4] = {MBFB_FRAMING_RTU, MBFB_FRAMING_ASCII,
                                    MBFB_FRAMING_RTU_NOCRC, MBFB_FRAMING_TCP};
    static const mbfb_backend_t *const backends[4] = {
        &mbfb_backend_rtu, &mbfb_backend_ascii, &mbfb_backend_nocrc, &mbfb_backend_tcp};
    fz_t f = {data, size};
    fz_req_t r;
    uint8_t req[MBFB_FRAME_MAX], frame[MBFB_FRAME_MAX];
    int sel, sv[2], rc, max;

    setup();
    if (size < 8 || size > 8 + 4096)
        return 0;
    sel = fz_u8(&f) & 3;
    max = (int)sizeof frame - (fz_u8(&f) & 3); /* also a little smaller than a frame */
    f.p--, f.n++;                               /* (that byte is the slave id as well) */
    if (fz_request(&f, &r, req) == 0)
        return 0;
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, sv) != 0)
        abort();
    if (f.n > 0 && write(sv[1], f.p, f.n) != (ssize_t)f.n)
        abort();
    shutdown(sv[1], SHUT_WR);

    memset(&bus, 0, sizeof bus);
    bus.cfg.framing = framings[sel];
    bus.cfg.baud = 115200;
    bus.be = backends[sel];
    bus.fd = sv[0];
    mbfb_timing_init(&bus.timing, 115200, 'N', 8, 1);
    if (sel == 0 || sel == 2) { /* the lm backend's state: its libmodbus context */
        bus.be_priv = rtu_ctx;
        modbus_set_socket(rtu_ctx, sv[0]);
    } else if (sel == 3) {
        bus.be_priv = tcp_ctx;
        modbus_set_socket(tcp_ctx, sv[0]);
    }
    rc = bus.be->recv(&bus, req, frame, max, 2000);
    if (rc >= 0) {
        FZ_ASSERT(rc >= 2 && rc <= max);
        FZ_ASSERT(fz_known_result(mbfb_check_reply(req, frame, rc)));
    } else {
        FZ_ASSERT(rc == -MBFB_E_TIMEOUT || rc == -MBFB_E_CRC || rc == -MBFB_E_BADREPLY ||
                  rc == -MBFB_E_PORTLOST);
    }
    /* the silence before a request reads and discards whatever is left */
    if (sel != 3)
        FZ_ASSERT(mbfb_serial_quiet(&bus, 1000, 5000) >= -MBFB_E_PORTLOST);
    if (bus.be_priv != NULL)
        modbus_set_socket((modbus_t *)bus.be_priv, -1);
    close(sv[0]);
    close(sv[1]);
    return 0;
}
