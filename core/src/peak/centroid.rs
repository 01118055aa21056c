//! The estimator for laser light: a centroid over ±3σ of the stripe's
//! scale, re-centred on itself.
//!
//! A laser line on a rail is speckled: the surface is rough at the
//! wavelength, so the stripe's pixels are a smooth Gaussian envelope times
//! a random speckle pattern of contrast near one (simulated and checked
//! against theory in the host's `sim::scene::light`). An estimator tuned
//! to white noise — a matched filter at the best-matching scale, a
//! Gaussian fit — then locks onto single speckles (narrow, bright): on the
//! reference head at F/8 the CWT's points scatter 2.9× as much as a
//! centroid placed on the true centre of the same rows, and the widths it
//! measures are a speckle's, not the stripe's. The centroid over the whole
//! stripe weighs every speckle by its light, which is what the speckle
//! error's bound is made of (Dorsch, Häusler & Herrmann, Appl. Opt. 33(7),
//! 1994): its scatter is within a few per cent of that oracle's. The
//! window's half-width is 3σ of the optics' scale (the geometric middle of
//! the configured range: the line's width is known from the optics, a
//! speckle's width must not set it); the background is the lower of the
//! means of three pixels at ±5σ (a neighbour's tail or a ghost on one side
//! does not lift it).
//!
//! The passes start at the candidate's brightest pixel; the stripe is then
//! detected at the optics' scale, at the centroid's centre ([`detected`]),
//! not by the CWT's climb to the best-matching scale (a speckle's).
//!
//! Under white noise alone it is a plain centroid: about 1.6× the
//! Cramér–Rao bound where the CWT reaches 1.0–1.2× (`cms-host bench speckle` and `bench accuracy` have
//! both under both lights).

use super::cwt::{self, Wider};
use super::kernels::{NORM_SHIFT, RUNGS};
use super::plan::Plan;
use super::{Flags, RowView, Sample, Stripe};
use crate::fixed::Px;

/// Centroids, each on the last one's centre, the last on the fixed point
/// extrapolated from the first two ([`extrapolated`]). A window of ±3σ
/// moves the centroid by a fraction ρ of its own move (ρ = 2h·f(h)/∫f, up
/// to 0.25 for a stripe 1.5× wider than the window's σ), so from the
/// brightest pixel (at most half a pixel from the stripe's centre on
/// white noise, about σ under speckle) three plain ones left up to
/// ρ³/2 ≤ 0.008 px; the extrapolation leaves ρ times the variation of ρ
/// over the steps.
const ITERATIONS: usize = 3;

/// A centroid of ±3σ's relative second moment: `1 − 6φ(3)/(2Φ(3) − 1)`,
/// so `σ = √m₂ / 0.9866`; Q16 of 1/0.9866.
const TRUNCATED_WIDTH_Q16: i64 = 66_426;

/// A centroid's window `[pos − half, pos + half]` over whole pixels: the
/// first and last pixel it touches and how much of each it covers (Q16).
#[derive(Clone, Copy, Debug, Default)]
struct Window {
    lo: i64,
    hi: i64,
    lo_q16: i64,
    hi_q16: i64,
}

impl Window {
    fn at(pos_q16: i64, half_q16: i64, n: i64) -> Window {
        let (a, b) = (pos_q16 - half_q16, pos_q16 + half_q16);
        let (lo, hi) = ((a + 32_768) >> 16, (b + 32_768) >> 16);
        let (lo, lo_q16) = if lo < 0 { (0, 65_536) } else { (lo, ((lo << 16) + 32_768) - a) };
        let (hi, hi_q16) = if hi > n - 1 { (n - 1, 65_536) } else { (hi, b - ((hi << 16) - 32_768)) };
        Window { lo, hi, lo_q16, hi_q16 }
    }
}

