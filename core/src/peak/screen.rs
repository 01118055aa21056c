//! The full-row screen: where in a row a stripe may stand, at a few
//! instructions per pixel.
//!
//! # Design
//! Everything else the detector does is local to a candidate; this is the
//! only pass over every pixel, so it is built for the budget (16 667
//! instructions per 752-px row at the sensor's 28 800 rows/s and 480 MHz):
//!
//! * **Blocks.** The row is cut into blocks of `B` pixels (a power of two,
//!   [`block_log2`]) and each block summed — one load and one add per pixel
//!   (two pixels per load on rows of up to 15 bits), read straight from the
//!   sensor's `u8`/`u16` row, no copy. The last block is aligned to the row's
//!   end (it overlaps the one before when the length is not a multiple of
//!   `B`).
//! * **Difference of boxes at the stripe's scale.** With `S[j]` the block sums,
//!   `R[j] = S[j] + S[j+1] − S[j−1] − S[j+2]`: the `2B` pixels of blocks `j`,
//!   `j+1` minus the `B` on each side, a zero-sum, symmetric band-pass (a
//!   crude Ricker): constant and linear backgrounds give exactly zero, and so
//!   does an even/odd column offset (each block holds as many even as odd
//!   columns) and a ripple whose period divides `2B`. Three additions and
//!   one compare per block, in registers. Past the row's ends the blocks
//!   are `B` × the edge pixel, so a stripe at the edge is screened too.
//! * **Block width.** For a Gaussian stripe of σ, with `u = B/σ`, the
//!   response over its noise is `∝ √σ · F/√u`, where `F` is the fraction of
//!   the box difference the stripe fills. The worst case is a stripe centred
//!   mid-block (both windows see it `B/2` off centre): `F/√u` = 0.34, 0.45,
//!   0.50, 0.50, 0.48 at `u` = 1.07, 1.6, 2.4, 3.2, 4 (aligned on a boundary:
//!   0.62 at 1.6, 0.56 at 3.2). So `B` ≈ 2.8 × the scale range's geometric
//!   mean, rounded to a power of two: over the default range 1.25–3.75 px
//!   that is 8 px, whose worst case across the range (0.40 at σ = 1.25) beats
//!   4 px's (0.34 at σ = 3.75), at half the blocks.
//! * **Threshold.** `R` above a constant-false-alarm threshold: a multiple of
//!   the robust σ of `R` itself (1.4826 · median |R|, which includes the fixed
//!   pattern — banding and ripple — as well as the noise), measured on the
//!   rows where the detector refreshes its noise estimates, not on every row
//!   (noise and fixed pattern are stationary within a frame).
//! * **Candidates** are the local maxima of `R` above it, placed at their
//!   block boundary; the strongest [`MAX_CANDIDATES`] are kept. They are
//!   accurate to about ±B px: the candidate's own stage finds the pixel.
//!
//! # Cost
//! On thumbv7em about 2 instructions per pixel (the block sums) and about 6
//! per block; the refresh rows add a median of the `n/B` responses.

use super::median::Histogram;
use super::{Candidate, MAX_CANDIDATES, Pixel};
use crate::fixed::{Px, Q24_8};
use heapless::Vec;

/// log2 of the block width for a coarse scale of `s` px: the power of two
/// nearest to 2.8 s (on a log axis; see the module doc), at least 2 px, at
/// most 32 px.
pub fn block_log2(s: Px) -> u32 {
    // 2.8 s in Q16, then the nearest power of two: compare with 2^(k + ½).
    let target = (s.0 as i64 * 28 / 10).max(1);
    let mut k = 1u32;
    // 2^(k+½) in Q16 = 2^k · 92682 (√2 · 65536).
    while k < 5 && target > ((1i64 << k) * 92_682) {
        k += 1;
    }
    k
}

