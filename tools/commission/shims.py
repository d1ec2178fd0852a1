"""The project's C shims (c_shims/include/mbfb.h) as a Python Modbus master, through ctypes.

The commissioning tool talks to instruments with the same engine as the function blocks: the
same line timing, reply checks, late-reply rules, confirmed writes and error ids. The shims are
built for a PLC scan (post, then poll); a command-line tool may wait, so each call here posts one
request and polls it until the worker has finished it.

    with Shims.load() as lib:
        bus = lib.open_bus("/dev/ttyUSB0", 9600, "N", 8, 2, "rtu")
        dev = lib.open_device(bus, 1)
        rc, words = lib.read(dev, 3, 0, 4)
"""
from __future__ import annotations

import ctypes
import os
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
LIB_ENV = "MBFB_LIB"

FRAMINGS = {"rtu": 0, "ascii": 1, "nocrc": 2, "tcp": 3}    # MBFB_FRAMING_*
REQ_DONE, REQ_FAILED = 3, 4                                # MBFB_REQ_*
WRITE_IDEMPOTENT = 0                                       # MBFB_WRITE_*
E_TIMEOUT, E_CRC, E_BADREPLY, E_NOPORT, E_PORTLOST = 1, 2, 3, 5, 6
E_CONFLICT, E_INVAL, E_BAUD, E_DIRECTION = 9, 10, 14, 15
DIRECTIONS = {"none": 0, "kernel": 1, "rts": 2, "gpio": 3}   # MBFB_DIR_*
E_EXCEPTION_BASE = 128
MAX_READ = 125


class Diag(ctypes.Structure):
    """mbfb_diag_t (c_shims/include/mbfb.h), in its order."""
    _fields_ = [(n, ctypes.c_int32 if n == "last_error" else ctypes.c_uint32) for n in (
        "requests", "good", "timeouts", "crc_errors", "bad_replies", "exceptions", "retries",
        "last_exception", "last_rtt_us", "offline", "last_error", "stray_bytes", "resyncs",
        "refreshes", "refresh_us", "line_permille")]


class ShimsError(RuntimeError):
    """The shared library is missing or does not load."""


def find_library() -> str:
    """$MBFB_LIB, else lib/libmbfb.so of the newest build*/ tree of this checkout."""
    given = os.environ.get(LIB_ENV)
    if given:
        if not os.path.isfile(given):
            raise ShimsError(f"{LIB_ENV}={given}: no such file")
        return given
    found = []
    for name in os.listdir(ROOT):
        path = os.path.join(ROOT, name, "lib", "libmbfb.so")
        if name.startswith("build") and os.path.isfile(path):
            found.append((os.path.getmtime(path), path))
    if not found:
        raise ShimsError("the shims' shared library is not built: run "
                         "'cmake -S . -B build -G Ninja && cmake --build build --target mbfb_shared' "
                         f"(or set {LIB_ENV})")
    return max(found)[1]


class Shims:
    """ctypes view of the shims' public API; one instance per process."""

    def __init__(self, path: str):
        try:
            self.lib = lib = ctypes.CDLL(path)
        except OSError as err:
            raise ShimsError(f"{path}: {err}") from None
        i, u16p = ctypes.c_int, ctypes.POINTER(ctypes.c_uint16)
        lib.mbfb_bus_open_line.argtypes = ([ctypes.c_char_p] + [i] * 12 +
                                           [ctypes.c_char_p, i, i])
        lib.mbfb_dev_open.argtypes = [i, i]
        lib.mbfb_post.argtypes = [i, i, i, i, u16p]
        lib.mbfb_post_write.argtypes = [i, i, i, i, u16p, i]
        lib.mbfb_poll.argtypes = [i]
        lib.mbfb_take.argtypes = [i, u16p, i]
        lib.mbfb_dev_diag.argtypes = [i, ctypes.POINTER(Diag)]
        lib.mbfb_strerror.argtypes = [i]
        lib.mbfb_strerror.restype = ctypes.c_char_p

    @classmethod
    def load(cls) -> "Shims":
        return cls(find_library())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.shutdown()

    def shutdown(self):
        """Stop every bus worker and close every port (a new line setting needs a new bus)."""
        self.lib.mbfb_shutdown()

    def strerror(self, code: int) -> str:
        return self.lib.mbfb_strerror(code).decode()

    def open_bus(self, port: str, baud: int, parity: str, data_bits: int, stop_bits: int,
                 framing: str, timeout_ms: int = 0, retries: int = -1, direction: str = "none",
                 active_low: bool = False, before_us: int = 0, after_us: int = 0,
                 gpio_chip: str = "", gpio_line: int = 0) -> int:
        """A bus handle >= 0, or a negative -MBFB_E_* (bad settings: nothing is opened).
        direction: who switches an RS-485 transceiver (DIRECTIONS, c_shims README)."""
        raw, chip = port.encode(), gpio_chip.encode()
        return self.lib.mbfb_bus_open_line(raw, len(raw), baud, ord(parity), data_bits,
                                           stop_bits, FRAMINGS[framing], timeout_ms, retries,
                                           DIRECTIONS[direction], int(active_low), before_us,
                                           after_us, chip, len(chip), gpio_line)

    def open_device(self, bus: int, slave: int) -> int:
        return self.lib.mbfb_dev_open(bus, slave)

    def stray_bytes(self, dev: int) -> int:
        """Bytes the device's bus heard outside any reply and dropped (a late reply of an
        earlier request heard in the silence before a request, or noise)."""
        d = Diag()
        return d.stray_bytes if self.lib.mbfb_dev_diag(dev, ctypes.byref(d)) == 0 else 0

    def _wait(self, req: int, count: int) -> tuple[int, list]:
        """Poll a posted request until it ends: (0, words) or (positive MBFB_E_*, [])."""
        if req < 0:
            return -req, []
        while self.lib.mbfb_poll(req) not in (REQ_DONE, REQ_FAILED):
            time.sleep(0.0005)
        buf = (ctypes.c_uint16 * MAX_READ)()
        rc = self.lib.mbfb_take(req, buf, MAX_READ)
        return (0, list(buf[:count])) if rc >= 0 else (-rc, [])

    def read(self, dev: int, fc: int, addr: int, count: int) -> tuple[int, list]:
        """FC03/FC04: (0, the words) or (MBFB_E_* / 128 + exception code, [])."""
        buf = (ctypes.c_uint16 * 1)()
        return self._wait(self.lib.mbfb_post(dev, fc, addr, count, buf), count)

    def write_block(self, dev: int, addr: int, values: list) -> int:
        """FC16 of `values` from `addr`, confirmed by the shims: 0 or MBFB_E_*."""
        buf = (ctypes.c_uint16 * len(values))(*[v & 0xFFFF for v in values])
        return self._wait(self.lib.mbfb_post_write(dev, 16, addr, len(values), buf,
                                                   WRITE_IDEMPOTENT), 0)[0]

    def write(self, dev: int, addr: int, value: int) -> int:
        """FC06, confirmed by the shims (an echo in step, or a read-back): 0 or MBFB_E_*."""
        buf = (ctypes.c_uint16 * 1)(value & 0xFFFF)
        return self._wait(self.lib.mbfb_post_write(dev, 6, addr, 1, buf, WRITE_IDEMPOTENT), 0)[0]
