//! `cms-host bench`: how accurate and how fast the detection methods are.
//!
//! * `bench accuracy` — Monte-Carlo study of every method against the
//!   Cramér–Rao bound (docs/reference.md §1), plus the paper's own synthetic protocol
//!   (§6.2, Table 3) beside random sub-pixel offsets. Writes `accuracy.csv`,
//!   `accuracy.svg`, `paper_protocol.csv` and `accuracy.md` (the printed
//!   report). The simulation is `cms_study::montecarlo`, shared with the tests.
//! * `bench speed` — nanoseconds per row of every method on 640-, 752- and
//!   1280-px 12-bit rows with 1 and 3 stripes, and the ratio `cwt` / `cog`
//!   measured in the same run. `cargo bench -p cms-host --bench detect` times
//!   the same rows with criterion.
//! * `bench corrugation` — the closed loop of `cms_host::sim::closed_loop`: the
//!   paper's four corrugation samples through the simulated head, the
//!   wavelength and amplitude errors over runs (`corrugation.md`,
//!   `corrugation.csv`) and one measured frame's plot (`frame_l50_a50.png`,
//!   `.svg`).
//! * `bench speckle` — the speckle budget of the reference head (the
//!   per-point bound against aperture, speed, exposure and angle, beside
//!   what the detector achieves) and the real-light sweep
//!   (`cms_host::sim::real_light`): `speckle.md`, `speckle.csv`.
//! * `bench render` — milliseconds of rendering a frame of the reference
//!   head's scene under a light model (`cms_host::bench::render`).
//! * `bench recording` — writes a synthetic calibrated recording of any
//!   length (`cms_host::sim::synthetic`), the input of the scale benchmarks of
//!   `analyze` and `export` (docs/benchmarks.md); with `--gnss REGISTER.csv`
//!   the simulated GNSS receiver's fixes among its frames (docs/gnss.md).
//! * `bench rails` — measured rails' roughness spectra laid on the simulated
//!   rail, measured as `listen sim` measures by default and judged as
//!   `analyze` judges (`cms_host::bench::rails`): `rails.md`.

use anyhow::{Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use cms_core::peak::Method;
use cms_host::bench::{
    self,
    accuracy::{AccuracyOptions, ReportTable},
    corrugation::CorrugationOptions,
    speckle::SpeckleOptions,
    speed::SpeedOptions,
};
use cms_study::montecarlo as mc;
use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// `cms-host bench …`
#[derive(Subcommand, Debug, Clone)]
pub enum BenchCmd {
    /// Monte-Carlo accuracy of every method against the Cramér–Rao bound
    /// (σ 1.5/2.5/4/10 px × SNR 10–40 dB), and the paper's Table 3 protocol.
    Accuracy(AccuracyArgs),
    /// Nanoseconds per row of every method (640/752/1280 px, 1 and 3 stripes).
    Speed(SpeedArgs),
    /// Instructions per row of every method on the emulated Cortex-M (QEMU -icount).
    Qemu(super::qemu::BenchQemuArgs),
    /// Corrugation through the simulated head (paper geometry, 30 dB): wavelength and amplitude errors of the
    /// paper's four samples over runs; writes corrugation.md, corrugation.csv and a plot of one frame.
    Corrugation(CorrugationArgs),
    /// Real light on the reference head: the speckle budget (bound per point against aperture, speed, exposure and
    /// triangulation angle, beside the detector) and the real-light sweep; writes speckle.md and speckle.csv.
    Speckle(SpeckleArgs),
    /// Milliseconds of rendering a frame of the reference head's scene under a light (as `listen sim` renders it).
    Render(RenderArgs),
    /// Writes a synthetic calibrated recording (a known rail, no rendering) to time analyze and export at scale;
    /// with --gnss, the simulated GNSS receiver's fixes on a track register among its frames.
    Recording(RecordingArgs),
    /// EN 13231-3 Annex A: the simulated head over a reference beam; the band RMS differences against the
    /// limits (1 / 1 / 2 µm) and a commercial trolley's own figures.
    #[command(name = "annex-a")]
    AnnexA(AnnexAArgs),
    /// The noise floor over a smooth rail against aperture, speed, exposure, frame overlap, rows and wavelength:
    /// the floor analyze reports beside what the rail reads, the minimum detectable corrugation; writes floor.md.
    Floor(FloorArgs),
    /// Measured rails' roughness spectra laid on the simulated rail and measured as `listen sim` measures by default
    /// (0.5 m/s, 30 frames/s, its light): per rail the lines' ISO 3095 third octaves 5–250 mm judged, the worst
    /// judged level against the rail's true one, wrong verdicts and EN 13231-3; writes rails.md.
    Rails(RailsArgs),
}

/// Options of `bench rails`.
#[derive(Args, Debug, Clone)]
pub struct RailsArgs {
    /// A rail's roughness spectrum (CSV `wavelength_mm,level_db`, as `listen --sim-roughness-spectrum` reads it;
    /// repeat for several) [default: every docs/examples/rails/*.csv].
    #[arg(long = "spectrum", value_name = "FILE")]
    pub spectra: Vec<PathBuf>,
    /// The light on the rail, as `--sim-light` spells it [default: `listen sim`'s].
    #[arg(long, value_name = "SPEC", value_parser = super::simulate::parse_light)]
    pub light: Option<cms_host::sim::scene::LightModel>,
    /// Seconds of `listen sim` at its 0.5 m/s: the length of rail per spectrum.
    #[arg(long, default_value_t = 30.0, value_parser = seconds)]
    pub seconds: f64,
    /// Length of rail per spectrum, m (1.2 to 100; instead of --seconds).
    #[arg(long = "length-m", conflicts_with = "seconds")]
    pub length_m: Option<f64>,
    /// Seed of the rails' phases, the speckle and the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=256))]
    pub threads: Option<u64>,
    /// Output directory (created if missing).
    #[arg(long, default_value = "out/rails")]
    pub out: PathBuf,
}

fn seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("seconds {s:?}: a positive number")),
    }
}

