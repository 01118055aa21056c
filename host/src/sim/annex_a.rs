//! EN 13231-3 Annex A, closed loop: the simulated head driven over a
//! reference beam of known longitudinal profile, and the RMS difference
//! between what it measures and the beam, band by band.
//!
//! Annex A validates a corrugation instrument against a beam whose
//! profile a coordinate-measuring machine has measured: both are
//! band-filtered into 10–30, 30–100 and 100–300 mm and the RMS of their
//! difference must stay under 1, 1 and 2 µm (the limits as a trolley
//! maker quotes them, with its own instrument's 0.1 / 0.0 / 0.4 µm — not
//! checked against the standard's text). Here the beam is the simulator's
//! rail ([`Beam`]: sines in every band on a flat, uncrowned bar), the head
//! the reference head with its true calibration, every frame rendered,
//! detected and triangulated as the head does, stitched as `analyze`
//! stitches a recording, and compared with the beam's own profile on the
//! same grid.
//!
//! The comparison aligns the two along the beam first (the instrument's
//! position on the beam is not known to a fraction of a millimetre in a
//! real test either): the shift minimising the 30–100 mm difference,
//! searched to 0.01 mm over ±5 mm. Band values within two of a band's
//! longest wavelengths of either end are left out (the filter's settling,
//! as in [`crate::analyze::standards::en13231`]).
//!
//! Cost: one frame (480 rows of three stripes) takes about 40 ms to render
//! and detect; the default 3 m beam at 30 mm a frame is 100 frames.

use crate::sim::closed_loop::ClosedLoopError;
use std::fmt::Write as _;

use crate::analyze::standards::en13231;
use crate::analyze::stitch::{self, Direction, FramePoints, Registration, Stitcher};
use crate::measure::Measurer;
use crate::sim::calibration::truth::truth;
use crate::sim::closed_loop::{detector, frame_profiles};
use crate::sim::scene::{Corrugation, RailModel, Scene, SimConfig};

/// The bands Annex A compares, their RMS-difference limits (µm), and what
/// RailMeasurement's CAT reports for itself (µm).
pub const BANDS: [(f64, f64, f64, f64); 3] =
    [(10.0, 30.0, 1.0, 0.1), (30.0, 100.0, 1.0, 0.0), (100.0, 300.0, 2.0, 0.4)];

/// The beam and the drive over it.
#[derive(Debug, Clone, PartialEq)]
pub struct Beam {
    /// Length of rail the head travels over, mm.
    pub length_mm: f64,
    /// The beam's profile.
    pub components: Vec<Corrugation>,
    /// Travel between frames, mm (a frame sees about 69 mm).
    pub step_mm: f64,
    /// Every `row_step`-th image row.
    pub row_step: usize,
    /// Seed of the sensor noise.
    pub seed: u64,
}

impl Default for Beam {
    /// 3 m; two sines in each band: 5 µm at 15 mm and 4 µm at 22 mm,
    /// 10 µm at 45 mm and 8 µm at 70 mm, 20 µm at 150 mm and 15 µm at
    /// 250 mm; a frame every 30 mm, every row.
    fn default() -> Self {
        let c = |w: f64, a: f64, p: f64| Corrugation { wavelength_mm: w, amplitude_um: a, phase_rad: p };
        Beam {
            length_mm: 3000.0,
            components: vec![
                c(15.0, 5.0, 0.3),
                c(22.0, 4.0, 1.9),
                c(45.0, 10.0, 0.7),
                c(70.0, 8.0, 2.5),
                c(150.0, 20.0, 1.2),
                c(250.0, 15.0, 4.0),
            ],
            step_mm: 30.0,
            row_step: 1,
            seed: 7,
        }
    }
}

/// One band of one line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandDifference {
    pub lo_mm: f64,
    pub hi_mm: f64,
    /// RMS of measured minus beam, band-filtered, µm.
    pub rms_difference_um: f64,
    /// RMS of the beam's own band signal, µm (what there was to measure).
    pub beam_rms_um: f64,
    pub limit_um: f64,
    /// CAT's own figure, µm.
    pub cat_um: f64,
    /// Samples compared.
    pub samples: usize,
}

impl BandDifference {
    pub fn passes(&self) -> bool {
        self.rms_difference_um <= self.limit_um
    }
}

/// The outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct AnnexAOutcome {
    pub frames: usize,
    /// Per line: the alignment shift found (mm) and its bands.
    pub lines: Vec<(usize, f64, Vec<BandDifference>)>,
}

impl AnnexAOutcome {
    /// Whether every line meets every limit.
    pub fn passes(&self) -> bool {
        self.lines.iter().all(|(_, _, b)| b.iter().all(BandDifference::passes))
    }
}

/// The reference head over the beam.
pub fn config(beam: &Beam) -> SimConfig {
    let mut cfg = SimConfig::reference();
    cfg.rail = RailModel { corrugation: beam.components.clone(), ..RailModel::flat() };
    cfg.speed_mm_s = beam.step_mm * cfg.frame_rate_hz;
    cfg.seed = beam.seed;
    cfg
}

