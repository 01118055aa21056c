//! `cms-host analyze RECORDING [--report DIR] [--json]`: a recording's
//! calibrated frames placed along the track by their odometer, stitched into
//! one longitudinal profile per laser line ([`stitch`]), and judged as a rail
//! engineer expects (docs/reference.md §2): the EN 13231-3 wavelength bands
//! and the EN 15610 one-third-octave roughness spectrum against the ISO 3095
//! limit ([`crate::analyze::standards`]). A summary goes to stdout (or one JSON
//! object with `--json`); `--report DIR` writes a Markdown and a
//! self-contained HTML report with SVG and PNG plots, and CSV exports
//! ([`crate::report`]); `--parquet DIR` (and the report) the stitched profile,
//! the blocks and the zones as Parquet files ([`crate::report::exports`], docs/exports.md).
//!
//! Whatever the recording holds, nothing here panics: a file that is not a
//! recording, a recording without calibrated points or absurd options are a
//! one-line error (exit status 2). A record too short for a standard's
//! window is not an error: the summary says which band or wavelength could
//! not be evaluated and why, and gives the rest.
//!
//! Cost: one pass over the file, frames streamed through
//! [`stitch::Stitcher`] as they are read (never all in memory), the lines
//! held in cell stores that spill to a temporary file ([`store`]); then
//! one walk along each section piece by piece ([`pieces`]) for the
//! standards and the verdict, `O(N)` in the samples (the spectrum's
//! segments `O(N log M)`). Memory is set by a piece (whole blocks, the
//! standards' margins), not by the length of track: a synthetic
//! 100 000-frame recording (`cms-host bench recording`, 1.7 km of rail,
//! 778 MB) takes about 14 s and 52 MB (docs/benchmarks.md).

pub mod floor;
pub mod line_floor;
pub mod live;
pub mod marks;
pub mod optics_floor;
pub mod pieces;
pub mod placing;
pub mod profile;
pub mod reprofiling;
pub mod runs;
pub mod standards;
pub mod stitch;
pub mod store;
pub mod survey;
pub mod trend;

use std::path::{Path, PathBuf};

use cms_core::protocol::DeviceMsg;

use crate::Error;
use crate::analyze::standards::{StandardsError, en13231, en15610};
use crate::measure::corrugation::Across;
use crate::measure::{Measurer, Profiles};
use crate::progress::Progress;
use crate::recording::{self, ScanStats};
use pieces::Wanted;
use stitch::{FrameAssembler, FramePoints, Stitched, Stitching};

/// What [`analyze`] needs besides the frames.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Options {
    pub stitch: stitch::Options,
    pub roughness: en15610::Options,
    pub verdict: reprofiling::Options,
}

/// What a recording said, besides its frames (which stream through
/// [`read_recording`]'s callback and are not kept).
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// Frames with calibrated points.
    pub frames: usize,
    /// Lowest and highest `seq` of those frames.
    pub seq_range: Option<(u32, u32)>,
    /// Lowest and highest odometer of those frames, mm.
    pub odometer_range_mm: Option<(f64, f64)>,
    /// Profile messages.
    pub profiles: u64,
    pub calibrated_points: u64,
    pub uncalibrated_points: u64,
    /// Calibration id of the last `Hello`.
    pub calibration_id: Option<u32>,
    /// The head of the recording: every `Hello`'s calibration id and
    /// sensor size, for [`crate::calib::file::CalibrationFile::check_recording`].
    pub heads: crate::calib::file::RecordedHeads,
    pub stats: ScanStats,
    /// Frames slid across ([`slide_frame`]) and the calibration file used.
    pub slid_across: Option<(usize, PathBuf)>,
    /// The survey the recording's header names ([`crate::recording::survey_info`]).
    pub survey: Option<crate::recording::survey_info::Survey>,
    /// A hash of the frames' contents (each frame's `seq`, odometer, point
    /// counts, first and last points and sum of heights, in order): two
    /// recordings holding the same frames have the same.
    pub fingerprint: u64,
    /// Set by [`check_runs`] when joined as asked: the earlier run (from 1)
    /// this one repeats, and the earlier run whose head differs (and how).
    pub repeats: Option<usize>,
    pub other_head: Option<(usize, String)>,
    /// The GNSS fixes the recording holds (`listen --gnss`), in file order:
    /// what the report plots the run's track from.
    pub fixes: Vec<crate::gnss::Placed>,
    /// The event marks recorded, in file order ([`marks`] places them).
    pub marks: Vec<crate::recording::mark::Mark>,
    /// The profiles' exposures and travel, for the head's motion during
    /// an exposure ([`Recording::motion`]).
    pub motion: MotionSums,
}

