//! The trend over surveys of one site: surveys at different dates, each
//! analysed as `cms-host analyze` analyses it ([`crate::analyze::runs`]),
//! aligned on chainage, and per block and EN 13231-3 band the growth of
//! the rail's figure per year, with its uncertainty, and when the block
//! will cross the band's limit — which blocks to grind next, before they
//! exceed.
//!
//! # Alignment
//!
//! Surveys are aligned by their placements (the chainage each was given):
//! the blocks are the first survey's ([`ReprofilingVerdict::blocks`]), and
//! every survey's figure of a block is taken over the same chainage. Each
//! later survey is checked against the first by registration: its longest
//! line of each laser, band-passed to 2.5·dx–500 mm, cross-correlated with
//! the first survey's (masked, normalised, [`masked_correlation`]) within
//! [`Options::search_mm`] of the given chainage, the best shift refined by
//! a parabola. A shift beyond [`Options::tolerance_mm`] is flagged
//! ([`Registration::disputed`]), not applied: the given chainage is the
//! user's, and a trend across a misplaced survey is reported as such.
//!
//! # The figure
//!
//! A block's figure in a band is what the verdict judges, reduced to one
//! number that crosses the limit when the block starts failing: under
//! EN 13231-3:2006 (mean peak-to-peak, at most 5 % of the length over) the
//! 95th percentile of the mean peak-to-peak along the block (of the
//! running band's profile, the lines' mean, as the verdict judges) — over the limit exactly when more than 5 % of the
//! block is; under 2012 (isolated points) the largest |displacement|. A
//! block measured over less than half its length in a survey has no
//! figure there.
//!
//! # The model and its uncertainty
//!
//! Per block and band, `figure(t) = a + b·(t − t̄)` by weighted least
//! squares over the surveys (`t` in years, 365.2425 days). A survey's own
//! standard uncertainty of a figure is the standard error of the figure
//! over the block's four quarters (sd / 2), at least 0.1 µm; the growth's
//! standard uncertainty `u(b)` is the weighted fit's, scaled by the
//! residuals' reduced χ² when it is above 1 (scatter the surveys'
//! uncertainties do not explain widens it, never narrows it). The crossing
//! `t* = t̄ + (limit − a)/b`; its standard uncertainty by linearisation,
//! `u(t*)² = (u(a)² + (t* − t̄)²·u(b)²)/b²`, and the interval given is
//! `t* ± 2·u(t*)` (open when the growth is not 2 u(b) above zero). A block
//! whose last figure is over the limit is *already over*; one not growing
//! or crossing later than [`Options::horizon_years`] after the last survey
//! is *not within* that horizon. A band whose noise floor, in the latest
//! survey, does not allow a verdict has no crossing: *at the noise floor*
//! (growth within the floor is not growth).
//!
//! # ISO 3095
//!
//! Beside the bands, per block and ISO 3095 third octave, each survey's
//! verdict of the lines' energy average and the rail's level with its
//! interval, the third octaves whose verdict changed and the growth of the
//! rail's level, dB per year ([`iso3095`]).

use std::fmt;

use crate::analyze::reprofiling::{Edition, ReprofilingVerdict};
use crate::analyze::standards::en13231::{self, Band};
use crate::analyze::survey::masked_correlation;
use crate::analyze::{Analysis, LaserAnalysis};
use crate::recording::survey_info::SurveyDate;

pub mod iso3095;

/// One survey of the site: its name (for messages), its day and its analysis.
#[derive(Debug, Clone)]
pub struct SurveyRun {
    pub name: String,
    pub date: SurveyDate,
    pub analysis: Analysis,
}

/// Options of [`trend`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// How far registration looks from the given chainage, mm.
    pub search_mm: f64,
    /// A registered shift beyond this disputes the given chainage, mm.
    pub tolerance_mm: f64,
    /// Crossings later than this after the last survey are "not within", years.
    pub horizon_years: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { search_mm: 2000.0, tolerance_mm: 100.0, horizon_years: 10.0 }
    }
}

