//! EN 15610 rail roughness: spike removal, curvature processing, the
//! one-third-octave roughness spectrum and its comparison with the ISO 3095
//! limit spectrum.
//!
//! # Processing (as docs/reference.md §2 describes it)
//!
//! 1. **Spikes** ([`remove_spikes`]): a sample is a spike candidate when the
//!    second derivative is below −1e7 µm/m² and the first derivative changes
//!    sign there (a sharp local maximum: dirt or a particle on the rail). Its
//!    edges are the nearest samples on either side where |first derivative|
//!    falls below 5e3 µm/m. It is removed when its height `h` above the line
//!    joining the edges exceeds `w²/a` (`w` the edge-to-edge width, a = 3 m),
//!    replaced by that line (linear interpolation), and the whole scan is
//!    repeated until nothing is removed. Derivatives are central (second) and
//!    one-sided per sample pair (first).
//! 2. **Curvature processing** ([`curvature_process`]) with a 0.375 m wheel:
//!    the path of the centre of a wheel rolled along the rail, less its
//!    radius — at every sample the highest point of the record above the
//!    wheel's circle centred over it, `r′(xᵢ) = maxₓ [r(x) − (R − √(R² −
//!    (x − xᵢ)²))]` (a dilation by the wheel's arc). Until 2026-12 this was
//!    the surface the wheel touches (that step followed by its reverse, a
//!    closing); docs/corrugation-and-standards.md gives the reading and its
//!    sources.
//!
//! Where a section has several lines, steps 1 and 2 act on the rail they
//! share, not on each line's noise ([`super::wheel`]): they run on the
//! lines' mean, despiked on evidence over its noise and denoised for the
//! wheel, and their effect is added to each line ([`Welch::add_corrected`]).
//! One line is its own rail estimate: the steps as above, on it.
//!
//! 3. **Spectrum** ([`third_octave_spectrum`]): Welch's method on segments of
//!    at least 1 m (option, default 1 m) with 50 % overlap inside each
//!    continuous run; per segment the mean and least-squares trend are
//!    removed and a periodic Hann window applied; power normalised by the
//!    window's power (`Σw²`), so the one-sided bins of a segment sum to its
//!    mean square; segments averaged by power. A one-third-octave band
//!    (base ten: centre 10^(k/10) cycles/m, edges ×10^(±1/20)) sums the bins,
//!    a bin straddling a band edge shared in proportion to its overlap. Level
//!    `L = 10·lg(r_rms²/r0²)`, r0 = 1 µm. Only bands whose nominal wavelength is
//!    ≤ segment length / 4 and whose upper edge is below the Nyquist frequency
//!    are reported.
//!
//! A sine of amplitude A has mean square A²/2 in its band: 3 µm at 1 cm reads
//! 10·lg 4.5 = 6.53 dB in the 10 mm band (tested).
//!
//! # Costs
//!
//! Spike removal `O(N)` per pass; curvature `O(N · S)` (`S` the wheel's
//! possible contact half-width in samples, bounded by the run's height range:
//! about 9 mm for 100 µm); the spectrum `O(N log M)` with `rustfft`.
//!
//! Records whose longest continuous run is shorter than one segment, or
//! sampled coarser than 1 mm, are errors ([`StandardsError`]).

use std::fmt::Write as _;

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::detection::{Decision, Estimate, Verdict};
use super::wheel::{self, Correction};
use super::{
    StandardsError, Stretch, check_dx, fmt_mm, fmt_nominal_mm, remove_mean_and_trend, run_mm, samples_for, segments,
};

