//! The instrument's noise floor, measured on the survey's own data, and
//! what it lets the standards judge.
//!
//! # What the lines see
//!
//! Corrugation runs across the rail head: the three lines, a few
//! millimetres apart on the running band, see the same rail. Speckle is
//! tied to each line's own patch of surface and sensor noise to each
//! line's own pixels: independent from line to line. So the lines' *null
//! combinations* ([`crate::analyze::pieces::RunningBand`], Helmert
//! contrasts: each line's weight summing to zero, orthonormal) hold no
//! common rail at all, only what differs among the lines, with the
//! statistics of one line's noise when the lines' noises are alike. Each
//! is run through exactly the processing a line goes through — the
//! EN 13231-3 band filters and moving windows, and EN 15610's Welch
//! spectrum with the effect of its nonlinear steps, which act on the rail
//! the lines share ([`crate::analyze::standards::wheel`]): a line's own
//! noise passes them linearly, and what the mean's noise leaves in their
//! effect is put into each null line from noise of the mean's statistics
//! ([`RunningBand::mean_noise`]).
//!
//! What it can and cannot see (docs/noise-floor.md):
//! * it sees speckle, sensor noise, the stitch's per-line errors and any
//!   disturbance of one line (grease, a glint);
//! * it counts rail that differs across the running band (a defect under
//!   one line only) as noise: the floor is then too high, never too low —
//!   a band may be *not judged* that could have been;
//! * it cannot see what is common to the lines: a vibration of the whole
//!   head, a calibration error, and the joint registration's error (one
//!   offset per frame for all its lines): that one is propagated from the
//!   solve ([`crate::analyze::stitch::StitchShare`]) and added in
//!   quadrature ([`Floor::with_stitch`]), so the floor is not too low.
//!
//! # The floor of each figure
//!
//! A line's floor in an EN 13231-3 band is the null lines' RMS, average
//! and worst mean peak-to-peak; the running band's profile (the lines'
//! mean) has `1/√k` of it for `k` lines ([`BandFloor::of_mean`]). In
//! EN 15610 it is the null lines' one-third-octave spectrum.
//!
//! # Verdicts the floor supports
//!
//! * EN 13231-3:2006: a band is judged when its floor's average mean
//!   peak-to-peak is at most `1/√2` of the limit ([`JUDGED_SHARE_OF_LIMIT`]:
//!   the noise's power at most half the limit's), and a position exceeds
//!   where the rail's own mean peak-to-peak does: the reading with the
//!   noise's power taken out, `reading > √(limit² + floor²)`
//!   ([`BandFloor::threshold_mm`]). Noise alone then cannot carry a window
//!   over it, and rail at the limit is not hidden by it.
//! * EN 13231-3:2012 (isolated points): when the floor's largest
//!   displacement (half the worst window max − min of the null lines) is
//!   at most half the limit.
//! * ISO 3095: a one-third octave is *within* when its reading, noise and
//!   all, is under the limit with confidence, *EXCEEDS* when the rail's
//!   own level (the floor's power taken out) is over it with confidence,
//!   and *not judged* between
//!   ([`crate::analyze::standards::detection`], [`en15610::ThirdOctave::decision`]).
//!   Each line against its own floor ([`crate::analyze::line_floor`]);
//!   EN 15610's energy average of the lines against their mean floor.
//!
//! A one-line profile (another instrument's CSV, a head with one line)
//! has no null combination: its floor is not known and it is judged as
//! measured, saying so.

use std::borrow::Cow;
use std::ops::Range;

use super::line_floor::{self, LineFloor, PairBands, PairSums};
use super::pieces::{self, RunningBand, Wanted};
use super::stitch::Stitched;
use super::{Grid, Options};
use crate::Error;
use crate::analyze::standards::en13231::{self, BandSums, BandTrace, Edition};
use crate::analyze::standards::en15610;
use crate::progress::Progress;