/// The stripe near `start` (window coordinates): the centroid from there,
/// then the detection test at its centre ([`detected`]).
#[inline(never)]
pub(crate) fn detect<S: Sample>(v: &RowView<'_, S>, start: usize) -> Result<Option<Stripe>, Wider> {
    if !v.fits(start, v.plan.method_reach_px) {
        return Err(Wider);
    }
    // The common case: the pixels within `FAST_REACH_PX` more than the
    // estimator's reach of the start, all inside the window and below the
    // saturation level (one test a word), read in place without clamps in
    // 32 bits.
    let sat = v.cfg.saturation as i32;
    let reach = v.plan.method_reach_px + FAST_REACH_PX;
    if sat < 1 << 12
        && let (Some(a), b) = (start.checked_sub(reach), start + reach)
        && let Some(near) = v.x.get(a..=b)
        && !any_at_least(near, sat)
    {
        match in_place(near, v.plan, (((start - a) as i32) << 16) + toward_brighter(v.x, start) as i32) {
            Passes::Fit(fit) => return detected(v, fit.moved_by(a), Some((near, a)), false),
            Passes::NoLight => return Ok(None),
            Passes::Leaves => {}
        }
    }
    let Some((fit, brightest)) = clamped_passes(v, ((start as i64) << 16) + toward_brighter(v.x, start)) else {
        return Ok(None);
    };
    if brightest > sat {
        // Pixels above the saturation level read in place: again, clamped
        // (only where the level is set below full scale).
        return detect_clamped(v, start);
    }
    detected(v, fit, None, brightest >= sat)
}

/// Where the passes start from the brightest pixel `b`, Q16 from it: half a
/// pixel towards a neighbour as bright as it (none where there is none).
/// Where the two brightest pixels are equal, a row and its mirror image
/// each take the first of them, a pixel apart, and three passes left each
/// up to ρ³ (10⁻³ px at σ 3 px) from the other: both start at the pair's
/// middle instead. Elsewhere the brightest pixel itself.
fn toward_brighter<S: Sample>(x: &[S], b: usize) -> i64 {
    let top = x.get(b).map(|p| p.get());
    if x.get(b + 1).map(|p| p.get()) == top {
        32_768
    } else if b.checked_sub(1).and_then(|l| x.get(l)).map(|p| p.get()) == top {
        -32_768
    } else {
        0
    }
}

/// How far beyond the estimator's reach from the start ([`Plan`]'s
/// `method_reach_px`: the background's pixels and two) the in-place
/// passes may read, px: the centroid moves up to about σ from the
/// brightest pixel of a speckled stripe.
const FAST_REACH_PX: usize = 4;

/// The detection test at the centroid's centre `c`: the Ricker response
/// at the optics' scale (the plan's rung nearest the scale range's
/// geometric middle) above `threshold ×` its own noise, and the amplitude
/// it implies above the floor. The stripe's width is known from the
/// optics, so it is tested at that one scale, not at the best-matching
/// one: under speckle the best match is a speckle's, and the climb over
/// scales cost more than the centroid. At the centre the response sees
/// the whole envelope; a stripe up to half a pixel off keeps 97 % of it at
/// σ = 2.5 px.
///
/// `checked`: pixels (and where they start in the window) known to be
/// below the saturation level, where the response is made in 32 bits if
/// its taps lie within them.
fn detected<S: Sample>(
    v: &RowView<'_, S>,
    fit: Fit,
    checked: Option<(&[S], usize)>,
    saturated: bool,
) -> Result<Option<Stripe>, Wider> {
    let x = v.x;
    let k = v.plan.centroid_k;
    let rung = &RUNGS[k];
    let c = fit.centre_px(x.len());
    if !v.fits(c, rung.half_len + 1) {
        return Err(Wider);
    }
    let sum32 = checked
        .filter(|_| v.plan.ricker32_k.is_some_and(|k32| k <= k32))
        .and_then(|(near, a)| cwt::ricker_sum32(near, c.checked_sub(a)?, k));
    let r0 = match sum32 {
        // |acc| < 2^31 and `norm` < 2^31: a 32 × 32 → 64 multiply.
        Some(acc) => (acc as i64 * (rung.norm as i32) as i64) >> NORM_SHIFT,
        None => cwt::response_q8(x, c, k).0,
    };
    let noise_resp_q8 = (v.noise_q8 as i64 * rung.noise_q8.0) >> 8;
    let thr = (noise_resp_q8 * v.cfg.threshold_sigma_q8 as i64) >> 8;
    let amplitude = (r0 * rung.amp_inv) >> 24;
    if r0 <= thr || amplitude < v.cfg.min_amplitude as i64 {
        return Ok(None);
    }
    let mut flags = Flags::NONE;
    if r0 < 2 * thr {
        // As the CWT's test: near an end of the row, where the kernel
        // reads the edge pixel repeated past it, twice the threshold.
        if v.clipped(c, ((3 * rung.scale_q16.0 as i64) >> 16) as usize + 1) {
            return Ok(None);
        }
        flags.insert(Flags::LOW_CONFIDENCE);
    }
    if v.clipped(c, v.plan.centroid_outer_px) {
        flags.insert(Flags::CLIPPED);
    }
    if saturated {
        flags.insert(Flags::SATURATED);
    }
    Ok(Some(Stripe {
        position: Px(fit.pos_q16.clamp(0, ((x.len() as i64) - 1) << 16) as i32),
        strength: amplitude.clamp(0, u32::MAX as i64) as u32,
        width: fit.width(),
        flags,
    }))
}

