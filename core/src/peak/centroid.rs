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
//! Cramér–Rao bound where the CWT reaches 1.0–1.2× (docs/light.md has
//! both under both lights).

use super::cwt::{self, Wider};
use super::kernels::PHASES;
use super::{Flags, RowView, Sample, Stripe};
use crate::fixed::Px;

/// Centroids, each on the last one's centre. A window of ±3σ moves the
/// centroid by a fraction ρ of its own move (ρ = 2h·f(h)/∫f ≈ 0.13 for a
/// stripe of the window's σ, 0.25 for one 1.5× wider), so from the
/// detection's sub-pixel guess (within 1/16 px of its mirror image's)
/// four leave under ρ⁴/16 ≤ 3·10⁻⁴ px; under speckle more change the
/// points' scatter by under 1 %.
const ITERATIONS: usize = 4;

/// A centroid of ±3σ's relative second moment: `1 − 6φ(3)/(2Φ(3) − 1)`,
/// so `σ = √m₂ / 0.9866`; Q16 of 1/0.9866.
const TRUNCATED_WIDTH_Q16: i64 = 66_426;

/// A centroid's window `[pos − half, pos + half]` over whole pixels: the
/// first and last pixel it touches and how much of each it covers (Q16),
/// and what the last pass summed.
#[derive(Clone, Copy, Debug, Default)]
struct Window {
    lo: i64,
    hi: i64,
    lo_q16: i64,
    hi_q16: i64,
    s_q16: i64,
    bg3: i64,
}

impl Window {
    fn at(pos_q16: i64, half_q16: i64, n: i64) -> Window {
        let (a, b) = (pos_q16 - half_q16, pos_q16 + half_q16);
        let (lo, hi) = ((a + 32_768) >> 16, (b + 32_768) >> 16);
        let (lo, lo_q16) = if lo < 0 { (0, 65_536) } else { (lo, ((lo << 16) + 32_768) - a) };
        let (hi, hi_q16) = if hi > n - 1 { (n - 1, 65_536) } else { (hi, b - ((hi << 16) - 32_768)) };
        Window { lo, hi, lo_q16, hi_q16, ..Window::default() }
    }
}

/// The multi-scale test of the shared front end ([`cwt::confirm`]: is
/// there a stripe at `start`, how strong), then the centroid.
pub(crate) fn detect<S: Sample>(
    v: &RowView<'_, S>,
    start: usize,
    scratch: &mut [i32],
) -> Result<Option<Stripe>, Wider> {
    let Some(ok) = cwt::confirm(v, start, scratch)? else {
        return Ok(None);
    };
    if !v.fits(ok.c, v.plan.method_reach_px) {
        return Err(Wider);
    }
    let start_q16 = ((ok.c as i64) << 16) + ok.guess as i64 * (65_536 / PHASES as i64);
    Ok(refine(v, start_q16, ok.amplitude, ok.flags))
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
    let sat = v.cfg.saturation as i64;
    // Read in place from the sensor's row, nothing above saturation.
    let at = |i: i64| (x[i.clamp(0, n - 1) as usize].get() as i64).min(sat);
    let mut pos_q16 = start_q16.clamp(0, (n - 1) << 16);
    let mut acc = Window::default();
    for _ in 0..ITERATIONS {
        let centre = (pos_q16 + 32_768) >> 16;
        // Background ×3: the lower of the three-pixel sums at ±5σ.
        let (l, r) = (centre - outer, centre + outer);
        let bg3 = (at(l) + at(l + 1) + at(l + 2)).min(at(r - 2) + at(r - 1) + at(r));
        acc = Window::at(pos_q16, half_q16, n);
        let (mut s, mut sx) = (0i64, 0i64);
        for i in acc.lo + 1..acc.hi {
            let xi = at(i);
            if xi >= sat {
                flags.insert(Flags::SATURATED);
            }
            let w = 3 * xi - bg3;
            s += w;
            sx += (i - acc.lo) * w;
        }
        // The edge pixels by the part of them inside the window (Q16): the
        // centroid then moves smoothly with its window, so the iteration
        // has one fixed point, the same for a row and its mirror image.
        let (wl, wh) = (3 * at(acc.lo) - bg3, 3 * at(acc.hi) - bg3);
        let s_q16 = (s << 16) + wl * acc.lo_q16 + wh * acc.hi_q16;
        let sx_q16 = (sx << 16) + (acc.hi - acc.lo) * wh * acc.hi_q16;
        if s_q16 <= 0 || sx_q16 < 0 {
            return None;
        }
        acc.s_q16 = s_q16;
        acc.bg3 = bg3;
        pos_q16 = (acc.lo << 16) + q16_ratio(sx_q16, s_q16);
    }
    // Width: the second moment about the centre over the last window.
    let mut m2 = 0i64;
    for i in acc.lo..=acc.hi {
        let d_q8 = ((i << 16) - pos_q16) >> 8;
        let part = if i == acc.lo {
            acc.lo_q16
        } else if i == acc.hi {
            acc.hi_q16
        } else {
            65_536
        };
        m2 += ((d_q8 * d_q8 * (3 * at(i) - acc.bg3)) >> 8) * part >> 8;
    }
    let width = if m2 > 0 {
        let m2_q16 = (m2 << 16) / acc.s_q16;
        let sd_q16 = ((m2_q16 as u64) << 16).isqrt() as i64;
        Px(((sd_q16 * TRUNCATED_WIDTH_Q16) >> 16).min(i32::MAX as i64) as i32)
    } else {
        Px(0)
    };
    Some(Stripe {
        position: Px(pos_q16.clamp(0, (n - 1) << 16) as i32),
        strength: amplitude.clamp(0, u32::MAX as i64) as u32,
        width,
        flags,
    })
}
