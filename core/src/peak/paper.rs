//! The paper's sub-pixel method, Eq. (12)–(13), exactly as written.
//!
//! The CWT of Eq. (2) (`s^(−1/2)` normalisation) with the Ricker wavelet of
//! Eq. (4) is computed at every integer scale in `[ceil(s_min), floor(s_max)]`
//! (the paper's synthetic test: 5..=15, 11 scales) and every position within
//! ±2 s_max of the candidate. The coefficients above a hard threshold
//! `T = ½ max W` (Eq. 12; "the energy of the laser Gaussian pattern" is not
//! specified further, docs/reference.md §1 uses half the maximum) are averaged with their
//! values as weights (Eq. 13): `t = Σ t₀ W / Σ W`.
//!
//! Kept for reproduction and comparison: it locks onto pixels (measured in
//! `cms-host bench accuracy`), and its cost is window × scales × kernel.

use super::kernels;
use super::{Flags, RowView, Stripe};
use crate::fixed::Px;

fn coeff(x: &[i32], t: usize, h: &[i16]) -> i64 {
    let n = x.len();
    let mut acc = h[0] as i64 * x[t] as i64;
    for (m, &w) in h.iter().enumerate().skip(1) {
        acc += w as i64 * (x[t.saturating_sub(m)] + x[(t + m).min(n - 1)]) as i64;
    }
    acc
}

pub(crate) fn refine(v: &RowView<'_>, c: usize) -> Option<Stripe> {
    let x = v.x;
    let n = x.len();
    let (lo_s, hi_s) = (v.plan.paper_lo, v.plan.paper_hi.min(kernels::PAPER_MAX_SCALE));
    let reach = 2 * v.plan.smax_px;
    let t_lo = c.saturating_sub(reach);
    let t_hi = (c + reach).min(n - 1);
    // Pass 1: the largest coefficient and its scale.
    let mut max = i64::MIN;
    let mut best_s = lo_s;
    for s in lo_s..=hi_s {
        let h = kernels::paper(s);
        for t in t_lo..=t_hi {
            let w = coeff(x, t, h);
            if w > max {
                max = w;
                best_s = s;
            }
        }
    }
    if max <= 0 {
        return None;
    }
    // Pass 2: Eq. (12)–(13).
    let thr = max / 2;
    let (mut sw, mut stw) = (0i64, 0i64);
    for s in lo_s..=hi_s {
        let h = kernels::paper(s);
        for t in t_lo..=t_hi {
            let w = coeff(x, t, h);
            if w > thr {
                sw += w;
                stw += w * t as i64;
            }
        }
    }
    let position = Px(((stw << 16) / sw.max(1)) as i32);
    let mut flags = Flags::NONE;
    if v.clipped(c, reach) {
        flags.insert(Flags::CLIPPED);
    }
    // With Eq. (2)'s normalisation a Gaussian of σ responds most at s = √5 σ.
    let width = Px(((((best_s as i64) << 16) * 29_309) >> 16) as i32); // 1/√5 = 29309/65536
    let b = position.round().clamp(0, n as i32 - 1) as usize;
    let bg = super::subpixel::local_background(x, b, reach);
    Some(Stripe { position, strength: (x[b] - bg).max(0) as u32, width, flags })
}
