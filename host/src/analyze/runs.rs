//! The whole of `cms-host analyze` short of writing its outputs: the
//! inputs told apart (recordings of one survey, or one profile file), each
//! recording read once and stitched as it is read (slid across the rail
//! head first with a calibration), the runs checked, placed and joined on
//! chainage, and the result judged. The command line, the viewer and the
//! trend over surveys all analyse through here, so they agree.

use std::path::{Path, PathBuf};

use crate::Error;
use crate::analyze::optics_floor::{HeadLens, Motion, OpticsCheck, OpticsSource};
use crate::analyze::reprofiling::{self, Edition};
use crate::analyze::standards::en15610;
use crate::analyze::stitch::{self, Direction, Registration, Stitcher};
use crate::analyze::survey::{self, Placement};
use crate::analyze::{self, Analysis, Options, Recording, RunsAllowed, Source, placing, profile};
use crate::calib::file::CalibrationFile;
use crate::measure::Measurer;
use crate::model::optics::Optics;
use crate::progress::Progress;
use crate::recording::survey_info::Survey;

/// What to analyse, besides the [`Options`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Request {
    /// Recordings of one survey, or one profile file.
    pub inputs: Vec<PathBuf>,
    /// Where each run lies, one per recording in order at most; a run
    /// without one takes its recording's survey block's, else none.
    pub placements: Vec<Placement>,
    /// The head's calibration file: every frame slid across the rail head.
    pub calibration: Option<PathBuf>,
    /// Repeated runs and mixed heads, refused unless allowed.
    pub allowed: RunsAllowed,
    /// How far registration may move a run from its given start, mm.
    pub search_mm: f64,
    /// The sample spacing the user asked for, mm; `None`: the options' for
    /// recordings and the data's own for a profile.
    pub dx_mm: Option<f64>,
    /// Options given that apply only to recordings (their flags, to name
    /// them when the input is a profile: refused, never ignored).
    pub recording_only: Vec<String>,
    /// A track register: each run with GNSS fixes placed by them, its
    /// typed start checked against them ([`crate::analyze::placing`]).
    pub track_register: Option<PathBuf>,
    /// The optics the recordings were made with (`analyze --optics`), for
    /// recordings that do not say: the floor is checked against them.
    pub optics: Option<Optics>,
}

/// The settings a user gives `analyze` (the command line's flags, the
/// Python package's arguments), with the command line's defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub edition: Edition,
    /// Block length for block RMS and the per-block spectrum, m.
    pub block_m: f64,
    /// The stitched profile's sample spacing, mm (`None`: 1 mm).
    pub dx_mm: Option<f64>,
    pub direction: Direction,
    pub registration: Registration,
    /// EN 15610 Welch segment length, mm.
    pub segment_mm: f64,
    pub remove_spikes: bool,
    pub curvature: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            edition: Edition::En2006,
            block_m: 50.0,
            dx_mm: None,
            direction: Direction::Auto,
            registration: stitch::Options::default().registration,
            segment_mm: en15610::MIN_SEGMENT_MM,
            remove_spikes: true,
            curvature: true,
        }
    }
}

impl Settings {
    /// The analysis options these settings ask for.
    pub fn options(&self) -> Options {
        Options {
            stitch: stitch::Options {
                dx_mm: self.dx_mm.unwrap_or(1.0),
                direction: self.direction,
                registration: self.registration,
                ..stitch::Options::default()
            },
            roughness: en15610::Options {
                segment_mm: self.segment_mm,
                remove_spikes: self.remove_spikes,
                curvature: self.curvature,
                ..en15610::Options::default()
            },
            verdict: reprofiling::Options { edition: self.edition, block_mm: self.block_m * 1000.0 },
        }
    }
}

/// A numeric setting of `analyze`, and the values it takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Range {
    /// Block length, m: shorter than a metre holds under one period of the
    /// longest band's wavelengths (300–1000 mm); longer than a kilometre is
    /// no longer a place on the track a verdict can point at.
    BlockM,
    /// How far registration may move a run, m.
    SearchM,
    /// Sample spacing, mm: finer than 0.05 mm is below every head's
    /// sampling along the rail (the reference head's rows are 0.144 mm
    /// apart) and only multiplies the work; coarser than 10 mm cannot show
    /// the shortest wavelength judged (10 mm).
    DxMm,
    /// EN 15610 Welch segment length, mm.
    SegmentMm,
}

