//! The live ISO 3095 / EN 15610 verdicts of `cms-host listen --serve`:
//! each line's and the lines' energy average's one-third octaves against
//! the ISO 3095 limit, each against its own floor, over the latest
//! stretch of track — what `analyze` would say of that stretch.
//!
//! # Which track
//!
//! EN 15610 wants a record several of its 1 m Welch segments long: the
//! 250 mm third octave is one FFT bin of a 1 m segment, so its level's
//! degrees of freedom grow only with the segments. The live verdicts are
//! made on a *stretch* of the most recent track:
//!
//! * Frames are stitched as they arrive by analyze's own stitcher
//!   ([`Stitcher`], O(points) a frame), a new stitcher opened every
//!   [`STRETCH_MM`]` / 2` of travel and the oldest dropped once it has
//!   travelled [`STRETCH_MM`]: the oldest open one holds the run so far
//!   at first, then always between the last 15 and 30 m.
//! * Nothing is judged until that stretch holds [`MIN_GAPLESS_MM`] of
//!   track every line has without a gap (nine Welch segments at 50 %
//!   overlap: the 250 mm third octave then has some 17 degrees of
//!   freedom, and its decision a chance of being made); until then the
//!   panel reads *not evaluated yet: it needs 5000 mm of track without a
//!   gap*, with what it has so far.
//! * From then on the stretch is judged again every [`EVAL_EVERY_MM`] of
//!   travel.
//!
//! # One implementation
//!
//! A stretch is judged by [`analyze::judge`] itself on the stitched
//! stretch ([`Stitcher::peek`]): the floor from the lines' null
//! combinations and each line's own from the three pairs, EN 15610's
//! nonlinear steps on the rail the lines share, the Welch spectra, each
//! line marked with its own floor and the energy average with the
//! running band's ([`crate::analyze::floor::Floor::mark_line`],
//! [`crate::analyze::floor::Floor::mark`]), and the ISO 11843 decisions
//! ([`en15610::ThirdOctave::decision`]). The figures shown are those
//! decisions', word for word. What differs from `analyze` of the
//! recording: the stretch is the last 15–30 m, not the whole run; the
//! joint registration's last eight frames are not committed yet (a
//! quarter of a second at 30 frames/s); and the stitch's own share of the
//! floor, which `analyze` propagates from the whole line's registration,
//! is left out, as [`super::bands`] leaves it out.
//!
//! # Cost
//!
//! `analyze::judge` on the stretch is its whole cost, and it is not
//! small: it walks the stretch twice (the floor, then the standards) and
//! runs EN 15610's nonlinear steps on the rail for the floor, the lines
//! and the blocks. The `live/iso3095_judge` benchmark (`cargo bench -p
//! cms-host --bench corrugation`) measured 173 ms for a 30 m stretch of
//! three lines of synthetic frames on the 2-core development VM, and the
//! first 5 m of a `listen sim` run took 1.04 s there while the simulated
//! head and a browser shared the machine; a frame stitched costs 0.25 ms
//! (`live/iso3095_add_per_frame`). So it never runs on the
//! listener's loop, nor on the view's hub: [`LiveIso3095::threaded`]
//! judges on a worker thread of its own (started by the hub, at the
//! hub's lowered priority), at most one stretch in flight; the hub takes
//! the verdicts when they are ready and peeks the next stretch (a copy
//! of its cells, O(cells)) only when the worker is free and has rested
//! as long as its last judgement took: the worker takes at most half of
//! one core, however slow the machine or fast the travel, and the
//! verdicts come as often as that allows (every [`EVAL_EVERY_MM`] of
//! travel at most).

use std::collections::VecDeque;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::analyze::floor::common_runs;
use crate::analyze::reprofiling::Iso3095;
use crate::analyze::standards::en15610;
use crate::analyze::stitch::{Direction, FramePoints, Stitcher, Stitching};
use crate::analyze::{self, Grid};

/// The longest stretch judged, mm: a stitcher opens every half of it.
pub const STRETCH_MM: f64 = 30_000.0;
/// Track without a gap, common to the lines, before anything is judged, mm.
pub const MIN_GAPLESS_MM: f64 = 5_000.0;
/// The stretch is judged again after this much new travel, mm.
pub const EVAL_EVERY_MM: f64 = 2_000.0;
/// While too short to judge, the track without a gap is measured again
/// after this much new travel, mm (a peek: a copy of the cells).
const WAIT_EVERY_MM: f64 = 250.0;

