//! `cms-host analyze`: its arguments and output.

use std::io::Write as _;
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::Error;
use cms_host::analyze::reprofiling::{self, Edition};
use cms_host::analyze::standards::en15610;
use cms_host::analyze::stitch::{self, Direction, Registration, Stitcher};
use cms_host::analyze::survey::{self, Placement};
use cms_host::analyze::{self, Options, Source, profile};
use cms_host::calib::file::CalibrationFile;
use cms_host::measure::Measurer;
use cms_host::recording::survey_info::Survey;

use super::progress::Bar;

/// `--direction`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DirectionArg {
    /// Whichever registers better (forward on a tie).
    Auto,
    /// Track position = odometer + along (image rows run with the odometer).
    Forward,
    /// Track position = odometer − along.
    Reverse,
}

/// `--edition`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EditionArg {
    /// EN 13231-3:2006: moving-window mean peak-to-peak.
    #[value(name = "2006")]
    En2006,
    /// EN 13231-3:2012: isolated points over the Class 1 limit.
    #[value(name = "2012")]
    En2012,
}

/// `--register`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RegisterArg {
    /// Height offset and tilt per frame from its overlap.
    OffsetTilt,
    /// Height offset only.
    Offset,
    /// No registration: overlapping frames averaged as they are.
    None,
}

/// Arguments of `cms-host analyze`.
#[derive(Args, Debug, Clone)]
pub struct AnalyzeArgs {
    /// Recordings (`cms-host listen --record`) of a calibrated head — the
    /// runs of one survey, joined on chainage — or one profile file from
    /// any instrument (`x_mm,height_um`, or `x_mm,height_um_0,height_um_1,…`).
    #[arg(value_name = "RECORDING|PROFILE.csv", required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// Where each run lies, one per recording in order: its start chainage
    /// (the chainage of odometer 0, `KM+M` or metres) and whether chainage
    /// runs up or down with it (`0+000`, `12+345.6:down`, `:down`, `auto`).
    /// Taken as given: a run after the first is registered only on runs it
    /// overlaps where its start puts it, and moved at most --search-m; a
    /// given heading is kept (and flagged when the other matches better).
    /// Without a start, a run is registered anywhere it overlaps.
    #[arg(long, value_name = "KM+M[:up|:down]", value_parser = placement)]
    pub chainage: Vec<Placement>,
    /// The EN 13231-3 edition whose criterion gives the verdict (zones, reprofiling table).
    #[arg(long, value_enum, default_value_t = EditionArg::En2006)]
    pub edition: EditionArg,
    /// Block length for block RMS and the per-block EN 15610 spectrum, m (1 to 1000).
    #[arg(long = "block-m", value_name = "M", default_value_t = 50.0, value_parser = block_m)]
    pub block_m: f64,
    /// How far registration may move a run from its given start chainage, m (above 0, at most 1000).
    #[arg(long = "search-m", value_name = "M", default_value_t = 25.0, value_parser = search_m)]
    pub search_m: f64,
    /// Join the same recording given more than once (refused otherwise: a
    /// run averaged with itself looks better measured than it is).
    #[arg(long = "allow-repeated-runs")]
    pub allow_repeated_runs: bool,
    /// Join recordings of different heads (calibration, sensor or survey
    /// instrument; refused otherwise).
    #[arg(long = "allow-mixed-heads")]
    pub allow_mixed_heads: bool,
    /// Write a report (report.md, report.html, SVG and PNG plots, CSV and the Parquet exports) into DIR
    /// (created if missing; an existing report is replaced whole, never mixed with the new one).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Write the stitched profile, the blocks and the zones as Parquet
    /// (profile.parquet, blocks.parquet, zones.parquet; docs/exports.md)
    /// into DIR (created if missing; an existing DIR is replaced whole).
    /// The report writes them too: the same DIR as --report writes the report once.
    #[arg(long, value_name = "DIR")]
    pub parquet: Option<PathBuf>,
    /// Print one JSON object instead of the text summary.
    #[arg(long)]
    pub json: bool,
    /// Sample spacing of the stitched profile, mm (EN 15610 needs ≤ 1);
    /// default 1 for recordings and the data's own spacing for a profile
    /// (0.05 to 10).
    #[arg(long = "dx-mm", value_name = "MM", value_parser = dx_mm)]
    pub dx_mm: Option<f64>,
    /// How image rows map onto the track (recordings; default auto).
    #[arg(long, value_enum)]
    pub direction: Option<DirectionArg>,
    /// What registration corrects per frame (recordings; default offset).
    #[arg(long, value_enum)]
    pub register: Option<RegisterArg>,
    /// EN 15610 Welch segment length, mm (1000 to 1e6; wavelengths up to a quarter of it).
    #[arg(long = "segment-mm", value_name = "MM", default_value_t = en15610::MIN_SEGMENT_MM, value_parser = segment_mm)]
    pub segment_mm: f64,
    /// Skip EN 15610 spike removal.
    #[arg(long = "no-spike-removal")]
    pub no_spike_removal: bool,
    /// Skip EN 15610 curvature (wheel) processing.
    #[arg(long = "no-curvature")]
    pub no_curvature: bool,
    /// The head's calibration file (the one it recorded with): every
    /// frame's points are then slid across the rail head's lateral slope
    /// (the lines' lateral positions come from its laser planes), which
    /// takes out the ±2–5 % height scale of the outer lines on a crowned rail.
    #[arg(long, value_name = "CAL.toml")]
    pub calibration: Option<PathBuf>,
}

