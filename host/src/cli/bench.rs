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
//! * `bench recording` — writes a synthetic calibrated recording of any
//!   length (`cms_host::sim::synthetic`), the input of the scale benchmarks of
//!   `analyze` and `export` (docs/benchmarks.md).

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use cms_core::peak::{Detector, Method, Stripes};
use cms_study::montecarlo::{self as mc, CellStats, Levels, SIGMAS, SNRS_DB, Study};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
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
    /// Writes a synthetic calibrated recording (a known rail, no rendering) to time analyze and export at scale.
    Recording(RecordingArgs),
    /// EN 13231-3 Annex A: the simulated head over a reference beam; the band RMS differences against the
    /// limits (1 / 1 / 2 µm) and a commercial trolley's own figures.
    #[command(name = "annex-a")]
    AnnexA(AnnexAArgs),
}

/// Options of `bench annex-a`.
#[derive(Args, Debug, Clone)]
pub struct AnnexAArgs {
    /// Length of beam driven over, m (at least 2.4: the 100–300 mm band's settling).
    #[arg(long = "length-m", default_value_t = 3.0)]
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
    /// The recording to write.
    #[arg(long, value_name = "FILE.cmsrec")]
    pub out: PathBuf,
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
        BenchCmd::Accuracy(a) => accuracy(&a)?,
        BenchCmd::Speed(s) => speed(&s)?,
        BenchCmd::Qemu(q) => cms_host::device::qemu::bench(&q.options())?,
        BenchCmd::Corrugation(c) => corrugation(&c)?,
        BenchCmd::Recording(r) => recording(&r)?,
        BenchCmd::AnnexA(a) => annex_a(&a)?,
    };
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes()).and_then(|()| out.flush()).context("writing the report to stdout")
}