/// Spike criterion: second derivative below this, µm/m².
pub const SPIKE_CURVATURE_UM_PER_M2: f64 = -1e7;
/// Spike edges: where |first derivative| falls below this, µm/m.
pub const SPIKE_EDGE_SLOPE_UM_PER_M: f64 = 5e3;
/// Spike removal: removed when h > w²/a with this a, m.
pub const SPIKE_A_M: f64 = 3.0;
/// A spike is taken out of a rail estimate only where its sharpness and
/// height stand this many standard deviations of the estimate's noise
/// over the criterion
/// ([`remove_spikes_over`]): one-sided 3 × 10⁻⁷ of the normal, so that
/// the tens of candidates a metre that noise offers the standard's
/// criterion yield about one false spike in 50 km.
pub const SPIKE_EVIDENCE_Z: f64 = 5.0;
/// Wheel radius of the curvature processing, mm.
pub const WHEEL_RADIUS_MM: f64 = 375.0;
/// EN 15610 sampling: at most this spacing, mm.
pub const MAX_DX_MM: f64 = 1.0;
/// EN 15610 segments: at least this long, mm.
pub const MIN_SEGMENT_MM: f64 = 1000.0;
/// The Hann window's equivalent noise bandwidth, bins: the band's bins
/// are correlated through the window, so a band of `B` bins holds about
/// `B / 1.5` independent ones.
const HANN_ENBW_BINS: f64 = 1.5;
/// The variance of a Welch average of Hann segments at 50 % overlap
/// against independent ones: `1 + 2c²` with the window's overlap
/// correlation `c = 0.167`.
const HANN_HALF_OVERLAP_VARIANCE: f64 = 1.056;

/// Effective degrees of freedom of a one-third octave's level averaged
/// over `segments` Hann segments at 50 % overlap, the band `bins` FFT
/// bins wide: `2 · max(bins / ENBW, 1) · segments / (1 + 2c²)`.
pub fn welch_dof(bins: f64, segments: usize) -> f64 {
    2.0 * (bins / HANN_ENBW_BINS).max(1.0) * segments as f64 / HANN_HALF_OVERLAP_VARIANCE
}

/// ISO 3095 limit spectrum: (nominal wavelength mm, level dB re 1 µm).
pub const ISO3095_LIMIT: [(f64, f64); 22] = [
    (400.0, 17.1),
    (315.0, 15.0),
    (250.0, 13.0),
    (200.0, 11.0),
    (160.0, 9.0),
    (125.0, 7.0),
    (100.0, 4.9),
    (80.0, 2.9),
    (63.0, 0.9),
    (50.0, -1.1),
    (40.0, -3.2),
    (31.5, -5.0),
    (25.0, -5.6),
    (20.0, -6.2),
    (16.0, -6.8),
    (12.5, -7.4),
    (10.0, -8.0),
    (8.0, -8.6),
    (6.3, -9.2),
    (5.0, -9.8),
    (4.0, -10.4),
    (3.15, -11.0),
];

/// Options of [`analyze`].
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Welch segment length, mm (≥ 1000; wavelengths up to a quarter of it are reported).
    pub segment_mm: f64,
    /// Apply spike removal.
    pub remove_spikes: bool,
    /// Apply curvature processing.
    pub curvature: bool,
    /// Wheel radius of the curvature processing, mm.
    pub wheel_radius_mm: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { segment_mm: MIN_SEGMENT_MM, remove_spikes: true, curvature: true, wheel_radius_mm: WHEEL_RADIUS_MM }
    }
}

/// The outcome of [`analyze`].
#[derive(Debug, Clone, PartialEq)]
pub struct Roughness {
    pub spectrum: Spectrum,
    /// Number of spikes removed.
    pub spikes_removed: usize,
}

/// A one-third-octave roughness spectrum.
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    pub dx_mm: f64,
    pub segment_mm: f64,
    /// Number of Welch segments averaged.
    pub segments: usize,
    /// Bands from long to short wavelength.
    pub bands: Vec<ThirdOctave>,
}