impl Range {
    /// (lowest, highest), whether the lowest is excluded, what the value is.
    fn bounds(self) -> ((f64, f64), bool, &'static str) {
        match self {
            Range::BlockM => ((1.0, 1000.0), false, "a block length in m"),
            Range::SearchM => ((0.0, 1000.0), true, "a search distance in m"),
            Range::DxMm => ((0.05, 10.0), false, "a sample spacing in mm"),
            Range::SegmentMm => ((en15610::MIN_SEGMENT_MM, 1e6), false, "an EN 15610 segment length in mm"),
        }
    }

    /// The value `s` names, in range; else an error naming the value and the range.
    pub fn parse(self, s: &str) -> Result<f64, Error> {
        let ((lo, hi), open, what) = self.bounds();
        match s.trim().parse::<f64>() {
            Ok(v) if v.is_finite() && (v > lo || (!open && v == lo)) && v <= hi => Ok(v),
            _ => Err(Error::Input(format!("`{s}` is not {what} ({}{lo} to {hi})", if open { "above " } else { "" }))),
        }
    }

    /// `v`, in range; else the error of [`Range::parse`].
    pub fn check(self, v: f64) -> Result<f64, Error> {
        self.parse(&v.to_string())
    }
}

/// Analyses what `req` names: the inputs read, joined and judged.
pub fn run(req: &Request, opts: &Options, progress: &dyn Progress) -> Result<(Source, Analysis), Error> {
    let mut opts = opts.clone();
    if req.placements.len() > req.inputs.len() {
        return Err(Error::Input(format!(
            "{} --chainage for {} input(s): give at most one per recording, in order",
            req.placements.len(),
            req.inputs.len()
        )));
    }
    // The calibration is checked before any input is read.
    let calibration = match &req.calibration {
        Some(path) => {
            let name = path.display().to_string();
            // The file's own errors name it.
            let file = CalibrationFile::load(path).map_err(Error::from)?;
            let m = Measurer::new(&file).map_err(|e| Error::Input(format!("{name}: {e}")))?;
            Some((file, m, name))
        }
        None => None,
    };
    let kinds = req.inputs.iter().map(|p| is_recording(p)).collect::<Result<Vec<bool>, Error>>()?;
    let recordings = kinds.iter().filter(|&&r| r).count();
    let mut placements = req.placements.clone();
    let mut gnss_placing = Vec::new();
    let (source, runs) = if recordings == 0 {
        let [path] = req.inputs.as_slice() else {
            return Err(Error::Input(format!(
                "{} profile files: analyze one at a time (recordings of one survey can be joined)",
                req.inputs.len()
            )));
        };
        if let Some(flag) = req.recording_only.first() {
            return Err(Error::Input(format!(
                "{}: {flag} applies to recordings, not to a profile file",
                path.display()
            )));
        }
        let (file, stitching) = profile::read(path, req.dx_mm)?;
        opts.stitch.dx_mm = stitching.lasers.first().map_or(opts.stitch.dx_mm, |l| l.dx_mm);
        (Source::Profile(path.clone(), file), vec![stitching])
    } else if recordings < req.inputs.len() {
        let odd = req.inputs.iter().zip(&kinds).find(|(_, r)| !**r).map(|(p, _)| p.display().to_string());
        return Err(Error::Input(format!(
            "{} is not a recording: give either recordings of one survey or one profile file",
            odd.unwrap_or_default()
        )));
    } else {
        if let Some(dx_mm) = req.dx_mm {
            opts.stitch.dx_mm = dx_mm;
        }
        let mut runs = Vec::new();
        let mut recs = Vec::new();
        for path in &req.inputs {
            let (mut rec, stitching) = read_run(path, &opts, calibration.as_ref(), progress)?;
            if let Some(sv) = self::survey(path)? {
                rec.survey = Some(sv);
            }
            recs.push((path.clone(), rec));
            runs.push(stitching);
        }
        analyze::check_runs(&mut recs, req.allowed)?;
        // A run's given placement, else its recording's survey.
        for (_, rec) in recs.iter().skip(placements.len()) {
            let p = match &rec.survey {
                Some(sv) => sv.placement().map_err(|e| Error::Input(e.to_string()))?,
                None => Placement::default(),
            };
            placements.push(p);
        }
        if let Some(path) = &req.track_register {
            let register = crate::gnss::register::Register::load(path).map_err(|e| Error::Input(e.to_string()))?;
            let paths: Vec<&Path> = recs.iter().map(|(p, _)| p.as_path()).collect();
            gnss_placing = placing::place(&register, &paths, &placements, req.search_mm / 1000.0)?;
            placements = gnss_placing.iter().map(placing::GnssPlacing::placement).collect();
        }
        (Source::Recordings(recs), runs)
    };
    let join_opts = survey::JoinOptions {
        search_mm: req.search_mm,
        section_gap_mm: survey::section_gap_mm(&opts.verdict),
        ..survey::JoinOptions::default()
    };
    let (stitching, joins) =
        survey::join(runs, &placements, &join_opts).map_err(|e| Error::Input(format!("{}: {e}", source.name())))?;
    let mut a = analyze::judge(stitching, joins, &opts, progress)?;
    a.gnss_placing = gnss_placing;
    let head = calibration.as_ref().and_then(|(file, _, _)| file.head_lens()).unwrap_or_else(HeadLens::reference);
    a.optics = optics_check(&source, req.optics, head, &a);
    Ok((source, a))
}

