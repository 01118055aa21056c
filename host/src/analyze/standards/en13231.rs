//! EN 13231-3 wavelength-band analysis of a longitudinal profile: the
//! profile band-pass filtered into 10–30, 30–100, 100–300 and 300–1000 mm,
//! the peak-to-peak of each band in moving windows, and the share of the
//! length over the limit.
//!
//! # Criteria
//!
//! [`BANDS`] holds the **2006-style criteria as a secondary source gives
//! them** (not checked against the standard's text): windows of 600 / 600 /
//! 1000 / 5000 mm, mean peak-to-peak limits 0.02 / 0.02 / 0.03 / 0.15 mm, at
//! most [`MAX_EXCEEDING_PERCENT`] of the length exceeding. The 2012 edition's
//! Class 1 limit for 30–100 mm, ±0.010 mm on the band-filtered displacement,
//! is evaluated too ([`Band::abs_limit_mm`]).
//!
//! # Filter
//!
//! Each band is a 6th-order Butterworth high-pass (at the band's longest
//! wavelength) followed by a 6th-order Butterworth low-pass (at its shortest),
//! both bilinear-transformed biquads run **forward and backward**, so the
//! result has zero phase (peaks stay where they are on the rail) and a
//! magnitude response of |H|², with 12th-order skirts. The cut-offs are
//! placed so that the forward–backward response is −3 dB (amplitude 1/√2)
//! exactly at the band edges: a sine at an edge splits its power evenly
//! between the two neighbouring bands. A 50 mm sine keeps 99.9 % of its
//! amplitude in 30–100 mm and leaves 0.5 % in 10–30 mm and < 0.1 % in
//! 100–300 mm (see the tests); in the interior it agrees with scipy's
//! `butter` + `sosfiltfilt` of the same design to 2e-7 µm
//! (`tests/scripts/standards_reference.py`). An FFT brick-wall filter would have no skirts
//! but rings over the whole record (its impulse response decays as 1/x);
//! the IIR pair is local.
//!
//! **Edges.** Each continuous run is extended at both ends by point
//! reflection (`2·z₀ − z₋ᵢ`, continuous in value and slope) over twice the
//! band's longest wavelength and the filters start in their steady state
//! for the first value. That still cannot know how the rail goes on: a sine
//! cut off at an arbitrary phase leaves transients of up to 40 % of its
//! amplitude in the neighbouring bands near the end, decaying to ≤ 1 % at
//! two longest wavelengths. So [`EDGE_WAVELENGTHS`] × the longest wavelength
//! at each run end ([`BandResult::edge_mm`]: 60 / 200 / 600 / 2000 mm) is
//! **left out of the window statistics** (the band values are still
//! returned there), and a band needs a run of its window plus both edge
//! zones: 720 / 1000 / 2200 / 9000 mm. That is the cost of a filter that
//! does not invent the rail beyond the record.
//!
//! **Bands the sampling cannot resolve.** A band needs at least two samples
//! per shortest wavelength; otherwise its result is
//! [`StandardsError::SamplingTooCoarse`].
//!
//! # Moving windows
//!
//! A window of the band's length is placed at every sample of every
//! continuous run where it fits whole between the edge zones. In each window:
//! * `max_pp` — the largest minus the smallest band value;
//! * `mean_pp` — the mean of the peak-to-peak heights of the half-waves
//!   (consecutive local extremum to extremum) wholly inside the window, the
//!   criterion's quantity (`max_pp` when no half-wave is whole inside).
//!
//! The exceedance is the share of window positions whose `mean_pp` is over
//! the limit, i.e. of the length of rail (one position per sample). A band
//! whose window and edge zones do not fit in the longest run gets
//! [`StandardsError::TooShort`] ("record 450 mm is too short for the 600 mm
//! window of the 10–30 mm band (plus 60 mm of filter settling at each
//! end)"); the other bands are still evaluated.

use std::collections::VecDeque;
use std::fmt::Write as _;

use super::{StandardsError, Stretch, check_dx, fmt_mm, run_mm, samples_for, segments};

