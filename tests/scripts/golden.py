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
  * protocol 5's Profile (docs/link-and-recordings.md, "Profiles in protocol
    version 5"): postcard's header, each entry's metric model (a least-squares
    fit in f32, emulated here by rounding every operation to f32), then a bit
    stream of row records and adaptive Rice codes.
  * the frames named "…-v3" and "…-v4" are protocols 3's and 4's (Profile
    with every point at full width; row records of varints): the Rust test
    decodes them.

Run: python3 tests/scripts/golden.py > tests/golden/frames.txt
The Rust test `protocol::goldens_match_the_reference_encoder` compares the
Rust encoder's frames with this file byte for byte.
"""
import struct
import zlib

VERSION = 5


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


def f32r(x):
    """x rounded to f32 (an f64 operation on f32 operands, rounded once, is the f32 operation)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def fit_v5(pts):
    """The model of one entry: [[c0, c1, c2] along, [c0, c1, c2] height], Q12, as the encoder fits it."""
    first_row = pts[0][0]
    m = [0.0] * 6
    b = [[0.0] * 3 for _ in range(2)]
    last = None
    seen = 0
    for row, pos, _s, _w, _f, metric in pts:
        if metric is None:
            continue
        seen += 1  # one step in four: from the metric point 4i to the next
        if seen % 4 not in (1, 2):
            continue
        q, v = round(pos * 256), [metric[0], (2 * metric[1] + 100) // 200]
        if seen % 4 == 1:
            last = (q, row, v)
            continue
        if last is not None:
            dq = f32r(q - last[0])
            x = [dq, f32r(f32r(dq * f32r(row - first_row)) / 256.0), f32r(row - last[1])]
            for k, (i, j) in enumerate([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]):
                m[k] = f32r(m[k] + f32r(x[i] * x[j]))
            for fld in range(2):
                y = f32r(v[fld] - last[2][fld])
                for k in range(3):
                    b[fld][k] = f32r(b[fld][k] + f32r(x[k] * y))
    return [solve3_v5(m, bf) for bf in b]


def solve3_v5(m, b):
    a, bb, c, d, e, f = m
    mul = lambda x, y: f32r(x * y)
    sub = lambda x, y: f32r(x - y)

    def det3(c0, c1, c2):
        t0 = mul(c0[0], sub(mul(c1[1], c2[2]), mul(c1[2], c2[1])))
        t1 = mul(c1[0], sub(mul(c0[1], c2[2]), mul(c0[2], c2[1])))
        t2 = mul(c2[0], sub(mul(c0[1], c1[2]), mul(c0[2], c1[1])))
        return f32r(sub(t0, t1) + t2)

    def q(v):
        v = f32r(v * 4096.0)
        if not abs(v) < 2.0e9:
            return 0
        return int(f32r(v + 0.5)) if v >= 0 else int(f32r(v - 0.5))

    k0, k1, k2 = [a, bb, c], [bb, d, e], [c, e, f]
    det = det3(k0, k1, k2)
    scale = mul(mul(a, d), f)
    if abs(det) > mul(f32r(1e-4), abs(scale)) and scale != 0.0:
        return [q(f32r(det3(b, k1, k2) / det)), q(f32r(det3(k0, b, k2) / det)), q(f32r(det3(k0, k1, b) / det))]
    return [0, 0, q(f32r(b[2] / f))] if f > 0 else [0, 0, 0]


class Bits:
    def __init__(self):
        self.s = ""

    def put(self, v, n):
        self.s += format(v, f"0{n}b") if n else ""

    def rice(self, z, k, escape):
        if z >> k < 8:
            self.put((1 << (z >> k)) - 1, z >> k)
            self.put(0, 1)
            self.put(z & ((1 << k) - 1), k)
        else:
            self.put(255, 8)
            self.put(z, escape)

    def bytes(self):
        s = self.s + "0" * (-len(self.s) % 8)
        return bytes(int(s[i:i + 8], 2) for i in range(0, len(s), 8))


H_MAX = (2**31 - 1) // 100
FIRST_BITS, ESCAPE_BITS = [24, 8, 8, 32, 26], [26, 9, 9, 32, 27]


def wrap32(v):
    return (v + 2**31) % 2**32 - 2**31


class Entry:
    def __init__(self, model):
        self.model, self.vals, self.metric, self.flags = model, [[], [], []], None, 0
        self.rice = [[16, 1] for _ in range(5)]

    def predict(self, f):
        v = self.vals[f]
        if not v:
            return None
        if f == 0:
            if len(v) == 1:
                return v[-1]
            if len(v) < 8:
                return max(-2**23, min(2**23 - 1, 2 * v[-1] - v[-2]))
            s, d = sum(v[-8:]), sum(v[-4:]) - sum(v[-8:-4])
            return max(-2**23, min(2**23 - 1, (4 * s + 9 * d + 16) >> 5))
        return v[-1] if len(v) < 4 else (sum(v[-4:]) + 2) >> 2

    def predict_metric(self, f, q, r):
        if self.metric is None:
            return None
        q0, r0, v0 = self.metric
        c0, c1, c2 = self.model[f - 3]
        dq = wrap32(q - q0)
        step = (c0 * dq + c2 * (r - r0) + ((c1 * dq * (r - self.first_row)) >> 8) + 2048) >> 12
        v = wrap32(v0[f - 3] + step)
        return max(-H_MAX, min(H_MAX, v)) if f == 4 else v

    def field(self, bits, f, v, pred):
        if pred is None:
            bits.put((v + 2**23) if f == 0 else (v + H_MAX) if f == 4 else v % 2**32, FIRST_BITS[f])
            return
        e = wrap32(v - pred)
        z = 2 * e if e >= 0 else -2 * e - 1
        a, n = self.rice[f]
        k = 0
        while n << k < a:
            k += 1
        bits.rice(z, k, ESCAPE_BITS[f])
        a, n = min(a + z, 2**32 - 1), n + 1
        self.rice[f] = [a >> 1, n >> 1] if n == 32 else [a, n]


def profile_v5(seqno, ts, odo, exposure, mask, lasers):
    """As profile_v4's arguments."""
    out = varint(seqno) + u8(0) + u8(1) + varint(ts) + zz(odo, 64) + varint(exposure) + u8(mask) + u8(len(lasers))
    entries = []
    for k, pts in lasers:
        model = fit_v5(pts) if any(p[5] is not None for p in pts) else None
        out += u8(k | (0x80 if model else 0))
        if model:
            out += b"".join(zz(c, 32) for c in model[0] + model[1])
        entries.append(Entry(model))
    bits = Bits()
    rows = sorted({p[0] for _, pts in lasers for p in pts})
    prev_row, prev_masks = -1, 0
    for r in rows:
        here = [(j, next(p for p in pts if p[0] == r)) for j, (_, pts) in enumerate(lasers) if any(p[0] == r for p in pts)]
        masks = sum(1 << j | (1 << (3 + j) if p[5] is not None else 0) for j, p in here)
        flagged = any(p[4] for _, p in here)
        skip = r - prev_row - 1
        if masks == prev_masks and not skip:
            bits.put(0b01 if flagged else 1, 2 if flagged else 1)
        else:
            bits.put(masks, 8)
            bits.put(flagged << 1 | (skip > 0), 2)
            if skip:
                bits.put(skip, 16)
        for j, (row, pos, strength, width, flags, metric) in here:
            t = entries[j]
            if not t.vals[0]:
                t.first_row = row
            v = [round(pos * 256), strength_code(strength), round(width * 16)]
            for f in range(3):
                t.field(bits, f, v[f], t.predict(f))
            if flagged:
                if not flags:
                    bits.put(0, 1)
                elif flags == t.flags:
                    bits.put(0b10, 2)
                else:
                    bits.put(0b11, 2)
                    bits.put(flags, 8)
            t.flags = flags or t.flags
            if metric is not None:
                mv = [metric[0], (2 * metric[1] + 100) // 200]
                for f in (3, 4):
                    t.field(bits, f, mv[f - 3], t.predict_metric(f, v[0], row))
                t.metric = (v[0], row, mv)
            for f in range(3):
                t.vals[f].append(v[f])
        prev_row, prev_masks = r, masks
    bits.put(0, 8)
    return out + bits.bytes()


DEVICE = {"hello": 0, "profile": 1, "status": 2, "ack": 3, "error": 4, "raw": 5}
HOST = {"start": 0, "stop": 1, "exposure": 2, "detector": 3, "calibration": 4, "capture": 5, "info": 6, "heartbeat": 7,
        "trigger": 8, "windows": 9, "readout": 10, "tracking": 11}


def dev(kind, body=b""):
    return varint(DEVICE[kind]) + body


def cmd(seqno, kind, body=b""):
    return varint(seqno) + varint(HOST[kind]) + body


SAMPLE = (7, 100000, 25000, 200, 1, [(0, [(0, 201.5, 1500, 2.5, 0, None), (1, 201.5, 1500, 2.5, 2, (-1200, 35250))])])
# Lasers 0 and 2: rows with gaps (a one-byte and a two-byte skip), the
# along prediction's second difference, negative heights, both ends of
# the strength scale, a row where only one laser has a point.
ROWS = (8, 133333, -4, 100, 5, [
    (0, [(3, 310.25, 158, 3.0, 0, (-33947, -142741)), (4, 310.0, 157, 3.0625, 0, (-33803, -139571)),
         (7, 309.5, 4095, 3.5, 1, (-33370, -145075))]),
    (2, [(4, 512.75, 5, 1.0, 4, None), (300, 498.0, 65535, 6.4375, 0, (9000, 7))])])
# Protocol 5's predictions at work: laser 1's slanted line of 14 points
# (position from the last 8, strength and width from the last 4), the
# metric model fitted to it, an outlier escaped, flags new and repeated, a
# point without its metric point, a skip; laser 2 without metric points.
LINE = (9, 166666, 70000, 100, 6, [
    (1, [(10, 300.05078125, 150, 2.875, 0, (-28568, -141236)), (11, 300.5078125, 150, 2.875, 0, (-28428, -149833)),
         (12, 300.6875, 150, 2.75, 1, (-28286, -152775)), (13, 301.0078125, 150, 2.875, 1, (-28140, -159162)),
         (14, 301.3515625, 4095, 2.6875, 0, None), (15, 301.8984375, 4095, 2.625, 32, (-27857, -176365)),
         (16, 302.10546875, 150, 2.6875, 1, (-27713, -180134)), (17, 302.50390625, 150, 2.8125, 0, (-27570, -187688)),
         (18, 303.13671875, 150, 3.0, 0, (-27425, -199593)), (19, 343.13671875, 150, 2.75, 0, (-27284, -959628)),
         (20, 303.52734375, 160, 2.9375, 0, (-27138, -207317)), (24, 304.109375, 160, 2.625, 0, (-26568, -218065)),
         (25, 304.43359375, 150, 2.75, 1, (-26424, -224055)), (26, 304.890625, 140, 2.6875, 0, (-26284, -232856))]),
    (2, [(12, 512.5, 90, 2.0, 0, None), (13, 512.25, 88, 2.0625, 0, None)])])

GOLDENS = [
    ("ack", dev("ack", varint(300))),
    ("error", dev("error", opt(varint(5)) + varint(5))),          # HeartbeatLost = 5
    ("error-version", dev("error", opt(None) + varint(2) + u8(2))),  # Version(2)
    ("status", dev("status", varint(1) + u8(7) + varint(1000) + varint(30000) + varint(14400)
                   + varint(0) + varint(52000) + varint(24960) + varint(3) + varint(4096) + varint(6)
                   + varint(120) + opt(None))),
    ("profile", dev("profile", profile_v5(*SAMPLE))),
    ("profile-rows", dev("profile", profile_v5(*ROWS))),
    ("profile-line", dev("profile", profile_v5(*LINE))),
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

# Protocol 4's frames that recordings hold (decoded, never written, by this build).
GOLDENS_V4 = [
    ("profile-v4", dev("profile", profile_v4(*SAMPLE))),
    ("profile-rows-v4", dev("profile", profile_v4(*ROWS))),
    ("hello-v4", dev("hello", string("0.1.0") + u8(4) + string("sim") + varint(752) + varint(480) + u8(12)
                     + default_detector() + varint(0) + varint(2))),
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
    for name, payload in GOLDENS_V4:
        print(f"{name}: {frame(payload, version=4).hex(' ')}")
