"""Serial transport: a pty we create, a serial device, or the S side of ptyline (--pace).

The serial side is written on os/pyserial rather than on pymodbus's serial server because the
line must (a) find frame ends by the t3.5 rule at the configured baud, (b) stay silent for bad
frames and foreign slave ids without hunting inside them, (c) pace replies at the character
time with a device turnaround, and (d) inject faults at byte level. pymodbus 3.8's server
offers none of these hooks (its RTU framer even warns it does not support multidrop lines).
"""
from __future__ import annotations

import asyncio
import fcntl
import os
import random
import struct
import termios
import tty

from . import frames
from .lineoffer import LineOffer
from .ptyline import PtyLine

LONG_GAP = 0.05   # an incomplete frame (by its function's length) is dropped after this silence
BAUD_CONST = {b: getattr(termios, f"B{b}") for b in (
    50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600,
    115200, 230400, 460800, 500000, 576000, 921600, 1000000) if hasattr(termios, f"B{b}")}
SPEED_BAUD = {v: k for k, v in BAUD_CONST.items()}
# Any other rate (the MT-S9's 14400, 28800, 76800): Linux's termios2 with BOTHER, the speed
# itself in c_ispeed/c_ospeed. struct termios2: 4 flag words, c_line, c_cc[19], then the two
# speeds (44 bytes); TCGETS2 = _IOR('T', 0x2A, termios2), TCSETS2 = _IOW('T', 0x2B, termios2).
TCGETS2, TCSETS2, BOTHER, CBAUD = 0x802C542A, 0x402C542B, 0o010000, 0o010017
TERMIOS2 = struct.Struct("=4I B 19s 2I")


def get_speed(fd: int) -> int:
    """The output speed of a tty in baud, also one set with BOTHER (termios2)."""
    fields = TERMIOS2.unpack(fcntl.ioctl(fd, TCGETS2, bytes(TERMIOS2.size)))
    return fields[7]


def set_speed(fd: int, baud: int) -> None:
    """Set any speed on a tty with termios2/BOTHER (input and output)."""
    iflag, oflag, cflag, lflag, line, cc, _, _ = TERMIOS2.unpack(
        fcntl.ioctl(fd, TCGETS2, bytes(TERMIOS2.size)))
    cflag = (cflag & ~(CBAUD | CBAUD << 16)) | BOTHER | BOTHER << 16
    fcntl.ioctl(fd, TCSETS2, TERMIOS2.pack(iflag, oflag, cflag, lflag, line, cc, baud, baud))


