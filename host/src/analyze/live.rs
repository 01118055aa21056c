//! The live corrugation estimate of `cms-host listen`: per laser, a sine
//! fitted to the last half metre of track stitched from the most recent
//! calibrated frames.
//!
//! Frames are gathered as they arrive ([`LiveEstimate::push`], O(points));
//! the estimate is made only when the status line is drawn
//! ([`LiveEstimate::estimate`], once a second, or four times with a
//! terminal): the window's frames are stitched ([`super::stitch`], 1 mm
//! samples, direction from the data, offset registration) and each laser's
//! profile gets the paper's rotated-sine fit ([`crate::measure::fit`]). The window is
//! the frames within [`WINDOW_MM`] of odometer of the newest (at most
//! [`MAX_FRAMES`]), so at walking pace or at 2 m/s it is about half a metre
//! of rail: ten wavelengths of 50 mm corrugation.
//!
//! **Cheap by design.** The status line is drawn by the listener's own
//! loop: while it computes, nobody reads the port, and a head whose link
//! buffer fills drops frames. The full fit ([`crate::measure::fit::fit`]: three starts,
//! the fallback scan, Levenberg–Marquardt on the rotated model) took 0.5 s
//! per update here, so the live estimate is the short path of the same
//! module: the profile detrended (a straight line takes the sensor's
//! rotation), ω from the interpolated peak of an FFT of the 1 mm samples
//! (zero-padded ×8, gaps as zeros, where [`fit::dft_omega`] resamples the
//! profile first), then
//! the IEEE 1057 four-parameter iteration ([`fit::four_param_ieee`]),
//! falling back to the three-parameter fit at the DFT's ω if the iteration
//! breaks down or wanders more than 20 % away. Cost per update: the
//! `corrugation` benchmark (`cargo bench -p cms-host --bench corrugation`).
//!
//! **Its verdict** is [`verdict::judge`]'s on what the quick fit knows: the
//! residual (of the sine and a line fitted together at the ω found, which
//! also gives the amplitude) against the stitched samples' own noise
//! ([`verdict::point_noise`], model-free), the periods in the window, the
//! 1 mm sampling, and one-σ uncertainties from the residual — the
//! amplitude's `σ √(2/N)` and the wavelength's Cramér–Rao bound for N
//! samples over the span L, `σ_ω = (σ/A) √(24/(N L²))` — so a wave not
//! told from the noise is failed and one too short a window holds is
//! doubtful. It is a diagnostic of the fit, not a verdict on the rail: a
//! rail of several wavelengths does not fit one sine, and says so here.
//! The rail's live verdict is [`bands`]': each line's EN 13231-3 figures
//! so far, judged by `analyze`'s code against its floor; and
//! [`iso3095`]'s: each line's and the energy average's ISO 3095 third
//! octaves over the latest stretch, judged by `analyze` itself.

pub mod bands;
pub mod iso3095;

use std::collections::VecDeque;
use std::fmt::Write as _;

use cms_core::protocol::Profile;

use super::stitch::{self, Direction, FrameAssembler, FramePoints, Registration};
use crate::measure::fit;
use crate::measure::verdict::{self, Evidence, Verdict};

/// Odometer span of the frames kept, mm.
pub const WINDOW_MM: f64 = 500.0;
/// Most frames kept.
pub const MAX_FRAMES: usize = 60;
/// Fewest stitched samples a fit is tried on.
const MIN_SAMPLES: usize = 40;

/// The recent calibrated frames.
#[derive(Debug, Default)]
pub struct LiveEstimate {
    asm: FrameAssembler,
    window: VecDeque<FramePoints>,
}

/// One laser's estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserEstimate {
    pub laser: usize,
    /// Stitched track length fitted, mm.
    pub length_mm: f64,
    /// The sine, or why there is none.
    pub fit: Result<Sine, SineError>,
    /// Whether the sine is to be believed (see the module docs); `None`
    /// without a sine.
    pub verdict: Option<Verdict>,
}

/// A fitted sine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sine {
    pub wavelength_mm: f64,
    /// Half the peak-to-peak, µm.
    pub amplitude_um: f64,
    /// Residual RMS of the samples about the sine, µm.
    pub rms_um: f64,
    /// Samples fitted.
    pub samples: usize,
    /// Whether the four-parameter iteration converged (else the
    /// three-parameter fit at the spectrum's ω is the result).
    pub converged: bool,
}

