//! The live EN 13231-3 band figures of `cms-host listen`: each line's and
//! the running band's RMS and moving-window mean peak-to-peak per band,
//! over the last stretch stitched and since the start, against the
//! edition's limits, with the noise floor `analyze` measures — what
//! `analyze` would say of the run so far.
//!
//! # How the run is cut
//!
//! Frames are stitched as they arrive ([`crate::analyze::stitch::Stitcher`],
//! analyze's own, O(points) a frame) into *stretches* of
//! [`LiveOptions::stretch_mm`] of travel, each starting
//! [`LiveOptions::overlap_mm`] before the last one ends (two stitchers
//! run over the overlap). The overlap is a window of the longest band
//! evaluated and its filter edge zones at both ends (2 200 mm for the
//! 100–300 mm band): a window centred in the *core* of a stretch (from
//! half the overlap after its start to half the overlap before its end)
//! has all its samples, settled, inside it. The cores tile the run, so
//! every window position is counted once, in the stretch that holds it
//! whole, as `analyze` counts it once on the whole line. A stretch is
//! judged through analyze's code: its lines laid on one grid and read as
//! one piece ([`pieces::piece_of`]: each line, their mean — the running
//! band — and their Helmert null combinations, band-filtered by
//! [`en13231::trace`]), the floor summed as [`crate::analyze::floor::measure`] sums it
//! ([`FloorSums`]: each line's own floor from the three pairs, and the
//! running band's profile and floor with its lines weighted by their own
//! noise, `1/σᵢ²` per band, by [`Floor::running_band_weights`] and
//! [`Floor::running_band`] as `analyze` weights them), each band's
//! figures as [`en13231::BandSums`], its verdict by [`BandJudgement`] (a
//! band whose floor is over `1/√2` of the limit is *not judged*, a window
//! exceeds over `√(limit² + floor²)`).
//!
//! When a stretch's travel is complete its core's sums join those of the
//! run; the stretch still open is judged on demand ([`LiveBands::report`],
//! at most once per [`EVAL_EVERY_MM`] of new travel) over its core so far,
//! its end taken as the record's end, as `analyze` of the recording so far
//! would. Memory: two stretches' cells (16 bytes per millimetre, lane and
//! laser) and fixed sums, whatever the run's length.
//!
//! # What differs from `analyze`
//!
//! * The stitch: `analyze` registers every frame onto the whole line, the
//!   live view onto its stretch. Offsets between stretches do not reach
//!   the bands (each stretch is filtered on its own, its edges outside
//!   the core); what differs is the registration's random walk inside a
//!   stretch.
//! * The exceedance threshold, and the lines' weights in the running
//!   band's profile, use the floor known when the stretch was summed,
//!   `analyze` the whole run's.
//! * The floor leaves out the stitch's share common to the lines, which
//!   `analyze` propagates from the whole line's registration.
//!
//! # The 300–1000 mm band
//!
//! Its window and edge zones are 9 m (the shorter bands' 2.2 m): stretches
//! cut for it would make the shorter bands' recent figures 18 m old and
//! judging them four times dearer. So it has its own series of stretches
//! (18 m, each starting 9 m before the last one ends,
//! judged every [`LONG_EVAL_EVERY_MM`]), cut and judged the same way, the
//! shorter bands theirs; the report takes each band from its series. Until
//! 9 m of track have stitched without a gap it is *not evaluated yet*, as
//! `analyze` says of a record too short for it.
//!
//! Each figure carries its uncertainty ([`Figures`]): the spread of the
//! window values over the independent windows the stretch holds, and
//! [`SYSTEMATIC_SHARE`] of the value for the stitch and the filters' cut
//! edges; `live_bands_agree_with_analyze` checks the live figures of a
//! recorded run against `analyze`'s within it.
//!
//! # Frames that would not stitch
//!
//! A frame the stretch's stitcher joins without registration (overlap
//! under [`crate::analyze::stitch::Options::min_overlap_mm`]: too fast, or
//! frames missing) is flagged as it is pushed ([`Unstitched`]), with its
//! overlap: these are the joins `analyze` reports.