class SerialLine:
    """One RS-485 line on a pty (`--pty`) or a serial device (`--serial`)."""

    def __init__(self, bus, device: str | None = None, link: str | None = None,
                 pace: bool = False, seed: int = 0, ptyline: str | None = None):
        self.bus = bus
        self.line = bus.line
        self.device = device            # None: create a pty
        self.link = os.path.abspath(link) if link else None
        self.pace = pace
        self.rng = random.Random(f"{seed}:turnaround")
        self.fd = self.slave_fd = None
        self.ser = None
        self.offer = None               # own pty: the tests' socket beside it (lineoffer.py)
        self.path = None
        self.rx: dict = {}              # framing -> Receiver
        self.wlock = asyncio.Lock()
        self.generation = 0             # replies scheduled before a reopen are not sent after it
        self.counters = {"tx_overflow": 0}
        self.seed = seed
        # With --pace on a pty, the line is tools/sim/ptyline (paced both ways, with line
        # statistics); the simulator then only answers on its S side and does not pace itself.
        self.ptyline = PtyLine(ptyline, self.line, seed) if ptyline and pace and not device \
            else None

    # ----- open / close -----
    async def start(self) -> str:
        self._open()
        return f"PTY {self.link or self.path}" if self.device is None else f"SERIAL {self.path}"

    def _open(self):
        if self.ptyline is not None:
            master_path, slave_path = self.ptyline.start()
            self.fd = os.open(slave_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            tty.setraw(self.fd)
            self.path = master_path
            self._relink()
        elif self.device is None:
            self.fd, self.slave_fd = os.openpty()
            # Raw mode before any master opens the pty: no echo, no line editing, no CR/LF
            # translation. The slave end stays open here so the pty survives masters that
            # close and reopen it (otherwise reads on our side fail with EIO).
            # The line's speed and stop bits too: a master that sets nothing is on the line.
            tty.setraw(self.slave_fd)
            attrs = termios.tcgetattr(self.slave_fd)
            speed = BAUD_CONST.get(self.line.baud)
            if speed is not None:
                attrs[4] = attrs[5] = speed
            if self.line.stop_bits == 2:
                attrs[2] |= termios.CSTOPB
            else:
                attrs[2] &= ~termios.CSTOPB
            termios.tcsetattr(self.slave_fd, termios.TCSANOW, attrs)
            if speed is None:
                set_speed(self.slave_fd, self.line.baud)
            self.path = os.ttyname(self.slave_fd)
            self.offer = LineOffer(self.path, self._feed)
            self._relink()
        else:
            import serial  # pyserial, pinned in requirements.txt
            self.ser = serial.Serial(self.device, self.line.baud, bytesize=self.line.data_bits,
                                     parity=self.line.parity, stopbits=self.line.stop_bits,
                                     timeout=0)
            self.fd = self.ser.fileno()
            self.path = self.device
        os.set_blocking(self.fd, False)
        asyncio.get_running_loop().add_reader(self.fd, self._readable)

    def _relink(self):
        """Point --symlink at the current port (atomically, so it is never missing)."""
        if self.link:
            tmp = f"{self.link}.tmp{os.getpid()}"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.path, tmp)
            os.replace(tmp, self.link)

    def close(self, remove_link: bool = True):
        if self.fd is None:
            return
        asyncio.get_running_loop().remove_reader(self.fd)
        for rx in self.rx.values():
            rx.reset()
        self.rx.clear()
        self.generation += 1
        if self.ser is not None:
            self.ser.close()
            self.ser = None
        else:
            os.close(self.fd)
            if self.slave_fd is not None:
                os.close(self.slave_fd)
        if self.ptyline is not None:
            self.ptyline.stop(final=remove_link)
        if self.offer is not None:
            self.offer.close()
            self.offer = None
        self.fd = self.slave_fd = None
        if remove_link and self.link and os.path.islink(self.link):
            os.unlink(self.link)

    async def reopen(self, down_ms: float) -> str:
        """Close the port (masters see it vanish), wait, open again (same --symlink path).
        On our own pty the old pty's number stays taken (its slave end held) until the link
        names the new one: a master reopening the link meanwhile finds a dead pty, never
        another program's pty that got the number."""
        hold = self.slave_fd if self.device is None and self.ptyline is None else None
        self.slave_fd = None
        try:
            self.close(remove_link=False)
            await asyncio.sleep(down_ms / 1000.0)
            self._open()
        finally:
            if hold is not None:
                os.close(hold)
        return self.link or self.path

    # ----- receive: every device hears every byte, in its own framing -----
    # One receiver per framing spoken on the line (RTU, RTU without CRC, ASCII), each with its
    # own buffer and frame-end rule, like the UARTs and firmware of the devices on a real line:
    # an RTU device takes ASCII text for a frame with a bad CRC, an ASCII device skips binary
    # RTU bytes while it waits for ':'. A frame a receiver decodes goes to the device of that
    # framing at its address (Bus.request). A line of one framing has one receiver.
    def receivers(self) -> list:
        """The receivers of the framings the devices speak now (an MT-S9's Type write changes
        its framing after the reply), in a fixed order; a framing nobody speaks any more is
        dropped with its buffer."""
        want = [f for f in frames.FRAMINGS if f in self.bus.framings()]
        for framing in list(self.rx):
            if framing not in want:
                self.rx.pop(framing).reset()
        for framing in want:
            if framing not in self.rx:
                self.rx[framing] = Receiver(self, framing)
        return [self.rx[f] for f in want]

    def _readable(self):
        try:
            data = os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return                      # EIO while no master has the pty open
        if data:
            self._feed(data)

    def _feed(self, data: bytes):
        """Bytes the line carried (from the pty, or from a test's socket: lineoffer.py)."""
        receivers = self.receivers()
        mixed = len(receivers) > 1
        for rx in receivers:
            rx.mixed = mixed
            rx.feed(data)

    def master_format(self) -> dict | None:
        """The master's port settings as far as our own pty shows them: tcgetattr on the pty
        master returns the termios the master set on its end (Linux): its speed. Parity and
        data bits cannot be seen (a pty drops PARENB and CS7), so Device.hears takes them from
        the line; stop bits are not compared (a UART checks only the first). None on a real
        serial port (its UART does the real thing) and through ptyline (ptyline checks both of
        its sides)."""
        if self.device is not None or self.ptyline is not None or self.fd is None:
            return None
        try:
            return {"baud": get_speed(self.fd)}
        except OSError:
            return None

    # ----- transmit: whole frame, or paced at the character time with a turnaround -----
    def line_stats(self) -> dict:
        if self.ptyline is None:
            return {"available": False, "why": "line statistics need --pty --pace with "
                    "tools/sim/ptyline built (--ptyline PATH or MBFB_PTYLINE)"}
        return {"available": True, "stats": self.ptyline.stats()}

    async def _send(self, data: bytes, delay: float, info: str, generation: int, sent, tag=None):
        try:
            await self._transmit(data, delay, info, generation, tag)
        finally:
            sent()                      # the device is free again (late replies: busy till now)

    async def _transmit(self, data: bytes, delay: float, info: str, generation: int, tag=None):
        if self.pace and self.ptyline is None:
            delay += self.line.t35 + self.rng.uniform(0.001, 0.010)   # 1..10 ms turnaround
        if delay > 0:
            await asyncio.sleep(delay)
        async with self.wlock:
            if generation != self.generation or self.fd is None:
                return
            for rx in list(self.rx.values()):   # the reply ends every frame held
                rx.end_frame()
            self.bus.record("tx", data, info, tag)
            if not self.pace or self.ptyline is not None:   # ptyline paces it (one write:
                self._write(data)                          # no stall can split the frame)
                return
            loop = asyncio.get_running_loop()
            start, sent, ct = loop.time(), 0, self.line.char_time
            while sent < len(data):
                due = min(len(data), int((loop.time() - start) / ct) + 1)
                if due > sent:
                    if not self._write(data[sent:due]):
                        return
                    sent = due
                if sent < len(data):
                    await asyncio.sleep(max(0.0, start + sent * ct - loop.time()))
                if generation != self.generation or self.fd is None:
                    return

    def _write(self, data: bytes) -> bool:
        sent = self.offer.send(data) if self.offer is not None else None
        if sent is not None:
            if not sent:
                self.counters["tx_overflow"] += 1
            return sent
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except (BlockingIOError, OSError):
                self.counters["tx_overflow"] += 1     # nobody reads the pty: bytes are lost
                return False
            view = view[n:]
        return True


