//! What a [`Config`] means for the detector, worked out once when it is
//! validated ([`Detector::new`](super::Detector::new)): rungs of the
//! kernel ladder, reaches and the widest rungs the 32-bit paths may use.

use super::{Config, Error, Method, kernels, screen};
use crate::fixed::Px;

/// Rung indices and constants derived once from a [`Config`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Plan {
    /// Ladder rungs covering the scale range.
    pub k_lo: usize,
    pub k_hi: usize,
    /// Rungs just beyond the width limits (the CWT measures widths out to there).
    pub k_width_lo: usize,
    pub k_width_hi: usize,
    /// Rung of the coarse pass.
    pub k_coarse: usize,
    /// Where the CWT's climb in scale starts: `k_coarse` within `k_lo..=k_hi`.
    pub k_start: usize,
    /// Integer scales of the paper's method.
    pub paper_lo: usize,
    pub paper_hi: usize,
    /// Hot-pixel test: e^(1/σ_min²), Q16.
    pub spike_k_q16: i64,
    /// Largest scale rounded up, px.
    pub smax_px: usize,
    /// The centroid's half-window, 3σ of the scale range's geometric
    /// middle, Q16 px; and where it reads its background, 5σ rounded, px.
    pub centroid_half_q16: i64,
    pub centroid_outer_px: usize,
    /// The rung the centroid's detection test responds on: the one nearest
    /// that middle (the optics' scale).
    pub centroid_k: usize,
    /// Smallest scale rounded down (at least 1), px: the screen's absolute
    /// floor is `min_amplitude` × this.
    pub smin_floor_px: usize,
    /// log2 of the screen's block width, px ([`screen::block_log2`]).
    pub block_log2: u32,
    /// √(4B), Q8: the screen response's σ per count of white pixel noise.
    pub screen_white_q8: i64,
    /// How far from its start pixel a candidate's estimators read, px, at
    /// most (stripes up to the width limit) and for stripes up to the scale
    /// range's top: the window first copied is the second, plus the screen's
    /// uncertainty each side; a wider stripe asks for the first.
    pub reach_px: usize,
    pub typ_reach_px: usize,
    /// How far a baseline estimator reads from the confirmed pixel, px.
    pub method_reach_px: usize,
    /// The widest fit rung whose slope fits 32 bits on pixels up to the
    /// saturation level (`sat < 2^15` and `sat × deriv_abs < 2^31`, and its
    /// taps stored in pairs: [`cwt::slope_pair32`]); `None`: not even the
    /// first.
    pub slope32_k: Option<usize>,
    /// The widest rung whose Ricker response is made in 32 bits straight
    /// from the row (`2·sat < 2^15` and `sat × (ricker_abs + 2^15) < 2^31`:
    /// [`cwt::ricker_sum32`]).
    pub ricker32_k: Option<usize>,
}

fn rung_floor(px: Px) -> usize {
    let mut k = 0;
    for (i, r) in kernels::RUNGS.iter().enumerate() {
        if r.scale_q16 <= px {
            k = i;
        }
    }
    k
}

fn rung_ceil(px: Px) -> usize {
    kernels::RUNGS.iter().position(|r| r.scale_q16 >= px).unwrap_or(kernels::LADDER_LEN - 1)
}

/// exp(x) for 0 ≤ x ≤ 4 by series (configuration only).
fn exp_small(x: f64) -> f64 {
    let mut term = 1.0;
    let mut sum = 1.0;
    for n in 1..40 {
        term *= x / n as f64;
        sum += term;
    }
    sum
}