/// An EN 13231-3:2006 band is judged when its floor's mean peak-to-peak
/// is at most this share of its limit (the floor's power at most half the
/// limit's: 3 dB under it).
pub const JUDGED_SHARE_OF_LIMIT: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// An EN 13231-3:2012 band (isolated points) is judged when the floor's
/// largest displacement is at most this share of its limit.
pub const JUDGED_SHARE_OF_LIMIT_2012: f64 = 0.5;

/// The survey's noise floor.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    /// Lines combined (the fewest of any section measured).
    pub lines: usize,
    /// Length where every line of a section has a sample, mm.
    pub measured_mm: f64,
    /// One line's floor per EN 13231-3 band ([`en13231::BANDS`] order;
    /// `None` where the common runs are too short for the band).
    pub bands: Vec<Option<BandFloor>>,
    /// One line's floor per one-third octave (`None`: no common run holds a segment).
    pub spectrum: Option<en15610::Spectrum>,
    /// "Spikes" EN 15610's spike removal took out of the null lines per
    /// metre: noise that looks like dirt.
    pub spikes_per_m: f64,
    /// Each line's own floor (three lines: [`line_floor`]); empty when
    /// the lines cannot be told apart, and each line carries the floor above.
    pub lines_own: Vec<LineFloor>,
}

/// One line's noise floor in an EN 13231-3 band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandFloor {
    /// RMS of the band-filtered noise, mm.
    pub rms_mm: f64,
    /// Mean over the window positions of the noise's mean peak-to-peak, mm.
    pub average_mean_pp_mm: f64,
    /// Largest mean peak-to-peak of a window of noise, mm.
    pub worst_mean_pp_mm: f64,
    /// Largest displacement of the noise, mm (half the largest window max − min).
    pub peak_mm: f64,
    /// Share of the lines' band power they have in common, 0–1: near 0
    /// where the band holds noise (or rail that differs across the
    /// band), near 1 where common rail stands far above the noise.
    pub coherence: f64,
    /// The stitch's own share, common to all lines, mm RMS: included in
    /// the figures above ([`BandFloor::with_stitch`]; 0 when none).
    pub stitch_rms_mm: f64,
}

impl BandFloor {
    /// The floor of the mean of `k` lines: independent noises average as
    /// `1/√k`, the stitch's share common to them does not.
    pub fn of_mean(&self, k: usize) -> BandFloor {
        let own2 = (self.rms_mm.powi(2) - self.stitch_rms_mm.powi(2)).max(0.0);
        let rms = (own2 / k.max(1) as f64 + self.stitch_rms_mm.powi(2)).sqrt();
        self.scaled(rms)
    }

    /// This floor with a share common to all lines (the stitch's, mm RMS)
    /// added in quadrature; the peak-to-peak figures grow as the RMS does.
    pub fn with_stitch(&self, stitch_rms_mm: f64) -> BandFloor {
        let own2 = (self.rms_mm.powi(2) - self.stitch_rms_mm.powi(2)).max(0.0);
        let stitch_rms_mm = stitch_rms_mm.max(0.0);
        BandFloor { stitch_rms_mm, ..self.scaled((own2 + stitch_rms_mm.powi(2)).sqrt()) }
    }

    /// The figures scaled to an RMS of `rms_mm`.
    pub fn scaled(&self, rms_mm: f64) -> BandFloor {
        let s = if self.rms_mm > 0.0 { rms_mm / self.rms_mm } else { 1.0 };
        BandFloor {
            rms_mm,
            average_mean_pp_mm: self.average_mean_pp_mm * s,
            worst_mean_pp_mm: self.worst_mean_pp_mm * s,
            peak_mm: self.peak_mm * s,
            ..*self
        }
    }

    /// The floor in the quantity `edition` judges: the average mean
    /// peak-to-peak (2006) or the largest displacement (2012), mm.
    pub fn judged_quantity_mm(&self, edition: Edition) -> f64 {
        match edition {
            Edition::En2006 => self.average_mean_pp_mm,
            Edition::En2012 => self.peak_mm,
        }
    }