/// Sums over a recording's profiles that give its mean exposure and speed.
#[derive(Debug, Clone, Copy, Default)]
pub struct MotionSums {
    exposure_us: f64,
    exposures: u64,
    travel_mm: f64,
    time_s: f64,
    /// The last profile's head time and odometer, µs and µm.
    last: Option<(u64, i64)>,
}

impl MotionSums {
    /// Adds a profile: its exposure, and its travel since the last one
    /// when they are of one stretch (under a second apart, time running on).
    pub fn profile(&mut self, timestamp_us: u64, odometer_um: i64, exposure_us: u32) {
        if exposure_us > 0 {
            self.exposure_us += f64::from(exposure_us);
            self.exposures += 1;
        }
        if let Some((t, o)) = self.last
            && timestamp_us > t
            && timestamp_us - t < 1_000_000
        {
            self.travel_mm += (odometer_um - o).unsigned_abs() as f64 * 1e-3;
            self.time_s += (timestamp_us - t) as f64 * 1e-6;
        }
        self.last = Some((timestamp_us, odometer_um));
    }

    /// The mean exposure and speed (`None`: no exposure or no travel time recorded).
    pub fn motion(&self) -> Option<optics_floor::Motion> {
        (self.exposures > 0 && self.time_s > 0.0).then(|| optics_floor::Motion {
            exposure_us: self.exposure_us / self.exposures as f64,
            speed_mm_s: self.travel_mm / self.time_s,
        })
    }

    /// Both recordings' sums.
    pub fn merge(&self, o: &MotionSums) -> MotionSums {
        MotionSums {
            exposure_us: self.exposure_us + o.exposure_us,
            exposures: self.exposures + o.exposures,
            travel_mm: self.travel_mm + o.travel_mm,
            time_s: self.time_s + o.time_s,
            last: None,
        }
    }
}

/// What [`check_runs`] lets through because the user asked for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RunsAllowed {
    /// The same recording given more than once.
    pub repeats: bool,
    /// Recordings of different heads.
    pub mixed_heads: bool,
}

/// Checks the runs of one survey before they are joined: the same
/// recording twice (the same file, or a copy: the same frames, points,
/// odometer and head) or recordings of different heads (calibration,
/// sensor, or the survey's instrument) are refused, naming both runs
/// (numbered from 1), unless `allowed`; then each is noted on the later
/// run for the report.
pub fn check_runs(runs: &mut [(PathBuf, Recording)], allowed: RunsAllowed) -> Result<(), Error> {
    for j in 1..runs.len() {
        for i in 0..j {
            let ((pi, ri), (pj, rj)) = (&runs[i], &runs[j]);
            let name = |k: usize, p: &Path| format!("run {} ({})", k + 1, p.display());
            if same_file(pi, pj) || ri.same_frames(rj) {
                if !allowed.repeats {
                    return Err(Error::Input(format!(
                        "{} is the same recording as {}: give each run once (or --allow-repeated-runs to join it with itself)",
                        name(j, pj),
                        name(i, pi)
                    )));
                }
                runs[j].1.repeats.get_or_insert(i + 1);
            } else if let Some(how) = ri.head_difference(rj) {
                if !allowed.mixed_heads {
                    return Err(Error::Input(format!(
                        "{} was recorded by another head than {} ({how}): join runs of one head (or --allow-mixed-heads)",
                        name(j, pj),
                        name(i, pi)
                    )));
                }
                runs[j].1.other_head.get_or_insert((i + 1, how));
            }
        }
    }
    Ok(())
}

/// Whether two paths name one file (the same device and inode).
fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => false,
    }
}

impl Recording {
    /// Whether `other` holds the same frames (a copy of one recording):
    /// the same count and [`Recording::fingerprint`].
    pub fn same_frames(&self, other: &Recording) -> bool {
        (self.frames, self.fingerprint) == (other.frames, other.fingerprint)
    }