/// The last pass of the centroid: its centre (window coordinates, Q16)
/// and its variance Σw·(d − mean)²/Σw (Q16 px²).
#[derive(Clone, Copy, Debug)]
struct Fit {
    pos_q16: i64,
    var_q16: i64,
}

impl Fit {
    /// The whole pixel nearest the centre, within the window.
    fn centre_px(&self, n: usize) -> usize {
        (((self.pos_q16 + 32_768) >> 16).max(0) as usize).min(n - 1)
    }

    /// The same fit `a` pixels to the right.
    fn moved_by(self, a: usize) -> Fit {
        Fit { pos_q16: self.pos_q16 + ((a as i64) << 16), ..self }
    }

    /// The width: the root of the variance, corrected for the window's
    /// truncation.
    fn width(&self) -> Px {
        let var_q16 = self.var_q16;
        if var_q16 > 0 {
            // √(var · 2^16), the radicand shifted right by an even `t`
            // to fit 32 bits (var < 2^31: m₂/m₀ is below the window's
            // span squared, 2^16).
            let var = var_q16.min(u32::MAX as i64) as u32;
            let t = ((32 - var.leading_zeros()).saturating_sub(16) + 1) & !1;
            let sd_q16 = (isqrt32(var << (16 - t)) << (t / 2)) as i64;
            Px(((sd_q16 * TRUNCATED_WIDTH_Q16) >> 16).min(i32::MAX as i64) as i32)
        } else {
            Px(0)
        }
    }
}

/// What the passes read in place came to.
enum Passes {
    /// The last pass.
    Fit(Fit),
    /// A window held no light above its background: no stripe.
    NoLight,
    /// A pass would read past the pixels checked: [`clamped_passes`]
    /// instead.
    Leaves,
}

/// `num · 2^16 / den` (`num ≥ 0`, `den > 0`, `num / den < 2^16`): both
/// shifted until the denominator is below 2^24 (a relative error under
/// 2^−23), then three 32-bit hardware divisions — the M7 has no 64-bit one,
/// and the library's takes ten times as long.
#[inline(always)]
fn q16_ratio(num: i64, den: i64) -> i64 {
    let sh = (64 - den.leading_zeros()).saturating_sub(24);
    let (n, d) = (num >> sh, (den >> sh).max(1));
    if !(0..1 << 32).contains(&n) {
        return (num << 16) / den.max(1);
    }
    let (n, d) = (n as u32, d as u32);
    let (q, r) = (n / d, n % d);
    // r < d < 2^24: r·2^8 fits, twice.
    let (f1, r1) = ((r << 8) / d, (r << 8) % d);
    let f2 = (r1 << 8) / d;
    ((q as i64) << 16) + ((f1 as i64) << 8) + f2 as i64
}

/// Σw, Σw·d, Σw·d² over `inner` (`w = 3x − bg3`, `d` from 1), in 32 bits
/// (up to 40 px and 13 bits: Σd²·w < 40³/3 × 3 × 2^13 < 2^30); the
/// brightest pixel into `brightest`.
#[inline(always)]
fn sums32<S: Sample>(inner: &[S], bg3: i32, brightest: &mut i32) -> (i64, i64, i64) {
    let (mut s, mut sx, mut sxx) = (0i32, 0i32, 0i32);
    let (mut d, mut dd) = (0i32, 0i32);
    let mut top = *brightest;
    for p in inner {
        let v = p.get();
        if v > top {
            top = v;
        }
        // d² from (d − 1)²: one addition.
        dd += 2 * d + 1;
        d += 1;
        let w = 3 * v - bg3;
        s += w;
        sx += d * w;
        sxx += dd * w;
    }
    *brightest = top;
    (s as i64, sx as i64, sxx as i64)
}