/// One one-third-octave band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThirdOctave {
    /// Band index: centre 10^(k/10) cycles/m.
    pub k: i32,
    pub centre_per_m: f64,
    /// Exact centre wavelength, mm.
    pub wavelength_mm: f64,
    /// Nominal (preferred-number) centre wavelength, mm: 400, 315, …, 10, 8, 6.3, …
    pub nominal_wavelength_mm: f64,
    /// Roughness level, dB re 1 µm.
    pub level_db: f64,
    /// The ISO 3095 limit for this band, where the table has one.
    pub iso3095_limit_db: Option<f64>,
    /// The instrument's noise floor in this band, dB re 1 µm, where it is
    /// known ([`crate::analyze::floor`]).
    pub floor_db: Option<f64>,
    /// Effective degrees of freedom of the level's estimate
    /// ([`welch_dof`]).
    pub dof: f64,
    /// Degrees of freedom of the floor's estimate.
    pub floor_dof: Option<f64>,
    /// The share of a rail component at the band's centre the band holds
    /// (the rest leaks into its neighbours through the Hann window: 0.67
    /// for a band one bin wide, near 1 from a few bins): the least the
    /// reading can make of the rail, which widens its upper bound ([`tone_capture`]).
    pub capture: f64,
}

impl ThirdOctave {
    /// Limit minus level, dB (negative: the reading, noise included, is over the limit).
    pub fn margin_db(&self) -> Option<f64> {
        self.iso3095_limit_db.map(|l| l - self.level_db)
    }

    /// The ISO 3095 decision ([`crate::analyze::standards::detection`]): the level and its degrees
    /// of freedom over the floor and its own, against the limit (`None`:
    /// no limit for this band).
    pub fn decision(&self) -> Option<Decision> {
        let limit = self.iso3095_limit_db?;
        let floor = self.floor_db.map(|f| Estimate { level_db: f, dof: self.floor_dof.unwrap_or(f64::INFINITY) });
        Some(Decision::of(Estimate { level_db: self.level_db, dof: self.dof }, floor, limit, self.capture))
    }

    /// The verdict alone (`None`: no limit).
    pub fn verdict(&self) -> Option<Verdict> {
        self.decision().map(|d| d.verdict)
    }

    /// The verdict in words: "EXCEEDS", "within", "not judged (floor …,
    /// limit …: what would settle it)" or "-" without a limit.
    pub fn verdict_words(&self) -> String {
        self.decision().map_or("-".into(), |d| d.words())
    }
}

/// Nominal wavelength (mm) of band `k`: the R10 preferred number nearest 10^(3 − k/10).
pub fn nominal_wavelength_mm(k: i32) -> f64 {
    const R10: [f64; 10] = [1.0, 1.25, 1.6, 2.0, 2.5, 3.15, 4.0, 5.0, 6.3, 8.0];
    let j = 30 - k;
    R10[j.rem_euclid(10) as usize] * 10f64.powi(j.div_euclid(10))
}

/// The ISO 3095 limit at a nominal wavelength, if the table has it.
pub fn iso3095_limit_db(nominal_wavelength_mm: f64) -> Option<f64> {
    ISO3095_LIMIT.iter().find(|(w, _)| (w - nominal_wavelength_mm).abs() < 1e-6 * w).map(|&(_, l)| l)
}

/// Full EN 15610 processing of a profile (heights µm, spacing mm, NaN for
/// gaps): spikes, curvature, spectrum, comparison.
pub fn analyze(z_um: &[f64], dx_mm: f64, opt: &Options) -> Result<Roughness, StandardsError> {
    let runs = segments(z_um);
    let mut welch = Welch::new(&runs, dx_mm, opt)?;
    let whole = Stretch { z_um, start: 0, core: 0..z_um.len(), runs: &runs, dx_mm };
    let spikes_removed = welch.add(&whole, opt);
    Ok(Roughness { spectrum: welch.spectrum(), spikes_removed })
}

/// The EN 15610 spectrum of a profile summed piece by piece ([`Stretch`]):
/// each piece processed (spikes, curvature) with its margin, and the
/// Welch segments that start in its core added in. Segments are placed
/// along each run from its start, as on the whole profile.
pub struct Welch {
    m: usize,
    dx_mm: f64,
    fft: std::sync::Arc<dyn rustfft::Fft<f64>>,
    window: Vec<f64>,
    window_power: f64,
    power: Vec<f64>,
    count: usize,
}