/// One EN 13231-3 wavelength band and its criteria.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Shortest wavelength of the band, mm.
    pub lo_mm: f64,
    /// Longest wavelength of the band, mm.
    pub hi_mm: f64,
    /// Moving-window length, mm.
    pub window_mm: f64,
    /// Limit of the mean peak-to-peak in a window, mm (2006-style, secondary source).
    pub mean_pp_limit_mm: f64,
    /// Limit of |band-filtered displacement|, mm, where one is given (2012 Class 1).
    pub abs_limit_mm: Option<f64>,
}

impl Band {
    /// "10–30 mm band".
    pub fn name(&self) -> String {
        format!("{}–{} mm band", fmt_mm(self.lo_mm), fmt_mm(self.hi_mm))
    }
}

/// The four bands with the 2006-style criteria (secondary source) and the
/// 2012 Class 1 ±0.010 mm limit for 30–100 mm.
pub const BANDS: [Band; 4] = [
    Band { lo_mm: 10.0, hi_mm: 30.0, window_mm: 600.0, mean_pp_limit_mm: 0.02, abs_limit_mm: None },
    Band { lo_mm: 30.0, hi_mm: 100.0, window_mm: 600.0, mean_pp_limit_mm: 0.02, abs_limit_mm: Some(0.010) },
    Band { lo_mm: 100.0, hi_mm: 300.0, window_mm: 1000.0, mean_pp_limit_mm: 0.03, abs_limit_mm: None },
    Band { lo_mm: 300.0, hi_mm: 1000.0, window_mm: 5000.0, mean_pp_limit_mm: 0.15, abs_limit_mm: None },
];

/// Which edition's criterion judges a position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Edition {
    /// EN 13231-3:2006: moving-window mean peak-to-peak, share of length exceeding.
    #[default]
    En2006,
    /// EN 13231-3:2012: isolated points, |band displacement| over the Class 1 limit.
    En2012,
}

impl Edition {
    /// "EN 13231-3:2006".
    pub fn name(self) -> &'static str {
        match self {
            Edition::En2006 => "EN 13231-3:2006",
            Edition::En2012 => "EN 13231-3:2012",
        }
    }

    /// Where the limits come from, as every report states it.
    pub fn source(self) -> &'static str {
        match self {
            Edition::En2006 => {
                "moving-window mean peak-to-peak limits 0.02 / 0.02 / 0.03 / 0.15 mm over windows of \
                 600 / 600 / 1000 / 5000 mm, at most 5 % of the length exceeding: a secondary source's \
                 account of the 2006 criteria (not checked against the standard's text)"
            }
            Edition::En2012 => {
                "isolated points: |band-filtered displacement| over ±0.010 mm in 30–100 mm (Class 1), as \
                 trade documentation quotes the 2012 edition (not checked against the standard's text); \
                 no 2012 limit is known to this build for the other bands"
            }
        }
    }

    /// The limit a band is judged against under this edition (mm), if any.
    pub fn limit_mm(self, band: &Band) -> Option<f64> {
        match self {
            Edition::En2006 => Some(band.mean_pp_limit_mm),
            Edition::En2012 => band.abs_limit_mm,
        }
    }
}

/// At most this share of the length may exceed the mean peak-to-peak limit
/// (2006-style, secondary source).
pub const MAX_EXCEEDING_PERCENT: f64 = 5.0;

/// Edge zone of each run end, in the band's longest wavelengths: excluded
/// from the window statistics (measured: a 50 mm sine cut off at an
/// arbitrary phase leaves ≤ 1 % of its amplitude in the neighbouring bands
/// beyond it, up to 40 % within the first longest wavelength).
pub const EDGE_WAVELENGTHS: f64 = 2.0;

/// Butterworth order of each of the high-pass and low-pass filters (the
/// forward–backward pass doubles it in magnitude).
pub const ORDER: usize = 6;

/// The ratio of a band's filter cut-off to its edge frequency, `(√2 − 1)^(1/2N)`:
/// forward–backward gives `|H|² = 1/(1 + (f/fc)^(2N))`, 3 dB down at the
/// edge where `(f/fc)^(2N) = √2 − 1`. The high-pass cuts at `shift / hi`,
/// the low-pass at `1 / (lo · shift)`.
pub fn edge_shift() -> f64 {
    (std::f64::consts::SQRT_2 - 1.0).powf(1.0 / (2.0 * ORDER as f64))
}

