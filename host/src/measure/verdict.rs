//! Whether a fitted result is to be believed: **good**, **doubtful** or
//! **failed**, with every reason found. An instrument that gives a
//! confident wrong answer is worse than one that gives none, so every
//! corrugation result (`measure`'s per-laser and joint fits) carries one.
//!
//! The evidence, in the order it is checked:
//! * **The residual against the noise the points show.** The points' own
//!   noise is measured without any model: each point against the straight
//!   line through its two neighbours along the line ([`point_noise`]), which
//!   a smooth profile sampled finely passes within a small fraction of the
//!   noise. A model that fits leaves residuals of that size; one that does
//!   not (a wrong surface, a wrong minimum) leaves more. Up to
//!   [`MISFIT_DOUBTFUL`] × the noise is good, up to [`MISFIT_FAILED`] ×
//!   doubtful (its uncertainty does not cover the misfit), beyond failed.
//! * **Bounds with a physical meaning**: the lines within 45° of the rail
//!   (yaw), a wavelength the frame can show (at least [`MIN_PERIODS`]
//!   periods along it for good, [`MIN_PERIODS_AT_ALL`] at all; at least
//!   four point spacings) and that is judged ([`MIN_WAVELENGTH_MM`]: under
//!   it failed).
//! * **A wave told from the noise**: the amplitude over its σ at least
//!   [`detection_snr`] (4.2 over a 68.6 mm frame), the level noise alone
//!   reaches once in a thousand frames over the wavelengths searched;
//!   under it failed, since the wavelength fitted is then the noise's.
//! * **Starts that disagree**: another start's minimum as good within the
//!   noise at a wavelength more than 3 σ away (doubtful: the data do not
//!   decide).
//! * **Lines that disagree**: each line's own sine on its corrected
//!   profile against the others', as a Birge ratio; over [`MAX_BIRGE`],
//!   where the uncertainty it grows to exceeds 0.05 % of the wavelength or
//!   1 % of the amplitude, doubtful (that uncertainty is then itself an
//!   estimate from three values, and large).
//! * **An imprecise result**: a 95 % interval wider than 0.1 % of the
//!   wavelength or 5 % of the amplitude (doubtful: right within its
//!   uncertainty, perhaps, but not to the instrument's class).
//! * **The fit's own state**: the refinement's convergence test (a result
//!   that did not converge but fits to the noise is doubtful, not failed),
//!   the share of points left out as outliers (over 5 % is doubtful).
//!
//! The thresholds were set on the misalignment sweep of
//! `corrugation::tests` (yaw to 10°, pitch and roll ±2°, crowns of 200 mm
//! to flat): every result there off by more than the accuracy limits
//! (0.05 mm, 2 µm) showed 1.9× or more of misfit.

use std::fmt;

use serde::Serialize;

/// Residual RMS over the points' noise above which a result is doubtful.
pub const MISFIT_DOUBTFUL: f64 = 1.5;
/// Residual RMS over the points' noise above which a result has failed.
pub const MISFIT_FAILED: f64 = 4.0;
/// Fewest periods in the frame for a good wavelength.
pub const MIN_PERIODS: f64 = 1.5;
/// Largest Birge ratio of the lines' own results for a good joint one: 3
/// is χ² = 18 over 2 degrees of freedom for three lines, p ≈ 1e-4 if they
/// differed only by their noise.
pub const MAX_BIRGE: f64 = 3.0;
/// The share of the wavelength, and of the amplitude, that the joint
/// uncertainty grown by the lines' disagreement must exceed for that
/// disagreement to make a result doubtful: below, the lines differ by what
/// their grown uncertainty carries, small against the value, and the
/// result stands.
pub const BIRGE_WAVELENGTH_SHARE: f64 = 5e-4;
/// See [`BIRGE_WAVELENGTH_SHARE`].
pub const BIRGE_AMPLITUDE_SHARE: f64 = 0.01;
/// The widest 95 % interval (half-width) of a good wavelength, as a share
/// of it: 0.05 mm at 50 mm, the accuracy this instrument claims there
/// (the wavelength's scatter grows as λ² at a given frame length).
pub const PRECISION_WAVELENGTH_SHARE: f64 = 1e-3;
/// The widest 95 % interval (half-width) of a good amplitude, as a share
/// of it.
pub const PRECISION_AMPLITUDE_SHARE: f64 = 0.05;
/// Largest yaw of the lines against the rail, rad (45°).
pub const MAX_YAW_RAD: f64 = std::f64::consts::FRAC_PI_4;
/// Fewest periods in the frame for a result at all: under one period the
/// wave never returns to itself in the data, and a sine is told from the
/// surface's own trend (the plane, the curvature along) only by its shape
/// over part of a period, which the trend terms take up.
pub const MIN_PERIODS_AT_ALL: f64 = 1.0;
/// The shortest wavelength trusted, mm. EN 13231-3's shortest band starts
/// at 10 mm, and nothing shorter is judged; under real light shorter
/// structure is what the light itself makes (a speckle and the travel in
/// the exposure span 0.2–0.7 mm along the rail, and their sum over a
/// frame peaks at 1–3 mm at a height that a small corrugation does not
/// reach). 10 % below the band's edge, so that a 10 mm wave read a few
/// per cent short stays a result: no result kept here is that far off.
pub const MIN_WAVELENGTH_MM: f64 = 9.0;
/// The chance that noise alone, over all the wavelengths searched, makes
/// an amplitude pass [`detection_snr`].
pub const FALSE_ALARM: f64 = 1e-3;

