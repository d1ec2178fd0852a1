#!/usr/bin/env python3
"""Write the seed corpora of the fuzz harnesses (fuzz/corpus/<harness>/) from the worked
frames of the manuals (the same frames tests/shims/test_frame.c checks byte for byte).
Run it again after changing a harness's input layout (with the project's venv:
.venv/bin/python fuzz/seeds.py); the files are committed (small)."""
import os
import shutil
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tools", "sim"))
from modsim.frames import crc_bytes, lrc  # noqa: E402  (pymodbus's CRC-16 and LRC)
FC_SEL = {3: 0, 4: 1, 6: 2, 16: 3, 1: 4, 2: 5, 5: 6, 15: 7}

# (request frame, reply frame) as printed or derived in the manuals, without check bytes:
# the SetPro MV/VD, MT-S9 and FDC-100 manuals, whose worked frames maps/*.json keep byte for
# byte ("frames"; maps/README.md names each manual).
PAIRS = [
    ("01 03 00 00 00 01", "01 03 02 03 E8"),             # MV-D94 read SV
    ("01 04 10 00 00 01", "01 04 02 00 1B"),             # MV-D94 read PV (FC04)
    ("01 06 00 00 01 F4", "01 06 00 00 01 F4"),          # MV-D94 write SV 500
    ("01 03 00 00 00 22", "01 83 02"),                   # exception 02
    ("01 06 00 01 FF F6", "01 85 01"),                   # wrong exception function
    ("01 03 00 00 00 02", "01 03 04 00 00 00 02"),       # MT-S9 read Real Data
    ("01 06 00 00 00 02", "01 06 00 00 00 02"),          # MT-S9 FC06
    ("01 10 00 00 00 02 04 00 0A 01 02", "01 10 00 00 00 02"),   # MT-S9 preset FC16
    ("01 03 00 80 00 04", "01 03 08 03 E8 05 DC 00 00 00 00"),   # FDC PV..MV2
    ("01 06 00 48 68 25", "01 06 00 48 68 25"),          # FDC CMND reset
    ("01 06 00 48 68 28", "01 86 03"),                   # FDC exception 03
    # coils and discrete inputs: the Modbus application protocol's examples (6.1, 6.2,
    # 6.5, 6.11), on slave 0x11 as the RTU examples print them
    ("11 01 00 13 00 25", "11 01 05 CD 6B B2 0E 1B"),    # read 37 coils
    ("11 02 00 C4 00 16", "11 02 03 AC DB 35"),          # read 22 discrete inputs
    ("11 05 00 AC FF 00", "11 05 00 AC FF 00"),          # coil 173 ON
    ("11 0F 00 13 00 0A 02 CD 01", "11 0F 00 13 00 0A"), # write 10 coils
    ("11 01 00 13 00 25", "11 81 02"),                   # exception 02
]


def b(hexs):
    return bytes.fromhex(hexs.replace(" ", ""))


def crc16(data):
    """The check bytes of an RTU frame, low byte first (pymodbus's CRC, as the simulator)."""
    return crc_bytes(data)


def ascii_frame(data):
    return b":" + (data + bytes([lrc(data)])).hex().upper().encode() + b"\r\n"


def header(req):
    """The 7-byte request header of fuzz_common.h for a request frame."""
    slave, fc = req[0], req[1]
    addr = req[2:4]
    if fc in (5, 6):
        return bytes([slave, FC_SEL[fc]]) + addr + bytes([1]) + req[4:6]
    count = req[5]
    v0 = req[7:9] if fc == 16 else req[8:6:-1] if fc == 15 else b"\0\0"  # FC15: LSB first
    return bytes([slave, FC_SEL[fc]]) + addr + bytes([count]) + v0


def write(target, name, data):
    d = os.path.join(HERE, "corpus", target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as fh:
        fh.write(data)


def main():
    shutil.rmtree(os.path.join(HERE, "corpus"), ignore_errors=True)
    for i, (q, r) in enumerate(PAIRS):
        req, rsp = b(q), b(r)
        h = header(req)
        write("fuzz_reply", f"{i:02d}", h + rsp)
        write("fuzz_recv", f"{i:02d}_rtu", b"\0" + h + rsp + crc16(rsp))
        write("fuzz_recv", f"{i:02d}_ascii", b"\1" + h + ascii_frame(rsp))
        write("fuzz_recv", f"{i:02d}_nocrc", b"\2" + h + rsp + crc16(rsp))
        mbap = bytes([0, 1, 0, 0, 0, len(rsp)])
        write("fuzz_recv", f"{i:02d}_tcp", b"\3" + h + mbap + rsp)
        # worker: one request, then answers: the manual's reply as raw bytes / a good one
        for framing in (0, 1, 2):
            wire = ascii_frame(rsp) if framing == 1 else rsp + crc16(rsp)
            raw_answer = bytes([0, 1, len(wire)]) + wire
            write("fuzz_worker", f"{i:02d}_f{framing}_raw",
                  bytes([framing, 1, 0]) + h + raw_answer)
    # worker scripts: good answers, a mutated one, silence, a late one, several requests
    h_sv, h_pv = header(b("01 03 00 00 00 01")), header(b("01 04 10 00 00 01"))
    h_w = header(b("01 10 00 00 00 02 04 00 0A 01 02"))
    write("fuzz_worker", "good3", bytes([0, 1, 2]) + h_sv + h_pv + h_w + bytes([1, 0] * 3))
    write("fuzz_worker", "mutated", bytes([0, 2, 0]) + h_sv + bytes([2, 0, 3, 0x40, 1, 0]))
    write("fuzz_worker", "silence_then_good", bytes([1, 2, 0]) + h_sv + bytes([3, 0, 1, 0]))
    write("fuzz_worker", "late_write", bytes([0, 2, 0]) + bytes([0x81]) + h_w[1:] +
          bytes([4, 10, 1, 0, 1, 0]))
    write("fuzz_worker", "ascii_two", bytes([1, 1, 1]) + h_sv + h_pv + bytes([1, 0, 1, 0]))
    # bits: coils and inputs read, 10 coils written, good answers; a coil write whose echo
    # is lost (silence), then its read-back (FC01) answered
    h_co, h_di = header(b("11 01 00 13 00 25")), header(b("11 02 00 C4 00 16"))
    h_c15, h_c5 = header(b("11 0F 00 13 00 0A 02 CD 01")), header(b("11 05 00 AC FF 00"))
    write("fuzz_worker", "bits_good3", bytes([0, 1, 2]) + h_co + h_di + h_c15 +
          bytes([1, 0] * 3))
    write("fuzz_worker", "bits_echo_lost", bytes([2, 2, 0]) + bytes([0x81]) + h_c5[1:] +
          bytes([3, 0, 1, 0, 1, 0]))


if __name__ == "__main__":
    main()
