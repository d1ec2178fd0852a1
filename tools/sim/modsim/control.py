"""Control protocol (docs/contracts.md section 3): newline-delimited JSON over a Unix socket,
one reply line per request. Extensions are listed in ../README.md."""
from __future__ import annotations

import asyncio
import json
import math
import os
import socket
import stat

from .faults import KINDS


def ms(req: dict, key: str, default: float) -> float:
    """A duration in ms: a finite number 0..3600000."""
    value = req.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or not 0 <= value <= 3600e3:
        raise ValueError(f"{key} must be 0..3600000 ms, not {value!r}")
    return float(value)


class Control:
    """Executes control requests against the running simulator (also used for --faults)."""

    def __init__(self, app):
        self.app = app
        self.server = None
        self.path = None
        self.ino = None

    async def start(self, path: str):
        """Serve on `path`. A socket another live process answers on is never taken over (the
        other simulator would lose its control); a stale socket is replaced; anything that is
        not a socket is left alone. ValueError (one line) when refused."""
        path = os.path.abspath(path)
        if os.path.lexists(path):
            if not stat.S_ISSOCK(os.lstat(path).st_mode):
                raise ValueError(f"--control {path}: exists and is not a socket; not replaced")
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            probe.settimeout(1.0)
            try:
                probe.connect(path)
            except (ConnectionRefusedError, FileNotFoundError):
                os.unlink(path)             # stale: its simulator is gone
            except OSError as err:
                raise ValueError(f"--control {path}: {err.strerror or err}") from None
            else:
                raise ValueError(f"--control {path}: another simulator is serving this socket "
                                 "(stop it, or choose another path)")
            finally:
                probe.close()
        try:
            self.server = await asyncio.start_unix_server(self._client, path)
        except OSError as err:
            raise ValueError(f"--control {path}: {err.strerror or err}") from None
        self.path = path
        self.ino = os.stat(path).st_ino

    def close(self):
        if self.server:
            self.server.close()
        # Remove our socket only (not one a later simulator put at the same path).
        if self.path and os.path.exists(self.path) and os.stat(self.path).st_ino == self.ino:
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

    @staticmethod
    def _reg(dev, req):
        if "reg" not in req:
            raise ValueError("'reg' is required")
        try:
            return dev.lookup(req["reg"])
        except KeyError as err:
            raise ValueError(str(err).strip('"')) from None

    def _dev(self, req):
        if "addr" not in req:
            raise ValueError("'addr' is required")
        try:
            return self.app.bus.device_by_key(int(req["addr"]))
        except KeyError as err:
            raise ValueError(str(err).strip('"')) from None

    # ----- the contract's ops -----
    def op_get(self, req):
        dev = self._dev(req)
        reg = self._reg(dev, req)
        raw = dev.get_raw(reg)
        out = {"raw": raw, "reg": reg.name, "words": dev.reg_words(reg)}
        if reg.scale != "raw" or reg.codes:
            out["eng"] = dev.to_eng(reg, raw)
        return out

    def op_set(self, req):
        """Raw write bypassing access rules and ranges (to provoke a device), but never a value
        the register's words cannot hold: it would wrap (SV eng 99999 -> raw -31073)."""
        dev = self._dev(req)
        reg = self._reg(dev, req)
        if "raw" in req:
            value = req["raw"]
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"raw must be an integer, not {value!r}")
            raw = value
        elif "eng" in req:
            value = req["eng"]
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"eng must be finite, not {value!r}")
            raw = dev.from_eng(reg, value)
        else:
            raise ValueError("'raw' or 'eng' is required")
        bits = 16 * reg.words
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if reg.signed else (0, (1 << bits) - 1)
        if not lo <= raw <= hi:
            raise ValueError(f"{reg.name}: raw {raw} does not fit its {bits}-bit "
                             f"{'signed' if reg.signed else 'unsigned'} word(s) ({lo}..{hi})")
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
        down = ms(req, "down_ms", 0)
        dev.offline = True
        if down > 0:
            await asyncio.sleep(down / 1000.0)
        dev.power_cycle()
        dev.offline = False
        return {}

    async def op_reopen_port(self, req):
        port = await self.app.transport.reopen(ms(req, "down_ms", 500))
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