/// The whole analysis of one profile.
#[derive(Debug, Clone, PartialEq)]
pub struct BandAnalysis {
    pub dx_mm: f64,
    /// Length of the longest continuous run, mm (what "too short" is judged on).
    pub record_mm: f64,
    /// Total length of finite samples, mm.
    pub finite_mm: f64,
    /// Number of continuous runs (1 when there are no gaps).
    pub runs: usize,
    /// Number of input samples (finite or not).
    pub samples: usize,
    /// One result per entry of [`BANDS`], in order.
    pub bands: Vec<BandResult>,
}

/// One band's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct BandResult {
    pub band: Band,
    /// Within this distance of a run's ends the band values carry filter edge
    /// effects; no window reaches into it, mm.
    pub edge_mm: f64,
    pub outcome: Result<BandStats, StandardsError>,
}

/// One band's figures.
#[derive(Debug, Clone, PartialEq)]
pub struct BandStats {
    /// Number of window positions evaluated.
    pub windows: usize,
    /// Mean over the window positions of the mean peak-to-peak, mm.
    pub average_mean_pp_mm: f64,
    /// Largest mean peak-to-peak of a window, mm.
    pub worst_mean_pp_mm: f64,
    /// Largest max − min of a window, mm.
    pub worst_max_pp_mm: f64,
    /// RMS of the band-filtered profile where the filters have settled
    /// (where the window statistics are: a run's edge zones left out), mm.
    pub rms_mm: f64,
    /// Share of window positions whose mean peak-to-peak exceeds the limit, %.
    pub exceeding_percent: f64,
    /// Length over the limit (one sample spacing per exceeding window), mm.
    pub exceeding_mm: f64,
    /// `exceeding_percent ≤ MAX_EXCEEDING_PERCENT`.
    pub passes: bool,
    /// With [`Band::abs_limit_mm`]: share of samples whose |band value| exceeds it, %.
    pub abs_exceeding_percent: Option<f64>,
}

/// One band along a stretch's core, aligned with it: what the figures
/// are made of, and what plots and exports show.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BandTrace {
    /// The band-filtered profile, mm (NaN in gaps).
    pub band_mm: Vec<f64>,
    /// Mean peak-to-peak of the window centred on each sample, mm (NaN where no whole window fits).
    pub mean_pp_mm: Vec<f64>,
    /// Max − min of the window centred on each sample, mm (NaN where no whole window fits).
    pub max_pp_mm: Vec<f64>,
}

impl BandTrace {
    /// The trace over `range` of its samples (cut to its length).
    pub fn within(&self, range: std::ops::Range<usize>) -> BandTrace {
        let cut = |v: &[f64]| v[range.start.min(v.len())..range.end.min(v.len())].to_vec();
        BandTrace { band_mm: cut(&self.band_mm), mean_pp_mm: cut(&self.mean_pp_mm), max_pp_mm: cut(&self.max_pp_mm) }
    }
}

/// A band's figures summed over the pieces of a profile, in any order.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BandSums {
    windows: usize,
    exceeding: usize,
    sum_mean_mm: f64,
    worst_mean_mm: f64,
    worst_max_mm: f64,
    sq_mm2: f64,
    count: usize,
    abs_over: usize,
}

impl BandSums {
    /// Adds a piece's trace of `band`.
    pub fn add(&mut self, band: &Band, t: &BandTrace) {
        self.add_over(band, t, band.mean_pp_limit_mm);
    }

