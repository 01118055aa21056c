//! Protocol version 5's `Profile`: the points as a bit stream of adaptive
//! Rice codes, the metric point predicted through the pixel point.
//!
//! # What
//! The header is postcard's (varints), then the rows as bits (most
//! significant first, the last byte padded with zeros):
//!
//! ```text
//! profile = seq:varint part:u8 parts:u8 timestamp_us:varint odometer_um:zigzag exposure_us:varint
//!           laser_mask:u8 entries:u8 entry × entries  bits…
//! entry   = laser:u8 (bit 7: a metric model follows)  [model: along c₀ c₁ c₂, height c₀ c₁ c₂, each i32 zigzag]
//! bits    = record … end  0-padding to a byte
//! record  = 1                                   same entries and metric points as the record before,
//!                                               the next row, no flags
//!         | 01                                  the same, with flags
//!         | 00 metrics:3 points:3 flags:1 s:1 [skip:16]   anything else (points ≠ 0; s: skip follows)
//!   points bit j: entry j has a point in this row; metrics bit j: that point carries its metric point
//! end     = 00 000000
//!   row   = previous record's row + 1 + skip (the first record's previous row is −1)
//! point   = position strength width [flags] [along height]   (the entry's fields, in this order)
//! field   = the entry's first value: raw (position 24 bits offset by 2²³, strength 8, width 8,
//!           along 32, height 26 offset by H_MAX)
//!         | after it: Rice(zigzag(value − prediction), k)
//! Rice(z, k) = (z >> k) ones, a zero, the k low bits of z      when z >> k < 8
//!            | 8 ones, z in W bits (position 26, strength 9, width 9, along 32, height 27)
//! flags   = 0 (none) | 10 (the entry's last flags that were not none) | 11 flags:8
//! ```
//!
//! Values are [`compact`](super::compact)'s codes (position 1/256 px,
//! strength's small float, width 1/16 px, along µm, height 0.1 µm): what a
//! host decodes is [`Point::on_wire`], as in version 4.
//!
//! **Predictions**, per entry, from the values decoded before:
//! * position: from the last 8 positions, their mean plus their slope
//!   carried to this row, `(4·S + 9·D + 16) >> 5` (`S` their sum, `D` the
//!   newer four's sum minus the older four's); after fewer, `2·p₁ − p₀`
//!   (`p₁` after one);
//! * strength and width: the mean of the last four, rounded (the last one
//!   after fewer);
//! * along and height: the entry's previous metric point `m` moved by the
//!   model, `v_m + ((c₀·Δq + c₂·Δr + ((c₁·Δq·(r − r₀)) >> 8) + 2¹¹) >> 12)`
//!   with `Δq` and `Δr` the position code and row from `m` to this point and
//!   `r₀` the entry's first row (coefficients Q12, `c₁` per 256 rows;
//!   `i64`, wrapping). Positions and heights are clamped to their range.
//! * `k` of each of the entry's five fields: the least with `n·2ᵏ ≥ a`, `a`
//!   the sum of the field's codes so far and `n` their count (16 and 1 at
//!   first), both halved when `n` reaches 32.
//!
//! # Why
//! A metric point is a smooth function of its pixel point: along the line
//! it moves 143 µm a row, and a pixel more to the side raises it
//! 190 µm. Version 4 predicted it from the metric points alone, so the
//! position's noise (speckle moves a stripe by tenths of a pixel) was paid
//! twice: 2.2 bytes a point for the metric point under incoherent light,
//! 2.9 under laser light. The encoder fits how the metric point follows
//! the position and the row in this frame (least squares over one in four
//! of the entry's steps, the model's six coefficients in the header), so what is left is
//! the rounding of the position to 1/256 px (≈ 3 bits of height) and the
//! rail itself. The fit is the encoder's alone: the decoder applies the
//! coefficients it is sent, in integers, so any coefficients decode
//! exactly (a poor fit costs bytes, never a value). The metric point is
//! still sent (rather than computed again on the host from the pixel point
//! and the calibration): the head computes it from the position before
//! its rounding to 1/256 px, and a recording reads without the
//! calibration it was made with.
//!
//! Whole bytes a field cost version 4 at least a byte each; here a field
//! costs about its entropy: noise of σ codes costs about log₂ σ + 2 bits.
//! Rice codes with a parameter that follows the field's mean (LOCO-I's)
//! stay within about 0.3 bit of that on these fields, with no tables.
//!
//! # Cost
//! The encoder passes over each entry's points twice: once to fit the
//! model (about thirty `f32` operations on one step in four), once to write.
//! Writing a field is its prediction, a loop for `k` and a few shifts;
//! fewer bytes go through the CRC and COBS than in version 4. Decoding
//! mirrors writing, in one pass.
//!
//! # Bounds
//! A point costs at most 26 + 9 + 9 + 32 + 27 escapes (8 bits each) and
//! 10 of flags: 153 bits; a record's head 26: [`MAX_RECORD_BITS`].

