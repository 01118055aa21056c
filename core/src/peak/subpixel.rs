//! The classic sub-pixel estimators: Table 2 of the paper and Section 6's
//! centre of gravity, with and without a low-pass FIR.
//!
//! Each Table 2 formula is a pure function of the brightest pixel `b` and its
//! neighbours `a` (left) and `c` (right), returning the offset δ from `b`
//! (Q16.16 px). The text of Table 2 lost its brackets; the intended formulas
//! (docs/reference.md §1) are implemented:
//!
//! | estimator | δ |
//! |---|---|
//! | Gaussian | ½ (ln a − ln c) / (ln a − 2 ln b + ln c) |
//! | centre of mass | (c − a) / (a + b + c) |
//! | parabolic | ½ (a − c) / (a − 2b + c) |
//! | linear | (c − a) / (2 (b − c)) if c < a, else (c − a) / (2 (b − a)) |
//! | Blais–Rioux | zero crossing of g(i) = f(i−2) + f(i−1) − f(i+1) − f(i+2) |
//! | FIR zero crossing | x₀ − y₀ (x₁ − x₀) / (y₁ − y₀) of a FIR derivative |
//!
//! The linear-interpolation row of Table 2 as printed swaps the two
//! denominators (δ would diverge as a → b); the form above is the one of
//! Fisher & Naidu, 1996, which gives ±½ px at a = b and c = b.
//!
//! Values are taken above the local background (the minimum within the
//! window), so a pedestal does not bias the ratios. Logarithms are integer:
//! `log2` in Q16 from a 257-entry table with linear interpolation.

use super::kernels::LOG2_Q16;
use super::{Flags, Method, RowView, Stripe};
use crate::fixed::{Px, Q16_16};

/// log2(v) for v ≥ 1 (error < 3·10⁻⁶).
pub fn log2_q16(v: u32) -> Q16_16 {
    debug_assert!(v > 0);
    let e = 31 - v.leading_zeros();
    let m = (v as u64) << (31 - e); // 1.xxx in bit 31
    let idx = ((m >> 23) & 0xff) as usize;
    let rem = ((m >> 7) & 0xffff) as i64;
    let (t0, t1) = (LOG2_Q16[idx] as i64, LOG2_Q16[idx + 1] as i64);
    Q16_16(((e as i64) << 16) as i32 + (t0 + (((t1 - t0) * rem) >> 16)) as i32)
}

fn ratio_q16(num: i64, den: i64) -> Option<Px> {
    if den == 0 {
        return None;
    }
    let q = (num << 16) / den;
    (q.abs() <= 1 << 16).then_some(Px(q as i32))
}

/// Gaussian 3-point fit: ½ (ln a − ln c) / (ln a − 2 ln b + ln c). Inputs > 0.
pub fn gaussian3(a: i32, b: i32, c: i32) -> Option<Px> {
    if a <= 0 || b <= 0 || c <= 0 {
        return None;
    }
    let (la, lb, lc) = (log2_q16(a as u32).0 as i64, log2_q16(b as u32).0 as i64, log2_q16(c as u32).0 as i64);
    ratio_q16(la - lc, 2 * (la - 2 * lb + lc))
}

/// Three-point centre of mass: (c − a) / (a + b + c).
pub fn centre_of_mass3(a: i32, b: i32, c: i32) -> Option<Px> {
    ratio_q16((c - a) as i64, (a + b + c) as i64)
}

/// Parabolic fit: ½ (a − c) / (a − 2b + c).
pub fn parabolic(a: i32, b: i32, c: i32) -> Option<Px> {
    ratio_q16((a - c) as i64, 2 * (a - 2 * b + c) as i64)
}

/// Linear interpolation (two lines of equal and opposite slope).
pub fn linear(a: i32, b: i32, c: i32) -> Option<Px> {
    if c < a { ratio_q16((c - a) as i64, 2 * (b - c) as i64) } else { ratio_q16((c - a) as i64, 2 * (b - a) as i64) }
}

/// Linear zero crossing between `(x0, y0)` and `(x0 + 1, y1)`: x₀ − y₀ / (y₁ − y₀).
pub fn zero_crossing(x0: i32, y0: i64, y1: i64) -> Option<Px> {
    if y1 == y0 {
        return None;
    }
    let d = (-(y0 << 16)) / (y1 - y0);
    (0..=65536).contains(&d).then(|| Px((x0 << 16) + d as i32))
}

