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
  * protocol 4's Profile (docs/link-and-recordings.md, "Profiles in protocol
    version 4"): row records, each point's position in 1/256 px minus the
    linear prediction 2·p1 − p0 from the laser's previous two, strength as a 4+4-bit float, width in 1/16 px,
    along minus 2·a1 − a0, height in 0.1 µm minus the previous one.
  * the frames named "…-v3" are protocol 3's (version byte 3, Profile with
    every point at full width): the Rust test decodes them.

Run: python3 tests/scripts/golden.py > tests/golden/frames.txt
The Rust test `protocol::goldens_match_the_reference_encoder` compares the
Rust encoder's frames with this file byte for byte.
"""
import struct
import zlib

VERSION = 4


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


def frame(payload, version=VERSION):
    raw = bytes([version]) + payload
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


def point_v3(row, flags=0, um=None):
    return (varint(row) + px(201.5) + varint(1500) + px(2.5) + u8(flags)
            + opt(None if um is None else zz(um[0], 32) + zz(um[1], 32)))


def strength_code(s):
    if s < 16:
        return s
    e = s.bit_length() - 4
    return e * 16 + (s >> (e - 1)) - 16


def predict(seen):
    """0 before any value, the last after one, 2·v1 − v0 after that."""
    return 0 if not seen else seen[-1] if len(seen) == 1 else 2 * seen[-1] - seen[-2]


def profile_v4(seqno, ts, odo, exposure, mask, lasers):
    """lasers: [(laser, [(row, position_px, strength, width_px, flags, (along_um, height_nm) or None)])]"""
    out = varint(seqno) + u8(0) + u8(1) + varint(ts) + zz(odo, 64) + varint(exposure) + u8(mask)
    out += u8(len(lasers)) + b"".join(u8(k) for k, _ in lasers)
    rows = sorted({p[0] for _, pts in lasers for p in pts})
    positions = [[] for _ in lasers]
    along = [[] for _ in lasers]
    last_h = [0] * len(lasers)
    prev = -1
    for r in rows:
        here = [(j, next(p for p in pts if p[0] == r)) for j, (_, pts) in enumerate(lasers) if any(p[0] == r for p in pts)]
        head = 0
        for j, p in here:
            head |= 1 << j
            if p[5] is not None:
                head |= 1 << (3 + j)
            if p[4]:
                head |= 1 << 6
        skip = r - prev - 1
        if skip:
            head |= 1 << 7
        out += u8(head) + (varint(skip) if skip else b"")
        for j, (row, pos, strength, width, flags, metric) in here:
            q = round(pos * 256)
            out += zz(q - predict(positions[j]), 32) + u8(strength_code(strength)) + u8(round(width * 16))
            positions[j].append(q)
            if head & (1 << 6):
                out += u8(flags)
            if metric is not None:
                a, nm = metric
                h = (2 * nm + 100) // 200
                out += zz(a - predict(along[j]), 32) + zz(h - last_h[j], 32)
                along[j].append(a)
                last_h[j] = h
        prev = r
    return out + u8(0)


DEVICE = {"hello": 0, "profile": 1, "status": 2, "ack": 3, "error": 4, "raw": 5}
HOST = {"start": 0, "stop": 1, "exposure": 2, "detector": 3, "calibration": 4, "capture": 5, "info": 6, "heartbeat": 7,
        "trigger": 8, "windows": 9, "readout": 10, "tracking": 11}


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
    ("profile", dev("profile", profile_v4(7, 100000, 25000, 200, 1, [
        (0, [(0, 201.5, 1500, 2.5, 0, None), (1, 201.5, 1500, 2.5, 2, (-1200, 35250))])]))),
    # Lasers 0 and 2: rows with gaps (a one-byte and a two-byte skip), the
    # along prediction's second difference, negative heights, both ends of
    # the strength scale, a row where only one laser has a point.
    ("profile-rows", dev("profile", profile_v4(8, 133333, -4, 100, 5, [
        (0, [(3, 310.25, 158, 3.0, 0, (-33947, -142741)), (4, 310.0, 157, 3.0625, 0, (-33803, -139571)),
             (7, 309.5, 4095, 3.5, 1, (-33370, -145075))]),
        (2, [(4, 512.75, 5, 1.0, 4, None), (300, 498.0, 65535, 6.4375, 0, (9000, 7))])]))),
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
    # Rows 40..440, one in two (a struct variant: its fields in order).
    ("readout", cmd(11, "readout", varint(40) + varint(400) + u8(2))),
    # Tracks of ±12 px (a one-field struct variant: the field).
    ("tracking", cmd(12, "tracking", varint(12))),
]

# Protocol 3's frames that recordings hold (decoded, never written, by this build).
GOLDENS_V3 = [
    ("profile-v3", dev("profile", varint(7) + u8(0) + u8(1) + varint(100000) + zz(25000, 64) + varint(200) + u8(1)
                       + seq([u8(0) + seq([point_v3(0), point_v3(1, flags=2, um=(-1200, 35250))])]))),
    ("hello-v3", dev("hello", string("0.1.0") + u8(3) + string("sim") + varint(752) + varint(480) + u8(12)
                     + default_detector() + varint(0) + varint(2))),
]

if __name__ == "__main__":
    for name, payload in GOLDENS:
        print(f"{name}: {frame(payload).hex(' ')}")
    for name, payload in GOLDENS_V3:
        print(f"{name}: {frame(payload, version=3).hex(' ')}")
