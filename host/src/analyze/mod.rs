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
//! [`stitch::Stitcher`] as they are read (never all in memory); the
//! standards `O(N log N)` in the samples. A synthetic 20 000-frame
//! recording (`cms-host bench recording`, 340 m of rail, 531 MB) takes
//! about 5 s and 180 MB (docs/benchmarks.md).

pub mod live;
pub mod profile;
pub mod reprofiling;
pub mod standards;
pub mod stitch;
pub mod survey;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use cms_core::protocol::DeviceMsg;
use serde_json::{Value, json};

use crate::Error;
use crate::analyze::standards::{StandardsError, en13231, en15610};
use crate::measure::corrugation::Across;
use crate::measure::{Measurer, Profiles};
use crate::progress::Progress;
use crate::recording::{self, ScanStats};
use stitch::{Direction, FrameAssembler, FramePoints, Registration, Stitched, Stitching};

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
}

impl Recording {
    fn count(&mut self, f: &FramePoints) {
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
    let scanned = recording::scan_file_with_progress(path, progress, |msg| {
        match msg {
            DeviceMsg::Profile(p) => {
                rec.profiles += 1;
                rec.heads.profile(p);
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
    pub roughness: Result<en15610::Roughness, StandardsError>,
}

/// The whole analysis.
#[derive(Debug, Clone)]
pub struct Analysis {
    pub options: Options,
    pub stitching: Stitching,
    /// How each run was placed on the line (one entry per run).
    pub joins: Vec<survey::RunJoin>,
    pub lasers: Vec<LaserAnalysis>,
    /// Zones, the reprofiling table and blocks over all the lines.
    pub verdict: reprofiling::ReprofilingVerdict,
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
        let origin_mm = lines.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
        let mut g = Grid { origin_mm: if origin_mm.is_finite() { origin_mm } else { 0.0 }, dx_mm, len: 0 };
        g.len = lines.iter().map(|l| g.offset(&l.stitched) + l.stitched.z_um.len()).max().unwrap_or(0);
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
pub fn analyze(frames: &[FramePoints], opts: &Options) -> Result<Analysis, stitch::StitchError> {
    Ok(judge(stitch::stitch(frames, &opts.stitch)?, Vec::new(), opts))
}

/// Runs both standards on every laser's stitched profile.
pub fn judge(mut stitching: Stitching, joins: Vec<survey::RunJoin>, opts: &Options) -> Analysis {
    let lasers: Vec<LaserAnalysis> = std::mem::take(&mut stitching.lasers)
        .into_iter()
        .map(|s| {
            let bands = en13231::analyze(&s.z_um, s.dx_mm);
            let roughness = en15610::analyze(&s.z_um, s.dx_mm, &opts.roughness);
            LaserAnalysis { stitched: s, bands, roughness }
        })
        .collect();
    let verdict = reprofiling::judge(&lasers, &opts.verdict);
    Analysis { options: opts.clone(), stitching, joins, lasers, verdict }
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

pub(crate) fn fmt_len(v: f64) -> String {
    if (v - v.round()).abs() < 1e-6 * v.abs().max(1.0) { format!("{}", v.round()) } else { format!("{v:.2}") }
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

fn direction_name(d: Direction) -> &'static str {
    match d {
        Direction::Forward => "x = odometer + along",
        Direction::Reverse => "x = odometer − along",
        Direction::Auto => "auto",
    }
}

fn registration_name(r: Registration) -> &'static str {
    match r {
        Registration::OffsetTilt => "offset and tilt",
        Registration::Offset => "offset",
        Registration::None => "none",
    }
}

fn opt_um(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2} µm"))
}

/// A position for people: chainage `km+m`.
pub fn chainage(x_mm: f64) -> String {
    survey::Chainage(x_mm / 1000.0).to_string()
}

/// The input's and the stitching's description (a few lines).
pub fn describe(source: &Source, a: &Analysis) -> String {
    let mut s = String::new();
    match source {
        Source::Recordings(runs) => {
            for (path, rec) in runs {
                describe_recording(&mut s, path, rec);
            }
            let st = &a.stitching;
            let auto = match st.auto_residuals_um {
                Some((f, r)) => format!(
                    " (chosen from the data: median overlap residual forward {}, reverse {})",
                    opt_um(f),
                    opt_um(r)
                ),
                None => String::new(),
            };
            let _ = writeln!(
                s,
                "stitching: {}{auto}; registration: {}; samples every {} mm",
                direction_name(st.direction),
                registration_name(a.options.stitch.registration),
                fmt_len(a.options.stitch.dx_mm)
            );
        }
        Source::Profile(path, p) => {
            let _ = writeln!(
                s,
                "profile {}: {} rows, {} line(s) ({}), {}; samples every {} mm{}",
                path.display(),
                p.rows,
                p.columns.len(),
                p.columns.join(", "),
                if p.has_x {
                    format!("positions every {} mm (median step)", fmt_len(p.data_dx_mm))
                } else {
                    "no position column".into()
                },
                fmt_len(a.options.stitch.dx_mm),
                if p.resampled { " (interpolated onto that grid; never across a gap)" } else { "" }
            );
        }
    }
    // One run where the user put it by default needs no placement line.
    let placed = a.joins.len() > 1 || a.joins.iter().any(|j| j.start_m != 0.0 || j.heading == survey::Heading::Down);
    if placed {
        for j in &a.joins {
            let _ = writeln!(s, "{}", describe_join(j));
        }
    }
    s
}

/// One run's placement on the line, in a line.
pub fn describe_join(j: &survey::RunJoin) -> String {
    let mut s = format!(
        "run {}: position 0 at chainage {} ({:.3} m), chainage {} with track position{}",
        j.run + 1,
        survey::Chainage(j.start_m),
        j.start_m,
        j.heading.name(),
        if j.heading_found { " (found by registration)" } else { "" }
    );
    if let Some(m) = j.moved_mm
        && j.overlap_mm > 0.0
    {
        let _ = write!(s, "; registered {:+.1} mm from its given start", m);
    }
    if j.overlap_mm > 0.0 {
        let _ = write!(s, "; overlap {:.1} m, residual {}", j.overlap_mm / 1000.0, opt_um(j.residual_um));
    } else if j.run > 0 {
        s.push_str("; overlaps no earlier run: placed as given");
    }
    if j.ambiguous() {
        s.push_str("; AMBIGUOUS: another placement matched nearly as well (give its start chainage)");
    }
    s
}

fn describe_recording(s: &mut String, path: &Path, rec: &Recording) {
    let (smin, smax) = rec.seq_range.unwrap_or((0, 0));
    let (olo, ohi) = rec.odometer_range_mm.unwrap_or((0.0, 0.0));
    let _ = writeln!(
        s,
        "recording {}: {} frames with calibrated points (seq {smin}–{smax}), {} points, odometer {olo:.3}–{ohi:.3} mm{}",
        path.display(),
        rec.frames,
        rec.calibrated_points,
        match rec.calibration_id {
            Some(id) => format!(", calibration {id:#010x}"),
            None => String::new(),
        }
    );
    if let Some(sv) = &rec.survey {
        let _ = writeln!(s, "  survey: {}", sv.describe());
    }
    if rec.uncalibrated_points > 0 {
        let _ = writeln!(s, "  {} points without a calibrated position were left out", rec.uncalibrated_points);
    }
    match &rec.slid_across {
        Some((n, cal)) => {
            let _ = writeln!(
                s,
                "  heights slid across the rail head's lateral slope with {} ({n} of {} frames)",
                cal.display(),
                rec.frames
            );
        }
        None => {
            let _ = writeln!(
                s,
                "  heights as the head measured them (no --calibration: the outer lines keep their lateral-slope scale)"
            );
        }
    }
    for w in recording::warnings(path, &rec.stats) {
        let _ = writeln!(s, "  {w}");
    }
}

/// One laser's stitching in a few lines.
pub fn describe_stitched(l: &Stitched) -> String {
    let mut s = String::new();
    let overlap = stitch::median(l.fits.iter().map(|f| f.overlap_mm).collect());
    let _ = writeln!(
        s,
        "laser {}: {:.0} mm of track from chainage {} ({:.0} mm covered), {} frames, {} points; {} registered \
         (median overlap {}, residual median {}, offsets RMS {:.2} µm, tilts RMS {:.4} µm/mm), {} unregistered join(s), {} gap(s)",
        l.laser,
        l.length_mm(),
        chainage(l.x0_mm),
        l.covered_mm(),
        l.frames,
        l.points,
        l.fits.len(),
        overlap.map_or("-".into(), |v| format!("{v:.0} mm")),
        opt_um(l.median_residual_um()),
        rms(l.fits.iter().map(|f| f.offset_um)),
        rms(l.fits.iter().map(|f| f.tilt_um_per_mm)),
        l.joins.len(),
        l.gaps.len()
    );
    for g in l.gaps.iter().take(20) {
        let _ = writeln!(s, "  gap at {}, {} mm long", chainage(g.start_mm), fmt_len(g.length_mm));
    }
    if l.gaps.len() > 20 {
        let _ = writeln!(s, "  … and {} more gaps (see the report)", l.gaps.len() - 20);
    }
    for j in l.joins.iter().take(10) {
        let _ = writeln!(
            s,
            "  frame {} joined unregistered at {} (overlap {:.1} mm)",
            j.seq,
            chainage(j.at_mm),
            j.overlap_mm
        );
    }
    if l.joins.len() > 10 {
        let _ = writeln!(s, "  … and {} more unregistered joins", l.joins.len() - 10);
    }
    s
}

/// One laser's EN 15610 outcome: the table, the wavelengths not evaluated,
/// the peak; or why there is none.
pub fn describe_roughness(r: &Result<en15610::Roughness, StandardsError>) -> String {
    let mut s = String::new();
    match r {
        Ok(r) => {
            s.push_str(&en15610::spectrum_table(r));
            let missing = iso3095_not_evaluated(r);
            if !missing.is_empty() {
                let list: Vec<String> = missing.iter().map(|(w, why)| format!("{} mm ({why})", fmt_len(*w))).collect();
                let _ = writeln!(s, "ISO 3095 wavelengths not evaluated: {}", list.join("; "));
            }
            if let Some(p) = spectrum_peak(r) {
                let over = r.spectrum.bands.iter().filter(|b| b.exceeds() == Some(true)).count();
                let _ = writeln!(
                    s,
                    "spectrum peak: {} mm one-third octave at {:.1} dB{}; {over} of {} bands over the ISO 3095 limit",
                    fmt_len(p.nominal_wavelength_mm),
                    p.level_db,
                    match p.margin_db() {
                        Some(m) if m < 0.0 =>
                            format!(" (ISO 3095 limit {:.1} dB: over by {:.1} dB)", p.level_db + m, -m),
                        Some(m) => format!(" (ISO 3095 limit {:.1} dB: {:.1} dB below)", p.level_db + m, m),
                        None => String::new(),
                    },
                    r.spectrum.bands.iter().filter(|b| b.iso3095_limit_db.is_some()).count()
                );
            }
        }
        Err(e) => {
            let _ = writeln!(s, "EN 15610 roughness not evaluated: {e}");
        }
    }
    s
}

/// One laser's EN 13231-3 outcome.
pub fn describe_bands(b: &Result<en13231::BandAnalysis, StandardsError>) -> String {
    match b {
        Ok(a) => en13231::band_table(a),
        Err(e) => format!("EN 13231-3 bands not evaluated: {e}\n"),
    }
}

/// The printed summary.
pub fn summary(source: &Source, a: &Analysis) -> String {
    let mut s = describe(source, a);
    for l in &a.lasers {
        s.push('\n');
        s.push_str(&describe_stitched(&l.stitched));
        for part in [describe_bands(&l.bands), describe_roughness(&l.roughness)] {
            for line in part.lines() {
                let _ = writeln!(s, "  {line}");
            }
        }
    }
    s.push('\n');
    s.push_str(&reprofiling::describe(&a.verdict));
    s
}

fn verdict_json(v: &reprofiling::ReprofilingVerdict) -> Value {
    let e = v.options.edition;
    json!({
        "edition": e.name(),
        "source": e.source(),
        "reprofile_mm": v.reprofile_mm,
        "measured_mm": v.measured_mm,
        "bands": v.rows.iter().map(|r| json!({
            "lo_mm": r.band.lo_mm,
            "hi_mm": r.band.hi_mm,
            "limit_mm": r.limit_mm,
            "measured_mm": r.measured_mm,
            "exceeding_mm": r.exceeding_mm,
            "exceeding_percent": r.exceeding_percent(),
            "passes": r.passes(e),
            "not_evaluated": r.not_evaluated,
        })).collect::<Vec<_>>(),
        "zones": v.zones.iter().map(|z| json!({
            "lo_mm": z.band.lo_mm,
            "hi_mm": z.band.hi_mm,
            "start_mm": z.start_mm,
            "end_mm": z.end_mm,
            "start_chainage": chainage(z.start_mm),
            "end_chainage": chainage(z.end_mm),
            "exceeding_mm": z.exceeding_mm,
            "worst_pp_mm": z.worst_pp_mm,
        })).collect::<Vec<_>>(),
        "block_mm": v.options.block_mm,
        "blocks": v.blocks.iter().map(|b| json!({
            "start_mm": b.start_mm,
            "end_mm": b.end_mm,
            "rms_mm": b.rms_mm,
            "iso3095_exceeded_mm": b.iso3095_exceeded,
        })).collect::<Vec<_>>(),
    })
}

fn num(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

/// The analysis as one JSON object.
pub fn to_json(source: &Source, a: &Analysis) -> Value {
    let lasers: Vec<Value> = a
        .lasers
        .iter()
        .map(|l| {
            let s = &l.stitched;
            let bands = match &l.bands {
                Ok(b) => json!({
                    "record_mm": b.record_mm,
                    "runs": b.runs,
                    "bands": b.bands.iter().map(|r| {
                        let mut o = json!({
                            "lo_mm": r.band.lo_mm, "hi_mm": r.band.hi_mm, "window_mm": r.band.window_mm,
                            "mean_pp_limit_mm": r.band.mean_pp_limit_mm, "edge_mm": r.edge_mm,
                        });
                        match &r.outcome {
                            Ok(st) => {
                                o["average_mean_pp_mm"] = num(st.average_mean_pp_mm);
                                o["worst_mean_pp_mm"] = num(st.worst_mean_pp_mm);
                                o["worst_max_pp_mm"] = num(st.worst_max_pp_mm);
                                o["rms_mm"] = num(st.rms_mm);
                                o["exceeding_percent"] = num(st.exceeding_percent);
                                o["exceeding_mm"] = num(st.exceeding_mm);
                                o["windows"] = json!(st.windows);
                                o["passes"] = json!(st.passes);
                                if let Some(p) = st.abs_exceeding_percent {
                                    o["abs_limit_mm"] = json!(r.band.abs_limit_mm);
                                    o["abs_exceeding_percent"] = num(p);
                                }
                            }
                            Err(e) => o["error"] = json!(e.to_string()),
                        }
                        o
                    }).collect::<Vec<_>>(),
                }),
                Err(e) => json!({ "error": e.to_string() }),
            };
            let roughness = match &l.roughness {
                Ok(r) => json!({
                    "segments": r.spectrum.segments,
                    "segment_mm": r.spectrum.segment_mm,
                    "spikes_removed": r.spikes_removed,
                    "bands": r.spectrum.bands.iter().map(|b| json!({
                        "nominal_wavelength_mm": b.nominal_wavelength_mm,
                        "wavelength_mm": b.wavelength_mm,
                        "level_db": num(b.level_db),
                        "iso3095_limit_db": b.iso3095_limit_db,
                        "exceeds": b.exceeds(),
                    })).collect::<Vec<_>>(),
                    "not_evaluated": iso3095_not_evaluated(r).iter().map(|(w, why)| json!({
                        "nominal_wavelength_mm": w, "why": why,
                    })).collect::<Vec<_>>(),
                    "peak_wavelength_mm": spectrum_peak(r).map(|p| p.nominal_wavelength_mm),
                }),
                Err(e) => json!({ "error": e.to_string() }),
            };
            json!({
                "laser": s.laser,
                "x0_mm": s.x0_mm,
                "dx_mm": s.dx_mm,
                "samples": s.z_um.len(),
                "length_mm": s.length_mm(),
                "covered_mm": s.covered_mm(),
                "frames": s.frames,
                "points": s.points,
                "registered": s.fits.len(),
                "registration_residual_median_um": s.median_residual_um(),
                "offset_rms_um": rms(s.fits.iter().map(|f| f.offset_um)),
                "tilt_rms_um_per_mm": rms(s.fits.iter().map(|f| f.tilt_um_per_mm)),
                "unregistered_joins": s.joins.iter().map(|j| json!({
                    "seq": j.seq, "at_mm": j.at_mm, "overlap_mm": j.overlap_mm,
                })).collect::<Vec<_>>(),
                "gaps": s.gaps.iter().map(|g| json!({ "start_mm": g.start_mm, "length_mm": g.length_mm })).collect::<Vec<_>>(),
                "en13231": bands,
                "en15610": roughness,
            })
        })
        .collect();
    let mut o = match source {
        Source::Recordings(runs) => {
            let mut o = json!({ "runs": runs.iter().map(|(p, r)| recording_json(p, r)).collect::<Vec<_>>() });
            // One recording: its fields at the top as well (as before runs).
            if let [(p, r)] = runs.as_slice()
                && let (Value::Object(top), Value::Object(one)) = (&mut o, recording_json(p, r))
            {
                top.extend(one);
            }
            o["direction"] = json!(match a.stitching.direction {
                Direction::Reverse => "reverse",
                _ => "forward",
            });
            o["auto_residuals_um"] =
                json!(a.stitching.auto_residuals_um.map(|(f, r)| json!({ "forward": f, "reverse": r })));
            o["registration"] = json!(match a.options.stitch.registration {
                Registration::OffsetTilt => "offset-tilt",
                Registration::Offset => "offset",
                Registration::None => "none",
            });
            o
        }
        Source::Profile(p, f) => json!({
            "profile": p.display().to_string(),
            "rows": f.rows,
            "columns": f.columns,
            "data_dx_mm": f.data_dx_mm,
            "resampled": f.resampled,
        }),
    };
    o["dx_mm"] = json!(a.options.stitch.dx_mm);
    o["run_joins"] = json!(
        a.joins
            .iter()
            .map(|j| json!({
                "run": j.run,
                "heading": j.heading.name(),
                "heading_found": j.heading_found,
                "start_m": j.start_m,
                "start_chainage": survey::Chainage(j.start_m).to_string(),
                "moved_mm": j.moved_mm,
                "overlap_mm": j.overlap_mm,
                "residual_um": j.residual_um,
                "correlation": j.correlation.map(|(b, s)| json!({ "best": b, "second": s })),
                "ambiguous": j.ambiguous(),
            }))
            .collect::<Vec<_>>()
    );
    o["lasers"] = json!(lasers);
    o["verdict"] = verdict_json(&a.verdict);
    o
}

fn recording_json(path: &Path, rec: &Recording) -> Value {
    let (olo, ohi) = rec.odometer_range_mm.unwrap_or((f64::NAN, f64::NAN));
    json!({
        "recording": path.display().to_string(),
        "frames": rec.frames,
        "profiles": rec.profiles,
        "calibrated_points": rec.calibrated_points,
        "uncalibrated_points": rec.uncalibrated_points,
        "calibration_id": rec.calibration_id,
        "slid_across_frames": rec.slid_across.as_ref().map(|(n, _)| n),
        "odometer_mm": [num(olo), num(ohi)],
        "damaged_frames": rec.stats.damaged,
        "duplicate_profiles": rec.stats.duplicates,
        "survey": rec.survey,
    })
}
