//! A survey from runs: chainage (track position as `km+m`), and recordings
//! of one survey joined into one profile per line.
//!
//! # Chainage
//!
//! Users locate rail by chainage — kilometres and metres along the line,
//! written `12+345.678` — not by an odometer that starts at zero. A run is
//! placed by its [`Placement`]: the chainage of its track position 0 (the
//! odometer's zero) and whether chainage runs up or down with it
//! ([`Heading`]). Every output position is chainage, in mm inside the
//! library (`x0_mm`) and as `km+m` or metres in what users read.
//!
//! # Joining runs
//!
//! Runs of one survey overlap (a trolley run stopped and restarted, a run
//! driven back over the last metres), and their nominal placements are
//! rarely exact: an odometer that crept, a start entered a few metres off.
//! So each run after the first is *registered* on what is joined so far —
//! within what the user said, never over it:
//!
//! * **A given start chainage is taken as given.** The run is registered
//!   only on sections it overlaps by [`JoinOptions::min_overlap_mm`] where
//!   that start puts it (whether runs overlap is the user's to say;
//!   registration says by how much), and moved at most
//!   [`JoinOptions::search_mm`] from it (the stated tolerance: a better
//!   match farther away is not taken). A run whose given start overlaps
//!   nothing is placed there as it is; a clear match registration finds
//!   near it anyway is reported ([`RunJoin::elsewhere`]), not taken.
//!   Without a start, a run is registered wherever it matches, and one
//!   that matches nothing is refused ([`JoinError::NoOverlap`]).
//! * **Registration moves a run only onto a clear match**: a normalised
//!   correlation of at least 0.9 (rail overlapping by chance stays far
//!   below, corrugation mirrored onto itself too), or of at least 0.5 that
//!   stands four times over every other placement searched (runs whose
//!   noise is comparable to the rail's roughness: repeat runs). A weaker
//!   best match leaves the run where the user put it.
//! * **A given heading is kept.** Both headings are tried only when none
//!   is given; with one given, the other is tried too, only to check it:
//!   when it matches clearly better the run is still placed as given and
//!   [`RunJoin::heading_disputed`] says so. The frames' direction
//!   ([`Stitching::direction_disputed`]) is checked the same way.
//!
//! Registration:
//!
//! 1. For each heading, the run's profiles, turned round for a down run,
//!    are cross-correlated with a section's — masked, normalised, summed
//!    over the lines, on the band 2.5·dx–500 mm (the long-wave trend of a
//!    run is its own registration error, not the rail) — by FFT over every
//!    shift that leaves at least [`JoinOptions::min_overlap_mm`] of overlap.
//! 2. The best shift is refined to a fraction of a sample: the RMS of run
//!    minus joined over the overlap, each line's offset and tilt removed,
//!    at the best whole shift and its neighbours; the parabola's minimum.
//! 3. The run is resampled at that shift by a windowed sinc (8 lobes, flat
//!    to 0.01 % down to 3 mm wavelength at 1 mm sampling; a sample whose
//!    kernel reaches a gap stays a gap), each line's offset
//!    and tilt over the overlap is subtracted, and the run is merged
//!    (overlapping samples averaged). The registration's residual, its
//!    shift from the nominal start and the heading chosen are reported
//!    ([`RunJoin`]).
//!
//! Repetitive corrugation makes a correlation peak every wavelength; the
//! broadband roughness every real rail has, the ends of a corrugated zone
//! and the long overlap decide between them, and a second peak within 1 %
//! of the best is reported as an ambiguous registration.
//!
//! # Sections
//!
//! The joined line is kept as *sections*: stretches measured without a gap
//! longer than [`JoinOptions::section_gap_mm`] (longer than a block and the
//! longest EN 13231-3 window: [`section_gap_mm`]). A run placed within that
//! of a section joins it (and bridges two it lies between); farther, it
//! starts a new one. Each section is dense on the grid and the standards run
//! per section, so memory follows what was measured, never the chainage
//! between runs: two runs 100 km apart cost what each costs alone. Runs and
//! sections are numbered from 1, runs in the order given, sections in
//! chainage order.
//!
//! # Memory
//!
//! The joined lines are cell stores ([`crate::analyze::store`]): a few
//! tiles in memory, the rest in a temporary file. A run is merged, checked
//! and trimmed by reading stretches of it (with the resampling kernel's
//! margin), so placing run 1, which is never registered, holds one stretch
//! at a time. Registration correlates vectors: of the run, at most
//! 100 m (at 1 mm: 10⁵ samples) — of what the shifts allowed can lay on the
//! section, the part nearest the run's start (where a stopped and restarted
//! run, or one driven back over the last metres, overlaps the one before);
//! of the section, what those shifts reach (the run's part plus
//! [`JoinOptions::search_mm`] each side with a given start). One shift
//! places the whole run, and 100 m of broadband roughness decides it as
//! surely as more does (the overlap asked for is 2 m); the shifts searched
//! are the same, so `search_mm` means what it did. Without a start the
//! whole section is searched, in chunks of two run windows (at least
//! 100 m) overlapping by one window: every shift that lays the window
//! whole on the section lies whole in one chunk, and a chunk leaves the
//! shifts that hang over its inner edges to its neighbour; the best of the
//! chunks' peaks is the section's (`a_run_without_a_start_is_found_along_a_long_section`:
//! a 60 m run found 520 m along a 700 m section). So registration holds
//! one chunk's correlation (≈ 100 bytes a sample of it), whatever the
//! section's length.
//!
//! Cost: per run four FFT correlations per line and heading of the length
//! of each section it may overlap (`O(N log N)`), then `O(overlap)` per
//! refinement step.