    /// How the head that made `other` differs from this one's, when both
    /// say: their calibration ids, sensor sizes or survey instruments.
    pub fn head_difference(&self, other: &Recording) -> Option<String> {
        let (a, b) = (&self.heads, &other.heads);
        let hex = |v: &[u32]| v.iter().map(|id| format!("{id:#010x}")).collect::<Vec<_>>().join(", ");
        if !a.calibration_ids.is_empty() && !b.calibration_ids.is_empty() && a.calibration_ids != b.calibration_ids {
            return Some(format!("calibration {} vs {}", hex(&b.calibration_ids), hex(&a.calibration_ids)));
        }
        let px = |v: &[(u32, u32)]| v.iter().map(|(w, h)| format!("{w}×{h}")).collect::<Vec<_>>().join(", ");
        if !a.sensors.is_empty() && !b.sensors.is_empty() && a.sensors != b.sensors {
            return Some(format!("sensor {} px vs {} px", px(&b.sensors), px(&a.sensors)));
        }
        let instrument = |r: &Recording| r.survey.as_ref().and_then(|s| s.instrument.clone());
        match (instrument(self), instrument(other)) {
            (Some(x), Some(y)) if x != y => {
                Some(format!("instrument {} vs {}", crate::output::printable(&y), crate::output::printable(&x)))
            }
            _ => None,
        }
    }

    fn count(&mut self, f: &FramePoints) {
        use std::hash::{Hash as _, Hasher as _};
        // Not every point: what tells two runs apart costs nothing next to reading them.
        let mut h = std::hash::DefaultHasher::new();
        (self.fingerprint, f.seq, f.odometer_mm.to_bits()).hash(&mut h);
        for pts in &f.lasers {
            let ends = [pts.first(), pts.last()].map(|p| p.map(|&(a, z)| (a.to_bits(), z.to_bits())));
            let sum: f64 = pts.iter().map(|p| p.1).sum();
            (pts.len(), ends, sum.to_bits()).hash(&mut h);
        }
        self.fingerprint = h.finish();
        self.frames += 1;
        let (s, o) = (f.seq, f.odometer_mm);
        self.seq_range = Some(self.seq_range.map_or((s, s), |(lo, hi)| (lo.min(s), hi.max(s))));
        if o.is_finite() {
            self.odometer_range_mm = Some(self.odometer_range_mm.map_or((o, o), |(lo, hi)| (lo.min(o), hi.max(o))));
        }
    }
}

/// Reads a recording, handing each frame with calibrated points to
/// `on_frame` as soon as it is complete, with what the recording has said
/// so far (its heads: a `Hello` precedes the profiles it describes).
/// Memory is one frame; `progress` is told the bytes read. An error of
/// `on_frame` stops the reading and is returned.
pub fn read_recording(
    path: &Path,
    progress: &dyn Progress,
    mut on_frame: impl FnMut(&Recording, FramePoints) -> Result<(), Error>,
) -> Result<Recording, Error> {
    let mut rec = Recording::default();
    let mut asm = FrameAssembler::default();
    // The callback's error, kept while the reader is told to stop.
    let mut failed: Option<Error> = None;
    let mut deliver = |rec: &mut Recording, f: FramePoints, failed: &mut Option<Error>| -> std::io::Result<()> {
        rec.count(&f);
        on_frame(rec, f).map_err(|e| {
            *failed = Some(e);
            std::io::Error::other("stopped")
        })
    };
    let scanned = recording::scan_file_records_with_progress(path, progress, |item| {
        let msg = match item {
            recording::Item::Device(msg) => msg,
            recording::Item::Host(recording::HostRecord::Fix(p)) => {
                rec.fixes.push(p.clone());
                return Ok(());
            }
            recording::Item::Host(recording::HostRecord::Mark(m)) => {
                rec.marks.push(m.clone());
                return Ok(());
            }
        };
        match msg {
            DeviceMsg::Profile(p) => {
                rec.profiles += 1;
                rec.heads.profile(p);
                rec.motion.profile(p.timestamp_us, p.odometer_um, p.exposure_us);
                if let Some(f) = asm.push(p) {
                    deliver(&mut rec, f, &mut failed)?;
                }
            }
            DeviceMsg::Hello(info) => {
                rec.calibration_id = Some(info.calibration_id);
                rec.heads.hello(info);
            }
            _ => {}
        }
        Ok(())
    });
    let stats = match scanned {
        Ok(stats) => stats,
        Err(e) => return Err(failed.take().unwrap_or_else(|| Error::Input(e.to_string()))),
    };
    if let Some(f) = asm.finish()
        && deliver(&mut rec, f, &mut failed).is_err()
        && let Some(e) = failed.take()
    {
        return Err(e);
    }
    rec.calibrated_points = asm.calibrated_points;
    rec.uncalibrated_points = asm.uncalibrated_points;
    rec.stats = stats;
    let name = path.display();
    if rec.profiles == 0 {
        return Err(Error::Input(format!("{name}: the recording holds no profiles")));
    }
    if rec.frames == 0 {
        return Err(Error::Input(format!(
            "{name}: no calibrated points in {} profiles (the head had no calibration loaded: see cms-host calibrate upload)",
            rec.profiles
        )));
    }
    Ok(rec)
}

