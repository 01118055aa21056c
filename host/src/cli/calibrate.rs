//! `cms-host calibrate camera|lasers|upload|render`: their arguments and
//! what they print. The work is `cms_host::calib`'s.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use cms_host::Error;
use cms_host::calib;
use cms_host::calib::camera::{BoardViews, CalibOptions, calibrate};
use cms_host::calib::file::{CalibrationFile, HeadSection, SigmaSection};
use cms_host::calib::lasers::{LaserOptions, Pair, calibrate_lasers};
use cms_host::device::upload;
use cms_host::input::read_rows;
use cms_host::model::board::Board;
use cms_host::sim::calibration::images as render;

use super::exit::input;
use super::simulate::{PresetArg, SimPortArgs};

/// `cms-host calibrate …`
#[derive(clap::Subcommand, Debug, Clone)]
pub enum CalibrateCmd {
    /// Camera intrinsics and distortion from checkerboard photographs.
    Camera(CameraArgs),
    /// Laser planes from laser-on/laser-off image pairs of the board.
    Lasers(LasersArgs),
    /// Send a calibration file to a sensor head (or `sim`).
    Upload(UploadArgs),
    /// Render calibration images from the simulated head, with the truth.
    Render(RenderArgs),
}

/// Runs one `calibrate` subcommand.
pub fn run(cmd: &CalibrateCmd) -> anyhow::Result<()> {
    match cmd {
        CalibrateCmd::Camera(a) => camera(a),
        CalibrateCmd::Lasers(a) => lasers(a),
        CalibrateCmd::Upload(a) => {
            let opts =
                upload::Options { file: a.file.clone(), port: a.port.clone(), baud: a.baud, sim: a.sim.options()? };
            println!("{}", upload::upload(&opts)?);
            Ok(())
        }
        CalibrateCmd::Render(a) => {
            let opts = render::Options {
                preset: a.preset.into(),
                poses: a.poses,
                seed: a.seed,
                noiseless: a.noiseless,
                out: a.out.clone(),
            };
            Ok(render::render(&opts)?)
        }
    }
}

/// `cms-host calibrate camera`: intrinsics and distortion from photographs
/// of a checkerboard.
#[derive(clap::Args, Debug, Clone)]
pub struct CameraArgs {
    /// Inner corners of the board, COLSxROWS (e.g. 9x6).
    #[arg(long, value_name = "COLSxROWS")]
    pub board: String,
    /// Side of a board square, mm.
    #[arg(long, value_name = "MM")]
    pub square_mm: f64,
    /// The calibration file to write (TOML): a regular file, replaced whole.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Keep fx = fy (OpenCV's CALIB_FIX_ASPECT_RATIO at 1).
    #[arg(long)]
    pub fix_aspect: bool,
    /// Estimate the skew too (fixed at 0 by default).
    #[arg(long)]
    pub free_skew: bool,
    /// Drop views whose RMS reprojection error exceeds this many pixels, and fit again.
    #[arg(long, value_name = "PX")]
    pub max_view_rms: Option<f64>,
    /// Photographs of the board (PNG, JPEG, TIFF; 8 or 16 bits).
    #[arg(required = true, value_name = "IMAGES")]
    pub images: Vec<PathBuf>,
}