use std::collections::VecDeque;
use std::ops::Range;

use serde::Serialize;

use crate::analyze::floor::{BandFloor, BandJudgement, Floor, FloorSums};
use crate::analyze::pieces::{self, Piece, Wanted};
use crate::analyze::standards::en13231::{self, BandSums, BandTrace, EDGE_WAVELENGTHS, Edition};
use crate::analyze::standards::fmt_mm;
use crate::analyze::stitch::{self, Direction, FramePoints, Stitched, Stitcher};

/// The stretch still open is judged again after this much new travel, mm.
pub const EVAL_EVERY_MM: f64 = 250.0;
/// The same for the 300–1000 mm band's series of stretches, mm (a tenth
/// of its 5 m window: its figures move slowly).
pub const LONG_EVAL_EVERY_MM: f64 = 500.0;
/// Bands judged on the short stretches: 10–30, 30–100 and 100–300 mm
/// (the others on the long ones).
const SHORT_BANDS: usize = 3;
/// Share of a figure stated as its systematic uncertainty: the stitch's
/// registration inside a stretch and the filters' cut edges (≤ 1 % at
/// two longest wavelengths, [`EDGE_WAVELENGTHS`]).
pub const SYSTEMATIC_SHARE: f64 = 0.01;
/// Frames that would not stitch kept for the page (the count goes on).
const FLAGS_KEPT: usize = 16;

/// What the live figures evaluate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveOptions {
    /// The first `bands` of [`en13231::BANDS`] (1 to 4; 4: the
    /// 300–1000 mm band too, on stretches of its own).
    pub bands: usize,
    pub edition: Edition,
    pub stitch: stitch::Options,
}

impl Default for LiveOptions {
    fn default() -> Self {
        LiveOptions { bands: 4, edition: Edition::default(), stitch: stitch::Options::default() }
    }
}

impl LiveOptions {
    /// What two of the shorter bands' stretches share: the longest of
    /// their windows and its edge zones at both ends, mm.
    pub fn overlap_mm(&self) -> f64 {
        overlap_of(&self.short())
    }

    /// The travel of one of the shorter bands' stretches: twice the overlap, mm.
    pub fn stretch_mm(&self) -> f64 {
        2.0 * self.overlap_mm()
    }

    /// The bands judged on the short stretches.
    fn short(&self) -> Range<usize> {
        0..self.bands.clamp(1, SHORT_BANDS)
    }
}

/// A window of the longest band of `bands` and its edge zones at both ends, mm.
fn overlap_of(bands: &Range<usize>) -> f64 {
    en13231::BANDS[bands.clone()].iter().map(|b| b.window_mm + 2.0 * EDGE_WAVELENGTHS * b.hi_mm).fold(0.0, f64::max)
}

/// A frame that would not stitch.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Unstitched {
    pub seq: u32,
    pub odometer_mm: f64,
    pub laser: usize,
    /// Its overlap with the frames before it, mm (0: none, a gap).
    pub overlap_mm: f64,
    /// "gap" (no overlap) or "too fast" (some, under what registers a frame).
    pub kind: &'static str,
}

/// One figure and its uncertainty (module docs), µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Figures {
    pub rms_um: f64,
    pub rms_u_um: f64,
    /// Mean over the window positions of the mean peak-to-peak.
    pub mean_pp_um: f64,
    pub mean_pp_u_um: f64,
    pub worst_mean_pp_um: f64,
    /// Window positions over the threshold, %.
    pub exceeding_percent: f64,
    /// Samples whose |band value| is over the 2012 limit, % (bands with one).
    pub abs_exceeding_percent: Option<f64>,
    pub windows: usize,
}

/// One band of one line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandLive {
    /// "10–30 mm".
    pub band: String,
    pub limit_um: Option<f64>,
    /// Over the last stretch stitched.
    pub recent: Option<Figures>,
    /// Since the start.
    pub since: Option<Figures>,
    /// The floor of this profile in the quantity the edition judges, µm.
    pub floor_um: Option<f64>,
    /// "within", "over", "not judged" or "not evaluated".
    pub state: &'static str,
    /// Why, in words (the floor and the limit where not judged).
    pub why: String,
}

