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

use super::kernels::{self, Deriv, NORM_SHIFT, PHASES, RUNGS};
use super::{Flags, RowView, Sample, Stripe};
use crate::fixed::{Px, Q56_8};

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

/// `Σ x[i] D(i − (k + p/PHASES))` on derivative table `d`: positive left of
/// the response's maximum, negative right of it. Edge pixels replicate.
/// `p` runs to `PHASES` (the next pixel's phase 0).
///
/// With `i = k + m`: right of `k` (`m ≥ 1`) the offset is `m − p/P`, on
/// phase `P − p` (phase 0 from its second tap when `p = 0`); left (`m ≥ 0`,
/// offset `−(m + p/P)`, `D` odd) on phase `p`. Both runs are contiguous in
/// the table ([`Deriv`]), so the inner loops are a load, a load and a
/// multiply-accumulate per tap.
pub fn slope_at<S: Sample>(x: &[S], k: isize, p: usize, d: Deriv) -> i64 {
    let n = x.len() as isize;
    let (right, left) = (d.right(p), d.left(p));
    let mut acc = 0i64;
    if k + 1 >= left.len() as isize && k + (right.len() as isize) < n {
        let k = k as usize;
        // Two accumulators, subtracted once: `acc -= a·w` in the loop is a
        // multiply and a 64-bit subtract, `+=` one multiply-accumulate.
        let (mut r_acc, mut l_acc) = (0i64, 0i64);
        for (&a, &w) in x[k + 1..=k + right.len()].iter().zip(right) {
            r_acc += a.get() as i64 * w as i64;
        }
        for (&a, &w) in x[k + 1 - left.len()..=k].iter().rev().zip(left) {
            l_acc += a.get() as i64 * w as i64;
        }
        acc = r_acc - l_acc;
    } else {
        let at = |i: isize| x[i.clamp(0, n - 1) as usize].get() as i64;
        for (m, &w) in right.iter().enumerate() {
            acc += at(k + 1 + m as isize) * w as i64;
        }
        for (m, &w) in left.iter().enumerate() {
            acc -= at(k - m as isize) * w as i64;
        }
    }
    acc
}

/// `Σ xs[i]·u[i]` and `Σ xs[i]·v[i]`, where `xs` is read forwards or
/// backwards (`REV`: `xs[len − 1 − i]`), over tap runs whose lengths differ
/// by at most one and that `xs` is as long as the longer of: one loop over
/// the common part with a single counter, then the longer run's last tap.
#[inline(always)]
fn dot2<S: Sample, const REV: bool>(xs: &[S], u: &[i16], v: &[i16]) -> (i64, i64) {
    let m = u.len().min(v.len());
    let len = xs.len();
    let (mut su, mut sv) = (0i64, 0i64);
    if len < m {
        return (0, 0);
    }
    let (u0, v0) = (&u[..m], &v[..m]);
    if REV {
        let xr = &xs[len - m..];
        for i in 0..m {
            let a = xr[m - 1 - i].get() as i64;
            su += a * u0[i] as i64;
            sv += a * v0[i] as i64;
        }
    } else {
        let xf = &xs[..m];
        for i in 0..m {
            let a = xf[i].get() as i64;
            su += a * u0[i] as i64;
            sv += a * v0[i] as i64;
        }
    }
    if len > m {
        let a = if REV { xs[len - 1 - m].get() } else { xs[m].get() } as i64;
        su += a * *u.get(m).unwrap_or(&0) as i64;
        sv += a * *v.get(m).unwrap_or(&0) as i64;
    }
    (su, sv)
}