class Receiver:
    """One framing's receiver on a serial line: its buffer, its frame-end rule, its timer.
    RTU and RTU without CRC: frame end by the function's length or t3.5 of silence. ASCII: a
    frame is ':' ... CR LF; a ':' starts a frame afresh (what came before it is dropped), and
    an unfinished frame is dropped after 1 s of silence."""

    def __init__(self, line: SerialLine, framing: str):
        self.line, self.framing = line, framing
        self.bus = line.bus
        self.settings = line.line
        self.buf = bytearray()
        self.timer = None               # the frame-end timer (t3.5, LONG_GAP, ASCII's 1 s)
        self.since = 0.0                # loop time of the bytes the timer waits after
        self.mixed = False              # other framings on the line too: log entries say which

    def _stop_timer(self):
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def reset(self):
        self._stop_timer()
        self.buf.clear()

    @property
    def tag(self):
        return self.framing if self.mixed else None

    def feed(self, data: bytes):
        # A frame-end timer already due runs before newer bytes are taken. asyncio runs the I/O
        # callbacks of a loop iteration before the timers that fell due in it, so after a stall
        # of this process (a loaded machine) the next request was appended to a frame whose
        # t3.5 had passed before it came: both lost as one bad frame, and no reply.
        loop = asyncio.get_running_loop()
        while self.timer is not None and self.timer.when() <= loop.time():
            self._stop_timer()
            self._silence()
        self.buf += data
        self._parse()

    def end_frame(self):
        """Another device's reply goes on the line: whatever this receiver holds is a whole
        frame or garbage now (the master's write is over; a real receiver also hears the reply
        and the silence after it). Without it a master that sent its next request at once
        (an unpaced line answers with no turnaround) had it appended to the held bytes."""
        self._stop_timer()
        if self.buf:
            self._silence(held=False)

    def _parse(self):
        loop = asyncio.get_running_loop()
        if self.framing == "ascii":
            while True:
                start = self.buf.find(b":")
                if start < 0:
                    if self.buf:
                        self._garbage(bytes(self.buf))
                    self.buf.clear()
                    break
                if start:
                    self._garbage(bytes(self.buf[:start]))
                    del self.buf[:start]
                end = self.buf.find(b"\r\n")
                restart = self.buf.find(b":", 1)
                if 0 < restart and (end < 0 or restart < end):
                    self._garbage(bytes(self.buf[:restart]))    # a new ':' starts again
                    del self.buf[:restart]
                    continue
                if end < 0:
                    break
                frame = bytes(self.buf[:end + 2])
                del self.buf[:end + 2]
                self._frame(frame)
        else:
            while self.buf:
                need = frames.rtu_request_length(bytes(self.buf))
                if need is None or len(self.buf) < need:
                    break
                frame = bytes(self.buf[:need])
                del self.buf[:need]
                self._frame(frame)
        self._stop_timer()
        if self.buf:
            wait = self.settings.t35 if self.framing != "ascii" else 1.0
            self.since = loop.time()
            self.timer = loop.call_later(wait, self._silence)

    def _silence(self, held: bool = True):
        """t3.5 of silence: the buffer is a whole frame unless its function says it is short.
        held=False: no longer wait for the rest of a short frame (end_frame)."""
        self.timer = None
        if not self.buf:
            return
        loop = asyncio.get_running_loop()
        need = frames.rtu_request_length(bytes(self.buf)) if self.framing != "ascii" else None
        short = need is not None and len(self.buf) < need
        # Too few bytes yet to know the length (address alone, or an FC16 header before its byte
        # count): as short. A pty line (ptyline) stalled by the scheduler after the first byte
        # otherwise cut a good request in two: "short frame", then "bad CRC", and no reply.
        if need is None and self.framing != "ascii" and frames.rtu_length_pending(bytes(self.buf)):
            short = True
        # RTU-without-CRC: a frame that simply omits the two CRC bytes is accepted too.
        if short and need is not None and self.framing == "nocrc" and len(self.buf) == need - 2:
            frame = bytes(self.buf) + b"\0\0"
            self.buf.clear()
            self._frame(frame)
            return
        if short and held and loop.time() - self.since < LONG_GAP:
            # A master's write split by the scheduler: wait a little longer than t3.5.
            self.timer = loop.call_later(LONG_GAP - (loop.time() - self.since), self._silence)
            return
        frame = bytes(self.buf)
        self.buf.clear()
        if short or self.framing == "ascii":
            self._garbage(frame)
        else:
            self._frame(frame)

    def _garbage(self, data: bytes):
        self.bus.record("rx", data, "garbage", self.tag)
        self.bus.bad_frame()

    def _frame(self, frame: bytes):
        try:
            if self.framing == "ascii":
                addr, pdu = frames.decode_ascii(frame)
            else:
                addr, pdu = frames.decode_rtu(frame, check_crc=self.framing == "rtu")
        except frames.BadFrame as err:
            self.bus.record("rx", frame, str(err), self.tag)
            self.bus.bad_frame()
            return
        self.bus.record("rx", frame, "", self.tag)
        line = self.line
        reply = self.bus.request(addr, pdu, line.master_format(), self.framing)
        if reply is None:
            return
        framing = self.framing
        out = frames.encode(framing, reply.addr, reply.pdu)
        delay, info = 0.0, ""
        if reply.fault is not None:
            out, delay = reply.queue.shape(reply.fault, out, framing,
                                      lambda a: frames.encode(framing, a, reply.pdu),
                                      lambda f: frames.corrupt_check(framing, f))
            info = reply.fault.kind
        if out is None:
            self.bus.record("tx", b"", "drop", self.tag)
            return
        asyncio.ensure_future(line._send(out, delay, info, line.generation, reply.sent, self.tag))