/// One profile's bands: a laser's line, or the running band (their mean).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LineLive {
    /// `Some(k)` for laser k, `None` for the running band.
    pub laser: Option<usize>,
    pub bands: Vec<BandLive>,
}

/// The live band figures of a run so far.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandsReport {
    /// "EN 13231-3:2006".
    pub edition: &'static str,
    /// Track judged since the start and in the last stretch, mm.
    pub since_mm: f64,
    pub recent_mm: f64,
    pub lines: Vec<LineLive>,
    /// Frames that would not stitch: all of them, and the latest.
    pub unstitched: usize,
    pub latest_unstitched: Vec<Unstitched>,
}

/// Band sums of one profile, per band.
type Sums4 = [BandSums; 4];

/// The window-value spread of one band (for its uncertainty).
#[derive(Debug, Clone, Copy, Default)]
struct Spread {
    n: f64,
    sum: f64,
    sq: f64,
}

/// What a run (or a stretch) summed: per line and for the running band.
#[derive(Debug, Clone, Default)]
struct RunSums {
    /// Per laser (in order met).
    lines: Vec<(usize, Sums4, [Spread; 4])>,
    mean: Option<(Sums4, [Spread; 4])>,
    floor: FloorSums,
    /// Lines combined into the running band.
    combined: usize,
    samples: usize,
}

/// One stretch being stitched.
struct Open {
    stitcher: Stitcher,
    /// Odometer of its first frame, mm.
    from_mm: f64,
    /// Track position where its core starts (`None`: the run's first stretch).
    core_from_mm: Option<f64>,
    /// Unregistered joins seen per laser.
    joins: [usize; 3],
}

/// The live band state of a run (module docs).
pub struct LiveBands {
    opts: LiveOptions,
    /// The bands this series of stretches judges.
    span: Range<usize>,
    /// The open stretch is judged again after this much new travel, mm.
    every_mm: f64,
    /// The 300–1000 mm band's own series of stretches (module docs).
    long: Option<Box<LiveBands>>,
    current: Option<Open>,
    next: Option<Open>,
    /// The direction of travel: +1 odometer counting up, −1 down.
    travel: f64,
    /// Decided from the first stretch judged (`Auto` before).
    direction: Direction,
    done: RunSums,
    done_mm: f64,
    /// The open stretch's last judgement and the odometer it was made at.
    report: Option<BandsReport>,
    judged_at_mm: Option<f64>,
    newest_mm: f64,
    unstitched: usize,
    flags: VecDeque<Unstitched>,
    /// The last completed stretch's sums (recent figures until the open
    /// one is judged).
    last: Option<(RunSums, f64)>,
}

impl Default for LiveBands {
    fn default() -> Self {
        LiveBands::new(LiveOptions::default())
    }
}

impl LiveBands {
    pub fn new(opts: LiveOptions) -> LiveBands {
        let long =
            (opts.bands >= 4).then(|| Box::new(LiveBands::series(opts, SHORT_BANDS..4, LONG_EVAL_EVERY_MM, None)));
        LiveBands::series(opts, opts.short(), EVAL_EVERY_MM, long)
    }

    /// One series of stretches, judging the bands of `span`.
    fn series(opts: LiveOptions, span: Range<usize>, every_mm: f64, long: Option<Box<LiveBands>>) -> LiveBands {
        LiveBands {
            opts,
            span,
            every_mm,
            long,
            current: None,
            next: None,
            travel: 0.0,
            direction: opts.stitch.direction,
            done: RunSums::default(),
            done_mm: 0.0,
            report: None,
            judged_at_mm: None,
            newest_mm: f64::NAN,
            unstitched: 0,
            flags: VecDeque::new(),
            last: None,
        }
    }