mod register;
mod resample;
mod section;

use std::io;
use std::ops::Range;

use super::stitch::{Direction, Stitched, Stitching};
use register::{Match, residual, search};
use section::Section;

pub use crate::recording::survey_info::{Chainage, Heading, Placement};

/// Options of [`join`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JoinOptions {
    /// Shortest overlap that registers a run, mm.
    pub min_overlap_mm: f64,
    /// With a given start: how far from it registration may move the run, mm.
    pub search_mm: f64,
    /// A stretch of the line without data longer than this separates two
    /// sections, mm; no section spans one.
    pub section_gap_mm: f64,
}

impl Default for JoinOptions {
    fn default() -> Self {
        JoinOptions { min_overlap_mm: 2_000.0, search_mm: 25_000.0, section_gap_mm: 50_000.0 }
    }
}

/// Masked normalised cross-correlation of profile pairs `(a, b)` (NaN a
/// gap), summed over the pairs, all `a` of one length and all `b` of
/// another: for every shift `d` (`a[j]` on `b[j + d]`, `d` from
/// `−(len a − 1)` to `len b − 1`), the correlation and the mean overlap in
/// samples. The registration's own correlation, for the trend's check of
/// one survey against another.
pub fn masked_correlation(pairs: &[(Vec<f64>, Vec<f64>)]) -> Vec<(f64, f64)> {
    if pairs.is_empty() || pairs[0].0.is_empty() || pairs[0].1.is_empty() {
        return Vec::new();
    }
    register::correlate(pairs)
}

/// The shortest stretch without data that separates two sections for a
/// verdict by `verdict`: longer than a block and than the longest EN
/// 13231-3 window, so that no block, window or zone spans two sections.
pub fn section_gap_mm(verdict: &crate::analyze::reprofiling::Options) -> f64 {
    let window = crate::analyze::standards::en13231::BANDS.iter().map(|b| b.window_mm).fold(0.0, f64::max);
    verdict.block_mm.max(window)
}

/// How one run was placed.
#[derive(Debug, Clone, PartialEq)]
pub struct RunJoin {
    /// The run's number, from 1, in the order the runs were given.
    pub run: usize,
    /// The section of the line it lies on, from 1, in chainage order.
    pub section: usize,
    pub heading: Heading,
    /// Chainage of the run's track position 0, m, as used.
    pub start_m: f64,
    /// Used minus nominal start, mm (`None` without a nominal start).
    pub moved_mm: Option<f64>,
    /// Whether the heading was found by registration rather than given.
    pub heading_found: bool,
    /// With a given heading: the registration residual of its best
    /// placement and of the other heading's, µm, when the other's is under
    /// 0.8 of it. The run keeps the heading the user gave; the report says
    /// it disagrees.
    pub heading_disputed: Option<(f64, f64)>,
    /// Placed as given because its given start overlaps no earlier run:
    /// where registration would have moved it (mm from the given start)
    /// and the correlation there, when that is a clear match (at least
    /// 0.9). Not taken: the report says the chainage may be wrong.
    pub elsewhere: Option<(f64, f64)>,
    /// How its frames were stitched (never `Auto`), and with a given
    /// direction, whether the other registered clearly better
    /// ([`Stitching::direction_disputed`]).
    pub direction: Direction,
    pub direction_disputed: Option<(f64, f64)>,
    /// The overlap it was registered on, mm (0: placed as given, not registered).
    pub overlap_mm: f64,
    /// RMS of run minus joined over the overlap after the correction, µm (mean over the lines).
    pub residual_um: Option<f64>,
    /// The correlation's best peak and the best peak at least a quarter of
    /// the search away from it (1 is perfect agreement).
    pub correlation: Option<(f64, f64)>,
}