/// The amplitude over its σ below which a wave is not told from the noise
/// over a frame of `span_mm`: the starts search the wavelengths from
/// [`MIN_WAVELENGTH_MM`] to twice the frame, `M = span (1/λ_min −
/// 1/(2 span))` independent Fourier frequencies (at least one), and noise
/// alone gives at one frequency an `A/σ_A` distributed as Rayleigh's, over
/// `M` of them exceeding `x` with probability `M e^{−x²/2}`; so `x =
/// √(2 ln(M / FALSE_ALARM))`: 4.2 over a 68.6 mm frame, 4.5 over 280 mm.
/// Under it the fitted wavelength is the noise's, whatever the amplitude.
pub fn detection_snr(span_mm: f64) -> f64 {
    let m = (span_mm / MIN_WAVELENGTH_MM - 0.5).max(1.0);
    (2.0 * (m / FALSE_ALARM).ln()).sqrt()
}

/// How far a result is to be believed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    Good,
    Doubtful,
    Failed,
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Level::Good => "good",
            Level::Doubtful => "doubtful",
            Level::Failed => "failed",
        })
    }
}

/// One reason a result is not good.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
#[non_exhaustive]
pub enum Reason {
    /// The residual is `ratio` × the noise the points show.
    Misfit { rms_um: f64, noise_um: f64, ratio: f64 },
    /// The lines are yawed beyond [`MAX_YAW_RAD`] (a wrong minimum).
    YawOutOfBounds { yaw_deg: f64 },
    /// Too few periods of the wavelength in the frame.
    FewPeriods { periods: f64 },
    /// The wavelength is under four point spacings.
    BelowSampling { wavelength_mm: f64, spacing_mm: f64 },
    /// The refinement did not meet its convergence test.
    NotConverged,
    /// A share of the points was left out as outliers.
    Outliers { rejected: usize, points: usize },
    /// The points' noise could not be measured (too few points).
    NoNoiseEstimate,
    /// Another start ends as well within the noise at another wavelength.
    StartsDisagree { wavelength_mm: f64, other_mm: f64 },
    /// The lines' own results differ by `ratio` (Birge) × their
    /// uncertainties.
    LinesDisagree { quantity: &'static str, ratio: f64 },
    /// The wavelength is under [`MIN_WAVELENGTH_MM`], where the light's
    /// own structure lies and nothing is judged.
    BelowRange { wavelength_mm: f64 },
    /// The amplitude is `snr` × its σ, under the `needed` of
    /// [`detection_snr`]: the wave is not told from the noise.
    NotDetected { snr: f64, needed: f64 },
    /// The 95 % interval (half-width `half_mm`) is wider than
    /// [`PRECISION_WAVELENGTH_SHARE`] / [`PRECISION_AMPLITUDE_SHARE`] of
    /// the value.
    Imprecise { quantity: &'static str, half_mm: f64, value_mm: f64 },
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reason::Misfit { rms_um, noise_um, ratio } => write!(
                f,
                "residual {rms_um:.2} µm RMS is {ratio:.1}× the {noise_um:.2} µm noise of the points (the model does not fit)"
            ),
            Reason::YawOutOfBounds { yaw_deg } => write!(f, "yaw {yaw_deg:.1}° is beyond ±45° (a wrong minimum)"),
            Reason::FewPeriods { periods } => write!(f, "only {periods:.2} periods in the frame"),
            Reason::BelowSampling { wavelength_mm, spacing_mm } => {
                write!(f, "wavelength {wavelength_mm:.3} mm is under four point spacings ({spacing_mm:.3} mm)")
            }
            Reason::NotConverged => f.write_str("the refinement did not converge"),
            Reason::Outliers { rejected, points } => {
                write!(f, "{rejected} of {points} points left out as outliers")
            }
            Reason::NoNoiseEstimate => f.write_str("too few points to measure their noise"),
            Reason::StartsDisagree { wavelength_mm, other_mm } => write!(
                f,
                "another start fits as well at {other_mm:.3} mm (against {wavelength_mm:.3} mm): the data do not decide"
            ),
            Reason::LinesDisagree { quantity, ratio } => {
                write!(f, "the lines disagree on the {quantity} by {ratio:.1}× their uncertainties")
            }
            Reason::BelowRange { wavelength_mm } => write!(
                f,
                "wavelength {wavelength_mm:.3} mm is under the {MIN_WAVELENGTH_MM} mm trusted (the light's own structure, not corrugation)"
            ),
            Reason::NotDetected { snr, needed } => write!(
                f,
                "the amplitude is {snr:.1}× its σ, under the {needed:.1}× that noise alone does not reach: the wave is not told from the noise"
            ),
            Reason::Imprecise { quantity, half_mm, value_mm } => write!(
                f,
                "the {quantity}'s 95 % interval ±{} is {:.2} % of it",
                if *quantity == "wavelength" {
                    format!("{half_mm:.3} mm")
                } else {
                    format!("{:.2} µm", half_mm * 1e3)
                },
                100.0 * half_mm / value_mm.abs()
            ),
        }
    }
}