    /// Why a band with this floor cannot be judged against `limit_mm`
    /// under `edition`, or `None` when it can.
    pub fn not_judged(&self, edition: Edition, limit_mm: f64) -> Option<String> {
        let f = self.judged_quantity_mm(edition);
        let (share, what, words) = match edition {
            Edition::En2006 => (JUDGED_SHARE_OF_LIMIT, "mean peak-to-peak", "over 0.71 ×"),
            Edition::En2012 => (JUDGED_SHARE_OF_LIMIT_2012, "largest displacement", "over half"),
        };
        (f > share * limit_mm).then(|| {
            format!(
                "not judged: the instrument's noise floor ({what} {:.1} µm) is {words} the {:.0} µm limit",
                f * 1000.0,
                limit_mm * 1000.0
            )
        })
    }

    /// The reading over which a position exceeds `limit_mm`: under 2006
    /// the rail's own mean peak-to-peak is over the limit when the
    /// reading, its noise's power taken out, is — `√(limit² + floor²)`
    /// (noise and rail are independent, their powers add); under 2012 the
    /// limit itself (a judged band's noise peaks stay under half of it).
    pub fn threshold_mm(&self, edition: Edition, limit_mm: f64) -> f64 {
        match edition {
            Edition::En2006 => limit_mm.hypot(self.average_mean_pp_mm),
            Edition::En2012 => limit_mm,
        }
    }
}

/// A figure's floor and whether it can be judged.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BandJudgement {
    /// The floor of the profile judged (`None`: not known).
    pub floor: Option<BandFloor>,
    /// Why the band is not judged (the floor is too high), if it is not.
    pub not_judged: Option<String>,
    /// The reading over which a position exceeds ([`BandFloor::threshold_mm`];
    /// the limit where the floor is not known; `None`: no limit), mm.
    pub threshold_mm: Option<f64>,
}

impl BandJudgement {
    /// The judgement of a profile whose floor is `floor`, against the
    /// `edition`'s limit for `band` (none: nothing to judge).
    pub fn of(floor: Option<BandFloor>, edition: Edition, band: &en13231::Band) -> BandJudgement {
        let limit = edition.limit_mm(band);
        let not_judged = floor.zip(limit).and_then(|(f, lim)| f.not_judged(edition, lim));
        let threshold_mm = limit.map(|lim| floor.map_or(lim, |f| f.threshold_mm(edition, lim)));
        BandJudgement { floor, not_judged, threshold_mm }
    }
}

/// Sums over the null lines and the mean line of one band, in any order.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    nulls: BandSums,
    mean: BandSums,
    seen: bool,
}

/// The floor's sums over pieces of running band, in any order: what
/// [`measure`] makes a survey's floor of, and the live view a run's so far
/// ([`FloorSums::floor`]: the same floor, each line's own and the running
/// band's lines weighted by them, in the EN 13231-3 bands).
#[derive(Debug, Clone, Default)]
pub struct FloorSums {
    bands: [Sums; 4],
    pairs: PairBands,
}

/// A trace cut to `within` (borrowed when that is all of it).
fn cut<'a>(t: &'a BandTrace, within: &Range<usize>) -> Cow<'a, BandTrace> {
    if within.start == 0 && within.end >= t.band_mm.len() {
        Cow::Borrowed(t)
    } else {
        Cow::Owned(t.within(within.clone()))
    }
}

impl FloorSums {
    /// Adds a piece's running band (lines of lasers `lasers`, in its
    /// order) over `within` (indices in the piece's core).
    pub fn add(&mut self, band: &RunningBand, lasers: &[usize], within: Range<usize>) {
        self.pairs.add(band, lasers, within.clone());
        for (b, (s, spec)) in self.bands.iter_mut().zip(&en13231::BANDS).enumerate() {
            if let Some(t) = band.mean.bands.get(b).and_then(Option::as_ref) {
                s.mean.add(spec, &cut(t, &within));
            }
            for n in &band.nulls {
                if let Some(t) = n.bands.get(b).and_then(Option::as_ref) {
                    s.nulls.add(spec, &cut(t, &within));
                    s.seen = true;
                }
            }
        }
    }

