//! The whole of `cms-host analyze` short of writing its outputs: the
//! inputs told apart (recordings of one survey, or one profile file), each
//! recording read once and stitched as it is read (slid across the rail
//! head first with a calibration), the runs checked, placed and joined on
//! chainage, and the result judged. The command line, the viewer and the
//! trend over surveys all analyse through here, so they agree.

use std::path::{Path, PathBuf};

use crate::Error;
use crate::analyze::stitch::{self, Stitcher};
use crate::analyze::survey::{self, Placement};
use crate::analyze::{self, Analysis, Options, Recording, RunsAllowed, Source, profile};
use crate::calib::file::CalibrationFile;
use crate::measure::Measurer;
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
            let name = path.display();
            if let Some(text) = crate::recording::survey_of(path).map_err(Error::from)? {
                let survey = Survey::parse(&text).map_err(|e| Error::Input(format!("{name}: survey block: {e}")))?;
                rec.survey = Some(survey);
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
        (Source::Recordings(recs), runs)
    };
    let join_opts = survey::JoinOptions {
        search_mm: req.search_mm,
        section_gap_mm: survey::section_gap_mm(&opts.verdict),
        ..survey::JoinOptions::default()
    };
    let (stitching, joins) =
        survey::join(runs, &placements, &join_opts).map_err(|e| Error::Input(format!("{}: {e}", source.name())))?;
    let a = analyze::judge(stitching, joins, &opts);
    Ok((source, a))
}

/// Whether a file is a recording (by its magic) rather than a profile.
pub fn is_recording(path: &Path) -> Result<bool, Error> {
    use std::io::Read as _;
    let mut f = std::fs::File::open(path).map_err(|e| Error::Input(format!("cannot read {}: {e}", path.display())))?;
    let mut magic = [0u8; 8];
    // Shorter than a recording's magic: not a recording.
    Ok(f.read_exact(&mut magic).is_ok() && magic == crate::recording::MAGIC)
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