/// [`sums32`] in 64 bits (wide windows, deep pixels; out of line: rare).
#[inline(never)]
fn sums64<S: Sample>(inner: &[S], bg3: i64, brightest: &mut i32) -> (i64, i64, i64) {
    let (mut s, mut sx, mut sxx) = (0i64, 0i64, 0i64);
    for (d, p) in (1i64..).zip(inner) {
        let v = p.get();
        *brightest = (*brightest).max(v);
        let w = 3 * v as i64 - bg3;
        (s, sx, sxx) = (s + w, sx + d * w, sxx + d * d * w);
    }
    (s, sx, sxx)
}

/// The centroid's passes on pixels `x` all below the saturation level,
/// at most 2^12 (the caller's test), read in place without clamps: each
/// pass checks once that its background's span (which holds its window)
/// lies within `x` ([`Passes::Leaves`] where it does not). Per pass the
/// raw sums Σv, Σk·v (and, on the last, Σk(k+1)/2·v) are running sums (an
/// addition a sum a pixel), the background and the weights' offsets are
/// taken off once after, and everything is in 32 bits: the same centroid
/// as [`clamped_passes`] but for the edge pixels' Q16 parts, here kept to
/// 1/128 of a count (a position within `span / (128 Σw)` px of it,
/// 10⁻⁵ px on a stripe of 300 counts).
#[inline(always)]
fn in_place<S: Sample>(x: &[S], plan: &Plan, start_q16: i32) -> Passes {
    let p1 = match pass::<S, true, false>(x, plan, start_q16) {
        Ok((q, _)) => q,
        Err(e) => return e,
    };
    let p2 = match pass::<S, false, false>(x, plan, p1) {
        Ok((q, _)) => q,
        Err(e) => return e,
    };
    match pass::<S, false, true>(x, plan, extrapolated([start_q16, p1, p2])) {
        Ok((q, var_q16)) => Passes::Fit(Fit { pos_q16: q as i64, var_q16 }),
        Err(e) => e,
    }
}

/// The fixed point of the line through two passes `p₀ → p₁ → p₂`
/// (Aitken's Δ²): a pass contracts the distance to the fixed point by ρ
/// (the steps' ratio), so it lies at `p₂ + d₂·ρ/(1 − ρ)`. Starting from
/// the brightest pixel, the residual ρ³ of three plain passes (10⁻³ px at
/// σ 3 px where the brightest pixel is one of two equal ones, and a row
/// and its mirror image start a pixel apart) becomes its variation over
/// the steps. A fixed point stays one (no step, no move), and the
/// arithmetic is odd in the steps (divisions truncate towards zero), so a
/// mirrored row moves the mirrored way. Where the steps do not contract
/// (|ρ| ≥ ½: noise, a jump) or are long (8 px), `p₂`.
#[inline(always)]
fn extrapolated([p0, p1, p2]: [i32; 3]) -> i32 {
    let (Some(d1), Some(d2)) = (p1.checked_sub(p0), p2.checked_sub(p1)) else {
        return p2;
    };
    if d2 == 0 || 2 * d2.unsigned_abs() >= d1.unsigned_abs() || d2.unsigned_abs() >= 1 << 19 {
        return p2;
    }
    // ρ in Q12 (|ρ| < ½), then d₂·ρ/(1 − ρ): |d₂·ρ| < 2^30.
    let rho_q12 = (d2 << 12) / d1;
    p2.saturating_add(d2 * rho_q12 / (4096 - rho_q12))
}