impl RunJoin {
    /// Whether registration placed it (rather than its placement as given).
    pub fn registered(&self) -> bool {
        self.correlation.is_some()
    }

    /// The chainage of the run's track position `x_mm` (its odometer for
    /// a frame's centre), mm.
    pub fn chainage_mm(&self, x_mm: f64) -> f64 {
        to_chainage(self.start_m * 1000.0, self.heading, x_mm)
    }

    /// Whether another placement matched nearly as well.
    pub fn ambiguous(&self) -> bool {
        self.correlation.is_some_and(|(best, second)| second > 0.99 * best)
    }
}

/// A run's line turned into chainage orientation: the chainage, mm, of
/// its first sample when the run's start is 0.
pub(super) fn origin(s: &Stitched, heading: Heading) -> f64 {
    match heading {
        Heading::Up => s.x0_mm,
        Heading::Down => -(s.x0_mm + (s.z.len() as f64 - 1.0) * s.dx_mm),
    }
}

/// Samples `range` of a run's line turned into chainage orientation
/// (reversed for a down run), clipped to the line.
pub(super) fn read_oriented(s: &Stitched, heading: Heading, range: Range<usize>) -> io::Result<Vec<f64>> {
    let n = s.z.len();
    let (a, b) = (range.start.min(n), range.end.min(n));
    match heading {
        Heading::Up => s.z.read(a..b),
        Heading::Down => {
            let mut v = s.z.read(n - b.max(a)..n - a)?;
            v.reverse();
            Ok(v)
        }
    }
}

/// Why runs could not be joined.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JoinError {
    /// The runs were stitched at different spacings (runs numbered from 1).
    #[error("run {run} is sampled every {dx_mm} mm, run 1 every {first_mm} mm")]
    Spacing { run: usize, dx_mm: f64, first_mm: f64 },
    /// A run without a start chainage matches no earlier run (runs numbered from 1).
    #[error(
        "run {run} matches no earlier run (no clear registration over {min_mm:.0} mm or more): give its start chainage (--chainage KM+M[:up|:down])"
    )]
    NoOverlap { run: usize, min_mm: f64 },
    /// The temporary file holding the joined line failed (the error's
    /// text: an I/O error is not `Clone`).
    #[error("cannot keep the joined survey line in a temporary file: {0}")]
    Spill(String),
}

impl From<io::Error> for JoinError {
    fn from(e: io::Error) -> JoinError {
        JoinError::Spill(e.to_string())
    }
}

/// A run's position `x` (mm) on the line: chainage mm.
pub(super) fn to_chainage(start_mm: f64, heading: Heading, x_mm: f64) -> f64 {
    match heading {
        Heading::Up => start_mm + x_mm,
        Heading::Down => start_mm - x_mm,
    }
}

