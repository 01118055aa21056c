//! Closed loop through the simulated head: a corrugated rail of known
//! wavelength and amplitude, the paper's camera and geometry (Table 4) and
//! 30 dB stripes (`SimConfig::paper`), the head's own detector and
//! triangulation with the head's true calibration, then `measure`'s fits —
//! and the errors against the truth, over runs with different noise seeds
//! and random phases. `cms-host bench corrugation` writes the table; the
//! test `host/tests/it/corrugation_sim.rs` asserts it.
//!
//! The rail is the simulator's default rail (300 mm crown) with one
//! corrugation sinusoid and, by default, no roughness (a machined sample
//! like the paper's CNC ones); `Study::roughness_um` puts the default
//! rail's texture back (2 µm RMS, 5 mm wavelength and up), which the sine
//! model does not know and which the three lines share. Every
//! `row_step`-th image row is used (1: all 3168 rows, 0.088 mm of rail
//! each); one frame covers 279 mm of rail.
//!
//! Cost: rendering and detecting a row of 4752 px takes about 0.4 ms, so a
//! full frame about 1.3 s, plus about 0.3 s of fits.

use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_core::protocol::LASERS;
use serde::Serialize;

use crate::measure::corrugation::joint_fit;
use crate::measure::fit;
use crate::measure::{Measurement, Measurer, Profiles};
use crate::sim::calibration::truth::truth;
use crate::sim::scene::{Corrugation, Scene, SimConfig};

/// One case of the study.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Case {
    /// True wavelength, mm.
    pub wavelength_mm: f64,
    /// True amplitude, µm.
    pub amplitude_um: f64,
}

/// The paper's four samples (Table 5).
pub const PAPER_CASES: [Case; 4] = [
    Case { wavelength_mm: 50.0, amplitude_um: 50.0 },
    Case { wavelength_mm: 50.0, amplitude_um: 100.0 },
    Case { wavelength_mm: 100.0, amplitude_um: 50.0 },
    Case { wavelength_mm: 100.0, amplitude_um: 100.0 },
];

/// One run's errors (measured − true).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunError {
    /// Joint fit: wavelength error, mm.
    pub wavelength_mm: f64,
    /// Joint fit: amplitude error, µm.
    pub amplitude_um: f64,
    /// Middle laser's own rotated fit: wavelength error, mm (if asked).
    pub single_wavelength_mm: Option<f64>,
    /// Middle laser's own rotated fit: amplitude error, µm (if asked).
    pub single_amplitude_um: Option<f64>,
}

/// Mean and standard deviation of the errors of one case.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseStats {
    /// The case.
    pub case: Case,
    /// Runs.
    pub runs: usize,
    /// Joint wavelength error: mean, std (mm).
    pub wavelength_mm: (f64, f64),
    /// Joint amplitude error: mean, std (µm).
    pub amplitude_um: (f64, f64),
    /// Largest |joint wavelength error| (mm) and |amplitude error| (µm).
    pub max_abs: (f64, f64),
    /// Middle laser alone: wavelength error mean, std (mm), if asked.
    pub single_wavelength_mm: Option<(f64, f64)>,
    /// Middle laser alone: amplitude error mean, std (µm), if asked.
    pub single_amplitude_um: Option<(f64, f64)>,
}

/// How the study runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Study {
    /// Runs per case.
    pub runs: usize,
    /// Every `row_step`-th image row.
    pub row_step: usize,
    /// Worker threads.
    pub threads: usize,
    /// Also fit the middle laser alone (for comparison).
    pub single: bool,
    /// RMS roughness of the rail, µm (0: a machined sample like the
    /// paper's CNC ones; the simulator's default rail has 2).
    pub roughness_um: f64,
}

/// The scene of run `run` of `case`: seed and phase from the run index.
pub fn config(case: Case, run: u64, roughness_um: f64) -> SimConfig {
    let mut cfg = SimConfig::paper();
    cfg.rail.roughness_rms_um = roughness_um;
    cfg.seed = 1000 + run;
    // A golden-ratio sequence of phases: spread, reproducible.
    let phase = (run as f64 * 0.618_033_988_749_895).fract() * std::f64::consts::TAU;
    cfg.rail.corrugation =
        vec![Corrugation { wavelength_mm: case.wavelength_mm, amplitude_um: case.amplitude_um, phase_rad: phase }];
    cfg
}