/// Runs `calibrate camera`.
pub fn camera(args: &CameraArgs) -> anyhow::Result<()> {
    // A device, FIFO or directory as --out is refused before the work.
    cms_host::output::check_target(&args.out)?;
    let board = parse_board(&args.board, args.square_mm).map_err(Error::Input)?;
    if let Some(m) = args.max_view_rms
        && !(m.is_finite() && m > 0.0)
    {
        return Err(input(format!("--max-view-rms {m}: must be a positive number of pixels")));
    }
    let mut out = std::io::stdout().lock();
    let mut rejected = Ok(());
    let found = calib::camera::board_views(&args.images, &board, load_gray, |path, e| {
        if rejected.is_ok() {
            rejected = writeln!(out, "{}: rejected: {e}", path.display());
        }
    });
    rejected.map_err(Error::Output)?;
    let BoardViews { views, names, size: (w, h) } = found.map_err(|e| input(e.to_string()))?;
    let opts = CalibOptions {
        fix_skew: !args.free_skew,
        fix_aspect: args.fix_aspect.then_some(1.0),
        max_view_rms_px: args.max_view_rms,
        ..CalibOptions::default()
    };
    let result = calibrate(&board, &views, w, h, &opts);
    // The views left out as duplicates are named whether or not the rest
    // calibrate (three copies of one photograph are one view).
    let dups = match &result {
        Ok(cal) => cal.duplicates.clone(),
        Err(_) => calib::camera::duplicates_of(&views),
    };
    for &(v, of, d) in &dups {
        writeln!(out, "{}: left out: the same pose as {} (corners {d:.3} px RMS apart)", names[v], names[of])
            .map_err(Error::Output)?;
    }
    let cal = result.map_err(|e| {
        let dup =
            if dups.is_empty() { String::new() } else { format!(" ({} near-duplicate views left out)", dups.len()) };
        Error::Input(format!("{e}{dup}"))
    })?;
    for &(v, e) in &cal.views_rejected {
        writeln!(out, "{}: rejected: RMS {e:.3} px > {:.3} px", names[v], args.max_view_rms.unwrap_or(0.0))
            .map_err(Error::Output)?;
    }
    for (&v, e) in cal.views_used.iter().zip(&cal.per_view_rms_px) {
        writeln!(out, "{}: RMS {e:.3} px", names[v]).map_err(Error::Output)?;
    }
    for why in &cal.fixed {
        writeln!(out, "{why}").map_err(Error::Output)?;
    }
    let k = &cal.intrinsics;
    writeln!(
        out,
        "{} views, {w} x {h}: fx {:.3} fy {:.3} cx {:.3} cy {:.3} skew {:.4} px; k1 {:.5} k2 {:.5} p1 {:.6} p2 {:.6} k3 {:.5}; RMS {:.4} px",
        cal.views_used.len(),
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        k.skew_px,
        k.k1,
        k.k2,
        k.p1,
        k.p2,
        k.k3,
        cal.rms_px
    )
    .map_err(Error::Output)?;
    let sigma: Vec<String> = calib::camera::INTRINSIC_NAMES
        .iter()
        .zip(cal.sigma.0)
        .map(|(n, s)| match s {
            Some(s) if n.starts_with('k') || n.starts_with('p') => format!("{n} {s:.2e}"),
            Some(s) => format!("{n} {s:.3}"),
            None => format!("{n} fixed"),
        })
        .collect();
    writeln!(out, "σ (one standard deviation, from the Jacobian; px for fx … skew): {}", sigma.join(", "))
        .map_err(Error::Output)?;
    let mut file = CalibrationFile::camera_only(&cal.intrinsics, cal.rms_px, Some(&board));
    file.camera_sigma = Some(SigmaSection::from_array(cal.sigma.0));
    file.save(&args.out)?;
    writeln!(out, "wrote {}", args.out.display()).map_err(Error::Output)?;
    Ok(())
}
/// Arguments of `calibrate lasers`.
#[derive(clap::Args, Debug, Clone)]
pub struct LasersArgs {
    /// The camera calibration (from `calibrate camera`).
    #[arg(long, value_name = "CAM.toml")]
    pub camera: PathBuf,
    /// Where to write the full calibration: a regular file, replaced whole.
    #[arg(long, value_name = "CAL.toml")]
    pub out: PathBuf,
    /// Inner corners of the board, COLSxROWS [default: the camera file's [board]].
    #[arg(long, value_name = "COLSxROWS")]
    pub board: Option<String>,
    /// Side of a square, mm [default: the camera file's [board]].
    #[arg(long = "square-mm", value_name = "S")]
    pub square_mm: Option<f64>,
    /// The pair (1-based) whose board plane is the rail-top datum.
    #[arg(long = "datum-pose", value_name = "K")]
    pub datum_pose: Option<usize>,
    /// Stripe σ range the detector searches on the board, px.
    #[arg(long, value_name = "MIN:MAX", default_value = "1:16")]
    pub scales: String,
    /// Largest acceptable RMS distance of a laser's points from its plane, mm.
    #[arg(long = "max-rms-mm", value_name = "MM", default_value_t = 0.1)]
    pub max_rms_mm: f64,
    /// Laser sheet thickness, mm: with --range-mm, adds the [head] section
    /// (the detector's scale range, paper Eq. 10–11).
    #[arg(long = "laser-diameter-mm", value_name = "D", requires = "range_mm")]
    pub laser_diameter_mm: Option<f64>,
    /// Working range, mm.
    #[arg(long = "range-mm", value_name = "MIN:MAX", requires = "laser_diameter_mm")]
    pub range_mm: Option<String>,
    /// Image pairs of the board at each pose: lasers off, then lasers on
    /// (PNG, TIFF or JPEG, same camera), e.g. board-00.png lasers-00.png board-01.png …
    #[arg(value_name = "OFF ON", required = true)]
    pub images: Vec<PathBuf>,
}