/// A result's verdict: its level (the worst of its reasons) and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    pub level: Level,
    pub reasons: Vec<Reason>,
    /// The noise of the points, µm RMS (model-free: [`point_noise`]).
    pub noise_um: Option<f64>,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.level)?;
        for (i, r) in self.reasons.iter().enumerate() {
            write!(f, "{}{r}", if i == 0 { ": " } else { "; " })?;
        }
        Ok(())
    }
}

/// What a verdict is formed from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence {
    pub rms_residual_mm: f64,
    /// The points' noise, mm ([`point_noise`]).
    pub noise_mm: Option<f64>,
    pub wavelength_mm: f64,
    /// Extent of the frame along the rail, mm.
    pub span_mm: f64,
    /// Mean spacing of the points along the rail, mm.
    pub spacing_mm: f64,
    pub yaw_rad: f64,
    pub converged: bool,
    pub rejected: usize,
    pub points: usize,
    /// Another start's minimum as good within the noise, mm.
    pub alternative_wavelength_mm: Option<f64>,
    /// The lines' Birge ratios (wavelength, amplitude) about their mean,
    /// for a joint result of several lines; 0 where the disagreement does
    /// not matter (the grown uncertainty under [`BIRGE_WAVELENGTH_SHARE`] /
    /// [`BIRGE_AMPLITUDE_SHARE`] of the value).
    pub birge: Option<(f64, f64)>,
    /// The result's one-σ uncertainties: wavelength (mm), amplitude (mm).
    pub sigma_mm: (Option<f64>, Option<f64>),
    /// The amplitude, mm.
    pub amplitude_mm: f64,
}