use core::fmt;

use serde::de::{Deserializer, SeqAccess, Visitor};
use serde::ser::{self, SerializeTuple, Serializer};
use serde::{Deserialize, Serialize};

use super::compact::{
    bad, height_code, next, position_code, read_header, strength_code, strength_from_code, width_code, write_header,
};
use super::{LASERS, LaserPoints, Metric, Point, Profile};
use crate::fixed::Px;
use crate::peak::Flags;

/// Largest record of one point, bits (a record's head of 26, the point's
/// every field escaped, its flags new).
pub const MAX_RECORD_BITS: usize = 26 + 8 * 5 + 26 + 9 + 9 + 32 + 27 + 10;
/// Largest encoding of the fields before the bits: seq 5, part 1, parts 1,
/// timestamp 10, odometer 10, exposure 5, mask 1, entries 1, each entry 1
/// and its model 6 × 5; and the end record with the padding before and
/// after it, 2.
pub const MAX_HEADER_BYTES: usize = 5 + 1 + 1 + 10 + 10 + 5 + 1 + 1 + LASERS * (1 + 6 * 5) + 2;

/// Fractional bits of a model coefficient.
pub const MODEL_FRAC_BITS: u32 = 12;
/// Codes of a Rice code before its escape.
const LIMIT: u32 = 8;
/// Raw widths of a first value, and of an escaped code.
const FIRST_BITS: [u32; FIELDS] = [24, 8, 8, 32, 26];
const ESCAPE_BITS: [u32; FIELDS] = [26, 9, 9, 32, 27];
const FIELDS: usize = 5;
const POSITION: usize = 0;
const STRENGTH: usize = 1;
const WIDTH: usize = 2;
const ALONG: usize = 3;
const HEIGHT: usize = 4;
/// Bit 7 of an entry's laser byte: a model follows.
const MODEL_FOLLOWS: u8 = 0x80;

const Q_MIN: i32 = -(1 << 23);
const Q_MAX: i32 = (1 << 23) - 1;
const H_MAX: i32 = i32::MAX / super::compact::HEIGHT_STEP_NM;

/// How the metric point of an entry follows its pixel point: along's and
/// height's `[c₀, c₁, c₂]` (Q12, see the module's documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Model(pub [[i32; 3]; 2]);

impl Model {
    /// How far `v` moves from the entry's previous metric point: `dq`, `dr`
    /// the position code and row from it, `dr0` the row from the entry's first.
    fn step(&self, field: usize, dq: i32, dr: i32, dr0: i32) -> i32 {
        let [c0, c1, c2] = self.0[field - ALONG].map(i64::from);
        let (dq, dr, dr0) = (i64::from(dq), i64::from(dr), i64::from(dr0));
        let cross = c1.wrapping_mul(dq).wrapping_mul(dr0) >> 8;
        let sum = c0.wrapping_mul(dq).wrapping_add(c2.wrapping_mul(dr)).wrapping_add(cross);
        (sum.wrapping_add(1 << (MODEL_FRAC_BITS - 1)) >> MODEL_FRAC_BITS) as i32
    }

