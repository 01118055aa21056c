//! An `f64` reference of the default CWT estimator (`cms_core::peak::cwt`),
//! written from its description rather than from its code: the same scale
//! ladder `s_k = 2^(k/4)`, the same `s^(−3/2)`-normalised Ricker response
//! (exact kernel values, truncated at ±ceil(5 s)), the same hill-climb and
//! width parabola, the same fit scale (nearest rung to 1.5 σ̂), and the zero
//! of `Σ y_i D((i − t)/s)`, `D(u) = (3u − u³) e^(−u²/2)`, solved by bisection
//! to 10⁻¹² px instead of phase tables and a secant.
//!
//! It takes the candidate pixel from the caller (the brightest pixel of the
//! clean stripe's neighbourhood), so only the estimator is compared.

fn ricker(u: f64) -> f64 {
    (1.0 - u * u) * (-u * u / 2.0).exp()
}

fn deriv(u: f64) -> f64 {
    (3.0 * u - u * u * u) * (-u * u / 2.0).exp()
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
    let l = (5.0 * s).ceil() as isize;
    (-l..=l).map(|m| at(y, c as isize + m) * ricker(m as f64 / s)).sum::<f64>() * s.powf(-1.5)
}

/// ∂R/∂t (up to a positive factor) at continuous `t`, scale `s`.
pub fn slope(y: &[f64], t: f64, s: f64) -> f64 {
    let l = (5.0 * s).ceil();
    let lo = (t - l).ceil() as isize;
    let hi = (t + l).floor() as isize;
    (lo..=hi).map(|i| at(y, i) * deriv((i as f64 - t) / s)).sum()
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