impl Welch {
    /// Checks the options against the profile's runs (the longest must
    /// hold a segment).
    pub fn new(runs: &[std::ops::Range<usize>], dx_mm: f64, opt: &Options) -> Result<Welch, StandardsError> {
        check_dx(dx_mm)?;
        if !(opt.wheel_radius_mm.is_finite() && opt.wheel_radius_mm > 0.0) {
            return Err(StandardsError::BadOption(format!(
                "wheel radius {} mm is not a positive finite number",
                opt.wheel_radius_mm
            )));
        }
        let longest = runs.iter().map(|r| r.len()).max().unwrap_or(0);
        let m = check_spectrum_args(longest, dx_mm, opt.segment_mm)?;
        let fft = FftPlanner::<f64>::new().plan_fft_forward(m);
        // Periodic Hann window.
        let window: Vec<f64> =
            (0..m).map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / m as f64).cos()).collect();
        let window_power: f64 = window.iter().map(|w| w * w).sum();
        Ok(Welch { m, dx_mm, fft, window, window_power, power: vec![0.0; m / 2 + 1], count: 0 })
    }

    /// How far beyond a core a stretch must reach, mm: a segment, and the
    /// wheel's reach and a spike's span on either side of it.
    pub fn margin_mm(opt: &Options) -> f64 {
        opt.segment_mm + 2.0 * opt.wheel_radius_mm + 100.0
    }

    /// Processes a stretch as `opt` says, the line taken as its own rail
    /// estimate (one line: no noise to tell it from), and adds the
    /// segments that start in its core; returns the spikes removed in the
    /// core.
    pub fn add(&mut self, s: &Stretch, opt: &Options) -> usize {
        self.add_corrected(s, &Correction::none(s.z_um.len()), opt)
    }

    /// Adds the segments that start in the stretch's core of the line
    /// with the nonlinear steps' `correction` of its rail estimate added
    /// (aligned with the stretch; where it has none, the line's own
    /// processing stands in); returns the spikes removed in the core.
    pub fn add_corrected(&mut self, s: &Stretch, correction: &Correction, opt: &Options) -> usize {
        let own_needed = s.z_um.iter().zip(&correction.c_um).any(|(z, c)| z.is_finite() && !c.is_finite());
        let own = own_needed.then(|| wheel::RailSteps::exact(self.dx_mm).correction(s.z_um, opt));
        let mut processed = s.z_um.to_vec();
        let mut spikes = 0;
        for (i, v) in processed.iter_mut().enumerate() {
            let (c, at) = match &own {
                Some(o) if !correction.c_um[i].is_finite() => (o.c_um[i], &o.spikes_at),
                _ => (correction.c_um[i], &correction.spikes_at),
            };
            if c.is_finite() {
                *v += c;
            }
            if at.binary_search(&i).is_ok() && s.core.contains(&(s.start + i)) {
                spikes += 1;
            }
        }
        let (m, hop) = (self.m, (self.m / 2).max(1));
        for run in s.runs {
            // Segments at run.start + k·hop, in the core, whole in the run and the stretch.
            let mut k = s.core.start.saturating_sub(run.start).div_ceil(hop);
            loop {
                let at = run.start + k * hop;
                if at >= s.core.end || at + m > run.end {
                    break;
                }
                if at >= s.start && at + m <= s.end() {
                    self.segment(&processed[at - s.start..at - s.start + m]);
                }
                k += 1;
            }
        }
        spikes
    }

    fn segment(&mut self, y: &[f64]) {
        let m = self.m;
        let mut seg = y.to_vec();
        remove_mean_and_trend(&mut seg);
        let mut buf: Vec<Complex<f64>> = seg.iter().zip(&self.window).map(|(v, w)| Complex::new(v * w, 0.0)).collect();
        self.fft.process(&mut buf);
        for (k, p) in self.power.iter_mut().enumerate() {
            // One-sided: every bin but DC and Nyquist stands for two.
            let two_sided = if k == 0 || 2 * k == m { 1.0 } else { 2.0 };
            *p += two_sided * buf[k].norm_sqr() / (m as f64 * self.window_power);
        }
        self.count += 1;
    }

    /// Segments added so far.
    pub fn segments(&self) -> usize {
        self.count
    }

    /// The one-third-octave spectrum of the segments added.
    pub fn spectrum(&self) -> Spectrum {
        let count_f = self.count.max(1) as f64;
        let power: Vec<f64> = self.power.iter().map(|p| p / count_f).collect();
        bands_of(&power, self.m, self.dx_mm, self.count)
    }
}

