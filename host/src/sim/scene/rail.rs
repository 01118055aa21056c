//! The rail head: a longitudinal height profile (corrugation + roughness)
//! and an optional transverse crown.
//!
//! The surface in the rail frame is `z(x, y) = h(x) + crown(y)`, with `x`
//! the position along the track (the odometer's coordinate, mm), `y` across
//! the head from its centreline, `z` up:
//!
//! * `h(x) = Σ A_i·sin(2π·x/λ_i + φ_i) + r(x)`: the corrugation components
//!   and a band-limited random roughness `r` (seeded; flat amplitude
//!   spectrum between two wavelengths with random phases, scaled to the
//!   requested RMS, tabulated over a long period by one inverse FFT
//!   (`rustfft`) and interpolated with a C¹ cubic), plus a measured
//!   roughness spectrum's profile where one is laid on the rail
//!   ([`RoughnessSpectrum`]: third-octave levels, tabulated and
//!   interpolated the same way);
//! * `crown(y) = −(R − sqrt(R² − y²))` for a crown radius `R` (≈ −y²/2R), 0
//!   without one.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::noise::Rng;
use super::roughness_spectrum::RoughnessSpectrum;
use super::{SimError, check};

/// One sinusoidal corrugation component.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Corrugation {
    /// Wavelength along the rail, mm.
    pub wavelength_mm: f64,
    /// Amplitude (half the peak-to-peak height), µm.
    pub amplitude_um: f64,
    /// Phase at track position 0, radians.
    pub phase_rad: f64,
}

/// The rail head's surface.
#[derive(Clone, Debug, PartialEq)]
pub struct RailModel {
    /// Corrugation components (summed).
    pub corrugation: Vec<Corrugation>,
    /// RMS of the random roughness, µm (0: none).
    pub roughness_rms_um: f64,
    /// Shortest roughness wavelength, mm.
    pub roughness_min_wavelength_mm: f64,
    /// Longest roughness wavelength, mm.
    pub roughness_max_wavelength_mm: f64,
    /// A measured roughness spectrum laid on the rail (added to the
    /// corrugation and the roughness above; `None`: none).
    pub roughness_spectrum: Option<RoughnessSpectrum>,
    /// Transverse crown radius of the rail head, mm (`None`: flat across).
    pub crown_radius_mm: Option<f64>,
    /// Relative reflectance of the surface (scales every stripe; 1 = nominal).
    pub reflectance: f64,
}

impl Default for RailModel {
    /// Moderate corrugation: 30 µm at 50 mm plus 20 µm at 200 mm, 2 µm RMS
    /// roughness over 5–500 mm, a 300 mm crown.
    fn default() -> Self {
        RailModel {
            corrugation: vec![
                Corrugation { wavelength_mm: 50.0, amplitude_um: 30.0, phase_rad: 0.0 },
                Corrugation { wavelength_mm: 200.0, amplitude_um: 20.0, phase_rad: 1.0 },
            ],
            roughness_rms_um: 2.0,
            roughness_min_wavelength_mm: 5.0,
            roughness_max_wavelength_mm: 500.0,
            roughness_spectrum: None,
            crown_radius_mm: Some(300.0),
            reflectance: 1.0,
        }
    }
}

impl RailModel {
    /// A perfectly flat rail: no corrugation, no roughness, no crown.
    pub fn flat() -> RailModel {
        RailModel { corrugation: Vec::new(), roughness_rms_um: 0.0, crown_radius_mm: None, ..RailModel::default() }
    }