/// Blais–Rioux 4th-order detector at brightest pixel `b` of `f`
/// (needs `f[b−3..=b+3]`): the zero crossing of
/// `g(i) = f(i−2) + f(i−1) − f(i+1) − f(i+2)` on the brighter neighbour's side.
pub fn blais_rioux(f: &[i32], b: usize) -> Option<Px> {
    if b < 3 || b + 3 >= f.len() {
        return None;
    }
    let g = |i: usize| (f[i - 2] + f[i - 1] - f[i + 1] - f[i + 2]) as i64;
    let right = || zero_crossing(b as i32, g(b), g(b + 1));
    let left = || zero_crossing(b as i32 - 1, g(b - 1), g(b));
    // Table 2 picks the side of the brighter neighbour; on a tie the sign of
    // g(b) does (g < 0 means the peak lies right of b). If noise puts the
    // crossing on the other side, that side is used: the detector stays
    // mirror-symmetric.
    let brighter_right = match f[b + 1].cmp(&f[b - 1]) {
        core::cmp::Ordering::Greater => true,
        core::cmp::Ordering::Less => false,
        core::cmp::Ordering::Equal => g(b) < 0,
    };
    if brighter_right { right().or_else(left) } else { left().or_else(right) }
}

/// Centre of gravity of `x` above `level` over the contiguous run around
/// `b` where `x > level`: Σ i (x − level) / Σ (x − level).
pub fn centroid_above(x: &[i32], b: usize, level: i32) -> Option<Px> {
    let mut lo = b;
    while lo > 0 && x[lo - 1] > level {
        lo -= 1;
    }
    let mut hi = b;
    while hi + 1 < x.len() && x[hi + 1] > level {
        hi += 1;
    }
    let (mut sw, mut siw) = (0i64, 0i64);
    for (i, &v) in x.iter().enumerate().take(hi + 1).skip(lo) {
        let w = (v - level).max(0) as i64;
        sw += w;
        siw += w * i as i64;
    }
    (sw > 0).then(|| Px(((siw << 16) / sw) as i32))
}

/// Minimum of `x` within `reach` of `b`.
pub fn local_background(x: &[i32], b: usize, reach: usize) -> i32 {
    let lo = b.saturating_sub(reach);
    let hi = (b + reach).min(x.len() - 1);
    x[lo..=hi].iter().copied().min().unwrap_or(0)
}

fn argmax_near(x: &[i32], c: usize, reach: usize) -> usize {
    let lo = c.saturating_sub(reach);
    let hi = (c + reach).min(x.len() - 1);
    // First maximum: ties resolve to the left, deterministically.
    let mut best = lo;
    for i in lo..=hi {
        if x[i] > x[best] {
            best = i;
        }
    }
    best
}

/// Width σ from the full width at half maximum above `bg` (FWHM / 2.3548).
fn fwhm_sigma(x: &[i32], b: usize, bg: i32) -> Px {
    let half = bg + (x[b] - bg) / 2;
    let n = x.len();
    let mut lo = b;
    while lo > 0 && x[lo - 1] > half {
        lo -= 1;
    }
    let mut hi = b;
    while hi + 1 < n && x[hi + 1] > half {
        hi += 1;
    }
    let l = if lo > 0 {
        let (p, q) = (x[lo - 1] as i64, x[lo] as i64);
        ((lo as i64 - 1) << 16) + ((half as i64 - p) << 16) / (q - p).max(1)
    } else {
        0
    };
    let r = if hi + 1 < n {
        let (p, q) = (x[hi] as i64, x[hi + 1] as i64);
        ((hi as i64) << 16) + ((p - half as i64) << 16) / (p - q).max(1)
    } else {
        (n as i64 - 1) << 16
    };
    Px((((r - l).max(0) * 27_830) >> 16) as i32)
}