/// Why there is no trend.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TrendError {
    /// Fewer than two surveys.
    #[error("{0} survey(s): a trend needs surveys of at least two dates")]
    TooFew(usize),
    /// Two surveys of one day.
    #[error("{0} and {1} are both of {2}: a trend needs each survey on its own date")]
    SameDate(String, String, SurveyDate),
    /// Analysed under different options (edition, block length).
    #[error("{0} was judged with other options than {1} (edition, block length): analyse them alike")]
    Options(String, String),
    /// A later survey that covers none of the first's blocks.
    #[error("{0} does not overlap {1} on chainage ({2}): surveys of one site must cover the same rail")]
    NoOverlap(String, String, String),
    /// The first survey has no blocks (nothing measured).
    #[error("{0} has no blocks: nothing measured to follow")]
    NoBlocks(String),
    /// The first survey has blocks but no figure in any (each under half measured).
    #[error(
        "{0} has no block with a figure ({1} m blocks need at least half of their length measured): use shorter blocks (--block-m) or a longer survey"
    )]
    NoFigures(String, f64),
    /// A survey's lines could not be read back (their temporary storage).
    #[error("{0}: {1}")]
    Scratch(String, String),
}

impl crate::error::Classify for TrendError {
    fn class(&self) -> crate::error::Class {
        match self {
            TrendError::Scratch(..) => crate::error::Class::Other,
            _ => crate::error::Class::Input,
        }
    }
}

/// A later survey's registration on the first.
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    /// Survey index (from 0, in date order).
    pub survey: usize,
    /// Where its rail lies against the first's, beyond its given chainage,
    /// mm (`None`: no line pair overlapped enough to register).
    pub shift_mm: Option<f64>,
    pub correlation: f64,
    /// The shift exceeds [`Options::tolerance_mm`] on a clear match
    /// (correlation ≥ 0.9): the given chainage is probably wrong.
    pub disputed: bool,
}

/// When a block crosses a band's limit.
#[derive(Debug, Clone, PartialEq)]
pub enum Crossing {
    /// The last survey's figure is over the limit.
    AlreadyOver,
    /// Projected: the date, and the interval `t* ± 2 u(t*)` (`None` end: open).
    On { date: SurveyDate, earliest: Option<SurveyDate>, latest: Option<SurveyDate> },
    /// Not growing, or crossing later than the horizon after the last survey (years).
    NotWithin(f64),
    /// The band has no limit under the edition, or too few figures to fit.
    NotJudged,
    /// The last survey's noise floor does not allow the band a verdict
    /// ([`crate::analyze::floor`]): growth within the floor is not
    /// growth. The floor in the edition's quantity, mm.
    AtTheFloor(f64),
}

/// One block and band's trend.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockTrend {
    pub start_mm: f64,
    pub end_mm: f64,
    pub band: Band,
    pub limit_mm: Option<f64>,
    /// Per survey (in date order): years since the first, figure and its
    /// standard uncertainty, mm (`None`: not measured over half the block).
    pub figures: Vec<Option<(f64, f64, f64)>>,
    /// Growth per year and its standard uncertainty, mm/year (`None`: fewer than two figures).
    pub growth: Option<(f64, f64)>,
    /// The reduced χ² of the fit (`None` with two figures).
    pub chi2_reduced: Option<f64>,
    pub crossing: Crossing,
}

/// The whole trend.
#[derive(Debug, Clone, PartialEq)]
pub struct Trend {
    pub edition: Edition,
    pub block_mm: f64,
    /// The surveys' names and dates, in date order.
    pub surveys: Vec<(String, SurveyDate)>,
    /// Per survey (in date order), how a track register placed its runs
    /// (empty: no register given).
    pub placings: Vec<Vec<crate::analyze::placing::GnssPlacing>>,
    pub registrations: Vec<Registration>,
    /// Per block, per band ([`en13231::BANDS`] order).
    pub blocks: Vec<BlockTrend>,
    /// Per block: its ISO 3095 third octaves over the surveys.
    pub iso3095: Vec<iso3095::BlockIso3095>,
}

