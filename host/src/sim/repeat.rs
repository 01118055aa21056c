//! Repeat runs over the same rail, closed loop: the simulated head driven
//! over one rail several times, each run with its own sensor noise and
//! its own place across the rail head, each run's lines stitched and the
//! runs joined as `analyze run1 run2 …` joins them — so that what averaging
//! runs does to the floor is measured, not assumed.
//!
//! Speckle is the surface's: a run whose lines fall on the same strip of
//! the rail head reads the same speckle, and only the sensor's noise
//! averages; a run standing 2.5 mm or more across (a stripe's width on
//! the rail, `sim::scene`'s repeat tests) reads other speckle, and the
//! floor's power falls as `1/N` for `N` such runs.

use crate::analyze::stitch::Stitching;
use crate::analyze::survey::{self, Heading, JoinOptions, Placement};
use crate::analyze::{self, Analysis};
use crate::sim::closed_loop::ClosedLoopError;
use crate::sim::floor::{MIN_LENGTH_MM, Setting, drive};

/// One run of a repeat: which run (its own frame noise), the head's place
/// across the rail, mm, and its odometer at frame 0, mm (runs rarely start
/// at the same millimetre, so their frames fall elsewhere on the rail).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    pub run: u64,
    pub lateral_mm: f64,
    pub odometer_start_mm: f64,
}

/// Drives the head over the setting's rail once per pass, joins the runs
/// and judges the survey ([`join`]).
pub fn run(s: &Setting, passes: &[Pass]) -> Result<Analysis, ClosedLoopError> {
    join(drive_passes(s, passes)?)
}

/// Each pass's lines, stitched as `analyze` stitches a recording.
pub fn drive_passes(s: &Setting, passes: &[Pass]) -> Result<Vec<Stitching>, ClosedLoopError> {
    if !(s.length_mm >= MIN_LENGTH_MM && s.length_mm <= 1e6 && s.step_mm > 0.0 && !passes.is_empty()) {
        return Err(ClosedLoopError::Options(format!(
            "{} mm of rail at {} mm a frame, {} run(s): at least {MIN_LENGTH_MM} mm, a positive step, a run",
            s.length_mm,
            s.step_mm,
            passes.len()
        )));
    }
    passes
        .iter()
        .map(|p| {
            let mut cfg = s.config();
            cfg.run = p.run;
            cfg.head.lateral_offset_mm = p.lateral_mm;
            cfg.odometer_start_mm = p.odometer_start_mm;
            drive(s, cfg)
        })
        .collect()
}