/// Why a closed loop through the simulated head could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ClosedLoopError {
    /// Options that make no closed loop.
    #[error("{0}")]
    Options(String),
    /// The scene refused its configuration.
    #[error(transparent)]
    Scene(#[from] crate::sim::scene::SimError),
    /// The true calibration cannot measure.
    #[error(transparent)]
    Measure(#[from] crate::measure::MeasureError),
    /// The head's optics give no detector scale range.
    #[error("{0}")]
    Optics(String),
    /// The detector refused its configuration or a row.
    #[error(transparent)]
    Detector(#[from] cms_core::peak::Error),
    /// A fit failed.
    #[error(transparent)]
    Fit(#[from] crate::measure::fit::FitError),
    /// Stitching or band-filtering the measured profile failed.
    #[error("{0}")]
    Analysis(String),
    /// A run of a sweep panicked: a defect of what it ran, reported with
    /// its run rather than ending the sweep.
    #[error("a run panicked: {0}")]
    Panicked(String),
}

impl crate::error::Classify for ClosedLoopError {
    fn class(&self) -> crate::Class {
        match self {
            ClosedLoopError::Options(_) => crate::Class::Input,
            _ => crate::Class::Other,
        }
    }
}

/// Renders frame 0 of `cfg` (every `row_step`-th row), detects and
/// triangulates with the true calibration: the measurer and the profiles.
pub fn profiles(cfg: &SimConfig, row_step: usize) -> Result<(Measurer, Profiles), ClosedLoopError> {
    profiles_calibrated_as(cfg, cfg, row_step)
}

/// [`profiles`] of `cfg`'s scene triangulated with the true calibration of
/// `calibrated`'s (the same head in the pose it was calibrated in).
pub fn profiles_calibrated_as(
    cfg: &SimConfig,
    calibrated: &SimConfig,
    row_step: usize,
) -> Result<(Measurer, Profiles), ClosedLoopError> {
    let mut scene = Scene::new(cfg.clone())?;
    let cal = truth(&Scene::new(calibrated.clone())?);
    let m = Measurer::new(&cal)?;
    let mut det = detector(cfg)?;
    let profiles = frame_profiles(&mut scene, 0, &m, &mut det, row_step)?;
    Ok((m, profiles))
}

/// The head's detector for `cfg`'s optics and light (laser light is
/// speckled: the centroid; incoherent light: the CWT), every stripe of a
/// row found, the strongest kept.
pub fn detector(cfg: &SimConfig) -> Result<Box<Detector<{ crate::input::detect::MAX_ROW }>>, ClosedLoopError> {
    let scales = cfg.optics().scale_range().map_err(|e| ClosedLoopError::Optics(e.to_string()))?;
    let mut det_cfg = Config::new(cfg.camera.bits, scales);
    det_cfg.method = cfg.light.method();
    det_cfg.max_stripes = LASERS as u8;
    det_cfg.select = Select::Strongest;
    Ok(Box::new(Detector::<{ crate::input::detect::MAX_ROW }>::new(det_cfg)?))
}

/// Frame `frame` of `scene` (every `row_step`-th row) rendered, detected
/// and triangulated with `m`: each laser's `(along_mm, height_mm)`, rows
/// where all three stripes were found.
pub fn frame_profiles(
    scene: &mut Scene,
    frame: u64,
    m: &Measurer,
    det: &mut Detector<{ crate::input::detect::MAX_ROW }>,
    row_step: usize,
) -> Result<Profiles, ClosedLoopError> {
    let mut row = vec![0u16; scene.width()];
    let mut profiles: Profiles = Default::default();
    for r in (0..scene.height()).step_by(row_step.max(1)) {
        scene.render_row(frame, r, scene.all_lasers_mask(), &mut row);
        let mut s: Stripes<LASERS> = Stripes::new();
        det.detect(&row, &mut s)?;
        if s.len() != LASERS {
            continue;
        }
        s.sort_unstable_by_key(|x| x.position);
        for (k, stripe) in s.iter().enumerate() {
            if let Some(p) = m.triangulator().profile(k, stripe.position, r as u16) {
                profiles[k].push((f64::from(p.along_mm), f64::from(p.height_mm)));
            }
        }
    }
    Ok(profiles)
}

/// Renders, detects, triangulates and measures frame 0 of `cfg` (all fits,
/// as `cms-host measure` does).
pub fn measure_frame(cfg: &SimConfig, row_step: usize) -> Result<Measurement, ClosedLoopError> {
    let (m, p) = profiles(cfg, row_step)?;
    Ok(m.measure("simulated head", &p))
}

/// One run: its errors; the middle laser's own fit only if `single`.
pub fn run(case: Case, run: u64, study: &Study) -> Result<RunError, ClosedLoopError> {
    let (m, p) = profiles(&config(case, run, study.roughness_um), study.row_step)?;
    let (j, _) = joint_fit(&m.lines(&p))?;
    let one = if study.single {
        let (x, z): (Vec<f64>, Vec<f64>) = p[1].iter().copied().unzip();
        let f = fit::fit(&x, &z, &fit::Options::default())?;
        Some((f.wavelength_mm - case.wavelength_mm, f.amplitude_mm * 1e3 - case.amplitude_um))
    } else {
        None
    };
    Ok(RunError {
        wavelength_mm: j.wavelength_mm - case.wavelength_mm,
        amplitude_um: j.amplitude_mm * 1e3 - case.amplitude_um,
        single_wavelength_mm: one.map(|o| o.0),
        single_amplitude_um: one.map(|o| o.1),
    })
}

fn mean_std(v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = v.clone().count() as f64;
    let m = v.clone().sum::<f64>() / n;
    let var = v.map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, var.sqrt())
}

/// Runs `runs` runs of each case on `threads` threads (`single`: also
/// the middle laser's own fit, for comparison).
pub fn study(cases: &[Case], study: &Study) -> Result<Vec<CaseStats>, ClosedLoopError> {
    let (runs, single) = (study.runs, study.single);
    let jobs: Vec<(usize, u64)> = (0..cases.len()).flat_map(|c| (0..runs as u64).map(move |r| (c, r))).collect();
    let results = in_parallel(jobs.len(), study.threads, |i| {
        let (c, r) = jobs[i];
        run(cases[c], r, study).map(|e| (c, e))
    });
    let mut per: Vec<Vec<RunError>> = vec![Vec::new(); cases.len()];
    for r in results {
        let (c, e) = r?;
        per[c].push(e);
    }
    Ok(cases
        .iter()
        .zip(per)
        .map(|(&case, e)| CaseStats {
            case,
            runs: e.len(),
            wavelength_mm: mean_std(e.iter().map(|e| e.wavelength_mm)),
            amplitude_um: mean_std(e.iter().map(|e| e.amplitude_um)),
            max_abs: (
                e.iter().fold(0.0f64, |m, e| m.max(e.wavelength_mm.abs())),
                e.iter().fold(0.0f64, |m, e| m.max(e.amplitude_um.abs())),
            ),
            single_wavelength_mm: single.then(|| mean_std(e.iter().filter_map(|e| e.single_wavelength_mm))),
            single_amplitude_um: single.then(|| mean_std(e.iter().filter_map(|e| e.single_amplitude_um))),
        })
        .collect())
}

/// The table as Markdown.
pub fn markdown(stats: &[CaseStats]) -> String {
    let mut s = String::from(
        "| λ (mm) | A (µm) | runs | λ error mean ± std (mm) | max \\|λ err\\| (mm) | A error mean ± std (µm) | \
         max \\|A err\\| (µm) | one line: λ err (mm) | one line: A err (µm) |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for c in stats {
        s += &format!(
            "| {} | {} | {} | {:+.4} ± {:.4} | {:.4} | {:+.3} ± {:.3} | {:.3} | {} | {} |\n",
            c.case.wavelength_mm,
            c.case.amplitude_um,
            c.runs,
            c.wavelength_mm.0,
            c.wavelength_mm.1,
            c.max_abs.0,
            c.amplitude_um.0,
            c.amplitude_um.1,
            c.max_abs.1,
            pair(c.single_wavelength_mm, 4),
            pair(c.single_amplitude_um, 3),
        );
    }
    s
}

fn pair(v: Option<(f64, f64)>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |(m, s)| format!("{m:+.digits$} ± {s:.digits$}"))
}

fn csv_pair(v: Option<(f64, f64)>) -> String {
    v.map_or_else(|| ",".into(), |(m, s)| format!("{m:.6},{s:.6}"))
}

/// The table as CSV.
pub fn csv(stats: &[CaseStats]) -> String {
    let mut s = String::from(
        "wavelength_mm,amplitude_um,runs,wl_err_mean_mm,wl_err_std_mm,wl_err_max_mm,amp_err_mean_um,amp_err_std_um,\
         amp_err_max_um,single_wl_err_mean_mm,single_wl_err_std_mm,single_amp_err_mean_um,single_amp_err_std_um\n",
    );
    for c in stats {
        s += &format!(
            "{},{},{},{:.6},{:.6},{:.6},{:.5},{:.5},{:.5},{},{}\n",
            c.case.wavelength_mm,
            c.case.amplitude_um,
            c.runs,
            c.wavelength_mm.0,
            c.wavelength_mm.1,
            c.max_abs.0,
            c.amplitude_um.0,
            c.amplitude_um.1,
            c.max_abs.1,
            csv_pair(c.single_wavelength_mm),
            csv_pair(c.single_amplitude_um),
        );
    }
    s
}

// ------------------------------------------------------------ the sweep

/// A head turned and tilted against the datum it was calibrated with,
/// degrees (the simulator's `HeadGeometry` angles).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Misalignment {
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
}