/// `bench rails`: the spectra read (the examples without --spectrum), then measured.
fn rails(r: &RailsArgs) -> Result<String> {
    use cms_host::sim::scene::RoughnessSpectrum;
    let mut files = r.spectra.clone();
    if files.is_empty() {
        let dir = std::path::Path::new("docs/examples/rails");
        let list = std::fs::read_dir(dir)
            .map_err(|e| super::exit::input(format!("no --spectrum, and {}: {e}", dir.display())))?;
        files = list
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "csv"))
            .collect();
        files.sort();
    }
    let mut rails = Vec::new();
    for f in &files {
        let name = f.file_stem().map_or_else(|| f.display().to_string(), |s| s.to_string_lossy().into_owned());
        rails.push((name, RoughnessSpectrum::load(f)?));
    }
    let light =
        r.light.clone().unwrap_or_else(|| cms_host::sim::head::default_light(cms_host::sim::head::Preset::Reference));
    let length_mm = r.length_m.map_or(r.seconds * cms_host::sim::head::DEFAULT_SPEED_MM_S, |m| m * 1000.0);
    Ok(bench::rails::rails(&bench::rails::RailsOptions {
        rails,
        light,
        length_mm,
        seed: r.seed,
        threads: r.threads.map(|t| t as usize),
        out: r.out.clone(),
    })?)
}

