//! Protocol version 4's compact `Profile`, read from recordings
//! ([`v4`](super::v4)), and the quantisation protocol 5 shares
//! ([`packed`](super::packed) sends the same codes: [`Point::on_wire`]).
//!
//! # What
//! A [`Profile`] is written in row order, one *row record* per image row
//! that has a point, instead of per laser with every field at full width:
//!
//! ```text
//! profile = seq:varint part:u8 parts:u8 timestamp_us:varint odometer_um:zigzag exposure_us:varint
//!           laser_mask:u8 entries:u8 laser:u8 × entries  row record …  0x00
//! record  = head:u8 [skip:varint] point × popcount(head & 7)
//!   head  bit j (0–2): entry j (of `lasers`) has a point in this row (never all clear: 0x00 ends the rows)
//!         bit 3 + j:   that point carries its metric point
//!         bit 6:       each point of the record has a flags byte (else its flags are 0)
//!         bit 7:       `skip` follows (non-zero): rows without points before this one
//!   row   = previous record's row + 1 + skip (the first record's previous row is −1)
//! point   = position:zigzag  1/256 px, minus the linear prediction 2·p₁ − p₀ from the entry's
//!                            previous two positions (p₁ after one, 0 before any)
//!           strength:u8      4-bit exponent, 4-bit mantissa ([`strength_code`])
//!           width:u8         1/16 px, saturating at 255
//!           [flags:u8]       with head bit 6
//!           [along:zigzag    µm, minus the linear prediction 2·a₁ − a₀ from the entry's previous two
//!                            metric points (a₁ after one, 0 before any)
//!            height:zigzag]  0.1 µm, minus the entry's previous metric height (0 before any)
//! ```
//!
//! Varints and zigzag are postcard's (the whole profile is one postcard
//! tuple, so it streams into the frame with no buffer of its own).
//!
//! # Why
//! Protocol 3 spent 12.8 bytes a point without a metric point and 19 with
//! one (Q16.16 varints, a full-width row per point): 1.1–1.7 × what USB full
//! speed carries at 60 frames/s of 1 440 points. Here a point of the
//! calibrated reference head is about 5.5 bytes: neighbouring rows' stripe
//! centres differ by well under a pixel (one byte in 1/256 px), the rows
//! along a laser line step evenly (a second difference of a few µm), and
//! heights change by a few µm a row. The resolutions stay far below the
//! noise they carry: 1/256 px (1.1·10⁻³ px RMS of rounding) against a
//! detector's ≥ 10⁻² px, 0.1 µm (0.029 µm RMS) against the analysis's 1 µm
//! budget; strength (6 % steps) and width (1/16 px) are diagnostics.
//!
//! # Cost
//! One pass over the points in row order (a three-way merge of the lasers'
//! lists) with a few integer operations a point; decoding the same. The
//! linear predictions make a slanted line (a stripe moving 0.5 px a row)
//! cost what a straight one does. The
//! quantisation is exact to invert: [`Point::on_wire`] is what a decoder
//! gets back, and encoding it again gives the same bytes.

use core::fmt;

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::ser::{self, SerializeTuple, Serializer};
use serde::{Deserialize, Serialize};

use super::{LASERS, LaserPoints, Metric, Point, Profile};
use crate::fixed::Px;
use crate::peak::Flags;

/// Fractional bits of a position on the wire: 1/256 px.
pub const POSITION_FRAC_BITS: u32 = 8;
/// Fractional bits of a width on the wire: 1/16 px.
pub const WIDTH_FRAC_BITS: u32 = 4;
/// A height on the wire is a multiple of this, nm (0.1 µm).
pub const HEIGHT_STEP_NM: i32 = 100;

/// Largest strength code ([`strength_code`] of 65 535).
pub const MAX_STRENGTH_CODE: u8 = 12 * 16 + 15;

/// Largest encoding of a point: position 4 (24-bit values: a prediction
/// error under 2²⁵), strength 1, width 1, flags 1, along 5, height 4 (a
/// difference of two values under 2²⁵).
pub const MAX_POINT_BYTES: usize = 4 + 1 + 1 + 1 + 5 + 4;
/// Largest encoding of a record's head: the byte and a skip of up to 65 535 rows.
pub const MAX_RECORD_BYTES: usize = 1 + 3;
/// Largest encoding of the fields before the records, and the end byte:
/// seq 5, part 1, parts 1, timestamp 10, odometer 10, exposure 5, mask 1,
/// entries 1 + 3, end 1.
pub const MAX_HEADER_BYTES: usize = 5 + 1 + 1 + 10 + 10 + 5 + 1 + 1 + LASERS + 1;

