//! `cms-host analyze`: its arguments and output.

use std::io::Write as _;
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::Error;
use cms_host::analyze::reprofiling::Edition;
use cms_host::analyze::standards::en15610;
use cms_host::analyze::stitch::{Direction, Registration};
use cms_host::analyze::survey::Placement;
use cms_host::analyze::{self, Options, runs};
use cms_host::model::optics::Optics;

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

impl EditionArg {
    /// The edition named.
    pub fn edition(self) -> Edition {
        match self {
            EditionArg::En2006 => Edition::En2006,
            EditionArg::En2012 => Edition::En2012,
        }
    }
}

/// `--register`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RegisterArg {
    /// One height offset per frame, common to its lines, solved from all
    /// overlaps of all lines together, each weighted by its noise.
    Joint,
    /// The joint solve with the head's pitch (a tilt per frame common to its lines).
    JointPitch,
    /// Height offset and tilt per frame from its overlap, each line on its own.
    OffsetTilt,
    /// Height offset per frame from its overlap, each line on its own.
    Offset,
    /// No registration: overlapping frames averaged as they are.
    None,
}

/// What to analyse and how: the arguments `cms-host analyze` and
/// `cms-host view` share.
#[derive(Args, Debug, Clone)]
pub struct AnalysisArgs {
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
    /// Sample spacing of the stitched profile, mm (EN 15610 needs ≤ 1);
    /// default 1 for recordings and the data's own spacing for a profile
    /// (0.05 to 10).
    #[arg(long = "dx-mm", value_name = "MM", value_parser = dx_mm)]
    pub dx_mm: Option<f64>,
    /// How image rows map onto the track (recordings; default auto).
    #[arg(long, value_enum)]
    pub direction: Option<DirectionArg>,
    /// What registration corrects per frame (recordings; default joint).
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
    /// A track register (`lat_deg,lon_deg,chainage_m`, docs/gnss.md): each
    /// run with GNSS fixes is placed by them, its typed start (--chainage,
    /// the survey's) checked against them and reported disputed beyond
    /// their combined tolerance; a run without a start is placed too.
    #[arg(long = "track-register", value_name = "REGISTER.csv")]
    pub track_register: Option<PathBuf>,
    /// The lens's F-number and the lasers' wavelength the recordings were
    /// made with, for recordings that do not say (their survey block's
    /// `[optics]`, written by listen): the noise floor is checked against
    /// what they predict (docs/noise-floor.md). E.g. 2.8@685.
    #[arg(long, value_name = "F_NUMBER@WAVELENGTH_NM", value_parser = optics)]
    pub optics: Option<Optics>,
}

/// Arguments of `cms-host analyze`.
#[derive(Args, Debug, Clone)]
pub struct AnalyzeArgs {
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Write a report (report.md, report.html, SVG and PNG plots, CSV and the Parquet exports) into DIR
    /// (created if missing; an existing report is replaced whole, never mixed with the new one).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Write the stitched profile, the blocks and the zones as Parquet
    /// (profile.parquet, blocks.parquet, zones.parquet, fixes.parquet,
    /// third_octaves.parquet; docs/exports.md)
    /// into DIR (created if missing; an existing DIR is replaced whole).
    /// The report writes them too: the same DIR as --report writes the report once.
    #[arg(long, value_name = "DIR")]
    pub parquet: Option<PathBuf>,
    /// Print one JSON object instead of the text summary.
    #[arg(long)]
    pub json: bool,
}

fn placement(s: &str) -> Result<Placement, String> {
    s.parse().map_err(|e: cms_host::recording::survey_info::SurveyError| e.to_string())
}

fn optics(s: &str) -> Result<Optics, String> {
    s.parse().map_err(|e: cms_host::model::optics::OpticsError| e.to_string())
}

fn block_m(s: &str) -> Result<f64, cms_host::Error> {
    runs::Range::BlockM.parse(s)
}

fn search_m(s: &str) -> Result<f64, cms_host::Error> {
    runs::Range::SearchM.parse(s)
}

fn dx_mm(s: &str) -> Result<f64, cms_host::Error> {
    runs::Range::DxMm.parse(s)
}