    fn open(&self, from_mm: f64, core_from_mm: Option<f64>) -> Option<Open> {
        let opts = stitch::Options { direction: self.direction, ..self.opts.stitch };
        Stitcher::new(&opts).ok().map(|stitcher| Open { stitcher, from_mm, core_from_mm, joins: [0; 3] })
    }

    /// Takes one frame (in the order the head sent them).
    pub fn add(&mut self, f: &FramePoints) {
        let o = f.odometer_mm;
        if !o.is_finite() || f.points() == 0 {
            return;
        }
        if let Some(l) = &mut self.long {
            l.add(f);
        }
        self.newest_mm = o;
        if self.current.is_none() {
            self.current = self.open(o, None);
        }
        let Some(from) = self.current.as_ref().map(|c| c.from_mm) else { return };
        if self.travel == 0.0 && (o - from).abs() > 1.0 {
            self.travel = (o - from).signum();
        }
        let travelled = (o - from) * self.travel;
        let overlap = overlap_of(&self.span);
        let stretch = 2.0 * overlap;
        if travelled >= stretch - overlap && self.next.is_none() {
            self.next = self.open(o, Some(o + self.travel * overlap / 2.0));
        }
        if travelled >= stretch {
            self.complete();
        }
        self.push(f);
    }

    /// Pushes a frame into the open stitchers, flagging the current one's
    /// unregistered joins.
    fn push(&mut self, f: &FramePoints) {
        if let Some(n) = &mut self.next {
            n.stitcher.push(f);
        }
        let direction = self.direction;
        let Some(c) = &mut self.current else { return };
        c.stitcher.push(f);
        for (laser, seen) in c.joins.iter_mut().enumerate() {
            let joins = c.stitcher.joins(laser, direction);
            for j in &joins[(*seen).min(joins.len())..] {
                self.unstitched += 1;
                self.flags.push_back(Unstitched {
                    seq: j.seq,
                    odometer_mm: f.odometer_mm,
                    laser,
                    overlap_mm: j.overlap_mm,
                    kind: if j.overlap_mm > 0.0 { "too fast" } else { "gap" },
                });
                if self.flags.len() > FLAGS_KEPT {
                    self.flags.pop_front();
                }
            }
            *seen = joins.len();
        }
    }

    /// Ends the current stretch: its core joins the run's sums.
    fn complete(&mut self) {
        let Some(mut c) = self.current.take() else { return };
        let core_to = self.next.as_ref().and_then(|n| n.core_from_mm);
        if let Some((core, whole)) = self.judge(&mut c, core_to) {
            self.done_mm += core.samples as f64 * self.opts.stitch.dx_mm;
            self.done.merge(&core);
            self.last = Some(whole);
        }
        self.current = self.next.take();
        self.report = None;
        self.judged_at_mm = None;
    }