    /// Adds the sums of other pieces.
    pub fn merge(&mut self, o: &FloorSums) {
        for (s, o) in self.bands.iter_mut().zip(&o.bands) {
            s.nulls.merge(&o.nulls);
            s.mean.merge(&o.mean);
            s.seen |= o.seen;
        }
        self.pairs.merge(&o.pairs);
    }

    /// The floor of the EN 13231-3 bands these sums hold, of `lines`
    /// lines sampled `dx_mm` apart over `measured_mm`: one line's, and
    /// each line's own (three lines) — what [`measure`] finds of the
    /// same pieces, without the one-third octaves (no spectrum, no spikes
    /// counted).
    pub fn floor(&self, lines: usize, dx_mm: f64, measured_mm: f64) -> Floor {
        let bands = self.bands(lines, dx_mm);
        let lines_own = self.pairs.lines(&bands);
        Floor { lines, measured_mm, bands, spectrum: None, spikes_per_m: 0.0, lines_own }
    }

    /// One line's floor per band ([`en13231::BANDS`] order; `None` where
    /// no null line was traced) of `lines` lines sampled `dx_mm` apart.
    pub fn bands(&self, lines: usize, dx_mm: f64) -> Vec<Option<BandFloor>> {
        self.bands
            .iter()
            .zip(&en13231::BANDS)
            .map(|(s, band)| {
                s.seen.then(|| {
                    let n = s.nulls.stats(band, dx_mm);
                    let m = s.mean.stats(band, dx_mm);
                    BandFloor {
                        rms_mm: n.rms_mm,
                        average_mean_pp_mm: n.average_mean_pp_mm,
                        worst_mean_pp_mm: n.worst_mean_pp_mm,
                        peak_mm: n.worst_max_pp_mm / 2.0,
                        coherence: coherence(m.rms_mm, n.rms_mm, lines),
                        stitch_rms_mm: 0.0,
                    }
                })
            })
            .collect()
    }
}

/// Measures the floor of a survey's lines (`stitched`, section by
/// section), walking each section with two lines or more once; `None`
/// when no section has two lines with samples in common.
pub fn measure(stitched: &[Stitched], opts: &Options, progress: &dyn Progress) -> Result<Option<Floor>, Error> {
    let mut sums = FloorSums::default();
    let mut welch: Option<en15610::Welch> = None;
    let mut pairs = PairSums::default();
    let (mut lines, mut measured_mm, mut spikes) = (usize::MAX, 0.0, 0usize);
    let sections: Vec<&[Stitched]> = stitched.chunk_by(|a, b| a.section == b.section).collect();
    let total_m: f64 = sections.iter().map(|s| section_len_mm(s) / 1000.0).sum();
    progress.begin("noise floor", total_m as u64, "m");
    let mut done_m = 0.0;
    for section in sections {
        if section.len() < 2 {
            continue;
        }
        let dx = section[0].dx_mm;
        let common = common_runs(section, dx);
        if common.is_empty() {
            continue;
        }
        lines = lines.min(section.len());
        measured_mm += common.iter().map(|r| r.len()).sum::<usize>() as f64 * dx;
        if welch.is_none() {
            welch = en15610::Welch::new(&common, dx, &opts.roughness).ok();
        }
        let evaluate = pieces::evaluated_on(&common, dx);
        let with: Vec<(&Stitched, [bool; 4])> = section.iter().map(|s| (s, evaluate)).collect();
        let want = Wanted { lines: false, mean: true, nulls: true };
        let lasers: Vec<usize> = section.iter().map(|s| s.laser).collect();
        let new_welch = || en15610::Welch::new(&common, dx, &opts.roughness).ok();
        pieces::walk_section(section[0].section, &with, opts, want, &mut |p| {
            let Some(band) = &p.band else { return Ok(()) };
            sums.add(band, &lasers, 0..p.core.len());
            // Noise through the processing a line goes through: its own
            // linearly, the mean's through EN 15610's steps.
            let steps = band.rail_steps(&opts.roughness);
            let corrections: Vec<_> =
                (0..band.nulls.len()).map(|j| steps.correction(&band.mean_noise(j), &opts.roughness)).collect();
            pairs.add(band, &lasers, p.core.clone(), &opts.roughness, &corrections, &new_welch);
            if let Some(w) = &mut welch {
                for (n, correction) in band.nulls.iter().zip(&corrections) {
                    spikes += w.add_corrected(&n.stretch(p.core.clone()), correction, &opts.roughness);
                }
            }
            done_m += p.core.len() as f64 * p.grid.dx_mm / 1000.0;
            progress.set(done_m as u64);
            Ok(())
        })?;
    }
    progress.end();
    if lines == usize::MAX {
        return Ok(None);
    }
    let nulls = (lines - 1) as f64;
    let bands = sums.bands(lines, stitched[0].dx_mm);
    let lines_own = pairs.lines(&sums.pairs, &bands);
    Ok(Some(Floor {
        lines,
        measured_mm,
        bands,
        spectrum: welch.map(|w| w.spectrum()),
        spikes_per_m: spikes as f64 / nulls / (measured_mm / 1000.0).max(1e-9),
        lines_own,
    }))
}