/// The verdict on `e` (module docs).
pub fn judge(e: &Evidence) -> Verdict {
    let mut reasons: Vec<(Level, Reason)> = Vec::new();
    match e.noise_mm.filter(|n| *n > 0.0 && n.is_finite()) {
        Some(noise) => {
            let ratio = e.rms_residual_mm / noise;
            let level = if ratio > MISFIT_FAILED {
                Some(Level::Failed)
            } else if ratio > MISFIT_DOUBTFUL {
                Some(Level::Doubtful)
            } else {
                None
            };
            if let Some(l) = level {
                reasons.push((l, Reason::Misfit { rms_um: e.rms_residual_mm * 1e3, noise_um: noise * 1e3, ratio }));
            }
        }
        None => reasons.push((Level::Doubtful, Reason::NoNoiseEstimate)),
    }
    if e.yaw_rad.abs() > MAX_YAW_RAD {
        reasons.push((Level::Failed, Reason::YawOutOfBounds { yaw_deg: e.yaw_rad.to_degrees() }));
    }
    let periods = e.span_mm / e.wavelength_mm;
    if periods.is_nan() || periods < MIN_PERIODS_AT_ALL {
        reasons.push((Level::Failed, Reason::FewPeriods { periods }));
    } else if periods < MIN_PERIODS {
        reasons.push((Level::Doubtful, Reason::FewPeriods { periods }));
    }
    if e.wavelength_mm < 4.0 * e.spacing_mm {
        reasons
            .push((Level::Failed, Reason::BelowSampling { wavelength_mm: e.wavelength_mm, spacing_mm: e.spacing_mm }));
    }
    if e.wavelength_mm < MIN_WAVELENGTH_MM {
        reasons.push((Level::Failed, Reason::BelowRange { wavelength_mm: e.wavelength_mm }));
    }
    if let Some(sa) = e.sigma_mm.1.filter(|s| *s > 0.0) {
        let (snr, needed) = (e.amplitude_mm.abs() / sa, detection_snr(e.span_mm));
        if snr < needed {
            reasons.push((Level::Failed, Reason::NotDetected { snr, needed }));
        }
    }
    if let Some(other_mm) = e.alternative_wavelength_mm {
        reasons.push((Level::Doubtful, Reason::StartsDisagree { wavelength_mm: e.wavelength_mm, other_mm }));
    }
    if let Some((bl, ba)) = e.birge {
        for (quantity, ratio) in [("wavelength", bl), ("amplitude", ba)] {
            if ratio > MAX_BIRGE {
                reasons.push((Level::Doubtful, Reason::LinesDisagree { quantity, ratio }));
            }
        }
    }
    for (quantity, sigma, value, share) in [
        ("wavelength", e.sigma_mm.0, e.wavelength_mm, PRECISION_WAVELENGTH_SHARE),
        ("amplitude", e.sigma_mm.1, e.amplitude_mm, PRECISION_AMPLITUDE_SHARE),
    ] {
        if let Some(half_mm) = sigma.map(|s| 1.96 * s).filter(|h| *h > share * value.abs()) {
            reasons.push((Level::Doubtful, Reason::Imprecise { quantity, half_mm, value_mm: value }));
        }
    }
    if !e.converged {
        reasons.push((Level::Doubtful, Reason::NotConverged));
    }
    if e.points > 0 && e.rejected * 20 > e.points {
        reasons.push((Level::Doubtful, Reason::Outliers { rejected: e.rejected, points: e.points }));
    }
    let level = reasons.iter().map(|r| r.0).max().unwrap_or(Level::Good);
    Verdict { level, reasons: reasons.into_iter().map(|r| r.1).collect(), noise_um: e.noise_mm.map(|n| n * 1e3) }
}

/// The noise of a line's heights without a model: every point against the
/// straight line through its two neighbours (by position), `r = z_i −
/// ((1 − w) z_{i−1} + w z_{i+1})`, `w` its fraction of the way; for white
/// noise of σ, `r` has variance `σ² (1 + (1 − w)² + w²)`, so each `r` is
/// scaled by that, and σ is 1.4826 × the median `|r|` (robust to outliers
/// and to a few steps). A smooth profile sampled at spacing `h` adds at
/// most `A (ω h)² / 8` per point: 0.05 µm for 100 µm at 30 mm and 0.14 mm
/// spacing. `points` is `(position, height)`, in any order; `None` under
/// 8 points.
pub fn point_noise(points: &[(f64, f64)]) -> Option<f64> {
    if points.len() < 8 {
        return None;
    }
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut r: Vec<f64> = p
        .windows(3)
        .filter_map(|w| {
            let span = w[2].0 - w[0].0;
            if span.is_nan() || span <= 0.0 {
                return None;
            }
            let t = (w[1].0 - w[0].0) / span;
            let d = w[1].1 - ((1.0 - t) * w[0].1 + t * w[2].1);
            Some((d / (1.0 + (1.0 - t).powi(2) + t * t).sqrt()).abs())
        })
        .filter(|v| v.is_finite())
        .collect();
    if r.len() < 6 {
        return None;
    }
    let mid = r.len() / 2;
    let (_, m, _) = r.select_nth_unstable_by(mid, f64::total_cmp);
    Some(1.4826 * *m)
}

/// The longest lag, points, over which [`residual_noise`] follows the
/// residuals' correlation: 16 points are 2.3 mm at the reference head's
/// 0.144 mm, beyond a speckle and the travel in a 100 µs exposure at
/// 5 m/s together (under 1 mm), short against the shortest wavelength
/// trusted.
pub const MAX_NOISE_LAG: usize = 16;