    /// Judges a stretch: the sums of its core (up to `core_to_mm`, or its
    /// end) and, for the recent figures, of all of it with its length, mm.
    fn judge(&mut self, c: &mut Open, core_to_mm: Option<f64>) -> Option<(RunSums, (RunSums, f64))> {
        let stitching = c.stitcher.peek().ok()?;
        if self.direction == Direction::Auto && matches!(stitching.direction_residuals_um, Some((Some(_), Some(_)))) {
            self.direction = stitching.direction;
        }
        let lines: Vec<(&Stitched, [bool; 4])> =
            stitching.lasers.iter().map(|s| (s, evaluated(s, &self.span))).collect();
        let first = lines.first()?.0;
        let grid = crate::analyze::Grid::of_lines(&lines.iter().map(|l| l.0).collect::<Vec<_>>(), first.dx_mm);
        let lasers: Vec<usize> = lines.iter().map(|l| l.0.laser).collect();
        let want = Wanted { lines: true, mean: false, nulls: true };
        let mut piece = pieces::piece_of(1, &lines, want, 0..grid.len, 0..grid.len, None).ok()??;
        let index = |x: f64| ((x - grid.origin_mm) / grid.dx_mm).round().clamp(0.0, grid.len as f64) as usize;
        let (a, b) = match (c.core_from_mm, core_to_mm) {
            (Some(f), Some(t)) => (index(f.min(t)), index(f.max(t))),
            (Some(f), None) if self.travel < 0.0 => (0, index(f)),
            (Some(f), None) => (index(f), grid.len),
            (None, Some(t)) if self.travel < 0.0 => (index(t), grid.len),
            (None, Some(t)) => (0, index(t)),
            (None, None) => (0, grid.len),
        };
        let mut sums = self.done.floor.clone();
        let mut core = RunSums::default();
        if let Some(rb) = &piece.band {
            core.floor.add(rb, &lasers, a..b);
            sums.merge(&core.floor);
        }
        let floor = sums.floor(lasers.len().max(2), grid.dx_mm, (self.done.samples + (b - a)) as f64 * grid.dx_mm);
        // The running band's profile with its lines weighted by their own
        // floors known so far, as analyze weights them over the survey's.
        let weights = floor.running_band_weights(&lasers);
        let mean = Wanted { lines: false, mean: true, nulls: false };
        let weighted = pieces::piece_of(1, &lines, mean, 0..grid.len, 0..grid.len, weights.as_deref()).ok()??;
        if let (Some(rb), Some(w)) = (piece.band.as_mut(), weighted.band) {
            rb.mean = w.mean;
        }
        core.add_piece(&piece, a..b, &floor, &self.span);
        let mut whole = RunSums { floor: core.floor.clone(), ..RunSums::default() };
        whole.add_piece(&piece, 0..grid.len, &floor, &self.span);
        Some((core, (whole, grid.len as f64 * grid.dx_mm)))
    }

    /// The figures so far: the open stretch judged again when the head
    /// has travelled [`EVAL_EVERY_MM`] since it last was (the 300–1000 mm
    /// band's, [`LONG_EVAL_EVERY_MM`]; `None` before any calibrated frame).
    pub fn report(&mut self) -> Option<&BandsReport> {
        let stale = self.judged_at_mm.is_none_or(|at| (self.newest_mm - at).abs() >= self.every_mm);
        if stale || self.report.is_none() {
            self.judge_series();
        }
        self.with_long(false)
    }

    /// The figures so far, the open stretches judged now (what
    /// [`LiveBands::report`] does when they are stale; its cost is the
    /// `live/bands_judge` benchmark's).
    pub fn judge_open(&mut self) -> Option<&BandsReport> {
        self.judge_series();
        self.with_long(true)
    }

    /// The report with the 300–1000 mm band's figures from its own series
    /// (judged `now`, or when stale).
    fn with_long(&mut self, now: bool) -> Option<&BandsReport> {
        if let (Some(long), Some(report)) = (&mut self.long, &mut self.report) {
            let span = long.span.clone();
            let from_long = if now { long.judge_open() } else { long.report() };
            if let Some(lr) = from_long {
                report.take_bands(lr, &span);
            }
        }
        self.report.as_ref()
    }

    /// Judges this series' open stretch now.
    fn judge_series(&mut self) {
        let Some(mut c) = self.current.take() else { return };
        let open = self.judge(&mut c, None);
        self.current = Some(c);
        self.judged_at_mm = Some(self.newest_mm);
        let mut since = self.done.clone();
        let mut since_mm = self.done_mm;
        if let Some((core, whole)) = open {
            since.merge(&core);
            since_mm += core.samples as f64 * self.opts.stitch.dx_mm;
            self.last = Some(whole);
        }
        self.report = Some(self.build(&since, since_mm));
    }