/// The sum of one block, four pixels at a time written out (the compiler
/// keeps a loop over `[P; 4]` otherwise: 5 instructions a pixel instead of
/// 2), two per word when every pixel is below 2^15 (`NARROW`).
#[inline(always)]
fn block_sum<P: Pixel, const B: usize, const NARROW: bool>(ch: &[P; B]) -> i32 {
    let (quads, rest) = ch.as_chunks::<4>();
    let sum4 = |q: &[P; 4]| {
        if NARROW { P::sum4_narrow(q) } else { (q[0].value() + q[1].value()) + (q[2].value() + q[3].value()) }
    };
    // Two quads written out too (8-px blocks: a loop of two is kept as a loop).
    let mut s = match quads {
        [a, b] => sum4(a) + sum4(b),
        _ => quads.iter().map(sum4).sum(),
    };
    for p in rest {
        s += p.value();
    }
    s
}

/// Adds a candidate, replacing the weakest when the list is full.
pub(crate) fn push_candidate(out: &mut Vec<Candidate, MAX_CANDIDATES>, c: Candidate) {
    if out.push(c).is_err()
        && let Some((j, w)) = out.iter().enumerate().min_by_key(|(_, c)| c.resp)
        && w.resp < c.resp
    {
        out[j] = c;
    }
}

/// The local maxima among the responses above the threshold, fed in row
/// order by the scan's rare path. A response below the threshold is below
/// every hit, so the maxima follow from the hits alone: a hit is a maximum
/// when it beats the hit (or non-hit) before it and is not beaten by the one
/// after it (`R[j] > R[j−1]`, `R[j] ≥ R[j+1]`).
struct Peaks<'a> {
    out: &'a mut Vec<Candidate, MAX_CANDIDATES>,
    /// The last hit (`usize::MAX` before the first) and its response.
    last_j: usize,
    last_r: i32,
    /// Whether the last hit beat the response before it.
    rising: bool,
    log2_b: u32,
    n: usize,
    /// Added to the positions (the span's first column in the row).
    base: usize,
}