/// One cell of the misalignment sweep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Cell {
    pub pose: Misalignment,
    /// Crown radius, mm (`None`: flat across).
    pub crown_mm: Option<f64>,
    pub case: Case,
}

/// The accuracy limits of a joint result: wavelength (mm), amplitude (µm).
pub const LIMITS: (f64, f64) = (0.05, 2.0);

/// The largest yaw of the operating envelope, degrees: cells beyond it
/// (15°) must be right or flagged, not within the limits.
pub const ENVELOPE_YAW_DEG: f64 = 10.0;

/// The full sweep: yaw {0, 2, 5, 10}° and 15° beyond the
/// envelope, pitch and roll {0, ±2}°, crown {flat, 300, 200} mm, λ {50,
/// 100} mm × A {50, 100} µm: 540 cells.
pub fn sweep_cells() -> Vec<Cell> {
    let mut cells = Vec::new();
    for yaw_deg in [0.0, 2.0, 5.0, 10.0, 15.0] {
        for pitch_deg in [0.0, 2.0, -2.0] {
            for roll_deg in [0.0, 2.0, -2.0] {
                for crown_mm in [None, Some(300.0), Some(200.0)] {
                    for case in PAPER_CASES {
                        cells.push(Cell { pose: Misalignment { yaw_deg, pitch_deg, roll_deg }, crown_mm, case });
                    }
                }
            }
        }
    }
    cells
}