/// `bench corrugation`: the closed-loop table and one frame's plot.
fn corrugation(a: &CorrugationArgs) -> Result<String> {
    use cms_host::sim::closed_loop::{self as cl, PAPER_CASES};
    if !(a.roughness_um >= 0.0 && a.roughness_um.is_finite()) {
        bail!("--roughness-um must be finite and ≥ 0");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    if a.sweep {
        let t = Instant::now();
        let cells = cl::sweep_cells();
        let runs = cl::sweep(&cells, a.runs, a.row_step as usize, threads(a.threads));
        let mut md = format!(
            "Misalignment sweep through the simulated head: paper geometry, 30 dB, the head turned and tilted \
             against the datum it was calibrated with, {} run(s) per cell (golden-ratio phases), every {} image \
             row(s); {:.0} s.\n\n",
            a.runs,
            a.row_step,
            t.elapsed().as_secs_f64()
        );
        md += &cl::sweep_markdown(&runs);
        put(&a.out.join("sweep.md"), &md)?;
        put(&a.out.join("sweep.csv"), &cl::sweep_csv(&runs))?;
        return Ok(md);
    }
    let study = cl::Study {
        runs: a.runs as usize,
        row_step: a.row_step as usize,
        threads: threads(a.threads),
        single: true,
        roughness_um: a.roughness_um,
    };
    let t = Instant::now();
    let stats = cl::study(&PAPER_CASES, &study).map_err(anyhow::Error::msg)?;
    let secs = t.elapsed().as_secs_f64();
    let mut md = format!(
        "Closed loop through the simulated head: paper geometry (Table 4), 30 dB stripes, {} runs per case, every \
         {} image row(s), rail roughness {} µm RMS; errors = measured − true; joint fit of the three lines with \
         the surface-normal correction, and the middle laser's own rotated-sine fit for comparison. {:.0} s on {} \
         thread(s).\n\n",
        study.runs, study.row_step, study.roughness_um, secs, study.threads
    );
    md += &cl::markdown(&stats);
    let path = |f: &str| a.out.join(f);
    put(&path("corrugation.md"), &md)?;
    put(&path("corrugation.csv"), &cl::csv(&stats))?;
    // One measured frame: λ 50 mm, A 50 µm, run 0.
    let cfg = cl::config(PAPER_CASES[0], 0, study.roughness_um);
    let m = cl::measure_frame(&cfg, study.row_step).map_err(anyhow::Error::msg)?;
    cms_host::measure::plot(&path("frame_l50_a50"), &m).map_err(anyhow::Error::msg)?;
    md += &format!("\nPlot of one frame (λ 50 mm, A 50 µm): {} and .svg\n", path("frame_l50_a50.png").display());
    Ok(md)
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
    let o = cms_host::sim::annex_a::measure(&beam).map_err(cms_host::Error::Input)?;
    let mut text = String::from(
        "EN 13231-3 Annex A through the simulated head (limits and CAT's figures as RailMeasurement quotes them)\n\n",
    );
    text.push_str(&cms_host::sim::annex_a::table(&o));
    text.push_str(if o.passes() { "every band within its limit\n" } else { "A LIMIT IS NOT MET\n" });
    Ok(text)
}

fn recording(a: &RecordingArgs) -> Result<String> {
    let opts = cms_host::sim::synthetic::Options {
        frames: a.frames,
        step_mm: a.step_mm,
        seed: a.seed,
        ..cms_host::sim::synthetic::Options::default()
    };
    let t = Instant::now();
    cms_host::sim::synthetic::write(&a.out, &opts, &super::progress::Bar::stderr())?;
    let bytes = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    Ok(format!(
        "{}: {} synthetic calibrated frames, {} points each, {:.1} m of rail, {:.1} MB, written in {:.1} s\n",
        a.out.display(),
        opts.frames,
        3 * opts.points_per_line as u32,
        opts.frames as f64 * opts.step_mm / 1000.0,
        bytes as f64 / 1e6,
        t.elapsed().as_secs_f64()
    ))
}

/// Writes one of the study's files whole ([`cms_host::output`]).
fn put(path: &Path, text: &str) -> Result<()> {
    Ok(cms_host::output::write_atomically(path, |w| w.write_all(text.as_bytes()))?)
}

fn threads(opt: Option<u64>) -> usize {
    opt.map(|t| t as usize).unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

// ---------------------------------------------------------------- accuracy

/// Runs the accuracy study, writes its files into `a.out`, returns the report.
pub fn accuracy(a: &AccuracyArgs) -> Result<String> {
    let mut levels = Levels::for_bits(a.bits);
    levels.amplitude = a.amplitude.unwrap_or(levels.amplitude);
    levels.background = a.background.unwrap_or(levels.background);
    let full = ((1u64 << a.bits) - 1) as f64;
    if !(levels.amplitude > 0.0 && levels.background >= 0.0 && levels.amplitude + levels.background < full) {
        bail!("amplitude {} + background {} must be positive and below {full}", levels.amplitude, levels.background);
    }
    let study = Study { seed: a.seed, trials: a.trials as usize, bits: a.bits, levels, threads: threads(a.threads) };
    let t0 = Instant::now();
    let cells = study.run();
    let (fixed, random) = study.paper_protocol(a.paper_trials as usize);
    let secs = t0.elapsed().as_secs_f64();

    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let csv_path = a.out.join("accuracy.csv");
    put(&csv_path, &mc::csv(&cells))?;
    let pp_path = a.out.join("paper_protocol.csv");
    put(&pp_path, &paper_csv(&fixed, &random))?;
    let svg_path = a.out.join("accuracy.svg");
    plot(&svg_path, &cells, &study).with_context(|| format!("plotting {}", svg_path.display()))?;

    let mut r = String::new();
    report_header(&mut r, &study);
    match a.table {
        TableKind::Pivot => pivot_tables(&mut r, &cells),
        TableKind::Full => full_table(&mut r, &cells),
    }
    paper_section(&mut r, &study, &fixed, &random);
    let md_path = a.out.join("accuracy.md");
    put(&md_path, &r)?;
    let _ = writeln!(
        r,
        "\nWrote {}, {}, {} and {} ({} threads, {secs:.1} s).",
        csv_path.display(),
        svg_path.display(),
        pp_path.display(),
        md_path.display(),
        study.threads
    );
    Ok(r)
}

fn report_header(r: &mut String, s: &Study) {
    let _ = writeln!(r, "# Stripe detector accuracy: Monte-Carlo against the Cramér–Rao bound\n");
    if s.trials < mc::FULL_TRIALS {
        let _ = writeln!(
            r,
            "> **Quick run: {} trials per cell; the full study needs at least {}.**\n",
            s.trials,
            mc::FULL_TRIALS
        );
    }
    let _ = writeln!(
        r,
        "* Rows: {} samples, {}-bit, one Gaussian stripe of amplitude A = {} counts on a background of {} \
         counts; true centre x0 uniform over [{}, {}) px (random sub-pixel offsets).",
        mc::ROW_LEN,
        s.bits,
        s.levels.amplitude,
        s.levels.background,
        mc::STUDY_X0.0,
        mc::STUDY_X0.1
    );
    let _ = writeln!(
        r,
        "* **SNR is measured over the whole {}-sample row**, as MATLAB `awgn(x, snr, 'measured')` on the \
         stripe signal (background excluded) — not peak amplitude over noise; A/σn is given per column.",
        mc::ROW_LEN
    );
    let _ = writeln!(
        r,
        "* CRLB = (σeff/A)·sqrt(2σ/√π) with **σeff = sqrt(σn² + 1/12): quantisation included** as uniform \
         noise of 1/12 LSB²."
    );
    let _ = writeln!(
        r,
        "* Detector: `Config::new({}, scales [max(σ/2, 1), 1.5σ])`, `max_stripes` 1, other settings default.",
        s.bits
    );
    let _ = writeln!(
        r,
        "* {} trials per cell, seed {}; every method sees the same rows. Misses (rows without exactly one \
         stripe) are left out of the statistics and shown as `(n miss)`. The sampling error of an RMS/CRLB \
         figure is about 1/sqrt(2·trials) = {:.0} % (relative).\n",
        s.trials,
        s.seed,
        100.0 / (2.0 * s.trials as f64).sqrt()
    );
}

fn ratio_str(v: f64) -> String {
    if !v.is_finite() {
        "—".into()
    } else if v < 10.0 {
        format!("{v:.2}")
    } else if v < 100.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    }
}

fn cell_of(cells: &[CellStats], m: Method, sigma: f64, snr: f64) -> Option<&CellStats> {
    cells.iter().find(|c| c.method == m && c.sigma == sigma && c.snr_db == snr)
}

fn pivot_tables(r: &mut String, cells: &[CellStats]) {
    let _ = writeln!(r, "## RMS error / CRLB (1.00 = the bound)\n");
    for &sigma in &SIGMAS {
        let (lo, hi) = mc::study_scales(sigma);
        let _ = writeln!(r, "### σ = {sigma} px (scales {lo}–{hi} px)\n");
        let _ = write!(r, "| method |");
        for snr in SNRS_DB {
            let _ = write!(r, " {snr} dB |");
        }
        let _ = write!(r, "\n|---|");
        for _ in SNRS_DB {
            let _ = write!(r, "---:|");
        }
        let any = |f: &dyn Fn(&CellStats) -> String| {
            SNRS_DB
                .iter()
                .map(|&snr| cell_of(cells, Method::Cwt, sigma, snr).map_or("—".into(), f))
                .collect::<Vec<_>>()
                .join(" | ")
        };
        let _ = write!(r, "\n| *A/σn* | {} |", any(&|c| format!("*{:.1}*", c.a_over_noise)));
        let _ = write!(r, "\n| *CRLB, px* | {} |", any(&|c| format!("*{:.5}*", c.crlb)));
        for m in Method::ALL {
            let _ = write!(r, "\n| {} |", m.name());
            for &snr in &SNRS_DB {
                let s = match cell_of(cells, m, sigma, snr) {
                    None => "—".into(),
                    Some(c) if c.misses > 0 => format!("{} ({} miss)", ratio_str(c.ratio()), c.misses),
                    Some(c) => ratio_str(c.ratio()),
                };
                let _ = write!(r, " {s} |");
            }
        }
        let _ = writeln!(r, "\n");
    }
    let _ = writeln!(r, "Bias, std, RMS, max |error|, misses per cell: `accuracy.csv`, or `--table full`.\n");
}

fn full_table(r: &mut String, cells: &[CellStats]) {
    let _ = writeln!(r, "## Every cell (errors in px)\n");
    let _ = writeln!(
        r,
        "| method | σ px | SNR dB | A/σn | CRLB | bias | std | RMS | max \\|e\\| | RMS/CRLB | misses | gross |"
    );
    let _ = writeln!(r, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for c in cells {
        let _ = writeln!(
            r,
            "| {} | {} | {} | {:.1} | {:.5} | {:+.5} | {:.5} | {:.5} | {:.4} | {} | {} | {} |",
            c.method.name(),
            c.sigma,
            c.snr_db,
            c.a_over_noise,
            c.crlb,
            c.bias,
            c.std,
            c.rms,
            c.max_abs,
            ratio_str(c.ratio()),
            c.misses,
            c.gross
        );
    }
    let _ = writeln!(r, "\n`gross`: detections more than one stripe σ from the truth (kept in the statistics).\n");
}

fn paper_section(r: &mut String, s: &Study, fixed: &[CellStats], random: &[CellStats]) {
    let crlb = fixed.first().map_or(f64::NAN, |c| c.crlb);
    let a_sn = fixed.first().map_or(f64::NAN, |c| c.a_over_noise);
    let trials = fixed.first().map_or(0, |c| c.trials);
    let _ = writeln!(r, "## Paper protocol (§6.2, Table 3) and why x0 = 107.5 flatters\n");
    let _ = writeln!(
        r,
        "{} samples, σ = {} px, scales {}–{} px, {} dB measured over the row (A/σn = {a_sn:.1}), {trials} trials, \
         {}-bit levels as above; CRLB {crlb:.5} px. *Published*: x0 = {} exactly, as in the paper. *Random*: x0 \
         uniform over [107, 108). The paper does not say what its ± is; mean |error| and RMS are both given.\n",
        mc::ROW_LEN,
        mc::paper::SIGMA,
        mc::paper::SCALES.0,
        mc::paper::SCALES.1,
        mc::paper::SNR_DB,
        s.bits,
        mc::paper::X0
    );
    let _ = writeln!(
        r,
        "| method | paper's Table 3 | published: mean \\|e\\| | RMS | bias | max \\|e\\| | RMS/CRLB | random: mean \\|e\\| \
         | RMS | bias | max \\|e\\| | RMS/CRLB |"
    );
    let _ = writeln!(r, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (f, x) in fixed.iter().zip(random) {
        let printed = mc::paper::TABLE3
            .iter()
            .find(|t| t.0 == f.method)
            .map_or("—".to_string(), |t| format!("±{} ({})", t.2, t.1));
        let miss = |c: &CellStats| if c.misses > 0 { format!(" ({} miss)", c.misses) } else { String::new() };
        let _ = writeln!(
            r,
            "| {} | {printed} | {:.4}{} | {:.4} | {:+.4} | {:.4} | {} | {:.4}{} | {:.4} | {:+.4} | {:.4} | {} |",
            f.method.name(),
            f.mean_abs,
            miss(f),
            f.rms,
            f.bias,
            f.max_abs,
            ratio_str(f.ratio()),
            x.mean_abs,
            miss(x),
            x.rms,
            x.bias,
            x.max_abs,
            ratio_str(x.ratio())
        );
    }
    let _ = writeln!(r);
}

fn paper_csv(fixed: &[CellStats], random: &[CellStats]) -> String {
    let mut s = format!("placement,{}\n", mc::CSV_HEADER);
    for (name, cells) in [("x0=107.5", fixed), ("x0~U[107,108)", random)] {
        for line in mc::csv(cells).lines().skip(1) {
            let _ = writeln!(s, "{name},{line}");
        }
    }
    s
}

const COLOURS: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

/// RMS/CRLB against SNR, log y, one line per method, one panel per σ.
fn plot(path: &Path, cells: &[CellStats], s: &Study) -> Result<()> {
    let finite = cells.iter().map(|c| c.ratio()).filter(|v| v.is_finite());
    let lo = finite.clone().fold(1.0f64, f64::min) * 0.8;
    let hi = finite.fold(1.0f64, f64::max) * 1.25;
    cms_host::plot::fonts();
    // Drawn into a string, then written whole like every output.
    let mut svg = String::new();
    draw(&mut svg, cells, s, lo, hi)?;
    put(path, &svg)
}

/// [`plot`]'s drawing.
fn draw(svg: &mut String, cells: &[CellStats], s: &Study, lo: f64, hi: f64) -> Result<()> {
    use plotters::prelude::*;
    let root = SVGBackend::with_string(svg, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "RMS error / CRLB, {} trials per point, {}-bit, A = {}; SNR measured over the {}-sample row (MATLAB awgn 'measured')",
        s.trials,
        s.bits,
        s.levels.amplitude,
        mc::ROW_LEN
    );
    let root = root.titled(&title, ("sans-serif", 20))?;
    for (i, (panel, &sigma)) in root.split_evenly((2, 2)).iter().zip(&SIGMAS).enumerate() {
        let (smin, smax) = mc::study_scales(sigma);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("stripe σ = {sigma} px (scales {smin}–{smax})"), ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(8f64..42f64, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_labels(4)
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| if *v >= 10.0 { format!("{v:.0}") } else { format!("{v:.1}") })
            .x_desc("SNR, dB (measured over the row)")
            .y_desc("RMS / CRLB")
            .draw()?;
        chart
            .draw_series(DashedLineSeries::new([(8.0, 1.0), (42.0, 1.0)], 6, 4, BLACK.stroke_width(1)))?
            .label("CRLB")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
        for (k, m) in Method::ALL.into_iter().enumerate() {
            let (r, g, b) = COLOURS[k % COLOURS.len()];
            let colour = RGBColor(r, g, b);
            let width = if m == Method::Cwt { 3 } else { 2 };
            let pts: Vec<(f64, f64)> = SNRS_DB
                .iter()
                .filter_map(|&snr| cell_of(cells, m, sigma, snr))
                .map(|c| (c.snr_db, c.ratio()))
                .filter(|p| p.1.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(width)).point_size(3))?
                .label(m.name())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(width)));
        }
        if i == 0 {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 13))
                .draw()?;
        }
    }
    root.present()?;
    Ok(())
}