impl Trend {
    /// The block trends that will cross, soonest first: already over, then
    /// by projected date.
    pub fn nearest(&self) -> Vec<&BlockTrend> {
        let mut v: Vec<&BlockTrend> =
            self.blocks.iter().filter(|b| matches!(b.crossing, Crossing::AlreadyOver | Crossing::On { .. })).collect();
        let key = |b: &BlockTrend| match &b.crossing {
            Crossing::AlreadyOver => i64::MIN,
            Crossing::On { date, .. } => date.day_number(),
            _ => i64::MAX,
        };
        v.sort_by_key(|b| (key(b), b.start_mm as i64));
        v
    }
}

impl fmt::Display for Crossing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let end = |d: &Option<SurveyDate>| d.map_or("open".to_string(), |d| d.to_string());
        match self {
            Crossing::AlreadyOver => write!(f, "already over"),
            Crossing::On { date, earliest, latest } => write!(f, "{date} ({} to {})", end(earliest), end(latest)),
            Crossing::NotWithin(y) => write!(f, "not within {y} years"),
            Crossing::NotJudged => write!(f, "not judged"),
            Crossing::AtTheFloor(x) => write!(f, "not judged: at the noise floor ({:.1} µm)", x * 1000.0),
        }
    }
}

/// The trend of `surveys` (any order; sorted by date).
pub fn trend(surveys: &[SurveyRun], opts: &Options) -> Result<Trend, TrendError> {
    if surveys.len() < 2 {
        return Err(TrendError::TooFew(surveys.len()));
    }
    let mut order: Vec<&SurveyRun> = surveys.iter().collect();
    order.sort_by_key(|s| s.date);
    for w in order.windows(2) {
        if w[0].date == w[1].date {
            return Err(TrendError::SameDate(w[0].name.clone(), w[1].name.clone(), w[0].date));
        }
    }
    let first = order[0];
    let verdict: &ReprofilingVerdict = &first.analysis.verdict;
    for s in &order[1..] {
        if s.analysis.verdict.options != verdict.options {
            return Err(TrendError::Options(s.name.clone(), first.name.clone()));
        }
    }
    if verdict.blocks.is_empty() {
        return Err(TrendError::NoBlocks(first.name.clone()));
    }
    let edition = verdict.options.edition;
    let t0 = first.date;
    let years: Vec<f64> = order.iter().map(|s| s.date.years_since(t0)).collect();
    let mut blocks = Vec::new();
    let mut covered = vec![false; order.len()];
    let per_survey = order
        .iter()
        .map(|s| block_figures(&s.analysis, edition).map_err(|e| TrendError::Scratch(s.name.clone(), e.to_string())))
        .collect::<Result<Vec<_>, TrendError>>()?;
    // The floor of the latest survey: a band it does not allow a verdict has no crossing.
    let latest = &order[order.len() - 1].analysis.verdict;
    for blk in &verdict.blocks {
        for (b, band) in en13231::BANDS.iter().enumerate() {
            let limit_mm = edition.limit_mm(band);
            let at_floor = latest.rows.get(b).and_then(|r| {
                r.judgement.not_judged.as_ref()?;
                Some(r.judgement.floor?.judged_quantity_mm(edition))
            });
            let figures: Vec<Option<(f64, f64, f64)>> = per_survey
                .iter()
                .zip(&years)
                .map(|(f, &t)| f.get(&(block_key(blk.start_mm), b)).map(|&(y, u)| (t, y, u)))
                .collect();
            for (c, f) in covered.iter_mut().zip(&figures) {
                *c |= f.is_some();
            }
            let mut fit =
                fit_block(blk.start_mm, blk.end_mm, *band, limit_mm, figures, t0, years[years.len() - 1], opts);
            if let Some(x) = at_floor {
                fit.crossing = Crossing::AtTheFloor(x);
            }
            blocks.push(fit);
        }
    }
    let span = |a: &Analysis| {
        let lo = a.lasers.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
        let hi = a.lasers.iter().map(|l| l.stitched.x_mm(l.stitched.z.len())).fold(f64::NEG_INFINITY, f64::max);
        format!("{} to {}", crate::analyze::chainage(lo), crate::analyze::chainage(hi))
    };
    if covered.first() == Some(&false) {
        return Err(TrendError::NoFigures(first.name.clone(), verdict.options.block_mm / 1000.0));
    }
    if let Some(i) = covered.iter().position(|c| !c) {
        return Err(TrendError::NoOverlap(
            order[i].name.clone(),
            first.name.clone(),
            format!("{} against {}", span(&order[i].analysis), span(&first.analysis)),
        ));
    }
    let registrations =
        order.iter().enumerate().skip(1).map(|(i, s)| register(i, &first.analysis, &s.analysis, opts)).collect();
    Ok(Trend {
        edition,
        block_mm: verdict.options.block_mm,
        surveys: order.iter().map(|s| (s.name.clone(), s.date)).collect(),
        placings: order.iter().map(|s| s.analysis.gnss_placing.clone()).collect(),
        registrations,
        blocks,
        iso3095: iso3095::trend(verdict, &order.iter().map(|s| &s.analysis.verdict).collect::<Vec<_>>(), &years),
    })
}