/// One third octave's ISO 3095 decision, as `analyze` makes it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IsoBand {
    /// Nominal wavelength, mm (250, 200, …, 3.15).
    pub wavelength_mm: f64,
    /// The reading, rail and noise together, dB re 1 µm.
    pub level_db: f64,
    /// This profile's own floor (`None`: not known).
    pub floor_db: Option<f64>,
    pub limit_db: f64,
    /// "within", "EXCEEDS" or "not judged".
    pub verdict: &'static str,
    /// The verdict in words: with the floor, the limit and what would
    /// settle it where not judged.
    pub words: String,
    /// The rail's own level, the floor's power taken out, and its
    /// interval ([`crate::analyze::standards::detection::CONFIDENCE_PERCENT`]).
    pub rail_db: Option<f64>,
    pub rail_lo_db: Option<f64>,
    pub rail_hi_db: Option<f64>,
    /// The same as the text summary writes it: "26.5 [25.1, 27.9]".
    pub rail: String,
}

/// One profile's third octaves: a laser's line or the energy average.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IsoLine {
    /// `Some(k)` for laser k, `None` for the lines' energy average.
    pub laser: Option<usize>,
    /// The spectrum's verdict in words ("EXCEEDS at 50, 40 mm; not judged at 8 mm").
    pub verdict: String,
    /// Welch segments averaged.
    pub segments: usize,
    /// The third octaves with an ISO 3095 limit, longest first.
    pub bands: Vec<IsoBand>,
    /// Why this line has no spectrum (`analyze`'s words).
    pub error: Option<String>,
}

/// The live ISO 3095 verdicts of the latest stretch.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Iso3095Live {
    /// "evaluated", "not evaluated yet" (too little track) or "not
    /// evaluated" (`analyze` refused the stretch: `why`).
    pub state: &'static str,
    pub why: Option<String>,
    /// Odometer of the stretch's first frame and of its newest, mm.
    pub from_odometer_mm: f64,
    pub to_odometer_mm: f64,
    /// The stretch's stitched length and its longest run every line has
    /// without a gap, mm.
    pub stretch_mm: f64,
    pub gapless_mm: f64,
    /// What a judgement needs without a gap, mm ([`MIN_GAPLESS_MM`]).
    pub needs_mm: f64,
    /// The judgement's cost, ms (`None`: not judged).
    pub cost_ms: Option<f64>,
    /// The confidence of the rails' intervals, percent.
    pub confidence_percent: f64,
    /// Each laser's line, then the energy average.
    pub lines: Vec<IsoLine>,
}

/// A stretch stitched so far, to be judged ([`judge`]).
pub struct RecentTrack {
    pub stitching: Stitching,
    /// Odometer of its first frame and its newest, mm.
    pub from_odometer_mm: f64,
    pub to_odometer_mm: f64,
    /// Stitched length, and the longest run every line has, mm.
    pub stretch_mm: f64,
    pub gapless_mm: f64,
}

impl RecentTrack {
    /// The stretch of `stitching`: its length and longest common run.
    pub fn of(stitching: Stitching, from_odometer_mm: f64, to_odometer_mm: f64) -> RecentTrack {
        let lines: Vec<_> = stitching.lasers.iter().collect();
        let dx = lines.first().map_or(1.0, |l| l.dx_mm);
        let grid = Grid::of_lines(&lines, dx);
        let longest = common_runs(&stitching.lasers, dx).iter().map(|r| r.len()).max().unwrap_or(0);
        RecentTrack {
            stitching,
            from_odometer_mm,
            to_odometer_mm,
            stretch_mm: grid.len as f64 * dx,
            gapless_mm: longest as f64 * dx,
        }
    }

    fn report(&self, state: &'static str, why: Option<String>) -> Iso3095Live {
        Iso3095Live {
            state,
            why,
            from_odometer_mm: self.from_odometer_mm,
            to_odometer_mm: self.to_odometer_mm,
            stretch_mm: self.stretch_mm,
            gapless_mm: self.gapless_mm,
            needs_mm: MIN_GAPLESS_MM,
            cost_ms: None,
            confidence_percent: crate::analyze::standards::detection::CONFIDENCE_PERCENT,
            lines: Vec::new(),
        }
    }
}

