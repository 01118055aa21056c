//! The real-light sweep: the reference head through each disturbance of
//! [`LightModel`] alone and all together, at rest and moving, at F/4 and
//! F/8, over corrugations of several wavelengths and amplitudes. Per run:
//! each point's error against the true stripe centre beside a ±3σ centroid
//! placed on the true centre of the same row (what the light allows a
//! row-by-row estimator), the rows kept, and `measure`'s joint result
//! against the truth with its σ and verdict. `cms-host bench speckle`
//! writes the table; `host/tests/it/real_light.rs` runs a reduced sweep.

use cms_core::fixed::Px;
use cms_core::peak::Stripes;
use cms_core::pipeline::assign;
use cms_core::pipeline::line::{Counts, LineCheck, Rules, Seconds};
use cms_core::protocol::{LASERS, LaserPoints};
use serde::Serialize;

use crate::measure::corrugation::joint_fit;
use crate::measure::verdict::Level;
use crate::measure::{Measurer, Profiles};
use crate::sim::calibration::truth::truth;
use crate::sim::closed_loop::{Case, ClosedLoopError, detector};
use crate::sim::scene::{Corrugation, LightModel, Scene, SimConfig};

/// Per-point scatter of one estimator.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Scatter {
    /// Points within 3σ of the true centre.
    pub points: usize,
    /// Points farther than that (another line, a ghost, a glint).
    pub wrong: usize,
    /// RMS error of the points, px.
    pub rms_px: f64,
    /// Robust σ of the errors (1.4826 × their median absolute deviation), px.
    pub robust_px: f64,
}

impl Scatter {
    /// The scatter of `errors` (px), with `wrong` points counted apart.
    pub fn of(errors: &mut [f64], wrong: usize) -> Scatter {
        let n = errors.len();
        if n == 0 {
            return Scatter { wrong, ..Scatter::default() };
        }
        let rms_px = (errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
        errors.sort_by(f64::total_cmp);
        let med = errors[n / 2];
        let mut dev: Vec<f64> = errors.iter().map(|e| (e - med).abs()).collect();
        dev.sort_by(f64::total_cmp);
        Scatter { points: n, wrong, rms_px, robust_px: 1.4826 * dev[n / 2] }
    }
}

/// The ±3σ centroid of a row about column `c` over the background `background`.
pub fn centroid_at(row: &[u16], c: f64, sigma: f64, background: f64) -> Option<f64> {
    let lo = (c - 3.0 * sigma).round().max(0.0) as usize;
    let hi = ((c + 3.0 * sigma).round().max(0.0) as usize).min(row.len().checked_sub(1)?);
    let (mut s, mut sx) = (0.0, 0.0);
    for (i, &v) in row.iter().enumerate().take(hi + 1).skip(lo) {
        let w = f64::from(v) - background;
        s += w;
        sx += w * i as f64;
    }
    (s > 0.0).then(|| sx / s)
}

/// One light of the sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct LightCase {
    /// What is on the rail: "speckle", "oxidation", …, "all".
    pub disturbance: &'static str,
    /// The lens's F-number.
    pub f_number: f64,
    /// Head speed, mm/s.
    pub speed_mm_s: f64,
    /// The light model.
    pub light: LightModel,
}

/// Each disturbance on top of speckle, and all of them together.
pub fn disturbances(f_number: f64) -> Vec<(&'static str, LightModel)> {
    let sp = LightModel::speckle(f_number);
    let all = LightModel {
        oxidation: LightModel::oxidation(),
        grease: LightModel::grease(),
        band: Some(LightModel::running_band()),
        glints: LightModel::glints(),
        ghosts: vec![LightModel::ghost()],
        ..sp.clone()
    };
    vec![
        ("speckle", sp.clone()),
        ("oxidation", LightModel { oxidation: LightModel::oxidation(), ..sp.clone() }),
        (
            "grease, band",
            LightModel { grease: LightModel::grease(), band: Some(LightModel::running_band()), ..sp.clone() },
        ),
        ("glints", LightModel { glints: LightModel::glints(), ..sp.clone() }),
        ("ghost", LightModel { ghosts: vec![LightModel::ghost()], ..sp.clone() }),
        ("all", all),
    ]
}