/// Joins runs at their true start (chainage 0, up: the simulated odometer
/// is exact) as `analyze run1 run2 …` joins them, and judges the survey
/// with `analyze`'s defaults.
pub fn join(runs: Vec<Stitching>) -> Result<Analysis, ClosedLoopError> {
    let at = vec![Placement { start_m: Some(0.0), heading: Some(Heading::Up) }; runs.len()];
    let analysis = |e: String| ClosedLoopError::Analysis(e);
    let (stitching, joins) = survey::join(runs, &at, &JoinOptions::default()).map_err(|e| analysis(e.to_string()))?;
    analyze::judge(stitching, joins, &analyze::Options::default(), &crate::progress::Silent)
        .map_err(|e| analysis(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One line's floor in the 10–30 mm band, dB re 1 µm, and the runs
    /// the lines average.
    fn floor(a: &Analysis) -> (f64, f64) {
        let f = a.floor.as_ref().and_then(|f| f.band(0)).expect("the 10–30 mm floor");
        let runs = a.lasers.iter().map(|l| l.stitched.runs_averaged).fold(f64::INFINITY, f64::min);
        (20.0 * (f.rms_mm * 1000.0).log10(), runs)
    }

    /// Repeat runs whose odometers each start at their own zero are laid on
    /// one another by registration alone (no start, no heading given): on
    /// a rail of 2 µm RMS roughness over 5–500 mm (the default rail's),
    /// under the sensor's own floor (incoherent light; the recommended
    /// head's 10–30 mm floor, 0.49 µm, is near its 0.29), each run's start
    /// is found to a twentieth of the shortest wavelength ISO 3095 judges
    /// (5 mm), so the runs average the rail in phase down to it (a
    /// misregistration δ costs a wavelength λ `cos(πδ/λ)` of its amplitude:
    /// 0.1 dB at 5 mm). The runs correlate at 0.7–0.8 where they belong and
    /// under 0.1 elsewhere, under the 0.9 of a clear match alone: they
    /// register by standing over their rivals. (At the push-trolley
    /// setting's speckle, 6.9 µm in that band, 2 µm of roughness does not
    /// register: the runs need their starts.)
    #[test]
    fn runs_registered_without_a_start_land_where_they_ran() {
        let s = Setting { step_mm: 60.0, f_number: None, ..Setting::push_trolley(5000.0) };
        let starts_mm = [0.0, 41.7, 96.2, 133.9];
        let runs: Vec<Stitching> = starts_mm
            .iter()
            .enumerate()
            .map(|(k, &start)| {
                let mut cfg = s.config();
                cfg.rail.roughness_rms_um = 2.0;
                cfg.run = k as u64;
                cfg.head.lateral_offset_mm = 3.0 * k as f64;
                cfg.odometer_start_mm = start;
                let mut run = drive(&s, cfg).unwrap();
                // The run's own odometer: zero where it started.
                for l in &mut run.lasers {
                    l.x0_mm -= start;
                }
                run
            })
            .collect();
        let mut at = vec![Placement::default(); runs.len()];
        at[0] = Placement { start_m: Some(0.0), heading: Some(Heading::Up) };
        let (_, joins) = survey::join(runs, &at, &JoinOptions::default()).unwrap();
        for (j, &start) in joins.iter().zip(&starts_mm) {
            let error_mm = j.start_m * 1000.0 - start;
            eprintln!(
                "run {}: registered at {:.3} mm, ran at {start} mm: {error_mm:+.3} mm ({:?}, correlation {:?})",
                j.run,
                j.start_m * 1000.0,
                j.heading,
                j.correlation
            );
            assert_eq!(j.heading, Heading::Up, "{j:?}");
            assert!(error_mm.abs() < 0.25, "run {} registered {error_mm:+.3} mm from where it ran", j.run);
        }
    }

    /// Runs 3 mm apart across the rail read independent speckle: the floor
    /// falls by 10·log₁₀ N dB; runs on one strip read the same speckle and
    /// their floor stays. 1.2 m of smooth rail at F/2.8, a frame every
    /// 60 mm: the 10–30 mm floor holds about 2 · 0.7 m · (1/10 − 1/30)
    /// mm⁻¹ ≈ 90 degrees of freedom a line pair, ±0.6 dB (1σ) an estimate
    /// and ±0.9 dB a difference of two: ±2 dB is over 2σ.
    #[test]
    fn the_floor_falls_as_one_over_n_with_runs_that_see_other_speckle() {
        let s = Setting { step_mm: 60.0, ..Setting::push_trolley(MIN_LENGTH_MM) };
        let pass = |run: u64, lateral_mm: f64| Pass { run, lateral_mm, odometer_start_mm: 7.3 * run as f64 };
        // Four runs 3 mm apart across the rail, and a second run on the first's strip.
        let passes = [pass(0, 0.0), pass(1, 3.0), pass(2, 6.0), pass(3, 9.0), pass(1, 0.0)];
        let runs = drive_passes(&s, &passes).unwrap();
        let joined = |k: &[usize]| floor(&join(k.iter().map(|&k| runs[k].clone()).collect()).unwrap());
        let ((one, n1), (two, n2), (four, n4), (same, n_same)) =
            (joined(&[0]), joined(&[0, 1]), joined(&[0, 1, 2, 3]), joined(&[0, 4]));
        eprintln!("10–30 mm floor: 1 run {one:.2} dB, 2 runs {two:.2}, 4 runs {four:.2}, 2 on one strip {same:.2}");
        // The runs start 7.3 mm apart: their ends average fewer.
        assert!((n1 - 1.0).abs() < 1e-9 && (1.9..=2.0).contains(&n2) && (3.6..=4.0).contains(&n4), "{n1} {n2} {n4}");
        assert!((1.9..=2.0).contains(&n_same), "{n_same}");
        assert!((one - two - 3.0).abs() < 2.0, "2 runs: {one:.2} → {two:.2} dB");
        assert!((one - four - 6.0).abs() < 2.0, "4 runs: {one:.2} → {four:.2} dB");
        assert!((one - same).abs() < 1.5, "2 runs on one strip: {one:.2} → {same:.2} dB");
    }
}