/// The energy average of spectra of one sampling and segment length (the
/// lines across the running band, as EN 15610 averages them): each band's
/// mean power over the spectra that have it; `None` without spectra.
pub fn energy_average(spectra: &[Spectrum]) -> Option<Spectrum> {
    let first = spectra.first()?;
    let mut out = first.clone();
    out.segments = spectra.iter().map(|s| s.segments).sum();
    for b in &mut out.bands {
        let same: Vec<&ThirdOctave> = spectra.iter().filter_map(|s| s.bands.iter().find(|o| o.k == b.k)).collect();
        let power: f64 = same.iter().map(|o| 10f64.powf(o.level_db / 10.0)).sum();
        b.level_db = 10.0 * (power / same.len() as f64).max(1e-30).log10();
        b.dof = same.iter().map(|o| o.dof).sum();
        b.floor_db = None;
        b.floor_dof = None;
    }
    Some(out)
}

fn check_spectrum_args(longest: usize, dx_mm: f64, segment_mm: f64) -> Result<usize, StandardsError> {
    check_dx(dx_mm)?;
    if dx_mm > MAX_DX_MM {
        return Err(StandardsError::SamplingTooCoarse {
            dx_mm,
            max_dx_mm: MAX_DX_MM,
            what: "the EN 15610 roughness spectrum".into(),
        });
    }
    if !(segment_mm.is_finite() && segment_mm >= MIN_SEGMENT_MM) {
        return Err(StandardsError::BadOption(format!(
            "EN 15610 segment length {segment_mm} mm: it must be at least {MIN_SEGMENT_MM} mm"
        )));
    }
    if longest == 0 {
        return Err(StandardsError::NoData);
    }
    let m = samples_for(segment_mm, dx_mm);
    if longest < m {
        return Err(StandardsError::TooShort {
            record_mm: run_mm(longest, dx_mm),
            window_mm: segment_mm,
            what: "the EN 15610 roughness spectrum (segments of at least 1 m)".into(),
        });
    }
    Ok(m)
}

/// Removes spikes in place (each continuous run on its own) and returns how
/// many were removed. See the module documentation for the criteria.
pub fn remove_spikes(z_um: &mut [f64], dx_mm: f64) -> usize {
    let mut at = Vec::new();
    remove_spikes_over(z_um, dx_mm, SpikeNoise::default(), &mut at);
    at.len()
}

/// The noise of a profile as the spike criterion sees it: standard
/// deviations, on noise alone, of a spike's height over the line joining
/// its edges and of the second difference.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SpikeNoise {
    pub height_um: f64,
    pub curvature_um_per_m2: f64,
}

/// [`remove_spikes`], a spike taken only where it stands over the
/// profile's `noise` ([`SpikeNoise`]; zero: every spike the standard's
/// criterion finds): its second difference under the criterion's by
/// [`SPIKE_EVIDENCE_Z`] of its noise, and its height over the line joining
/// its edges over that many of its noise — a spike that is the rail's,
/// not noise's nor the noise's push on a rounded crest. Each spike's peak
/// index pushed to `at`.
pub fn remove_spikes_over(z_um: &mut [f64], dx_mm: f64, noise: SpikeNoise, at: &mut Vec<usize>) {
    let gate = SpikeNoise {
        height_um: SPIKE_EVIDENCE_Z * noise.height_um.max(0.0),
        curvature_um_per_m2: SPIKE_CURVATURE_UM_PER_M2 - SPIKE_EVIDENCE_Z * noise.curvature_um_per_m2.max(0.0),
    };
    if check_dx(dx_mm).is_err() {
        return;
    }
    let dx_m = dx_mm / 1000.0;
    for run in segments(z_um) {
        let start = run.start;
        let y = &mut z_um[run];
        // Every removal flattens at least one sample that was a strict local
        // maximum onto a line, so passes are bounded by the samples; the cap
        // only guards against floating-point surprises.
        for _ in 0..y.len() {
            let before = at.len();
            spike_pass(y, dx_m, gate, &mut |i| at.push(start + i));
            if at.len() == before {
                break;
            }
        }
    }
}