/// One run of a cell: the joint result against the truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepRun {
    pub cell: Cell,
    pub run: u64,
    /// Wavelength error (mm), amplitude error (µm); `None`: no result.
    pub error: Option<(f64, f64)>,
    /// Reported one-σ of the wavelength (mm) and amplitude (µm).
    pub sigma: (Option<f64>, Option<f64>),
    /// The verdict's level, or failed when there is no result.
    pub level: crate::measure::verdict::Level,
    /// The verdict (or why there is no result).
    pub verdict: String,
    /// Each line's own fit on its corrected profile: wavelength error (mm),
    /// its σ, amplitude error (µm), its σ.
    pub lines: Vec<(f64, Option<f64>, f64, Option<f64>)>,
}

impl SweepRun {
    /// Whether the result is within [`LIMITS`] × `k`.
    pub fn within(&self, k: f64) -> bool {
        self.error.is_some_and(|(l, a)| l.abs() <= k * LIMITS.0 && a.abs() <= k * LIMITS.1)
    }
    /// Whether the 95 % intervals (±1.96 σ) of the wavelength and of the
    /// amplitude hold the truth (`None` without a result or an uncertainty).
    pub fn covered(&self) -> (Option<bool>, Option<bool>) {
        let Some((l, a)) = self.error else { return (None, None) };
        (self.sigma.0.map(|s| l.abs() <= 1.96 * s), self.sigma.1.map(|s| a.abs() <= 1.96 * s))
    }
    /// Whether the cell is within the operating envelope (yaw up to
    /// [`ENVELOPE_YAW_DEG`]).
    pub fn in_envelope(&self) -> bool {
        self.cell.pose.yaw_deg.abs() <= ENVELOPE_YAW_DEG
    }
}