/// A block's key: its start chainage to the micrometre.
pub fn block_key(start_mm: f64) -> i64 {
    (start_mm * 1000.0).round() as i64
}

/// Figures and uncertainties by ([`block_key`], band), mm.
pub type BlockFigures = std::collections::HashMap<(i64, usize), (f64, f64)>;

/// Every block's figure in every band of an analysis, with its standard
/// uncertainty (see [`block_figure`]), by ([`block_key`], band), in one
/// walk along the line: of the running band's profile where a section
/// has one (what the verdict judges), else the largest line's.
pub fn block_figures(a: &Analysis, edition: Edition) -> Result<BlockFigures, crate::Error> {
    let mut out = std::collections::HashMap::new();
    let block_mm = a.verdict.options.block_mm;
    // The block being filled (a block may span several pieces): its
    // start and, per band, the largest line's criterion per position.
    let mut open: Option<(f64, Vec<Vec<f64>>)> = None;
    let close = |open: &mut Option<(f64, Vec<Vec<f64>>)>, out: &mut BlockFigures| {
        if let Some((lo, values)) = open.take() {
            for (b, value) in values.iter().enumerate() {
                if let Some(f) = block_figure(value, edition) {
                    out.insert((block_key(lo), b), f);
                }
            }
        }
    };
    let want = crate::analyze::pieces::Wanted { lines: true, mean: true, nulls: false };
    a.for_each_piece_with(want, |p| {
        let dx = p.grid.dx_mm;
        let judged: Vec<&crate::analyze::pieces::PieceLine> = match &p.band {
            Some(band) => vec![&band.mean],
            None => p.lines.iter().collect(),
        };
        for part in crate::analyze::pieces::blocks(p, block_mm) {
            let (lo, hi) = part.span_mm;
            if open.as_ref().is_none_or(|o| o.0 != lo) {
                close(&mut open, &mut out);
                let n = ((hi - lo) / dx).round().max(1.0) as usize;
                open = Some((lo, vec![vec![f64::NAN; n]; en13231::BANDS.len()]));
            }
            let Some((_, values)) = &mut open else { continue };
            for (b, value) in values.iter_mut().enumerate() {
                let n = value.len();
                for t in judged.iter().filter_map(|l| l.bands.get(b).and_then(Option::as_ref)) {
                    for i in part.range.clone() {
                        let mean = t.mean_pp_mm[i];
                        let v = match edition {
                            Edition::En2006 => mean,
                            Edition::En2012 if mean.is_finite() => t.band_mm[i].abs(),
                            Edition::En2012 => f64::NAN,
                        };
                        let k = ((p.grid.origin_mm + (p.core.start + i) as f64 * dx - lo) / dx).round();
                        if !v.is_finite() || k < 0.0 || k >= n as f64 {
                            continue;
                        }
                        let slot = &mut value[k as usize];
                        *slot = if slot.is_nan() { v } else { slot.max(v) };
                    }
                }
            }
            if part.ends {
                close(&mut open, &mut out);
            }
        }
        Ok(())
    })?;
    close(&mut open, &mut out);
    Ok(out)
}