    /// [`BandSums::add`], a window exceeding where its mean peak-to-peak
    /// is over `threshold_mm` (the limit with a noise floor's power added:
    /// `crate::analyze::floor::BandFloor::threshold_mm`).
    pub fn add_over(&mut self, band: &Band, t: &BandTrace, threshold_mm: f64) {
        for (v, mn) in t.band_mm.iter().zip(&t.mean_pp_mm).filter(|(v, _)| v.is_finite()) {
            // The RMS where the filters have settled (the windows' part): at a
            // run's ends the point reflection over one sample puts a step's
            // worth of the band's long wavelengths into noise.
            if !mn.is_finite() {
                continue;
            }
            self.sq_mm2 += v * v;
            self.count += 1;
            if band.abs_limit_mm.is_some_and(|lim| v.abs() > lim) {
                self.abs_over += 1;
            }
        }
        for (&mn, &mx) in t.mean_pp_mm.iter().zip(&t.max_pp_mm) {
            if !mn.is_finite() {
                continue;
            }
            self.windows += 1;
            self.sum_mean_mm += mn;
            self.worst_mean_mm = self.worst_mean_mm.max(mn);
            self.worst_max_mm = self.worst_max_mm.max(mx);
            if mn > threshold_mm {
                self.exceeding += 1;
            }
        }
    }

    /// Adds the sums of other pieces.
    pub fn merge(&mut self, o: &BandSums) {
        self.windows += o.windows;
        self.exceeding += o.exceeding;
        self.sum_mean_mm += o.sum_mean_mm;
        self.worst_mean_mm = self.worst_mean_mm.max(o.worst_mean_mm);
        self.worst_max_mm = self.worst_max_mm.max(o.worst_max_mm);
        self.sq_mm2 += o.sq_mm2;
        self.count += o.count;
        self.abs_over += o.abs_over;
    }

    /// Window positions summed.
    pub fn windows(&self) -> usize {
        self.windows
    }

    /// The band's figures.
    pub fn stats(&self, band: &Band, dx_mm: f64) -> BandStats {
        // A band is evaluated only where its window fits: at least one window.
        let windows_f = self.windows.max(1) as f64;
        let exceeding_percent = 100.0 * self.exceeding as f64 / windows_f;
        BandStats {
            windows: self.windows,
            average_mean_pp_mm: self.sum_mean_mm / windows_f,
            worst_mean_pp_mm: self.worst_mean_mm,
            worst_max_pp_mm: self.worst_max_mm,
            rms_mm: (self.sq_mm2 / self.count.max(1) as f64).sqrt(),
            exceeding_percent,
            exceeding_mm: self.exceeding as f64 * dx_mm,
            passes: exceeding_percent <= MAX_EXCEEDING_PERCENT,
            abs_exceeding_percent: band.abs_limit_mm.map(|_| 100.0 * self.abs_over as f64 / self.count.max(1) as f64),
        }
    }
}

/// What a profile's runs say about it before any filtering: the figures
/// of [`BandAnalysis`] that are not sums, and whether each band can be
/// evaluated (its window and edge zones fit the longest run, its sampling).
pub fn plan(runs: &[std::ops::Range<usize>], samples: usize, dx_mm: f64) -> Result<BandAnalysis, StandardsError> {
    check_dx(dx_mm)?;
    if runs.is_empty() {
        return Err(StandardsError::NoData);
    }
    let longest = runs.iter().map(|r| r.len()).max().unwrap_or(0);
    let finite: usize = runs.iter().map(|r| r.len()).sum();
    let bands = BANDS
        .iter()
        .map(|band| {
            let edge_mm = EDGE_WAVELENGTHS * band.hi_mm;
            BandResult {
                band: *band,
                edge_mm,
                outcome: fits(band, dx_mm, longest).map(|()| BandSums::default().stats(band, dx_mm)),
            }
        })
        .collect();
    Ok(BandAnalysis {
        dx_mm,
        record_mm: run_mm(longest, dx_mm),
        finite_mm: run_mm(finite, dx_mm),
        runs: runs.len(),
        samples,
        bands,
    })
}

/// Whether `band` can be evaluated at `dx_mm` on a longest run of `longest` samples.
fn fits(band: &Band, dx_mm: f64, longest: usize) -> Result<(), StandardsError> {
    let w = samples_for(band.window_mm, dx_mm);
    let edge_mm = EDGE_WAVELENGTHS * band.hi_mm;
    let e = samples_for(edge_mm, dx_mm);
    if longest < w.saturating_add(e.saturating_mul(2)) {
        return Err(StandardsError::TooShort {
            record_mm: run_mm(longest, dx_mm),
            window_mm: band.window_mm,
            what: format!("the {} (plus {} mm of filter settling at each end)", band.name(), fmt_mm(edge_mm)),
        });
    }
    if dx_mm > band.lo_mm / 2.0 {
        return Err(StandardsError::SamplingTooCoarse {
            dx_mm,
            max_dx_mm: band.lo_mm / 2.0,
            what: format!("the {}–{} mm band", fmt_mm(band.lo_mm), fmt_mm(band.hi_mm)),
        });
    }
    Ok(())
}