/// ω (rad/mm) of the largest spectral peak of samples on a grid (x a
/// multiple of the spacing apart; missing samples count as zero), by a
/// zero-padded FFT and parabolic interpolation of the magnitude, over
/// wavelengths from three samples to the span.
fn fft_omega(x: &[f64], z: &[f64]) -> Option<f64> {
    let (lo, hi) = (x.first()?, x.last()?);
    let dx = x.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    if !(dx > 0.0 && dx.is_finite()) {
        return None;
    }
    let n = ((hi - lo) / dx).round() as usize + 1;
    let m = (8 * n).next_power_of_two();
    let mut buf = vec![rustfft::num_complex::Complex::new(0.0, 0.0); m];
    for (x, z) in x.iter().zip(z) {
        let i = ((x - lo) / dx).round() as usize;
        if let Some(b) = buf.get_mut(i) {
            b.re = *z;
        }
    }
    rustfft::FftPlanner::<f64>::new().plan_fft_forward(m).process(&mut buf);
    let mag: Vec<f64> = buf[..m / 2].iter().map(|c| c.norm()).collect();
    // Bins of wavelengths between the span and three samples.
    let (k_lo, k_hi) = ((m / n).max(1), m / 3);
    let k = (k_lo..k_hi.min(mag.len() - 1)).max_by(|&a, &b| mag[a].total_cmp(&mag[b]))?;
    let (a, b, c) = (mag[k - 1], mag[k], mag[k + 1]);
    let den = a - 2.0 * b + c;
    let delta = if den < 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 };
    Some(std::f64::consts::TAU * (k as f64 + delta) / (m as f64 * dx))
}

/// Why the quick sine fit gave nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SineError {
    /// Too few samples (or unequal lengths).
    #[error("{0} samples")]
    TooFew(usize),
    /// The spectrum has no peak.
    #[error("no spectral peak")]
    NoPeak,
    /// The linear fit at the peak is singular.
    #[error("singular fit")]
    Singular,
    /// The fit is not finite.
    #[error("no finite fit")]
    NotFinite,
}

/// The quick sine fit of a profile (x mm, z µm); see the module docs.
pub fn quick_sine(x: &[f64], z_um: &[f64]) -> Result<Sine, SineError> {
    let n = x.len() as f64;
    if x.len() < MIN_SAMPLES || x.len() != z_um.len() {
        return Err(SineError::TooFew(x.len()));
    }
    let xm = x.iter().sum::<f64>() / n;
    let zm = z_um.iter().sum::<f64>() / n;
    let xc: Vec<f64> = x.iter().map(|v| v - xm).collect();
    let sxx: f64 = xc.iter().map(|v| v * v).sum();
    let slope = xc.iter().zip(z_um).map(|(x, z)| x * (z - zm)).sum::<f64>() / sxx;
    let zd: Vec<f64> = xc.iter().zip(z_um).map(|(x, z)| z - zm - slope * x).collect();
    let w0 = fft_omega(&xc, &zd).ok_or(SineError::NoPeak)?;
    let (w, lin, converged) = match fit::four_param_ieee(&xc, &zd, w0, 20) {
        Some(f) if (f.omega / w0 - 1.0).abs() < 0.2 => (f.omega, f.linear, f.converged),
        _ => (w0, fit::three_param(&xc, &zd, w0).ok_or(SineError::Singular)?, false),
    };
    // The detrend took the sine's own slope over the window (up to 6A/(ωL)
    // at the ends): at the found ω, the sine and the line are fitted
    // together on the centred profile, so that the residual is the
    // profile's, not the detrend's.
    let (amplitude_um, rss) = sine_and_line(&xc, z_um, zm, w).unwrap_or((lin.sin.hypot(lin.cos), lin.rss));
    let s = Sine {
        wavelength_mm: std::f64::consts::TAU / w,
        amplitude_um,
        rms_um: (rss / n).sqrt(),
        samples: x.len(),
        converged,
    };
    if s.wavelength_mm.is_finite() && s.amplitude_um.is_finite() { Ok(s) } else { Err(SineError::NotFinite) }
}

/// Least squares of `z − zm ≈ a sin ωx + b cos ωx + c + d x`: the
/// amplitude `√(a² + b²)` and the residual sum of squares.
fn sine_and_line(x: &[f64], z: &[f64], zm: f64, omega: f64) -> Option<(f64, f64)> {
    use nalgebra::{Matrix4, Vector4};
    let row = |x: f64| {
        let (s, c) = (omega * x).sin_cos();
        Vector4::new(s, c, 1.0, x)
    };
    let (mut ata, mut atb) = (Matrix4::zeros(), Vector4::zeros());
    for (&x, &z) in x.iter().zip(z) {
        let r = row(x);
        ata += r * r.transpose();
        atb += r * (z - zm);
    }
    let p = ata.cholesky()?.solve(&atb);
    let rss = x.iter().zip(z).map(|(&x, &z)| (z - zm - row(x).dot(&p)).powi(2)).sum();
    Some((p[0].hypot(p[1]), rss))
}