/// A block's figure from its per-position criterion values (NaN: not
/// measured there), and its standard uncertainty (the quarters' standard
/// error), mm.
pub fn block_figure(value: &[f64], edition: Edition) -> Option<(f64, f64)> {
    let n = value.len();
    let figure = |v: &[f64]| figure_of(v, edition);
    let y = figure(value)?;
    let quarters: Vec<f64> = value.chunks(n.div_ceil(4).max(1)).filter_map(figure).collect();
    let u = if quarters.len() >= 2 {
        let m = quarters.iter().sum::<f64>() / quarters.len() as f64;
        let var = quarters.iter().map(|q| (q - m).powi(2)).sum::<f64>() / (quarters.len() - 1) as f64;
        (var / quarters.len() as f64).sqrt()
    } else {
        0.0
    };
    Some((y, u.max(MIN_UNCERTAINTY_MM)))
}

/// The figure of a block's per-position criterion values (NaN: not
/// measured there): under 2006 the 95th percentile, under 2012 the
/// largest; `None` when under half the positions are measured.
pub fn figure_of(values: &[f64], edition: Edition) -> Option<f64> {
    let mut f: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() || f.len() * 2 < values.len() {
        return None;
    }
    f.sort_by(f64::total_cmp);
    Some(match edition {
        Edition::En2006 => f[((f.len() - 1) as f64 * 0.95).round() as usize],
        Edition::En2012 => f[f.len() - 1],
    })
}

/// The least a survey's figure is uncertain by, mm (a figure equal in every
/// quarter is not known better than the profile's resolution).
pub const MIN_UNCERTAINTY_MM: f64 = 1e-4;

/// A straight line `y = a + b·(t − tm)` fitted by weighted least squares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    /// The weighted mean time, years.
    pub tm: f64,
    pub a: f64,
    /// The slope per year.
    pub b: f64,
    /// Standard uncertainties of `a` and `b`, scaled by the reduced χ² when above 1.
    pub ua: f64,
    pub ub: f64,
    /// The reduced χ² (`None` with two points).
    pub chi2_reduced: Option<f64>,
}

/// The weighted fit of `(t, y, u)` points (weights `1/u²`): the slope's
/// uncertainty the fit's, scaled by the residuals' reduced χ² when it is
/// above 1 (scatter the points' uncertainties do not explain widens it,
/// never narrows it). `None` with fewer than two distinct times.
pub fn weighted_fit(pts: &[(f64, f64, f64)]) -> Option<Fit> {
    let distinct = pts.iter().map(|p| p.0).fold(Vec::<f64>::new(), |mut v, t| {
        if !v.contains(&t) {
            v.push(t);
        }
        v
    });
    if distinct.len() < 2 {
        return None;
    }
    let w: Vec<f64> = pts.iter().map(|p| 1.0 / (p.2 * p.2)).collect();
    let sw: f64 = w.iter().sum();
    let tm = pts.iter().zip(&w).map(|(p, w)| w * p.0).sum::<f64>() / sw;
    let a = pts.iter().zip(&w).map(|(p, w)| w * p.1).sum::<f64>() / sw;
    let stt: f64 = pts.iter().zip(&w).map(|(p, w)| w * (p.0 - tm).powi(2)).sum();
    let b = pts.iter().zip(&w).map(|(p, w)| w * (p.0 - tm) * (p.1 - a)).sum::<f64>() / stt;
    let dof = pts.len() - 2;
    let chi2: f64 = pts.iter().zip(&w).map(|(p, w)| w * (p.1 - a - b * (p.0 - tm)).powi(2)).sum();
    let scale = if dof > 0 { (chi2 / dof as f64).max(1.0) } else { 1.0 };
    let chi2_reduced = (dof > 0).then(|| chi2 / dof as f64);
    Some(Fit { tm, a, b, ua: (scale / sw).sqrt(), ub: (scale / stt).sqrt(), chi2_reduced })
}