fn pair_of(s: &str, what: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once(':').ok_or_else(|| format!("{what} {s:?}: expected MIN:MAX"))?;
    let p = |t: &str| t.trim().parse::<f64>().map_err(|_| format!("{what} {s:?}: {t:?} is not a number"));
    let (a, b) = (p(a)?, p(b)?);
    if !(a.is_finite() && b.is_finite() && a > 0.0 && b > a) {
        return Err(format!("{what} {s:?}: need 0 < MIN < MAX"));
    }
    Ok((a, b))
}

/// Runs `calibrate lasers`.
pub fn lasers(args: &LasersArgs) -> anyhow::Result<()> {
    let usage = input;
    cms_host::output::check_target(&args.out)?;
    let mut file = CalibrationFile::load(&args.camera).map_err(Error::from)?;
    let board = match (&args.board, args.square_mm, file.board()) {
        (Some(b), Some(s), _) => parse_board(b, s).map_err(usage)?,
        (None, None, Some(b)) => b,
        (None, None, None) => {
            return Err(usage(format!("{} has no [board]: give --board and --square-mm", args.camera.display())));
        }
        _ => return Err(usage("--board and --square-mm go together".into())),
    };
    let scales = pair_of(&args.scales, "--scales").map_err(usage)?;
    if !(args.max_rms_mm.is_finite() && args.max_rms_mm > 0.0) {
        return Err(usage(format!("--max-rms-mm {}: must be > 0", args.max_rms_mm)));
    }
    let head = match (args.laser_diameter_mm, &args.range_mm) {
        (Some(d), Some(r)) => {
            let (lo, hi) = pair_of(r, "--range-mm").map_err(usage)?;
            if !(d.is_finite() && d > 0.0) {
                return Err(usage(format!("--laser-diameter-mm {d}: must be > 0")));
            }
            Some(HeadSection {
                laser_diameter_mm: d,
                range_min_mm: lo,
                range_max_mm: hi,
                f_number: None,
                wavelength_nm: None,
            })
        }
        _ => None,
    };
    if !args.images.len().is_multiple_of(2) || args.images.len() < 6 {
        return Err(usage(format!(
            "{} images: give pairs (lasers off, lasers on) of at least 3 poses",
            args.images.len()
        )));
    }
    let mut pairs = Vec::new();
    for ch in args.images.chunks(2) {
        let off = read_rows(&ch[0])?;
        let on = read_rows(&ch[1])?;
        pairs.push(Pair { off, on, name: format!("{} + {}", ch[0].display(), ch[1].display()) });
    }
    let opts = LaserOptions { scales, max_rms_mm: args.max_rms_mm, datum_pose: args.datum_pose.map(|k| k.max(1) - 1) };
    if args.datum_pose == Some(0) {
        return Err(usage("--datum-pose counts from 1".into()));
    }
    let intr = file.intrinsics();
    let cal = calibrate_lasers(&intr, &board, &pairs, &opts).map_err(|e| usage(e.to_string()))?;
    let mut report = String::new();
    for (i, p) in cal.poses.iter().enumerate() {
        let _ = match p {
            Ok(r) => writeln!(
                report,
                "pose {:>2}: board {:.3} px RMS at {:.0} mm; points per laser {:?}; {} stripes not assigned",
                i + 1,
                r.board_rms_px,
                r.pose.t_mm[2],
                r.points,
                r.ambiguous_rows
            ),
            Err(e) => writeln!(report, "pose {:>2}: rejected: {e}", i + 1),
        };
    }
    for (k, l) in cal.planes.iter().enumerate() {
        let _ = writeln!(
            report,
            "laser {k}: n = ({:+.6}, {:+.6}, {:+.6}), d = {:.4} mm, RMS {:.4} mm over {} points from {} poses ({} outliers), \
             spread {:.2} mm across the line, depths {:.1}–{:.1} mm",
            l.normal[0],
            l.normal[1],
            l.normal[2],
            l.d_mm,
            l.rms_mm,
            l.points,
            l.poses,
            l.outliers,
            l.spread_mm,
            l.depth_mm.0,
            l.depth_mm.1
        );
    }
    cal.complete(&mut file, head).map_err(|e| usage(e.to_string()))?;
    // The report first: a file refused on saving (a [head] range no
    // detector scale fits, say) still shows what was fitted.
    print!("{report}");
    file.save(&args.out)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Arguments of `calibrate upload`.
#[derive(clap::Args, Debug, Clone)]
pub struct UploadArgs {
    /// The calibration file (from `calibrate lasers`).
    #[arg(value_name = "CAL.toml")]
    pub file: PathBuf,
    /// Serial port of the head (`/dev/ttyACM0`), or `sim` for the simulated head.
    #[arg(value_name = "PORT")]
    pub port: String,
    /// Baud rate (ignored by USB CDC heads).
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub sim: SimPortArgs,
}

/// Arguments of `cms-host calibrate render`.
#[derive(clap::Args, Debug, Clone)]
pub struct RenderArgs {
    /// The simulated head.
    #[arg(long, value_enum, default_value_t = PresetArg::Reference)]
    pub preset: PresetArg,
    /// Number of board poses, 1..=100.
    #[arg(long, value_name = "N", default_value_t = 12)]
    pub poses: usize,
    /// Seed of the poses, the sensor's pattern and the images' noise.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// No random noise (read, shot, banding): the images differ from the
    /// model only by quantisation and the sensor's fixed pattern.
    #[arg(long)]
    pub noiseless: bool,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// Parses `COLSxROWS`.
fn parse_board(s: &str, square_mm: f64) -> Result<Board, String> {
    let bad = || format!("--board {s:?}: expected COLSxROWS inner corners, e.g. 9x6");
    let (c, r) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let cols: usize = c.trim().parse().map_err(|_| bad())?;
    let rows: usize = r.trim().parse().map_err(|_| bad())?;
    if !(2..=1000).contains(&cols) || !(2..=1000).contains(&rows) {
        return Err(format!("--board {s}: needs 2 to 1000 inner corners each way"));
    }
    if !(square_mm.is_finite() && square_mm > 0.0) {
        return Err(format!("--square-mm {square_mm}: must be a positive length"));
    }
    Ok(Board { cols, rows, square_mm })
}

/// Reads an image as grayscale `0..1` (8- or 16-bit, colour converted by luma).
fn load_gray(path: &Path) -> Result<(Vec<f32>, u32, u32), String> {
    let bytes = cms_host::input::read_capped(path, cms_host::input::MAX_INPUT_BYTES).map_err(|e| e.to_string())?;
    let img = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("{}: {e}", path.display()))?
        .decode()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let g = img.to_luma32f();
    let (w, h) = g.dimensions();
    Ok((g.into_raw(), w, h))
}