/// Judges a stretch by `analyze` (module docs): every line's and the
/// energy average's ISO 3095 third octaves, or why not.
pub fn judge(track: RecentTrack, opts: &analyze::Options) -> Iso3095Live {
    if track.gapless_mm < MIN_GAPLESS_MM {
        let why = format!(
            "not evaluated yet: it needs {MIN_GAPLESS_MM:.0} mm of track without a gap ({:.0} mm so far)",
            track.gapless_mm
        );
        return track.report("not evaluated yet", Some(why));
    }
    let t0 = Instant::now();
    let mut out = track.report("evaluated", None);
    let a = match analyze::judge(track.stitching, Vec::new(), opts, &crate::progress::Silent) {
        Ok(a) => a,
        Err(e) => return Iso3095Live { state: "not evaluated", why: Some(format!("not evaluated: {e}")), ..out },
    };
    for l in &a.lasers {
        out.lines.push(match &l.roughness {
            Ok(r) => line(Some(l.stitched.laser), &r.spectrum),
            Err(e) => IsoLine {
                laser: Some(l.stitched.laser),
                verdict: "not evaluated".into(),
                segments: 0,
                bands: Vec::new(),
                error: Some(e.to_string()),
            },
        });
    }
    if let Some(s) = a.running_bands.first().and_then(|rb| rb.roughness.as_ref()) {
        out.lines.push(line(None, s));
    }
    out.cost_ms = Some(t0.elapsed().as_secs_f64() * 1e3);
    out
}

/// A spectrum's third octaves with an ISO 3095 limit, as decided.
fn line(laser: Option<usize>, s: &en15610::Spectrum) -> IsoLine {
    let bands = s
        .bands
        .iter()
        .filter_map(|b| {
            let d = b.decision()?;
            Some(IsoBand {
                wavelength_mm: b.nominal_wavelength_mm,
                level_db: b.level_db,
                floor_db: b.floor_db,
                limit_db: d.limit_db,
                verdict: d.verdict.name(),
                words: d.words(),
                rail_db: d.rail.db,
                rail_lo_db: d.rail.lo_db,
                rail_hi_db: d.rail.hi_db,
                rail: d.rail.to_string(),
            })
        })
        .collect();
    IsoLine { laser, verdict: Iso3095::of(s).words(), segments: s.segments, bands, error: None }
}

/// One stitcher of the series.
struct Open {
    stitcher: Stitcher,
    /// Odometer of its first frame, mm.
    from_mm: f64,
}

/// The live ISO 3095 state of a run (module docs).
pub struct LiveIso3095 {
    opts: analyze::Options,
    /// Oldest first.
    open: VecDeque<Open>,
    /// +1 odometer counting up, −1 down (0 before it moved).
    travel: f64,
    /// Decided from the first stretch peeked (`Auto` before).
    direction: Direction,
    newest_mm: f64,
    /// The odometer the last stretch was taken at, and whether it was too short.
    taken_at: Option<(f64, bool)>,
    report: Option<Iso3095Live>,
    worker: Option<Worker>,
    /// The worker rests until then: as long as its last judgement took.
    rest_until: Option<Instant>,
}

impl LiveIso3095 {
    /// Judged where asked ([`LiveIso3095::report`] judges, when due, before it returns).
    pub fn new(opts: analyze::Options) -> LiveIso3095 {
        LiveIso3095 {
            direction: opts.stitch.direction,
            opts,
            open: VecDeque::new(),
            travel: 0.0,
            newest_mm: f64::NAN,
            taken_at: None,
            report: None,
            worker: None,
            rest_until: None,
        }
    }

    /// Judged on a worker thread of its own ([`LiveIso3095::report`]
    /// hands a stretch over and returns the last verdicts at once); where
    /// no thread can be started, where asked.
    pub fn threaded(opts: analyze::Options) -> LiveIso3095 {
        let worker = Worker::spawn(opts.clone());
        LiveIso3095 { worker, ..LiveIso3095::new(opts) }
    }

    fn open_at(&mut self, from_mm: f64) {
        let opts = crate::analyze::stitch::Options { direction: self.direction, ..self.opts.stitch };
        if let Ok(stitcher) = Stitcher::new(&opts) {
            self.open.push_back(Open { stitcher, from_mm });
        }
    }

    /// Takes one frame (in the order the head sent them).
    pub fn add(&mut self, f: &FramePoints) {
        let o = f.odometer_mm;
        if !o.is_finite() || f.points() == 0 {
            return;
        }
        self.newest_mm = o;
        let Some(first) = self.open.front().map(|s| s.from_mm) else {
            self.open_at(o);
            return self.push(f);
        };
        if self.travel == 0.0 && (o - first).abs() > 1.0 {
            self.travel = (o - first).signum();
        }
        let newest = self.open.back().map_or(first, |s| s.from_mm);
        if self.travel != 0.0 && (o - newest) * self.travel >= STRETCH_MM / 2.0 {
            self.open_at(o);
        }
        while self.open.len() > 1 && self.open.front().is_some_and(|s| (o - s.from_mm) * self.travel >= STRETCH_MM) {
            self.open.pop_front();
        }
        self.push(f);
    }