const POINTS: u8 = 0b0000_0111;
const METRIC_SHIFT: u32 = 3;
const FLAGS_FOLLOW: u8 = 1 << 6;
const SKIP_FOLLOWS: u8 = 1 << 7;

/// Position range on the wire (Q16.16 shifted right by 8 fits 24 bits).
const Q_MIN: i32 = i32::MIN >> (16 - POSITION_FRAC_BITS);
const Q_MAX: i32 = i32::MAX >> (16 - POSITION_FRAC_BITS);
/// Height range on the wire, in [`HEIGHT_STEP_NM`].
const H_MAX: i32 = i32::MAX / HEIGHT_STEP_NM;
const H_MIN: i32 = -H_MAX;

/// A position in 1/256 px, rounded half up, saturating.
pub fn position_code(p: Px) -> i32 {
    const SHIFT: u32 = 16 - POSITION_FRAC_BITS;
    (((p.0 >> (SHIFT - 1)) + 1) >> 1).clamp(Q_MIN, Q_MAX)
}

fn position_from_code(q: i32) -> Option<Px> {
    // Not `then_some`: the shift must not run on a value out of range.
    if (Q_MIN..=Q_MAX).contains(&q) { Some(Px(q << (16 - POSITION_FRAC_BITS))) } else { None }
}

/// A width in 1/16 px, rounded half up, saturating at 0 and 255.
pub fn width_code(w: Px) -> u8 {
    const SHIFT: u32 = 16 - WIDTH_FRAC_BITS;
    (((w.0 >> (SHIFT - 1)) + 1) >> 1).clamp(0, 255) as u8
}

fn width_from_code(c: u8) -> Px {
    Px(i32::from(c) << (16 - WIDTH_FRAC_BITS))
}

/// A height in [`HEIGHT_STEP_NM`], rounded half up, saturating.
pub fn height_code(nm: i32) -> i32 {
    // In `i32` where `2·nm + step` fits (a division by a constant the
    // compiler turns into a multiplication; the head's heights are all
    // there), else in `i64` (a library division on the head).
    const FITS: i32 = i32::MAX / 2 - HEIGHT_STEP_NM;
    if (-FITS..=FITS).contains(&nm) {
        return (nm * 2 + HEIGHT_STEP_NM).div_euclid(2 * HEIGHT_STEP_NM);
    }
    let step = i64::from(HEIGHT_STEP_NM);
    ((i64::from(nm) * 2 + step).div_euclid(2 * step)).clamp(i64::from(H_MIN), i64::from(H_MAX)) as i32
}

fn height_from_code(h: i32) -> Option<i32> {
    if (H_MIN..=H_MAX).contains(&h) { Some(h * HEIGHT_STEP_NM) } else { None }
}

/// A strength as a small float: below 16 the count itself; above, a 4-bit
/// exponent `e` (1–12) and the 4 bits after the leading one, `16·e + m`
/// for `(16 + m)·2^(e−1)` counts (steps of 1/16 to 1/32 of the value).
pub fn strength_code(s: u16) -> u8 {
    if s < 16 {
        return s as u8;
    }
    let bits = 16 - s.leading_zeros(); // 5..=16
    let e = bits - 4;
    let m = u32::from(s >> (e - 1)) - 16;
    (e * 16 + m) as u8
}

/// The strength a code stands for: the middle of its step. `None` above
/// [`MAX_STRENGTH_CODE`].
pub fn strength_from_code(c: u8) -> Option<u16> {
    let (e, m) = (u32::from(c >> 4), u32::from(c & 15));
    match e {
        0 => Some(m as u16),
        1..=12 => Some((((16 + m) << (e - 1)) + ((1 << (e - 1)) >> 1)) as u16),
        _ => None,
    }
}

impl Point {
    /// The point as protocol versions 4 and 5 carry it: what a host decodes from
    /// this point's bytes (position to 1/256 px, strength to its step, width
    /// to 1/16 px, height to 0.1 µm; row, flags and along unchanged).
    pub fn on_wire(&self) -> Point {
        Point {
            row: self.row,
            position: position_from_code(position_code(self.position)).unwrap_or(Px::ZERO),
            strength: strength_from_code(strength_code(self.strength)).unwrap_or(0),
            width: width_from_code(width_code(self.width)),
            flags: self.flags,
            metric: self.metric.map(|m| Metric {
                along_um: m.along_um,
                height_nm: height_from_code(height_code(m.height_nm)).unwrap_or(0),
            }),
        }
    }
}