/// One pass of [`in_place`] from `pos_q16`: the centroid and (on the
/// `LAST`) its variance (Q16 px²).
///
/// # Range
/// Pixels below 2^12 over at most 40 inner pixels: |w| = |3v − bg3| < 2^14,
/// Σw < 2^19.3, Σw·d < 2^24.7 (d ≤ 41), Σw·d² < 2^30; an edge pixel's
/// weight times its part (Q16) < 2^30. At 1/128 of a count the moments
/// Σw < 2^26.3 and Σw·d < 2^31 − 2^26, so the quotient's digits come by
/// 32-bit divisions ([`q16_ratio32`]).
#[inline(always)]
fn pass<S: Sample, const FIRST: bool, const LAST: bool>(
    x: &[S],
    plan: &Plan,
    pos_q16: i32,
) -> Result<(i32, i64), Passes> {
    let outer = plan.centroid_outer_px;
    let centre = ((pos_q16 + 32_768) >> 16) as usize;
    // On a half pixel (the `FIRST` pass's start between two pixels), both
    // roundings.
    let halfway = FIRST && pos_q16 & 0xFFFF == 0x8000;
    let (Some(l), r) = (centre.checked_sub(outer + halfway as usize), centre + outer) else {
        return Err(Passes::Leaves);
    };
    let Some(span_px) = x.get(l..=r) else {
        return Err(Passes::Leaves);
    };
    // Background ×3: the lower of the three-pixel sums at ±5σ.
    let (Some(a), Some(b)) = (span_px.first_chunk::<4>(), span_px.last_chunk::<4>()) else {
        return Err(Passes::Leaves);
    };
    let sum3 = |p: &[S]| p[0].get() + p[1].get() + p[2].get();
    let (bl, br) = (sum3(&a[halfway as usize..]), sum3(&b[1..]));
    let bg3 = if halfway { bl.min(br).min(sum3(a)).min(sum3(b)) } else { bl.min(br) };
    // The window `[pos − half, pos + half]` over whole pixels (as
    // [`Window::at`]) within the background's span (3σ < 5σ − 1 for σ ≥ 1).
    let (wa, wb) = (pos_q16 - plan.centroid_half_q16 as i32, pos_q16 + plan.centroid_half_q16 as i32);
    let (lo, hi) = ((wa + 32_768) >> 16, (wb + 32_768) >> 16);
    let (lo_q16, hi_q16) = ((lo << 16) + 32_768 - wa, wb - ((hi << 16) - 32_768));
    if lo < l as i32 || hi > r as i32 || hi - lo > 41 {
        return Err(Passes::Leaves);
    }
    let (lo, hi) = (lo as usize, hi as usize);
    let (Some(inner), Some(xl), Some(xh)) = (x.get(lo + 1..hi), x.get(lo), x.get(hi)) else {
        return Err(Passes::Leaves);
    };
    let (s0, t1, u2) = raw_sums::<S, LAST>(inner);
    // With d = i + 1 over the inner pixels (i from 0) and k = m − i:
    // Σd·v = (m + 1)Σv − Σk·v, Σd²·v = (m + 1)²Σv − (2m + 3)Σk·v + 2Σk(k+1)/2·v.
    let m = inner.len() as i32;
    let s = 3 * s0 - m * bg3;
    let sx = 3 * ((m + 1) * s0 - t1) - bg3 * (m * (m + 1) / 2);
    // The edge pixels by the part of them inside the window (Q16): the
    // centroid then moves smoothly with its window, so the iteration has
    // one fixed point.
    let (wl, wh) = ((3 * xl.get() - bg3) * lo_q16, (3 * xh.get() - bg3) * hi_q16);
    let span = (hi - lo) as i32;
    // The moments at 1/128 of a count (Q7).
    let m0 = (s << 7) + (wl >> 9) + (wh >> 9);
    let m1 = (sx << 7) + span * (wh >> 9);
    if m0 <= 0 || m1 < 0 {
        return Err(Passes::NoLight);
    }
    // Within the window (where negative weights put it further, the
    // moments are not a stripe's; the clamp keeps the arithmetic in range).
    let pos_q16 = ((lo as i32) << 16) + q16_ratio32(m1 as u32, m0 as u32).min((span as u32) << 16) as i32;
    let var_q16 = if LAST {
        // The second moment about the window's middle pixel `c` (so that
        // the square of the mean taken off is small), edges' parts to 1/16
        // of a count: Σw·(d − c)² = Σw·d² − 2c·Σw·d + c²·Σw, each < 2^30
        // and the sum < 2^26.2 before the shift.
        let sdd = (m + 1) * (m + 1) * s0 - (2 * m + 3) * t1 + 2 * u2;
        let sxx = 3 * sdd - bg3 * (m * (m + 1) * (2 * m + 1) / 6);
        let c = span >> 1;
        let about_c = sxx - 2 * c * sx + c * c * s;
        let m0 = (s << 4) + ((wl >> 12) + (wh >> 12));
        let m2 = (about_c << 4) + (wl >> 12) * c * c + (wh >> 12) * (span - c) * (span - c);
        let off_q16 = (pos_q16 - ((lo as i32) << 16) - (c << 16)) as i64;
        if m0 > 0 {
            q16_ratio32(m2.max(0) as u32, m0 as u32).min(((span * span) as u32) << 16) as i64
                - ((off_q16 * off_q16) >> 16)
        } else {
            0
        }
    } else {
        0
    };
    Ok((pos_q16, var_q16))
}