/// Options of `bench floor`.
#[derive(Args, Debug, Clone)]
pub struct FloorArgs {
    /// The reduced sweep: the push-trolley setting alone.
    #[arg(long)]
    pub reduced: bool,
    /// Length of smooth rail per setting, m (1.2 to 100).
    #[arg(long = "length-m", default_value_t = 3.0)]
    pub length_m: f64,
    /// Only the settings whose name holds TEXT (e.g. "405 nm").
    #[arg(long, value_name = "TEXT")]
    pub only: Option<String>,
    /// Measure these heads instead of the sweep (repeat for several): the push-trolley setting (100 µs, 1.5 m/s)
    /// under each light, as `--sim-light` spells it: speckle=F-NUMBER, patterns=K, scheimpflug[=each], exact (many
    /// patterns as speckle fields: the fast rendering's reference), or incoherent (e.g.
    /// `--light speckle=1.4,patterns=100,scheimpflug --light incoherent`); per ISO 3095 third octave 5–250 mm, each
    /// line, the worst and the lines' energy average against the limit.
    #[arg(long = "light", value_name = "SPEC", value_parser = super::simulate::parse_light)]
    pub lights: Vec<cms_host::sim::scene::LightModel>,
    /// With --light: travel between frames, mm [default: 30; 10 at 1.5 m/s is 150 frames/s]: each point of the
    /// rail seen by more frames (the sensor's noise averages, the speckle, tied to the rail, does not).
    #[arg(long = "step-mm", value_parser = step_mm)]
    pub step_mm: Option<f64>,
    /// With --light: each laser's power, mW [default: 50] (the stripe's peak scales with it, to the full well).
    #[arg(long = "power-mw")]
    pub power_mw: Option<f64>,
    /// With --light: the sensor's read noise, electrons [default: 25].
    #[arg(long = "read-noise-e")]
    pub read_noise_e: Option<f64>,
    /// With --light: the lens's focal length, px [default: 1400, 8.4 mm on 6 µm pixels]: a longer lens or finer
    /// pixels put more rows on a millimetre of rail and less rail in a frame (at 2800: 34 mm; set --step-mm under it).
    #[arg(long = "focal-px")]
    pub focal_px: Option<f64>,
    /// With --light: no sensor noise and no ambient light (quantisation alone): what speckle does by itself.
    #[arg(long = "no-sensor-noise")]
    pub no_sensor_noise: bool,
    /// Worker threads [default: all cores].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=256))]
    pub threads: Option<u64>,
    /// Output directory (created if missing).
    #[arg(long, default_value = "out/floor")]
    pub out: PathBuf,
}

/// Options of `bench annex-a`.
#[derive(Args, Debug, Clone)]
pub struct AnnexAArgs {
    /// Length of beam driven over, m (2.4 to 100: the 100–300 mm band's settling, and a real beam's length).
    #[arg(long = "length-m", default_value_t = 3.0, value_parser = beam_length_m)]
    pub length_m: f64,
    /// Travel between frames, mm (a frame sees about 69 mm).
    #[arg(long = "step-mm", default_value_t = 30.0, value_parser = step_mm)]
    pub step_mm: f64,
    /// Every N-th image row.
    #[arg(long = "row-step", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub row_step: u16,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
}

/// Options of `bench recording`.
#[derive(Args, Debug, Clone)]
pub struct RecordingArgs {
    /// Frames to write (10 000 at 17 mm: 170 m of rail).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub frames: u32,
    /// Travel between frames, mm (17: 0.5 m/s at 30 Hz).
    #[arg(long = "step-mm", default_value_t = 17.0, value_parser = step_mm)]
    pub step_mm: f64,
    /// Seed of the noise and the head's bounce.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Points per laser line and frame (2 to the protocol's rows per profile; fewer: a smaller, faster file).
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u16).range(2..=cms_core::protocol::MAX_ROWS_PER_PROFILE as i64))]
    pub points: u16,
    /// The survey the recording says it is of (line, track, date, start
    /// chainage…: `listen --survey`'s TOML), in its header.
    #[arg(long, value_name = "FILE.toml")]
    pub survey: Option<PathBuf>,
    /// A survey's rail instead of corrugation everywhere: broadband
    /// roughness under every limit and a corrugated zone `FROM:TO` m of
    /// track position (`--wavelength-mm`, `--amplitude-um`).
    #[arg(long = "zone-m", value_name = "FROM:TO", value_parser = zone_m)]
    pub zone_m: Option<(f64, f64)>,
    /// The zone's corrugation wavelength, mm (10 to 1000).
    #[arg(long = "wavelength-mm", default_value_t = 50.0, value_parser = wavelength_mm, requires = "zone_m")]
    pub wavelength_mm: f64,
    /// The zone's corrugation amplitude, µm (0 to 1000).
    #[arg(long = "amplitude-um", default_value_t = 20.0, value_parser = amplitude_um, requires = "zone_m")]
    pub amplitude_um: f64,
    /// The recording to write.
    #[arg(long, value_name = "FILE.cmsrec")]
    pub out: PathBuf,
    /// The run's start in its survey block: the chainage of the
    /// odometer's zero (km+m or m; not with --survey).
    #[arg(long = "start-chainage", value_name = "KM+M", conflicts_with = "survey")]
    pub start_chainage: Option<String>,
    /// The survey's date in its survey block, YYYY-MM-DD (not with --survey).
    #[arg(long, value_name = "YYYY-MM-DD", conflicts_with = "survey")]
    pub date: Option<String>,
    /// A simulated GNSS receiver rides along on this track register's
    /// centreline (`listen --gnss sim`'s: RTK fixed, 10 mm a side, 10 Hz
    /// of the head's clock, seeded by --seed), at the chainage of each
    /// frame's odometer from the survey's start chainage (--start-chainage
    /// or --survey's; its `chainage = "down"` drives it the other way).
    /// The whole run must lie on the register (docs/gnss.md).
    #[arg(long, value_name = "REGISTER.csv")]
    pub gnss: Option<PathBuf>,
}