impl Profile {
    /// The profile as protocol versions 4 and 5 carry it ([`Point::on_wire`]
    /// for every point).
    pub fn on_wire(&self) -> Profile {
        let mut p = self.clone();
        for lp in p.lasers.iter_mut() {
            for pt in lp.points.iter_mut() {
                *pt = pt.on_wire();
            }
        }
        p
    }
}

/// A linear prediction from the last two values of a sequence: 0 before
/// any, the last after one, 2·v₁ − v₀ after that (wrapping: encoder and
/// decoder wrap alike, so any value round-trips).
#[derive(Clone, Copy, Default)]
struct Linear {
    last: [i32; 2],
    seen: u8,
}

impl Linear {
    fn predict(&self) -> i32 {
        match self.seen {
            0 => 0,
            1 => self.last[1],
            _ => self.last[1].wrapping_mul(2).wrapping_sub(self.last[0]),
        }
    }

    fn push(&mut self, v: i32) {
        self.last = [self.last[1], v];
        self.seen = self.seen.saturating_add(1);
    }
}

/// What the predictions of one entry (one laser's points) start from.
#[derive(Clone, Copy, Default)]
struct Track {
    position: Linear,
    along: Linear,
    height: i32,
}

/// Writes `p` in version 4's encoding (for `#[serde(with)]`).
pub(super) fn serialize<S: Serializer>(p: &Profile, s: S) -> Result<S::Ok, S::Error> {
    V4(p).serialize(s)
}

/// Reads a profile in version 4's encoding (for `#[serde(with)]`).
pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Profile, D::Error> {
    d.deserialize_tuple(usize::MAX, ProfileVisitor)
}

/// A profile to write in version 4's encoding.
struct V4<'a>(&'a Profile);

impl Serialize for V4<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let profile = self.0;
        // postcard writes a tuple's elements without a length: the records
        // stream into the frame as they are made.
        let mut t = s.serialize_tuple(usize::MAX)?;
        write_header(&mut t, profile)?;
        for lp in &profile.lasers {
            t.serialize_element(&lp.laser)?;
        }
        let mut next = [0usize; LASERS];
        let mut tracks = [Track::default(); LASERS];
        let mut previous_row = -1i32;
        fn at<'p>(next: &[usize; LASERS], j: usize, lp: &'p LaserPoints) -> Option<&'p Point> {
            lp.points.get(next[j])
        }
        while let Some(row) =
            profile.lasers.iter().enumerate().filter_map(|(j, lp)| at(&next, j, lp)).map(|p| p.row).min()
        {
            let skip = i32::from(row) - previous_row - 1;
            if skip < 0 {
                return Err(ser::Error::custom("a laser's points are not in ascending rows"));
            }
            let mut head = if skip > 0 { SKIP_FOLLOWS } else { 0 };
            for (j, lp) in profile.lasers.iter().enumerate() {
                if let Some(p) = at(&next, j, lp).filter(|p| p.row == row) {
                    head |= 1 << j;
                    if p.metric.is_some() {
                        head |= 1 << (METRIC_SHIFT as usize + j);
                    }
                    if p.flags != Flags::NONE {
                        head |= FLAGS_FOLLOW;
                    }
                }
            }
            t.serialize_element(&head)?;
            if skip > 0 {
                t.serialize_element(&(skip as u32))?;
            }
            for (j, lp) in profile.lasers.iter().enumerate() {
                if head & (1 << j) == 0 {
                    continue;
                }
                let p = &lp.points[next[j]];
                next[j] += 1;
                let track = &mut tracks[j];
                let q = position_code(p.position);
                t.serialize_element(&q.wrapping_sub(track.position.predict()))?;
                track.position.push(q);
                t.serialize_element(&strength_code(p.strength))?;
                t.serialize_element(&width_code(p.width))?;
                if head & FLAGS_FOLLOW != 0 {
                    t.serialize_element(&p.flags.0)?;
                }
                if let Some(m) = p.metric {
                    let h = height_code(m.height_nm);
                    t.serialize_element(&m.along_um.wrapping_sub(track.along.predict()))?;
                    t.serialize_element(&h.wrapping_sub(track.height))?;
                    track.along.push(m.along_um);
                    track.height = h;
                }
            }
            previous_row = i32::from(row);
        }
        t.serialize_element(&0u8)?;
        t.end()
    }
}

struct ProfileVisitor;

/// The next element of a profile's tuple (protocols 4 and 5).
pub(super) fn next<'de, T: Deserialize<'de>, A: SeqAccess<'de>>(a: &mut A) -> Result<T, A::Error> {
    a.next_element()?.ok_or_else(|| de::Error::custom("the profile ends early"))
}