/// Joins the runs' stitchings into one survey line on chainage: run 1 is
/// placed as its placement says (chainage 0 and up by default), each later
/// one registered on the runs before it (see the module docs). Lines are
/// matched by number. The profiles come out per section (their
/// [`Stitched::section`]), in chainage order.
pub fn join(
    runs: Vec<Stitching>,
    placements: &[Placement],
    opts: &JoinOptions,
) -> Result<(Stitching, Vec<RunJoin>), JoinError> {
    let Some(first) = runs.iter().flat_map(|r| r.lasers.first()).next() else {
        let empty = Stitching {
            direction: Direction::Forward,
            direction_residuals_um: None,
            direction_given: false,
            lasers: Vec::new(),
            share: None,
        };
        return Ok((empty, vec![]));
    };
    let dx = first.dx_mm;
    let p0 = placements.first().copied().unwrap_or_default();
    let (start0_mm, heading0) = (p0.start_m.unwrap_or(0.0) * 1000.0, p0.heading.unwrap_or(Heading::Up));
    // The grid: run 1's samples exactly on it.
    let g0 = (start0_mm + origin(first, heading0)).rem_euclid(dx);
    let mut sections: Vec<Section> = Vec::new();
    let mut report: Vec<RunJoin> = Vec::new();
    let (direction, direction_residuals_um, direction_given) =
        (runs[0].direction, runs[0].direction_residuals_um, runs[0].direction_given);
    let section_gap = (opts.section_gap_mm / dx).ceil() as i64;
    // The runs' stitch shares, summed (each run's error is its own).
    let mut share: Option<crate::analyze::stitch::StitchShare> = None;
    for r in runs.iter().filter_map(|r| r.share.as_ref()) {
        share.get_or_insert_default().merge(r);
    }
    for (r, run) in runs.into_iter().enumerate() {
        if let Some(l) = run.lasers.iter().find(|l| (l.dx_mm - dx).abs() > 1e-9 * dx) {
            return Err(JoinError::Spacing { run: r + 1, dx_mm: l.dx_mm, first_mm: dx });
        }
        if run.lasers.is_empty() {
            continue;
        }
        let place = placements.get(r).copied().unwrap_or_default();
        let Placed { heading, lo, frac, correlation, on, heading_disputed, elsewhere, e } =
            place_run(&sections, &run, r, place, (g0, dx), opts)?;
        let start_mm = (lo as f64 + frac - e) * dx;
        // Every section within a section gap of the run is one with it now.
        let (rlo, rhi) = extent(&run, heading, lo, (g0, dx)).unwrap_or((lo, lo + 1));
        let near =
            |s: &Section| s.span().is_some_and(|(slo, shi)| slo - rhi <= section_gap && rlo - shi <= section_gap);
        let mut merged = Section::default();
        let mut kept = Vec::new();
        for (k, s) in sections.into_iter().enumerate() {
            if near(&s) || on == Some(k) { merged.absorb(s)? } else { kept.push(s) }
        }
        sections = kept;
        let (residual_sum, overlap_samples) = merged.merge_run(r, &run, (heading, lo, frac, start_mm), (g0, dx))?;
        sections.push(merged);
        report.push(RunJoin {
            run: r + 1,
            section: 0,
            heading,
            start_m: start_mm / 1000.0,
            moved_mm: place.start_m.map(|m| start_mm - m * 1000.0),
            heading_found: place.heading.is_none() && correlation.is_some(),
            heading_disputed,
            elsewhere,
            direction: run.direction,
            direction_disputed: run.direction_disputed(),
            overlap_mm: overlap_samples as f64 * dx,
            residual_um: (residual_sum.1 > 0).then(|| residual_sum.0 / residual_sum.1 as f64),
            correlation,
        });
    }
    sections.sort_by_key(|s| s.span().map_or(0, |s| s.0));
    let mut lasers = Vec::new();
    for (k, s) in sections.into_iter().enumerate() {
        for j in report.iter_mut().filter(|j| s.runs.contains(&(j.run - 1))) {
            j.section = k + 1;
        }
        lasers.extend(s.into_stitched(k + 1, g0, dx)?);
    }
    Ok((Stitching { direction, direction_residuals_um, direction_given, lasers, share }, report))
}

/// Where and how a run goes on the line ([`place_run`]).
struct Placed {
    heading: Heading,
    /// Whole grid index of its start, and the fraction of a sample beyond.
    lo: i64,
    frac: f64,
    /// With registration: its best and second correlation, and the section.
    correlation: Option<(f64, f64)>,
    on: Option<usize>,
    heading_disputed: Option<(f64, f64)>,
    elsewhere: Option<(f64, f64)>,
    /// The run's offset from the grid at that heading, samples.
    e: f64,
}