// ---------------------------------------------------------------- speed

/// One timed configuration.
struct Timing {
    len: usize,
    stripes: usize,
    method: Method,
    ns: Vec<f64>,
    found_ok: u64,
    found_rows: u64,
}

/// The least disturbed repetition: other load only ever adds time.
fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NAN, f64::min)
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

const SPEED_BITS: u8 = 12;
const SPEED_DISTINCT_ROWS: usize = 64;

/// Times every method on every size; returns the report.
pub fn speed(a: &SpeedArgs) -> Result<String> {
    let methods: Vec<Method> = if a.methods.is_empty() { Method::ALL.to_vec() } else { a.methods.clone() };
    let sizes: Vec<(usize, usize)> = if a.sizes.is_empty() {
        mc::SPEED_LENGTHS.iter().flat_map(|&l| mc::SPEED_STRIPES.iter().map(move |&k| (l, k))).collect()
    } else {
        a.sizes.clone()
    };
    let mut timings = Vec::new();
    for &(len, stripes) in &sizes {
        let rows = mc::speed_rows(len, stripes, SPEED_BITS, SPEED_DISTINCT_ROWS, a.seed);
        let mut dets = methods
            .iter()
            .map(|&m| {
                Detector::<{ mc::SPEED_MAX_LEN }>::new(mc::speed_config(m, SPEED_BITS, stripes))
                    .map(Box::new)
                    .with_context(|| format!("configuring {}", m.name()))
            })
            .collect::<Result<Vec<_>>>()?;
        let mut ts: Vec<Timing> = methods
            .iter()
            .map(|&method| Timing { len, stripes, method, ns: Vec::new(), found_ok: 0, found_rows: 0 })
            .collect();
        let mut out: Stripes<4> = Stripes::new();
        for (det, t) in dets.iter_mut().zip(ts.iter_mut()) {
            for i in 0..a.warmup as usize {
                det.detect(std::hint::black_box(rows[i % rows.len()].as_slice()), &mut out)?;
            }
            for r in &rows {
                det.detect(r.as_slice(), &mut out)?;
                t.found_rows += 1;
                t.found_ok += u64::from(out.len() == stripes);
            }
        }
        // Repetitions outermost, methods interleaved: a clock or thermal drift
        // during the run hits every method alike, so the ratios are fair.
        for _ in 0..a.reps {
            for (det, t) in dets.iter_mut().zip(ts.iter_mut()) {
                let mut acc = 0usize;
                let start = Instant::now();
                for i in 0..a.rows as usize {
                    det.detect(std::hint::black_box(rows[i % rows.len()].as_slice()), &mut out)?;
                    acc += out.len();
                }
                let dt = start.elapsed();
                std::hint::black_box(acc);
                t.ns.push(dt.as_nanos() as f64 / a.rows as f64);
            }
        }
        timings.extend(ts);
    }
    Ok(speed_report(a, &methods, &sizes, &timings))
}