/// The share of `k` lines' band power they have in common, from the
/// RMS of their mean and of their null combinations: per line the power
/// is `mean² + (k−1)/k · null²` (the transform is orthonormal), the
/// common part `mean² − null²/k`.
pub fn coherence(mean_rms: f64, null_rms: f64, k: usize) -> f64 {
    let k = k.max(2) as f64;
    let (m2, n2) = (mean_rms * mean_rms, null_rms * null_rms);
    let total = m2 + (k - 1.0) / k * n2;
    if total > 0.0 { ((m2 - n2 / k) / total).clamp(0.0, 1.0) } else { 0.0 }
}

/// The runs (grid indices of the section) where every line has a sample.
pub(crate) fn common_runs(section: &[Stitched], dx_mm: f64) -> Vec<Range<usize>> {
    let grid = Grid::of_lines(&section.iter().collect::<Vec<_>>(), dx_mm);
    let runs: Vec<Vec<Range<usize>>> = section
        .iter()
        .map(|s| {
            let off = grid.offset(s);
            pieces::runs(s).into_iter().map(|r| r.start + off..r.end + off).collect()
        })
        .collect();
    pieces::common_runs(&runs)
}

fn section_len_mm(section: &[Stitched]) -> f64 {
    let dx = section[0].dx_mm;
    Grid::of_lines(&section.iter().collect::<Vec<_>>(), dx).len as f64 * dx
}

impl Floor {
    /// The floor with the stitch's own share (common to all lines, which
    /// the null lines cannot see) added in quadrature in each band it was
    /// measured in.
    pub fn with_stitch(mut self, share: &crate::analyze::stitch::StitchShare) -> Floor {
        let own = self.lines_own.iter_mut().map(|l| &mut l.bands);
        for bands in std::iter::once(&mut self.bands).chain(own) {
            for (b, f) in bands.iter_mut().enumerate() {
                if let (Some(f), Some(s)) = (f.as_mut(), share.rms_mm(b)) {
                    *f = f.with_stitch(s);
                }
            }
        }
        self
    }

    /// The line of laser `laser`'s own floor, where the lines could be told apart.
    pub fn line(&self, laser: usize) -> Option<&LineFloor> {
        self.lines_own.iter().find(|l| l.laser == laser)
    }

    /// Laser `laser`'s floor in band `b`: its own, or the lines' shared one.
    pub fn line_band(&self, laser: usize, b: usize) -> Option<&BandFloor> {
        match self.line(laser) {
            Some(l) => l.bands.get(b).and_then(Option::as_ref),
            None => self.band(b),
        }
    }