/// Places run `r` (index from 0) on the sections so far: registered where
/// the user's placement allows it and the match is clear, else as given
/// (see the module docs).
fn place_run(
    sections: &[Section],
    run: &Stitching,
    r: usize,
    place: Placement,
    (g0, dx): (f64, f64),
    opts: &JoinOptions,
) -> Result<Placed, JoinError> {
    let any = &run.lasers[0];
    let headings: Vec<Heading> = match (place.heading, r) {
        (Some(h), _) => vec![h],
        (None, 0) => vec![Heading::Up],
        (None, _) => vec![Heading::Up, Heading::Down],
    };
    // The run's lines lie a fraction `e(h)` of a sample off the grid.
    let e = |h: Heading| {
        let q = (origin(any, h) - g0) / dx;
        q - q.round()
    };
    let nominal = |h: Heading| place.start_m.map(|m| m * 1000.0 / dx + e(h));
    // A nominal start applies to the heading it was given with; searched
    // headings share it.
    let n = nominal(headings[0]);
    // The headings at which the run where its start puts it comes within
    // `reach` samples of section `k` (all without a start, none for run 1).
    let within = |k: usize, reach: i64| -> Vec<Heading> {
        let Some(n) = n else { return if r > 0 { headings.clone() } else { Vec::new() } };
        let Some((slo, shi)) = sections[k].span() else { return Vec::new() };
        let near = |h: &Heading| {
            extent(run, *h, n.round() as i64, (g0, dx)).is_some_and(|(lo, hi)| slo - hi <= reach && lo - shi <= reach)
        };
        headings.iter().copied().filter(near).collect()
    };
    // Registration places it only on sections (and at headings) it overlaps
    // where the user put it (the user's chainage says whether runs overlap;
    // registration only says by how much).
    let min_overlap = (opts.min_overlap_mm / dx).ceil() as i64;
    let mut best: Option<(usize, Match)> = None;
    // The best correlation of the placements other than the best: its
    // rivals (the other heading's, other sections').
    let mut rival = 0.0f64;
    for (k, sec) in sections.iter().enumerate() {
        for m in search(&sec.lines, run, &within(k, -min_overlap), (g0, dx), n, opts)? {
            match best {
                Some((_, b)) if m.correlation <= b.correlation => rival = rival.max(m.correlation),
                _ => {
                    rival = rival.max(best.map_or(0.0, |(_, b)| b.correlation));
                    best = Some((k, m));
                }
            }
        }
    }
    let clear = best.filter(|(_, m)| is_clear(m, rival));
    // A run placed as given is still checked: registration near its given
    // start (within the tolerance) that finds a clear match is reported,
    // not taken.
    let mut elsewhere = None;
    if let (Some(n), None) = (n, clear) {
        let window = (opts.search_mm / dx).ceil() as i64;
        for (k, sec) in sections.iter().enumerate() {
            for m in search(&sec.lines, run, &within(k, window), (g0, dx), Some(n), opts)? {
                if is_clear(&m, 0.0) && elsewhere.is_none_or(|(_, c)| m.correlation > c) {
                    elsewhere = Some(((m.lo as f64 - n) * dx, m.correlation));
                }
            }
        }
    }
    let heading_disputed = match (best, headings.as_slice()) {
        (Some((k, m)), [given]) => heading_dispute(&sections[k], run, m, *given, n, (g0, dx), opts)?,
        _ => None,
    };
    match clear {
        // Registration moves a run only onto a clear match.
        Some((k, m)) => {
            let (lo, frac, _) = refine(&sections[k], run, m, (g0, dx))?;
            let correlation = Some((m.correlation, m.second));
            Ok(Placed {
                heading: m.heading,
                lo,
                frac,
                correlation,
                on: Some(k),
                heading_disputed,
                elsewhere,
                e: e(m.heading),
            })
        }
        _ => {
            if r > 0 && !sections.is_empty() && place.start_m.is_none() {
                return Err(JoinError::NoOverlap { run: r + 1, min_mm: opts.min_overlap_mm });
            }
            let h = place.heading.unwrap_or(Heading::Up);
            let s = nominal(h).unwrap_or(e(h));
            let lo = s.round();
            // Run 1 is on the grid by construction; a placed run may not be.
            let frac = if (s - lo).abs() < 1e-6 { 0.0 } else { s - s.floor() };
            let lo = if frac == 0.0 { lo } else { s.floor() };
            Ok(Placed {
                heading: h,
                lo: lo as i64,
                frac,
                correlation: None,
                on: None,
                heading_disputed,
                elsewhere,
                e: e(h),
            })
        }
    }
}