    /// The least-squares model of an entry's metric steps (`None` without
    /// a point), over one step in four (from the metric point `4i` to the
    /// next: the fit is done once a quarter of the points have spoken, at a
    /// quarter of the cost). `f32`: the fit only has to be good, the decoder
    /// uses what it is sent.
    pub fn fit(points: &[Point]) -> Option<Model> {
        let first_row = i32::from(points.first()?.row);
        let mut m = [0f32; 6]; // xx symmetric: 00 01 02 11 12 22
        let mut b = [[0f32; 3]; 2];
        let mut last: Option<(i32, i32, [i32; 2])> = None;
        let (mut seen, mut steps) = (0u32, 0u32);
        for p in points {
            let Some(metric) = p.metric else { continue };
            seen += 1;
            if seen % 4 > 2 || seen % 4 == 0 {
                continue;
            }
            let (q, r) = (position_code(p.position), i32::from(p.row));
            let v = [metric.along_um, height_code(metric.height_nm)];
            if seen % 4 == 1 {
                last = Some((q, r, v));
                continue;
            }
            if let Some((q0, r0, v0)) = last {
                let dq = q.wrapping_sub(q0) as f32;
                let x = [dq, dq * (r - first_row) as f32 / 256.0, r.wrapping_sub(r0) as f32];
                m[0] += x[0] * x[0];
                m[1] += x[0] * x[1];
                m[2] += x[0] * x[2];
                m[3] += x[1] * x[1];
                m[4] += x[1] * x[2];
                m[5] += x[2] * x[2];
                for (bf, (vi, v0i)) in b.iter_mut().zip(v.iter().zip(v0)) {
                    let y = vi.wrapping_sub(v0i) as f32;
                    for (bk, xk) in bf.iter_mut().zip(x) {
                        *bk += xk * y;
                    }
                }
                steps += 1;
            }
        }
        if steps == 0 {
            return Some(Model::default());
        }
        Some(Model(b.map(|bf| solve3(&m, &bf))))
    }
}

/// `[c₀, c₁, c₂]` (Q12) of the normal equations `m c = b` by Cramer's rule,
/// or of the row term alone where they are singular (a line with no
/// sideways steps), or nothing.
fn solve3(m: &[f32; 6], b: &[f32; 3]) -> [i32; 3] {
    let [a, bb, c, d, e, f] = *m;
    let det3 = |c0: [f32; 3], c1: [f32; 3], c2: [f32; 3]| {
        c0[0] * (c1[1] * c2[2] - c1[2] * c2[1]) - c1[0] * (c0[1] * c2[2] - c0[2] * c2[1])
            + c2[0] * (c0[1] * c1[2] - c0[2] * c1[1])
    };
    let (k0, k1, k2) = ([a, bb, c], [bb, d, e], [c, e, f]);
    let det = det3(k0, k1, k2);
    let scale = a * d * f;
    let q = |v: f32| {
        let v = v * (1 << MODEL_FRAC_BITS) as f32;
        // NaN and infinities: 0.
        if v.abs() >= 2.0e9 || v.is_nan() {
            0
        } else if v >= 0.0 {
            (v + 0.5) as i32
        } else {
            (v - 0.5) as i32
        }
    };
    if det.is_finite() && scale.is_finite() && det.abs() > 1e-4 * scale.abs() && scale != 0.0 {
        return [det3(*b, k1, k2) / det, det3(k0, *b, k2) / det, det3(k0, k1, *b) / det].map(q);
    }
    if f > 0.0 { [0, 0, q(b[2] / f)] } else { [0; 3] }
}

/// What one entry's predictions start from.
#[derive(Clone, Copy)]
struct Track {
    /// Position, strength, width: the last 8 values, the newest at
    /// `(seen - 1) % 8`.
    recent: [[i32; 8]; 3],
    seen: u32,
    /// Sums of the newest four positions and of the four before them
    /// (`S = new + old`, `D = new − old`); within ±2²⁵ each.
    sums: [i32; 2],
    /// The last metric point: position code, row, along, height code.
    metric: Option<(i32, i32, [i32; 2])>,
    first_row: i32,
    flags: u8,
    /// `a`, `n` of each field's Rice parameter.
    rice: [(u32, u32); FIELDS],
    model: Model,
}