    pub(crate) fn validate(&self) -> Result<(), SimError> {
        for c in &self.corrugation {
            check("rail.corrugation.wavelength_mm", c.wavelength_mm, c.wavelength_mm > 0.0, "finite and > 0")?;
            check("rail.corrugation.amplitude_um", c.amplitude_um, c.amplitude_um.is_finite(), "finite")?;
            check("rail.corrugation.phase_rad", c.phase_rad, c.phase_rad.is_finite(), "finite")?;
        }
        check("rail.roughness_rms_um", self.roughness_rms_um, self.roughness_rms_um >= 0.0, "finite and ≥ 0")?;
        let (lo, hi) = (self.roughness_min_wavelength_mm, self.roughness_max_wavelength_mm);
        check("rail.roughness_min_wavelength_mm", lo, lo > 0.0, "finite and > 0")?;
        check("rail.roughness_max_wavelength_mm", hi, hi > lo, "finite and above the minimum wavelength")?;
        if let Some(r) = self.crown_radius_mm {
            check("rail.crown_radius_mm", r, r > 0.0, "finite and > 0")?;
        }
        check("rail.reflectance", self.reflectance, self.reflectance >= 0.0, "finite and ≥ 0")?;
        Ok(())
    }
}

/// Longest roughness table (samples): 32 MiB of `f64`.
const MAX_TABLE: usize = 1 << 22;
/// Roughness samples per shortest wavelength.
const SAMPLES_PER_MIN_WAVELENGTH: f64 = 16.0;
/// Table period in longest wavelengths (at least).
const PERIOD_IN_MAX_WAVELENGTHS: f64 = 40.0;

/// The surface, ready to evaluate.
#[derive(Clone, Debug)]
pub(crate) struct RailSurface {
    /// (2π/λ per mm, amplitude mm, phase).
    corrugation: Vec<(f64, f64, f64)>,
    /// The random roughness (`None`: none).
    rough: Option<Table>,
    /// The measured roughness spectrum's profile (`None`: none).
    spectrum: Option<Table>,
    crown_radius_mm: Option<f64>,
}

/// A periodic profile, mm, sampled every `step_mm` (a power of two of
/// samples), read with a C¹ cubic.
#[derive(Clone, Debug)]
struct Table {
    samples: Vec<f64>,
    step_mm: f64,
    inv_step: f64,
}

impl Table {
    fn new(samples: Vec<f64>, step_mm: f64) -> Table {
        Table { samples, step_mm, inv_step: 1.0 / step_mm }
    }

    fn period_mm(&self) -> f64 {
        self.samples.len() as f64 * self.step_mm
    }

    /// Catmull–Rom interpolation of the periodic table.
    fn at(&self, x_mm: f64) -> f64 {
        let n = self.samples.len();
        let t = x_mm.rem_euclid(self.period_mm()) * self.inv_step;
        let i = (t.floor() as usize).min(n - 1);
        let f = t - i as f64;
        let m = n - 1; // n is a power of two
        let p0 = self.samples[(i + n - 1) & m];
        let p1 = self.samples[i];
        let p2 = self.samples[(i + 1) & m];
        let p3 = self.samples[(i + 2) & m];
        p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0)))
    }
}

