//! A measured roughness spectrum laid on the simulated rail: third-octave
//! levels as EN 15610 and ISO 3095 report them, turned into a random
//! profile whose power in each listed third octave is the level.
//!
//! The file is CSV, `wavelength_mm,level_db` (dB re 1 µm, a header line,
//! `#` comments), one line per third octave, any subset of the standard
//! ones from 1 to 1000 mm (EN 15610's: centre 10^(k/10) cycles/m, named by
//! the R10 preferred number, [`en15610::nominal_wavelength_mm`]).
//!
//! The profile (`RoughnessSpectrum::table`) is a sum of cosines on the
//! bins of one long inverse FFT (`rustfft`), with seeded random phases:
//! every bin whose frequency lies inside a listed band gets the same
//! amplitude (a flat density within the band), chosen so that the band's
//! mean square is `10^(L/10)` µm²; bins outside the listed bands get
//! nothing. The table is periodic over at least 100 m (and 40 of its
//! longest wavelengths), so that a run of a few tens of metres meets no
//! repeat, and sampled 16 times per shortest wavelength.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::noise::Rng;
use crate::analyze::standards::{en15610, fmt_nominal_mm};

/// Longest third octave a spectrum may list, mm (band k = 0: 1 cycle/m).
pub const MAX_WAVELENGTH_MM: f64 = 1000.0;
/// Shortest, mm (band k = 30: 1000 cycles/m).
pub const MIN_WAVELENGTH_MM: f64 = 1.0;
/// Highest level, dB re 1 µm (1 mm RMS in a band).
pub const MAX_LEVEL_DB: f64 = 60.0;
/// A wavelength names a band when within this share of its nominal or
/// exact centre (neighbours are 26 % apart).
const WAVELENGTH_TOLERANCE: f64 = 0.02;
/// Samples per shortest wavelength (the band's short edge).
const SAMPLES_PER_MIN_WAVELENGTH: f64 = 16.0;
/// Shortest period of the table, mm.
const MIN_PERIOD_MM: f64 = 100_000.0;
/// Period in longest wavelengths (the band's long edge), at least.
const PERIOD_IN_MAX_WAVELENGTHS: f64 = 40.0;
/// The header line.
pub const HEADER: &str = "wavelength_mm,level_db";

/// One third octave of a spectrum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpectrumBand {
    /// Band index: centre 10^(k/10) cycles/m.
    pub k: i32,
    /// Nominal (preferred-number) centre wavelength, mm.
    pub nominal_wavelength_mm: f64,
    /// Roughness level, dB re 1 µm.
    pub level_db: f64,
}

impl SpectrumBand {
    /// The band's edges, cycles/mm (low, high).
    fn edges_per_mm(&self) -> (f64, f64) {
        let centre = 10f64.powf(f64::from(self.k) / 10.0) / 1000.0;
        (centre * 10f64.powf(-0.05), centre * 10f64.powf(0.05))
    }
}

/// Third-octave roughness levels to lay on the rail, long wavelengths first.
#[derive(Clone, Debug, PartialEq)]
pub struct RoughnessSpectrum {
    bands: Vec<SpectrumBand>,
}

/// Why a roughness spectrum could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RoughnessSpectrumError {
    /// The file could not be read.
    #[error("roughness spectrum {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A line is not a third octave's level.
    #[error("roughness spectrum {}, line {line}: {what}", path.display())]
    Line {
        /// The file.
        path: PathBuf,
        /// Its line, from 1.
        line: usize,
        /// What is wrong with it.
        what: String,
    },
    /// No third octave at all.
    #[error("roughness spectrum {}: no third octave (a header `{HEADER}`, then one line a band)", path.display())]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

impl crate::error::Classify for RoughnessSpectrumError {
    fn class(&self) -> crate::Class {
        crate::Class::Input
    }
}

/// The band a wavelength names, or why none.
fn band_of(wavelength_mm: f64, level_db: f64) -> Result<SpectrumBand, String> {
    if !(wavelength_mm.is_finite() && wavelength_mm > 0.0) {
        return Err(format!("wavelength {wavelength_mm} mm: not a positive number"));
    }
    let k = (10.0 * (1000.0 / wavelength_mm).log10()).round() as i32;
    let nominal = en15610::nominal_wavelength_mm(k);
    let exact = 1000.0 / 10f64.powf(f64::from(k) / 10.0);
    let near = |w: f64| (wavelength_mm - w).abs() <= WAVELENGTH_TOLERANCE * w;
    if !(near(nominal) || near(exact)) {
        return Err(format!(
            "wavelength {wavelength_mm} mm is not a standard third octave (nearest {} mm)",
            fmt_nominal_mm(nominal)
        ));
    }
    if !(0..=30).contains(&k) {
        return Err(format!(
            "wavelength {} mm: the simulated rail takes third octaves from {MIN_WAVELENGTH_MM} to {MAX_WAVELENGTH_MM} mm",
            fmt_nominal_mm(nominal)
        ));
    }
    if !level_db.is_finite() || level_db > MAX_LEVEL_DB {
        return Err(format!("level {level_db} dB: a finite level of at most {MAX_LEVEL_DB} dB re 1 µm"));
    }
    Ok(SpectrumBand { k, nominal_wavelength_mm: nominal, level_db })
}