/// How far beyond a piece's core a stretch must reach for its band values
/// and windows there to be those of the whole profile, mm: half the
/// longest window, and [`SETTLE_WAVELENGTHS`] of the band's longest
/// wavelength for the filters to forget where the stretch was cut.
pub fn margin_mm() -> f64 {
    BANDS.iter().map(|b| b.window_mm / 2.0 + SETTLE_WAVELENGTHS * b.hi_mm).fold(0.0, f64::max)
}

/// Filter settling beyond a cut, in the band's longest wavelengths. The
/// slowest pole of the 6th-order high-pass (Q = 1.93) decays by e every
/// 0.61 of its cut-off wavelength: after 20 wavelengths a transient is
/// down by e^-32; the figures of a line judged in pieces equal those of
/// the whole line to 1e-7 of their value (`pieces_equal_the_whole_line`
/// in `analyze::pieces`).
pub const SETTLE_WAVELENGTHS: f64 = 20.0;

/// Analyses a profile (heights µm, spacing mm, NaN for gaps) in all four
/// bands. Fails only when the spacing is not usable or nothing is finite;
/// a band that cannot be evaluated carries its own error.
pub fn analyze(z_um: &[f64], dx_mm: f64) -> Result<BandAnalysis, StandardsError> {
    analyze_traced(z_um, dx_mm).map(|(a, _)| a)
}

/// [`analyze`], with each band's trace along the whole profile (`None`
/// where the band is not evaluated).
pub fn analyze_traced(z_um: &[f64], dx_mm: f64) -> Result<(BandAnalysis, Vec<Option<BandTrace>>), StandardsError> {
    let runs = segments(z_um);
    let mut a = plan(&runs, z_um.len(), dx_mm)?;
    let whole = Stretch { z_um, start: 0, core: 0..z_um.len(), runs: &runs, dx_mm };
    let mut traces = Vec::new();
    for r in &mut a.bands {
        let t = match r.outcome {
            Ok(_) => Some(trace(&whole, &r.band)?),
            Err(_) => None,
        };
        if let (Some(t), Ok(st)) = (&t, &mut r.outcome) {
            let mut sums = BandSums::default();
            sums.add(&r.band, t);
            *st = sums.stats(&r.band, dx_mm);
        }
        traces.push(t);
    }
    Ok((a, traces))
}

/// One band along a stretch's core: the band-filtered values, and the
/// window statistics of the windows centred there that fit whole inside
/// the settled part of their run (the edge zones of the run's own ends
/// left out, not the stretch's). The stretch must reach [`margin_mm`]
/// beyond the core where the profile goes on; windows it cannot hold are
/// left NaN.
pub fn trace(s: &Stretch, band: &Band) -> Result<BandTrace, StandardsError> {
    let dx_mm = s.dx_mm;
    let w = samples_for(band.window_mm, dx_mm);
    let e = samples_for(EDGE_WAVELENGTHS * band.hi_mm, dx_mm);
    let band_um = band_pass(s.z_um, dx_mm, band.lo_mm, band.hi_mm)?;
    let band_mm: Vec<f64> = band_um.iter().map(|v| v / 1000.0).collect();
    let (c0, c1) = (s.core.start, s.core.end);
    let n = c1 - c0;
    let mut mean_pp_mm = vec![f64::NAN; n];
    let mut max_pp_mm = vec![f64::NAN; n];
    for run in s.runs {
        if run.len() < w + 2 * e {
            continue;
        }
        // Window `a` of the run covers its samples start+e+a .. +w and is
        // centred on start+e+a+w/2; those centred in the core, and held by the stretch.
        let first = run.start + e;
        let last_a = run.len() - 2 * e - w;
        let a_lo = c0.saturating_sub(w / 2).max(first).max(s.start) - first;
        let a_hi = (c1.saturating_sub(1 + w / 2)).min(s.end().saturating_sub(w)).saturating_sub(first).min(last_a);
        if c1 < 1 + w / 2 + first || a_lo > a_hi || s.end() < first + a_hi + w {
            continue;
        }
        // Two samples of the run before the first window, so that an
        // extremum on its first sample is seen as the whole run sees it.
        let lead = a_lo.min(2).min(first + a_lo - s.start.max(first));
        let from = first + a_lo - lead - s.start;
        let y = &band_mm[from..first + a_hi + w - s.start];
        let maxpp = moving_max_minus_min(y, w);
        let meanpp = moving_mean_pp(y, w, &maxpp);
        for (k, (&mx, &mn)) in maxpp.iter().zip(&meanpp).enumerate().skip(lead) {
            let centre = first + a_lo + (k - lead) + w / 2;
            if (c0..c1).contains(&centre) {
                max_pp_mm[centre - c0] = mx;
                mean_pp_mm[centre - c0] = mn;
            }
        }
    }
    Ok(BandTrace { band_mm: band_mm[c0 - s.start..c1 - s.start].to_vec(), mean_pp_mm, max_pp_mm })
}

