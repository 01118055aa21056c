//! An `f64` reference of the default CWT estimator (`cms_core::peak::cwt`),
//! written from its description rather than from its code: the same scale
//! ladder `s_k = 2^(k/4)`, the same `s^(−3/2)`-normalised Ricker response
//! (exact kernel values, truncated at ±ceil(4 s), made zero-sum by its
//! centre value), the same hill-climb and width parabola, the same fit
//! scale (nearest rung to 1.5 σ̂), and the zero of `Σ y_i D((i − t)/s)`,
//! `D(u) = w(u)·((3u − u³) − λu)·e^(−u²/2)` (`w` 1 to 3.25 and a raised
//! cosine to 0 at 4; `λ` such that `∫ u·D(u) du = 0`), solved by bisection
//! to 10⁻¹² px instead of phase tables and a secant.
//!
//! It takes the candidate pixel from the caller (the brightest pixel of the
//! clean stripe's neighbourhood), so only the estimator is compared.

fn ricker(u: f64) -> f64 {
    (1.0 - u * u) * (-u * u / 2.0).exp()
}

/// The taper of the sub-pixel kernel: 1 to 3.25, a raised cosine to 0 at 4.
fn taper(u: f64) -> f64 {
    let a = u.abs();
    if a <= 3.25 {
        1.0
    } else if a >= 4.0 {
        0.0
    } else {
        (std::f64::consts::FRAC_PI_2 * (a - 3.25) / 0.75).cos().powi(2)
    }
}

/// `λ`: the odd Gaussian's weight that makes `∫ u·D(u) du` zero (midpoint
/// rule on 10⁵ intervals of [0, 4]).
fn slope_fix() -> f64 {
    let n = 100_000;
    let h = 4.0 / n as f64;
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n {
        let u = (i as f64 + 0.5) * h;
        let g = (-u * u / 2.0).exp() * taper(u);
        num += u * (3.0 * u - u * u * u) * g;
        den += u * u * g;
    }
    num / den
}

fn deriv(u: f64, lambda: f64) -> f64 {
    taper(u) * ((3.0 * u - u * u * u) - lambda * u) * (-u * u / 2.0).exp()
}

/// Scale of ladder rung `k`.
pub fn rung(k: usize) -> f64 {
    2f64.powf(k as f64 / 4.0)
}

fn at(y: &[f64], i: isize) -> f64 {
    y[i.clamp(0, y.len() as isize - 1) as usize]
}

/// Normalised Ricker response at integer `c`, scale `s`.
pub fn response(y: &[f64], c: usize, s: f64) -> f64 {
    let l = (4.0 * s).ceil() as isize;
    let mean = (-l..=l).map(|m| ricker(m as f64 / s)).sum::<f64>();
    let psi = |m: isize| ricker(m as f64 / s) - if m == 0 { mean } else { 0.0 };
    (-l..=l).map(|m| at(y, c as isize + m) * psi(m)).sum::<f64>() * s.powf(-1.5)
}

/// ∂R/∂t (up to a positive factor) at continuous `t`, scale `s`.
pub fn slope(y: &[f64], t: f64, s: f64) -> f64 {
    let l = (4.0 * s).ceil();
    let lo = (t - l).ceil() as isize;
    let hi = (t + l).floor() as isize;
    static LAMBDA: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    let lambda = *LAMBDA.get_or_init(slope_fix);
    (lo..=hi).map(|i| at(y, i) * deriv((i as f64 - t) / s, lambda)).sum()
}

/// The estimator: `(position, width)` for the stripe near `c0`, scales in rungs `k_lo..=k_hi`.
pub fn cwt(y: &[f64], c0: usize, k_lo: usize, k_hi: usize) -> Option<(f64, f64)> {
    let best = |c: usize| -> (usize, Vec<f64>) {
        let r: Vec<f64> = (0..=k_hi).map(|k| if k < k_lo { f64::MIN } else { response(y, c, rung(k)) }).collect();
        let kb = (k_lo..=k_hi).fold(k_lo, |b, k| if r[k] > r[b] { k } else { b });
        (kb, r)
    };
    let (mut kb, mut r) = best(c0);
    let mut c = c0;
    let mut moved = false;
    for _ in 0..3 {
        let s = rung(kb);
        let here = response(y, c, s);
        let left = if c > 0 { response(y, c - 1, s) } else { f64::MIN };
        let right = if c + 1 < y.len() { response(y, c + 1, s) } else { f64::MIN };
        if right > here && right >= left {
            c += 1;
        } else if left > here {
            c -= 1;
        } else {
            break;
        }
        moved = true;
    }
    if moved {
        (kb, r) = best(c);
    }
    let dk = if kb > k_lo && kb < k_hi {
        let den = r[kb - 1] - 2.0 * r[kb] + r[kb + 1];
        if den < 0.0 { (0.5 * (r[kb - 1] - r[kb + 1]) / den).clamp(-0.5, 0.5) } else { 0.0 }
    } else {
        0.0
    };
    let width = rung(kb) * 2f64.powf(dk / 4.0);
    let j = (kb as f64 + dk + 4.0 * 1.5f64.log2()).round().clamp(0.0, 22.0) as usize;
    let s = rung(j);
    // Bracket the zero near c, then bisect.
    let (mut lo, mut hi) = (c as f64 - 3.0, c as f64 + 3.0);
    let mut t = c as f64;
    let f0 = slope(y, t, s);
    if f0 > 0.0 {
        while slope(y, t + 1.0, s) > 0.0 {
            t += 1.0;
            if t >= hi {
                return None;
            }
        }
        lo = t;
        hi = t + 1.0;
    } else {
        while slope(y, t - 1.0, s) <= 0.0 {
            t -= 1.0;
            if t <= lo {
                return None;
            }
        }
        lo = t - 1.0;
        hi = t;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if slope(y, mid, s) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some((0.5 * (lo + hi), width))
}