/// The sweep's lights: every disturbance × {rest, 5 m/s} × {F/4, F/8};
/// reduced: speckle alone and everything together, at F/8, at rest and
/// at 5 m/s.
pub fn light_cases(reduced: bool) -> Vec<LightCase> {
    let mut out = Vec::new();
    for f_number in if reduced { vec![8.0] } else { vec![4.0, 8.0] } {
        for (disturbance, light) in disturbances(f_number) {
            if reduced && !matches!(disturbance, "speckle" | "all") {
                continue;
            }
            for speed_mm_s in [0.0, 5000.0] {
                out.push(LightCase { disturbance, f_number, speed_mm_s, light: light.clone() });
            }
        }
    }
    out
}

/// The corrugations of the sweep: 12 mm / 30 µm (near the shortest
/// wavelength judged), 30 mm / 50 µm, 50 mm / 80 µm (under one and a half
/// periods in a reference frame of 68.6 mm).
pub const CORRUGATIONS: [Case; 3] = [
    Case { wavelength_mm: 12.0, amplitude_um: 30.0 },
    Case { wavelength_mm: 30.0, amplitude_um: 50.0 },
    Case { wavelength_mm: 50.0, amplitude_um: 80.0 },
];

/// One run: the points, and the joint result against the truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LightRun {
    /// Index into the sweep's lights.
    pub light: usize,
    /// The corrugation.
    pub case: Case,
    /// Run (seed and phase).
    pub run: u64,
    /// The head's points against the truth.
    pub detector: Scatter,
    /// The ±3σ centroid on the true centre.
    pub oracle: Scatter,
    /// Fewest rows of a line that gave a point, as a fraction of the rows the line crosses.
    pub rows_kept: f64,
    /// What the head's line pass flagged in the frame.
    pub line: Counts,
    /// Wavelength (mm) and amplitude (µm) errors; `None`: no result.
    pub error: Option<(f64, f64)>,
    /// Their reported one-σ.
    pub sigma: (Option<f64>, Option<f64>),
    /// The verdict's level (failed without a result).
    pub level: Level,
    /// The verdict, or why there is no result.
    pub verdict: String,
}

impl LightRun {
    /// Whether the 95 % intervals hold the truth (λ, A).
    pub fn covered(&self) -> (Option<bool>, Option<bool>) {
        let Some((l, a)) = self.error else { return (None, None) };
        (self.sigma.0.map(|s| l.abs() <= 1.96 * s), self.sigma.1.map(|s| a.abs() <= 1.96 * s))
    }

    /// The larger of the errors in units of their σ (`None`: no result or no σ).
    pub fn worst_sigmas(&self) -> Option<f64> {
        let (l, a) = self.error?;
        Some((l.abs() / self.sigma.0?).max(a.abs() / self.sigma.1?))
    }
}

/// The scene of a run: the reference head, the light, one corrugation,
/// no roughness; seed and golden-ratio phase from the run.
pub fn config(light: &LightCase, case: Case, run: u64) -> SimConfig {
    let mut cfg = SimConfig {
        light: light.light.clone(),
        speed_mm_s: light.speed_mm_s,
        seed: 100 + run,
        ..SimConfig::reference()
    };
    cfg.rail.roughness_rms_um = 0.0;
    let phase = (run as f64 * 0.618_033_988_749_895).fract() * std::f64::consts::TAU;
    cfg.rail.corrugation =
        vec![Corrugation { wavelength_mm: case.wavelength_mm, amplitude_um: case.amplitude_um, phase_rad: phase }];
    if let Some(s) = cfg.light.speckle.as_mut() {
        s.f_number = light.f_number;
    }
    cfg
}

/// What one frame's rows give: the detector's and the oracle's scatter,
/// the fewest rows kept of a line, and the profiles triangulated with the
/// true calibration.
pub struct FramePoints {
    /// The head's points against the truth.
    pub detector: Scatter,
    /// The ±3σ centroid on the true centre.
    pub oracle: Scatter,
    /// Fewest rows of a line that gave a point, as a fraction of the rows the line crosses.
    pub rows_kept: f64,
    /// What the head's line pass flagged.
    pub line: Counts,
    /// The measurer of the head's true calibration.
    pub measurer: Measurer,
    /// Each laser's profile.
    pub profiles: Profiles,
}

