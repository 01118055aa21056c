//! The slope `∂R/∂t = Σ x[i] D(i − t)` of the response at the fit rung,
//! at phase points, and the search for its zero: the sub-pixel half of
//! the CWT estimator (step 2 of [`cwt`](super)).

use super::kernels::{self, Deriv, PHASES};
use super::{Sample, ratio_q};
use crate::fixed::Px;

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
pub(super) fn lo16(w: u32) -> i32 {
    w as i16 as i32
}

#[inline(always)]
pub(super) fn hi16(w: u32) -> i32 {
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

/// The slope at phases `t` and `t + 1` (`t` in phases from pixel 0, ≥ 0: a
/// shift and a mask, `PHASES` being a power of two): two taps a word where
/// `pairs` allows it ([`slope_pair32`]), else [`slope_pair`]; `None` past
/// the row.
#[inline(always)]
fn slope_pair_at<S: Sample>(x: &[S], t: isize, d: Deriv, pairs: Option<kernels::DerivPairs>) -> Option<(i64, i64)> {
    if t < 0 {
        return None;
    }
    let n = x.len() as isize;
    let (k, p) = (t >> PHASES.trailing_zeros(), (t as usize) & (PHASES - 1));
    if let Some(dp) = pairs
        && let Some((a, b)) = slope_pair32(x, k as usize, p, dp)
    {
        return Some((a as i64, b as i64));
    }
    if k < n && (p + 1 < PHASES || k + 1 < n) { Some(slope_pair_wide(x, k, p, d)) } else { None }
}

/// [`slope_pair`] out of line: the phases next to whole pixels and the
/// widest rungs, whose taps are not stored in pairs.
#[inline(never)]
fn slope_pair_wide<S: Sample>(x: &[S], k: isize, p: usize, d: Deriv) -> (i64, i64) {
    slope_pair(x, k, p, d)
}

/// [`slope_pair_at`] out of line, for the search's further pairs.
#[inline(never)]
fn slope_pair_at_far<S: Sample>(x: &[S], t: isize, d: Deriv, pairs: Option<kernels::DerivPairs>) -> Option<(i64, i64)> {
    slope_pair_at(x, t, d, pairs)
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
    let ph = PHASES as isize;
    // The first pair inline (most stripes need no other), the search's
    // further pairs by a call.
    let pair = |t: isize| slope_pair_at_far(x, t, d, pairs);
    // The zero in [lo, lo + 1] (phases), fa > 0 ≥ fb.
    let zero = |lo: isize, fa: i64, fb: i64| {
        const STEP: i64 = 65536 / PHASES as i64;
        let frac = ratio_q(fa.max(0), (fa - fb).max(1), STEP.trailing_zeros());
        Px((lo as i64 * STEP + frac) as i32)
    };
    let mut t = c as isize * ph + guess as isize;
    let (mut fa, mut fb) = slope_pair_at(x, t, d, pairs)?;
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