/// Renders run `run` of `cell` (the head posed, calibrated aligned; phase
/// and noise seed from the run), detects, triangulates and fits jointly.
pub fn sweep_run(cell: Cell, run: u64, row_step: usize) -> SweepRun {
    let mut cfg = config(cell.case, run, 0.0);
    cfg.rail.crown_radius_mm = cell.crown_mm;
    let calibrated = cfg.clone();
    cfg.head.yaw_deg = cell.pose.yaw_deg;
    cfg.head.pitch_deg = cell.pose.pitch_deg;
    cfg.head.roll_deg = cell.pose.roll_deg;
    let fitted = profiles_calibrated_as(&cfg, &calibrated, row_step).and_then(|(m, p)| Ok(joint_fit(&m.lines(&p))?));
    match fitted {
        Ok((j, _)) => SweepRun {
            cell,
            run,
            error: Some((j.wavelength_mm - cell.case.wavelength_mm, j.amplitude_mm * 1e3 - cell.case.amplitude_um)),
            sigma: (j.wavelength_sigma_mm, j.amplitude_sigma_mm.map(|s| s * 1e3)),
            level: j.verdict.level,
            verdict: j.verdict.to_string(),
            lines: j
                .per_line
                .iter()
                .map(|l| {
                    (
                        l.wavelength_mm - cell.case.wavelength_mm,
                        l.wavelength_sigma_mm,
                        l.amplitude_mm * 1e3 - cell.case.amplitude_um,
                        l.amplitude_sigma_mm.map(|s| s * 1e3),
                    )
                })
                .collect(),
        },
        Err(e) => SweepRun {
            cell,
            run,
            error: None,
            sigma: (None, None),
            level: crate::measure::verdict::Level::Failed,
            verdict: format!("no result: {e}"),
            lines: Vec::new(),
        },
    }
}

/// Every cell × `runs` runs on `threads` threads, in cell order.
pub fn sweep(cells: &[Cell], runs: u64, row_step: usize, threads: usize) -> Vec<SweepRun> {
    let jobs: Vec<(usize, u64)> = (0..cells.len()).flat_map(|c| (0..runs).map(move |r| (c, r))).collect();
    in_parallel(jobs.len(), threads, |i| sweep_run(cells[jobs[i].0], jobs[i].1, row_step))
}

/// `f(0..jobs)` on `threads` threads, each taking the next job as it is
/// free; the results in job order.
fn in_parallel<T: Send>(jobs: usize, threads: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<(usize, T)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads.max(1))
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if i >= jobs {
                            break;
                        }
                        out.push((i, f(i)));
                    }
                    out
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().unwrap_or_default()).collect()
    });
    out.sort_by_key(|r| r.0);
    out.into_iter().map(|r| r.1).collect()
}

/// What the sweep shows against its criteria: within, coverage
/// and flags over the envelope's runs (yaw to [`ENVELOPE_YAW_DEG`]), good
/// but wrong over all of them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SweepSummary {
    /// Runs in the envelope.
    pub runs: usize,
    /// Runs beyond it (15° of yaw).
    pub beyond: usize,
    /// Runs within [`LIMITS`].
    pub within: usize,
    /// Runs marked good.
    pub good: usize,
    /// Runs marked good but beyond 3 × [`LIMITS`] (must be 0), in and
    /// beyond the envelope.
    pub good_but_wrong: usize,
    /// Runs beyond [`LIMITS`] and not marked good (flagged).
    pub flagged: usize,
    /// Runs with an uncertainty of the wavelength, and those whose 95 %
    /// interval holds the truth; the same for the amplitude.
    pub with_sigma: (usize, usize),
    pub covered: (usize, usize),
    /// The same for the lines' own fits: (with σ, covered) of the
    /// wavelength, then of the amplitude.
    pub line_coverage: ((usize, usize), (usize, usize)),
}