/// Slides one frame's points across the rail head's lateral slope
/// ([`crate::measure::corrugation::Across`]: the points lifted to the head frame with
/// the calibration's laser frames, the slope from the parabola through the
/// three lines' mean heights); false when the frame has fewer than two
/// lines of 8 points (it is left as it is).
pub fn slide_frame(f: &mut FramePoints, m: &Measurer) -> bool {
    let profiles: Profiles = std::array::from_fn(|k| f.lasers[k].iter().map(|&(a, h)| (a, h * 1e-3)).collect());
    let lines = m.lines(&profiles);
    let Some(across) = Across::new(&lines) else { return false };
    for (k, (pts, line)) in f.lasers.iter_mut().zip(&lines).enumerate() {
        // `lines` keeps every point of a known laser, in order.
        for (pt, p3) in pts.iter_mut().zip(&line.points) {
            pt.1 += (across.slide(k, *p3)[2] - p3[2]) * 1e3;
        }
    }
    true
}

/// One laser's outcome.
#[derive(Debug, Clone)]
pub struct LaserAnalysis {
    pub stitched: Stitched,
    pub bands: Result<en13231::BandAnalysis, StandardsError>,
    /// Per EN 13231-3 band: one line's noise floor and whether it allows
    /// a verdict on this line (under the verdict's edition).
    pub judgements: Vec<floor::BandJudgement>,
    /// Its third octaves carry the floor ([`en15610::ThirdOctave::floor_db`]).
    pub roughness: Result<en15610::Roughness, StandardsError>,
}

/// A section's running band seen through all its lines: the profile the
/// verdict judges ([`reprofiling`]) and EN 15610's lines averaged.
#[derive(Debug, Clone)]
pub struct RunningBandAnalysis {
    pub section: usize,
    /// Lines combined.
    pub lines: usize,
    /// EN 13231-3 of the lines' mean, where every line has a sample.
    pub bands: Result<en13231::BandAnalysis, StandardsError>,
    /// Per band: the mean's floor (`1/√lines` of a line's) and whether it allows a verdict.
    pub judgements: Vec<floor::BandJudgement>,
    /// EN 15610: the lines' spectra energy-averaged, with the floor (`None`: no line has a spectrum).
    pub roughness: Option<en15610::Spectrum>,
}

/// The whole analysis.
#[derive(Debug, Clone)]
pub struct Analysis {
    pub options: Options,
    pub stitching: Stitching,
    /// How each run was placed on the line (one entry per run).
    pub joins: Vec<survey::RunJoin>,
    /// Every line of every section, section by section ([`Analysis::sections`]).
    pub lasers: Vec<LaserAnalysis>,
    /// The instrument's noise floor, measured on the lines (`None`: no
    /// section has two lines, so it is not known).
    pub floor: Option<floor::Floor>,
    /// Each section's running band (sections of two lines or more).
    pub running_bands: Vec<RunningBandAnalysis>,
    /// Zones, the reprofiling table and blocks over all the lines.
    pub verdict: reprofiling::ReprofilingVerdict,
    /// With a track register: how each run was placed by its GNSS fixes
    /// or its typed start ([`placing`]), one per run; empty without.
    pub gnss_placing: Vec<placing::GnssPlacing>,
    /// The floor checked against what the recorded optics predict
    /// ([`optics_floor`]; [`runs::run`] fills it in).
    pub optics: optics_floor::OpticsCheck,
}