impl RoughnessSpectrum {
    /// A spectrum of `(wavelength mm, level dB re 1 µm)` pairs, checked as
    /// a file's lines are (the error's line is the pair's index from 1).
    pub fn new(levels: &[(f64, f64)]) -> Result<RoughnessSpectrum, RoughnessSpectrumError> {
        let path = PathBuf::from("(given)");
        let mut bands: Vec<(usize, SpectrumBand)> = Vec::new();
        for (i, &(w, l)) in levels.iter().enumerate() {
            let b =
                band_of(w, l).map_err(|what| RoughnessSpectrumError::Line { path: path.clone(), line: i + 1, what })?;
            push(&mut bands, i + 1, b).map_err(|what| RoughnessSpectrumError::Line {
                path: path.clone(),
                line: i + 1,
                what,
            })?;
        }
        Self::of(bands, path)
    }

    /// Reads and checks the CSV file at `path`.
    pub fn load(path: &Path) -> Result<RoughnessSpectrum, RoughnessSpectrumError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| RoughnessSpectrumError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses a file's text (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<RoughnessSpectrum, RoughnessSpectrumError> {
        let err = |line: usize, what: String| RoughnessSpectrumError::Line { path: path.to_path_buf(), line, what };
        let mut header = false;
        let mut bands: Vec<(usize, SpectrumBand)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let n = i + 1;
            let line = raw.split('#').next().unwrap_or_default().trim();
            if line.is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if !header {
                if fields.len() != 2
                    || !fields[0].eq_ignore_ascii_case("wavelength_mm")
                    || !fields[1].eq_ignore_ascii_case("level_db")
                {
                    return Err(err(n, format!("expected the header `{HEADER}`, found {line:?}")));
                }
                header = true;
                continue;
            }
            if fields.len() != 2 {
                return Err(err(n, format!("expected two fields `wavelength_mm,level_db`, found {}", fields.len())));
            }
            let number = |s: &str, what: &str| -> Result<f64, RoughnessSpectrumError> {
                s.parse::<f64>().map_err(|_| err(n, format!("{what} {s:?} is not a number")))
            };
            let b = band_of(number(fields[0], "wavelength")?, number(fields[1], "level")?).map_err(|w| err(n, w))?;
            push(&mut bands, n, b).map_err(|w| err(n, w))?;
        }
        Self::of(bands, path.to_path_buf())
    }

    fn of(mut bands: Vec<(usize, SpectrumBand)>, path: PathBuf) -> Result<RoughnessSpectrum, RoughnessSpectrumError> {
        if bands.is_empty() {
            return Err(RoughnessSpectrumError::Empty { path });
        }
        bands.sort_by_key(|(_, b)| b.k);
        Ok(RoughnessSpectrum { bands: bands.into_iter().map(|(_, b)| b).collect() })
    }

    /// The third octaves, long wavelengths first.
    pub fn bands(&self) -> &[SpectrumBand] {
        &self.bands
    }

    /// The level at a nominal wavelength, dB re 1 µm (`None`: not listed).
    pub fn level_db(&self, nominal_wavelength_mm: f64) -> Option<f64> {
        self.bands
            .iter()
            .find(|b| (b.nominal_wavelength_mm - nominal_wavelength_mm).abs() < 1e-6 * nominal_wavelength_mm)
            .map(|b| b.level_db)
    }

    /// The RMS of the whole spectrum, µm.
    pub fn rms_um(&self) -> f64 {
        self.bands.iter().map(|b| 10f64.powf(b.level_db / 10.0)).sum::<f64>().sqrt()
    }

    /// The spectrum as the file spells it.
    pub fn to_csv(&self) -> String {
        let mut s = format!("{HEADER}\n");
        for b in &self.bands {
            let _ = writeln!(s, "{},{:.2}", fmt_nominal_mm(b.nominal_wavelength_mm), b.level_db);
        }
        s
    }

    /// The profile, mm, sampled every `step_mm` over one period (a power
    /// of two of samples), random phases from `seed`: `(samples, step_mm)`.
    pub(crate) fn table(&self, seed: u64) -> (Vec<f64>, f64) {
        let f_max = self.bands.iter().map(|b| b.edges_per_mm().1).fold(0.0, f64::max);
        let f_min = self.bands.iter().map(|b| b.edges_per_mm().0).fold(f64::INFINITY, f64::min);
        let step_mm = 1.0 / (f_max * SAMPLES_PER_MIN_WAVELENGTH);
        let period_mm = MIN_PERIOD_MM.max(PERIOD_IN_MAX_WAVELENGTHS / f_min);
        // At most 1000 / 0.89 × 16 × 45 m: 2^20 samples, 8 MiB.
        let n = ((period_mm / step_mm).ceil() as usize).next_power_of_two();
        let period_mm = n as f64 * step_mm;
        let mut rng = Rng::for_stream(seed, 0x5350_4543, 0, 0);
        let mut spectrum = vec![Complex::new(0.0, 0.0); n];
        for b in &self.bands {
            let (lo, hi) = b.edges_per_mm();
            // Bin j is j / period cycles/mm; the band takes those inside its edges.
            let (first, last) = ((lo * period_mm).ceil() as usize, ((hi * period_mm).ceil() as usize).min(n / 2));
            let bins = last.saturating_sub(first).max(1);
            // Σ a²/2 over the band's bins is its mean square, µm² → mm.
            let a_mm = (2.0 * 10f64.powf(b.level_db / 10.0) / bins as f64).sqrt() * 1e-3;
            for c in &mut spectrum[first..last.max(first + 1)] {
                let (s, co) = (std::f64::consts::TAU * rng.uniform()).sin_cos();
                *c = Complex::new(a_mm * co, a_mm * s);
            }
        }
        // Unnormalised inverse DFT: the real part is Σ a·cos(2π·j·i/n + φ_j).
        FftPlanner::<f64>::new().plan_fft_inverse(n).process(&mut spectrum);
        (spectrum.into_iter().map(|c| c.re).collect(), step_mm)
    }
}