/// A beam shorter than 2.4 m leaves the 100–300 mm band no settled
/// stretch (1.2 m settling at each end); Annex A's beams are a few metres,
/// and 100 m is already an hour of rendering.
fn beam_length_m(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (cms_host::sim::annex_a::MIN_BEAM_MM..=cms_host::sim::annex_a::MAX_BEAM_MM).contains(&(v * 1e3)) => {
            Ok(v)
        }
        _ => Err(format!("`{s}` is not a beam length in m (2.4 to 100)")),
    }
}

fn zone_m(s: &str) -> Result<(f64, f64), String> {
    let bad = || format!("`{s}` is not a zone FROM:TO in m (FROM below TO, within ±1e6)");
    let (a, b) = s.split_once(':').ok_or_else(bad)?;
    let (a, b) = (a.trim().parse::<f64>().map_err(|_| bad())?, b.trim().parse::<f64>().map_err(|_| bad())?);
    if a.is_finite() && b.is_finite() && a < b && a.abs() <= 1e6 && b.abs() <= 1e6 { Ok((a, b)) } else { Err(bad()) }
}

fn wavelength_mm(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (10.0..=1000.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}` is not a wavelength in mm (10 to 1000)")),
    }
}

fn amplitude_um(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1000.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}` is not an amplitude in µm (0 to 1000)")),
    }
}

fn step_mm(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1000.0 => Ok(v),
        _ => Err(format!("`{s}` is not a travel between frames in mm (above 0, at most 1000)")),
    }
}

/// Options of `bench corrugation`.
#[derive(Args, Debug, Clone)]
pub struct CorrugationArgs {
    /// Runs per case (noise seeds 1000.., golden-ratio phases).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub runs: u64,
    /// Use every N-th image row (1: all 3168).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub row_step: u64,
    /// RMS roughness of the rail, µm (0: a machined sample; the simulator's default rail has 2).
    #[arg(long, default_value_t = 0.0)]
    pub roughness_um: f64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    pub threads: Option<u64>,
    /// The misalignment sweep instead (yaw 0–10° and 15° beyond, pitch and roll ±2°, crowns flat/300/200 mm, the four cases;
    /// the head calibrated aligned): writes sweep.md and sweep.csv. `--runs` runs per cell.
    #[arg(long)]
    pub sweep: bool,
    /// Output directory (created if missing).
    #[arg(long, default_value = "out/corrugation")]
    pub out: PathBuf,
}

/// Options of `bench render`.
#[derive(Args, Debug, Clone)]
pub struct RenderArgs {
    /// The light on the rail (as `simulate --light`).
    #[arg(long, value_name = "SPEC", default_value = "speckle=2.8", value_parser = super::simulate::parse_light)]
    pub light: cms_host::sim::scene::LightModel,
    /// Travel speed along the rail, mm/s [default: the reference head's, 2000].
    #[arg(long = "speed-mm-s", value_name = "V", default_value_t = 2000.0, value_parser = super::simulate::speed)]
    pub speed_mm_s: f64,
    /// Frames timed (after one untimed).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub frames: u64,
}

/// Options of `bench speckle`.
#[derive(Args, Debug, Clone)]
pub struct SpeckleArgs {
    /// Runs per light and corrugation (seeds 100.., golden-ratio phases).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub runs: u64,
    /// The reduced sweep: speckle alone and every disturbance together, F/8, at rest and 5 m/s.
    #[arg(long)]
    pub reduced: bool,
    /// Worker threads [default: all cores].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=256))]
    pub threads: Option<u64>,
    /// Output directory (created if missing).
    #[arg(long, default_value = "out/speckle")]
    pub out: PathBuf,
}