/// Renders frame `frame` of `cfg` and measures every point against its
/// truth and the oracle, with the detector the light calls for. The points
/// are the head's: its detector row by row, its assignment to the lasers
/// ([`assign`]) and its line pass ([`LineCheck`], with the true
/// calibration's bands); a point the pass rejects is no point, one farther
/// than 3σ from its laser's true centre is a wrong one.
pub fn frame_points(cfg: &SimConfig, frame: u64) -> Result<FramePoints, ClosedLoopError> {
    let mut scene = Scene::new(cfg.clone())?;
    let file = truth(&scene);
    let m = Measurer::new(&file)?;
    let mut det = detector(cfg)?;
    let rules = Rules::new(det.config(), Some(&file.to_head().map_err(crate::measure::MeasureError::from)?));
    let w = scene.width();
    let mut row = vec![0u16; w];
    let mut sorted = vec![0u16; w];
    let (mut de, mut oe, mut dw, mut ow) = (Vec::new(), Vec::new(), 0, 0);
    let (mut crossed, mut kept) = ([0usize; LASERS], [0usize; LASERS]);
    let mut lasers: heapless::Vec<LaserPoints, LASERS> =
        (0..LASERS as u8).map(|laser| LaserPoints { laser, points: heapless::Vec::new() }).collect();
    let (mut track, mut seconds) = ([Px::ZERO; LASERS], Seconds::new());
    // Each row's true stripes: (centre, σ) px.
    let mut truths = Vec::with_capacity(scene.height());
    det.refresh_noise();
    for r in 0..scene.height() {
        let truth = scene.render_row(frame, r, scene.all_lasers_mask(), &mut row);
        let mut s: Stripes<LASERS> = Stripes::new();
        det.detect(&row, &mut s)?;
        sorted.copy_from_slice(&row);
        sorted.sort_unstable();
        let background = f64::from(sorted[w / 2]);
        let mut t_row = [None; LASERS];
        for (laser, t) in truth.stripes.iter().enumerate().take(LASERS) {
            let Some(t) = t else { continue };
            crossed[laser] += 1;
            t_row[laser] = Some((t.column_px, t.sigma_px));
            match centroid_at(&row, t.column_px, t.sigma_px, background) {
                Some(c) if (c - t.column_px).abs() <= 3.0 * t.sigma_px => oe.push(c - t.column_px),
                Some(_) => ow += 1,
                None => {}
            }
        }
        truths.push(t_row);
        assign(&s, LASERS, &mut track, &mut lasers, r as u16, &mut seconds);
    }
    let line = LineCheck::default().check(&rules, &mut lasers, &seconds);
    let mut profiles: Profiles = Default::default();
    for lp in &lasers {
        let k = usize::from(lp.laser);
        for p in lp.points.iter().filter(|p| !p.flags.rejected()) {
            match truths[usize::from(p.row)][k] {
                Some((c, sigma)) if (p.position.to_f64() - c).abs() <= 3.0 * sigma => {
                    de.push(p.position.to_f64() - c);
                    kept[k] += 1;
                }
                _ => dw += 1,
            }
            if let Some(q) = m.triangulator().profile(k, p.position, p.row) {
                profiles[k].push((f64::from(q.along_mm), f64::from(q.height_mm)));
            }
        }
    }
    Ok(FramePoints {
        detector: Scatter::of(&mut de, dw),
        oracle: Scatter::of(&mut oe, ow),
        rows_kept: (0..LASERS).map(|k| kept[k] as f64 / crossed[k].max(1) as f64).fold(1.0, f64::min),
        line,
        measurer: m,
        profiles,
    })
}

/// Renders frame 0 of a run, measures its points and fits jointly.
pub fn run(lights: &[LightCase], light: usize, case: Case, run: u64) -> Result<LightRun, ClosedLoopError> {
    let f = frame_points(&config(&lights[light], case, run), 0)?;
    let (error, sigma, level, verdict) = match joint_fit(&f.measurer.lines(&f.profiles)) {
        Ok((j, _)) => (
            Some((j.wavelength_mm - case.wavelength_mm, j.amplitude_mm * 1e3 - case.amplitude_um)),
            (j.wavelength_sigma_mm, j.amplitude_sigma_mm.map(|s| s * 1e3)),
            j.verdict.level,
            j.verdict.to_string(),
        ),
        Err(e) => (None, (None, None), Level::Failed, format!("no result: {e}")),
    };
    Ok(LightRun {
        light,
        case,
        run,
        detector: f.detector,
        oracle: f.oracle,
        rows_kept: f.rows_kept,
        line: f.line,
        error,
        sigma,
        level,
        verdict,
    })
}