/// Adds `b` (from line `line`) unless its band is already listed.
fn push(bands: &mut Vec<(usize, SpectrumBand)>, line: usize, b: SpectrumBand) -> Result<(), String> {
    if let Some((first, _)) = bands.iter().find(|(_, o)| o.k == b.k) {
        return Err(format!(
            "third octave {} mm listed twice (also on line {first})",
            fmt_nominal_mm(b.nominal_wavelength_mm)
        ));
    }
    bands.push((line, b));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<RoughnessSpectrum, RoughnessSpectrumError> {
        RoughnessSpectrum::parse(text, Path::new("rail.csv"))
    }

    #[test]
    fn parses_any_subset_of_the_third_octaves() {
        let s = parse("# a rail\nwavelength_mm, level_db\n\n 31.5, -7 # grinding\n250,3\n5,-12.5\n6.3,-11\n").unwrap();
        let w: Vec<f64> = s.bands().iter().map(|b| b.nominal_wavelength_mm).collect();
        assert_eq!(w, [250.0, 31.5, 6.3, 5.0]);
        assert_eq!(s.level_db(31.5), Some(-7.0));
        assert_eq!(s.level_db(40.0), None);
        // The exact centre names the band too.
        assert_eq!(parse("wavelength_mm,level_db\n31.62,1\n").unwrap().bands()[0].nominal_wavelength_mm, 31.5);
        assert_eq!(parse(&s.to_csv()).unwrap(), s);
    }

    #[test]
    fn bad_files_are_refused_naming_the_line() {
        let cases = [
            ("", "no third octave"),
            ("wavelength_mm,level_db\n# nothing\n", "no third octave"),
            ("50,1\n", "line 1: expected the header"),
            ("wavelength_mm,level_db\n33,1\n", "line 2: wavelength 33 mm is not a standard third octave"),
            ("wavelength_mm,level_db\n50,1\n# x\n50,2\n", "line 4: third octave 50 mm listed twice (also on line 2)"),
            ("wavelength_mm,level_db\n50,nan\n", "line 2: level NaN dB"),
            ("wavelength_mm,level_db\n50,inf\n", "line 2: level inf dB"),
            ("wavelength_mm,level_db\n50,x\n", "line 2: level \"x\" is not a number"),
            ("wavelength_mm,level_db\n50\n", "line 2: expected two fields"),
            ("wavelength_mm,level_db\n50,1,2\n", "line 2: expected two fields"),
            ("wavelength_mm,level_db\n-5,1\n", "line 2: wavelength -5 mm: not a positive number"),
            ("wavelength_mm,level_db\n2000,1\n", "from 1 to 1000 mm"),
            ("wavelength_mm,level_db\n50,61\n", "at most 60 dB"),
        ];
        for (text, want) in cases {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.starts_with("roughness spectrum rail.csv") && e.contains(want), "{text:?}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        let missing = RoughnessSpectrum::load(Path::new("/nonexistent/rail.csv")).unwrap_err();
        assert!(missing.to_string().starts_with("roughness spectrum /nonexistent/rail.csv: "), "{missing}");
    }
}