/// One section of the survey line: a stretch measured without a gap
/// longer than a section gap, its lines on one grid.
#[derive(Debug, Clone, Copy)]
pub struct Section<'a> {
    /// From 1, in chainage order.
    pub number: usize,
    pub grid: Grid,
    pub lasers: &'a [LaserAnalysis],
}

impl Section<'_> {
    /// Chainage of its first sample and past its last, mm.
    pub fn span_mm(&self) -> (f64, f64) {
        (self.grid.origin_mm, self.grid.origin_mm + self.grid.len as f64 * self.grid.dx_mm)
    }
}

impl Analysis {
    /// The sections of the survey line, in chainage order (one for a
    /// single run or a profile file).
    pub fn sections(&self) -> Vec<Section<'_>> {
        self.lasers
            .chunk_by(|a, b| a.stitched.section == b.stitched.section)
            .map(|lasers| Section {
                number: lasers[0].stitched.section,
                grid: Grid::of(lasers, self.options.stitch.dx_mm),
                lasers,
            })
            .collect()
    }
}

/// The lines' profiles on one grid: sample `i` at chainage
/// `origin_mm + i·dx_mm`, every line's first sample a whole number of
/// spacings from the lowest one's (the stitcher and the join put them so).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub origin_mm: f64,
    pub dx_mm: f64,
    /// Samples from the lowest first sample to past the highest last one.
    pub len: usize,
}

impl Grid {
    /// The grid of `lines` at spacing `dx_mm` (empty without lines).
    pub fn of(lines: &[LaserAnalysis], dx_mm: f64) -> Grid {
        Grid::of_lines(&lines.iter().map(|l| &l.stitched).collect::<Vec<_>>(), dx_mm)
    }

    /// [`Grid::of`] stitched lines.
    pub fn of_lines(lines: &[&Stitched], dx_mm: f64) -> Grid {
        let origin_mm = lines.iter().map(|l| l.x0_mm).fold(f64::INFINITY, f64::min);
        let mut g = Grid { origin_mm: if origin_mm.is_finite() { origin_mm } else { 0.0 }, dx_mm, len: 0 };
        g.len = lines.iter().map(|l| g.offset(l) + l.z.len()).max().unwrap_or(0);
        g
    }

    /// The grid index of a line's first sample.
    pub fn offset(&self, s: &Stitched) -> usize {
        ((s.x0_mm - self.origin_mm) / self.dx_mm).round().max(0.0) as usize
    }

    /// Chainage of sample `i`, mm, rounded to the nanometre (as written to files).
    pub fn chainage_mm(&self, i: usize) -> f64 {
        ((self.origin_mm + i as f64 * self.dx_mm) * 1e6).round() / 1e6
    }
}

/// Where the profiles came from.
#[derive(Debug, Clone)]
pub enum Source {
    /// Recordings — the runs of one survey — each with what it said.
    Recordings(Vec<(PathBuf, Recording)>),
    /// A longitudinal profile from any instrument ([`profile`]).
    Profile(PathBuf, profile::ProfileFile),
}

impl Source {
    /// The input's name(s), for titles.
    pub fn name(&self) -> String {
        match self {
            Source::Recordings(r) => r.iter().map(|(p, _)| p.display().to_string()).collect::<Vec<_>>().join(", "),
            Source::Profile(p, _) => p.display().to_string(),
        }
    }
}

/// Stitches the frames and runs both standards on every laser's profile.
pub fn analyze(frames: &[FramePoints], opts: &Options) -> Result<Analysis, Error> {
    let stitching = stitch::stitch(frames, &opts.stitch).map_err(|e| Error::Input(e.to_string()))?;
    judge(stitching, Vec::new(), opts, &crate::progress::Silent)
}

