//! A Gaussian stripe on a row, point-sampled or integrated over each
//! pixel (through a tabulated erf).

/// Adds a Gaussian stripe (peak `peak_e` electrons, centre `c`, σ px) to a
/// row, point-sampled or integrated over each pixel's width.
pub(super) fn add_stripe(buf: &mut [f64], c: f64, sigma: f64, peak_e: f64, integrate: bool) {
    if !(peak_e > 0.0 && sigma > 0.0) {
        return;
    }
    let n = buf.len() as isize;
    // Beyond 5σ a stripe is below 4e-6 of its peak: under a code even at
    // 16 bits.
    let reach = 5.0 * sigma + 1.0;
    let lo = ((c - reach).floor() as isize).max(0);
    let hi = ((c + reach).ceil() as isize).min(n - 1);
    if lo > hi {
        return;
    }
    if integrate {
        let k = peak_e * sigma * (std::f64::consts::PI / 2.0).sqrt();
        let inv = 1.0 / (sigma * std::f64::consts::SQRT_2);
        let mut prev = erf((lo as f64 - 0.5 - c) * inv);
        for i in lo..=hi {
            let next = erf((i as f64 + 0.5 - c) * inv);
            buf[i as usize] += k * (next - prev);
            prev = next;
        }
    } else {
        let inv = -0.5 / (sigma * sigma);
        for i in lo..=hi {
            let d = i as f64 - c;
            buf[i as usize] += peak_e * (inv * d * d).exp();
        }
    }
}

/// The error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7; odd,
/// so a rendered stripe stays exactly symmetric about its centre). Used to
/// check [`erf`] against.
#[cfg(test)]
pub(crate) fn erf_as(x: f64) -> f64 {
    let a = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * a);
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-a * a).exp();
    if x < 0.0 { -y } else { y }
}

/// Table of erf on [0, 6] every 1/256 with its derivative, for cubic Hermite
/// interpolation.
pub(super) const ERF_STEPS: f64 = 256.0;
pub(super) const ERF_LEN: usize = 6 * 256 + 2;

pub(super) fn erf_table() -> &'static [(f64, f64)] {
    static T: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        let d = 2.0 / std::f64::consts::PI.sqrt();
        (0..ERF_LEN)
            .map(|i| {
                let x = i as f64 / ERF_STEPS;
                (erf_series(x), d * (-x * x).exp() / ERF_STEPS)
            })
            .collect()
    })
}

/// erf by its Taylor series (|x| ≤ 3) or continued fraction of erfc (beyond),
/// to about 1e-15: only for building the table.
pub(super) fn erf_series(x: f64) -> f64 {
    let a = x.abs();
    let y = if a <= 3.0 {
        // erf x = 2/√π · Σ (−1)^n x^(2n+1) / (n! (2n+1))
        let (mut term, mut sum, x2) = (a, a, a * a);
        let mut n = 0.0;
        while term.abs() > 1e-17 * sum.abs() {
            n += 1.0;
            term *= -x2 / n;
            sum += term / (2.0 * n + 1.0);
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    } else {
        // erfc x = e^(−x²)/√π · 1/(x + (1/2)/(x + 1/(x + (3/2)/(x + …))))
        let mut f = a;
        for k in (1..60).rev() {
            f = a + (k as f64 / 2.0) / f;
        }
        1.0 - (-a * a).exp() / (std::f64::consts::PI.sqrt() * f)
    };
    if x < 0.0 { -y } else { y }
}

/// The error function: table + cubic Hermite (error < 1e-11; exactly odd, so a
/// rendered stripe stays symmetric about its centre).
#[inline]
pub(crate) fn erf(x: f64) -> f64 {
    let a = x.abs();
    let t = a * ERF_STEPS;
    if x.is_nan() {
        return x;
    }
    if t >= (ERF_LEN - 2) as f64 {
        return x.signum();
    }
    let tab = erf_table();
    let i = t as usize;
    let f = t - i as f64;
    let ((y0, d0), (y1, d1)) = (tab[i], tab[i + 1]);
    // Hermite basis on [0, 1] (derivatives already per table step).
    let f2 = f * f;
    let f3 = f2 * f;
    let y = (2.0 * f3 - 3.0 * f2 + 1.0) * y0 + (f3 - 2.0 * f2 + f) * d0 + (-2.0 * f3 + 3.0 * f2) * y1 + (f3 - f2) * d1;
    if x < 0.0 { -y } else { y }
}

#[cfg(test)]
mod erf_tests {
    use super::*;

    #[test]
    fn erf_table_is_accurate() {
        // Reference values (Abramowitz & Stegun Table 7.1).
        for (x, want) in
            [(0.5, 0.520_499_877_813_046_5), (1.0, 0.842_700_792_949_714_9), (2.0, 0.995_322_265_018_952_7)]
        {
            assert!((erf_series(x) - want).abs() < 1e-15, "{x}");
            assert!((erf(x) - want).abs() < 1e-12, "{x}");
            assert!((erf(-x) + want).abs() < 1e-12, "{x}");
        }
        assert!((erf_series(3.5) - 0.999_999_256_901_627_7).abs() < 1e-15);
        let mut worst: f64 = 0.0;
        for i in 0..20_000 {
            let x = -7.0 + i as f64 * 7e-4 + 1.3e-5;
            worst = worst.max((erf(x) - erf_series(x)).abs());
            assert!((erf(x) - erf_as(x)).abs() < 2e-7);
        }
        assert!(worst < 1e-11, "{worst}");
        assert_eq!(erf(0.0), 0.0);
        assert_eq!(erf(9.0), 1.0);
        assert_eq!(erf(-9.0), -1.0);
    }
}