/// One scan over a run; returns the number of spikes removed.
fn spike_pass(y: &mut [f64], dx_m: f64, gate: SpikeNoise, removed_at: &mut dyn FnMut(usize)) -> usize {
    let n = y.len();
    let slope = |y: &[f64], j: usize| (y[j + 1] - y[j]) / dx_m;
    let mut removed = 0;
    let mut i = 1;
    while i + 1 < n {
        let left = slope(y, i - 1);
        let right = slope(y, i);
        let d2 = (right - left) / dx_m;
        if !(d2 < gate.curvature_um_per_m2 && left >= 0.0 && right <= 0.0) {
            i += 1;
            continue;
        }
        let mut l = i - 1;
        while l > 0 && slope(y, l - 1).abs() >= SPIKE_EDGE_SLOPE_UM_PER_M {
            l -= 1;
        }
        let mut r = i + 1;
        while r + 1 < n && slope(y, r).abs() >= SPIKE_EDGE_SLOPE_UM_PER_M {
            r += 1;
        }
        let span = (r - l) as f64;
        let base = y[l] + (y[r] - y[l]) * (i - l) as f64 / span;
        let h_m = (y[i] - base) * 1e-6;
        let w_m = span * dx_m;
        if h_m > w_m * w_m / SPIKE_A_M && h_m * 1e6 > gate.height_um {
            let (yl, yr) = (y[l], y[r]);
            for (t, v) in y[l + 1..r].iter_mut().enumerate() {
                *v = yl + (yr - yl) * (t + 1) as f64 / span;
            }
            removed += 1;
            removed_at(i);
            i = r;
        } else {
            i += 1;
        }
    }
    removed
}

/// Curvature processing (EN 15610 §7.3 as read in docs/corrugation-and-standards.md):
/// the path of the centre of a wheel of radius `radius_mm` rolled along
/// the record, less the radius — at every sample `x_i`,
/// `r′(x_i) = max_k [r(x_k) − (R − √(R² − (x_k − x_i)²))]` over the samples
/// `x_k` of the run (the wheel's lowest point when its centre is above
/// `x_i`). Each continuous run on its own; NaN stays NaN. Heights µm,
/// spacing mm.
///
/// A dip narrower than the wheel is bridged at the height where the wheel
/// rests on its rims; a smooth profile is raised by about `R·r′²/2` where
/// it slopes (the wheel touches beside the sample), which puts a little of
/// a large corrugation's power into its second harmonic — that is what the
/// wheel, and the standard's processing, do.
pub fn curvature_process(z_um: &[f64], dx_mm: f64, radius_mm: f64) -> Vec<f64> {
    let mut out = z_um.to_vec();
    if check_dx(dx_mm).is_err() || !(radius_mm.is_finite() && radius_mm > 0.0) {
        return out;
    }
    let r_um = radius_mm * 1000.0;
    let dx_um = dx_mm * 1000.0;
    for run in segments(z_um) {
        let y = &z_um[run.clone()];
        let n = y.len();
        let (lo, hi) = y.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        let range = hi - lo;
        // A sample farther than where the wheel's sagitta exceeds the run's
        // height range cannot raise anything: s² > 2R·range − range².
        let reach_um = if range < r_um { (2.0 * r_um * range - range * range).max(0.0).sqrt() } else { r_um };
        let reach = ((reach_um / dx_um).ceil()).min((r_um / dx_um).floor()).min((n - 1) as f64).max(0.0) as usize;
        let sag: Vec<f64> = (0..=reach)
            .map(|t| {
                let s = t as f64 * dx_um;
                r_um - (r_um * r_um - s * s).max(0.0).sqrt()
            })
            .collect();
        for (i, o) in out[run.clone()].iter_mut().enumerate() {
            let (first, last) = (i.saturating_sub(reach), (i + reach).min(n - 1));
            *o = (first..=last).map(|k| y[k] - sag[k.abs_diff(i)]).fold(f64::NEG_INFINITY, f64::max);
        }
    }
    out
}