impl<'a> Peaks<'a> {
    /// Adds to `out` (not cleared).
    fn new(out: &'a mut Vec<Candidate, MAX_CANDIDATES>, log2_b: u32, n: usize, base: usize) -> Peaks<'a> {
        Peaks { out, last_j: usize::MAX, last_r: 0, rising: false, log2_b, n, base }
    }

    fn emit(&mut self) {
        let pos = ((self.last_j + 1) << self.log2_b).min(self.n - 1) + self.base;
        let c = Candidate { pos, resp: self.last_r };
        push_candidate(self.out, c);
    }

    /// Response `r` at `j` is above the threshold.
    #[inline(never)]
    fn hit(&mut self, j: usize, r: i32) {
        if self.last_j != usize::MAX && self.last_j + 1 == j {
            if r > self.last_r {
                self.rising = true;
            } else {
                if self.rising {
                    self.emit();
                }
                self.rising = false;
            }
        } else {
            // The response after the last hit was below the threshold.
            if self.rising {
                self.emit();
            }
            self.rising = true;
        }
        (self.last_j, self.last_r) = (j, r);
    }

    fn finish(mut self) {
        if self.rising {
            self.emit();
        }
    }
}

/// The scan for blocks of `B`: block sums in registers, three blocks per
/// iteration (on the narrow path) so that the window of sums slides without
/// moves, one compare per block on the fast path.
fn scan_b<P: Pixel, const B: usize, const NARROW: bool>(
    row: &[P],
    base: usize,
    log2_b: u32,
    threshold: i32,
    out: &mut Vec<Candidate, MAX_CANDIDATES>,
) {
    let n = row.len();
    let (chunks, tail) = row.as_chunks::<B>();
    let mut pk = Peaks::new(out, log2_b, n, base);
    // S[−1] (B × the edge pixel), S[0], S[1].
    let (mut s0, mut s1, mut s2) =
        (B as i32 * row[0].value(), block_sum::<P, B, NARROW>(&chunks[0]), block_sum::<P, B, NARROW>(&chunks[1]));
    let mut j = 0usize;
    // Three blocks per iteration on the fast path (4- and 8-px blocks of
    // rows up to 15 bits); elsewhere one, for flash.
    let (triples, rest) = if NARROW { chunks[2..].as_chunks::<3>() } else { (&[][..], &chunks[2..]) };
    for t in triples {
        let n0 = block_sum::<P, B, NARROW>(&t[0]);
        let r = s1 + s2 - s0 - n0;
        if r > threshold {
            pk.hit(j, r);
        }
        let n1 = block_sum::<P, B, NARROW>(&t[1]);
        let r = s2 + n0 - s1 - n1;
        if r > threshold {
            pk.hit(j + 1, r);
        }
        let n2 = block_sum::<P, B, NARROW>(&t[2]);
        let r = n0 + n1 - s2 - n2;
        if r > threshold {
            pk.hit(j + 2, r);
        }
        (s0, s1, s2) = (n0, n1, n2);
        j += 3;
    }
    let mut step = |s: i32| {
        let r = s1 + s2 - s0 - s;
        if r > threshold {
            pk.hit(j, r);
        }
        (s0, s1, s2) = (s1, s2, s);
        j += 1;
    };
    for ch in rest {
        step(block_sum::<P, B, NARROW>(ch));
    }
    if !tail.is_empty() {
        step(row[n - B..].iter().map(|p| p.value()).sum());
    }
    step(B as i32 * row[n - 1].value());
    pk.finish();
}

/// Dispatches to the block width's monomorphic scan.
macro_rules! by_block {
    ($log2_b:expr, $narrow:expr, $f:ident, $($arg:expr),*) => {
        match ($log2_b, $narrow) {
            (1, _) => $f::<P, 2, false>($($arg),*),
            (2, false) => $f::<P, 4, false>($($arg),*),
            (2, true) => $f::<P, 4, true>($($arg),*),
            (3, false) => $f::<P, 8, false>($($arg),*),
            (3, true) => $f::<P, 8, true>($($arg),*),
            // 16- and 32-px blocks (wide stripes) take the plain sums: the
            // pair-per-word code is not worth its flash there.
            (4, _) => $f::<P, 16, false>($($arg),*),
            (_, _) => $f::<P, 32, false>($($arg),*),
        }
    };
}

/// Whether `row` is long enough for the block screen (at least four blocks).
pub fn screens(n: usize, log2_b: u32) -> bool {
    n >= 4 << log2_b
}

/// The candidates of `row`: local maxima of the block response above
/// `threshold` (see the module doc), strongest [`MAX_CANDIDATES`], each at
/// its block boundary, into `out` (cleared first). `row` must pass [`screens`].
///
/// `narrow`: every pixel is below 2^15 (a sensor of up to 15 bits), so the
/// block sums may add two pixels per word; a pixel above that in a narrow
/// row can only misplace that block's response (the screen nominates, the
/// window clamps and decides).
#[inline(never)]
pub fn candidates<P: Pixel>(
    row: &[P],
    log2_b: u32,
    narrow: bool,
    threshold: i32,
    out: &mut Vec<Candidate, MAX_CANDIDATES>,
) {
    out.clear();
    by_block!(log2_b, narrow, scan_b, row, 0, log2_b, threshold, out)
}

/// As [`candidates`] for `span`, the columns `base..` of a row, adding its
/// candidates (in row coordinates) to those already in `out`, the
/// strongest [`MAX_CANDIDATES`] kept: the search windows' screens fill one
/// list.
pub fn candidates_at<P: Pixel>(
    span: &[P],
    base: usize,
    log2_b: u32,
    narrow: bool,
    threshold: i32,
    out: &mut Vec<Candidate, MAX_CANDIDATES>,
) {
    by_block!(log2_b, narrow, scan_b, span, base, log2_b, threshold, out)
}

/// Every block response `R[0..]` of `row` into `out` (as many as fit);
/// returns how many. `row` must pass [`screens`].
///
/// This runs on the rows that refresh the noise estimates only (one in
/// `NOISE_ROWS`): one loop for every block width, not a scan per width,
/// for flash.
pub fn responses<P: Pixel>(row: &[P], log2_b: u32, out: &mut [i32]) -> usize {
    let (n, b) = (row.len(), 1usize << log2_b);
    let sum = |lo: usize| row[lo..lo + b].iter().map(|p| p.value()).sum::<i32>();
    let (mut s0, mut s1, mut s2) = (b as i32 * row[0].value(), sum(0), sum(b));
    let mut m = 0;
    let mut step = |s: i32| {
        if let Some(d) = out.get_mut(m) {
            *d = s1 + s2 - s0 - s;
            m += 1;
        }
        (s0, s1, s2) = (s1, s2, s);
    };
    let full = n / b;
    for j in 2..full {
        step(sum(j * b));
    }
    if full * b < n {
        step(sum(n - b));
    }
    step(b as i32 * row[n - 1].value());
    m
}

/// Robust σ of the block responses, counts: 1.4826 · median |R| (380/256).
/// `scratch` holds the responses on entry (reordered).
pub fn sigma_q8(scratch: &mut [i32]) -> Q24_8 {
    let mut h = Histogram::new();
    for v in scratch.iter_mut() {
        *v = v.saturating_abs();
        h.add(*v);
    }
    h.set_total(scratch.len());
    let m = scratch.len();
    if m == 0 {
        return Q24_8::ZERO;
    }
    Q24_8(h.kth(scratch, m / 2).saturating_mul(380))
}

/// Rows shorter than this measure their noise on every second difference
/// (`n − 2` overlapping triples) rather than on every third window: the
/// median of a handful of samples is too often far below the noise. At
/// 750 px both ways give 250 samples or more, so the count, and with it
/// [`detection_margin_q8`], has no step there.
pub const NOISE_EVERY_TRIPLE_BELOW: usize = 750;

/// How many second differences [`pixel_noise_q8`] takes the median of for
/// a row of `n` pixels.
pub const fn noise_samples(n: usize) -> usize {
    if n < NOISE_EVERY_TRIPLE_BELOW { n.saturating_sub(2) } else { n / 3 }
}

/// Robust pixel-noise σ, counts, straight from the sensor's row, values above
/// `sat` clamped: for white noise `x[i−1] − 2x[i] + x[i+1]` has σ√6 and
/// median |·| = 0.6745 σ√6, so σ = 0.6053 × the median (155/256). Every
/// third window (the row's chunks of three): the median of 250 samples of
/// a 752-px row has a relative standard error of about 8 %, ample for a
/// threshold. Rows shorter than [`NOISE_EVERY_TRIPLE_BELOW`] take every
/// triple ([`noise_samples`]); [`detection_margin_q8`] covers what error
/// is left. Stripes, hot pixels and edges are a minority of the row and
/// do not move the median.
/// `scratch` needs [`noise_samples`] of the row.
#[inline(never)]
pub fn pixel_noise_q8<P: Pixel>(row: &[P], sat: i32, scratch: &mut [i32]) -> Q24_8 {
    let mut h = Histogram::new();
    let mut m = 0;
    let d2 = |a: P, b: P, c: P| (a.value().min(sat) - 2 * b.value().min(sat) + c.value().min(sat)).abs();
    if row.len() < NOISE_EVERY_TRIPLE_BELOW {
        for (s, w) in scratch.iter_mut().zip(row.windows(3)) {
            let v = d2(w[0], w[1], w[2]);
            *s = v;
            h.add(v);
            m += 1;
        }
    } else {
        for (s, &[a, b, c]) in scratch.iter_mut().zip(row.as_chunks::<3>().0) {
            let v = d2(a, b, c);
            *s = v;
            h.add(v);
            m += 1;
        }
    }
    h.set_total(m);
    Q24_8(h.kth(&mut scratch[..m], m / 2).saturating_mul(155))
}

/// The factor the detection thresholds put on a noise σ estimated
/// from `m` second differences, so that a row whose few samples happen to
/// read low does not turn its noise into stripes: the median of `m`
/// samples has a relative standard error of about 1.17/√m (the half-normal
/// median's), and the margin is three of them beyond what the 250 samples
/// of a full 752-px row leave: `1 + k·(1/√m − 1/√250)`, `k = 3 × 1.17`.
/// It is 1 at and above 250 samples (full rows keep the configured
/// threshold as it stands), 1.14 for a 96-px window, 1.7 for 16 px. On
/// uniform bytes it takes 16-px rows from 1–2 % "stripes" to under 0.02 %
/// (`white_noise_in_short_rows_is_rarely_a_stripe`).
pub fn detection_margin_q8(m: usize) -> Q24_8 {
    // 1/√m in Q16 from an integer square root of m in Q8; 1/√250 = 4145/65536.
    let sqrt_q8 = ((m.max(1) as u64) << 16).isqrt();
    let inv_q16 = ((1u64 << 24) / sqrt_q8) as i64;
    Q24_8(256 + ((MARGIN_Q8 * (inv_q16 - 4145).max(0)) >> 16) as i32)
}

/// `k` of [`detection_margin_q8`], Q8: 3 × 1.17 × 256 = 898.6.
const MARGIN_Q8: i64 = 899;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detection_margin_follows_its_formula() {
        for m in [1usize, 2, 6, 14, 30, 94, 189, 249, 250, 251, 683, 10_000] {
            let want = 1.0 + 3.0 * 1.17 * (1.0 / (m as f64).sqrt() - 1.0 / 250f64.sqrt()).max(0.0);
            let got = detection_margin_q8(m).to_f64();
            assert!((got - want).abs() < 2.0 / 256.0, "{m}: {got} vs {want}");
        }
        assert_eq!(detection_margin_q8(noise_samples(752)), Q24_8::ONE);
        assert_eq!(noise_samples(96), 94);
        assert_eq!(noise_samples(749), 747);
        assert_eq!(noise_samples(750), 250);
        assert!(detection_margin_q8(noise_samples(200)) > Q24_8::ONE);
        assert_eq!(detection_margin_q8(noise_samples(252)), Q24_8::ONE);
    }