/// The slope at two neighbouring phases, `k + p/PHASES` and `k + (p +
/// 1)/PHASES` (`p < PHASES`), as [`slope_at`] gives them (the same sums), in
/// one pass: each pixel is loaded once for both tap runs.
pub fn slope_pair<S: Sample>(x: &[S], k: isize, p: usize, d: Deriv) -> (i64, i64) {
    let n = x.len() as isize;
    let l = d.half_len();
    if let Some((right, left)) = d.pair_runs(p)
        && k + 1 >= l as isize
        && k + (l as isize) < n
    {
        // The common case: both pairs of runs `l` long, one loop a side.
        let k = k as usize;
        let (xr, xl) = (&x[k + 1..][..l], &x[k + 1 - l..][..l]);
        let (r_next, r_this) = right.split_at(l);
        let (l_this, l_next) = left.split_at(l);
        let (r_this, r_next, l_this, l_next) = (&r_this[..l], &r_next[..l], &l_this[..l], &l_next[..l]);
        // Two accumulators for both sides (the left side's pixels negated:
        // four would not fit the M4's registers with the loop's pointers).
        let (mut fa, mut fb) = (0i64, 0i64);
        for i in 0..l {
            let a = xr[i].get() as i64;
            fa += a * r_this[i] as i64;
            fb += a * r_next[i] as i64;
        }
        for i in 0..l {
            let a = -(xl[l - 1 - i].get() as i64);
            fa += a * l_this[i] as i64;
            fb += a * l_next[i] as i64;
        }
        return (fa, fb);
    }
    let (ra, rb) = (d.right(p), d.right(p + 1));
    let (la, lb) = (d.left(p), d.left(p + 1));
    let (r_len, l_len) = (ra.len().max(rb.len()), la.len().max(lb.len()));
    if k + 1 < l_len as isize || k + r_len as isize >= n {
        return (slope_at(x, k, p, d), slope_at(x, k, p + 1, d));
    }
    let k = k as usize;
    let (r_a, r_b) = dot2::<S, false>(&x[k + 1..=k + r_len], ra, rb);
    let (l_a, l_b) = dot2::<S, true>(&x[k + 1 - l_len..=k], la, lb);
    (r_a - l_a, r_b - l_b)
}

/// The low and high halves of a word of tap pairs ([`kernels::DerivPairs`]), as i16.
#[inline(always)]
fn lo16(w: u32) -> i32 {
    w as i16 as i32
}

#[inline(always)]
fn hi16(w: u32) -> i32 {
    (w as i32) >> 16
}

/// [`slope_pair`] in 32-bit arithmetic, two taps a word, for `1 ≤ p ≤
/// PHASES − 2` (`None` elsewhere, or where the taps would reach past `x`).
///
/// Each side reads `2 × per_phase` pixels: on a rung of odd half length
/// one more than the kernel, whose tap (the last word's high half) is zero.
///
/// # Range
/// The caller guarantees every sample in `0..=sat` with `sat < 2^15` (so
/// [`Sample::get16`] is the value) and `sat × deriv_abs < 2^31` for this
/// rung (`Plan`'s `slope32_k`): then each of the four sums, and
/// every partial sum on the way, is within `±sat × Σ|D|` of its phase's
/// taps, below 2^31. The sums are exact, so the values equal
/// [`slope_pair`]'s. Each tap is an i16 half of a word and each sample an
/// i16, so the products are the Cortex-M4's 16 × 16 + 32 multiply-accumulates
/// (`smlabb`, `smlatb`), a word of taps per two.
#[inline(always)]
pub fn slope_pair32<S: Sample>(x: &[S], k: usize, p: usize, dp: kernels::DerivPairs) -> Option<(i32, i32)> {
    if !(1..PHASES - 1).contains(&p) {
        return None;
    }
    let h = dp.per_phase();
    // Right of k: offsets m − (p or p + 1)/P on phases P − p and P − p − 1
    // (stored in that order's reverse); at and left of k, read from k
    // outwards, offsets −(m + p/P) on phases p and p + 1, subtracted.
    let (rb, ra) = dp.two_phases(PHASES - 1 - p)?;
    let (la, lb) = dp.two_phases(p)?;
    // x[k + 1 − 2h .. k + 1 + 2h]: at and left of k the first 2h, right the rest.
    let xs = x.get((k + 1).checked_sub(2 * h)?..k + 1 + 2 * h)?;
    let (xl, xr) = xs.split_at(2 * h);
    let (xl, xr) = (xl.as_chunks::<2>().0, xr.as_chunks::<2>().0);
    // Plain indices over slices of one length (one counter, no bounds
    // checks; a zip with a reversed iterator tests both ends at every step).
    let (xr, ra, rb) = (&xr[..h], &ra[..h], &rb[..h]);
    let (mut fa, mut fb) = (0i32, 0i32);
    for i in 0..h {
        // The pixels as one word, each half an i16 (below 2^15).
        let q = S::word(&xr[i]);
        fa += lo16(q) * lo16(ra[i]) + hi16(q) * hi16(ra[i]);
        fb += lo16(q) * lo16(rb[i]) + hi16(q) * hi16(rb[i]);
    }
    // Summed, subtracted once.
    let (xl, la, lb) = (&xl[..h], &la[..h], &lb[..h]);
    let (mut ga, mut gb) = (0i32, 0i32);
    for i in 0..h {
        // Read from k outwards: the word's high half is the nearer pixel.
        let q = S::word(&xl[h - 1 - i]);
        ga += hi16(q) * lo16(la[i]) + lo16(q) * hi16(la[i]);
        gb += hi16(q) * lo16(lb[i]) + lo16(q) * hi16(lb[i]);
    }
    Some((fa - ga, fb - gb))
}