/// The weighted fit of one block and band.
#[allow(clippy::too_many_arguments)]
fn fit_block(
    start_mm: f64,
    end_mm: f64,
    band: Band,
    limit_mm: Option<f64>,
    figures: Vec<Option<(f64, f64, f64)>>,
    t0: SurveyDate,
    t_last: f64,
    opts: &Options,
) -> BlockTrend {
    let pts: Vec<(f64, f64, f64)> = figures.iter().flatten().copied().collect();
    let mut out = BlockTrend {
        start_mm,
        end_mm,
        band,
        limit_mm,
        figures,
        growth: None,
        chi2_reduced: None,
        crossing: Crossing::NotJudged,
    };
    let Some(fit) = weighted_fit(&pts) else { return out };
    let Fit { tm, a, b, ua, ub, chi2_reduced } = fit;
    out.chi2_reduced = chi2_reduced;
    out.growth = Some((b, ub));
    let Some(limit) = limit_mm else { return out };
    let last = pts.iter().max_by(|p, q| p.0.total_cmp(&q.0)).map_or(0.0, |p| p.1);
    out.crossing = if last > limit {
        Crossing::AlreadyOver
    } else if b <= 0.0 {
        Crossing::NotWithin(opts.horizon_years)
    } else {
        let ts = tm + (limit - a) / b;
        let uts = (ua * ua + (ts - tm).powi(2) * ub * ub).sqrt() / b;
        let day = |t: f64| t0.plus_days((t * crate::recording::survey_info::DAYS_PER_YEAR).round() as i64);
        if ts - t_last > opts.horizon_years {
            Crossing::NotWithin(opts.horizon_years)
        } else {
            match day(ts) {
                Some(date) => Crossing::On {
                    date,
                    earliest: day(ts - 2.0 * uts),
                    latest: if b > 2.0 * ub { day(ts + 2.0 * uts) } else { None },
                },
                None => Crossing::NotWithin(opts.horizon_years),
            }
        }
    };
    out
}

/// The longest line of each laser of an analysis.
fn longest(a: &Analysis) -> Vec<&LaserAnalysis> {
    let mut out: Vec<&LaserAnalysis> = Vec::new();
    for l in &a.lasers {
        match out.iter_mut().find(|o| o.stitched.laser == l.stitched.laser) {
            Some(o) if o.stitched.z.len() < l.stitched.z.len() => *o = l,
            Some(_) => {}
            None => out.push(l),
        }
    }
    out
}

