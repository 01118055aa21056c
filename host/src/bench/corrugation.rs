//! `bench corrugation`: the closed loop of [`crate::sim::closed_loop`] — the
//! paper's four corrugation samples through the simulated head, the
//! wavelength and amplitude errors over runs (`corrugation.md`,
//! `corrugation.csv`) and one measured frame's plot (`frame_l50_a50.png`,
//! `.svg`); or, with `sweep`, the head turned and tilted against its datum.

use std::path::PathBuf;
use std::time::Instant;

use super::{BenchError, put};
use crate::sim::closed_loop::{self as cl, PAPER_CASES};

/// Options of the closed-loop benchmark.
#[derive(Debug, Clone)]
pub struct CorrugationOptions {
    /// Runs per case.
    pub runs: u64,
    /// Every how many image rows a point is taken.
    pub row_step: u64,
    /// Rail roughness, µm RMS.
    pub roughness_um: f64,
    /// The misalignment sweep instead of the paper's cases.
    pub sweep: bool,
    /// Worker threads (`None`: one a core).
    pub threads: Option<usize>,
    /// Folder of the files.
    pub out: PathBuf,
}

/// The closed-loop table (or the misalignment sweep) and one frame's plot,
/// written into `a.out`; returns the report.
pub fn corrugation(a: &CorrugationOptions) -> Result<String, BenchError> {
    if !(a.roughness_um >= 0.0 && a.roughness_um.is_finite()) {
        return Err(BenchError::Options("--roughness-um must be finite and ≥ 0".into()));
    }
    super::create_dir(&a.out)?;
    if a.sweep {
        let t = Instant::now();
        let cells = cl::sweep_cells();
        let runs = cl::sweep(&cells, a.runs, a.row_step as usize, super::threads(a.threads));
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
        threads: super::threads(a.threads),
        single: true,
        roughness_um: a.roughness_um,
    };
    let t = Instant::now();
    let stats = cl::study(&PAPER_CASES, &study)?;
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
    let m = cl::measure_frame(&cfg, study.row_step)?;
    crate::measure::plot(&path("frame_l50_a50"), &m)
        .map_err(|why| BenchError::Plot { path: path("frame_l50_a50.png"), why: why.to_string() })?;
    md += &format!("\nPlot of one frame (λ 50 mm, A 50 µm): {} and .svg\n", path("frame_l50_a50.png").display());
    Ok(md)
}