/// Zero-phase band-pass of a profile between wavelengths `lo_mm` and `hi_mm`
/// (−3 dB at both), each continuous run on its own; NaN stays NaN. Units out
/// are those in.
pub fn band_pass(z: &[f64], dx_mm: f64, lo_mm: f64, hi_mm: f64) -> Result<Vec<f64>, StandardsError> {
    check_dx(dx_mm)?;
    if !(lo_mm.is_finite() && hi_mm.is_finite() && lo_mm > 0.0 && hi_mm > lo_mm) {
        return Err(StandardsError::BadOption(format!("band {lo_mm}–{hi_mm} mm is not a band of wavelengths")));
    }
    if dx_mm > lo_mm / 2.0 {
        return Err(StandardsError::SamplingTooCoarse {
            dx_mm,
            max_dx_mm: lo_mm / 2.0,
            what: format!("the {}–{} mm band", fmt_mm(lo_mm), fmt_mm(hi_mm)),
        });
    }
    let shift = edge_shift();
    // Normalised angular cut-offs (radians per sample).
    let w_hp = 2.0 * std::f64::consts::PI * dx_mm / hi_mm * shift;
    let w_lp = 2.0 * std::f64::consts::PI * dx_mm / lo_mm / shift;
    let mut sections = butterworth(w_hp, false);
    // Near Nyquist the sampling itself is the low-pass (the bilinear
    // transform cannot place a cut-off at or beyond π).
    if w_lp < 0.95 * std::f64::consts::PI {
        sections.extend(butterworth(w_lp, true));
    }
    let pad_samples = samples_for(2.0 * hi_mm, dx_mm);
    let mut out = vec![f64::NAN; z.len()];
    for run in segments(z) {
        let y = filtfilt(&z[run.clone()], &sections, pad_samples);
        out[run].copy_from_slice(&y);
    }
    Ok(out)
}

/// A biquad, normalised (a0 = 1): `[b0, b1, b2, a1, a2]`.
type Biquad = [f64; 5];

/// A Butterworth filter of order [`ORDER`] with cut-off `w0` (rad/sample)
/// as biquads: each analogue second-order section bilinear-transformed with
/// pre-warping at `w0` (the "audio EQ cookbook" forms), Q_k = 1/(2 sin((2k−1)π/2N)).
fn butterworth(w0: f64, low_pass: bool) -> Vec<Biquad> {
    let (s, c) = w0.sin_cos();
    (1..=ORDER / 2)
        .map(|k| {
            let q = 1.0 / (2.0 * ((2 * k - 1) as f64 * std::f64::consts::PI / (2 * ORDER) as f64).sin());
            let alpha = s / (2.0 * q);
            let a0 = 1.0 + alpha;
            let (b0, b1) = if low_pass { ((1.0 - c) / 2.0, 1.0 - c) } else { ((1.0 + c) / 2.0, -(1.0 + c)) };
            [b0 / a0, b1 / a0, b0 / a0, -2.0 * c / a0, (1.0 - alpha) / a0]
        })
        .collect()
}