    fn push(&mut self, f: &FramePoints) {
        for s in &mut self.open {
            s.stitcher.push(f);
        }
    }

    /// Whether the stretch is due to be taken again: after
    /// [`EVAL_EVERY_MM`] of travel ([`WAIT_EVERY_MM`] while too short).
    fn due(&self) -> bool {
        match self.taken_at {
            None => self.newest_mm.is_finite(),
            Some((at, short)) => (self.newest_mm - at).abs() >= if short { WAIT_EVERY_MM } else { EVAL_EVERY_MM },
        }
    }

    /// The oldest open stretch as stitched so far (the direction settled
    /// from it once the stitcher can tell).
    pub fn take(&mut self) -> Option<RecentTrack> {
        let s = self.open.front_mut()?;
        let from_mm = s.from_mm;
        let stitching = s.stitcher.peek().ok()?;
        if self.direction == Direction::Auto && matches!(stitching.direction_residuals_um, Some((Some(_), Some(_)))) {
            self.direction = stitching.direction;
        }
        let track = RecentTrack::of(stitching, from_mm, self.newest_mm);
        self.taken_at = Some((self.newest_mm, track.gapless_mm < MIN_GAPLESS_MM));
        Some(track)
    }

    /// The verdicts so far (`None` before a calibrated frame): the
    /// stretch taken and judged when due — on the worker, whose verdicts
    /// are returned once ready (until then the last ones), and which
    /// then rests as long as the judgement took, or here.
    pub fn report(&mut self) -> Option<&Iso3095Live> {
        match self.worker.as_mut().map(Worker::poll) {
            Some(Ok(Some(r))) => {
                let cost = Duration::from_secs_f64(r.cost_ms.unwrap_or(0.0).max(0.0) / 1e3);
                self.rest_until = Some(Instant::now() + cost);
                self.report = Some(r);
            }
            // The thread is gone (it cannot panic on a stretch, but if it
            // did): judge here from now on.
            Some(Err(())) => self.worker = None,
            _ => {}
        }
        let rested = self.rest_until.is_none_or(|t| Instant::now() >= t);
        if self.due() && rested && self.worker.as_ref().is_none_or(|w| !w.busy) {
            self.judge_taken();
        }
        self.report.as_ref()
    }

    /// The verdicts of the stretch taken now, judged here (what
    /// [`LiveIso3095::report`] does when due; its cost is the
    /// `live/iso3095_judge` benchmark's).
    pub fn judge_now(&mut self) -> Option<&Iso3095Live> {
        let track = self.take()?;
        self.report = Some(judge(track, &self.opts));
        self.report.as_ref()
    }

    fn judge_taken(&mut self) {
        let Some(track) = self.take() else { return };
        if track.gapless_mm < MIN_GAPLESS_MM {
            self.report = Some(judge(track, &self.opts));
            return;
        }
        match &mut self.worker {
            Some(w) => {
                if let Err(track) = w.submit(track) {
                    // The worker is gone: judge here from now on.
                    self.worker = None;
                    self.report = Some(judge(*track, &self.opts));
                }
            }
            None => self.report = Some(judge(track, &self.opts)),
        }
    }
}

/// The thread that judges stretches, one at a time.
struct Worker {
    tx: mpsc::Sender<RecentTrack>,
    rx: mpsc::Receiver<Iso3095Live>,
    busy: bool,
}

impl Worker {
    /// A thread named `cms-iso3095`; it ends when its [`Worker`] is
    /// dropped and the stretch in hand is judged. `None` where no thread
    /// can be started.
    fn spawn(opts: analyze::Options) -> Option<Worker> {
        let (tx, work) = mpsc::channel::<RecentTrack>();
        let (done, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("cms-iso3095".into())
            .spawn(move || {
                for track in work {
                    if done.send(judge(track, &opts)).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Worker { tx, rx, busy: false })
    }

    /// Hands a stretch over (the caller checks that none is in hand);
    /// the stretch back if the thread is gone.
    fn submit(&mut self, track: RecentTrack) -> Result<(), Box<RecentTrack>> {
        self.tx.send(track).map_err(|e| Box::new(e.0))?;
        self.busy = true;
        Ok(())
    }

    /// The verdicts of the stretch in hand, once judged; `Err` when the
    /// thread is gone.
    fn poll(&mut self) -> Result<Option<Iso3095Live>, ()> {
        match self.rx.try_recv() {
            Ok(r) => {
                self.busy = false;
                Ok(Some(r))
            }
            Err(mpsc::TryRecvError::Empty) => Ok(None),
            Err(mpsc::TryRecvError::Disconnected) => Err(()),
        }
    }
}

#[cfg(test)]
mod tests;
