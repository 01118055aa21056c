#!/usr/bin/env python3
"""Independent reference encoder for the CMS wire protocol's golden frames.

Written from the format descriptions, not from the Rust code:
  * postcard (https://postcard.jamesmunns.com/wire-format): u8 and bool as one
    byte; u16/u32/u64/usize as LEB128 varints; signed integers zigzag-encoded
    then varint; f32 as 4 bytes little-endian; Option as 0 / 1 + value; enum
    variants as a varint index; sequences and strings as varint length + items;
    fixed arrays, tuples and structs as their fields in order, no prefix.
  * frame: COBS(version ‖ payload ‖ CRC-32/ISO-HDLC(version ‖ payload) LE) ‖ 0x00,
    the CRC being zlib's crc32.

Run: python3 tests/scripts/golden.py > tests/golden/frames.txt
The Rust test `protocol::goldens_match_the_reference_encoder` compares the
Rust encoder's frames with this file byte for byte.
"""
import struct
import zlib

VERSION = 3


def varint(n):
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def zz(n, bits):
    return varint((n << 1) ^ (n >> (bits - 1)) if n < 0 else n << 1)


def u8(n):
    return bytes([n])


def f32(x):
    return struct.pack("<f", x)


def opt(v):
    return b"\x00" if v is None else b"\x01" + v


def seq(items):
    return varint(len(items)) + b"".join(items)


def string(s):
    b = s.encode()
    return varint(len(b)) + b


def px(v):  # Px is Q16.16 in an i32
    return zz(round(v * 65536), 32)


def cobs(data):
    out = bytearray()
    block = bytearray()
    for b in data:
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block = bytearray()
        else:
            block.append(b)
            if len(block) == 254:
                out.append(255)
                out += block
                block = bytearray()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def frame(payload):
    raw = bytes([VERSION]) + payload
    raw += struct.pack("<I", zlib.crc32(raw) & 0xFFFFFFFF)
    return cobs(raw) + b"\x00"


# Detector configuration of `pipeline::default_detector()`:
# Cwt, 12 bit, scales 1.5–4 px, 3 stripes, Strongest, 6σ (1536 in Q8), floor 4,
# separation 2·4 px, widths [0.9, 6.4] px, saturation 4095.
def default_detector():
    smin, smax = round(1.5 * 65536), round(4.0 * 65536)
    return (
        varint(0) + u8(12) + zz(smin, 32) + zz(smax, 32) + u8(3) + varint(0)
        + varint(1536) + varint(4) + zz(2 * smax, 32) + zz(smin * 6 // 10, 32)
        + zz(smax * 16 // 10, 32) + varint(4095)
    )


def point(row, flags=0, um=None):
    return (varint(row) + px(201.5) + varint(1500) + px(2.5) + u8(flags)
            + opt(None if um is None else zz(um[0], 32) + zz(um[1], 32)))


DEVICE = {"hello": 0, "profile": 1, "status": 2, "ack": 3, "error": 4, "raw": 5}
HOST = {"start": 0, "stop": 1, "exposure": 2, "detector": 3, "calibration": 4, "capture": 5, "info": 6, "heartbeat": 7,
        "trigger": 8, "windows": 9}


def dev(kind, body=b""):
    return varint(DEVICE[kind]) + body


def cmd(seqno, kind, body=b""):
    return varint(seqno) + varint(HOST[kind]) + body


GOLDENS = [
    ("ack", dev("ack", varint(300))),
    ("error", dev("error", opt(varint(5)) + varint(5))),          # HeartbeatLost = 5
    ("error-version", dev("error", opt(None) + varint(2) + u8(2))),  # Version(2)
    ("status", dev("status", varint(1) + u8(7) + varint(1000) + varint(30000) + varint(14400)
                   + varint(0) + varint(52000) + varint(24960) + varint(3) + varint(4096) + varint(6)
                   + varint(120) + opt(None))),
    ("profile", dev("profile", varint(7) + u8(0) + u8(1) + varint(100000) + zz(25000, 64) + varint(200) + u8(1)
                    + seq([u8(0) + seq([point(0), point(1, flags=2, um=(-1200, 35250))])]))),
    ("hello", dev("hello", string("0.1.0") + u8(VERSION) + string("sim") + varint(752) + varint(480) + u8(12)
                  + default_detector() + varint(0) + varint(2))),  # StoreHealth::Recovered = 2
    ("raw", dev("raw", varint(9) + varint(2) + varint(0) + varint(4) + varint(3) + u8(8) + seq([bytes([b]) for b in (0, 1, 2, 255)]))),
    ("start", cmd(1, "start", varint(30) + u8(7) + varint(1))),     # Sequential = 1
    ("stop", cmd(2, "stop")),
    ("exposure", cmd(3, "exposure", varint(250))),
    ("detector", cmd(4, "detector", default_detector())),
    ("calibration", cmd(5, "calibration", varint(1)
                        + b"".join(f32(v) for v in (1400.0, 1400.0, 376.0, 240.0, 0.0))
                        + b"".join(f32(0.0) for _ in range(5))
                        + b"".join(f32(v) for _ in range(3) for v in (0.0, 0.6691306, 0.7431448, 300.0))
                        + b"".join(f32(v) for v in (0.0, 0.0, -1.0, -200.0)))),
    ("capture", cmd(6, "capture", u8(0))),
    ("info", cmd(7, "info")),
    ("heartbeat", cmd(8, "heartbeat")),
    ("trigger", cmd(9, "trigger", varint(1) + varint(5000))),        # Distance { every_um: 5000 }
    # Laser 0: columns 80..176, laser 1 none, laser 2: 600..696 (a fixed-size array: no length).
    ("windows", cmd(10, "windows", opt(varint(80) + varint(96)) + opt(None) + opt(varint(600) + varint(96)))),
]

if __name__ == "__main__":
    for name, payload in GOLDENS:
        print(f"{name}: {frame(payload).hex(' ')}")