fn speed_report(a: &SpeedArgs, methods: &[Method], sizes: &[(usize, usize)], ts: &[Timing]) -> String {
    let mut r = String::new();
    let _ = writeln!(
        r,
        "# Detection time per row (ns; fastest of {} repetitions of {} rows, methods interleaved)\n",
        a.reps, a.rows
    );
    let _ = writeln!(
        r,
        "{SPEED_BITS}-bit rows, stripes of σ = {} px at {} dB measured over the row, {} distinct rows cycled; \
         detector scales {}–{} px, `max_stripes` = stripes per row. Single thread, `{}` build.\n",
        mc::SPEED_SIGMA,
        mc::SPEED_SNR_DB,
        SPEED_DISTINCT_ROWS,
        mc::study_scales(mc::SPEED_SIGMA).0,
        mc::study_scales(mc::SPEED_SIGMA).1,
        if cfg!(debug_assertions) { "debug (numbers meaningless)" } else { "release" }
    );
    let get = |m: Method, (l, k): (usize, usize)| {
        ts.iter().find(|t| t.method == m && t.len == l && t.stripes == k).map_or(f64::NAN, |t| fastest(&t.ns))
    };
    let _ = write!(r, "| method |");
    for (l, k) in sizes {
        let _ = write!(r, " {l} px × {k} |");
    }
    let _ = write!(r, "\n|---|");
    for _ in sizes {
        let _ = write!(r, "---:|");
    }
    for &m in methods {
        let _ = write!(r, "\n| {} |", m.name());
        for &s in sizes {
            let _ = write!(r, " {:.0} |", get(m, s));
        }
    }
    if methods.contains(&Method::Cwt) && methods.contains(&Method::Cog) {
        let _ = write!(r, "\n| **cwt / cog** |");
        for &s in sizes {
            let _ = write!(r, " **{:.2}** |", get(Method::Cwt, s) / get(Method::Cog, s));
        }
    }
    let _ = writeln!(r, "\n");
    let noisy = ts.iter().filter(|t| t.ns.len() > 1 && median(&t.ns) > 1.1 * fastest(&t.ns)).count();
    if noisy > 0 {
        let _ = writeln!(
            r,
            "Note: in {noisy} of {} configurations the median repetition was more than 10 % slower than the \
             fastest (a busy machine?); `scripts/instructions.sh` counts instructions instead.\n",
            ts.len()
        );
    }
    for t in ts.iter().filter(|t| t.found_ok < t.found_rows) {
        let _ = writeln!(
            r,
            "Note: {} found the wrong number of stripes in {} of {} rows of {} px × {}.",
            t.method.name(),
            t.found_rows - t.found_ok,
            t.found_rows,
            t.len,
            t.stripes
        );
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(out: PathBuf, seed: u64, threads: u64) -> AccuracyArgs {
        AccuracyArgs {
            seed,
            trials: 4,
            out,
            bits: 12,
            amplitude: None,
            background: None,
            paper_trials: 5,
            table: TableKind::Pivot,
            threads: Some(threads),
        }
    }

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("cms-bench-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn accuracy_writes_every_cell_and_repeats_with_the_seed() {
        let (d1, d2) = (scratch("a"), scratch("b"));
        let report = accuracy(&args(d1.clone(), 9, 2)).unwrap();
        accuracy(&args(d2.clone(), 9, 1)).unwrap();
        let c1 = std::fs::read_to_string(d1.join("accuracy.csv")).unwrap();
        let c2 = std::fs::read_to_string(d2.join("accuracy.csv")).unwrap();
        assert_eq!(c1, c2, "same seed, same CSV");
        assert_eq!(
            std::fs::read(d1.join("paper_protocol.csv")).unwrap(),
            std::fs::read(d2.join("paper_protocol.csv")).unwrap()
        );
        let mut lines = c1.lines();
        assert_eq!(lines.next(), Some(mc::CSV_HEADER));
        assert_eq!(lines.count(), 10 * 4 * 4);
        let svg = std::fs::read_to_string(d1.join("accuracy.svg")).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("cwt-paper"));
        assert!(report.contains("measured over the whole 480-sample row"));
        assert!(report.contains("Quick run"));
        assert!(report.contains("| cwt-paper | ±0.0062"));
        let _ = std::fs::remove_dir_all(&d1);
        let _ = std::fs::remove_dir_all(&d2);
    }

    #[test]
    fn speed_reports_the_ratio() {
        let a = SpeedArgs {
            rows: 20,
            reps: 1,
            warmup: 0,
            methods: vec![Method::Cwt, Method::Cog],
            sizes: vec![(640, 1), (1280, 3)],
            seed: 1,
        };
        let r = speed(&a).unwrap();
        assert!(r.contains("| **cwt / cog** |"), "{r}");
        assert!(!r.contains("wrong number"), "{r}");
    }

    #[test]
    fn sizes_and_methods_parse() {
        assert_eq!(parse_size("1280x3"), Ok((1280, 3)));
        assert!(parse_size("2000x1").is_err());
        assert_eq!(parse_method("cog-filtered"), Ok(Method::CogFiltered));
        assert!(parse_method("nope").is_err());
    }
}