/// A baseline estimator for one candidate. The brightest pixel within the
/// coarse pass's reach is `b`; every estimator works around it.
pub(crate) fn refine(v: &RowView<'_>, c: usize, method: Method) -> Option<Stripe> {
    let x = v.x;
    let n = x.len();
    let reach = v.plan.smax_px.max(2);
    let b = argmax_near(x, c, reach);
    let win = 3 * v.plan.smax_px + 2;
    let bg = local_background(x, b, win);
    let amp = x[b] - bg;
    if amp < v.cfg.min_amplitude as i32 || amp <= 0 {
        return None;
    }
    let mut flags = Flags::NONE;
    if v.clipped(b, 1) {
        flags.insert(Flags::CLIPPED);
    }
    let three = |b: usize| -> Option<(i32, i32, i32)> {
        (b > 0 && b + 1 < n).then(|| (x[b - 1] - bg, x[b] - bg, x[b + 1] - bg))
    };
    let at_b = |d: Option<Px>| d.map(|d| Px((b as i32) << 16) + d);
    let position = match method {
        Method::Max => Some(Px::from_int(b as i32)),
        Method::Cog => centroid_above(x, b, bg + amp / 2),
        Method::CogFiltered => {
            let g = v.g;
            let gb = argmax_near(g, c, reach);
            let gbg = local_background(g, gb, win);
            centroid_above(g, gb, gbg + (g[gb] - gbg) / 2)
        }
        Method::Gaussian => three(b).and_then(|(a, bb, cc)| at_b(gaussian3(a.max(1), bb.max(1), cc.max(1)))),
        Method::Parabolic => three(b).and_then(|(a, bb, cc)| at_b(parabolic(a, bb, cc))),
        Method::Linear => three(b).and_then(|(a, bb, cc)| at_b(linear(a, bb, cc))),
        Method::BlaisRioux => blais_rioux(x, b),
        Method::FirZero => {
            // First derivative of the low-pass filtered row (central
            // difference of the box-cascade FIR), zero crossing near its max.
            let g = v.g;
            let gb = argmax_near(g, c, reach);
            if gb < 2 || gb + 2 >= n {
                None
            } else {
                let dd = |i: usize| (g[i + 1] - g[i - 1]) as i64;
                if dd(gb) > 0 {
                    zero_crossing(gb as i32, dd(gb), dd(gb + 1))
                } else {
                    zero_crossing(gb as i32 - 1, dd(gb - 1), dd(gb))
                }
            }
        }
        Method::Cwt | Method::CwtPaper | Method::Centroid => None,
    };
    let position = position.unwrap_or_else(|| {
        flags.insert(Flags::LOW_CONFIDENCE);
        Px::from_int(b as i32)
    });
    Some(Stripe { position, strength: amp as u32, width: fwhm_sigma(x, b, bg), flags })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(p: Px) -> f64 {
        p.to_f64()
    }

    #[test]
    fn log2_is_accurate() {
        for v in [1u32, 2, 3, 10, 255, 1000, 4095, 65535, 1 << 20] {
            let want = (v as f64).log2();
            let got = log2_q16(v).to_f64();
            assert!((got - want).abs() < 3e-5, "{v}: {got} vs {want}");
        }
    }

    // Hand-computed cases: a = 50, b = 100, c = 80.
    #[test]
    fn table2_by_hand() {
        // centre of mass: (80 − 50) / 230 = 0.130435
        assert!((f(centre_of_mass3(50, 100, 80).unwrap()) - 0.130435).abs() < 1e-4);
        // parabolic: ½ (50 − 80) / (50 − 200 + 80) = −15 / −70 = 0.214286
        assert!((f(parabolic(50, 100, 80).unwrap()) - 0.214286).abs() < 1e-4);
        // Gaussian: ½ (ln 50 − ln 80) / (ln 50 − 2 ln 100 + ln 80)
        //   = ½ (−0.470004) / (3.912023 − 9.210340 + 4.382027) = 0.256484
        assert!((f(gaussian3(50, 100, 80).unwrap()) - 0.256484).abs() < 1e-4);
        // linear, c ≥ a: (80 − 50) / (2 (100 − 50)) = 0.3
        assert!((f(linear(50, 100, 80).unwrap()) - 0.3).abs() < 1e-4);
        // linear, c < a: (50 − 80) / (2 (100 − 50)) = −0.3
        assert!((f(linear(80, 100, 50).unwrap()) + 0.3).abs() < 1e-4);
        // zero crossing: 4 − 6 (1) / (−2 − 6) = 4.75
        assert!((f(zero_crossing(4, 6, -2).unwrap()) - 4.75).abs() < 1e-4);
    }

    #[test]
    fn table2_symmetric_and_half_pixel() {
        for est in [gaussian3, centre_of_mass3, parabolic, linear] {
            assert_eq!(est(70, 100, 70), Some(Px(0)));
        }
        // Equal top pixels: the peak is halfway.
        assert!((f(parabolic(100, 100, 20).unwrap()) + 0.5).abs() < 1e-4);
        assert!((f(linear(100, 100, 20).unwrap()) + 0.5).abs() < 1e-4);
        assert!((f(gaussian3(20, 100, 100).unwrap()) - 0.5).abs() < 1e-4);
    }

    #[test]
    fn blais_rioux_by_hand() {
        // f = 0 0 10 50 100 80 20 0 0, b = 4, f(5) > f(3):
        // g(4) = 10 + 50 − 80 − 20 = −40; g(5) = 50 + 100 − 20 − 0 = 130
        // crossing: 4 + 40 / 170 = 4.235294
        let fr = [0, 0, 10, 50, 100, 80, 20, 0, 0];
        assert!((f(blais_rioux(&fr, 4).unwrap()) - 4.235294).abs() < 1e-4);
        // Mirrored: 8 − 4.235294 = 3.764706
        let mut m = fr;
        m.reverse();
        assert!((f(blais_rioux(&m, 4).unwrap()) - 3.764706).abs() < 1e-4);
    }

    #[test]
    fn centroid_by_hand() {
        // level 10: weights 0 at i=1 (10), 20 at 2, 40 at 3, 10 at 4: (40 + 120 + 40) / 70 = 2.857143
        let x = [0, 10, 30, 50, 20, 5];
        assert!((f(centroid_above(&x, 3, 10).unwrap()) - 2.857143).abs() < 1e-4);
    }

    #[test]
    fn degenerate_inputs_are_none() {
        assert_eq!(parabolic(10, 10, 10), None);
        assert_eq!(gaussian3(0, 10, 5), None);
        assert_eq!(zero_crossing(3, 5, 5), None);
        assert_eq!(blais_rioux(&[1, 2, 3], 1), None);
    }
}