/// The survey's floor against the optics its recordings were made with
/// (`given` for all of them, else each one's survey block), on `head`
/// (the calibration's when one is given, else the reference head: the
/// check says which).
fn optics_check(source: &Source, given: Option<Optics>, head: HeadLens, a: &Analysis) -> OpticsCheck {
    let Source::Recordings(recs) = source else { return OpticsCheck::NotRecorded };
    let (optics, from) = match given {
        Some(o) => (o, OpticsSource::Given),
        None => {
            let each: Vec<Option<Optics>> =
                recs.iter().map(|(_, r)| r.survey.as_ref().and_then(|s| s.optics)).collect();
            let Some(Some(first)) = each.first() else { return OpticsCheck::NotRecorded };
            if let Some(k) = each.iter().position(|o| o.as_ref() != Some(first)) {
                return OpticsCheck::Mixed(match each[k] {
                    Some(o) => format!("run 1 was recorded with {first}, run {} with {o}", k + 1),
                    None => format!("run {} does not say what optics it was made with", k + 1),
                });
            }
            (*first, OpticsSource::Recorded)
        }
    };
    let sums = recs.iter().fold(analyze::MotionSums::default(), |s, (_, r)| s.merge(&r.motion));
    let motion = sums.motion().unwrap_or(Motion { exposure_us: 0.0, speed_mm_s: 0.0 });
    OpticsCheck::of_runs(optics, from, (head, motion), runs_averaged(&a.lasers), a.floor.as_ref())
}

/// The runs averaged over all the lines' samples (harmonic: the factor by
/// which noise independent from run to run falls in the pooled floor).
pub fn runs_averaged(lasers: &[analyze::LaserAnalysis]) -> f64 {
    let (samples, inverse) = lasers.iter().fold((0.0, 0.0), |(n, i), l| {
        let k = l.stitched.z.finite() as f64;
        (n + k, i + k / l.stitched.runs_averaged.max(1.0))
    });
    if inverse > 0.0 { samples / inverse } else { 1.0 }
}

/// The survey block of a recording, checked (`None`: none given).
pub fn survey(path: &Path) -> Result<Option<Survey>, Error> {
    let Some(text) = crate::recording::survey_of(path).map_err(Error::from)? else { return Ok(None) };
    let survey = Survey::parse(&text).map_err(|e| Error::Input(format!("{}: survey block: {e}", path.display())))?;
    Ok(Some(survey))
}

/// Whether a file is read as a recording rather than a profile CSV
/// ([`crate::recording::taken_for_recording`]: by its name or its first
/// bytes).
pub fn is_recording(path: &Path) -> Result<bool, Error> {
    crate::recording::taken_for_recording(path)
        .map_err(|e| Error::Input(format!("cannot read {}: {e}", path.display())))
}

/// One recording read and stitched (slid across with a calibration).
fn read_run(
    path: &Path,
    opts: &Options,
    calibration: Option<&(CalibrationFile, Measurer, String)>,
    progress: &dyn Progress,
) -> Result<(Recording, stitch::Stitching), Error> {
    let rec_name = path.display().to_string();
    let mut stitcher = Stitcher::new(&opts.stitch).map_err(|e| Error::Input(format!("{rec_name}: {e}")))?;
    let mut slid = 0usize;
    let mut rec = analyze::read_recording(path, progress, |so_far, mut f| {
        if let Some((file, m, name)) = calibration {
            // The heads seen so far (a `Hello` precedes its profiles): a
            // calibration of another head is refused before the work.
            if so_far.frames == 1 {
                file.check_recording(name, &rec_name, &so_far.heads)?;
            }
            slid += usize::from(analyze::slide_frame(&mut f, m));
        }
        stitcher.push(&f);
        Ok(())
    })?;
    if let Some((file, _, name)) = calibration {
        // Every head of the recording, the later ones included.
        file.check_recording(name, &rec_name, &rec.heads)?;
        rec.slid_across = Some((slid, PathBuf::from(name)));
    }
    let stitching = stitcher.finish().map_err(|e| Error::Input(format!("{rec_name}: {e}")))?;
    Ok((rec, stitching))
}
