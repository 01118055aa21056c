//! ISO 3095 over surveys: per block of the first survey and ISO 3095 third
//! octave, each survey's verdict of the lines' EN 15610 energy average and
//! the rail's level with its interval — the block's own decision as
//! `cms-host analyze` made it ([`crate::analyze::reprofiling::Iso3095::bands`]), not
//! judged again — and the growth per year of the rail's level.
//!
//! # The figure
//!
//! A survey's figure of a third octave is the rail's level, the floor's
//! power taken out ([`RailLevel`]), where the third octave is judged
//! (within or EXCEEDS) and the level and both bounds of its interval are
//! known. A third octave not judged gives no figure there: what it reads
//! is the floor, and the trend would follow the instrument, not the rail.
//! The figure's standard uncertainty is its interval's half-width over the
//! deviate each bound is taken at ([`detection::Z_PAIR`]; in dB the
//! χ² bounds are near symmetric), at least [`MIN_UNCERTAINTY_DB`].
//!
//! # The growth
//!
//! dB per year by the weighted fit of the EN 13231-3 trend
//! ([`super::weighted_fit`]), over the surveys with a figure, where there
//! are at least two; its uncertainty the fit's, widened by the reduced χ²
//! when above 1. A verdict *changed* when the first and the last survey
//! that read the third octave judge it differently.

use crate::analyze::reprofiling::{Block, ReprofilingVerdict};
use crate::analyze::standards::detection::{self, RailLevel, Verdict};
use crate::analyze::standards::en15610;

/// The least a figure is uncertain by, dB: levels are given to 0.1 dB.
pub const MIN_UNCERTAINTY_DB: f64 = 0.1;

/// How far under the limit a judged rail level stands out in the text, dB.
pub const SHOWN_UNDER_LIMIT_DB: f64 = 6.0;

/// One survey's decision of a block's third octave (the lines' energy average).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    pub verdict: Verdict,
    /// The reading, noise included, dB re 1 µm.
    pub level_db: f64,
    /// The floor taken out (`None`: not known).
    pub floor_db: Option<f64>,
    /// The rail's level and its interval.
    pub rail: RailLevel,
}

impl Reading {
    /// The rail's level as a figure of the trend and its standard
    /// uncertainty, dB (`None`: not judged, or the level or a bound unknown).
    pub fn figure(&self) -> Option<(f64, f64)> {
        if self.verdict == Verdict::NotJudged {
            return None;
        }
        let (db, lo, hi) = (self.rail.db?, self.rail.lo_db?, self.rail.hi_db?);
        Some((db, ((hi - lo) / (2.0 * detection::Z_PAIR)).max(MIN_UNCERTAINTY_DB)))
    }
}

/// One block's third octave over the surveys.
#[derive(Debug, Clone, PartialEq)]
pub struct ThirdOctaveTrend {
    /// Nominal wavelength, mm.
    pub wavelength_mm: f64,
    pub limit_db: f64,
    /// Per survey (date order): its decision (`None`: the survey has no
    /// spectrum of the block).
    pub readings: Vec<Option<Reading>>,
    /// Growth of the rail's level and its standard uncertainty, dB/year
    /// (`None`: fewer than two surveys with a figure).
    pub growth: Option<(f64, f64)>,
    /// The reduced χ² of the fit (`None` with two figures).
    pub chi2_reduced: Option<f64>,
}

impl ThirdOctaveTrend {
    /// The first and the last survey's verdicts where they differ (of the
    /// surveys that read the third octave).
    pub fn changed(&self) -> Option<(Verdict, Verdict)> {
        let mut read = self.readings.iter().flatten();
        let first = read.next()?.verdict;
        let last = read.next_back()?.verdict;
        (first != last).then_some((first, last))
    }

    /// The latest survey's figure ([`Reading::figure`]), dB.
    pub fn latest_figure(&self) -> Option<(f64, f64)> {
        self.readings.iter().rev().flatten().find_map(Reading::figure)
    }

    /// Whether the text shows it: its verdict changed, or its latest
    /// figure stands within [`SHOWN_UNDER_LIMIT_DB`] of the limit or over.
    pub fn shown(&self) -> bool {
        self.changed().is_some() || self.latest_figure().is_some_and(|f| f.0 > self.limit_db - SHOWN_UNDER_LIMIT_DB)
    }
}

/// One block's ISO 3095 third octaves over the surveys.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockIso3095 {
    pub start_mm: f64,
    pub end_mm: f64,
    /// Long wavelengths first: every third octave some survey judged or not.
    pub third_octaves: Vec<ThirdOctaveTrend>,
}