impl RailSurface {
    pub(crate) fn new(rail: &RailModel, seed: u64) -> Result<RailSurface, SimError> {
        rail.validate()?;
        let corrugation = rail
            .corrugation
            .iter()
            .map(|c| (std::f64::consts::TAU / c.wavelength_mm, c.amplitude_um * 1e-3, c.phase_rad))
            .collect();
        let step_mm = rail.roughness_min_wavelength_mm / SAMPLES_PER_MIN_WAVELENGTH;
        let mut rough = None;
        if rail.roughness_rms_um > 0.0 {
            let want = (PERIOD_IN_MAX_WAVELENGTHS * rail.roughness_max_wavelength_mm / step_mm).ceil();
            if want > MAX_TABLE as f64 {
                return Err(SimError::RoughnessBand {
                    min_mm: rail.roughness_min_wavelength_mm,
                    max_mm: rail.roughness_max_wavelength_mm,
                });
            }
            let n = (want as usize).next_power_of_two().max(4096);
            let period = n as f64 * step_mm;
            let k_lo = (period / rail.roughness_max_wavelength_mm).ceil().max(1.0) as usize;
            let k_hi = ((period / rail.roughness_min_wavelength_mm).floor() as usize).min(n / 2 - 1);
            if k_lo > k_hi {
                return Err(SimError::RoughnessBand {
                    min_mm: rail.roughness_min_wavelength_mm,
                    max_mm: rail.roughness_max_wavelength_mm,
                });
            }
            let mut rng = Rng::for_stream(seed, 0x524f_5547, 0, 0);
            let mut spectrum = vec![Complex::new(0.0, 0.0); n];
            for c in &mut spectrum[k_lo..=k_hi] {
                let (s, co) = (std::f64::consts::TAU * rng.uniform()).sin_cos();
                *c = Complex::new(co, s);
            }
            // Unnormalised inverse DFT: the real part is Σ cos(2π·k·i/n + φ_k).
            FftPlanner::<f64>::new().plan_fft_inverse(n).process(&mut spectrum);
            let re: Vec<f64> = spectrum.iter().map(|c| c.re).collect();
            let rms = (re.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
            let k = rail.roughness_rms_um * 1e-3 / rms;
            rough = Some(Table::new(re.into_iter().map(|v| v * k).collect(), step_mm));
        }
        let spectrum = rail.roughness_spectrum.as_ref().map(|s| {
            let (samples, step_mm) = s.table(seed);
            Table::new(samples, step_mm)
        });
        Ok(RailSurface { corrugation, rough, spectrum, crown_radius_mm: rail.crown_radius_mm })
    }

    /// Longitudinal profile `h(x)` at track position `x_mm`, mm.
    pub(crate) fn profile_mm(&self, x_mm: f64) -> f64 {
        let mut h = 0.0;
        for &(k, a, p) in &self.corrugation {
            h += a * (k * x_mm + p).sin();
        }
        for t in [&self.rough, &self.spectrum].into_iter().flatten() {
            h += t.at(x_mm);
        }
        h
    }

    /// Crown drop `crown(y)` (≤ 0) and its slope at `y_mm`; `None` beyond the radius.
    pub(crate) fn crown_mm(&self, y_mm: f64) -> Option<(f64, f64)> {
        match self.crown_radius_mm {
            None => Some((0.0, 0.0)),
            Some(r) => {
                let q = r * r - y_mm * y_mm;
                if q <= 0.0 {
                    return None;
                }
                let s = q.sqrt();
                Some((s - r, -y_mm / s))
            }
        }
    }

    /// The crown radius, if any.
    pub(crate) fn crown_radius_mm(&self) -> Option<f64> {
        self.crown_radius_mm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roughness_rms_band_and_period() {
        let rail = RailModel { corrugation: Vec::new(), roughness_rms_um: 3.0, ..RailModel::default() };
        let s = RailSurface::new(&rail, 7).unwrap();
        let period = s.rough.as_ref().unwrap().period_mm();
        assert!(period >= 40.0 * 500.0, "{period}");
        // RMS over the table, sampled off the grid.
        let m = 200_000;
        let rms =
            ((0..m).map(|i| s.profile_mm(i as f64 * period / m as f64 + 0.013).powi(2)).sum::<f64>() / m as f64).sqrt();
        assert!((rms * 1e3 - 3.0).abs() < 0.05, "{rms}");
        // Periodic and continuous.
        assert!((s.profile_mm(123.4) - s.profile_mm(123.4 + period)).abs() < 1e-12);
        assert!((s.profile_mm(-0.001) - s.profile_mm(0.001)).abs() < 1e-5);
        // Another seed, another profile.
        let t = RailSurface::new(&rail, 8).unwrap();
        assert!((0..50).any(|i| (s.profile_mm(i as f64) - t.profile_mm(i as f64)).abs() > 1e-4));
    }

    /// A measured spectrum's rail, read off the table's grid (the cubic's
    /// response in it) over one period and put through an FFT: each third
    /// octave's power is the file's level within 0.5 dB (bins counted by
    /// their centre inside the band's edges), and no power outside them.
    #[test]
    fn the_spectrum_rail_has_the_levels_asked_for() {
        let levels: Vec<(f64, f64)> = crate::analyze::standards::en15610::ISO3095_LIMIT
            .iter()
            .filter(|(w, _)| (5.0..=250.0).contains(w))
            .enumerate()
            .map(|(i, &(w, l))| (w, l + [-3.0, 4.0, -9.0, 1.0][i % 4]))
            .collect();
        let spectrum = RoughnessSpectrum::new(&levels).unwrap();
        let s = RailSurface::new(&RailModel { roughness_spectrum: Some(spectrum.clone()), ..RailModel::flat() }, 3)
            .unwrap();
        let t = s.spectrum.as_ref().unwrap();
        assert!(t.period_mm() >= 100_000.0, "{}", t.period_mm());
        let n = t.samples.len();
        let mut z: Vec<Complex<f64>> =
            (0..n).map(|i| Complex::new(s.profile_mm((i as f64 + 0.5) * t.step_mm) * 1e3, 0.0)).collect();
        FftPlanner::<f64>::new().plan_fft_forward(n).process(&mut z);
        // One-sided mean square of bin j, µm², at j / period cycles/mm.
        let power = |j: usize| 2.0 * z[j].norm_sqr() / (n as f64 * n as f64);
        let band = |lo: f64, hi: f64| -> f64 {
            let (a, b) = ((lo * t.period_mm()).ceil() as usize, (hi * t.period_mm()).ceil() as usize);
            (a..b).map(power).sum()
        };
        for b in spectrum.bands() {
            let centre = 10f64.powf(f64::from(b.k) / 10.0) / 1000.0;
            let got = 10.0 * band(centre * 10f64.powf(-0.05), centre * 10f64.powf(0.05)).log10();
            assert!((got - b.level_db).abs() < 0.5, "{} mm: {got} dB for {}", b.nominal_wavelength_mm, b.level_db);
        }
        let total: f64 = (1..n / 2).map(power).sum();
        let listed: f64 = spectrum.bands().iter().map(|b| 10f64.powf(b.level_db / 10.0)).sum();
        assert!((total / listed - 1.0).abs() < 0.02, "{total} µm² in all, {listed} listed");
        // Outside the listed bands (the 250 mm band's long edge is 282 mm,
        // the 5 mm band's short edge 4.47 mm): nothing.
        let (long, short) = (band(0.0, 1.0 / 283.0), band(1.0 / 4.4, 0.5 / t.step_mm));
        assert!(long + short < 1e-9 * listed, "{long} and {short} µm² outside, {listed} listed");
    }

    /// A measured spectrum adds to the corrugation: the profile is their sum.
    #[test]
    fn spectrum_adds_to_the_corrugation() {
        let spectrum = RoughnessSpectrum::new(&[(16.0, -3.0), (100.0, 2.0)]).unwrap();
        let sine = Corrugation { wavelength_mm: 50.0, amplitude_um: 10.0, phase_rad: 0.0 };
        let both =
            RailModel { corrugation: vec![sine], roughness_spectrum: Some(spectrum.clone()), ..RailModel::flat() };
        let alone = RailModel { roughness_spectrum: Some(spectrum), ..RailModel::flat() };
        let (b, a) = (RailSurface::new(&both, 5).unwrap(), RailSurface::new(&alone, 5).unwrap());
        for x in [0.0, 3.7, 12.5, 1234.5] {
            let want = 0.01 * (std::f64::consts::TAU * x / 50.0).sin();
            assert!((b.profile_mm(x) - a.profile_mm(x) - want).abs() < 1e-12, "{x}");
        }
        assert!((0..100).any(|i| a.profile_mm(i as f64).abs() > 1e-4));
    }

    #[test]
    fn crown() {
        let rail = RailModel { crown_radius_mm: Some(300.0), ..RailModel::flat() };
        let s = RailSurface::new(&rail, 0).unwrap();
        let (z, slope) = s.crown_mm(10.0).unwrap();
        assert!((z + 100.0 / 600.0).abs() < 1e-3 && (slope + 10.0 / 300.0).abs() < 1e-3);
        assert!(s.crown_mm(301.0).is_none());
    }
}