/// Sub-pixel zero of the slope near `c` on derivative table `d`, Q16.16 px.
/// `None` when no sign change is found within ±3 px.
pub fn slope_zero<S: Sample>(x: &[S], c: usize, d: Deriv) -> Option<Px> {
    let n = x.len() as isize;
    let mut k = c as isize;
    let mut f_k = slope_at(x, k, 0, d);
    // Bracket [k, k+1] with f(k) > 0 ≥ f(k+1).
    let mut steps = 0;
    let (lo, f_lo, f_hi) = loop {
        if f_k > 0 {
            if k + 1 >= n {
                return None;
            }
            let f1 = slope_at(x, k + 1, 0, d);
            if f1 <= 0 {
                break (k, f_k, f1);
            }
            k += 1;
            f_k = f1;
        } else {
            if k == 0 {
                return None;
            }
            let f0 = slope_at(x, k - 1, 0, d);
            if f0 > 0 {
                break (k - 1, f0, f_k);
            }
            k -= 1;
            f_k = f0;
        }
        steps += 1;
        if steps > 3 {
            return None;
        }
    };
    // First guess by linear interpolation, then the enclosing phase interval.
    let guess = ratio_q(f_lo, f_lo - f_hi, PHASES.trailing_zeros()) as usize;
    let mut p = guess.min(PHASES - 1);
    let eval = |p: usize| match p {
        0 => f_lo,
        PHASES => f_hi,
        _ => slope_at(x, lo, p, d),
    };
    let mut fa = eval(p);
    let mut fb = eval(p + 1);
    while fa <= 0 && p > 0 {
        p -= 1;
        fb = fa;
        fa = eval(p);
    }
    while fb > 0 && p + 1 < PHASES {
        p += 1;
        fa = fb;
        fb = eval(p + 1);
    }
    const STEP: i64 = 65536 / PHASES as i64;
    let frac = ratio_q(fa.max(0), (fa - fb).max(1), STEP.trailing_zeros());
    Some(Px(((lo as i64) * 65536 + p as i64 * STEP + frac) as i32))
}

