"""A Modbus slave from pymodbus (a peer we did not write), for test_pymodbus.c and
test_rtutcp.c.

usage: pymodbus_peer.py PORT rtu|ascii     serial server on PORT (a device, or socket://
                                           HOST:PORT, where it listens); prints READY
       pymodbus_peer.py rtu-tcp [mvd94 [poll]]  RTU framer on a TCP server at 127.0.0.1, any
                                           free port (RTU over TCP); prints READY PORT
Slave 1: holding register at PDU address a = 0x3001 + a, input register = 0x4001 + a
(pymodbus's sequential block is 1-based), 100 of each; coil a is ON when (a + 1) % 3 == 0,
discrete input a when (a + 1) % 5 < 2, 100 of each; other addresses give exception 2.
With `mvd94`, slave 1 holds an MV-D94's map instead (MVD94_HR: holding registers 0x00..0x21 at the factory settings with SV 123.4 at one decimal; PV 27.5 at input
register 0x1000), for a device block (tests/fb t_rtutcp_pymodbus.st). With `poll` too, slave 2
is a generic device for MB_Poll (tests/fb t_poll_pymodbus.st): POLL_COILS at coils 0..19,
POLL_INPUTS at discrete inputs 10..49, 1..10 at holding registers 0..9, POLL_IR at input
registers 100..104, coils and holding registers writable; slave 3's coil 0 ON pulls slave 2
off the line (no reply), OFF puts it back. Serves until killed.
"""
import asyncio
import sys

from pymodbus import FramerType
from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server import ModbusTcpServer, StartSerialServer

# SV SPOF PVOF A1SP A2SP A3SP PB TD CT HYST A1HY A2HY A3HY LOCK TYPE UNIT DP ACT LOLT HILT
# FILT A1FU A1MD A2FU A2MD A3FU A3MD ADDR BAUD CH01..CH04 MR (maps/mvd94.json)
MVD94_HR = [1234, 0, 0, 10, 10, 10, 100, 30, 20, 1, 1, 1, 1, 0x20, 1, 0x0C, 0x11, 0x14,
            0xF831, 9999, 0, 0x30, 0x16, 0x31, 0x16, 0x32, 0x16, 1, 0x1E, 0, 0, 3000, 0, 0]

# slave 2 of `poll` (tests/fb/poll_device.json holds the same for the simulator)
POLL_COILS = [1, 0, 1, 1, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 0]
POLL_INPUTS = [0, 1, 1, 0, 1] + [0] * 11 + [1] + [0] * 22 + [1]
POLL_IR = [11, 12, 13, 14, 65535]

if sys.argv[1:3] == ["rtu-tcp", "mvd94"]:
    hr = ModbusSequentialDataBlock(0, [0] + MVD94_HR)
    ir = ModbusSequentialDataBlock(0x1000, [0, 275])
    bits = {}
else:
    hr = ModbusSequentialDataBlock(0, [0x3000 + i for i in range(101)])
    ir = ModbusSequentialDataBlock(0, [0x4000 + i for i in range(101)])
    # bits (mbfb_test.h T_PM_COIL, T_PM_INPUT): index i of the 1-based blocks
    bits = {"co": ModbusSequentialDataBlock(0, [i % 3 == 0 for i in range(101)]),
            "di": ModbusSequentialDataBlock(0, [i % 5 < 2 for i in range(101)])}
slaves = {1: ModbusSlaveContext(hr=hr, ir=ir, **bits)}
POLL = sys.argv[3:] == ["poll"]


class PullSwitch(ModbusSequentialDataBlock):
    """Slave 3's coil 0 (`poll`): ON pulls slave 2 off the line (no reply at all: the server
    ignores missing slaves), OFF puts it back, values kept."""

    def setValues(self, address, values):
        super().setValues(address, values)
        if values[0] and 2 in ctx.slaves():
            pulled[2] = ctx[2]
            del ctx[2]
        elif not values[0] and 2 in pulled:
            ctx[2] = pulled.pop(2)


if POLL:   # each block's first element is address -1 (1-based blocks)
    slaves[2] = ModbusSlaveContext(co=ModbusSequentialDataBlock(0, [0] + POLL_COILS),
                                   di=ModbusSequentialDataBlock(10, [0] + POLL_INPUTS),
                                   hr=ModbusSequentialDataBlock(0, [0] + list(range(1, 11))),
                                   ir=ModbusSequentialDataBlock(100, [0] + POLL_IR))
    slaves[3] = ModbusSlaveContext(co=PullSwitch(0, [0, 0]))
pulled: dict = {}
ctx = ModbusServerContext(slaves=slaves, single=False)


async def rtu_over_tcp():
    """pymodbus's RTU framer on a TCP server: what a transparent gateway carries."""
    server = ModbusTcpServer(ctx, framer=FramerType.RTU, address=("127.0.0.1", 0),
                             ignore_missing_slaves=POLL)
    await server.serve_forever(background=True)
    print("READY", server.transport.sockets[0].getsockname()[1], flush=True)
    await server.serving


if sys.argv[1] == "rtu-tcp":
    asyncio.run(rtu_over_tcp())
else:
    port, framer = sys.argv[1], sys.argv[2]
    print("READY", flush=True)
    StartSerialServer(context=ctx, port=port, baudrate=9600,
                      framer=FramerType.ASCII if framer == "ascii" else FramerType.RTU)
