//! Rail-standard analysis of a longitudinal rail profile: the EN 13231-3
//! wavelength-band criteria ([`en13231`]) and the EN 15610 roughness spectrum
//! against the ISO 3095 limit ([`en15610`]).
//!
//! # Input
//!
//! A uniformly sampled longitudinal profile: heights `z_um` in micrometres,
//! one every `dx_mm` millimetres along the rail. Gaps (frames missing, a
//! stitching hole) are NaN (or ±∞) samples: the profile is split into
//! continuous runs of finite samples ([`segments`]) and every filter,
//! window and spectrum segment works inside one run only, so nothing is ever
//! interpolated across a gap. Whether a record is "long enough" for a
//! standard's window is judged on its **longest run**.
//!
//! # Choices and costs
//!
//! * Band filtering ([`en13231::band_pass`]) is a 6th-order Butterworth
//!   high-pass and low-pass pair run forward and backward: zero phase,
//!   12th-order skirts, local in time (edge transients die out within about a
//!   band's longest wavelength). `O(N)` per band.
//! * Moving-window statistics are evaluated at every sample: a monotonic
//!   deque for max − min and prefix sums over half-waves for the mean
//!   peak-to-peak, `O(N log N)` per band.
//! * The roughness spectrum is Welch's method with `rustfft` (`O(N log N)`).
//!   Curvature processing is a direct search over the wheel's possible contact
//!   points, `O(N · S)` with `S` the contact half-width in samples (the
//!   sagitta of a 0.375 m wheel exceeds the run's height range beyond
//!   `√(2·R·range)`: about 9 mm for a 100 µm range).
//!
//! No function here panics on finite input of any value; inputs that make no
//! sense (non-positive or non-finite sampling, records shorter than a window)
//! are [`StandardsError`]s with a message that says what is missing.

pub mod detection;
pub mod en13231;
pub mod en15610;
pub mod wheel;

use std::ops::Range;

/// Why an analysis could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StandardsError {
    /// The sample spacing is not a positive finite number.
    #[error("sample spacing {dx_mm} mm is not a positive finite number")]
    BadSampling { dx_mm: f64 },
    /// The sampling is too coarse for what is asked (`max_dx_mm` is the limit).
    #[error("sample spacing {dx_mm} mm is too coarse for {what} (at most {max_dx_mm} mm)")]
    SamplingTooCoarse { dx_mm: f64, max_dx_mm: f64, what: String },
    /// The longest continuous run is shorter than a window the analysis needs.
    #[error("record {} mm is too short for the {} mm window of {what}", fmt_mm(*record_mm), fmt_mm(*window_mm))]
    TooShort { record_mm: f64, window_mm: f64, what: String },
    /// Nothing finite to analyse.
    #[error("the profile has no finite samples")]
    NoData,
    /// An option is out of its range.
    #[error("{0}")]
    BadOption(String),
}

/// A length in mm without a useless fraction ("450", "1000", "12.5").
pub fn fmt_mm(v: f64) -> String {
    if (v - v.round()).abs() < 1e-6 * v.abs().max(1.0) { format!("{}", v.round()) } else { format!("{v:.1}") }
}

/// A nominal (preferred-number) wavelength as the standards write it:
/// 3.15, 31.5, 250 (the R10 series needs two decimals where [`fmt_mm`]
/// keeps one).
pub fn fmt_nominal_mm(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Checks the sample spacing.
fn check_dx(dx_mm: f64) -> Result<(), StandardsError> {
    if dx_mm.is_finite() && dx_mm > 0.0 { Ok(()) } else { Err(StandardsError::BadSampling { dx_mm }) }
}

/// A stretch of a longer profile, analysed as a piece of it: the samples
/// `z_um` are the profile's from index `start`, and `core` (profile
/// indices, inside the stretch) the positions the piece answers for; the
/// rest is margin, there so that filters and windows near the core see
/// the rail as it goes on. `runs` are the profile's continuous runs that
/// meet the stretch, whole (profile indices): a window or a spectrum
/// segment is placed by its run, not by where the stretch happens to cut.
#[derive(Debug, Clone)]
pub struct Stretch<'a> {
    pub z_um: &'a [f64],
    pub start: usize,
    pub core: Range<usize>,
    pub runs: &'a [Range<usize>],
    pub dx_mm: f64,
}

impl Stretch<'_> {
    /// Profile index past the stretch's last sample.
    pub fn end(&self) -> usize {
        self.start + self.z_um.len()
    }
}

/// The continuous runs of finite samples of `z`, in order, as index ranges.
pub fn segments(z: &[f64]) -> Vec<Range<usize>> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, v) in z.iter().enumerate() {
        match (v.is_finite(), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push(s..z.len());
    }
    out
}

/// Length in mm of a run of `n` samples: each sample stands for `dx_mm` of rail.
fn run_mm(n: usize, dx_mm: f64) -> f64 {
    n as f64 * dx_mm
}

/// Number of samples covering `len_mm` (at least 1), saturating instead of
/// overflowing for absurd ratios.
fn samples_for(len_mm: f64, dx_mm: f64) -> usize {
    let n = (len_mm / dx_mm).round();
    if n.is_finite() && n < usize::MAX as f64 { (n as usize).max(1) } else { usize::MAX }
}

/// Least-squares line through `y` (index as abscissa) removed in place.
fn remove_mean_and_trend(y: &mut [f64]) {
    let n = y.len();
    if n == 0 {
        return;
    }
    let mean = y.iter().sum::<f64>() / n as f64;
    if n < 2 {
        y[0] -= mean;
        return;
    }
    let xm = (n as f64 - 1.0) / 2.0;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, v) in y.iter().enumerate() {
        let dx = i as f64 - xm;
        sxy += dx * (v - mean);
        sxx += dx * dx;
    }
    let slope = sxy / sxx;
    for (i, v) in y.iter_mut().enumerate() {
        *v -= mean + slope * (i as f64 - xm);
    }
}