/// Runs the cascade over `x` forward and backward, the ends extended by
/// point reflection over `pad` samples and each section started in its
/// steady state for the first value it sees.
fn filtfilt(x: &[f64], sections: &[Biquad], pad: usize) -> Vec<f64> {
    let n = x.len();
    if n < 2 {
        // A single sample has no wavelength in any band.
        return vec![0.0; n];
    }
    let p = pad.min(n - 1);
    let mut ext = Vec::with_capacity(n + 2 * p);
    ext.extend((1..=p).rev().map(|i| 2.0 * x[0] - x[i]));
    ext.extend_from_slice(x);
    ext.extend((1..=p).map(|i| 2.0 * x[n - 1] - x[n - 1 - i]));
    run_cascade(&mut ext, sections);
    ext.reverse();
    run_cascade(&mut ext, sections);
    ext.reverse();
    ext[p..p + n].to_vec()
}

/// Transposed direct form II, in place, from the steady state for `y[0]`.
fn run_cascade(y: &mut [f64], sections: &[Biquad]) {
    for &[b0, b1, b2, a1, a2] in sections {
        let Some(&u) = y.first() else { return };
        // Steady state for a constant input u: output g·u with g the DC gain.
        let g = (b0 + b1 + b2) / (1.0 + a1 + a2);
        let g = if g.is_finite() { g } else { 0.0 };
        let out = g * u;
        let mut s2 = b2 * u - a2 * out;
        let mut s1 = b1 * u - a1 * out + s2;
        for v in y.iter_mut() {
            let x = *v;
            let o = b0 * x + s1;
            s1 = b1 * x - a1 * o + s2;
            s2 = b2 * x - a2 * o;
            *v = o;
        }
    }
}

/// max − min of every window of `w` samples (`y.len() − w + 1` values).
fn moving_max_minus_min(y: &[f64], w: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(y.len().saturating_sub(w) + 1);
    let (mut hi, mut lo) = (VecDeque::new(), VecDeque::new());
    for (i, &v) in y.iter().enumerate() {
        while hi.back().is_some_and(|&j: &usize| y[j] <= v) {
            hi.pop_back();
        }
        hi.push_back(i);
        while lo.back().is_some_and(|&j: &usize| y[j] >= v) {
            lo.pop_back();
        }
        lo.push_back(i);
        if i + 1 >= w {
            let start = i + 1 - w;
            while hi.front().is_some_and(|&j| j < start) {
                hi.pop_front();
            }
            while lo.front().is_some_and(|&j| j < start) {
                lo.pop_front();
            }
            if let (Some(&a), Some(&b)) = (hi.front(), lo.front()) {
                out.push(y[a] - y[b]);
            }
        }
    }
    out
}

/// Indices of the local extrema of `y` (a plateau counts once, at its start).
fn extrema(y: &[f64]) -> Vec<usize> {
    let mut out = Vec::new();
    let mut last_sign = 0.0;
    let mut last_change = 0;
    for i in 1..y.len() {
        let d = y[i] - y[i - 1];
        if d == 0.0 {
            continue;
        }
        let s = d.signum();
        if last_sign != 0.0 && s != last_sign {
            out.push(last_change);
        }
        if s != last_sign {
            last_sign = s;
        }
        last_change = i;
    }
    out
}

/// Mean peak-to-peak of the half-waves whole inside every window of `w`
/// samples; `fallback[a]` (max − min) where a window holds none.
fn moving_mean_pp(y: &[f64], w: usize, fallback: &[f64]) -> Vec<f64> {
    let ext = extrema(y);
    // prefix[j] = sum of the first j half-wave heights (half-wave j joins ext[j] and ext[j+1]).
    let mut prefix = Vec::with_capacity(ext.len());
    prefix.push(0.0);
    for pair in ext.windows(2) {
        let last = prefix.last().copied().unwrap_or(0.0);
        prefix.push(last + (y[pair[1]] - y[pair[0]]).abs());
    }
    fallback
        .iter()
        .enumerate()
        .map(|(a, &fb)| {
            let j0 = ext.partition_point(|&e| e < a);
            let j1 = ext.partition_point(|&e| e < a + w);
            // Extrema j0..j1 lie in the window: half-waves j0..j1-1.
            if j1 >= j0 + 2 { (prefix[j1 - 1] - prefix[j0]) / (j1 - j0 - 1) as f64 } else { fb }
        })
        .collect()
}