/// The noise of a fit's residuals where the points' errors are correlated
/// along a line (laser speckle, stretched by the travel in the exposure):
/// [`point_noise`]'s neighbours then share most of a point's error, and it
/// measures only the part that changes from row to row (at 5 m/s a
/// quarter of the error). Here each residual is set against the mean of
/// the residuals `m` points either side, `m` the first lag at which the
/// residuals' correlation (pooled over the lines) falls under 0.1, at most
/// [`MAX_NOISE_LAG`]; the difference has variance `σ² (3/2 − 2ρ(m) +
/// ρ(2m)/2)`, about `3σ²/2`, and σ is 1.4826 × its median over √(3/2). A
/// model that does not fit leaves a residual smooth over a wavelength,
/// which a difference over `2m` points takes out: the misfit still shows
/// against this noise. `residuals` per line, in the order of the points
/// along it; `None` under 8 differences. Returns σ and `m`.
pub fn residual_noise(residuals: &[Vec<f64>]) -> Option<(f64, usize)> {
    let rho = |k: usize| {
        let (mut num, mut den) = (0.0, 0.0);
        for r in residuals {
            den += r.iter().map(|v| v * v).sum::<f64>();
            num += r.iter().zip(r.iter().skip(k)).map(|(a, b)| a * b).sum::<f64>();
        }
        num / den
    };
    let m = (1..=MAX_NOISE_LAG).find(|&k| rho(k) < 0.1).unwrap_or(MAX_NOISE_LAG);
    let mut d: Vec<f64> = residuals
        .iter()
        .flat_map(|r| (m..r.len().saturating_sub(m)).map(move |i| (r[i] - 0.5 * (r[i - m] + r[i + m])).abs()))
        .filter(|v| v.is_finite())
        .collect();
    if d.len() < 8 {
        return None;
    }
    let mid = d.len() / 2;
    let (_, med, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    Some((1.4826 * *med / 1.5f64.sqrt(), m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_noise_measures_white_noise_under_a_sine() {
        let mut s = 0x1234_5678_9abc_def1u64;
        let mut normal = || {
            let mut u = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            let (a, b) = (u().max(1e-300), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        // 100 µm at 30 mm, 0.14 mm spacing (jittered), 2 µm of noise.
        let pts: Vec<(f64, f64)> = (0..2000)
            .map(|i| {
                let x = 0.14 * i as f64 + 0.03 * normal();
                (x, 0.1 * (std::f64::consts::TAU * x / 30.0).sin() + 0.002 * normal())
            })
            .collect();
        let n = point_noise(&pts).unwrap();
        assert!((n / 0.002 - 1.0).abs() < 0.08, "{n}");
        assert_eq!(point_noise(&pts[..7]), None);
    }

    /// The detection threshold is what its docs say, and noise alone
    /// passes it as rarely as [`FALSE_ALARM`] says: the largest `A/σ_A`
    /// of independent Gaussian (a, b) pairs over `M` frequencies, in many
    /// frames.
    #[test]
    fn noise_alone_is_rarely_detected() {
        assert!((detection_snr(68.6) - 4.2).abs() < 0.05, "{}", detection_snr(68.6));
        assert!((detection_snr(280.0) - 4.55).abs() < 0.05, "{}", detection_snr(280.0));
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut normal = || {
            let mut u = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            let (a, b) = (u().max(1e-300), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        let (frames, m) = (20_000, 7);
        let needed = detection_snr(68.6);
        let passed =
            (0..frames).filter(|_| (0..m).map(|_| normal().hypot(normal())).fold(0.0, f64::max) >= needed).count();
        // 1e-3 of 20 000 is 20; Poisson's 5σ above is 42.
        assert!(passed <= 42, "{passed} of {frames}");
        assert!(passed >= 5, "{passed} of {frames}: the threshold is needlessly high");
    }

    #[test]
    fn what_cannot_be_right_has_failed() {
        let e = Evidence {
            rms_residual_mm: 0.1,
            noise_mm: Some(0.1),
            wavelength_mm: 12.0,
            span_mm: 68.6,
            spacing_mm: 0.144,
            yaw_rad: 0.0,
            converged: true,
            rejected: 0,
            points: 1440,
            alternative_wavelength_mm: None,
            birge: None,
            sigma_mm: (Some(0.3), Some(0.005)),
            amplitude_mm: 0.03,
        };
        assert_eq!(judge(&e).level, Level::Doubtful, "{}", judge(&e));
        // Noise's own scale along the rail.
        let v = judge(&Evidence { wavelength_mm: 1.07, ..e });
        assert_eq!(v.level, Level::Failed);
        assert!(v.reasons.iter().any(|r| matches!(r, Reason::BelowRange { .. })), "{v}");
        // 20 µm at σ 5 µm: 4σ, which noise reaches once in 300 frames.
        let v = judge(&Evidence { amplitude_mm: 0.02, ..e });
        assert_eq!(v.level, Level::Failed);
        assert!(v.to_string().contains("the amplitude is 4.0× its σ, under the 4.2×"), "{v}");
        // Under one period.
        let v = judge(&Evidence { wavelength_mm: 70.0, ..e });
        assert!(v.reasons.iter().any(|r| matches!(r, Reason::FewPeriods { .. })) && v.level == Level::Failed, "{v}");
    }

    /// White noise: lag 1 and its σ. Noise averaged over 6 points (as the
    /// travel in the exposure averages speckle): `point_noise` sees a
    /// fraction, `residual_noise` the whole, at a lag beyond the averaging.
    #[test]
    fn residual_noise_follows_the_correlation() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut normal = || {
            let mut u = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            let (a, b) = (u().max(1e-300), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        let white: Vec<Vec<f64>> = (0..3).map(|_| (0..2000).map(|_| normal()).collect()).collect();
        let (n, m) = residual_noise(&white).unwrap();
        assert_eq!(m, 1);
        assert!((n - 1.0).abs() < 0.06, "{n}");
        let smooth: Vec<Vec<f64>> =
            white.iter().map(|w| w.windows(6).map(|v| v.iter().sum::<f64>() / 6f64.sqrt()).collect()).collect();
        let (n, m) = residual_noise(&smooth).unwrap();
        assert!((6..=7).contains(&m), "{m}");
        assert!((n - 1.0).abs() < 0.08, "{n}");
        let pts: Vec<(f64, f64)> = smooth[0].iter().enumerate().map(|(i, &z)| (i as f64, z)).collect();
        assert!(point_noise(&pts).unwrap() < 0.5);
    }

    #[test]
    fn levels_follow_the_evidence() {
        let e = Evidence {
            rms_residual_mm: 0.0011,
            noise_mm: Some(0.001),
            wavelength_mm: 50.0,
            span_mm: 280.0,
            spacing_mm: 0.1,
            yaw_rad: 0.05,
            converged: true,
            rejected: 0,
            points: 4500,
            alternative_wavelength_mm: None,
            birge: Some((1.2, 0.4)),
            sigma_mm: (Some(0.01), Some(0.0005)),
            amplitude_mm: 0.05,
        };
        assert_eq!(judge(&e).level, Level::Good);
        assert_eq!(judge(&Evidence { rms_residual_mm: 0.002, ..e }).level, Level::Doubtful);
        let v = judge(&Evidence { rms_residual_mm: 0.043, yaw_rad: 1.6, ..e });
        assert_eq!(v.level, Level::Failed);
        assert_eq!(v.reasons.len(), 2, "{v}");
        assert!(v.to_string().starts_with("failed: residual 43.00 µm RMS is 43.0× the 1.00 µm noise"), "{v}");
        assert_eq!(judge(&Evidence { converged: false, ..e }).level, Level::Doubtful);
        assert_eq!(judge(&Evidence { wavelength_mm: 250.0, ..e }).level, Level::Doubtful);
        assert_eq!(judge(&Evidence { wavelength_mm: 300.0, ..e }).level, Level::Failed);
        assert_eq!(judge(&Evidence { wavelength_mm: 600.0, ..e }).level, Level::Failed);
        assert_eq!(judge(&Evidence { wavelength_mm: 0.3, ..e }).level, Level::Failed);
        assert_eq!(judge(&Evidence { noise_mm: None, ..e }).level, Level::Doubtful);
        assert_eq!(judge(&Evidence { alternative_wavelength_mm: Some(47.0), ..e }).level, Level::Doubtful);
        let v = judge(&Evidence { birge: Some((1.0, 3.5)), ..e });
        assert_eq!(v.level, Level::Doubtful);
        assert_eq!(v.to_string(), "doubtful: the lines disagree on the amplitude by 3.5× their uncertainties");
        let v = judge(&Evidence { sigma_mm: (Some(0.04), Some(0.002)), ..e });
        assert_eq!(
            v.to_string(),
            "doubtful: the wavelength's 95 % interval ±0.078 mm is 0.16 % of it; the amplitude's 95 % interval \
             ±3.92 µm is 7.84 % of it"
        );
    }
}