/// Survey `index`'s registration on `first` within the search range.
fn register(index: usize, first: &Analysis, later: &Analysis, opts: &Options) -> Registration {
    let none = Registration { survey: index, shift_mm: None, correlation: 0.0, disputed: false };
    let (fa, la) = (longest(first), longest(later));
    let Some(dx) = fa.first().map(|l| l.stitched.dx_mm) else { return none };
    let hp = |z: &[f64]| en13231::band_pass(z, dx, 2.5 * dx, 500.0).unwrap_or_else(|_| z.to_vec());
    // Every pair on one grid: the first's lines from `lo`, the later's from `llo`.
    let lo = fa.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
    let hi = fa.iter().map(|l| l.stitched.x_mm(l.stitched.z.len())).fold(f64::NEG_INFINITY, f64::max);
    let llo = la.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
    let lhi = la.iter().map(|l| l.stitched.x_mm(l.stitched.z.len())).fold(f64::NEG_INFINITY, f64::max);
    let (nb, na) = (((hi - lo) / dx).round() as usize, ((lhi - llo) / dx).round() as usize);
    let mut pairs = Vec::new();
    for l in &la {
        let Some(f) = fa.iter().find(|f| f.stitched.laser == l.stitched.laser) else { continue };
        let place = |s: &crate::analyze::stitch::Stitched, origin: f64, n: usize| {
            let mut v = vec![f64::NAN; n];
            let o = ((s.x0_mm - origin) / dx).round() as usize;
            for (j, z) in hp(&s.z.to_vec().unwrap_or_default()).into_iter().enumerate() {
                if let Some(slot) = v.get_mut(o + j) {
                    *slot = z;
                }
            }
            v
        };
        pairs.push((place(&l.stitched, llo, na), place(&f.stitched, lo, nb)));
    }
    let ncc = masked_correlation(&pairs);
    if ncc.is_empty() {
        return none;
    }
    // Shift d puts the later's sample j (chainage llo + j dx) on the
    // first's j + d (lo + (j + d) dx): the same chainage at d0.
    let d0 = (llo - lo) / dx;
    let shift = |t: usize| t as f64 - (na as f64 - 1.0) - d0;
    let window = opts.search_mm / dx;
    let min_overlap = 2000.0 / dx;
    let best = (0..ncc.len())
        .filter(|&t| shift(t).abs() <= window && ncc[t].1 >= min_overlap)
        .max_by(|&a, &b| ncc[a].0.total_cmp(&ncc[b].0));
    let Some(t) = best else { return none };
    let frac = if t > 0 && t + 1 < ncc.len() {
        let (a, b, c) = (ncc[t - 1].0, ncc[t].0, ncc[t + 1].0);
        let den = a - 2.0 * b + c;
        if den < 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 }
    } else {
        0.0
    };
    let shift_mm = (shift(t) + frac) * dx;
    let correlation = ncc[t].0;
    Registration {
        survey: index,
        shift_mm: Some(shift_mm),
        correlation,
        disputed: correlation >= 0.9 && shift_mm.abs() > opts.tolerance_mm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn date(s: &str) -> SurveyDate {
        s.parse().unwrap()
    }

    fn fit(points: &[(f64, f64, f64)], limit: Option<f64>) -> BlockTrend {
        let t_last = points.iter().map(|p| p.0).fold(0.0, f64::max);
        let figures = points.iter().map(|&p| Some(p)).collect();
        fit_block(0.0, 50_000.0, en13231::BANDS[1], limit, figures, date("2024-01-01"), t_last, &Options::default())
    }

    #[test]
    fn a_straight_growth_is_recovered_with_its_uncertainty() {
        // 4 µm a year from 8 µm, each figure known to 0.5 µm.
        let b = fit(&[(0.0, 0.008, 5e-4), (1.0, 0.012, 5e-4), (2.0, 0.016, 5e-4)], Some(0.020));
        let (g, u) = b.growth.unwrap();
        assert!((g - 0.004).abs() < 1e-12, "{g}");
        // Exact points: u from the surveys' own uncertainty, σ/√Σ(t − t̄)².
        assert!((u - 5e-4 / 2f64.sqrt()).abs() < 1e-12, "{u}");
        // 0.020 is reached at t = 3: 2027-01-01 (2024 + 3 × 365.2425 days).
        let Crossing::On { date: d, earliest, latest } = &b.crossing else { panic!("{:?}", b.crossing) };
        assert_eq!(d.to_string(), "2027-01-01");
        assert!(earliest.unwrap() < *d && latest.unwrap() > *d);
    }

    #[test]
    fn scatter_widens_the_uncertainty_and_limits_decide() {
        let tight = fit(&[(0.0, 0.008, 1e-4), (1.0, 0.013, 1e-4), (2.0, 0.016, 1e-4)], Some(0.020));
        let (_, u) = tight.growth.unwrap();
        // The residuals (±0.67 µm) dominate the 0.1 µm uncertainties.
        assert!(tight.chi2_reduced.unwrap() > 1.0 && u > 1e-4, "{u}");
        let over = fit(&[(0.0, 0.018, 1e-4), (1.0, 0.021, 1e-4)], Some(0.020));
        assert_eq!(over.crossing, Crossing::AlreadyOver);
        let flat = fit(&[(0.0, 0.010, 1e-4), (1.0, 0.0099, 1e-4)], Some(0.020));
        assert_eq!(flat.crossing, Crossing::NotWithin(10.0));
        let slow = fit(&[(0.0, 0.010, 1e-4), (1.0, 0.0101, 1e-4)], Some(0.020));
        assert_eq!(slow.crossing, Crossing::NotWithin(10.0));
        assert_eq!(fit(&[(0.0, 0.010, 1e-4), (1.0, 0.011, 1e-4)], None).crossing, Crossing::NotJudged);
        assert_eq!(fit(&[(0.0, 0.010, 1e-4)], Some(0.02)).growth, None);
    }
}