/// The band table as plain text: one line per band with the criteria and
/// the figures, or why the band could not be evaluated.
pub fn band_table(a: &BandAnalysis) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "EN 13231-3 bands (2006-style criteria, secondary source); record {} mm in {} run(s), sampling {} mm",
        fmt_mm(a.record_mm),
        a.runs,
        a.dx_mm
    );
    let _ = writeln!(
        s,
        "{:<12} {:>9} {:>9} {:>10} {:>10} {:>10} {:>9} {:>11} {:>6}  note",
        "band_mm", "window_mm", "limit_mm", "avg_pp_mm", "worst_pp_mm", "max_pp_mm", "rms_mm", "exceeding_%", "pass"
    );
    for b in &a.bands {
        let name = format!("{}-{}", fmt_mm(b.band.lo_mm), fmt_mm(b.band.hi_mm));
        match &b.outcome {
            Ok(st) => {
                let note = match (b.band.abs_limit_mm, st.abs_exceeding_percent) {
                    (Some(lim), Some(p)) => format!("2012 Class 1 ±{lim:.3} mm: {p:.1} % of length over"),
                    _ => String::new(),
                };
                let _ = writeln!(
                    s,
                    "{:<12} {:>9} {:>9.3} {:>10.4} {:>10.4} {:>10.4} {:>9.4} {:>11.1} {:>6}  {}",
                    name,
                    fmt_mm(b.band.window_mm),
                    b.band.mean_pp_limit_mm,
                    st.average_mean_pp_mm,
                    st.worst_mean_pp_mm,
                    st.worst_max_pp_mm,
                    st.rms_mm,
                    st.exceeding_percent,
                    if st.passes { "yes" } else { "NO" },
                    note
                );
            }
            Err(e) => {
                let _ = writeln!(
                    s,
                    "{:<12} {:>9} {:>9.3} {:>10} {:>10} {:>10} {:>9} {:>11} {:>6}  {}",
                    name,
                    fmt_mm(b.band.window_mm),
                    b.band.mean_pp_limit_mm,
                    "-",
                    "-",
                    "-",
                    "-",
                    "-",
                    "-",
                    e
                );
            }
        }
    }
    s
}

/// The band-filtered profiles as CSV: `x_mm` and one column per band (mm),
/// empty where a sample is a gap or a band was not evaluated.
pub fn bands_csv(a: &BandAnalysis, traces: &[Option<BandTrace>]) -> String {
    let mut s = bands_csv_header(a);
    bands_csv_rows(&mut s, 0.0, a.dx_mm, traces);
    s
}

/// The header of [`bands_csv`].
pub fn bands_csv_header(a: &BandAnalysis) -> String {
    let mut s = String::from("x_mm");
    for b in &a.bands {
        let _ = write!(s, ",band_{}_{}_mm", fmt_mm(b.band.lo_mm), fmt_mm(b.band.hi_mm));
    }
    s.push('\n');
    s
}

/// Rows of [`bands_csv`] for a stretch of traces (one per band, `None`
/// where not evaluated) whose first sample is at track position `x0_mm`.
pub fn bands_csv_rows(s: &mut String, x0_mm: f64, dx_mm: f64, traces: &[Option<BandTrace>]) {
    let n = traces.iter().flatten().map(|t| t.band_mm.len()).max().unwrap_or(0);
    for i in 0..n {
        // Rounded to the nanometre: no 0.30000000000000004.
        let _ = write!(s, "{}", ((x0_mm + i as f64 * dx_mm) * 1e6).round() / 1e6);
        for t in traces {
            match t.as_ref().and_then(|t| t.band_mm.get(i)).filter(|v| v.is_finite()) {
                Some(v) => {
                    let _ = write!(s, ",{v:.6}");
                }
                None => s.push(','),
            }
        }
        s.push('\n');
    }
}
