"""Wire framing: RTU, RTU-without-CRC, ASCII (serial lines) and MBAP (TCP).

CRC-16 and LRC come from pymodbus (FramerRTU.compute_CRC, FramerAscii.compute_LRC), and the
expected length of an RTU request comes from pymodbus's PDU decoder (calculateRtuFrameSize).
The frame *handling* is written here by hand because pymodbus's framers cannot do what the
manuals require on a shared line:
  * RTU without CRC (MT-S9 Type 2): the request's CRC field is not checked, the reply still
    carries a real CRC. pymodbus's FramerRTU rejects such frames.
  * Silence: a frame with a bad CRC/LRC, or for a slave id nobody here owns, must get no reply
    and must not be "hunted" for a valid frame inside it (FramerRTU.decode scans for one).
  * Exact per-manual exception behaviour is decided by the device models, not by a datastore.
"""
from __future__ import annotations

from binascii import a2b_hex, b2a_hex

from pymodbus.framer.ascii import FramerAscii
from pymodbus.framer.rtu import FramerRTU
from pymodbus.pdu import DecodePDU

FRAMINGS = ("rtu", "nocrc", "ascii")

_server_decoder = DecodePDU(is_server=True)


def crc_bytes(frame: bytes) -> bytes:
    """CRC-16/MODBUS of `frame` in wire order (low byte first)."""
    return FramerRTU.compute_CRC(frame).to_bytes(2, "big")


def lrc(data: bytes) -> int:
    """ASCII-mode LRC: two's complement of the 8-bit sum."""
    return FramerAscii.compute_LRC(data)


def rtu_request_length(buf: bytes) -> int | None:
    """Length of the RTU request starting at buf[0], or None if not known (yet)."""
    if len(buf) < 2:
        return None
    if buf[1] & 0x80:
        return None
    cls = _server_decoder.lookupPduClass(buf)
    if cls is None:
        return None
    try:
        size = cls.calculateRtuFrameSize(buf)
    except Exception:  # pylint: disable=broad-except  (needs more bytes, e.g. FC16 byte count)
        return None
    return size or None


def rtu_length_pending(buf: bytes) -> bool:
    """True when rtu_request_length(buf) is None only because buf is too short to tell: the
    address alone, or a known function whose length field has not arrived (FC16's byte count)."""
    if len(buf) < 2:
        return True
    if buf[1] & 0x80 or _server_decoder.lookupPduClass(buf) is None:
        return False
    return rtu_request_length(buf) is None


def encode_rtu(addr: int, pdu: bytes) -> bytes:
    """RTU frame with a real CRC (used for replies in rtu and nocrc modes)."""
    frame = bytes([addr]) + pdu
    return frame + crc_bytes(frame)


def encode_ascii(addr: int, pdu: bytes) -> bytes:
    """ASCII frame ':' hex LRC CR LF, upper-case hex like the MT-S9 manual."""
    body = bytes([addr]) + pdu
    return b":" + b2a_hex(body + bytes([lrc(body)])).upper() + b"\r\n"


def encode(framing: str, addr: int, pdu: bytes) -> bytes:
    """Reply frame in the line's framing."""
    return encode_ascii(addr, pdu) if framing == "ascii" else encode_rtu(addr, pdu)


class BadFrame(Exception):
    """A frame that a real device would silently ignore (bad CRC/LRC, garbage)."""


def decode_rtu(frame: bytes, check_crc: bool = True) -> tuple[int, bytes]:
    """(address, pdu) of a complete RTU frame; BadFrame if too short or CRC wrong."""
    if len(frame) < 4:
        raise BadFrame("short frame")
    if check_crc and crc_bytes(frame[:-2]) != frame[-2:]:
        raise BadFrame("bad CRC")
    return frame[0], bytes(frame[1:-2])


def decode_ascii(frame: bytes) -> tuple[int, bytes]:
    """(address, pdu) of ':' ... CR LF; BadFrame on bad hex or LRC."""
    if not (frame.startswith(b":") and frame.endswith(b"\r\n")):
        raise BadFrame("not an ASCII frame")
    try:
        raw = a2b_hex(frame[1:-2])
    except Exception as exc:  # binascii.Error: odd length or non-hex
        raise BadFrame("bad hex") from exc
    if len(raw) < 3 or lrc(raw[:-1]) != raw[-1]:
        raise BadFrame("bad LRC")
    return raw[0], bytes(raw[1:-1])


def corrupt_check(framing: str, frame: bytes) -> bytes:
    """Same frame with its CRC (RTU) or LRC (ASCII) made wrong."""
    if framing == "ascii":
        body = a2b_hex(frame[1:-2])
        bad = body[:-1] + bytes([body[-1] ^ 0x5A])
        return b":" + b2a_hex(bad).upper() + b"\r\n"
    return frame[:-2] + bytes([frame[-2] ^ 0x5A, frame[-1]])


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    """Modbus/TCP ADU: MBAP header (transaction, protocol 0, length, unit) + PDU."""
    return tid.to_bytes(2, "big") + b"\0\0" + (len(pdu) + 1).to_bytes(2, "big") + bytes([unit]) + pdu


def hexs(data: bytes) -> str:
    """'01 03 00 00' style hex, as in the manuals and the control log."""
    return " ".join(f"{b:02X}" for b in data)
