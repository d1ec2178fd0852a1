"""The simulator's own pty offered to the tests as a line whose bytes go through a Unix socket.

A pty's bytes pass from one side to the other in a kernel worker thread at ordinary priority,
shared by every pty on the machine: on a loaded machine it held them for seconds, while the
simulator and the master ran on time. With MBFB_TESTLINE_DIR set (the tests set it, with
tests/shims/testline.c preloaded into the master's process), the simulator also listens on
$MBFB_TESTLINE_DIR/mbfb-line-pts-N for its pty /dev/pts/N. A master that opens the pty with
that library preloaded connects there instead and keeps the pty for its settings only (which
SerialLine.master_format reads on the pty as before); its bytes and the replies go through
the socket. Replies go to the connected masters, or to the pty while none is connected.
Without the variable nothing changes: users' masters open the pty itself."""
from __future__ import annotations

import asyncio
import os
import socket

ENV = "MBFB_TESTLINE_DIR"
PTS = "/dev/pts/"
SUN_PATH_MAX = 107          # sockaddr_un.sun_path (108 bytes) less the terminating NUL


class LineOffer:
    """The Unix socket beside the pty `pty_path`: accepts masters and hands their bytes to
    `feed`. Listens only when MBFB_TESTLINE_DIR is set and the name fits."""

    def __init__(self, pty_path: str, feed):
        self.feed = feed
        self.conns: list[socket.socket] = []
        self.path = self.sock = None
        folder = os.environ.get(ENV, "")
        if not folder.startswith("/") or not os.path.isdir(folder) or \
                not pty_path.startswith(PTS):
            return
        path = os.path.join(folder, "mbfb-line-pts-" + pty_path[len(PTS):])
        if len(os.fsencode(path)) > SUN_PATH_MAX:
            return
        if os.path.lexists(path):   # left by a simulator that was killed
            os.unlink(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.bind(path)
        self.sock.listen(4)
        self.sock.setblocking(False)
        self.path = path
        asyncio.get_running_loop().add_reader(self.sock.fileno(), self._accept)

    def _accept(self):
        try:
            conn, _ = self.sock.accept()
        except (BlockingIOError, InterruptedError):
            return
        conn.setblocking(False)
        self.conns.append(conn)
        asyncio.get_running_loop().add_reader(conn.fileno(), self._readable, conn)

    def _readable(self, conn: socket.socket):
        try:
            data = conn.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if data:
            self.feed(data)
        else:                       # the master closed its port
            self._drop(conn)

    def _drop(self, conn: socket.socket):
        asyncio.get_running_loop().remove_reader(conn.fileno())
        conn.close()
        self.conns.remove(conn)

    def send(self, data: bytes) -> bool | None:
        """Send to the connected masters: True, False when one took nothing more (bytes
        lost, as on a pty nobody reads), None when none is connected (write to the pty)."""
        if not self.conns:
            return None
        ok = True
        for conn in list(self.conns):
            try:
                conn.sendall(data)
            except BlockingIOError:
                ok = False
            except OSError:
                self._drop(conn)
        return ok

    def close(self):
        for conn in list(self.conns):
            self._drop(conn)
        if self.sock is not None:
            asyncio.get_running_loop().remove_reader(self.sock.fileno())
            self.sock.close()
            self.sock = None
        if self.path is not None and os.path.lexists(self.path):
            os.unlink(self.path)
        self.path = None