/// The verdict on a quick sine of the samples `(x mm, z µm)` spanning
/// `span_mm` at `dx_mm` (module docs).
pub fn judge_sine(s: &Sine, samples: &[(f64, f64)], span_mm: f64, dx_mm: f64) -> Verdict {
    let n = s.samples.max(1) as f64;
    let (sigma, amp) = (s.rms_um * 1e-3, s.amplitude_um * 1e-3);
    let sigma_omega =
        if amp > 0.0 && span_mm > 0.0 { sigma / amp * (24.0 / (n * span_mm * span_mm)).sqrt() } else { f64::NAN };
    let sigma_lambda = s.wavelength_mm * s.wavelength_mm / std::f64::consts::TAU * sigma_omega;
    verdict::judge(&Evidence {
        rms_residual_mm: sigma,
        noise_mm: verdict::point_noise(samples).map(|v| v * 1e-3),
        wavelength_mm: s.wavelength_mm,
        span_mm,
        spacing_mm: dx_mm,
        yaw_rad: 0.0,
        converged: s.converged,
        rejected: 0,
        points: s.samples,
        alternative_wavelength_mm: None,
        birge: None,
        sigma_mm: (sigma_lambda.is_finite().then_some(sigma_lambda), Some(sigma * (2.0 / n).sqrt())),
        amplitude_mm: amp,
    })
}

impl LiveEstimate {
    /// Feeds one profile message; the frame it completed, if any.
    pub fn push(&mut self, p: &Profile) -> Option<&FramePoints> {
        let f = self.asm.push(p)?;
        self.add(f);
        self.window.back()
    }

    /// Adds a complete frame.
    pub fn add(&mut self, f: FramePoints) {
        let newest = f.odometer_mm;
        self.window.push_back(f);
        while self.window.len() > MAX_FRAMES
            || self.window.front().is_some_and(|o| (newest - o.odometer_mm).abs() > WINDOW_MM)
        {
            self.window.pop_front();
        }
    }

    /// Frames in the window.
    pub fn frames(&self) -> usize {
        self.window.len()
    }

    /// The estimate per laser (empty without calibrated frames).
    pub fn estimate(&self) -> Vec<LaserEstimate> {
        let frames: Vec<FramePoints> = self.window.iter().cloned().collect();
        let opts = stitch::Options {
            dx_mm: 1.0,
            direction: Direction::Auto,
            registration: Registration::Offset,
            ..stitch::Options::default()
        };
        let Ok(s) = stitch::stitch(&frames, &opts) else { return Vec::new() };
        s.lasers
            .iter()
            .map(|l| {
                let xz: Vec<(f64, f64)> = {
                    let z = l.z.to_vec().unwrap_or_default();
                    (0..z.len()).filter(|&i| z[i].is_finite()).map(|i| (l.x_mm(i), z[i])).collect()
                };
                let (x, z): (Vec<f64>, Vec<f64>) = xz.iter().copied().unzip();
                let fit = quick_sine(&x, &z);
                let span_mm = match (x.first(), x.last()) {
                    (Some(a), Some(b)) => b - a + opts.dx_mm,
                    _ => 0.0,
                };
                let verdict = fit.as_ref().ok().map(|s| judge_sine(s, &xz, span_mm, opts.dx_mm));
                LaserEstimate { laser: l.laser, length_mm: l.covered_mm(), fit, verdict }
            })
            .collect()
    }

    /// `corrugation L0 50.1 mm/30.2 µm L1 …` (empty without calibrated frames).
    pub fn status(&self) -> String {
        let est = self.estimate();
        if est.is_empty() {
            return String::new();
        }
        let mut s = String::from("corrugation");
        for e in &est {
            match &e.fit {
                Ok(f) => {
                    let _ = write!(s, " L{} {:.1} mm/{:.1} µm", e.laser, f.wavelength_mm, f.amplitude_um);
                }
                Err(_) => {
                    let _ = write!(s, " L{} -", e.laser);
                }
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::verdict::{Level, Reason};

    /// 500 samples 1 mm apart: `amplitude_um` at 50 mm plus seeded
    /// normal noise of `noise_um` RMS.
    fn samples(amplitude_um: f64, noise_um: f64) -> Vec<(f64, f64)> {
        let mut rng = cms_study::Rng::new(7);
        (0..500)
            .map(|i| {
                let x = f64::from(i);
                (x, amplitude_um * (std::f64::consts::TAU * x / 50.0).sin() + noise_um * rng.normal())
            })
            .collect()
    }

    fn judged(amplitude_um: f64, noise_um: f64) -> (Sine, Verdict) {
        let xz = samples(amplitude_um, noise_um);
        let (x, z): (Vec<f64>, Vec<f64>) = xz.iter().copied().unzip();
        let s = quick_sine(&x, &z).unwrap();
        let v = judge_sine(&s, &xz, 500.0, 1.0);
        (s, v)
    }

    #[test]
    fn a_clear_wave_is_good() {
        let (s, v) = judged(30.0, 1.0);
        assert!((s.wavelength_mm - 50.0).abs() < 0.05, "{s:?}");
        assert!((s.amplitude_um - 30.0).abs() < 0.3, "{s:?}");
        assert_eq!(v.level, Level::Good, "{v}");
    }

    #[test]
    fn noise_alone_is_failed_as_not_detected() {
        let (_, v) = judged(0.0, 1.0);
        assert_eq!(v.level, Level::Failed, "{v}");
        assert!(v.reasons.iter().any(|r| matches!(r, Reason::NotDetected { .. })), "{v}");
    }
}
