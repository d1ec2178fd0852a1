"""Modbus/TCP transport on 127.0.0.1 (MBAP header handled by hand: 7 bytes, see transport.py
for why the simulator does not use pymodbus's server)."""
from __future__ import annotations

import asyncio
import struct

from . import frames
from .regmap import ANY_LINE


class TcpLine:
    """Modbus/TCP server on 127.0.0.1: MBAP unit id = slave address (MBAP by hand: 7 bytes)."""

    def __init__(self, bus, host: str, port: int):
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError("the simulator listens on 127.0.0.1 only")
        self.bus, self.host, self.port = bus, host, port
        self.server = None
        self.writers = set()
        self.counters = {}

    def line_stats(self) -> dict:
        return {"available": False, "why": "no RS-485 line on Modbus/TCP"}

    async def start(self) -> str:
        self.server = await asyncio.start_server(self._client, self.host, self.port)
        self.port = self.server.sockets[0].getsockname()[1]
        return f"TCP {self.host}:{self.port}"

    def close(self, remove_link: bool = True):
        if self.server:
            self.server.close()
            self.server = None
        for writer in list(self.writers):
            writer.close()
        self.writers.clear()

    async def reopen(self, down_ms: float) -> str:
        self.close()
        await asyncio.sleep(down_ms / 1000.0)
        await self.start()
        return f"{self.host}:{self.port}"

    async def _client(self, reader, writer):
        self.writers.add(writer)
        try:
            while True:
                head = await reader.readexactly(7)
                tid, proto, length, unit = struct.unpack(">HHHB", head)
                if length < 2 or length > 254:
                    self.bus.record("rx", head, "bad MBAP length")
                    break
                pdu = await reader.readexactly(length - 1)
                if proto != 0:
                    self.bus.record("rx", head + pdu, "bad protocol id")
                    continue
                self.bus.record("rx", head + pdu)
                reply = self.bus.request(unit, pdu, ANY_LINE)
                if reply is None:
                    continue
                out, delay, info = frames.mbap(tid, reply.addr, reply.pdu), 0.0, ""
                if reply.fault is not None:
                    out, delay = reply.queue.shape(reply.fault, out, "tcp",
                                             lambda a: frames.mbap(tid, a, reply.pdu),
                                             lambda f: f)
                    info = reply.fault.kind
                if out is None:
                    self.bus.record("tx", b"", "drop")
                    continue
                asyncio.ensure_future(self._send(writer, out, delay, info, reply.sent))
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    async def _send(self, writer, data, delay, info, sent):
        try:
            if delay:
                await asyncio.sleep(delay)
            if writer.is_closing():
                return
            self.bus.record("tx", data, info)
            writer.write(data)
        finally:
            sent()                      # the device is free again (late replies: busy till now)
