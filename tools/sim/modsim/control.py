"""Control protocol (docs/contracts.md section 3): newline-delimited JSON over a Unix socket,
one reply line per request. Extensions are listed in ../README.md."""
from __future__ import annotations

import asyncio
import json
import os

from .faults import KINDS


class Control:
    """Executes control requests against the running simulator (also used for --faults)."""

    def __init__(self, app):
        self.app = app
        self.server = None
        self.path = None

    async def start(self, path: str):
        self.path = os.path.abspath(path)
        if os.path.exists(self.path):
            os.unlink(self.path)
        self.server = await asyncio.start_unix_server(self._client, self.path)

    def close(self):
        if self.server:
            self.server.close()
        if self.path and os.path.exists(self.path):
            os.unlink(self.path)

    async def _client(self, reader, writer):
        try:
            while line := await reader.readline():
                if not line.strip():
                    continue
                try:
                    req = json.loads(line)
                    if not isinstance(req, dict):
                        raise ValueError("a request is a JSON object")
                    reply = await self.execute(req)
                except Exception as err:  # pylint: disable=broad-except  (reported to caller)
                    reply = {"ok": False, "error": f"{type(err).__name__}: {err}"}
                writer.write((json.dumps(reply) + "\n").encode())
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            writer.close()

    async def execute(self, req: dict) -> dict:
        op = req.get("op")
        handler = getattr(self, f"op_{op}", None) if isinstance(op, str) else None
        if handler is None:
            raise ValueError(f"unknown op {op!r}")
        result = handler(req)
        if asyncio.iscoroutine(result):
            result = await result
        return {"ok": True, **(result or {})}

    def _dev(self, req):
        if "addr" not in req:
            raise ValueError("'addr' is required")
        return self.app.bus.device_by_key(int(req["addr"]))

    # ----- the contract's ops -----
    def op_get(self, req):
        dev = self._dev(req)
        reg = dev.lookup(req["reg"])
        raw = dev.get_raw(reg)
        out = {"raw": raw, "reg": reg.name, "words": dev.read_words(reg.addr, reg.words)}
        if reg.scale != "raw" or reg.codes:
            out["eng"] = dev.to_eng(reg, raw)
        return out

    def op_set(self, req):
        dev = self._dev(req)
        reg = dev.lookup(req["reg"])
        if "raw" in req:
            raw = int(req["raw"])
        elif "eng" in req:
            raw = dev.from_eng(reg, req["eng"])
        else:
            raise ValueError("'raw' or 'eng' is required")
        dev.set_raw(reg, raw)
        return {"raw": dev.get_raw(reg)}

    def op_fault(self, req):
        kind = req.get("kind")
        if kind == "bad_crc" and self.app.transport_kind == "tcp":
            raise ValueError("bad_crc has no meaning on Modbus/TCP (no CRC)")
        dev = self._dev(req)
        dev.fault_queue.add(req)
        return {"pending": len(dev.fault_queue.pending), "kinds": list(KINDS)}

    def op_offline(self, req):
        dev = self._dev(req)
        dev.offline = bool(req.get("on", True))
        return {"offline": dev.offline}

    async def op_power_cycle(self, req):
        dev = self._dev(req)
        down = float(req.get("down_ms", 0))
        dev.offline = True
        if down > 0:
            await asyncio.sleep(down / 1000.0)
        dev.power_cycle()
        dev.offline = False
        return {}

    async def op_reopen_port(self, req):
        port = await self.app.transport.reopen(float(req.get("down_ms", 500)))
        return {"port": port}

    def op_stats(self, req):
        out = self.app.bus.stats()
        out["line"].update(self.app.transport.counters)
        return out

    def op_log(self, req):
        log = list(self.app.bus.log)
        if req.get("clear"):
            self.app.bus.log.clear()
        return {"frames": log}

    # ----- extensions -----
    def op_ping(self, req):
        return {"pid": os.getpid(), "port": self.app.ready_line}

    def op_plant(self, req):
        """Thermal process of a controller: ambient, gain, tau, temp, hold."""
        dev = self._dev(req)
        if not hasattr(dev, "loop"):
            raise ValueError(f"{dev.KIND} has no thermal process")
        return {"plant": dev.loop.plant.configure(**req)}

    def op_devices(self, req):
        return {"devices": [{"kind": d.KIND, "addr": d.addr} for d in self.app.bus.devices]}

    def op_line_stats(self, req):
        return self.app.line_stats()