    fn build(&self, since: &RunSums, since_mm: f64) -> BandsReport {
        let dx = self.opts.stitch.dx_mm;
        let (recent, recent_mm) = self.last.as_ref().map_or((None, 0.0), |(s, l)| (Some(s), *l));
        let k = since.combined.max(recent.map_or(0, |r| r.combined));
        let floor = since.floor.floor(k.max(2), dx, since_mm);
        let lasers: Vec<usize> = since.lines.iter().map(|l| l.0).collect();
        let mut lines = Vec::new();
        for (laser, sums, spread) in &since.lines {
            let r = recent.and_then(|r| r.lines.iter().find(|l| l.0 == *laser)).map(|l| (&l.1, &l.2));
            let own = |b: usize| floor.line_band(*laser, b).copied();
            lines.push(LineLive { laser: Some(*laser), bands: self.bands(sums, spread, r, &own) });
        }
        if let Some((sums, spread)) = &since.mean {
            let r = recent.and_then(|r| r.mean.as_ref()).map(|m| (&m.0, &m.1));
            let running = |b: usize| floor.running_band(b, &lasers);
            lines.push(LineLive { laser: None, bands: self.bands(sums, spread, r, &running) });
        }
        BandsReport {
            edition: self.opts.edition.name(),
            since_mm,
            recent_mm,
            lines,
            unstitched: self.unstitched,
            latest_unstitched: self.flags.iter().cloned().collect(),
        }
    }

    /// One profile's bands from its sums since the start and over the
    /// last stretch; `floor_of(b)`: its floor in band `b`.
    fn bands(
        &self,
        since: &Sums4,
        spread: &[Spread; 4],
        recent: Option<(&Sums4, &[Spread; 4])>,
        floor_of: &dyn Fn(usize) -> Option<BandFloor>,
    ) -> Vec<BandLive> {
        let dx = self.opts.stitch.dx_mm;
        let edition = self.opts.edition;
        en13231::BANDS
            .iter()
            .enumerate()
            .map(|(b, band)| {
                let floor = floor_of(b);
                let j = BandJudgement::of(floor, edition, band);
                let fig = |s: &BandSums, sp: &Spread| (s.windows() > 0).then(|| figures(s, sp, band, dx));
                let since_f = fig(&since[b], &spread[b]);
                let recent_f = recent.and_then(|(s, sp)| fig(&s[b], &sp[b]));
                let limit_um = edition.limit_mm(band).map(|l| l * 1000.0);
                let (state, why) = state(b, self.opts.bands, since_f.as_ref(), &j, limit_um, edition);
                BandLive {
                    band: format!("{}–{} mm", fmt_mm(band.lo_mm), fmt_mm(band.hi_mm)),
                    limit_um,
                    recent: recent_f,
                    since: since_f,
                    floor_um: floor.map(|f| f.judged_quantity_mm(edition) * 1000.0),
                    state,
                    why,
                }
            })
            .collect()
    }
}

/// A band's state and why: not evaluated (live, or the run too short),
/// not judged (the floor), within or over (2006: the share of windows
/// over the threshold against [`en13231::MAX_EXCEEDING_PERCENT`]; 2012:
/// any sample over the limit).
fn state(
    b: usize,
    live_bands: usize,
    since: Option<&Figures>,
    j: &BandJudgement,
    limit_um: Option<f64>,
    edition: Edition,
) -> (&'static str, String) {
    let band = &en13231::BANDS[b];
    if b >= live_bands {
        let need = band.window_mm + 2.0 * EDGE_WAVELENGTHS * band.hi_mm;
        return ("not evaluated", format!("not evaluated live (it needs {need:.0} mm a stretch): analyze judges it"));
    }
    let Some(f) = since else {
        let need = band.window_mm + 2.0 * EDGE_WAVELENGTHS * band.hi_mm;
        return ("not evaluated", format!("not evaluated yet: it needs {need:.0} mm of track without a gap"));
    };
    if let Some(why) = &j.not_judged {
        return ("not judged", why.clone());
    }
    let Some(limit) = limit_um else {
        return ("not judged", format!("not judged: no {} limit for this band", edition.name()));
    };
    let threshold = j.threshold_mm.map_or(limit, |t| t * 1000.0);
    if edition == Edition::En2012 {
        let over = f.abs_exceeding_percent.unwrap_or(0.0);
        let what = format!("{over:.1} % of the samples over ±{limit:.0} µm");
        return (if over > 0.0 { "over" } else { "within" }, what);
    }
    if f.exceeding_percent > en13231::MAX_EXCEEDING_PERCENT {
        let what = format!(
            "{:.1} % of the windows over {threshold:.1} µm (the {limit:.0} µm limit with the floor's power)",
            f.exceeding_percent
        );
        ("over", what)
    } else {
        ("within", format!("{:.1} % of the windows over {threshold:.1} µm", f.exceeding_percent))
    }
}