/// The summary of `runs`.
pub fn summarize(runs: &[SweepRun]) -> SweepSummary {
    use crate::measure::verdict::Level;
    let all = runs;
    let runs: Vec<&SweepRun> = all.iter().filter(|r| r.in_envelope()).collect();
    let lines = || runs.iter().flat_map(|r| r.lines.iter());
    let cover = |e: f64, s: Option<f64>| s.map(|s| e.abs() <= 1.96 * s);
    SweepSummary {
        runs: runs.len(),
        beyond: all.len() - runs.len(),
        within: runs.iter().filter(|r| r.within(1.0)).count(),
        good: runs.iter().filter(|r| r.level == Level::Good).count(),
        good_but_wrong: all.iter().filter(|r| r.level == Level::Good && !r.within(3.0)).count(),
        flagged: runs.iter().filter(|r| !r.within(1.0) && r.level != Level::Good).count(),
        with_sigma: (
            runs.iter().filter(|r| r.covered().0.is_some()).count(),
            runs.iter().filter(|r| r.covered().1.is_some()).count(),
        ),
        covered: (
            runs.iter().filter(|r| r.covered().0 == Some(true)).count(),
            runs.iter().filter(|r| r.covered().1 == Some(true)).count(),
        ),
        line_coverage: (
            (lines().filter(|l| l.1.is_some()).count(), lines().filter(|l| cover(l.0, l.1) == Some(true)).count()),
            (lines().filter(|l| l.3.is_some()).count(), lines().filter(|l| cover(l.2, l.3) == Some(true)).count()),
        ),
    }
}

/// The sweep as Markdown: the summary, then one row per cell (worst run).
pub fn sweep_markdown(runs: &[SweepRun]) -> String {
    let s = summarize(runs);
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    let ((lw, lc), (aw, ac)) = s.line_coverage;
    let mut md = format!(
        "{} runs in the envelope (yaw to {}°): {} within {} mm and {} µm; {} good; {} beyond the limits and \
         flagged; the 95 % intervals hold the truth in {} of {} runs ({:.1} %) for the wavelength, {} of {} \
         ({:.1} %) for the amplitude; the lines' own fits in {lc} of {lw} ({:.1} %) and {ac} of {aw} ({:.1} %). \
         {} runs beyond it (15°). In all: {} good but beyond 3× the limits.\n\n",
        s.runs,
        ENVELOPE_YAW_DEG,
        s.within,
        LIMITS.0,
        LIMITS.1,
        s.good,
        s.flagged,
        s.covered.0,
        s.with_sigma.0,
        pct(s.covered.0, s.with_sigma.0),
        s.covered.1,
        s.with_sigma.1,
        pct(s.covered.1, s.with_sigma.1),
        pct(lc, lw),
        pct(ac, aw),
        s.beyond,
        s.good_but_wrong,
    );
    md += "| yaw ° | pitch ° | roll ° | crown mm | λ mm | A µm | runs | max \\|λ err\\| mm | max \\|A err\\| µm | good | worst verdict |\n";
    md += "|---|---|---|---|---|---|---|---|---|---|---|\n";
    for group in runs.chunk_by(|a, b| a.cell == b.cell) {
        let c = group[0].cell;
        let max = |f: fn(&(f64, f64)) -> f64| {
            group.iter().map(|r| r.error.as_ref().map_or(f64::INFINITY, f)).fold(0.0, f64::max)
        };
        let worst = group.iter().max_by_key(|r| r.level).map_or("", |r| r.verdict.as_str());
        md += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.4} | {:.3} | {} | {} |\n",
            c.pose.yaw_deg,
            c.pose.pitch_deg,
            c.pose.roll_deg,
            c.crown_mm.map_or("flat".into(), |r| r.to_string()),
            c.case.wavelength_mm,
            c.case.amplitude_um,
            group.len(),
            max(|e| e.0.abs()),
            max(|e| e.1.abs()),
            group.iter().filter(|r| r.level == crate::measure::verdict::Level::Good).count(),
            worst.replace('|', "/"),
        );
    }
    md
}

/// The sweep as CSV, one line per run.
pub fn sweep_csv(runs: &[SweepRun]) -> String {
    let mut s = String::from(
        "yaw_deg,pitch_deg,roll_deg,crown_mm,wavelength_mm,amplitude_um,run,wl_err_mm,amp_err_um,wl_sigma_mm,amp_sigma_um,level\n",
    );
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    for r in runs {
        let c = r.cell;
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{}\n",
            c.pose.yaw_deg,
            c.pose.pitch_deg,
            c.pose.roll_deg,
            c.crown_mm.map_or(String::new(), |v| v.to_string()),
            c.case.wavelength_mm,
            c.case.amplitude_um,
            r.run,
            opt(r.error.map(|e| e.0)),
            opt(r.error.map(|e| e.1)),
            opt(r.sigma.0),
            opt(r.sigma.1),
            r.level,
        );
    }
    s
}
