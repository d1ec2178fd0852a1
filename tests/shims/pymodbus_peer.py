"""A Modbus slave from pymodbus (a peer we did not write), for test_pymodbus.c and
test_rtutcp.c.

usage: pymodbus_peer.py PORT rtu|ascii     serial server on PORT; prints READY
       pymodbus_peer.py rtu-tcp            RTU framer on a TCP server at 127.0.0.1, any free
                                           port (RTU over TCP); prints READY PORT
Slave 1: holding register at PDU address a = 0x3001 + a, input register = 0x4001 + a
(pymodbus's sequential block is 1-based), 100 of each; other addresses give
exception 2. Serves until killed.
"""
import asyncio
import sys

from pymodbus import FramerType
from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server import ModbusTcpServer, StartSerialServer

hr = ModbusSequentialDataBlock(0, [0x3000 + i for i in range(101)])
ir = ModbusSequentialDataBlock(0, [0x4000 + i for i in range(101)])
ctx = ModbusServerContext(slaves={1: ModbusSlaveContext(hr=hr, ir=ir)}, single=False)


async def rtu_over_tcp():
    """pymodbus's RTU framer on a TCP server: what a transparent gateway carries."""
    server = ModbusTcpServer(ctx, framer=FramerType.RTU, address=("127.0.0.1", 0))
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