/// A band's figures from its sums, with their uncertainties (module docs).
fn figures(s: &BandSums, sp: &Spread, band: &en13231::Band, dx_mm: f64) -> Figures {
    let st = s.stats(band, dx_mm);
    let n = sp.n.max(1.0);
    let mean = sp.sum / n;
    let sd = (sp.sq / n - mean * mean).max(0.0).sqrt();
    // Windows are independent one window apart; cycles of the longest wavelength for the RMS.
    let windows_indep = (st.windows as f64 * dx_mm / band.window_mm).max(1.0);
    let cycles = (st.windows as f64 * dx_mm / band.hi_mm).max(1.0);
    let sys = |v: f64| SYSTEMATIC_SHARE * v;
    let rms_um = st.rms_mm * 1000.0;
    let mean_pp_um = st.average_mean_pp_mm * 1000.0;
    Figures {
        rms_um,
        rms_u_um: (rms_um / (2.0 * cycles).sqrt()).hypot(sys(rms_um)),
        mean_pp_um,
        mean_pp_u_um: (sd / windows_indep.sqrt()).hypot(sys(mean_pp_um)),
        worst_mean_pp_um: st.worst_mean_pp_mm * 1000.0,
        exceeding_percent: st.exceeding_percent,
        abs_exceeding_percent: st.abs_exceeding_percent,
        windows: st.windows,
    }
}

/// Which bands a stretched line evaluates: those of `span`, as its runs allow.
fn evaluated(s: &Stitched, span: &Range<usize>) -> [bool; 4] {
    let mut e = pieces::evaluated_on(&pieces::runs(s), s.dx_mm);
    for (b, v) in e.iter_mut().enumerate() {
        *v &= span.contains(&b);
    }
    e
}

impl RunSums {
    /// Adds a piece's lines and running band over `within` (core
    /// indices), windows exceeding over the threshold of `floor` (each
    /// line's own, the running band's of its lines weighted).
    fn add_piece(&mut self, p: &Piece, within: Range<usize>, floor: &Floor, bands: &Range<usize>) {
        let over = |floor_of: &dyn Fn(usize) -> Option<BandFloor>| -> [f64; 4] {
            std::array::from_fn(|b| {
                let band = &en13231::BANDS[b];
                floor_of(b).map_or(band.mean_pp_limit_mm, |f| f.threshold_mm(Edition::En2006, band.mean_pp_limit_mm))
            })
        };
        let lasers: Vec<usize> = p.lines.iter().map(|l| l.laser).collect();
        for l in &p.lines {
            let line_over = over(&|b| floor.line_band(l.laser, b).copied());
            let at = match self.lines.iter().position(|x| x.0 == l.laser) {
                Some(i) => i,
                None => {
                    self.lines.push((l.laser, Sums4::default(), [Spread::default(); 4]));
                    self.lines.len() - 1
                }
            };
            let (_, sums, spread) = &mut self.lines[at];
            add_traces(sums, spread, &l.bands, &within, &line_over, bands);
        }
        if let Some(rb) = &p.band {
            let (sums, spread) = self.mean.get_or_insert_with(Default::default);
            let mean_over = over(&|b| floor.running_band(b, &lasers));
            add_traces(sums, spread, &rb.mean.bands, &within, &mean_over, bands);
            self.combined = self.combined.max(rb.lines);
        }
        self.samples += within.len();
    }