/// Per block of `first`, the ISO 3095 trend over `verdicts` (the surveys'
/// verdicts in date order, `years` since the first).
pub fn trend(first: &ReprofilingVerdict, verdicts: &[&ReprofilingVerdict], years: &[f64]) -> Vec<BlockIso3095> {
    let key = super::block_key;
    first
        .blocks
        .iter()
        .map(|blk| {
            let of: Vec<Option<&Block>> =
                verdicts.iter().map(|v| v.blocks.iter().find(|b| key(b.start_mm) == key(blk.start_mm))).collect();
            block(blk, &of, years)
        })
        .collect()
}

/// The ISO 3095 third octaves of a survey's block (none without one, or without a spectrum).
fn bands<'a>(b: &Option<&'a Block>) -> &'a [en15610::ThirdOctave] {
    b.and_then(|b| b.iso3095.as_ref()).map_or(&[], |i| i.bands.as_slice())
}

/// One block's trend from its blocks in each survey (`None`: none there).
fn block(blk: &Block, of: &[Option<&Block>], years: &[f64]) -> BlockIso3095 {
    let mut waves: Vec<f64> = Vec::new();
    for b in of {
        for t in bands(b) {
            if t.iso3095_limit_db.is_some() && !waves.contains(&t.nominal_wavelength_mm) {
                waves.push(t.nominal_wavelength_mm);
            }
        }
    }
    waves.sort_by(|a, b| b.total_cmp(a));
    let third_octaves = waves
        .into_iter()
        .filter_map(|w| {
            let mut limit_db = None;
            let readings: Vec<Option<Reading>> = of
                .iter()
                .map(|b| {
                    let d = bands(b).iter().find(|t| t.nominal_wavelength_mm == w)?.decision()?;
                    limit_db = Some(d.limit_db);
                    Some(Reading { verdict: d.verdict, level_db: d.level_db, floor_db: d.floor_db, rail: d.rail })
                })
                .collect();
            let pts: Vec<(f64, f64, f64)> =
                readings.iter().zip(years).filter_map(|(r, &t)| r.as_ref()?.figure().map(|(y, u)| (t, y, u))).collect();
            let fit = super::weighted_fit(&pts);
            Some(ThirdOctaveTrend {
                wavelength_mm: w,
                limit_db: limit_db?,
                readings,
                growth: fit.map(|f| (f.b, f.ub)),
                chi2_reduced: fit.and_then(|f| f.chi2_reduced),
            })
        })
        .collect();
    BlockIso3095 { start_mm: blk.start_mm, end_mm: blk.end_mm, third_octaves }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(verdict: Verdict, db: f64, half_width: f64) -> Option<Reading> {
        let rail = RailLevel { db: Some(db), lo_db: Some(db - half_width), hi_db: Some(db + half_width) };
        Some(Reading { verdict, level_db: db, floor_db: None, rail })
    }

    fn third_octave(readings: Vec<Option<Reading>>) -> ThirdOctaveTrend {
        ThirdOctaveTrend { wavelength_mm: 50.0, limit_db: 10.0, readings, growth: None, chi2_reduced: None }
    }

    #[test]
    fn a_third_octave_not_judged_gives_no_figure() {
        let w = reading(Verdict::Within, 2.0, 1.0).unwrap();
        // The half-width over the deviate each bound is taken at.
        assert_eq!(w.figure(), Some((2.0, 1.0 / detection::Z_PAIR)));
        assert_eq!(reading(Verdict::NotJudged, 2.0, 1.0).unwrap().figure(), None);
        let open = Reading { rail: RailLevel { lo_db: None, ..w.rail }, ..w };
        assert_eq!(open.figure(), None);
        assert_eq!(reading(Verdict::Exceeds, 12.0, 0.01).unwrap().figure(), Some((12.0, MIN_UNCERTAINTY_DB)));
    }

    #[test]
    fn changes_and_levels_near_the_limit_are_shown() {
        let t = third_octave(vec![reading(Verdict::Within, 2.0, 1.0), None, reading(Verdict::Exceeds, 12.0, 1.0)]);
        assert_eq!(t.changed(), Some((Verdict::Within, Verdict::Exceeds)));
        assert!(t.shown());
        // Judged alike, 3 dB under the limit: shown; 7 dB under: not.
        let near = third_octave(vec![reading(Verdict::Within, 2.0, 1.0), reading(Verdict::Within, 7.0, 1.0)]);
        assert_eq!(near.changed(), None);
        assert!(near.shown());
        let far = third_octave(vec![reading(Verdict::Within, 2.0, 1.0), reading(Verdict::Within, 3.0, 1.0)]);
        assert!(!far.shown());
        // The latest figure is the latest judged one: a last survey at the floor shows the one before.
        let floor = third_octave(vec![reading(Verdict::Within, 8.0, 1.0), reading(Verdict::NotJudged, 9.0, 9.0)]);
        assert_eq!(floor.latest_figure().map(|f| f.0), Some(8.0));
    }
}
