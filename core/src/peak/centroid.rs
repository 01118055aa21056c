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

/// Centroids, each on the last one's centre: from the detection's
/// sub-pixel guess the first lands within a few tenths of a pixel of
/// where the iteration settles, the third within a hundredth (measured:
/// more change the points' scatter under speckle by under 1 %).
const ITERATIONS: usize = 3;

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

/// `num · 2^16 / den` for `0 < den`: hardware 32-bit
/// divisions while the denominator is below 2^18 (every 8–12-bit row),
/// 64-bit otherwise.
#[inline(always)]
fn q16_ratio(num: i64, den: i64) -> i64 {
    if (0..1 << 31).contains(&num) && den < 1 << 18 {
        let (n, d) = (num as u32, den as u32);
        let (q, r) = (n / d, n % d);
        // r < d < 2^18: r·2^14 fits; the last two bits are zero (1/16384 px).
        ((q as i64) << 16) + ((((r << 14) / d) as i64) << 2)
    } else {
        (num << 16) / den
    }
}

/// A centroid of ±3σ's relative second moment: `1 − 6φ(3)/(2Φ(3) − 1)`,
/// so `σ = √m₂ / 0.9866`; Q16 of 1/0.9866.
const TRUNCATED_WIDTH_Q16: i64 = 66_426;

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
    let mut weights = (0i64, 0i64);
    let mut lo = 0i64;
    let mut bg3 = 0i64;
    for _ in 0..ITERATIONS {
        let centre = (pos_q16 + 32_768) >> 16;
        // Background ×3: the lower of the three-pixel sums at ±5σ.
        let (l, r) = (centre - outer, centre + outer);
        bg3 = (at(l) + at(l + 1) + at(l + 2)).min(at(r - 2) + at(r - 1) + at(r));
        lo = ((pos_q16 - half_q16 + 32_768) >> 16).max(0);
        let hi = ((pos_q16 + half_q16 + 32_768) >> 16).min(n - 1);
        let (mut s, mut sx) = (0i64, 0i64);
        for i in lo..=hi {
            let xi = at(i);
            if xi >= sat {
                flags.insert(Flags::SATURATED);
            }
            let w = 3 * xi - bg3;
            s += w;
            sx += (i - lo) * w;
        }
        if s <= 0 {
            return None;
        }
        weights = (s, sx);
        pos_q16 = (lo << 16) + q16_ratio(sx, s);
    }
    let (s, _) = weights;
    // Width: the second moment about the centre over the same window.
    let hi = ((pos_q16 + half_q16 + 32_768) >> 16).min(n - 1);
    let mut m2 = 0i64;
    for i in lo..=hi {
        let d_q8 = ((i << 16) - pos_q16) >> 8;
        m2 += d_q8 * d_q8 * (3 * at(i) - bg3);
    }
    let width = if m2 > 0 {
        let m2_q16 = m2 / s;
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
