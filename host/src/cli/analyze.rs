//! `cms-host analyze`: its arguments and output.

use std::io::Write as _;
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::Error;
use cms_host::analyze::stitch::{self, Direction, Registration, Stitcher};
use cms_host::analyze::{self, Options};
use cms_host::calib::file::CalibrationFile;
use cms_host::measure::Measurer;
use cms_host::standards::en15610;

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
    /// A recording (`cms-host listen --record`) of a calibrated head.
    #[arg(value_name = "RECORDING")]
    pub recording: PathBuf,
    /// Write a report (report.md, report.html, SVG and PNG plots, CSV) into DIR (created if missing).
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Print one JSON object instead of the text summary.
    #[arg(long)]
    pub json: bool,
    /// Sample spacing of the stitched profile, mm (EN 15610 needs ≤ 1).
    #[arg(long = "dx-mm", value_name = "MM", default_value_t = 1.0, value_parser = positive)]
    pub dx_mm: f64,
    /// How image rows map onto the track.
    #[arg(long, value_enum, default_value_t = DirectionArg::Auto)]
    pub direction: DirectionArg,
    /// What registration corrects per frame.
    #[arg(long, value_enum, default_value_t = RegisterArg::Offset)]
    pub register: RegisterArg,
    /// EN 15610 Welch segment length, mm (≥ 1000; wavelengths up to a quarter of it).
    #[arg(long = "segment-mm", value_name = "MM", default_value_t = en15610::MIN_SEGMENT_MM, value_parser = positive)]
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

fn positive(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1e6 => Ok(v),
        _ => Err(format!("`{s}` is not a positive length in mm (at most 1e6)")),
    }
}

impl AnalyzeArgs {
    /// The analysis options these arguments ask for.
    pub fn options(&self) -> Options {
        Options {
            stitch: stitch::Options {
                dx_mm: self.dx_mm,
                direction: match self.direction {
                    DirectionArg::Auto => Direction::Auto,
                    DirectionArg::Forward => Direction::Forward,
                    DirectionArg::Reverse => Direction::Reverse,
                },
                registration: match self.register {
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
        }
    }
}

/// Runs `cms-host analyze`: one pass over the recording, each frame slid
/// across (with `--calibration`) and stitched as it is read.
pub fn run(args: &AnalyzeArgs) -> anyhow::Result<()> {
    let opts = args.options();
    let rec_name = args.recording.display().to_string();
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
    let mut stitcher = Stitcher::new(&opts.stitch).map_err(|e| Error::Input(format!("{rec_name}: {e}")))?;
    let mut slid = 0usize;
    let mut rec = analyze::read_recording(&args.recording, &Bar::stderr(), |so_far, mut f| {
        if let Some((file, m, name)) = &calibration {
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
    if let Some((file, _, name)) = &calibration {
        // Every head of the recording, the later ones included.
        file.check_recording(name, &rec_name, &rec.heads)?;
        rec.slid_across = Some((slid, PathBuf::from(name)));
    }
    let stitching = stitcher.finish().map_err(|e| Error::Input(format!("{rec_name}: {e}")))?;
    let a = analyze::judge(stitching, &opts);
    let text = analyze::summary(&args.recording, &rec, &a);
    if let Some(dir) = &args.report {
        analyze::report::write(dir, &args.recording, &rec, &a, &text)?;
    }
    let mut out = std::io::stdout().lock();
    if args.json {
        writeln!(out, "{}", analyze::to_json(&args.recording, &rec, &a)).map_err(Error::Output)?;
    } else {
        out.write_all(text.as_bytes()).map_err(Error::Output)?;
        if let Some(dir) = &args.report {
            writeln!(out, "\nreport: {}", dir.join("report.html").display()).map_err(Error::Output)?;
        }
    }
    out.flush().map_err(Error::Output)?;
    Ok(())
}