/// `num · 2^16 / den` (`den > 0`, `num / den < 2^16`, `den < 2^26`): the
/// whole part, then the fraction 6, 6 and 4 bits at a time, each a 32-bit
/// division of a remainder below `den · 2^6 < 2^32`.
#[inline(always)]
fn q16_ratio32(num: u32, den: u32) -> u32 {
    let d = den.max(1);
    let (q, r) = (num / d, num % d);
    let (f1, r) = ((r << 6) / d, (r << 6) % d);
    let (f2, r) = ((r << 6) / d, (r << 6) % d);
    let f3 = (r << 4) / d;
    (q << 16) | (f1 << 10) | (f2 << 4) | f3
}

/// Σv, Σk·v and (`LAST`) Σk(k+1)/2·v over `inner`, `k = len − i` for the
/// pixel at `i`: running sums, one addition each a pixel. Exact in 32 bits
/// for up to 40 pixels below 2^13 (Σk(k+1)/2 ≤ 11 480, × 2^13 < 2^27);
/// wrapping where a pixel is above that (the caller then starts again on a
/// clamped copy).
#[inline(always)]
fn raw_sums<S: Sample, const LAST: bool>(inner: &[S]) -> (i32, i32, i32) {
    let (mut s0, mut t1, mut u2) = (0i32, 0i32, 0i32);
    for p in inner {
        s0 = s0.wrapping_add(p.get());
        t1 = t1.wrapping_add(s0);
        if LAST {
            u2 = u2.wrapping_add(t1);
        }
    }
    (s0, t1, u2)
}

/// Whether a pixel of `x` is at or above `sat` (`sat < 2^13`), two pixels
/// a word: a half `p` below 2^15 plus `2^15 − sat` sets its bit 15 exactly
/// where `p ≥ sat`, and carries into nothing (`p + 2^15 − sat < 2^16`); a
/// half at or above 2^15 has that bit set already.
#[inline(always)]
fn any_at_least<S: Sample>(x: &[S], sat: i32) -> bool {
    const LANES: u32 = 0x0001_0001;
    let k = (0x8000 - sat) as u32 * LANES;
    let (pairs, rest) = x.as_chunks::<2>();
    let mut acc = rest.first().map_or(0, |p| (p.get() as u32 & 0xFFFF).wrapping_add(k) | p.get() as u32);
    for p in pairs {
        let w = S::word(p);
        acc |= w.wrapping_add(k) | w;
    }
    acc & 0x8000_8000 != 0
}

/// ⌊√n⌋ by Newton's iteration from above (a power of two at least √n):
/// each step a 32-bit division, five or six in all (the library's 64-bit
/// root calls a 64-bit division at every step).
#[inline(always)]
fn isqrt32(n: u32) -> u32 {
    if n == 0 {
        return 0;
    }
    let mut x = 1u32 << (32 - n.leading_zeros()).div_ceil(2);
    loop {
        let y = (x + n / x) >> 1;
        if y >= x {
            return x;
        }
        x = y;
    }
}

/// [`detect`] on a copy of the window clamped to the saturation level
/// (out of line: only for a level set below full scale, with pixels above it).
#[inline(never)]
fn detect_clamped<S: Sample>(v: &RowView<'_, S>, start: usize) -> Result<Option<Stripe>, Wider> {
    let mut buf = [0i32; CLAMPED_MAX];
    let n = v.x.len().min(CLAMPED_MAX);
    let sat = v.cfg.saturation as i32;
    for (b, p) in buf.iter_mut().zip(v.x) {
        *b = p.get().min(sat);
    }
    let view = RowView {
        x: &buf[..n],
        g: v.g,
        cfg: v.cfg,
        plan: v.plan,
        noise_q8: v.noise_q8,
        off: v.off,
        row_len: v.row_len,
    };
    detect(&view, start)
}

/// Longest window [`detect_clamped`] copies, px.
const CLAMPED_MAX: usize = 256;