impl Track {
    fn new(model: Model) -> Track {
        Track {
            recent: [[0; 8]; 3],
            seen: 0,
            sums: [0; 2],
            metric: None,
            first_row: 0,
            flags: 0,
            rice: [(16, 1); FIELDS],
            model,
        }
    }

    fn back(&self, f: usize, i: u32) -> i32 {
        self.recent[f][((self.seen - i) % 8) as usize]
    }

    /// The prediction of position, strength or width (`None`: a first value).
    fn predict(&self, f: usize) -> Option<i32> {
        let n = self.seen;
        match (f, n) {
            (_, 0) => None,
            (POSITION, 1) => Some(self.back(f, 1)),
            (POSITION, 2..=7) => {
                let v = 2 * i64::from(self.back(f, 1)) - i64::from(self.back(f, 2));
                Some(v.clamp(Q_MIN.into(), Q_MAX.into()) as i32)
            }
            (POSITION, _) => {
                // (4·S + 9·D + 16) >> 5 = (13·new − 5·old + 16) >> 5: within ±2²⁹·¹.
                let [new, old] = self.sums;
                Some(((13 * new - 5 * old + 16) >> 5).clamp(Q_MIN, Q_MAX))
            }
            (_, 1..=3) => Some(self.back(f, 1)),
            _ => Some((self.back(f, 1) + self.back(f, 2) + self.back(f, 3) + self.back(f, 4) + 2) >> 2),
        }
    }

    fn push(&mut self, row: i32, v: [i32; 3]) {
        if self.seen == 0 {
            self.first_row = row;
        }
        // The position leaving the newest four joins the older four, the
        // one leaving the eight goes (zeros before there were that many).
        let q = &self.recent[POSITION];
        let (fourth, eighth) = (q[(self.seen.wrapping_sub(4) % 8) as usize], q[(self.seen % 8) as usize]);
        let (fourth, eighth) = (if self.seen >= 4 { fourth } else { 0 }, if self.seen >= 8 { eighth } else { 0 });
        self.sums = [self.sums[0] + v[POSITION] - fourth, self.sums[1] + fourth - eighth];
        for (r, x) in self.recent.iter_mut().zip(v) {
            r[(self.seen % 8) as usize] = x;
        }
        // At most MAX_ROWS_PER_PROFILE points an entry: no wrap.
        self.seen += 1;
    }

    /// The prediction of along or height at position code `q`, row `r`.
    fn predict_metric(&self, f: usize, q: i32, r: i32) -> Option<i32> {
        let (q0, r0, v0) = self.metric?;
        let v = v0[f - ALONG].wrapping_add(self.model.step(f, q.wrapping_sub(q0), r - r0, r - self.first_row));
        Some(if f == HEIGHT { v.clamp(-H_MAX, H_MAX) } else { v })
    }

    /// The least `k` with `n·2ᵏ ≥ a`: from the bit lengths (`n·2ᵏ` has
    /// `a`'s when `k` is their difference), one more if that falls short.
    fn k(&self, f: usize) -> u32 {
        let (a, n) = self.rice[f];
        let k = n.leading_zeros().saturating_sub(a.leading_zeros());
        k + u32::from((u64::from(n) << k) < u64::from(a))
    }

    fn adapt(&mut self, f: usize, z: u32) {
        let (a, n) = &mut self.rice[f];
        *a = a.saturating_add(z);
        *n += 1;
        if *n == 32 {
            *a >>= 1;
            *n >>= 1;
        }
    }
}

fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

fn unzigzag(z: u32) -> i32 {
    ((z >> 1) as i32) ^ -((z & 1) as i32)
}

/// A first value as raw bits.
fn first_raw(f: usize, v: i32) -> u32 {
    match f {
        POSITION => v.wrapping_sub(Q_MIN) as u32,
        HEIGHT => v.wrapping_add(H_MAX) as u32,
        _ => v as u32,
    }
}