impl Plan {
    pub(super) fn new(cfg: &Config) -> Result<Plan, Error> {
        if !(8..=16).contains(&cfg.bits) {
            return Err(Error::BitDepth(cfg.bits));
        }
        let (smin, smax) = (cfg.scales.min(), cfg.scales.max());
        if smin.0 < Px::ONE.0 {
            return Err(Error::ScaleTooSmall);
        }
        if smax.0 > Px::from_int(24).0 {
            return Err(Error::ScaleTooLarge);
        }
        if cfg.max_stripes == 0 {
            return Err(Error::MaxStripes);
        }
        if cfg.min_width.0 <= 0 || cfg.min_width >= cfg.max_width {
            return Err(Error::WidthRange);
        }
        if cfg.threshold_sigma_q8 == 0 {
            return Err(Error::Threshold);
        }
        if cfg.saturation == 0 || (cfg.saturation as u32) > (1u32 << cfg.bits) - 1 {
            return Err(Error::Saturation);
        }
        let k_lo = rung_floor(smin);
        let k_hi = rung_ceil(smax).max(k_lo + 1);
        let geo = (smin.0 as u64 * smax.0 as u64).isqrt();
        let k_coarse = kernels::nearest_rung(Px(geo as i32));
        let paper_lo = (smin.0 as usize).div_ceil(65536).max(1);
        let paper_hi = (smax.0 as usize >> 16).max(paper_lo);
        let w = cfg.min_width.to_f64().max(0.5);
        let spike_k_q16 = (exp_small(1.0 / (w * w)) * 65536.0) as i64;
        let k_width_lo = rung_floor(cfg.min_width).saturating_sub(1).min(k_lo);
        let k_width_hi = (rung_ceil(cfg.max_width) + 1).min(kernels::LADDER_LEN - 4).max(k_hi);
        // Reach of the estimators from the candidate's start pixel: the
        // Ricker responses out to the width limit's rung, the position climb
        // (3 px) and the slope's bracket (3 px more) on the widest fit rung a
        // stripe within the width limits can get (1.5 × max_width, plus the
        // rounding), and the baselines' own windows.
        let rung_half = |k: usize| kernels::RUNGS[k.min(kernels::LADDER_LEN - 1)].half_len;
        let fit_max = rung_ceil(Px(((cfg.max_width.0 as i64 * 3) / 2).min(i32::MAX as i64) as i32)) + 1;
        let smax_px = (smax.0 as usize).div_ceil(65536);
        let cwt_reach = rung_half(k_width_hi).max(rung_half(fit_max)) + 8;
        let paper_reach = 2 * smax_px + kernels::PAPER_RUNGS[paper_hi.min(kernels::PAPER_MAX_SCALE) - 1].1 + 2;
        let c = &kernels::RUNGS[k_coarse];
        let base_reach = 4 * smax_px + 3 + 3 * c.box_half + c.lag + 2;
        let centroid_outer_px = ((5 * geo + 32_768) >> 16) as usize;
        let method_reach_px = match cfg.method {
            Method::Cwt => 0,
            Method::CwtPaper => paper_reach,
            // The background's pixels, and two for the re-centring.
            Method::Centroid => centroid_outer_px + 2,
            _ => base_reach,
        };
        let reach_px = cwt_reach.max(method_reach_px + 6);
        // The first window: a stripe up to the middle of the scale range
        // (its fit rung is 2–3 rungs above it; the sub-pixel search stays
        // within a pixel and reads one more). Wider ones, and a search that
        // has to fall back to the whole-pixel bracket, ask for the full
        // reach, at the price of a second copy.
        let k_mid = (k_lo + k_hi).div_ceil(2);
        let typ_reach_px = (rung_half(k_mid + 3) + 2).max(method_reach_px + 6).min(reach_px);
        // Every sample the estimators read is in 0..=saturation (the
        // in-place window is checked for it, the copy clamps to it).
        let sat = cfg.saturation as i64;
        let slope32_k = if sat < 1 << 15 {
            (0..=kernels::PAIR_RUNGS).take_while(|&k| sat * kernels::RUNGS[k].deriv_abs < 1 << 31).last()
        } else {
            None
        };
        let ricker32_k = if 2 * sat < 1 << 15 {
            (0..kernels::LADDER_LEN).take_while(|&k| sat * (kernels::RUNGS[k].ricker_abs + (1 << 15)) < 1 << 31).last()
        } else {
            None
        };
        Ok(Plan {
            slope32_k,
            ricker32_k,
            smin_floor_px: ((smin.0 as usize) >> 16).max(1),
            block_log2: screen::block_log2(Px(geo as i32)),
            screen_white_q8: (((4u64 << screen::block_log2(Px(geo as i32))) << 16).isqrt()) as i64,
            reach_px,
            typ_reach_px,
            method_reach_px,
            k_lo,
            k_hi,
            k_width_lo,
            k_width_hi,
            k_coarse,
            k_start: k_coarse.clamp(k_lo, k_hi),
            paper_lo,
            paper_hi,
            spike_k_q16,
            smax_px,
            centroid_half_q16: 3 * geo as i64,
            centroid_outer_px,
            centroid_k: k_coarse,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The head's scales (and the benchmark's, σ 2.5 px in 1.5–4 px) read
    /// a first window of the length the sized spike screen is compiled for.
    #[test]
    fn the_default_first_window_is_the_sized_screens() {
        let plan = Plan::new(&crate::pipeline::default_detector()).unwrap();
        assert_eq!(plan.typ_reach_px, super::super::CENTRED_REACH_PX);
    }
}