/// A given heading checked against the other, by the residual of each
/// one's best placement on the section of `m` (corrugation correlates with
/// itself mirrored; only the residual tells): both residuals, µm, when
/// the other's is clearly smaller.
fn heading_dispute(
    section: &Section,
    run: &Stitching,
    m: Match,
    given: Heading,
    n: Option<f64>,
    grid: (f64, f64),
    opts: &JoinOptions,
) -> io::Result<Option<(f64, f64)>> {
    let other = match given {
        Heading::Up => Heading::Down,
        Heading::Down => Heading::Up,
    };
    let Some(&o) = search(&section.lines, run, &[other], grid, n, opts)?.first() else { return Ok(None) };
    let (Some(given_um), Some(other_um)) = (refine(section, run, m, grid)?.2, refine(section, run, o, grid)?.2) else {
        return Ok(None);
    };
    Ok((other_um < HEADING_AGREEMENT * given_um).then_some((given_um, other_um)))
}

/// A given heading is disputed when the other heading's registration
/// residual is under this share of its own (as [`Direction::Auto`] judges
/// the frames).
const HEADING_AGREEMENT: f64 = 0.8;

/// The correlation of a match clear enough to register on (or to report
/// against a placement as given) whatever else the search found:
/// normalised, band-passed, over at least the registration's overlap. Rail
/// overlapping by chance stays far below; corrugation mirrored onto itself
/// does not (a run over a corrugated stretch given the wrong heading:
/// 0.73, residual 40 µm, against 0.98 and 0.6 µm where it belongs,
/// `host/tests/it/hostile_survey.rs`).
const CLEAR_MATCH: f64 = 0.9;

/// A weaker correlation is still a clear match when it stands this many
/// times over every other placement searched (its heading's best peak
/// outside the main lobe, the other heading's best, other sections'):
/// runs of one rail whose own noise is comparable to the rail's roughness
/// (repeat runs averaged for just that reason) correlate at 0.7–0.8 where
/// they belong and under 0.1 anywhere else (2 µm of roughness in the
/// sensor's floor: `sim::repeat`'s registration test). Chance peaks of the
/// many shifts searched cluster near their maximum, so the best of them is
/// never several times the next; corrugation repeats its peak a wavelength
/// away, so a periodic rail's rival is nearly the best itself.
const CLEAR_RATIO: f64 = 4.0;

/// The least correlation a clear match has however far it stands over its
/// rivals: under it the shift's refinement is too noisy to average runs by.
const LEAST_MATCH: f64 = 0.5;

/// Whether a match is clear enough to register on, against the best
/// correlation `rival` of the other placements searched.
fn is_clear(m: &Match, rival: f64) -> bool {
    m.correlation >= CLEAR_MATCH || (m.correlation >= LEAST_MATCH && m.correlation >= CLEAR_RATIO * rival.max(m.second))
}

/// Grid indices `lo..hi` the run covers with its start at index `start`.
fn extent(run: &Stitching, h: Heading, start: i64, (g0, dx): (f64, f64)) -> Option<(i64, i64)> {
    let at = |s: &Stitched| {
        let x0 = match h {
            Heading::Up => s.x0_mm,
            Heading::Down => -(s.x0_mm + (s.z.len() as f64 - 1.0) * s.dx_mm),
        };
        let o = ((x0 - g0) / dx).round() as i64;
        (o, o + s.z.len() as i64)
    };
    let lo = run.lasers.iter().map(|s| at(s).0).min()?;
    let hi = run.lasers.iter().map(|s| at(s).1).max()?;
    Some((start + lo, start + hi))
}

/// The match's whole start refined to a fraction of a sample: the
/// parabola through the overlap residuals at the start and its
/// neighbours. Returns (whole start, fraction in 0..1, the residual at
/// the whole start, µm).
fn refine(section: &Section, run: &Stitching, m: Match, grid: (f64, f64)) -> io::Result<(i64, f64, Option<f64>)> {
    let at = |d: i64| residual(&section.lines, run, m.heading, m.lo + d, grid).map(|r| r.map(|r| r.0));
    let here = at(0)?;
    let frac = match (at(-1)?, here, at(1)?) {
        (Some(a), Some(b), Some(c)) => {
            let (a, b, c) = (a * a, b * b, c * c);
            let den = a - 2.0 * b + c;
            if den > 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 }
        }
        _ => 0.0,
    };
    // A negative fraction is the previous sample's positive one.
    Ok(if frac < 0.0 { (m.lo - 1, 1.0 + frac, here) } else { (m.lo, frac, here) })
}