    /// Sets each one-third octave's floor of laser `laser`'s spectrum: its
    /// own where the lines could be told apart, else the shared one.
    pub fn mark_line(&self, laser: usize, s: &mut en15610::Spectrum) {
        let Some(own) = self.line(laser).and_then(|l| l.spectrum.as_ref()) else { return self.mark(s) };
        for b in &mut s.bands {
            let f = own.bands.iter().find(|o| o.k == b.k);
            b.floor_db = f.map(|f| f.level_db);
            b.floor_dof = f.map(|f| f.dof);
        }
    }

    /// The weights of the lines of lasers `lasers` in the running band's
    /// profile, per band: inverse to each line's own noise power (the
    /// stitch's share, common to them, left out), so that one noisy line
    /// does not drag the running band's floor up; `None` where the lines'
    /// own floors are not known (the plain mean).
    pub fn running_band_weights(&self, lasers: &[usize]) -> Option<Vec<[f64; 4]>> {
        let own: Vec<&LineFloor> = lasers.iter().map(|&l| self.line(l)).collect::<Option<_>>()?;
        let mut w = vec![[1.0 / lasers.len() as f64; 4]; lasers.len()];
        for b in 0..en13231::BANDS.len() {
            let inv: Option<Vec<f64>> = own
                .iter()
                .map(|l| {
                    let f = l.bands.get(b).copied().flatten()?;
                    let p = (f.rms_mm.powi(2) - f.stitch_rms_mm.powi(2)).max(1e-18);
                    Some(1.0 / p)
                })
                .collect();
            if let Some(inv) = inv {
                let sum: f64 = inv.iter().sum();
                for (wl, i) in w.iter_mut().zip(&inv) {
                    wl[b] = i / sum;
                }
            }
        }
        Some(w)
    }

    /// The lasers whose own floors are known, or `0..lines` (the plain
    /// mean's floor depends only on how many lines there are).
    pub fn lasers(&self) -> Vec<usize> {
        if self.lines_own.len() == self.lines {
            self.lines_own.iter().map(|l| l.laser).collect()
        } else {
            (0..self.lines).collect()
        }
    }

    /// The floor of the running band's profile of the lines of lasers
    /// `lasers` in band `b`: with their own floors, of the lines weighted
    /// as [`Floor::running_band_weights`] (`Σ wᵢ² σᵢ²`, the stitch's share
    /// whole); without, of their plain mean ([`BandFloor::of_mean`]).
    pub fn running_band(&self, b: usize, lasers: &[usize]) -> Option<BandFloor> {
        let shared = self.band(b)?;
        let Some(w) = self.running_band_weights(lasers) else { return Some(shared.of_mean(lasers.len())) };
        let mut own2 = 0.0;
        for (&l, wl) in lasers.iter().zip(&w) {
            let f = self.line_band(l, b)?;
            own2 += wl[b].powi(2) * (f.rms_mm.powi(2) - f.stitch_rms_mm.powi(2)).max(0.0);
        }
        let rms = (own2 + shared.stitch_rms_mm.powi(2)).sqrt();
        Some(shared.scaled(rms))
    }

    /// The line whose floor stands out over the others', and by how much, dB.
    pub fn standing_out(&self) -> Option<(usize, f64)> {
        line_floor::standing_out(&self.lines_own)
    }

    /// One line's floor in band `b`.
    pub fn band(&self, b: usize) -> Option<&BandFloor> {
        self.bands.get(b).and_then(Option::as_ref)
    }

    /// One line's floor at the one-third octave `k`, dB re 1 µm.
    pub fn third_octave_db(&self, k: i32) -> Option<f64> {
        self.third_octave(k).map(|b| b.level_db)
    }

    fn third_octave(&self, k: i32) -> Option<&en15610::ThirdOctave> {
        self.spectrum.as_ref()?.bands.iter().find(|b| b.k == k)
    }