fn first_value(f: usize, raw: u32) -> Option<i32> {
    match f {
        POSITION => Some((raw as i32).wrapping_add(Q_MIN)),
        HEIGHT => (raw <= 2 * H_MAX as u32).then(|| raw as i32 - H_MAX),
        _ => Some(raw as i32),
    }
}

/// Bits into postcard's output, a byte at a time.
struct BitWriter<T> {
    out: T,
    acc: u64,
    bits: u32,
}

impl<T: SerializeTuple> BitWriter<T> {
    /// The low `n` (≤ 32) bits of `v`.
    #[inline(always)]
    fn put(&mut self, v: u32, n: u32) -> Result<(), T::Error> {
        if n == 0 {
            return Ok(());
        }
        self.acc = (self.acc << n) | u64::from(v & (u32::MAX >> (32 - n)));
        self.bits += n;
        while self.bits >= 8 {
            self.bits -= 8;
            self.out.serialize_element(&((self.acc >> self.bits) as u8))?;
        }
        Ok(())
    }

    fn rice(&mut self, z: u32, k: u32, escape: u32) -> Result<(), T::Error> {
        let q = u64::from(z) >> k;
        if q < u64::from(LIMIT) {
            let q = q as u32;
            // q ones and a zero, then z's k low bits: in one go when they
            // fit 32 bits (z's bits above k are q's).
            if q + 1 + k <= 32 {
                let low = u64::from(z) & ((1u64 << k) - 1);
                return self.put(((((1u64 << q) - 1) << (k + 1)) | low) as u32, q + 1 + k);
            }
            self.put(((1 << q) - 1) << 1, q + 1)?;
            let low = if k >= 32 { z } else { z & ((1u32 << k) - 1) };
            self.put(low, k.min(32))
        } else {
            self.put((1 << LIMIT) - 1, LIMIT)?;
            self.put(z, escape)
        }
    }

    /// The last byte, padded with zeros.
    fn finish(mut self) -> Result<T, T::Error> {
        if self.bits > 0 {
            let pad = 8 - self.bits;
            self.put(0, pad)?;
        }
        Ok(self.out)
    }
}

/// Writes one field of an entry's point.
fn write_field<T: SerializeTuple>(
    w: &mut BitWriter<T>,
    t: &mut Track,
    f: usize,
    v: i32,
    pred: Option<i32>,
) -> Result<(), T::Error> {
    match pred {
        None => w.put(first_raw(f, v), FIRST_BITS[f]),
        Some(p) => {
            let z = zigzag(v.wrapping_sub(p));
            w.rice(z, t.k(f), ESCAPE_BITS[f])?;
            t.adapt(f, z);
            Ok(())
        }
    }
}

impl Serialize for Profile {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // postcard writes a tuple's elements without a length: the bytes
        // stream into the frame as they are made.
        let mut t = s.serialize_tuple(usize::MAX)?;
        write_header(&mut t, self)?;
        let mut tracks = [Track::new(Model::default()); LASERS];
        for (lp, track) in self.lasers.iter().zip(tracks.iter_mut()) {
            let model = if lp.points.iter().any(|p| p.metric.is_some()) { Model::fit(&lp.points) } else { None };
            t.serialize_element(&(lp.laser | if model.is_some() { MODEL_FOLLOWS } else { 0 }))?;
            if let Some(m) = model {
                for c in m.0.iter().flatten() {
                    t.serialize_element(c)?;
                }
                track.model = m;
            }
        }
        let mut w = BitWriter { out: t, acc: 0, bits: 0 };
        let mut next = [0usize; LASERS];
        let mut previous_row = -1i32;
        let mut previous_masks = 0u8;
        let at = |next: &[usize; LASERS], j: usize| self.lasers[j].points.get(next[j]);
        while let Some(row) = (0..self.lasers.len()).filter_map(|j| at(&next, j)).map(|p| p.row).min() {
            let skip = i32::from(row) - previous_row - 1;
            if skip < 0 {
                return Err(ser::Error::custom("a laser's points are not in ascending rows"));
            }
            let (mut masks, mut flagged) = (0u8, false);
            for j in 0..self.lasers.len() {
                if let Some(p) = at(&next, j).filter(|p| p.row == row) {
                    masks |= 1 << j;
                    masks |= u8::from(p.metric.is_some()) << (3 + j);
                    flagged |= p.flags != Flags::NONE;
                }
            }
            if masks == previous_masks && skip == 0 {
                // 1: no flags; 01: flags.
                w.put(1, 1 + u32::from(flagged))?;
            } else {
                w.put(u32::from(masks), 8)?;
                w.put(u32::from(flagged) << 1 | u32::from(skip > 0), 2)?;
                if skip > 0 {
                    w.put(skip as u32, 16)?;
                }
            }
            for j in 0..self.lasers.len() {
                if masks & (1 << j) == 0 {
                    continue;
                }
                let p = &self.lasers[j].points[next[j]];
                next[j] += 1;
                write_point(&mut w, &mut tracks[j], p, flagged)?;
            }
            previous_row = i32::from(row);
            previous_masks = masks;
        }
        w.put(0, 8)?;
        w.finish()?.end()
    }
}