/// Shortest beam, mm: the 100–300 mm band's filter settles over 1.2 m at
/// each end, and needs a settled stretch between.
pub const MIN_BEAM_MM: f64 = 2400.0;
/// Longest beam, mm: Annex A's beams are a few metres; every frame is
/// rendered, so 100 m is already about an hour.
pub const MAX_BEAM_MM: f64 = 100_000.0;

/// Drives the head over the beam and compares.
pub fn measure(beam: &Beam) -> Result<AnnexAOutcome, ClosedLoopError> {
    if !((MIN_BEAM_MM..=MAX_BEAM_MM).contains(&beam.length_mm) && beam.step_mm > 0.0) {
        return Err(ClosedLoopError::Options(format!(
            "a {} mm beam at {} mm per frame: the 100–300 mm band needs at least {} m, and a beam is at most {} m",
            beam.length_mm,
            beam.step_mm,
            MIN_BEAM_MM / 1e3,
            MAX_BEAM_MM / 1e3
        )));
    }
    let cfg = config(beam);
    let mut scene = Scene::new(cfg.clone())?;
    let m = Measurer::new(&truth(&scene))?;
    let mut det = detector(&cfg)?;
    let opts = stitch::Options {
        direction: Direction::Auto,
        registration: Registration::Offset,
        ..stitch::Options::default()
    };
    let mut stitcher = Stitcher::new(&opts).map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
    let frames = (beam.length_mm / beam.step_mm).ceil() as u64 + 1;
    for n in 0..frames {
        let p = frame_profiles(&mut scene, n, &m, &mut det, beam.row_step)?;
        let mut f = FramePoints { seq: n as u32, odometer_mm: scene.odometer_mm(n), ..FramePoints::default() };
        for (k, line) in p.iter().enumerate() {
            f.lasers[k] = line.iter().map(|&(a, h)| (a, h * 1000.0)).collect();
        }
        stitcher.push(&f);
    }
    let stitching = stitcher.finish().map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
    let mut lines = Vec::new();
    for s in &stitching.lasers {
        let dx = s.dx_mm;
        let measured = &s.z.to_vec().unwrap_or_default();
        let truth_at =
            |shift: f64| -> Vec<f64> { (0..measured.len()).map(|i| scene.profile_um(s.x_mm(i) + shift)).collect() };
        let diff_rms = |band: (f64, f64), shift: f64| -> Result<(f64, f64, usize), ClosedLoopError> {
            let a = en13231::band_pass(measured, dx, band.0, band.1)
                .map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
            let b = en13231::band_pass(&truth_at(shift), dx, band.0, band.1)
                .map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
            let edge = (2.0 * band.1 / dx).ceil() as usize;
            let (mut sd, mut sb, mut n) = (0.0, 0.0, 0usize);
            for i in edge..a.len().saturating_sub(edge) {
                if a[i].is_finite() && b[i].is_finite() {
                    sd += (a[i] - b[i]).powi(2);
                    sb += b[i] * b[i];
                    n += 1;
                }
            }
            if n == 0 {
                return Err(ClosedLoopError::Analysis(format!("no settled samples in {}–{} mm", band.0, band.1)));
            }
            Ok(((sd / n as f64).sqrt(), (sb / n as f64).sqrt(), n))
        };
        // Align: a coarse scan then a finer one around the best.
        let mut best = (f64::INFINITY, 0.0);
        for step in [0.25, 0.01] {
            let centre = best.1;
            let span = if step > 0.1 { 5.0 } else { 0.3 };
            let mut k = -span;
            while k <= span + 1e-9 {
                let shift = centre + k;
                let (d, _, _) = diff_rms((30.0, 100.0), shift)?;
                if d < best.0 {
                    best = (d, shift);
                }
                k += step;
            }
        }
        let shift = best.1;
        let bands = BANDS
            .iter()
            .map(|&(lo, hi, limit_um, cat_um)| {
                let (rms_difference_um, beam_rms_um, samples) = diff_rms((lo, hi), shift)?;
                Ok(BandDifference { lo_mm: lo, hi_mm: hi, rms_difference_um, beam_rms_um, limit_um, cat_um, samples })
            })
            .collect::<Result<Vec<_>, ClosedLoopError>>()?;
        lines.push((s.laser, shift, bands));
    }
    Ok(AnnexAOutcome { frames: frames as usize, lines })
}

/// The comparison as a Markdown table, beside the limits and CAT's figures.
pub fn table(o: &AnnexAOutcome) -> String {
    let mut s = String::from(
        "| line | band mm | beam RMS µm | RMS difference µm | Annex A limit µm | CAT µm | pass |\n|---|---|---:|---:|---:|---:|---|\n",
    );
    for (line, _, bands) in &o.lines {
        for b in bands {
            let _ = writeln!(
                s,
                "| {line} | {}–{} | {:.2} | {:.3} | {} | {} | {} |",
                b.lo_mm,
                b.hi_mm,
                b.beam_rms_um,
                b.rms_difference_um,
                b.limit_um,
                b.cat_um,
                if b.passes() { "yes" } else { "NO" }
            );
        }
    }
    let shifts: Vec<String> = o.lines.iter().map(|(l, sh, _)| format!("line {l} {sh:+.2} mm")).collect();
    let _ = writeln!(s, "\n{} frames; alignment along the beam: {}", o.frames, shifts.join(", "));
    s
}