    /// Sets each one-third octave's floor (and how well it is known) of a line's spectrum.
    pub fn mark(&self, s: &mut en15610::Spectrum) {
        for b in &mut s.bands {
            let f = self.third_octave(b.k);
            b.floor_db = f.map(|f| f.level_db);
            b.floor_dof = f.map(|f| f.dof);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::standards::detection::Verdict;
    use crate::analyze::stitch::{Direction, Stitching};
    use crate::analyze::{Analysis, judge, profile};

    /// Three lines 1 mm apart over `n` samples: the rail `rail(x_mm)` on
    /// each, plus independent Gaussian noise of `sigma_um` per sample.
    fn survey(n: usize, sigma_um: f64, rail: &dyn Fn(f64) -> f64, seed: u64) -> Analysis {
        let mut gauss = crate::analyze::seeded_gauss(seed);
        let lasers = (0..3)
            .map(|k| {
                let z = (0..n).map(|i| rail(i as f64) + sigma_um * gauss()).collect();
                profile::stitched(k, 0.0, 1.0, z)
            })
            .collect();
        let stitching = Stitching {
            direction: Direction::Forward,
            direction_residuals_um: None,
            direction_given: true,
            lasers,
            share: None,
        };
        judge(stitching, Vec::new(), &Options::default(), &crate::progress::Silent).unwrap()
    }

    fn line_stats(a: &Analysis, k: usize, b: usize) -> en13231::BandStats {
        a.lasers[k].bands.as_ref().unwrap().bands[b].outcome.clone().unwrap()
    }

    fn corrugated(x: f64) -> f64 {
        15.0 * (x * std::f64::consts::TAU / 20.0).sin() + 20.0 * (x * std::f64::consts::TAU / 60.0 + 1.0).sin()
    }

    /// On a smooth rail the floor is what each line reads, band by band
    /// and third octave by third octave, and nothing is judged on noise;
    /// on a corrugated rail under the same noise the floor stays where it was.
    #[test]
    fn the_floor_is_what_a_smooth_rail_reads_and_does_not_move_with_corrugation() {
        let n = 12_000;
        let smooth = survey(n, 27.0, &|_| 0.0, 3);
        let f = smooth.floor.as_ref().expect("three lines: a floor");
        assert_eq!(f.lines, 3);
        for b in 0..3 {
            let fl = f.band(b).unwrap();
            for k in 0..3 {
                let st = line_stats(&smooth, k, b);
                let r = fl.rms_mm / st.rms_mm;
                assert!((0.8..1.25).contains(&r), "band {b} line {k}: floor RMS {} vs {}", fl.rms_mm, st.rms_mm);
                let r = fl.average_mean_pp_mm / st.average_mean_pp_mm;
                assert!((0.8..1.25).contains(&r), "band {b} line {k}: floor p-p {r}");
            }
            assert!(fl.coherence < 0.1, "band {b}: noise is not common: {}", fl.coherence);
        }
        let spectrum = f.spectrum.as_ref().unwrap();
        let lines = smooth.running_bands[0].roughness.as_ref().unwrap();
        for (fb, mb) in spectrum.bands.iter().zip(&lines.bands) {
            assert!((fb.level_db - mb.level_db).abs() < 1.5, "{fb:?} vs {mb:?}");
            assert_ne!(mb.verdict(), Some(Verdict::Exceeds), "noise never exceeds ({mb:?})");
        }
        // Noise never fails: the running band's 10–30 mm floor (about 12 µm
        // mean peak-to-peak) leaves the band judged, and it passes.
        let v = &smooth.verdict;
        assert!(v.rows.iter().all(|r| r.passes(v.options.edition) != Some(false)), "{:?}", v.rows);
        assert_eq!(v.reprofile_mm, 0.0);
        assert!(v.zones.is_empty());
        assert!(v.blocks.iter().all(|b| b.iso3095.as_ref().is_none_or(|i| i.exceeded_mm.is_empty())));
        for l in &smooth.lasers {
            assert!(l.roughness.as_ref().unwrap().spectrum.bands.iter().all(|b| b.verdict() != Some(Verdict::Exceeds)));
        }

        let rough = survey(n, 27.0, &corrugated, 3);
        let g = rough.floor.as_ref().unwrap();
        for b in 0..3 {
            let (x, y) = (f.band(b).unwrap(), g.band(b).unwrap());
            assert!((y.rms_mm / x.rms_mm - 1.0).abs() < 0.02, "band {b}: {} vs {}", x.rms_mm, y.rms_mm);
        }
        assert!(g.band(0).unwrap().coherence > 0.4 && g.band(1).unwrap().coherence > 0.8, "{g:?}");
    }

    /// EN 15610's nonlinear steps act on the rail the lines share: on a
    /// smooth rail no spike is taken out of the noise, and the floor and
    /// each line read the noise as the linear processing does (the wheel
    /// on each line's noise lifted 50–250 mm by several dB).
    #[test]
    fn the_wheel_leaves_the_noise_linear() {
        let a = survey(12_000, 27.0, &|_| 0.0, 4);
        let f = a.floor.as_ref().unwrap();
        assert!(f.spikes_per_m < 0.5, "{}", f.spikes_per_m);
        let z: Vec<f64> = a.lasers[0].stitched.z.read(0..a.lasers[0].stitched.z.len()).unwrap();
        let linear = en15610::third_octave_spectrum(&z, 1.0, en15610::MIN_SEGMENT_MM).unwrap();
        let line = &a.lasers[0].roughness.as_ref().unwrap().spectrum;
        for ((fb, lb), nb) in f.spectrum.as_ref().unwrap().bands.iter().zip(&line.bands).zip(&linear.bands) {
            assert!((lb.level_db - nb.level_db).abs() < 0.5, "line {lb:?} vs linear {nb:?}");
            if (50.0..=250.0).contains(&fb.nominal_wavelength_mm) {
                assert!((fb.level_db - nb.level_db).abs() < 1.5, "floor {fb:?} vs linear {nb:?}");
            }
        }
    }

    /// A floor too high for a verdict: not judged, the floor and the limit
    /// named, never failed; the bands it allows are judged.
    #[test]
    fn a_floor_over_the_limit_is_not_judged() {
        let a = survey(6_000, 60.0, &|_| 0.0, 9);
        let v = &a.verdict;
        let why = v.rows[0].judgement.not_judged.as_ref().expect("10–30 mm at 60 µm a sample: not judged");
        assert!(why.contains("noise floor") && why.contains("20 µm limit"), "{why}");
        assert_eq!(v.rows[0].passes(v.options.edition), None);
        assert_eq!((v.reprofile_mm, v.zones.len()), (0.0, 0));
        assert!(a.lasers.iter().all(|l| l.judgements[0].not_judged.is_some()));
    }

    /// Corrugation over the limits in two bands under a floor that allows
    /// a verdict: both bands judged, and failed, on the running band.
    #[test]
    fn corrugation_over_the_floor_is_judged_and_fails() {
        let a = survey(6_000, 8.0, &corrugated, 5);
        let v = &a.verdict;
        for b in 0..2 {
            let row = &v.rows[b];
            assert!(row.judgement.not_judged.is_none(), "band {b}: {row:?}");
            assert_eq!(row.passes(v.options.edition), Some(false), "band {b}: {row:?}");
        }
        assert!(v.reprofile_mm > 0.9 * v.measured_mm, "{} of {}", v.reprofile_mm, v.measured_mm);
    }

    #[test]
    fn coherence_is_the_common_share_of_the_lines_power() {
        // Identical lines: no null power.
        assert_eq!(coherence(1.0, 0.0, 3), 1.0);
        // Pure noise of one line's σ: the mean has σ/√3, the nulls σ.
        assert!(coherence(1.0 / 3f64.sqrt(), 1.0, 3).abs() < 1e-12);
        // Common rail of power 1 over noise of power 1: half the lines' power is common.
        let m = (1.0 + 1.0 / 3.0f64).sqrt();
        assert!((coherence(m, 1.0, 3) - 0.5).abs() < 1e-12);
    }
}