/// Options of `bench accuracy`.
#[derive(Args, Debug, Clone)]
pub struct AccuracyArgs {
    /// Master seed; the same seed gives byte-identical CSV files.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Trials per cell (at least 200 for the full study; fewer is a quick look).
    #[arg(long, default_value_t = mc::FULL_TRIALS as u64, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub trials: u64,
    /// Output directory (created if missing).
    #[arg(long, default_value = "out/accuracy")]
    pub out: PathBuf,
    /// Bit depth of the synthetic rows.
    #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u8).range(8..=16))]
    pub bits: u8,
    /// Stripe amplitude, counts [default: 2^(bits−1)].
    #[arg(long)]
    pub amplitude: Option<f64>,
    /// Background, counts [default: 2^(bits−2)].
    #[arg(long)]
    pub background: Option<f64>,
    /// Trials of the paper-protocol comparison (the paper ran 100).
    #[arg(long, default_value_t = mc::paper::TRIALS as u64, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub paper_trials: u64,
    /// Markdown table printed: RMS/CRLB pivots, or every statistic per cell.
    #[arg(long, value_enum, default_value_t = TableKind::Pivot)]
    pub table: TableKind,
    /// Worker threads [default: available cores]; the results do not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=256))]
    pub threads: Option<u64>,
}

/// Which Markdown table `bench accuracy` prints.
#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum TableKind {
    /// RMS/CRLB, methods as rows, SNR as columns, one table per σ.
    Pivot,
    /// One row per method × σ × SNR with bias, std, RMS, max |e|, misses.
    Full,
}

/// Options of `bench speed`.
#[derive(Args, Debug, Clone)]
pub struct SpeedArgs {
    /// Rows timed per method, size and repetition.
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..))]
    pub rows: u64,
    /// Repetitions (methods interleaved); the fastest is reported.
    #[arg(long, default_value_t = 15, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub reps: u64,
    /// Untimed rows per method and size before the repetitions.
    #[arg(long, default_value_t = 200)]
    pub warmup: u64,
    /// Only these methods (repeatable) [default: all].
    #[arg(long = "method", value_parser = parse_method)]
    pub methods: Vec<Method>,
    /// Only these row sizes, LENxSTRIPES (repeatable, e.g. 1280x3) [default: all].
    #[arg(long = "size", value_parser = parse_size)]
    pub sizes: Vec<(usize, usize)>,
    /// Seed of the synthetic rows.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

fn parse_method(s: &str) -> Result<Method, String> {
    Method::from_name(s)
        .ok_or_else(|| format!("unknown method {s:?}; one of {}", Method::ALL.map(|m| m.name()).join(", ")))
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("size {s:?}: expected LENxSTRIPES with LEN 5..=1280 and STRIPES 1..=3, e.g. 1280x3");
    let (l, k) = s.split_once('x').ok_or_else(bad)?;
    let (l, k): (usize, usize) = (l.parse().map_err(|_| bad())?, k.parse().map_err(|_| bad())?);
    if !(5..=mc::SPEED_MAX_LEN).contains(&l) || !(1..=3).contains(&k) {
        return Err(bad());
    }
    Ok((l, k))
}

/// Runs a `bench` subcommand; the report goes to stdout.
pub fn run(cmd: BenchCmd) -> Result<()> {
    let text = match cmd {
        BenchCmd::Accuracy(a) => bench::accuracy::accuracy(&a.options())?,
        BenchCmd::Speed(s) => bench::speed::speed(&s.options())?,
        BenchCmd::Qemu(q) => cms_host::device::qemu::bench(&q.options())?,
        BenchCmd::Corrugation(c) => bench::corrugation::corrugation(&c.options())?,
        BenchCmd::Speckle(s) => bench::speckle::speckle(&SpeckleOptions {
            runs: s.runs,
            reduced: s.reduced,
            threads: s.threads.map(|t| t as usize),
            out: s.out.clone(),
        })?,
        BenchCmd::Render(r) => bench::render::render(&bench::render::RenderOptions {
            light: r.light.clone(),
            speed_mm_s: r.speed_mm_s,
            frames: r.frames,
        })?,
        BenchCmd::Recording(r) => recording(&r)?,
        BenchCmd::AnnexA(a) => annex_a(&a)?,
        BenchCmd::Floor(f) => bench::floor::floor(&bench::floor::FloorOptions {
            reduced: f.reduced,
            only: f.only.clone(),
            lights: f.lights.clone(),
            step_mm: f.step_mm,
            sensor: {
                let r = cms_host::sim::floor::Sensor::reference();
                cms_host::sim::floor::Sensor {
                    power_mw: f.power_mw.unwrap_or(r.power_mw),
                    read_noise_e: f.read_noise_e.unwrap_or(r.read_noise_e),
                    focal_px: f.focal_px.unwrap_or(r.focal_px),
                    noise: !f.no_sensor_noise,
                }
            },
            length_mm: f.length_m * 1000.0,
            threads: f.threads.map(|t| t as usize),
            out: f.out.clone(),
        })?,
        BenchCmd::Rails(r) => rails(&r)?,
    };
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes()).and_then(|()| out.flush()).context("writing the report to stdout")
}

