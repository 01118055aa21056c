//! Saturated stripes: a run of pixels at the saturation level is one
//! stripe whatever the method, centred on the run by the half-level
//! crossings of its flanks.

use super::{Flags, RowView, Stripe};
use crate::fixed::Px;

/// One stripe from a saturated run `[s, e]`: centre of the half-level
/// crossings on both flanks (the run's midpoint if a flank is missing).
pub(super) fn saturated_stripe(v: &RowView<'_>, (s, e): (usize, usize), sat: i32) -> Option<Stripe> {
    let x = v.x;
    let n = x.len();
    let len = e - s + 1;
    let max_len = (6 * v.cfg.max_width.0 as usize).div_ceil(65536);
    if len > max_len.max(4) {
        return None;
    }
    let reach = len + 3 * v.plan.smax_px;
    let lo = s.saturating_sub(reach);
    let hi = (e + reach).min(n - 1);
    let bg = x[lo..=hi].iter().copied().min().unwrap_or(0);
    let level = (sat + bg) / 2;
    let mut flags = Flags::SATURATED;
    let mid = Px((((s + e) as i64) << 15) as i32);
    let left = (0..s).rev().find(|&i| x[i] < level).map(|i| {
        // crossing between i and i+1
        let (a, b) = (x[i] as i64, x[i + 1] as i64);
        Px(((i as i64) << 16) as i32 + (((level as i64 - a) << 16) / (b - a).max(1)) as i32)
    });
    let right = (e + 1..n).find(|&i| x[i] < level).map(|i| {
        let (a, b) = (x[i - 1] as i64, x[i] as i64);
        Px((((i - 1) as i64) << 16) as i32 + (((a - level as i64) << 16) / (a - b).max(1)) as i32)
    });
    let (position, width) = match (left, right) {
        (Some(l), Some(r)) => {
            (Px(((l.0 as i64 + r.0 as i64) / 2) as i32), Px((((r.0 - l.0) as i64 * 27_830) >> 16) as i32))
        }
        _ => {
            flags.insert(Flags::CLIPPED);
            flags.insert(Flags::LOW_CONFIDENCE);
            (mid, Px(((((len as i64) << 16) * 27_830) >> 16) as i32))
        }
    };
    // 27_830 / 65536 = 1/2.3548: full width at half level → σ of a Gaussian
    // (the half level is below the clipped stripe's true half maximum, so
    // this errs wide: a stripe of σ ≥ σ_min is never measured narrower).
    // A saturated run is a stripe only if it is one by its width and it
    // stands out of the noise as the detection test demands of any stripe
    // (at the pixel level: the height above the background over `threshold
    // × σ`): a stuck pixel or pair at full scale is neither.
    let strength = (sat - bg).max(0) as i64;
    let floor = ((v.noise_q8 as i64 * v.cfg.threshold_sigma_q8 as i64) >> 16).max(v.cfg.min_amplitude as i64).max(1);
    if width < v.cfg.min_width || strength < floor {
        return None;
    }
    Some(Stripe { position, strength: strength as u32, width, flags })
}