/// Runs both standards on every laser's stitched profile and judges the
/// survey line: first the noise floor from the lines' null combinations
/// ([`floor::measure`], one walk; the stitch's own share added), then the standards and the verdict,
/// walking it piece by piece ([`pieces`]); `progress` is told the metres
/// of line walked.
pub fn judge(
    mut stitching: Stitching,
    joins: Vec<survey::RunJoin>,
    opts: &Options,
    progress: &dyn Progress,
) -> Result<Analysis, Error> {
    let stitched = std::mem::take(&mut stitching.lasers);
    let floor = floor::measure(&stitched, opts, progress)?;
    let floor = match &stitching.share {
        Some(share) => floor.map(|f| f.with_stitch(share)),
        None => floor,
    };
    progress.begin("judging", line_metres(&stitched), "m");
    let mut done_m = 0.0;
    let dx = stitched.first().map_or(opts.stitch.dx_mm, |s| s.dx_mm);
    let mut verdict = reprofiling::Builder::new(&opts.verdict, &opts.roughness, dx, floor.clone());
    let edition = opts.verdict.edition;
    // Each line judged against its own floor (the shared one where the lines cannot be told apart).
    let line_judgements = |laser: usize| -> Vec<floor::BandJudgement> {
        en13231::BANDS
            .iter()
            .enumerate()
            .map(|(b, band)| {
                floor::BandJudgement::of(floor.as_ref().and_then(|f| f.line_band(laser, b).copied()), edition, band)
            })
            .collect()
    };
    // 2006: a window exceeds where the rail's own mean peak-to-peak does (the floor's power taken out).
    let threshold = |f: Option<floor::BandFloor>, b: usize| -> f64 {
        let band = &en13231::BANDS[b];
        f.map_or(band.mean_pp_limit_mm, |f| f.threshold_mm(reprofiling::Edition::En2006, band.mean_pp_limit_mm))
    };
    let over_of = |floor: Option<&floor::Floor>, lasers: &[usize]| -> [f64; 4] {
        std::array::from_fn(|b| threshold(floor.and_then(|f| f.running_band(b, lasers)), b))
    };
    let line_over = |laser: usize| -> [f64; 4] {
        std::array::from_fn(|b| threshold(floor.as_ref().and_then(|f| f.line_band(laser, b).copied()), b))
    };
    let mut lasers = Vec::new();
    let mut running_bands = Vec::new();
    for section in stitched.chunk_by(|a, b| a.section == b.section) {
        let mut bands = Vec::new();
        let mut welch = Vec::new();
        for s in section {
            let runs = pieces::runs(s);
            bands.push(en13231::plan(&runs, s.z.len(), s.dx_mm));
            welch.push(en15610::Welch::new(&runs, s.dx_mm, &opts.roughness));
        }
        not_evaluated(&bands, &mut verdict);
        let lines: Vec<(&Stitched, [bool; 4])> = section.iter().zip(&bands).map(|(s, a)| (s, evaluated(a))).collect();
        let mut sums = vec![[en13231::BandSums::default(); 4]; section.len()];
        let mut mean_sums = [en13231::BandSums::default(); 4];
        let mut spikes = vec![0usize; section.len()];
        let want = Wanted { lines: true, mean: true, nulls: false };
        let overs: Vec<[f64; 4]> = section.iter().map(|s| line_over(s.laser)).collect();
        let numbers: Vec<usize> = section.iter().map(|s| s.laser).collect();
        let weights = floor.as_ref().and_then(|f| f.running_band_weights(&numbers));
        let band_over = over_of(floor.as_ref(), &numbers);
        pieces::walk_section_weighted(section[0].section, &lines, opts, want, weights.as_deref(), &mut |p| {
            // EN 15610's nonlinear steps on the rail the lines share, their
            // effect added to each line (one line: on itself).
            let rail = p
                .band
                .as_ref()
                .map(|rb| rb.rail_steps(&opts.roughness).correction(rb.mean.ext_z_um(), &opts.roughness));
            for (k, l) in p.lines.iter().enumerate() {
                for (((sum, t), band), over) in sums[k].iter_mut().zip(&l.bands).zip(&en13231::BANDS).zip(&overs[k]) {
                    if let Some(t) = t {
                        sum.add_over(band, t, *over);
                    }
                }
                if let Ok(w) = &mut welch[k] {
                    spikes[k] += match &rail {
                        Some(c) => w.add_corrected(&l.stretch(p.core.clone()), c, &opts.roughness),
                        None => w.add(&l.stretch(p.core.clone()), &opts.roughness),
                    };
                }
            }
            if let Some(rb) = &p.band {
                let over = band_over;
                for (((sum, t), band), over) in mean_sums.iter_mut().zip(&rb.mean.bands).zip(&en13231::BANDS).zip(&over)
                {
                    if let Some(t) = t {
                        sum.add_over(band, t, *over);
                    }
                }
            }
            verdict.piece(p);
            done_m += p.core.len() as f64 * p.grid.dx_mm / 1000.0;
            progress.set(done_m as u64);
            Ok(())
        })?;
        let mut spectra = Vec::new();
        for (k, s) in section.iter().enumerate() {
            let bands = summed(&bands[k], &sums[k]);
            let roughness = match &welch[k] {
                Ok(w) => {
                    let mut spectrum = w.spectrum();
                    spectra.push(spectrum.clone());
                    if let Some(f) = &floor {
                        f.mark_line(s.laser, &mut spectrum);
                    }
                    Ok(en15610::Roughness { spectrum, spikes_removed: spikes[k] })
                }
                Err(e) => Err(e.clone()),
            };
            lasers.push(LaserAnalysis { stitched: s.clone(), bands, judgements: line_judgements(s.laser), roughness });
        }
        if section.len() >= 2 {
            running_bands.push(running_band(section, &mean_sums, &spectra, floor.as_ref(), edition));
        }
    }
    progress.end();
    Ok(Analysis {
        options: opts.clone(),
        stitching,
        joins,
        lasers,
        floor,
        running_bands,
        verdict: verdict.finish(),
        gnss_placing: Vec::new(),
        optics: optics_floor::OpticsCheck::NotRecorded,
    })
}