/// The one-third-octave spectrum of a profile as it is (no spike removal
/// or curvature processing): heights µm, spacing mm, NaN for gaps.
pub fn third_octave_spectrum(z_um: &[f64], dx_mm: f64, segment_mm: f64) -> Result<Spectrum, StandardsError> {
    let runs = segments(z_um);
    let opt = Options { segment_mm, remove_spikes: false, curvature: false, ..Options::default() };
    let mut welch = Welch::new(&runs, dx_mm, &opt)?;
    welch.add(&Stretch { z_um, start: 0, core: 0..z_um.len(), runs: &runs, dx_mm }, &opt);
    Ok(welch.spectrum())
}

/// The one-third-octave bands of a mean one-sided power spectrum of
/// segments of `m` samples.
fn bands_of(power: &[f64], m: usize, dx_mm: f64, count: usize) -> Spectrum {
    let df = 1000.0 / (m as f64 * dx_mm); // cycles/m
    let nyquist = 500.0 / dx_mm;
    let seg_len_mm = m as f64 * dx_mm;
    let k_lo = (10.0 * (4000.0 / seg_len_mm).log10()).floor() as i32 - 1;
    let k_hi = (10.0 * nyquist.log10()).ceil() as i32 + 1;
    let mut bands = Vec::new();
    for k in k_lo..=k_hi {
        let centre = 10f64.powf(k as f64 / 10.0);
        let (f_lo, f_hi) = (centre * 10f64.powf(-0.05), centre * 10f64.powf(0.05));
        let nominal = nominal_wavelength_mm(k);
        if nominal > seg_len_mm / 4.0 * (1.0 + 1e-9) || f_hi > nyquist * (1.0 + 1e-9) {
            continue;
        }
        let ms_um2 = band_power(power, df, f_lo, f_hi);
        bands.push(ThirdOctave {
            k,
            centre_per_m: centre,
            wavelength_mm: 1000.0 / centre,
            nominal_wavelength_mm: nominal,
            level_db: 10.0 * ms_um2.max(1e-30).log10(),
            iso3095_limit_db: iso3095_limit_db(nominal),
            floor_db: None,
            dof: welch_dof((f_hi - f_lo) / df, count),
            floor_dof: None,
            capture: tone_capture(df, f_lo, f_hi, centre),
        });
    }
    Spectrum { dx_mm, segment_mm: seg_len_mm, segments: count, bands }
}

/// The share of a sine at `centre` (cycles/m) that the band `f_lo`–`f_hi`
/// holds in a Welch spectrum of periodic Hann segments (bin width `df`):
/// the window spreads a sine over its bins as `|W(d)|²`,
/// `W(d) = sinc(d) / (1 − d²)` at `d` bins off, which sums to 1.5 over all
/// bins; the band takes each bin in proportion to its overlap, as `band_power` does.
pub fn tone_capture(df: f64, f_lo: f64, f_hi: f64, centre: f64) -> f64 {
    let x = centre / df;
    let w2 = |d: f64| -> f64 {
        if d.abs() < 1e-9 {
            return 1.0;
        }
        if (d.abs() - 1.0).abs() < 1e-9 {
            return 0.25;
        }
        let s = (std::f64::consts::PI * d).sin() / (std::f64::consts::PI * d);
        (s / (1.0 - d * d)).powi(2)
    };
    let (first, last) = ((f_lo / df).floor() as i64 - 4, (f_hi / df).ceil() as i64 + 4);
    let held: f64 = (first.max(0)..=last)
        .map(|k| {
            let (a, b) = ((k as f64 - 0.5) * df, (k as f64 + 0.5) * df);
            let overlap = (b.min(f_hi) - a.max(f_lo)).max(0.0) / df;
            w2(k as f64 - x) * overlap
        })
        .sum();
    (held / 1.5).clamp(0.05, 1.0)
}

