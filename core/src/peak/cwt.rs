//! The default detector: multi-scale Ricker CWT, sub-pixel by the maximum of
//! the response over *continuous* position.
//!
//! # What it does
//! For a candidate at pixel `c`:
//!
//! 1. **Best-matching scale** (pixel level, paper §5): the Ricker response
//!    `R(c, s) = s^(−3/2) Σ x[i] ψ((i − c)/s)`, climbing the ladder of rungs
//!    from the scale range's middle at the candidate's brightest pixel (and,
//!    for stripes of 4 px or wider, climbing in position too). For a Gaussian stripe of
//!    width σ, `R(s) ∝ σ s^(3/2) / (s² + σ²)^(3/2)` peaks at s = σ under this
//!    normalisation (with Eq. 2's `s^(−1/2)` it would peak at s = √5 σ ≈ 2.24 σ,
//!    and with `s^(−1)` at s = √2 σ). A parabola through the three best
//!    rungs (quarter-octave spaced) gives the width σ̂.
//! 2. **Sub-pixel position**: the maximum of `R(t, s_fit)` over continuous
//!    `t`, i.e. the zero of `∂R/∂t = Σ x[i] D(i − t)` with `D = −ψ′` (odd), at
//!    `s_fit ≈ 1.5 σ̂`. `D` is tabulated at 1/16-px phases (`build.rs`), so
//!    `∂R/∂t` is evaluated exactly at phase points — no interpolation of the
//!    response between pixels, hence no pixel locking — and the last 1/16 px
//!    is a secant step on a function that is linear there to < 10⁻⁵ px. The
//!    search starts at the vertex of a parabola (through the three brightest
//!    pixels, or through the responses) and steps phase by phase to the sign
//!    change; where the zero lies one phase beside the first pair read, that
//!    pair's line extrapolated is taken (within 1.4·10⁻⁴ px of the bracketed
//!    secant on noiseless stripes, one pair of dot products fewer); the
//!    whole-pixel bracket is the fallback.
//!
//! # Why this estimator
//! The zero of `Σ x[i] D(i − t)` for an odd kernel is an M-estimator whose
//! variance for a Gaussian stripe in white noise is
//! `σn² Σ D² / (A Σ g′ D)²` (the RMS ratios below are its square root); for
//! `D = −ψ′` at `s = 1.5 σ` it is 1.051 × the Cramér–Rao bound (1.05–1.07
//! over a quarter-octave width mismatch). The tables hold `−ψ′` tapered to
//! zero between 3.25 s and 4 s, with the odd Gaussian term that keeps it
//! orthogonal to a slope (`core/build.rs`): 1.056 ×, for a fifth fewer
//! taps than `−ψ′` to 5 s (a hard cut at 4 s would make the slope jump as
//! a tap enters at each whole pixel).
//! The derivative-of-Gaussian correlator would reach 1.00 ×, but it responds
//! to a linear background; `−ψ′` is orthogonal to constants *and* slopes
//! (`∫ t ψ′ = 0`) and, being odd, to any even background around the stripe
//! (glow), so an ambient gradient does not move the stripe. Sampling bias is
//! negligible for σ ≥ 1: by Poisson summation the pixel-periodic error term is
//! of order `e^(−2π² s²)`.
//!
//! # Cost
//! Per candidate: three Ricker evaluations for a typical stripe (ceil(4 s)
//! symmetric taps each; five more for a wide one, whose position climbs),
//! and two derivative evaluations of 2·ceil(4 s_fit)+1 taps from a good
//! guess (four by the whole-pixel bracket): for σ = 2.5 px about 120
//! multiply-adds, independent of row length. The derivative tables are
//! stored phase-major, so an evaluation reads two contiguous runs.

use super::kernels::{self, NORM_SHIFT, RUNGS};
use super::{Flags, RowView, Sample, Stripe};
use crate::fixed::{Px, Q56_8};

mod slope;
use slope::{hi16, lo16};
pub use slope::{slope_at, slope_pair, slope_pair32, slope_zero, slope_zero_near};