/// The survey line's length, m, summed over its sections (the progress's whole).
fn line_metres(stitched: &[Stitched]) -> u64 {
    stitched
        .chunk_by(|a, b| a.section == b.section)
        .map(|s| (Grid::of_lines(&s.iter().collect::<Vec<_>>(), s[0].dx_mm).len as f64 * s[0].dx_mm / 1000.0) as u64)
        .sum()
}

/// Tells the verdict which bands a section's lines could not evaluate, and why.
fn not_evaluated(plans: &[Result<en13231::BandAnalysis, StandardsError>], verdict: &mut reprofiling::Builder) {
    for a in plans {
        match a {
            Ok(a) => {
                for (b, r) in a.bands.iter().enumerate() {
                    if let Err(e) = &r.outcome {
                        verdict.not_evaluated(b, e.to_string());
                    }
                }
            }
            Err(e) => (0..en13231::BANDS.len()).for_each(|b| verdict.not_evaluated(b, e.to_string())),
        }
    }
}

/// A profile's plan with its band figures summed over the pieces.
fn summed(
    plan: &Result<en13231::BandAnalysis, StandardsError>,
    sums: &[en13231::BandSums; 4],
) -> Result<en13231::BandAnalysis, StandardsError> {
    let mut bands = plan.clone();
    if let Ok(a) = &mut bands {
        for (r, sum) in a.bands.iter_mut().zip(sums) {
            if let Ok(st) = &mut r.outcome {
                *st = sum.stats(&r.band, a.dx_mm);
            }
        }
    }
    bands
}

/// A section's running band from its mean's band sums and its lines' spectra.
fn running_band(
    section: &[Stitched],
    sums: &[en13231::BandSums; 4],
    spectra: &[en15610::Spectrum],
    floor: Option<&floor::Floor>,
    edition: reprofiling::Edition,
) -> RunningBandAnalysis {
    let dx = section[0].dx_mm;
    let grid = Grid::of_lines(&section.iter().collect::<Vec<_>>(), dx);
    let runs: Vec<Vec<std::ops::Range<usize>>> = section
        .iter()
        .map(|s| {
            let off = grid.offset(s);
            pieces::runs(s).into_iter().map(|r| r.start + off..r.end + off).collect()
        })
        .collect();
    let common = pieces::common_runs(&runs);
    let bands = summed(&en13231::plan(&common, grid.len, dx), sums);
    let k = section.len();
    let lasers: Vec<usize> = section.iter().map(|s| s.laser).collect();
    let judgements = en13231::BANDS
        .iter()
        .enumerate()
        .map(|(b, band)| floor::BandJudgement::of(floor.and_then(|f| f.running_band(b, &lasers)), edition, band))
        .collect();
    let mut roughness = en15610::energy_average(spectra);
    if let (Some(s), Some(f)) = (&mut roughness, floor) {
        f.mark(s);
    }
    RunningBandAnalysis { section: section[0].section, lines: k, bands, judgements, roughness }
}

