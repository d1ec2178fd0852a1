"""A Modbus serial slave from pymodbus (a peer we did not write), for test_pymodbus.c.

usage: pymodbus_peer.py PORT rtu|ascii
Slave 1: holding register at PDU address a = 0x3001 + a, input register = 0x4001 + a
(pymodbus's sequential block is 1-based), 100 of each; other addresses give
exception 2. Prints READY, then serves until killed.
"""
import sys

from pymodbus import FramerType
from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server import StartSerialServer

port, framer = sys.argv[1], sys.argv[2]
hr = ModbusSequentialDataBlock(0, [0x3000 + i for i in range(101)])
ir = ModbusSequentialDataBlock(0, [0x4000 + i for i in range(101)])
ctx = ModbusServerContext(slaves={1: ModbusSlaveContext(hr=hr, ir=ir)}, single=False)
print("READY", flush=True)
StartSerialServer(context=ctx, port=port, baudrate=9600,
                  framer=FramerType.ASCII if framer == "ascii" else FramerType.RTU)