fn segment_mm(s: &str) -> Result<f64, cms_host::Error> {
    runs::Range::SegmentMm.parse(s)
}

impl AnalysisArgs {
    /// The analysis options these arguments ask for.
    pub fn options(&self) -> Options {
        let defaults = runs::Settings::default();
        runs::Settings {
            edition: self.edition.edition(),
            block_m: self.block_m,
            dx_mm: self.dx_mm,
            direction: match self.direction {
                None => defaults.direction,
                Some(DirectionArg::Auto) => Direction::Auto,
                Some(DirectionArg::Forward) => Direction::Forward,
                Some(DirectionArg::Reverse) => Direction::Reverse,
            },
            registration: match self.register {
                None => defaults.registration,
                Some(RegisterArg::Joint) => Registration::Joint,
                Some(RegisterArg::JointPitch) => Registration::JointPitch,
                Some(RegisterArg::OffsetTilt) => Registration::OffsetTilt,
                Some(RegisterArg::Offset) => Registration::Offset,
                Some(RegisterArg::None) => Registration::None,
            },
            segment_mm: self.segment_mm,
            remove_spikes: !self.no_spike_removal,
            curvature: !self.no_curvature,
        }
        .options()
    }

    /// The options given that differ from their defaults, by flag.
    pub fn given(&self) -> Vec<&'static str> {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            analysis: AnalysisArgs,
        }
        let defaults = <Defaults as clap::Parser>::parse_from(["cms-host", "input"]).analysis;
        [
            ("--chainage", !self.chainage.is_empty()),
            ("--edition", self.edition != defaults.edition),
            ("--block-m", self.block_m != defaults.block_m),
            ("--search-m", self.search_m != defaults.search_m),
            ("--allow-repeated-runs", self.allow_repeated_runs),
            ("--allow-mixed-heads", self.allow_mixed_heads),
            ("--dx-mm", self.dx_mm.is_some()),
            ("--direction", self.direction.is_some()),
            ("--register", self.register.is_some()),
            ("--segment-mm", self.segment_mm != defaults.segment_mm),
            ("--no-spike-removal", self.no_spike_removal),
            ("--no-curvature", self.no_curvature),
            ("--calibration", self.calibration.is_some()),
            ("--optics", self.optics.is_some()),
        ]
        .into_iter()
        .filter_map(|(flag, given)| given.then_some(flag))
        .collect()
    }

    /// What to analyse, for [`runs::run`].
    pub fn request(&self) -> runs::Request {
        let args = self;
        let only_recordings = [
            ("--calibration", args.calibration.is_some()),
            ("--direction", args.direction.is_some()),
            ("--register", args.register.is_some()),
            ("--allow-repeated-runs", args.allow_repeated_runs),
            ("--allow-mixed-heads", args.allow_mixed_heads),
            ("--track-register", args.track_register.is_some()),
            ("--optics", args.optics.is_some()),
        ];
        runs::Request {
            inputs: args.inputs.clone(),
            placements: args.chainage.clone(),
            calibration: args.calibration.clone(),
            allowed: analyze::RunsAllowed { repeats: args.allow_repeated_runs, mixed_heads: args.allow_mixed_heads },
            search_mm: args.search_m * 1000.0,
            dx_mm: args.dx_mm,
            recording_only: only_recordings.iter().filter(|(_, given)| *given).map(|(f, _)| f.to_string()).collect(),
            track_register: args.track_register.clone(),
            optics: args.optics,
        }
    }
}

/// Runs `cms-host analyze`: its outputs checked before the work, the
/// analysis ([`runs::run`]), then the summary and the files.
pub fn run(args: &AnalyzeArgs) -> anyhow::Result<()> {
    let opts = args.analysis.options();
    // An output set never goes where it could replace an input.
    let outputs = [("--report", &args.report), ("--parquet", &args.parquet)];
    for (flag, dir) in outputs.iter().filter_map(|(f, d)| d.as_ref().map(|d| (f, d))) {
        let inputs = args.analysis.inputs.iter().chain(&args.analysis.calibration);
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
    let (source, a) = runs::run(&args.analysis.request(), &opts, &Bar::stderr())?;
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