/// Which EN 13231-3 bands a line's plan evaluates.
fn evaluated(a: &Result<en13231::BandAnalysis, StandardsError>) -> [bool; 4] {
    let mut out = [false; 4];
    if let Ok(a) = a {
        for (o, r) in out.iter_mut().zip(&a.bands) {
            *o = r.outcome.is_ok();
        }
    }
    out
}

impl Analysis {
    /// Walks the survey line piece by piece, every section in chainage
    /// order, with the lines' samples and band traces (what plots and
    /// exports are written from; recomputed, never held whole).
    pub fn for_each_piece(&self, f: impl FnMut(&pieces::Piece) -> Result<(), Error>) -> Result<(), Error> {
        self.for_each_piece_with(Wanted::LINES, f)
    }

    /// [`Analysis::for_each_piece`], each piece with what `wanted` asks for.
    pub fn for_each_piece_with(
        &self,
        wanted: Wanted,
        mut f: impl FnMut(&pieces::Piece) -> Result<(), Error>,
    ) -> Result<(), Error> {
        for section in self.sections() {
            let lines: Vec<(&Stitched, [bool; 4])> =
                section.lasers.iter().map(|l| (&l.stitched, evaluated(&l.bands))).collect();
            let lasers: Vec<usize> = section.lasers.iter().map(|l| l.stitched.laser).collect();
            let weights = self.floor.as_ref().and_then(|f| f.running_band_weights(&lasers));
            pieces::walk_section_weighted(section.number, &lines, &self.options, wanted, weights.as_deref(), &mut f)?;
        }
        Ok(())
    }
}

/// ISO 3095 wavelengths the spectrum does not reach, with why.
pub fn iso3095_not_evaluated(r: &en15610::Roughness) -> Vec<(f64, String)> {
    let s = &r.spectrum;
    en15610::ISO3095_LIMIT
        .iter()
        .filter(|(w, _)| !s.bands.iter().any(|b| (b.nominal_wavelength_mm - w).abs() < 1e-6 * w))
        .map(|&(w, _)| {
            let why = if w > s.segment_mm / 4.0 {
                format!("needs segments of at least {} mm (--segment-mm)", fmt_len(4.0 * w))
            } else {
                format!("shorter than the sampling resolves (spacing {} mm)", fmt_len(s.dx_mm))
            };
            (w, why)
        })
        .collect()
}

/// The band of highest level.
pub fn spectrum_peak(r: &en15610::Roughness) -> Option<&en15610::ThirdOctave> {
    r.spectrum.bands.iter().max_by(|a, b| a.level_db.total_cmp(&b.level_db))
}

/// The peak's reading against the ISO 3095 limit, in words: the measured
/// level, the rail's own with its interval, and the band's verdict —
/// never "over the limit" unless the rail exceeds it.
pub fn peak_words(p: &en15610::ThirdOctave) -> String {
    let Some(d) = p.decision() else {
        return format!("measured {:.1} dB; ISO 3095 sets no limit at this wavelength", p.level_db);
    };
    format!("measured {:.1} dB, rail {} dB, ISO 3095 limit {:.1} dB: {}", d.level_db, d.rail, d.limit_db, d.words())
}

/// How many third octaves with an ISO 3095 limit earn each verdict:
/// `(exceeds, within, not judged)`.
pub fn verdict_counts(s: &en15610::Spectrum) -> (usize, usize, usize) {
    use standards::detection::Verdict;
    let count = |v: Verdict| s.bands.iter().filter(|b| b.verdict() == Some(v)).count();
    (count(Verdict::Exceeds), count(Verdict::Within), count(Verdict::NotJudged))
}

/// A length for people: whole numbers without decimals.
pub fn fmt_len(v: f64) -> String {
    if (v - v.round()).abs() < 1e-6 * v.abs().max(1.0) { format!("{}", v.round()) } else { format!("{v:.2}") }
}

/// A position for people: chainage `km+m`.
pub fn chainage(x_mm: f64) -> String {
    survey::Chainage(x_mm / 1000.0).to_string()
}

/// A seeded Gaussian (xorshift and Box–Muller) for the analysis's unit
/// tests: the same profile every run.
#[cfg(test)]
pub(crate) fn seeded_gauss(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed.max(1);
    let mut uniform = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    move || (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos()
}
