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

use crate::analyze::survey::{self, Heading, JoinOptions, Placement};
use crate::analyze::{self, Analysis};
use crate::sim::closed_loop::ClosedLoopError;
use crate::sim::floor::{MIN_LENGTH_MM, Setting, drive};

/// One run of a repeat: the head's place across the rail, mm, and its
/// odometer at frame 0, mm (runs rarely start at the same millimetre, so
/// their frames fall elsewhere on the rail).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    pub lateral_mm: f64,
    pub odometer_start_mm: f64,
}

/// Drives the head over the setting's rail once per pass, run `k` with its
/// own frame noise, joins the runs at their true start (chainage 0, up: the
/// simulated odometer is exact) and judges the survey with `analyze`'s
/// defaults.
pub fn run(s: &Setting, passes: &[Pass]) -> Result<Analysis, ClosedLoopError> {
    if !(s.length_mm >= MIN_LENGTH_MM && s.length_mm <= 1e6 && s.step_mm > 0.0 && !passes.is_empty()) {
        return Err(ClosedLoopError::Options(format!(
            "{} mm of rail at {} mm a frame, {} run(s): at least {MIN_LENGTH_MM} mm, a positive step, a run",
            s.length_mm,
            s.step_mm,
            passes.len()
        )));
    }
    let mut runs = Vec::with_capacity(passes.len());
    for (k, p) in passes.iter().enumerate() {
        let mut cfg = s.config();
        cfg.run = k as u64;
        cfg.head.lateral_offset_mm = p.lateral_mm;
        cfg.odometer_start_mm = p.odometer_start_mm;
        runs.push(drive(s, cfg)?);
    }
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

    /// Runs 3 mm apart across the rail read independent speckle: the floor
    /// falls by 10·log₁₀ N dB; runs on one strip read the same speckle and
    /// their floor stays. 1.2 m of smooth rail at F/2.8, a frame every
    /// 60 mm: the 10–30 mm floor holds about 2 · 0.7 m · (1/10 − 1/30)
    /// mm⁻¹ ≈ 90 degrees of freedom a line pair, ±0.6 dB (1σ) an estimate
    /// and ±0.9 dB a difference of two: ±2 dB is over 2σ.
    #[test]
    fn the_floor_falls_as_one_over_n_with_runs_that_see_other_speckle() {
        let s = Setting { step_mm: 60.0, ..Setting::push_trolley(MIN_LENGTH_MM) };
        let pass = |k: usize, lateral_mm: f64| Pass { lateral_mm, odometer_start_mm: 7.3 * k as f64 };
        let across: Vec<Pass> = (0..4).map(|k| pass(k, 3.0 * k as f64)).collect();
        let (one, n1) = floor(&run(&s, &across[..1]).unwrap());
        let (two, n2) = floor(&run(&s, &across[..2]).unwrap());
        let (four, n4) = floor(&run(&s, &across).unwrap());
        let (same, n_same) = floor(&run(&s, &[pass(0, 0.0), pass(1, 0.0)]).unwrap());
        eprintln!("10–30 mm floor: 1 run {one:.2} dB, 2 runs {two:.2}, 4 runs {four:.2}, 2 on one strip {same:.2}");
        assert!((n1 - 1.0).abs() < 1e-9 && (n2 - 2.0).abs() < 0.05 && (n4 - 4.0).abs() < 0.1, "{n1} {n2} {n4}");
        assert!((n_same - 2.0).abs() < 0.05, "{n_same}");
        assert!((one - two - 3.0).abs() < 2.0, "2 runs: {one:.2} → {two:.2} dB");
        assert!((one - four - 6.0).abs() < 2.0, "4 runs: {one:.2} → {four:.2} dB");
        assert!((one - same).abs() < 1.5, "2 runs on one strip: {one:.2} → {same:.2} dB");
    }
}