/// The `s^(−3/2)`-normalised Ricker response at integer `c` on rung `k`,
/// counts. Taps past the row's edge read the edge pixel.
pub fn response_q8<S: Sample>(x: &[S], c: usize, k: usize) -> Q56_8 {
    let h = kernels::ricker(k);
    let n = x.len();
    let l = h.len() - 1;
    let mut acc = h[0] as i64 * x[c].get() as i64;
    if c >= l && c + l < n {
        // Plain indices over slices of the kernel's length: one counter and
        // no bounds checks (a zip with a reversed iterator tests both ends
        // at every tap).
        let (left, right) = (&x[c - l..c], &x[c + 1..=c + l]);
        for (m, (&w, &b)) in h[1..].iter().zip(right).enumerate() {
            acc += w as i64 * (left[l - 1 - m].get() + b.get()) as i64;
        }
    } else {
        for (m, &w) in h.iter().enumerate().skip(1) {
            let a = x[c.saturating_sub(m)].get();
            let b = x[(c + m).min(n - 1)].get();
            acc += w as i64 * (a + b) as i64;
        }
    }
    Q56_8((acc * RUNGS[k].norm) >> NORM_SHIFT)
}

/// `Σ x[i] ψ(i − c)` on rung `k` (before the normalisation of
/// [`response_q8`]) straight from the row in 32 bits, two taps a word
/// (`RICKER_PAIRS_OF`); `None` where the taps (and, on a rung of even half
/// length, one pixel more each side, whose tap is zero) would reach past
/// `x`. The centre pixel is read on both sides and its tap taken off once.
///
/// # Range
/// The caller guarantees every sample in `0..=sat` with `2·sat < 2^15`
/// (a sum of two is an i16) and `sat × (ricker_abs + 2^15) < 2^31` on
/// this rung (`Plan`'s `ricker32_k`): every partial sum is within
/// `±sat × (Σ|ψ| + |ψ(0)|)`, so the sum is exact, the same as the 64-bit
/// one.
#[inline(always)]
pub fn ricker_sum32<S: Sample>(x: &[S], c: usize, k: usize) -> Option<i32> {
    let words = kernels::ricker_pairs(k);
    let w = words.len();
    // x[c ..= c + 2w − 1] and x[c + 1 − 2w ..= c] (read from c outwards).
    let right = x.get(c..c + 2 * w)?;
    let left = x.get((c + 1).checked_sub(2 * w)?..=c)?;
    let (r2, l2) = (right.as_chunks::<2>().0, left.as_chunks::<2>().0);
    let (r2, l2) = (r2.get(..w)?, l2.get(..w)?);
    let mut acc = -(lo16(*words.first()?) * right[0].get16());
    for i in 0..w {
        // (x[c + m], x[c + m + 1]) and (x[c − m − 1], x[c − m]), m = 2i, a
        // word each; the second turned half for half and added: the word
        // of the sums x[c + m] + x[c − m] and x[c + m + 1] + x[c − m − 1],
        // each below 2^15 (`2·sat < 2^15`), so no carry crosses the halves
        // and each half as an i16 is its sum (one add with a rotated
        // operand, then two 16 × 16 multiply-accumulates on the halves).
        let (q, u, t) = (S::word(&r2[i]), S::word(&l2[w - 1 - i]), words[i]);
        let s = q.wrapping_add(u.rotate_right(16));
        acc += lo16(s) * lo16(t) + hi16(s) * hi16(t);
    }
    Some(acc)
}

/// The Ricker responses at one position `c` from the row folded about it:
/// `x[c]` and the sums `x[c − m] + x[c + m]`, made once (as far as the
/// widest rung asked for reaches) into a scratch buffer, so that each
/// rung's response is one multiply-accumulate per tap over a contiguous
/// run, and the climb's further rungs reuse the sums. The same values as
/// [`response_q8`] (which it falls back to where the kernel would reach
/// past the row's ends or the buffer).
pub struct Folded<'a, 'b, S> {
    x: &'a [S],
    buf: &'b mut [i32],
    c: usize,
    /// How many sums are made (`buf[..len]`).
    len: usize,
}

impl<'a, 'b, S: Sample> Folded<'a, 'b, S> {
    /// The row `x` about `c`, with `buf` as scratch.
    pub fn new(x: &'a [S], c: usize, buf: &'b mut [i32]) -> Self {
        Folded { x, buf, c, len: 0 }
    }

    /// Moves to position `c` (the sums are made again).
    pub fn at(&mut self, c: usize) {
        if c != self.c {
            (self.c, self.len) = (c, 0);
        }
    }