/// `bench recording`: the synthetic recording, and a line saying what it is.
/// `bench annex-a`: the table, and a failure when a limit is not met.
fn annex_a(a: &AnnexAArgs) -> Result<String> {
    let beam = cms_host::sim::annex_a::Beam {
        length_mm: a.length_m * 1000.0,
        step_mm: a.step_mm,
        row_step: a.row_step.into(),
        seed: a.seed,
        ..cms_host::sim::annex_a::Beam::default()
    };
    let o = cms_host::sim::annex_a::measure(&beam).map_err(|e| cms_host::Error::Input(e.to_string()))?;
    let mut text = String::from(
        "EN 13231-3 Annex A through the simulated head (limits and CAT's figures as RailMeasurement quotes them)\n\n",
    );
    text.push_str(&cms_host::sim::annex_a::table(&o));
    text.push_str(if o.passes() { "every band within its limit\n" } else { "A LIMIT IS NOT MET\n" });
    Ok(text)
}

fn recording(a: &RecordingArgs) -> Result<String> {
    use cms_host::recording::survey_info::Survey;
    use cms_host::sim::synthetic::Rail;
    let rail = match a.zone_m {
        Some((from, to)) => Rail::Survey {
            zone_mm: (from * 1000.0, to * 1000.0),
            wavelength_mm: a.wavelength_mm,
            amplitude_um: a.amplitude_um,
        },
        None => Rail::Corrugated,
    };
    let survey = if let Some(path) = &a.survey {
        Some(Survey::load(path)?)
    } else if a.start_chainage.is_some() || a.date.is_some() {
        let s = Survey { start_chainage: a.start_chainage.clone(), date: a.date.clone(), ..Survey::default() };
        // The block is checked as `listen --survey` checks a survey file.
        Some(Survey::parse(&s.to_text()).map_err(|e| cms_host::Error::Input(format!("survey block: {e}")))?)
    } else {
        None
    };
    let opts = cms_host::sim::synthetic::Options {
        frames: a.frames,
        step_mm: a.step_mm,
        seed: a.seed,
        points_per_line: a.points,
        rail,
        survey: survey.as_ref().map(Survey::to_text),
        ..cms_host::sim::synthetic::Options::default()
    };
    let opts = match &a.gnss {
        Some(register) => {
            let gnss = synthetic_gnss(register, survey.as_ref(), &opts, a.seed)?;
            cms_host::sim::synthetic::Options { gnss: Some(gnss), ..opts }
        }
        None => opts,
    };
    let t = Instant::now();
    cms_host::sim::synthetic::write(&a.out, &opts, &super::progress::Bar::stderr())?;
    let bytes = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    let fixes = match &opts.gnss {
        Some(g) => format!(", {} GNSS fixes", fixes_written(opts.frames, g.receiver.rate_hz)),
        None => String::new(),
    };
    Ok(format!(
        "{}: {} synthetic calibrated frames, {} points each{fixes}, {:.1} m of rail, {:.1} MB, written in {:.1} s\n",
        a.out.display(),
        opts.frames,
        3 * opts.points_per_line as u32,
        opts.frames as f64 * opts.step_mm / 1000.0,
        bytes as f64 / 1e6,
        t.elapsed().as_secs_f64()
    ))
}