/// Every light × corrugation × `runs` runs, on `threads` threads.
pub fn sweep(lights: &[LightCase], runs: u64, threads: usize) -> Vec<Result<LightRun, ClosedLoopError>> {
    let jobs: Vec<(usize, usize, u64)> = (0..lights.len())
        .flat_map(|l| (0..CORRUGATIONS.len()).flat_map(move |c| (0..runs).map(move |r| (l, c, r))))
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<(usize, Result<LightRun, ClosedLoopError>)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads.max(1))
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&(l, c, r)) = jobs.get(i) else { break };
                        // A panic in one run (a defect of the head it
                        // runs) is that run's error, named in the report,
                        // not the end of the sweep.
                        let got = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            run(lights, l, CORRUGATIONS[c], r)
                        }))
                        .unwrap_or_else(|p| {
                            let what = p
                                .downcast_ref::<String>()
                                .cloned()
                                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                                .unwrap_or_default();
                            Err(ClosedLoopError::Panicked(what))
                        });
                        mine.push((i, got));
                    }
                    mine
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().expect("a sweep worker panicked")).collect()
    });
    out.sort_by_key(|r| r.0);
    out.into_iter().map(|r| r.1).collect()
}

/// What a light's runs show: point scatter against the oracle, rows kept,
/// errors, coverage and verdicts.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct LightSummary {
    /// Runs.
    pub runs: usize,
    /// Detector RMS / oracle RMS and robust / robust, over the runs' points (medians of the runs).
    pub rms_ratio: f64,
    pub robust_ratio: f64,
    /// The detector's robust scatter, px (median of the runs).
    pub robust_px: f64,
    /// Fewest rows kept of any line of any run.
    pub rows_kept: f64,
    /// Largest |λ| (mm) and |A| (µm) error of the results not failed.
    pub worst_error: (f64, f64),
    /// Results not failed with a σ, and those whose 95 % interval holds
    /// the truth: λ, then A.
    pub with_sigma: (usize, usize),
    pub covered: (usize, usize),
    /// Largest error in σ among the results not failed.
    pub worst_sigmas: f64,
    /// Verdicts: good, doubtful, failed.
    pub levels: (usize, usize, usize),
    /// Good results off by more than 3σ or 0.15 mm / 6 µm.
    pub good_but_wrong: usize,
    /// Points the line pass flagged per frame (mean of the runs): glint,
    /// ghost (outside the band), off the line, kept with a second
    /// candidate dropped.
    pub line_per_frame: [f64; 4],
}

/// The summary of one light's runs.
pub fn summarize(runs: &[&LightRun]) -> LightSummary {
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let live: Vec<&&LightRun> = runs.iter().filter(|r| r.level != Level::Failed).collect();
    let count = |l: Level| runs.iter().filter(|r| r.level == l).count();
    LightSummary {
        runs: runs.len(),
        rms_ratio: med(runs.iter().map(|r| r.detector.rms_px / r.oracle.rms_px).collect()),
        robust_ratio: med(runs.iter().map(|r| r.detector.robust_px / r.oracle.robust_px).collect()),
        robust_px: med(runs.iter().map(|r| r.detector.robust_px).collect()),
        rows_kept: runs.iter().map(|r| r.rows_kept).fold(1.0, f64::min),
        worst_error: live
            .iter()
            .filter_map(|r| r.error)
            .fold((0.0, 0.0), |(l, a), (x, y)| (l.max(x.abs()), a.max(y.abs()))),
        with_sigma: (
            live.iter().filter(|r| r.covered().0.is_some()).count(),
            live.iter().filter(|r| r.covered().1.is_some()).count(),
        ),
        covered: (
            live.iter().filter(|r| r.covered().0 == Some(true)).count(),
            live.iter().filter(|r| r.covered().1 == Some(true)).count(),
        ),
        worst_sigmas: live.iter().filter_map(|r| r.worst_sigmas()).fold(0.0, f64::max),
        levels: (count(Level::Good), count(Level::Doubtful), count(Level::Failed)),
        good_but_wrong: runs
            .iter()
            .filter(|r| {
                r.level == Level::Good
                    && (r.worst_sigmas().is_none_or(|s| s > 3.0)
                        || r.error.is_some_and(|(l, a)| l.abs() > 0.15 || a.abs() > 6.0))
            })
            .count(),
        line_per_frame: {
            let n = runs.len().max(1) as f64;
            let sum = |f: fn(&Counts) -> u32| runs.iter().map(|r| f64::from(f(&r.line))).sum::<f64>() / n;
            [sum(|c| c.glint), sum(|c| c.ghost), sum(|c| c.off_line), sum(|c| c.second_dropped)]
        },
    }
}