    /// Makes the sums out to offset `l`; false where they would reach past
    /// the row's ends or the buffer.
    #[inline(never)]
    fn extend(&mut self, l: usize) -> bool {
        let (x, c, from) = (self.x, self.c, self.len);
        let Some(lo) = c.checked_sub(l) else {
            return false;
        };
        // x[c − l ..= c + l], and buf[from ..= l].
        let (Some(span), Some(out)) = (x.get(lo..=c + l), self.buf.get_mut(from..l + 1)) else {
            return false;
        };
        let (left, right) = span.split_at(l);
        let (mut out, mut m) = (&mut out[..l + 1 - from], from);
        if m == 0 {
            out[0] = right[0].get();
            (out, m) = (&mut out[1..], 1);
        }
        // m.. : x[c − m] (left[l − m], the left half read backwards) + x[c + m].
        let cnt = out.len();
        let (lf, rt) = (&left[..cnt], &right[m..][..cnt]);
        for i in 0..cnt {
            out[i] = lf[cnt - 1 - i].get() + rt[i].get();
        }
        self.len = l + 1;
        true
    }

    /// Makes the sums as far as rung `k` reaches (where they fit), so that
    /// the responses up to it only multiply.
    pub fn reserve(&mut self, k: usize) {
        let l = RUNGS[k].half_len;
        if l >= self.len {
            self.extend(l);
        }
    }

    /// [`response_q8`] at the current position on rung `k`.
    #[inline(always)]
    pub fn response_q8(&mut self, k: usize) -> Q56_8 {
        let l = RUNGS[k].half_len;
        if l >= self.len && !self.extend(l) {
            return response_q8(self.x, self.c, k);
        }
        let h = kernels::ricker(k);
        // Two taps per iteration (the loop's counter and branch shared).
        let (h2, h_rest) = h.as_chunks::<2>();
        let (p2, p_rest) = self.buf[..=l].as_chunks::<2>();
        let (mut acc, mut acc2) = (0i64, 0i64);
        for (w, p) in h2.iter().zip(p2) {
            acc += w[0] as i64 * p[0] as i64;
            acc2 += w[1] as i64 * p[1] as i64;
        }
        if let (Some(&w), Some(&p)) = (h_rest.first(), p_rest.first()) {
            acc += w as i64 * p as i64;
        }
        let acc = acc + acc2;
        Q56_8((acc * RUNGS[k].norm) >> NORM_SHIFT)
    }
}

/// `⌊num · 2^bits / den⌋` for `0 ≤ num ≤ den`, `den > 0`, `bits ≤ 15`, by a
/// 32-bit division: both are shifted right until `den` has `31 − bits`
/// bits, so the quotient keeps at least `30 − bits` bits of precision —
/// 18 bits for the 1/4096-px step, far below the estimator's noise — where
/// a 64-bit division is a library call of ~100 instructions on the M4.
#[inline]
pub fn ratio_q(num: i64, den: i64, bits: u32) -> i64 {
    if den <= 0 {
        return 0;
    }
    let num = num.clamp(0, den);
    if let Ok(d32) = u32::try_from(den) {
        // The same shifts in 32 bits (`den` below 2^32 has as many bits
        // either way): the usual case, without 64-bit shifts.
        return ratio_q32(num as u32, d32, bits) as i64;
    }
    ratio_q_wide(num, den, bits)
}

/// [`ratio_q`] of 32-bit operands: `⌊min(num, den) · 2^bits / den⌋`, 0
/// for `den = 0` (the same shifts, so the same value).
#[inline(always)]
pub fn ratio_q32(num: u32, den: u32, bits: u32) -> u32 {
    if den == 0 {
        return 0;
    }
    let num = num.min(den);
    let sh = (32 - den.leading_zeros()).saturating_sub(31 - bits);
    ((num >> sh) << bits) / (den >> sh).max(1)
}

/// [`ratio_q`] for a denominator of 2^32 or more (out of line: rare).
#[inline(never)]
fn ratio_q_wide(num: i64, den: i64, bits: u32) -> i64 {
    let sh = (64 - den.leading_zeros()).saturating_sub(31 - bits);
    let (n, d) = ((num >> sh) as u32, ((den >> sh) as u32).max(1));
    ((n << bits) / d) as i64
}

