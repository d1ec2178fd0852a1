"""RTU over TCP on 127.0.0.1: what a transparent Ethernet-to-RS-485 gateway shows its client.
RTU frames with their CRC on a TCP stream, replies (late ones included) forwarded as they come.

A stream has no t3.5: a request is framed by its expected length (function code and byte
count, frames.rtu_request_length); a partial frame is dropped after PARTIAL_S of silence and
bytes that start no known request are dropped as garbage, as the device on the gateway's line
would ignore them. Like a gateway in TCP-server mode, what the line carries goes to every open
connection: a late reply reaches a master that has connected again meanwhile.

With --pace the gateway's RS-485 line is timed at --baud: one frame at a time, a request's
characters, then the device's turnaround (1..10 ms, seeded, as ptyline's) and the reply's
characters, and only then the reply goes on the stream, whole, as a gateway forwards it."""
from __future__ import annotations

import asyncio
import random

from . import frames
from .tcp import TcpLine

PARTIAL_S = 0.5     # a request cut short is dropped after this much silence


class RtuTcpLine(TcpLine):
    """A gateway on 127.0.0.1: each connection is a byte stream of RTU frames (CRC checked)."""

    def __init__(self, bus, host: str, port: int, pace: bool = False, seed: int = 0):
        super().__init__(bus, host, port)
        self.pace = pace
        self.rng = random.Random(f"{seed}:turnaround")
        self.line_free = 0.0            # --pace: when the gateway's line is silent again

    def _line_delay(self, request: bytes, reply: bytes) -> float:
        """--pace: seconds from now until the reply has crossed the gateway's line."""
        loop = asyncio.get_running_loop()
        ct = self.bus.line.char_time
        start = max(loop.time(), self.line_free)
        done = start + len(request) * ct + self.rng.uniform(0.001, 0.010) + len(reply) * ct
        self.line_free = done
        return done - loop.time()

    async def start(self) -> str:
        await super().start()
        return f"RTU-TCP {self.host}:{self.port}"

    def line_stats(self) -> dict:
        return {"available": False, "why": "the gateway's RS-485 line is not simulated"}

    async def _client(self, reader, writer):
        if self.server is None:             # accepted just before a reopen_port closed it
            writer.close()
            return
        self.writers.add(writer)
        buf = bytearray()
        try:
            while True:
                try:
                    data = await asyncio.wait_for(reader.read(512), PARTIAL_S if buf else None)
                except asyncio.TimeoutError:
                    self._garbage(bytes(buf))       # a partial frame: silence ended it
                    buf.clear()
                    continue
                if not data:
                    break
                buf += data
                self._frames(buf, writer)
        except ConnectionError:
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    def _garbage(self, data: bytes):
        self.bus.record("rx", data, "garbage")
        self.bus.bad_frame()

    def _frames(self, buf: bytearray, writer):
        """Take every whole request off the front of buf and answer it."""
        while buf:
            need = frames.rtu_request_length(bytes(buf))
            if need is None:
                if not frames.rtu_length_pending(bytes(buf)):
                    self._garbage(bytes(buf))       # no request starts like this
                    buf.clear()
                return
            if len(buf) < need:
                return
            frame = bytes(buf[:need])
            del buf[:need]
            self._frame(frame, writer)

    def _frame(self, frame: bytes, writer):
        try:
            addr, pdu = frames.decode_rtu(frame)
        except frames.BadFrame as err:
            self.bus.record("rx", frame, str(err))
            self.bus.bad_frame()
            return
        self.bus.record("rx", frame)
        reply = self.bus.request(addr, pdu, None, "rtu")   # the gateway's line is set like the line
        if reply is None:
            return
        out = frames.encode_rtu(reply.addr, reply.pdu)
        delay, info = (self._line_delay(frame, out) if self.pace else 0.0), ""
        if reply.fault is not None:
            out, extra = reply.queue.shape(reply.fault, out, "rtu",
                                           lambda a: frames.encode_rtu(a, reply.pdu),
                                           lambda f: frames.corrupt_check("rtu", f))
            delay += extra
            info = reply.fault.kind
        if out is None:
            self.bus.record("tx", b"", "drop")
            return
        asyncio.ensure_future(self._send(writer, out, delay, info, reply.sent))

    async def _send(self, writer, data, delay, info, sent):
        """After `delay`: the reply onto the line, i.e. to every connection still open."""
        try:
            if delay:
                await asyncio.sleep(delay)
            open_now = [w for w in self.writers if not w.is_closing()]
            if open_now:
                self.bus.record("tx", data, info)
            for w in open_now:
                w.write(data)
        finally:
            sent()                      # the device is free again (late replies: busy till now)