pub(super) fn bad<E: de::Error>(what: &'static str) -> E {
    E::custom(what)
}

/// A profile's header as protocols 4 and 5 write it: its fields before
/// the laser entries, then the number of entries.
pub(super) fn write_header<T: SerializeTuple>(t: &mut T, p: &Profile) -> Result<(), T::Error> {
    t.serialize_element(&p.seq)?;
    t.serialize_element(&p.part)?;
    t.serialize_element(&p.parts)?;
    t.serialize_element(&p.timestamp_us)?;
    t.serialize_element(&p.odometer_um)?;
    t.serialize_element(&p.exposure_us)?;
    t.serialize_element(&p.laser_mask)?;
    t.serialize_element(&(p.lasers.len() as u8))
}

/// [`write_header`]'s fields read back: a profile without points, and
/// its number of laser entries (checked against [`LASERS`]).
pub(super) fn read_header<'de, A: SeqAccess<'de>>(a: &mut A) -> Result<(Profile, u8), A::Error> {
    let mut p = Profile::empty();
    p.seq = next(a)?;
    p.part = next(a)?;
    p.parts = next(a)?;
    p.timestamp_us = next(a)?;
    p.odometer_um = next(a)?;
    p.exposure_us = next(a)?;
    p.laser_mask = next(a)?;
    let entries: u8 = next(a)?;
    if usize::from(entries) > LASERS {
        return Err(bad("more laser entries than lasers"));
    }
    Ok((p, entries))
}

impl<'de> Visitor<'de> for ProfileVisitor {
    type Value = Profile;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a protocol 4 profile")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Profile, A::Error> {
        let (mut p, entries) = read_header(&mut a)?;
        for _ in 0..entries {
            let laser: u8 = next(&mut a)?;
            if usize::from(laser) >= LASERS {
                return Err(bad("no such laser"));
            }
            p.lasers.push(LaserPoints { laser, points: heapless::Vec::new() }).map_err(|_| bad("too many entries"))?;
        }
        let mut tracks = [Track::default(); LASERS];
        let mut previous_row = -1i64;
        loop {
            let head: u8 = next(&mut a)?;
            if head == 0 {
                break;
            }
            let points = head & POINTS;
            let metrics = (head >> METRIC_SHIFT) & POINTS;
            if points == 0 || points >> entries != 0 || metrics & !points != 0 {
                return Err(bad("a row record names no point, or an entry that is not there"));
            }
            let skip: u32 = if head & SKIP_FOLLOWS != 0 { next(&mut a)? } else { 0 };
            if head & SKIP_FOLLOWS != 0 && skip == 0 {
                return Err(bad("a skip of no rows"));
            }
            let row = previous_row + 1 + i64::from(skip);
            let row = u16::try_from(row).map_err(|_| bad("row past 65535"))?;
            let mut any_flags = false;
            for (j, track) in tracks.iter_mut().enumerate().take(usize::from(entries)) {
                if points & (1 << j) == 0 {
                    continue;
                }
                let dq: i32 = next(&mut a)?;
                let q = track.position.predict().wrapping_add(dq);
                let position = position_from_code(q).ok_or_else(|| bad("position out of range"))?;
                track.position.push(q);
                let strength = strength_from_code(next(&mut a)?).ok_or_else(|| bad("no such strength"))?;
                let width = width_from_code(next(&mut a)?);
                let flags = if head & FLAGS_FOLLOW != 0 { Flags(next(&mut a)?) } else { Flags::NONE };
                any_flags |= flags != Flags::NONE;
                let metric = if metrics & (1 << j) != 0 {
                    let da: i32 = next(&mut a)?;
                    let dh: i32 = next(&mut a)?;
                    let along_um = track.along.predict().wrapping_add(da);
                    let h = track.height.wrapping_add(dh);
                    let height_nm = height_from_code(h).ok_or_else(|| bad("height out of range"))?;
                    track.along.push(along_um);
                    track.height = h;
                    Some(Metric { along_um, height_nm })
                } else {
                    None
                };
                let point = Point { row, position, strength, width, flags, metric };
                p.lasers[j].points.push(point).map_err(|_| bad("more points than rows"))?;
            }
            // One encoding per profile: a flags byte per point only when one is set.
            if head & FLAGS_FOLLOW != 0 && !any_flags {
                return Err(bad("flags bytes that are all zero"));
            }
            previous_row = i64::from(row);
        }
        Ok(p)
    }
}