/// The fixes a synthetic run of `frames` writes at `rate_hz`: one per
/// epoch from the first frame's time to the last's.
fn fixes_written(frames: u32, rate_hz: u32) -> u64 {
    let last_us = u64::from(frames.saturating_sub(1)) * cms_host::sim::synthetic::FRAME_US;
    last_us / (1_000_000 / u64::from(rate_hz.max(1))) + 1
}

/// `bench recording --gnss`: the receiver on `register` from the survey's
/// start chainage, the whole run on the register; UTC from 08:00 of the
/// survey's date (the first of January 2026 without one).
fn synthetic_gnss(
    register: &std::path::Path,
    survey: Option<&cms_host::recording::survey_info::Survey>,
    opts: &cms_host::sim::synthetic::Options,
    seed: u64,
) -> Result<cms_host::sim::synthetic::Gnss> {
    use cms_host::recording::survey_info::{Chainage, Heading};
    let input = |m: String| anyhow::Error::from(cms_host::Error::Input(m));
    let placement = survey.map(|s| s.placement()).transpose().map_err(|e| input(format!("survey: {e}")))?;
    let start_m = placement.and_then(|p| p.start_m).ok_or_else(|| {
        input("--gnss needs the run's start chainage (--start-chainage, or start_chainage in --survey)".into())
    })?;
    let direction = if placement.and_then(|p| p.heading) == Some(Heading::Down) { -1.0 } else { 1.0 };
    let reg = cms_host::gnss::register::Register::load(register).map_err(|e| input(e.to_string()))?;
    let (lo, hi) = opts.odometer_span_mm();
    let (a, b) = (start_m + direction * lo / 1000.0, start_m + direction * hi / 1000.0);
    let (from, to) = (a.min(b), a.max(b));
    let (r0, r1) = reg.span_m();
    if from < r0 || to > r1 {
        return Err(input(format!(
            "--gnss: the run covers {} to {} but {} spans {} to {}",
            Chainage(from),
            Chainage(to),
            register.display(),
            Chainage(r0),
            Chainage(r1)
        )));
    }
    let date = survey
        .map(|s| s.date())
        .transpose()
        .map_err(|e| input(format!("survey: {e}")))?
        .flatten()
        .and_then(|d| chrono::NaiveDate::from_num_days_from_ce_opt(i32::try_from(d.day_number()).ok()?))
        .unwrap_or_else(|| chrono::NaiveDate::from_ymd_opt(2026, 1, 1).unwrap_or_default());
    // `listen --gnss sim`'s receiver (GnssSimOptions::built_in) on this register.
    let receiver = cms_host::sim::gnss::GnssSimOptions {
        register: reg,
        start_chainage_m: start_m,
        direction,
        rate_hz: 10,
        quality: cms_host::gnss::Quality::RtkFixed,
        sigma_m: 0.01,
        seed,
    };
    Ok(cms_host::sim::synthetic::Gnss { receiver, date, utc_ms_of_day: 8 * 3_600_000 })
}

impl AccuracyArgs {
    /// The library's options.
    fn options(&self) -> AccuracyOptions {
        AccuracyOptions {
            seed: self.seed,
            trials: self.trials,
            out: self.out.clone(),
            bits: self.bits,
            amplitude: self.amplitude,
            background: self.background,
            paper_trials: self.paper_trials,
            table: match self.table {
                TableKind::Pivot => ReportTable::Pivot,
                TableKind::Full => ReportTable::Full,
            },
            threads: self.threads.map(|t| t as usize),
        }
    }
}

impl SpeedArgs {
    /// The library's options.
    fn options(&self) -> SpeedOptions {
        SpeedOptions {
            rows: self.rows,
            reps: self.reps,
            warmup: self.warmup,
            methods: self.methods.clone(),
            sizes: self.sizes.clone(),
            seed: self.seed,
        }
    }
}

impl CorrugationArgs {
    /// The library's options.
    fn options(&self) -> CorrugationOptions {
        CorrugationOptions {
            runs: self.runs,
            row_step: self.row_step,
            roughness_um: self.roughness_um,
            sweep: self.sweep,
            threads: self.threads.map(|t| t as usize),
            out: self.out.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_methods_parse() {
        assert_eq!(parse_size("1280x3"), Ok((1280, 3)));
        assert!(parse_size("2000x1").is_err());
        assert_eq!(parse_method("cog-filtered"), Ok(Method::CogFiltered));
        assert!(parse_method("nope").is_err());
    }
}