/// Sum of the bins' power between `f_lo` and `f_hi`, a bin (width `df`,
/// centred on k·df) counted in proportion to its overlap with the band.
fn band_power(power: &[f64], df: f64, f_lo: f64, f_hi: f64) -> f64 {
    let first = ((f_lo / df - 0.5).floor().max(0.0) as usize).min(power.len());
    let last = ((f_hi / df + 0.5).ceil().max(0.0) as usize).min(power.len().saturating_sub(1));
    (first..=last)
        .filter_map(|k| power.get(k).map(|p| (k, p)))
        .map(|(k, p)| {
            let (a, b) = ((k as f64 - 0.5) * df, (k as f64 + 0.5) * df);
            let overlap = (b.min(f_hi) - a.max(f_lo)).max(0.0) / df;
            p * overlap
        })
        .sum()
}

/// The spectrum as CSV, one line per band, long wavelengths first:
/// `k,centre_per_m,wavelength_mm,nominal_wavelength_mm,level_db,iso3095_limit_db,margin_db,floor_db,rail_db,rail_lo_db,rail_hi_db,verdict`
/// (limit, margin and the decision's columns empty where ISO 3095 has no
/// value; `floor_db` empty where the floor is not known; `rail_db` the
/// level with the floor's power taken out and its interval
/// ([`crate::analyze::standards::detection`]), empty where the reading is at or under the floor or
/// a bound is open; `verdict` `within`, `EXCEEDS` or `not judged`).
pub fn spectrum_csv(s: &Spectrum) -> String {
    let mut out = String::from(
        "k,centre_per_m,wavelength_mm,nominal_wavelength_mm,level_db,iso3095_limit_db,margin_db,floor_db,rail_db,rail_lo_db,rail_hi_db,verdict\n",
    );
    let opt = |v: Option<f64>, digits: usize| v.map_or(String::new(), |v| format!("{v:.digits$}"));
    for b in &s.bands {
        let d = b.decision();
        let _ = writeln!(
            out,
            "{},{:.4},{:.4},{},{:.2},{},{},{},{},{},{},{}",
            b.k,
            b.centre_per_m,
            b.wavelength_mm,
            fmt_nominal_mm(b.nominal_wavelength_mm),
            b.level_db,
            opt(b.iso3095_limit_db, 1),
            opt(b.margin_db(), 2),
            opt(b.floor_db, 2),
            opt(d.as_ref().and_then(|d| d.rail.db), 2),
            opt(d.as_ref().and_then(|d| d.rail.lo_db), 2),
            opt(d.as_ref().and_then(|d| d.rail.hi_db), 2),
            d.map_or("", |d| d.verdict.name()),
        );
    }
    out
}

/// The spectrum against the ISO 3095 limit as a plain-text table: each
/// band's reading, its floor, the rail with the floor taken out and its
/// interval, the limit and the verdict.
pub fn spectrum_table(r: &Roughness) -> String {
    let s = &r.spectrum;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "EN 15610 roughness, one-third octaves (dB re 1 µm): {} segment(s) of {} mm, sampling {} mm, {} spike(s) removed",
        s.segments,
        fmt_mm(s.segment_mm),
        s.dx_mm,
        r.spikes_removed
    );
    let _ = writeln!(
        out,
        "{:>14} {:>9} {:>9} {:>26} {:>10}  verdict",
        "wavelength_mm",
        "level_db",
        "floor_db",
        format!("rail_db [{}% interval]", super::detection::CONFIDENCE_PERCENT),
        "limit_db"
    );
    let dash = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
    for b in &s.bands {
        let d = b.decision();
        let _ = writeln!(
            out,
            "{:>14} {:>9.1} {:>9} {:>26} {:>10}  {}",
            fmt_nominal_mm(b.nominal_wavelength_mm),
            b.level_db,
            dash(b.floor_db),
            d.as_ref().map_or("-".into(), |d| d.rail.to_string()),
            dash(b.iso3095_limit_db),
            d.map_or("-".into(), |d| d.words())
        );
    }
    out
}