fn write_point<T: SerializeTuple>(
    w: &mut BitWriter<T>,
    t: &mut Track,
    p: &Point,
    flagged: bool,
) -> Result<(), T::Error> {
    let row = i32::from(p.row);
    let v = [position_code(p.position), i32::from(strength_code(p.strength)), i32::from(width_code(p.width))];
    for f in [POSITION, STRENGTH, WIDTH] {
        write_field(w, t, f, v[f], t.predict(f))?;
    }
    if flagged {
        match p.flags.0 {
            0 => w.put(0, 1)?,
            x if x == t.flags => w.put(0b10, 2)?,
            x => {
                w.put(0b11, 2)?;
                w.put(u32::from(x), 8)?;
            }
        }
    }
    if p.flags.0 != 0 {
        t.flags = p.flags.0;
    }
    if let Some(m) = p.metric {
        let mv = [m.along_um, height_code(m.height_nm)];
        for f in [ALONG, HEIGHT] {
            write_field(w, t, f, mv[f - ALONG], t.predict_metric(f, v[POSITION], row))?;
        }
        t.metric = Some((v[POSITION], row, mv));
    }
    t.push(row, v);
    Ok(())
}

impl<'de> Deserialize<'de> for Profile {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Profile, D::Error> {
        d.deserialize_tuple(usize::MAX, ProfileVisitor)
    }
}

struct ProfileVisitor;

/// Bits out of postcard's input, a byte at a time.
struct BitReader<A> {
    seq: A,
    acc: u64,
    bits: u32,
}

impl<'de, A: SeqAccess<'de>> BitReader<A> {
    /// `n` (≤ 32) bits.
    fn get(&mut self, n: u32) -> Result<u32, A::Error> {
        while self.bits < n {
            let b: u8 = next(&mut self.seq)?;
            self.acc = (self.acc << 8) | u64::from(b);
            self.bits += 8;
        }
        self.bits -= n;
        Ok(((self.acc >> self.bits) & ((1u64 << n) - 1)) as u32)
    }

    fn rice(&mut self, k: u32, escape: u32) -> Result<u32, A::Error> {
        let mut q = 0;
        while q < LIMIT && self.get(1)? == 1 {
            q += 1;
        }
        if q == LIMIT {
            let z = self.get(escape)?;
            if u64::from(z) >> k < u64::from(LIMIT) {
                return Err(bad("an escaped code that fits the Rice code"));
            }
            return Ok(z);
        }
        let low = self.get(k.min(32))?;
        u32::try_from((u64::from(q) << k) | u64::from(low)).map_err(|_| bad("a Rice code past 32 bits"))
    }
}

fn read_field<'de, A: SeqAccess<'de>>(
    r: &mut BitReader<A>,
    t: &mut Track,
    f: usize,
    pred: Option<i32>,
) -> Result<i32, A::Error> {
    match pred {
        None => first_value(f, r.get(FIRST_BITS[f])?).ok_or_else(|| bad("a first value out of range")),
        Some(p) => {
            let z = r.rice(t.k(f), ESCAPE_BITS[f])?;
            t.adapt(f, z);
            Ok(p.wrapping_add(unzigzag(z)))
        }
    }
}