    #[test]
    fn block_width_follows_the_scale() {
        let px = |v: f64| Px((v * 65536.0) as i32);
        assert_eq!(block_log2(px(0.5)), 1);
        assert_eq!(block_log2(px(1.0)), 1); // 2.8 px → 2 (2^1.49)
        assert_eq!(block_log2(px(1.1)), 2); // 3.1 px → 4 (2^1.62)
        assert_eq!(block_log2(px(2.17)), 3); // 6.1 px → 8 (2^2.6)
        assert_eq!(block_log2(px(5.0)), 4); // 14 → 16
        assert_eq!(block_log2(px(15.0)), 5); // 42 → 32, the largest
        assert_eq!(block_log2(px(40.0)), 5);
    }

    #[test]
    fn constant_and_sloped_rows_give_zero_response() {
        let flat = [700u16; 64];
        let mut r = [1i32; 16];
        let m = responses(&flat, 2, &mut r);
        assert_eq!(m, 15);
        assert!(r[..m].iter().all(|&v| v == 0));
        // A slope: zero everywhere but at the ends, where the virtual edge blocks replicate.
        let ramp: [u16; 64] = core::array::from_fn(|i| 100 + 3 * i as u16);
        let m = responses(&ramp, 2, &mut r);
        assert!(r[1..m - 1].iter().all(|&v| v == 0), "{:?}", &r[..m]);
        let mut c = Vec::new();
        candidates(&ramp, 2, true, 1, &mut c);
        assert!(c.iter().all(|c| c.pos < 8 || c.pos > 56), "{c:?}");
    }

    #[test]
    fn a_bump_is_a_candidate_at_its_block() {
        for centre in 8..56 {
            let mut row = [100u16; 64];
            for (i, p) in row.iter_mut().enumerate() {
                let d = i as i32 - centre as i32;
                if d.abs() <= 2 {
                    *p += (300 - 100 * d.abs()) as u16;
                }
            }
            let mut c = Vec::new();
            candidates(&row, 2, true, 50, &mut c);
            assert_eq!(c.len(), 1, "centre {centre}: {c:?}");
            assert!(c[0].pos.abs_diff(centre) <= 4, "centre {centre}: {c:?}");
        }
    }
}