/// The centroid's passes from `start_q16` (window coordinates, Q16) with
/// every read clamped to the window and to the saturation level (the
/// general path: near the window's ends, wide windows, deep pixels), and
/// the brightest pixel of the windows. `None` if a window holds no light
/// above its background.
#[inline(never)]
fn clamped_passes<S: Sample>(v: &RowView<'_, S>, start_q16: i64) -> Option<(Fit, i32)> {
    let x = v.x;
    let n = x.len() as i64;
    let half_q16 = v.plan.centroid_half_q16;
    let outer = v.plan.centroid_outer_px as i64;
    let sat = v.cfg.saturation as i32;
    let last = n - 1;
    // One pixel, in place from the sensor's row, nothing above saturation.
    let at = |i: i64| {
        let v = x[i.clamp(0, last) as usize].get();
        if v > sat { sat } else { v }
    } as i64;
    let mut win = Window::default();
    let mut moments = (0i64, 0i64, 0i64);
    let mut brightest = 0;
    let mut p = [start_q16.clamp(0, last << 16); ITERATIONS];
    let mut pos_q16 = p[0];
    for i in 0..ITERATIONS {
        if i + 1 == ITERATIONS {
            // The last pass from the fixed point extrapolated from the
            // first two ([`extrapolated`]).
            let q = p.map(|q| i32::try_from(q).unwrap_or(i32::MAX));
            pos_q16 = if q.contains(&i32::MAX) { p[i] } else { extrapolated(q) as i64 };
        }
        let centre = (pos_q16 + 32_768) >> 16;
        // Background ×3: the lower of the three-pixel sums at ±5σ (on a
        // half pixel, of both roundings', as [`pass`]).
        let (l, r) = (centre - outer, centre + outer);
        let sum3 = |i: i64| at(i) + at(i + 1) + at(i + 2);
        let bg3 = sum3(l).min(sum3(r - 2));
        let bg3 = if pos_q16 & 0xFFFF == 0x8000 { bg3.min(sum3(l - 1)).min(sum3(r - 3)) } else { bg3 };
        win = Window::at(pos_q16, half_q16, n);
        // A window past the row's end (a centre moved off it by noise):
        // no stripe.
        let inner = x.get((win.lo + 1) as usize..win.hi as usize)?;
        let (s, sx, sxx) = if inner.len() <= 40 && sat < 1 << 13 {
            sums32(inner, bg3 as i32, &mut brightest)
        } else {
            sums64(inner, bg3, &mut brightest)
        };
        let (wl, wh) = ((3 * at(win.lo) - bg3) * win.lo_q16, (3 * at(win.hi) - bg3) * win.hi_q16);
        let span = win.hi - win.lo;
        moments = ((s << 16) + wl + wh, (sx << 16) + span * wh, (sxx << 16) + span * span * wh);
        if moments.0 <= 0 || moments.1 < 0 {
            return None;
        }
        pos_q16 = (win.lo << 16) + q16_ratio(moments.1, moments.0);
        if i + 1 < ITERATIONS {
            p[i + 1] = pos_q16;
        }
    }
    // Σw·d²/Σw − mean², d from the window's first pixel.
    let (m0, _, m2) = moments;
    let mean_q16 = pos_q16 - (win.lo << 16);
    let var_q16 = q16_ratio(m2.max(0), m0) - ((mean_q16 * mean_q16) >> 16);
    Some((Fit { pos_q16, var_q16 }, brightest))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::ScaleRange;
    use crate::peak::Config;

    fn xorshift(s: &mut u64) -> u64 {
        *s ^= *s << 13;
        *s ^= *s >> 7;
        *s ^= *s << 17;
        *s
    }

    #[test]
    fn isqrt32_is_the_floor_of_the_root() {
        let mut s = 7u64;
        let cases = (0..70_000u32).chain((0..20_000).map(|_| xorshift(&mut s) as u32)).chain([u32::MAX, 1 << 31]);
        for n in cases {
            let r = isqrt32(n) as u64;
            assert!(r * r <= n as u64 && (r + 1) * (r + 1) > n as u64, "{n}: {r}");
        }
    }

    #[test]
    fn q16_ratio32_is_the_floor_of_the_quotient() {
        let mut s = 11u64;
        for _ in 0..50_000 {
            let den = (xorshift(&mut s) % (1 << 26)) as u32 + 1;
            let num = (xorshift(&mut s) % (den as u64 * 41)) as u32;
            let want = ((num as u64) << 16) / den as u64;
            assert_eq!(q16_ratio32(num, den) as u64, want, "{num} / {den}");
        }
    }

    /// The in-place passes (32 bits, the edges' parts to 1/128 of a count)
    /// and the clamped passes (64 bits) find the same centroid to 10⁻⁴ px
    /// and the same width to 10⁻³ px, on noisy 12-bit stripes of σ 1.5 to
    /// 4 px from starts up to 3 px off, and one at full scale but a count.
    #[test]
    fn in_place_passes_match_the_clamped_ones() {
        extern crate std;
        let cfg = Config::new(12, ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap());
        let plan = Plan::new(&cfg).unwrap();
        let mut s = 3u64;
        for trial in 0..3_000 {
            let sigma = 1.5 + 2.5 * (xorshift(&mut s) % 1000) as f64 / 1000.0;
            let x0 = 40.0 + (xorshift(&mut s) % 1000) as f64 / 1000.0;
            let amp = if trial == 0 { 3794.0 } else { 100.0 + (xorshift(&mut s) % 3500) as f64 };
            let x: [u16; 81] = core::array::from_fn(|i| {
                let t = (i as f64 - x0) / sigma;
                let noise = (xorshift(&mut s) % 21) as f64 - 10.0;
                (300.0 + amp * std::primitive::f64::exp(-0.5 * t * t) + noise).clamp(0.0, 4094.0) as u16
            });
            let start = 40 + (xorshift(&mut s) % 7) as usize - 3;
            let v = RowView { x: &x[..], g: &[], cfg: &cfg, plan: &plan, noise_q8: 5 << 8, off: 0, row_len: x.len() };
            let Passes::Fit(fast) = in_place(&x[..], &plan, (start as i32) << 16) else {
                panic!("trial {trial}: the in-place passes gave no fit");
            };
            let (slow, _) = clamped_passes(&v, (start as i64) << 16).unwrap();
            let d = (fast.pos_q16 - slow.pos_q16) as f64 / 65536.0;
            assert!(d.abs() < 1e-4, "trial {trial}: σ {sigma:.2} x0 {x0:.3}: {d:e} px");
            let dw = (fast.width().to_f64() - slow.width().to_f64()).abs();
            assert!(dw < 1e-3, "trial {trial}: width {} against {}", fast.width(), slow.width());
        }
    }

    /// A row whose two brightest pixels are equal: it and its mirror image
    /// take their first maxima a pixel apart, and still give mirrored
    /// positions to 10⁻⁴ px (the rounding of a few divisions: a few
    /// 2^−16 px), σ 1.6–3.8 px; three plain passes from those pixels left
    /// up to 10⁻³ px.
    #[test]
    fn a_tie_at_the_top_still_mirrors() {
        extern crate std;
        let cfg = Config::new(12, ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap());
        let plan = Plan::new(&cfg).unwrap();
        let mut s = 5u64;
        let mut worst = 0.0f64;
        for trial in 0..2_000 {
            let sigma = 1.6 + 2.2 * (xorshift(&mut s) % 1000) as f64 / 1000.0;
            let x0 = 40.5 + ((xorshift(&mut s) % 200) as f64 - 100.0) / 1000.0;
            let mut x: [u16; 81] = core::array::from_fn(|i| {
                let t = (i as f64 - x0) / sigma;
                let noise = (xorshift(&mut s) % 11) as f64 - 5.0;
                (300.0 + 2500.0 * std::primitive::f64::exp(-0.5 * t * t) + noise) as u16
            });
            let top = x[40].max(x[41]);
            (x[40], x[41]) = (top, top);
            let mut m = x;
            m.reverse();
            let at = |x: &[u16]| {
                let start = (0..x.len()).fold(0, |b, i| if x[i] > x[b] { i } else { b });
                let v = RowView { x, g: &[], cfg: &cfg, plan: &plan, noise_q8: 5 << 8, off: 0, row_len: x.len() };
                detect(&v, start).unwrap().unwrap().position.to_f64()
            };
            let d = at(&x[..]) + at(&m[..]) - 80.0;
            worst = worst.max(d.abs());
            assert!(d.abs() < 1e-4, "trial {trial}: σ {sigma:.2} x0 {x0:.3}: mirror error {d:e} px");
        }
        std::println!("worst mirror error {worst:e} px");
    }
}