impl<'de> Visitor<'de> for ProfileVisitor {
    type Value = Profile;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a protocol 5 profile")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Profile, A::Error> {
        let (mut p, entries) = read_header(&mut a)?;
        let mut tracks = [Track::new(Model::default()); LASERS];
        let mut modelled = 0u8;
        for (j, track) in tracks.iter_mut().enumerate().take(usize::from(entries)) {
            let byte: u8 = next(&mut a)?;
            let laser = byte & !MODEL_FOLLOWS;
            if usize::from(laser) >= LASERS {
                return Err(bad("no such laser"));
            }
            if byte & MODEL_FOLLOWS != 0 {
                let mut m = Model::default();
                for c in m.0.iter_mut().flatten() {
                    *c = next(&mut a)?;
                }
                track.model = m;
                modelled |= 1 << j;
            }
            p.lasers.push(LaserPoints { laser, points: heapless::Vec::new() }).map_err(|_| bad("too many entries"))?;
        }
        let mut r = BitReader { seq: a, acc: 0, bits: 0 };
        let mut previous_row = -1i64;
        let mut previous_masks = 0u8;
        let mut metrics_seen = 0u8;
        loop {
            let (masks, flagged, skip) = if r.get(1)? == 1 {
                (previous_masks, false, 0)
            } else if r.get(1)? == 1 {
                (previous_masks, true, 0)
            } else {
                let masks = r.get(6)? as u8;
                if masks == 0 {
                    break;
                }
                let flagged = r.get(1)? == 1;
                let skip = if r.get(1)? == 1 { r.get(16)? } else { u32::MAX };
                let skip = match skip {
                    0 => return Err(bad("a skip of no rows")),
                    u32::MAX => 0,
                    s => s,
                };
                if masks == previous_masks && skip == 0 {
                    return Err(bad("a long record head where a short one says it"));
                }
                (masks, flagged, skip)
            };
            let points = masks & 7;
            let metrics = masks >> 3;
            if points == 0 || points >> entries != 0 || metrics & !points != 0 {
                return Err(bad("a row record names no point, or an entry that is not there"));
            }
            if metrics & !modelled != 0 {
                return Err(bad("a metric point of an entry without a model"));
            }
            let row = previous_row + 1 + i64::from(skip);
            let row = u16::try_from(row).map_err(|_| bad("row past 65535"))?;
            let mut any_flags = false;
            for (j, track) in tracks.iter_mut().enumerate().take(usize::from(entries)) {
                if points & (1 << j) == 0 {
                    continue;
                }
                let point = read_point(&mut r, track, row, flagged, metrics & (1 << j) != 0)?;
                any_flags |= point.flags != Flags::NONE;
                p.lasers[j].points.push(point).map_err(|_| bad("more points than rows"))?;
            }
            // One encoding per profile: a row is flagged only when a point's flags are set.
            if flagged && !any_flags {
                return Err(bad("a flagged row with no flags"));
            }
            metrics_seen |= metrics;
            previous_row = i64::from(row);
            previous_masks = masks;
        }
        if r.acc & ((1 << r.bits) - 1) != 0 {
            return Err(bad("padding that is not zero"));
        }
        if modelled & !metrics_seen != 0 {
            return Err(bad("a model for an entry without metric points"));
        }
        Ok(p)
    }
}