/// The response on rung `k` at `c` for [`climb_scale`]: straight from the
/// row in 32 bits where the plan allows it (`k32`, [`ricker_sum32`]), else
/// from the row folded about `c` ([`Folded`]).
#[inline(always)]
fn climb_response<S: Sample>(x: &[S], folded: &mut Folded<'_, '_, S>, k32: Option<usize>, c: usize, k: usize) -> i32 {
    if k32.is_some_and(|k32| k <= k32)
        && let Some(acc) = ricker_sum32(x, c, k)
    {
        // |acc| < 2^31 and `norm` < 2^31: a 32 × 32 → 64 multiply.
        return ((acc as i64 * (RUNGS[k].norm as i32) as i64) >> NORM_SHIFT) as i32;
    }
    folded.at(c);
    folded.response_q8(k).0 as i32
}

/// `confirm`'s climb in scale from rung `k0` at position `c`, within the
/// width limits' rungs `w_lo ..= w_hi`: the best rung and the responses at
/// it and at both its neighbours (`i32::MIN` where not evaluated: beyond
/// the limits). Inlined, and each response in it: a call per response
/// cost about a fifth of it.
#[inline(always)]
fn climb_scale<S: Sample>(
    x: &[S],
    folded: &mut Folded<'_, '_, S>,
    k32: Option<usize>,
    c: usize,
    k0: usize,
    (w_lo, w_hi): (usize, usize),
) -> (usize, [i32; 3]) {
    let mut k = k0;
    let mut here = climb_response(x, folded, k32, c, k);
    let (mut below, mut above) = (i32::MIN, i32::MIN);
    while k < w_hi {
        let r = climb_response(x, folded, k32, c, k + 1);
        if r <= here {
            above = r;
            break;
        }
        (below, here) = (here, r);
        k += 1;
    }
    if k == k0 {
        while k > w_lo {
            let r = climb_response(x, folded, k32, c, k - 1);
            if r <= here {
                below = r;
                break;
            }
            (above, here) = (here, r);
            k -= 1;
        }
    }
    (k, [below, here, above])
}

/// A candidate confirmed as a stripe by the multi-scale test.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Confirmed {
    /// Integer maximum of the best scale's response.
    pub c: usize,
    /// Best rung and its sub-rung offset (Q16, |·| ≤ ½).
    pub kb: usize,
    pub dk_q16: i32,
    /// σ̂.
    pub width: Px,
    /// Amplitude estimate, counts.
    pub amplitude: i64,
    /// Flags so far (weak, width at the range's edge).
    pub flags: Flags,
    /// Where the maximum lies from `c`, 1/PHASES px: the vertex of the
    /// parabola through the responses at `c − 1, c, c + 1` (a first guess
    /// for the sub-pixel search, within ±PHASES/2).
    pub guess: i32,
}

/// The candidate's window is too short for the stripe found there: copy a
/// wider one and ask again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Wider;

/// The CWT estimator for one candidate.
pub(crate) fn refine<S: Sample>(v: &RowView<'_, S>, c0: usize, scratch: &mut [i32]) -> Result<Option<Stripe>, Wider> {
    let Some(Confirmed { c, kb, dk_q16, width, amplitude, mut flags, guess }) = confirm(v, c0, scratch)? else {
        return Ok(None);
    };
    let x = v.x;
    // Fit rung: nearest to 1.5 σ̂, i.e. kb + dk + 4·log2(1.5) (= 2.3399, Q16 153_348).
    // In 32 bits: kb < 2^5, |dk| ≤ 2^15.
    let j = ((((kb as i32) << 16) + dk_q16 + 153_348 + 32_768) >> 16).clamp(0, kernels::LADDER_LEN as i32 - 1) as usize;
    // The whole kernel, tapered to zero at 4 s (`core/build.rs`): cut
    // where `D` is still 1.3 % of its peak, the slope jumped as a tap
    // entered at each whole pixel, and the secant across that jump moved
    // the zero by ~3·10⁻⁴ px near whole pixels (3.7 % of the f64
    // reference's RMS error).
    let d = kernels::deriv(j);
    let reach = d.half_len();
    if v.clipped(c, reach) {
        flags.insert(Flags::CLIPPED);
    }
    // The search from the guess stays within a pixel of `c`, and its taps
    // reach one more than the kernel; the whole-pixel bracket (if the guess
    // was poor) moves up to 3 px more.
    if !v.fits(c, reach + 2) {
        return Err(Wider);
    }
    let pairs = if v.plan.slope32_k.is_some_and(|k| j <= k) { kernels::DerivPairs::of(j) } else { None };
    let found = match slope_zero_near(x, c, guess, d, pairs) {
        Some(p) => Some(p),
        None if !v.fits(c, reach + 5) => return Err(Wider),
        None => slope_zero(x, c, d),
    };
    let position = match found {
        Some(p) => p,
        None => {
            flags.insert(Flags::LOW_CONFIDENCE);
            Px::from_int(c as i32)
        }
    };
    Ok(Some(Stripe { position, strength: amplitude.clamp(0, u32::MAX as i64) as u32, width, flags }))
}