fn placement(s: &str) -> Result<Placement, String> {
    s.parse().map_err(|e: cms_host::recording::survey_info::SurveyError| e.to_string())
}

/// A number in `lo..=hi` (`lo` itself excluded when `open`), else an
/// error naming the value and the range.
fn in_range(s: &str, (lo, hi): (f64, f64), open: bool, what: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (v > lo || (!open && v == lo)) && v <= hi => Ok(v),
        _ => Err(format!("`{s}` is not {what} ({}{lo} to {hi})", if open { "above " } else { "" })),
    }
}

/// A block shorter than a metre holds under one period of the longest
/// band's wavelengths (300–1000 mm); one longer than a kilometre is no
/// longer a place on the track a verdict can point at.
fn block_m(s: &str) -> Result<f64, String> {
    in_range(s, (1.0, 1000.0), false, "a block length in m")
}

fn search_m(s: &str) -> Result<f64, String> {
    in_range(s, (0.0, 1000.0), true, "a search distance in m")
}

/// Finer than 0.05 mm is below every head's sampling along the rail (the
/// reference head's rows are 0.144 mm apart) and only multiplies the work;
/// coarser than 10 mm cannot show the shortest wavelength judged (10 mm).
fn dx_mm(s: &str) -> Result<f64, String> {
    in_range(s, (0.05, 10.0), false, "a sample spacing in mm")
}

fn segment_mm(s: &str) -> Result<f64, String> {
    in_range(s, (en15610::MIN_SEGMENT_MM, 1e6), false, "an EN 15610 segment length in mm")
}

impl AnalyzeArgs {
    /// The analysis options these arguments ask for.
    pub fn options(&self) -> Options {
        Options {
            stitch: stitch::Options {
                dx_mm: self.dx_mm.unwrap_or(1.0),
                direction: match self.direction.unwrap_or(DirectionArg::Auto) {
                    DirectionArg::Auto => Direction::Auto,
                    DirectionArg::Forward => Direction::Forward,
                    DirectionArg::Reverse => Direction::Reverse,
                },
                registration: match self.register.unwrap_or(RegisterArg::Offset) {
                    RegisterArg::OffsetTilt => Registration::OffsetTilt,
                    RegisterArg::Offset => Registration::Offset,
                    RegisterArg::None => Registration::None,
                },
                ..stitch::Options::default()
            },
            roughness: en15610::Options {
                segment_mm: self.segment_mm,
                remove_spikes: !self.no_spike_removal,
                curvature: !self.no_curvature,
                ..en15610::Options::default()
            },
            verdict: reprofiling::Options {
                edition: match self.edition {
                    EditionArg::En2006 => Edition::En2006,
                    EditionArg::En2012 => Edition::En2012,
                },
                block_mm: self.block_m * 1000.0,
            },
        }
    }
}