/// Sub-pixel zero of the slope starting from the guess `c + guess/PHASES`
/// (the guess rounded down to a phase; Q16.16 px out): the slope at the
/// guess's phase and the next in one pass ([`slope_pair`]), then pair by
/// pair towards the sign change, at most 8 phases (half a pixel) each way;
/// `None` if it is not found there. A good guess needs one pass where the
/// whole-pixel bracket of [`slope_zero`] needs four evaluations; the zero
/// is the same, the one in the enclosing phase interval.
///
/// `pairs`: the rung's tap pairs where the 32-bit slope is proven to fit
/// ([`slope_pair32`]; the same values, fewer instructions).
pub fn slope_zero_near<S: Sample>(
    x: &[S],
    c: usize,
    guess: i32,
    d: Deriv,
    pairs: Option<kernels::DerivPairs>,
) -> Option<Px> {
    let n = x.len() as isize;
    let ph = PHASES as isize;
    // The slope at phases t and t + 1 (t in phases from pixel 0, ≥ 0: a
    // shift and a mask, PHASES being a power of two).
    let pair = |t: isize| -> Option<(i64, i64)> {
        if t < 0 {
            return None;
        }
        let (k, p) = (t >> PHASES.trailing_zeros(), (t as usize) & (PHASES - 1));
        if let Some((a, b)) = pairs.and_then(|dp| slope_pair32(x, k as usize, p, dp)) {
            return Some((a as i64, b as i64));
        }
        (k < n && (p + 1 < PHASES || k + 1 < n)).then(|| slope_pair(x, k, p, d))
    };
    // The zero in [lo, lo + 1] (phases), fa > 0 ≥ fb.
    let zero = |lo: isize, fa: i64, fb: i64| {
        const STEP: i64 = 65536 / PHASES as i64;
        let frac = ratio_q(fa.max(0), (fa - fb).max(1), STEP.trailing_zeros());
        Px((lo as i64 * STEP + frac) as i32)
    };
    let mut t = c as isize * ph + guess as isize;
    let (mut fa, mut fb) = pair(t)?;
    // The zero a phase beside the first pair: the line through it, not a
    // second pair. The guess is that close for nearly every stripe it
    // misses (its noise is about a phase); the line is then extrapolated by
    // at most a phase, where it is within 1.4·10⁻⁴ px of the zero of the
    // pair that brackets it (noiseless stripes σ 1.5–10 px:
    // `tests::a_phase_beside_the_pair`), and a second pass costs as much
    // as the first.
    let fall = fa - fb;
    if fall > 0 {
        if fa > 0 && fb > 0 && fb <= fall {
            return Some(zero(t + 1, fb, fb - fall));
        }
        if fa <= 0 && -fa < fall {
            return Some(zero(t - 1, fall + fa, fa));
        }
    }
    for _ in 0..4 {
        if fa > 0 && fb <= 0 {
            return Some(zero(t, fa, fb));
        }
        // The next pair where the line through these two puts the zero
        // (the slope falls through it; at most 8 phases away, at least the
        // next pair): between `u` and `u + 1`, or, with the pair next to
        // this one, between it and the phase of this one beside it.
        let fall = fa - fb;
        let j = if fall > 0 { ratio_q(fa.abs(), fall.saturating_mul(8), 3) as isize } else { 1 }.max(1);
        if fa > 0 {
            // Rightwards (fa, fb > 0): t + 1 is known.
            let u = t + j.max(2);
            let (ga, gb) = pair(u)?;
            if u == t + 2 && ga <= 0 {
                return Some(zero(t + 1, fb, ga));
            }
            (t, fa, fb) = (u, ga, gb);
        } else {
            // Leftwards (fa ≤ 0): t is known.
            let u = t - (j + 1).max(2);
            let (ga, gb) = pair(u)?;
            if u == t - 2 && gb > 0 && fa <= 0 {
                return Some(zero(t - 1, gb, fa));
            }
            (t, fa, fb) = (u, ga, gb);
        }
    }
    None
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

/// A candidate confirmed as a stripe by the multi-scale test.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Confirmed {
    /// Integer maximum of the best scale's response.
    pub c: usize,
    /// Best rung and its sub-rung offset (Q16).
    pub kb: usize,
    pub dk_q16: i64,
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
    let j = ((((kb as i64) << 16) + dk_q16 + 153_348 + 32_768) >> 16).clamp(0, kernels::LADDER_LEN as i64 - 1) as usize;
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
    let mut climb_scale = |c: usize, k0: usize| -> (usize, [i32; 3]) {
        let mut response = |k: usize| -> i32 {
            if k32.is_some_and(|k32| k <= k32)
                && let Some(acc) = ricker_sum32(x, c, k)
            {
                // |acc| < 2^31 and `norm` < 2^31: a 32 × 32 → 64 multiply.
                return r32((acc as i64 * (RUNGS[k].norm as i32) as i64) >> NORM_SHIFT);
            }
            folded.at(c);
            r32(folded.response_q8(k).0)
        };
        let mut k = k0;
        let mut here = response(k);
        let (mut below, mut above) = (i32::MIN, i32::MIN);
        while k < w_hi {
            let r = response(k + 1);
            if r <= here {
                above = r;
                break;
            }
            (below, here) = (here, r);
            k += 1;
        }
        if k == k0 {
            while k > w_lo {
                let r = response(k - 1);
                if r <= here {
                    below = r;
                    break;
                }
                (above, here) = (here, r);
                k -= 1;
            }
        }
        (k, [below, here, above])
    };
    let mut c = c0;
    let k_start = v.plan.k_start;
    let (mut kb, mut resp) = climb_scale(c, k_start);
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
            (kb, resp) = climb_scale(c, kb);
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
    let dk_q16: i64 = if kb > 0 && rm != i32::MIN && rp != i32::MIN {
        let (den, num) = (rm - 2 * r0 + rp, rm - rp);
        // (rm − rp) / (2 den) in Q16, |·| ≤ ½: a 32-bit division (`ratio_q32`).
        if den < 0 {
            let q = ratio_q32(num.unsigned_abs(), den.unsigned_abs(), 15) as i64;
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
    let y = (dk_q16 * 11357) >> 16;
    let factor = 65536 + y + ((y * y) >> 17);
    let width = Px(((RUNGS[kb].scale_q16.0 as i64 * factor) >> 16) as i32);

    // Detection test at the best scale: response above threshold × its noise.
    let noise_resp_q8 = (v.noise_q8 as i64 * RUNGS[kb].noise_q8.0) >> 8;
    let thr = (noise_resp_q8 * v.cfg.threshold_sigma_q8.to_bits() as i64) >> 8;
    let amplitude = (r0 as i64 * RUNGS[kb].amp_inv) >> 24;
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
mod tests {
    use super::*;

    /// A row with structure and noise (xorshift), values up to 16 bits.
    fn row(n: usize, seed: u64) -> [i32; 160] {
        let mut s = seed | 1;
        core::array::from_fn(|i| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let bump = if (i as isize - n as isize / 2).abs() < 6 { 40_000 } else { 0 };
            ((s % 25_000) as i32 + bump).min(65_535)
        })
    }

    /// The 32-bit pair equals the 64-bit one wherever the plan allows it:
    /// 12-bit rows (the widest rung whose bound holds at 4095), every
    /// phase it takes, every position whose taps fit the row.
    #[test]
    fn slope_pair32_matches_slope_pair() {
        let sat = 4095i64;
        let top = (0..=kernels::PAIR_RUNGS).take_while(|&k| sat * RUNGS[k].deriv_abs < 1 << 31).last().unwrap();
        assert!(top >= 9, "12-bit rows take the 32-bit slope up to rung {top}");
        for seed in 1..4u64 {
            let full = row(160, seed).map(|v| v & 4095);
            // Full scale where the taps are largest, too.
            let mut hot = full;
            hot[70..90].fill(4095);
            for x in [&full[..], &hot[..]] {
                for k in 0..=top {
                    let (d, dp) = (kernels::deriv(k), kernels::DerivPairs::of(k).unwrap());
                    let w = 2 * dp.per_phase();
                    assert!(w == d.half_len() || w == d.half_len() + 1);
                    for c in 0..x.len() {
                        for p in 0..PHASES {
                            let got = slope_pair32(x, c, p, dp);
                            if (1..PHASES - 1).contains(&p) && c + 1 >= w && c + w < x.len() {
                                let (a, b) = got.unwrap();
                                assert_eq!((a as i64, b as i64), slope_pair(x, c as isize, p, d), "k {k} c {c} p {p}");
                            } else {
                                assert_eq!(got, None, "k {k} c {c} p {p}");
                            }
                        }
                    }
                }
            }
        }
    }

    /// From a guess in the zero's bracket, the bracketed zero
    /// ([`slope_zero`]'s) itself; from a guess a phase beside it, the line
    /// through the first pair, extrapolated, within 2·10⁻⁴ px of it for
    /// σ ≥ 1.5 px; from further (up to 4 phases), a later pass that lands
    /// within a phase of it, as close. Noiseless Gaussian stripes on
    /// 12-bit rows, every 1/64 px, the fit rung nearest 1.5 σ, both slope
    /// paths.
    #[test]
    fn a_phase_beside_the_pair() {
        extern crate std;
        let mut worst = [0.0f64; 3];
        for sigma in [1.5f64, 2.5, 4.0, 10.0] {
            let j = kernels::nearest_rung(Px::from_f64(1.5 * sigma));
            let d = kernels::deriv(j);
            for o in 0..64 {
                let x0 = 80.0 + o as f64 / 64.0;
                let x: [i32; 160] = core::array::from_fn(|i| {
                    let t = (i as f64 - x0) / sigma;
                    (200.0 + 3000.0 * std::primitive::f64::exp(-0.5 * t * t)).round() as i32
                });
                let c = 80 + o / 32;
                let z = slope_zero(&x, c, d).unwrap().0;
                // The bracket's first phase, from c.
                let b = ((z as i64 - ((c as i64) << 16)) >> 12) as i32;
                for pairs in [None, kernels::DerivPairs::of(j)] {
                    for g in b - 4..=b + 4 {
                        let got = slope_zero_near(&x, c, g, d, pairs).unwrap().0;
                        let e = (got - z).abs() as f64 / 65536.0;
                        let at = match (g - b).abs() {
                            0 => 0,
                            1 => 1,
                            _ => 2,
                        };
                        worst[at] = worst[at].max(e);
                    }
                }
            }
        }
        assert!(worst[0] < 2e-5, "{worst:?}");
        assert!(worst[1] < 2e-4 && worst[2] < 2e-4, "{worst:?}");
    }

    /// Every response of 16-bit pixels fits i32 with room for the sums of
    /// three that `confirm` forms (below 2^28): `sat × Σ|ψ| × norm / 2^24`.
    #[test]
    fn responses_fit_32_bits() {
        for (k, r) in RUNGS.iter().enumerate() {
            let bound = (65_535 * r.ricker_abs * r.norm) >> NORM_SHIFT;
            assert!(bound < 1 << 26, "rung {k}: {bound}");
            assert!(r.norm < 1 << 31);
        }
    }

    /// The 32-bit sum straight from the row equals the 64-bit one on the
    /// rungs the plan allows for 12-bit rows, wherever its taps fit.
    #[test]
    fn ricker_sum32_matches_response() {
        let sat = 4095i64;
        let top =
            (0..kernels::LADDER_LEN).take_while(|&k| sat * (RUNGS[k].ricker_abs + (1 << 15)) < 1 << 31).last().unwrap();
        assert!(top >= 9, "12-bit rows take the 32-bit responses up to rung {top}");
        for seed in 1..4u64 {
            let full = row(160, seed).map(|v| v & 4095);
            let mut hot = full;
            hot[60..100].fill(4095);
            for x in [&full[..], &hot[..]] {
                for (k, rung) in RUNGS.iter().enumerate().take(top + 1) {
                    let reach = 2 * kernels::ricker_pairs(k).len() - 1;
                    for c in 0..x.len() {
                        match ricker_sum32(x, c, k) {
                            Some(acc) => {
                                assert_eq!((acc as i64 * rung.norm) >> NORM_SHIFT, response_q8(x, c, k).0, "{k} {c}")
                            }
                            None => assert!(c < reach || c + reach >= x.len(), "k {k} c {c}"),
                        }
                    }
                }
            }
        }
    }

    /// Both by definition: every tap, indices clamped to the row.
    #[test]
    fn response_and_slope_match_direct_sums() {
        for seed in 1..4u64 {
            for n in [20usize, 97, 160] {
                let full = row(n, seed);
                let x = &full[..n];
                let at = |i: isize| x[i.clamp(0, n as isize - 1) as usize] as i64;
                for k in [0, 3, 6, 9] {
                    let h = kernels::ricker(k);
                    let d = kernels::deriv(k);
                    for c in 0..n {
                        let sum: i64 = (-(h.len() as isize - 1)..h.len() as isize)
                            .map(|m| h[m.unsigned_abs()] as i64 * at(c as isize + m))
                            .sum();
                        assert_eq!(response_q8(x, c, k).0, (sum * RUNGS[k].norm) >> NORM_SHIFT, "k {k} c {c} n {n}");
                        let mut buf = [0i32; 160];
                        let mut f = Folded::new(x, c, &mut buf[..n]);
                        for k2 in [k, k + 2, k + 1] {
                            assert_eq!(f.response_q8(k2), response_q8(x, c, k2), "k {k2} c {c} n {n}");
                        }
                        for p in 0..PHASES {
                            let next = slope_at(x, c as isize, p + 1, d);
                            assert_eq!(slope_pair(x, c as isize, p, d), (slope_at(x, c as isize, p, d), next));
                        }
                        if c + 1 < n {
                            assert_eq!(slope_at(x, c as isize, PHASES, d), slope_at(x, c as isize + 1, 0, d));
                        }
                        for p in [0, 1, 7, PHASES - 1] {
                            // Σ x[i] D(i − (c + p/P)), D odd: table index |i − c|·P ∓ p.
                            let mut s = 0i64;
                            for m in 1.. {
                                let j = m * PHASES - p;
                                if j >= d.len() {
                                    break;
                                }
                                s += at(c as isize + m as isize) * d.at(j) as i64;
                            }
                            for m in 0.. {
                                let j = m * PHASES + p;
                                if j >= d.len() {
                                    break;
                                }
                                s -= at(c as isize - m as isize) * d.at(j) as i64;
                            }
                            assert_eq!(slope_at(x, c as isize, p, d), s, "k {k} c {c} p {p} n {n}");
                        }
                    }
                }
            }
        }
    }
}