/// Pixel-level detection (paper §5): the best-matching scale, the integer
/// maximum of its response, the width, and the test that decides whether
/// the candidate is a stripe at all — the response at the best scale above
/// `threshold ×` its own noise, the amplitude above the floor, the width in
/// range. Every method detects through this test, so methods differ only in
/// their sub-pixel estimate.
///
/// # Cost
/// The scale is found by climbing, not by search: from the coarse rung up
/// or down the ladder while the response grows (a Gaussian stripe's
/// response is unimodal in scale: `∝ σ s^(3/2) / (s² + σ²)^(3/2)`), at the
/// candidate's brightest pixel: three Ricker responses for a typical stripe
/// (it took 10–18 over the whole scale range, and a climb in position). A
/// stripe of 4 px or wider climbs in position too, then in scale again if
/// it moved. The climb stays within the width limits' rungs, so a
/// stripe (or glow) wider or narrower than the range is measured there and
/// rejected rather than clamped to the range's edge.
pub(crate) fn confirm<S: Sample>(
    v: &RowView<'_, S>,
    c0: usize,
    scratch: &mut [i32],
) -> Result<Option<Confirmed>, Wider> {
    let x = v.x;
    let n = x.len();
    let (k_lo, k_hi) = (v.plan.k_lo, v.plan.k_hi);
    let (w_lo, w_hi) = (v.plan.k_width_lo, v.plan.k_width_hi);
    // Climb in scale from rung `k0` at position `c`: the best rung and the
    // responses at it and at both its neighbours (`i32::MIN` where not
    // evaluated: beyond the width limits).
    //
    // The responses come from the row folded about `c` ([`Folded`]), in
    // 32 bits: a response is within `±sat × Σ|ψ| × norm / 2^24` (counts ×
    // 256), below 2^26 on every rung for 16-bit pixels
    // (`responses_fit_32_bits`), so it, and the sums and differences of
    // three of them below, are exact in i32.
    let r32 = |r: i64| r as i32;
    //
    // Where the plan allows it (`ricker32_k`), straight from the row in 32
    // bits ([`ricker_sum32`]): the same values, no sums to make first.
    let mut folded = Folded::new(x, c0, scratch);
    let k32 = v.plan.ricker32_k;
    let mut c = c0;
    let k_start = v.plan.k_start;
    let (mut kb, mut resp) = climb_scale(x, &mut folded, k32, c, k_start, (w_lo, w_hi));
    // Pixel level. A stripe narrower than 4 px: its brightest pixel (where
    // the candidate starts) is within a pixel of the response's maximum, and
    // the parabola through the three pixels (its vertex does not see a
    // constant background) is the first guess of the sub-pixel search,
    // which finds the maximum from there. A wider one: climb to the integer
    // maximum of the best scale's response (its top is flat, the brightest
    // pixel can be several pixels off), and take the guess from the
    // parabola through the responses at c − 1, c, c + 1.
    let vertex = |l: i32, m: i32, r: i32| -> i32 {
        // (l − r) / (2 (l − 2m + r)) in phases, when the three bend down.
        let (den, num) = (l - 2 * m + r, l - r);
        if den < 0 && num.unsigned_abs() < den.unsigned_abs() {
            // |δ| · 16 = |num| / |den| · 8; δ has the sign of r − l.
            // Rounded down to a phase: the zero is then expected between
            // the guess and the next phase (what `slope_zero_near` reads first).
            let q = ratio_q32(num.unsigned_abs(), den.unsigned_abs(), 3) as i32;
            if num < 0 { q } else { -q - 1 }
        } else {
            0
        }
    };
    let guess = if RUNGS[kb].scale_q16.0 < 4 << 16 {
        if c > 0 && c + 1 < n { vertex(x[c - 1].get(), x[c].get(), x[c + 1].get()) } else { 0 }
    } else {
        let mut best = resp[1];
        let mut left = if c > 0 { r32(response_q8(x, c - 1, kb).0) } else { i32::MIN };
        let mut right = if c + 1 < n { r32(response_q8(x, c + 1, kb).0) } else { i32::MIN };
        let mut moved = 0;
        while moved < 6 {
            if right > best && right >= left {
                c += 1;
                (left, best) = (best, right);
                right = if c + 1 < n { r32(response_q8(x, c + 1, kb).0) } else { i32::MIN };
            } else if left > best {
                c -= 1;
                (right, best) = (best, left);
                left = if c > 0 { r32(response_q8(x, c - 1, kb).0) } else { i32::MIN };
            } else {
                break;
            }
            moved += 1;
        }
        if moved > 0 {
            (kb, resp) = climb_scale(x, &mut folded, k32, c, kb, (w_lo, w_hi));
        }
        if left != i32::MIN && right != i32::MIN { vertex(left, best, right) } else { 0 }
    };
    // The responses read `half_len` of the widest rung evaluated each side.
    if !v.fits(c, RUNGS[(kb + 1).min(w_hi)].half_len + 1) {
        return Err(Wider);
    }
    let r0 = resp[1];
    if r0 <= 0 {
        return Ok(None);
    }
    let mut flags = Flags::NONE;
    // Width: parabola through the neighbouring rungs (log-scale axis).
    let [rm, _, rp] = resp;
    let dk_q16: i32 = if kb > 0 && rm != i32::MIN && rp != i32::MIN {
        let (den, num) = (rm - 2 * r0 + rp, rm - rp);
        // (rm − rp) / (2 den) in Q16, |·| ≤ ½: a 32-bit division (`ratio_q32`).
        if den < 0 {
            let q = ratio_q32(num.unsigned_abs(), den.unsigned_abs(), 15) as i32;
            if num < 0 { q } else { -q }
        } else {
            0
        }
    } else {
        0
    };
    if (kb <= k_lo && dk_q16 <= 0) || (kb >= k_hi && dk_q16 >= 0) {
        // Width at or beyond the scale range's edge.
        flags.insert(Flags::LOW_CONFIDENCE);
    }
    // σ̂ = s_kb · 2^(dk/4) ≈ s_kb (1 + y + y²/2), y = dk · ln2/4 (11357/65536).
    // In 32 bits (|dk| ≤ 2^15, |y| < 2^13), the width's product in 64.
    let y = (dk_q16 * 11357) >> 16;
    let factor = 65536 + y + ((y * y) >> 17);
    let width = Px(((RUNGS[kb].scale_q16.0 as i64 * factor as i64) >> 16) as i32);

    // Detection test at the best scale: response above threshold × its noise.
    // The rung's constants are below 2^31 (`rung_constants_fit_32_bits`):
    // 32 × 32 → 64-bit multiplies, the same values.
    let rung = &RUNGS[kb];
    let noise_resp_q8 = (v.noise_q8 as i64 * (rung.noise_q8.0 as i32) as i64) >> 8;
    let thr = (noise_resp_q8 * v.cfg.threshold_sigma_q8 as i64) >> 8;
    let amplitude = (r0 as i64 * (rung.amp_inv as i32) as i64) >> 24;
    let r0 = r0 as i64;
    if r0 <= thr || amplitude < v.cfg.min_amplitude as i64 || width < v.cfg.min_width || width > v.cfg.max_width {
        return Ok(None);
    }
    if r0 < 2 * thr {
        // Near an end of the row the kernel (to 3 s) reads the edge pixel
        // repeated past it, and one noisy edge pixel then responds like a
        // wide, weak stripe (1 row in about 2 000 of white noise σ 5 put
        // one within 2 s of the end). There a stripe must pass twice the
        // threshold.
        let reach_px = ((3 * RUNGS[kb].scale_q16.0 as i64) >> 16) as usize + 1;
        if v.clipped(c, reach_px) {
            return Ok(None);
        }
        flags.insert(Flags::LOW_CONFIDENCE);
    }
    Ok(Some(Confirmed { c, kb, dk_q16, width, amplitude, flags, guess }))
}

#[cfg(test)]
mod tests;
