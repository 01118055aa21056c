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
//! Under white noise alone it is a plain centroid: about 1.6× the
//! Cramér–Rao bound where the CWT reaches 1.0–1.2× (`cms-host bench speckle` and `bench accuracy` have
//! both under both lights).

use super::cwt::{self, Wider};
use super::{Flags, RowView, Sample, Stripe};
use crate::fixed::Px;

/// Centroids, each on the last one's centre. A window of ±3σ moves the
/// centroid by a fraction ρ of its own move (ρ = 2h·f(h)/∫f ≈ 0.13 for a
/// stripe of the window's σ, 0.25 for one 1.5× wider), so from the
/// detection's whole pixel (at most half a pixel from the stripe's centre
/// on white noise) three leave under ρ³/2 ≤ 0.008 px, typically 0.001;
/// under speckle more change the points' scatter by under 1 %. Starting
/// from a whole pixel, not the detection's sub-pixel guess, keeps a row
/// and its mirror image exactly symmetric.
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

/// The multi-scale test of the shared front end ([`cwt::confirm`]: is
/// there a stripe at `start`, how strong), then the centroid.
#[inline(never)]
pub(crate) fn detect<S: Sample>(
    v: &RowView<'_, S>,
    start: usize,
    scratch: &mut [i32],
) -> Result<Option<Stripe>, Wider> {
    let Some(ok) = cwt::confirm_as::<S, false>(v, start, scratch)? else {
        return Ok(None);
    };
    if !v.fits(ok.c, v.plan.method_reach_px) {
        return Err(Wider);
    }
    Ok(refine(v, (ok.c as i64) << 16, ok.amplitude, ok.flags))
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

/// [`refine`] on a copy of the window clamped to the saturation level
/// (out of line: only for a level set below full scale, with pixels above it).
#[inline(never)]
fn refine_clamped<S: Sample>(v: &RowView<'_, S>, start_q16: i64, amplitude: i64, flags: Flags) -> Option<Stripe> {
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
    refine(&view, start_q16, amplitude, flags)
}

/// Longest window [`refine_clamped`] copies, px.
const CLAMPED_MAX: usize = 256;

/// The centroid of the stripe confirmed near `start_q16` (window
/// coordinates, Q16), with the detection's amplitude and flags. `None` if
/// the window holds no light above its background.
fn refine<S: Sample>(v: &RowView<'_, S>, start_q16: i64, amplitude: i64, mut flags: Flags) -> Option<Stripe> {
    let x = v.x;
    let n = x.len() as i64;
    let half_q16 = v.plan.centroid_half_q16;
    let outer = v.plan.centroid_outer_px as i64;
    let c = ((start_q16 + 32_768) >> 16).clamp(0, n - 1) as usize;
    if v.clipped(c, v.plan.centroid_outer_px) {
        flags.insert(Flags::CLIPPED);
    }
    let sat = v.cfg.saturation as i32;
    let last = n - 1;
    // One pixel, in place from the sensor's row, nothing above saturation.
    let at = |i: i64| {
        let v = x[if i < 0 {
            0
        } else if i > last {
            last as usize
        } else {
            i as usize
        }]
        .get();
        if v > sat { sat } else { v }
    } as i64;
    let mut pos_q16 = start_q16.clamp(0, last << 16);
    let mut win = Window::default();
    // Σw, Σw·d, Σw·d² of the last pass, d from the window's first pixel, Q16.
    let mut moments = (0i64, 0i64, 0i64);
    let mut brightest = 0;
    for _ in 0..ITERATIONS {
        let centre = (pos_q16 + 32_768) >> 16;
        // Background ×3: the lower of the three-pixel sums at ±5σ.
        let (l, r) = (centre - outer, centre + outer);
        let (bl, br) = (at(l) + at(l + 1) + at(l + 2), at(r - 2) + at(r - 1) + at(r));
        let bg3 = if bl < br { bl } else { br };
        win = Window::at(pos_q16, half_q16, n);
        let inner = &x[(win.lo + 1) as usize..win.hi as usize];
        let (s, sx, sxx) = if inner.len() <= 40 && sat < 1 << 13 {
            sums32(inner, bg3 as i32, &mut brightest)
        } else {
            sums64(inner, bg3, &mut brightest)
        };
        // The edge pixels by the part of them inside the window (Q16): the
        // centroid then moves smoothly with its window, so the iteration
        // has one fixed point.
        let (wl, wh) = ((3 * at(win.lo) - bg3) * win.lo_q16, (3 * at(win.hi) - bg3) * win.hi_q16);
        let span = win.hi - win.lo;
        moments = ((s << 16) + wl + wh, (sx << 16) + span * wh, (sxx << 16) + span * span * wh);
        if moments.0 <= 0 || moments.1 < 0 {
            return None;
        }
        pos_q16 = (win.lo << 16) + q16_ratio(moments.1, moments.0);
    }
    if brightest > sat {
        // Pixels above the saturation level read in place: again, clamped
        // (only where the level is set below full scale).
        return refine_clamped(v, start_q16, amplitude, flags);
    }
    if brightest >= sat {
        flags.insert(Flags::SATURATED);
    }
    // Width: the second moment about the centre, Σw·d²/Σw − mean².
    let (m0, m1, m2) = moments;
    let mean_q16 = pos_q16 - (win.lo << 16);
    let var_q16 = q16_ratio(m2.max(0), m0) - ((mean_q16 * mean_q16) >> 16);
    let width = if var_q16 > 0 {
        let sd_q16 = ((var_q16 as u64) << 16).isqrt() as i64;
        Px(((sd_q16 * TRUNCATED_WIDTH_Q16) >> 16).min(i32::MAX as i64) as i32)
    } else {
        Px(0)
    };
    let _ = m1;
    Some(Stripe {
        position: Px(pos_q16.clamp(0, (n - 1) << 16) as i32),
        strength: amplitude.clamp(0, u32::MAX as i64) as u32,
        width,
        flags,
    })
}