/// Whether a file is a recording (by its magic) rather than a profile.
fn is_recording(path: &std::path::Path) -> Result<bool, Error> {
    use std::io::Read as _;
    let mut f = std::fs::File::open(path).map_err(|e| Error::Input(format!("cannot read {}: {e}", path.display())))?;
    let mut magic = [0u8; 8];
    // Shorter than a recording's magic: not a recording.
    Ok(f.read_exact(&mut magic).is_ok() && magic == cms_host::recording::MAGIC)
}

/// Runs `cms-host analyze`: one pass over each recording, each frame slid
/// across (with `--calibration`) and stitched as it is read, the runs
/// joined on chainage; or one profile file.
pub fn run(args: &AnalyzeArgs) -> anyhow::Result<()> {
    let mut opts = args.options();
    if args.chainage.len() > args.inputs.len() {
        return Err(Error::Input(format!(
            "{} --chainage for {} input(s): give at most one per recording, in order",
            args.chainage.len(),
            args.inputs.len()
        ))
        .into());
    }
    // An output set never goes where it could replace an input.
    let outputs = [("--report", &args.report), ("--parquet", &args.parquet)];
    for (flag, dir) in outputs.iter().filter_map(|(f, d)| d.as_ref().map(|d| (f, d))) {
        let inputs = args.inputs.iter().chain(&args.calibration);
        if let Some(input) = inputs.into_iter().find(|i| cms_host::output::folder_holds(dir, i)) {
            return Err(Error::Input(format!(
                "{flag} {}: the folder holds the input {}; write the output set into another folder",
                dir.display(),
                input.display()
            ))
            .into());
        }
    }
    // An output folder that cannot take its set fails before the work: a
    // file, a device, a folder holding what the set does not write.
    if let Some(dir) = &args.report {
        cms_host::output::set::check_set(dir, cms_host::report::owns)
            .map_err(|e| anyhow::Error::from(Error::from(e)).context("--report"))?;
    }
    let parquet_in_report = match (&args.report, &args.parquet) {
        (Some(r), Some(p)) => {
            let (r, p) = (resolved(r), resolved(p));
            if r != p && (r.starts_with(&p) || p.starts_with(&r)) {
                return Err(Error::Input(format!(
                    "--report {} and --parquet {}: one folder inside the other; each is replaced whole, give folders side by side",
                    r.display(),
                    p.display()
                ))
                .into());
            }
            r == p
        }
        _ => false,
    };
    // The same folder as --report: the report holds the Parquet files.
    if let Some(dir) = args.parquet.as_ref().filter(|_| !parquet_in_report) {
        cms_host::output::set::check_set(dir, cms_host::report::exports::owns)
            .map_err(|e| anyhow::Error::from(Error::from(e)).context("--parquet"))?;
    }
    // The calibration is checked before any input is read.
    let calibration = match &args.calibration {
        Some(path) => {
            let name = path.display().to_string();
            // The file's own errors name it.
            let file = CalibrationFile::load(path).map_err(Error::from)?;
            let m = Measurer::new(&file).map_err(|e| Error::Input(format!("{name}: {e}")))?;
            Some((file, m, name))
        }
        None => None,
    };
    let kinds = args.inputs.iter().map(|p| is_recording(p)).collect::<Result<Vec<bool>, Error>>()?;
    let recordings = kinds.iter().filter(|&&r| r).count();
    let mut placements = args.chainage.clone();
    let (source, runs) = if recordings == 0 {
        let [path] = args.inputs.as_slice() else {
            return Err(Error::Input(format!(
                "{} profile files: analyze one at a time (recordings of one survey can be joined)",
                args.inputs.len()
            ))
            .into());
        };
        // Options that only recordings have are refused, not ignored: the
        // user asked for something this input cannot give.
        let only_recordings = [
            ("--calibration", args.calibration.is_some()),
            ("--direction", args.direction.is_some()),
            ("--register", args.register.is_some()),
            ("--allow-repeated-runs", args.allow_repeated_runs),
            ("--allow-mixed-heads", args.allow_mixed_heads),
        ];
        if let Some((flag, _)) = only_recordings.iter().find(|(_, given)| *given) {
            return Err(Error::Input(format!(
                "{}: {flag} applies to recordings, not to a profile file",
                path.display()
            ))
            .into());
        }
        let (file, stitching) = profile::read(path, args.dx_mm)?;
        opts.stitch.dx_mm = stitching.lasers.first().map_or(opts.stitch.dx_mm, |l| l.dx_mm);
        (Source::Profile(path.clone(), file), vec![stitching])
    } else if recordings < args.inputs.len() {
        let odd = args.inputs.iter().zip(&kinds).find(|(_, r)| !**r).map(|(p, _)| p.display().to_string());
        let odd = odd.unwrap_or_default();
        return Err(Error::Input(format!(
            "{odd} is not a recording: give either recordings of one survey or one profile file"
        ))
        .into());
    } else {
        let mut runs = Vec::new();
        let mut recs = Vec::new();
        for path in &args.inputs {
            let (mut rec, stitching) = read_run(path, &opts, calibration.as_ref())?;
            let name = path.display();
            if let Some(text) = cms_host::recording::survey_of(path).map_err(Error::from)? {
                let survey = Survey::parse(&text).map_err(|e| Error::Input(format!("{name}: survey block: {e}")))?;
                rec.survey = Some(survey);
            }
            recs.push((path.clone(), rec));
            runs.push(stitching);
        }
        let allowed = analyze::RunsAllowed { repeats: args.allow_repeated_runs, mixed_heads: args.allow_mixed_heads };
        analyze::check_runs(&mut recs, allowed)?;
        // A run's --chainage, else its recording's survey.
        for (k, (_, rec)) in recs.iter().enumerate() {
            if k >= placements.len() {
                let p = match &rec.survey {
                    Some(sv) => sv.placement().map_err(|e| Error::Input(e.to_string()))?,
                    None => Placement::default(),
                };
                placements.push(p);
            }
        }
        (Source::Recordings(recs), runs)
    };
    let join_opts = survey::JoinOptions {
        search_mm: args.search_m * 1000.0,
        section_gap_mm: survey::section_gap_mm(&opts.verdict),
        ..survey::JoinOptions::default()
    };
    let (stitching, joins) =
        survey::join(runs, &placements, &join_opts).map_err(|e| Error::Input(format!("{}: {e}", source.name())))?;
    let a = analyze::judge(stitching, joins, &opts);
    let text = cms_host::report::text::summary(&source, &a);
    if let Some(dir) = &args.report {
        cms_host::report::write(dir, &source, &a, &text)?;
    }
    if let Some(dir) = args.parquet.as_ref().filter(|_| !parquet_in_report) {
        cms_host::report::exports::write(dir, &source, &a)?;
    }
    let mut out = std::io::stdout().lock();
    if args.json {
        writeln!(out, "{}", cms_host::report::json::to_json(&source, &a)).map_err(Error::Output)?;
    } else {
        out.write_all(text.as_bytes()).map_err(Error::Output)?;
        if let Some(dir) = &args.report {
            writeln!(out, "\nreport: {}", dir.join("report.html").display()).map_err(Error::Output)?;
        }
    }
    out.flush().map_err(Error::Output)?;
    Ok(())
}

/// `p` made absolute with its links resolved as far as it exists (an
/// output folder may not exist yet), to tell whether two folders are one.
fn resolved(p: &std::path::Path) -> PathBuf {
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut tail = Vec::new();
    let mut head = abs.as_path();
    loop {
        if let Ok(real) = std::fs::canonicalize(head) {
            return tail.iter().rev().fold(real, |acc: PathBuf, part| acc.join(part));
        }
        match (head.parent(), head.file_name()) {
            (Some(up), Some(name)) => {
                tail.push(name.to_os_string());
                head = up;
            }
            _ => return abs,
        }
    }
}

/// One recording read and stitched (slid across with a calibration).
fn read_run(
    path: &std::path::Path,
    opts: &Options,
    calibration: Option<&(CalibrationFile, Measurer, String)>,
) -> anyhow::Result<(analyze::Recording, stitch::Stitching)> {
    let rec_name = path.display().to_string();
    let mut stitcher = Stitcher::new(&opts.stitch).map_err(|e| Error::Input(format!("{rec_name}: {e}")))?;
    let mut slid = 0usize;
    let mut rec = analyze::read_recording(path, &Bar::stderr(), |so_far, mut f| {
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