fn read_point<'de, A: SeqAccess<'de>>(
    r: &mut BitReader<A>,
    t: &mut Track,
    row: u16,
    flagged: bool,
    metric: bool,
) -> Result<Point, A::Error> {
    let rw = i32::from(row);
    let mut v = [0i32; 3];
    for f in [POSITION, STRENGTH, WIDTH] {
        v[f] = read_field(r, t, f, t.predict(f))?;
    }
    if !(Q_MIN..=Q_MAX).contains(&v[POSITION]) {
        return Err(bad("position out of range"));
    }
    let position = Px(v[POSITION] << (16 - super::compact::POSITION_FRAC_BITS));
    let strength =
        u8::try_from(v[STRENGTH]).ok().and_then(strength_from_code).ok_or_else(|| bad("no such strength"))?;
    let width = u8::try_from(v[WIDTH]).map_err(|_| bad("no such width"))?;
    let width = Px(i32::from(width) << (16 - super::compact::WIDTH_FRAC_BITS));
    let flags = if !flagged || r.get(1)? == 0 {
        0
    } else if r.get(1)? == 0 {
        if t.flags == 0 {
            return Err(bad("the last flags of an entry that had none"));
        }
        t.flags
    } else {
        let x = r.get(8)? as u8;
        if x == 0 || x == t.flags {
            return Err(bad("new flags that are none or the last"));
        }
        x
    };
    if flags != 0 {
        t.flags = flags;
    }
    let metric = if metric {
        let mut mv = [0i32; 2];
        for f in [ALONG, HEIGHT] {
            mv[f - ALONG] = read_field(r, t, f, t.predict_metric(f, v[POSITION], rw))?;
        }
        if !(-H_MAX..=H_MAX).contains(&mv[1]) {
            return Err(bad("height out of range"));
        }
        t.metric = Some((v[POSITION], rw, mv));
        Some(Metric { along_um: mv[0], height_nm: mv[1] * super::compact::HEIGHT_STEP_NM })
    } else {
        None
    };
    t.push(rw, v);
    Ok(Point { row, position, strength, width, flags: Flags(flags), metric })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(
        n: u16,
        metric: impl Fn(i32, i32) -> (i32, i32),
    ) -> heapless::Vec<Point, { super::super::MAX_ROWS_PER_PROFILE }> {
        (0..n)
            .map(|r| {
                // 300 px, 0.2 px a row, a wobble of ±0.3 px.
                let q = 300 * 256 + 51 * i32::from(r) + [0, 77, -40, 13, -77][usize::from(r) % 5];
                let (along_um, h) = metric(q, i32::from(r));
                Point {
                    row: r + 10,
                    position: Px(q << 8),
                    strength: 150,
                    width: Px(3 << 16),
                    flags: Flags::NONE,
                    metric: Some(Metric { along_um, height_nm: h * 100 }),
                }
            })
            .collect()
    }

    /// The fit finds a metric point that follows the position and the row
    /// exactly (up to the Q12 rounding of its coefficients).
    #[test]
    fn the_model_fits_a_linear_map() {
        let pts = line(200, |q, r| (-34_000 + 143 * r + (q - 300 * 256), -1_400 - 7 * (q - 300 * 256) + 2 * r));
        let Model([along, height]) = Model::fit(&pts).unwrap();
        let near = |c: i32, want: f64| (f64::from(c) / 4096.0 - want).abs() < 2e-3;
        assert!(near(along[0], 1.0) && near(along[2], 143.0) && along[1].abs() < 8, "{along:?}");
        assert!(near(height[0], -7.0) && near(height[2], 2.0) && height[1].abs() < 8, "{height:?}");
    }

    /// The predictions leave only rounding: such a line costs under 2 bytes
    /// a point with its metric point, and decodes to itself.
    #[test]
    fn a_predicted_line_is_cheap_and_exact() {
        let pts = line(480, |q, r| (-34_000 + 143 * r, -1_400 - (37 * (q - 300 * 256)) / 5));
        let mut lasers = heapless::Vec::new();
        lasers.push(LaserPoints { laser: 0, points: pts }).unwrap();
        let p = Profile { lasers, ..Profile::empty() };
        let mut buf = [0u8; 4096];
        let bytes = postcard::to_slice(&p, &mut buf).unwrap();
        assert!(bytes.len() < 2 * 480, "{} bytes", bytes.len());
        let back: Profile = postcard::from_bytes(bytes).unwrap();
        assert_eq!(back, p.on_wire());
    }

    #[test]
    fn zigzag_inverts() {
        for v in [0, 1, -1, 2, -2, i32::MAX, i32::MIN, 12345, -98765] {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
    }
}