    fn merge(&mut self, o: &RunSums) {
        for (laser, sums, spread) in &o.lines {
            match self.lines.iter_mut().find(|x| x.0 == *laser) {
                Some(x) => merge_into(&mut x.1, &mut x.2, sums, spread),
                None => self.lines.push((*laser, *sums, *spread)),
            }
        }
        if let Some((sums, spread)) = &o.mean {
            let (s, sp) = self.mean.get_or_insert_with(Default::default);
            merge_into(s, sp, sums, spread);
        }
        self.floor.merge(&o.floor);
        self.combined = self.combined.max(o.combined);
        self.samples += o.samples;
    }
}

fn merge_into(s: &mut Sums4, sp: &mut [Spread; 4], o: &Sums4, osp: &[Spread; 4]) {
    for b in 0..4 {
        s[b].merge(&o[b]);
        sp[b].n += osp[b].n;
        sp[b].sum += osp[b].sum;
        sp[b].sq += osp[b].sq;
    }
}

/// Adds the traces of `bands` over `within` to the sums, windows
/// exceeding over `over` (mm).
fn add_traces(
    sums: &mut Sums4,
    spread: &mut [Spread; 4],
    traces: &[Option<BandTrace>],
    within: &Range<usize>,
    over: &[f64; 4],
    bands: &Range<usize>,
) {
    for (b, t) in traces.iter().enumerate().filter(|(b, _)| bands.contains(b)) {
        let Some(t) = t else { continue };
        let t = t.within(within.clone());
        sums[b].add_over(&en13231::BANDS[b], &t, over[b]);
        for v in t.mean_pp_mm.iter().filter(|v| v.is_finite()) {
            let v = v * 1000.0;
            spread[b].n += 1.0;
            spread[b].sum += v;
            spread[b].sq += v * v;
        }
    }
}

impl BandsReport {
    /// Takes the bands of `span` from `other` (the same run judged on
    /// another series of stretches), line by line.
    fn take_bands(&mut self, other: &BandsReport, span: &Range<usize>) {
        for line in &mut self.lines {
            let Some(theirs) = other.lines.iter().find(|l| l.laser == line.laser) else { continue };
            for b in span.clone() {
                if let (Some(mine), Some(t)) = (line.bands.get_mut(b), theirs.bands.get(b)) {
                    *mine = t.clone();
                }
            }
        }
    }

    /// `bands 2006 since 3.9 m: 10–30 not judged (floor 21.1 µm), 30–100
    /// L0 60.1 L1 61.9 L2 61.1 µm over, …; 1 frame not stitched (last seq 1: gap)`.
    pub fn status(&self) -> String {
        use std::fmt::Write as _;
        let mut s =
            format!("bands {} since {:.1} m:", self.edition.trim_start_matches("EN 13231-3:"), self.since_mm / 1000.0);
        let Some(first) = self.lines.first() else { return String::new() };
        for (b, band) in first.bands.iter().enumerate() {
            if band.state == "not evaluated" {
                continue;
            }
            let _ = write!(s, " {}", band.band.trim_end_matches(" mm"));
            for l in self.lines.iter().filter(|l| l.laser.is_some()) {
                if let (Some(k), Some(f)) = (l.laser, l.bands.get(b).and_then(|x| x.since)) {
                    let _ = write!(s, " L{k} {:.1}", f.mean_pp_um);
                }
            }
            let rb = self.lines.iter().find(|l| l.laser.is_none()).and_then(|l| l.bands.get(b)).unwrap_or(band);
            let _ = write!(s, " µm p-p {}", rb.state);
            if rb.state == "not judged"
                && let (Some(f), Some(l)) = (rb.floor_um, rb.limit_um)
            {
                let _ = write!(s, " (floor {f:.1} of {l:.0} µm)");
            }
            s.push(';');
        }
        if self.unstitched > 0 {
            let last = self.latest_unstitched.last();
            let _ = write!(s, " {} frame(s) not stitched", self.unstitched);
            if let Some(u) = last {
                let _ = write!(
                    s,
                    " (last seq {} at {:.3} m: {}, overlap {:.1} mm)",
                    u.seq,
                    u.odometer_mm / 1000.0,
                    u.kind,
                    u.overlap_mm
                );
            }
        }
        s.trim_end_matches(';').to_string()
    }
}

#[cfg(test)]
mod tests;
