//! The three laser lines of one image together: the head frame they share,
//! the surface normal they give (paper §2.2), and the joint sine fit of the
//! corrugation with a common wavelength.
//!
//! # Geometry
//!
//! The calibration gives each laser's profile frame (`cms_core::triangulation`:
//! origin `O_k` on the datum, axis `a_k` along the line, `up` the datum
//! normal), so a profile point `(along, height)` of laser k is the 3-D point
//! `O_k + along·a_k + height/(up·w_k)·w_k`, `w_k = n_k × a_k` the direction
//! of the laser plane across its line. [`HeadFrame`] writes every point in
//! one frame for all lasers: `u` along the mean line direction, `v` across
//! the rail, `h` the datum normal; the lines sit at their known lateral
//! offsets (15 mm apart at the paper's geometry), and lines that are not
//! parallel are handled point by point.
//!
//! # The surface normal (paper §2.2)
//!
//! A head that is not perpendicular to the rail (pitch, roll) measures
//! heights along the wrong direction; one that is not parallel to it (yaw)
//! cuts the corrugation obliquely, stretching the wavelength along each line
//! by `1/cos ψ` (1.5 % at 10°, as the paper notes). One line only sees the
//! pitch; three lines across the running band see the roll as well: the
//! least-squares plane `h = c + p·u + q·v` through the points of all lines
//! gives the local surface normal `n ∝ (−p, −q, 1)`. Every point is then
//! written in the surface frame (`z` along `n`, `x` the head's along axis
//! projected on the surface) — the profile "projected to the measurement
//! plane through the rail's longitudinal axis and the surface normal". This
//! matters beyond the tilt itself: the laser planes are inclined (α = 42°),
//! so on a surface rolled by β a crest moves its line sideways onto higher or
//! lower ground and the heights along one line scale by `1/(1 − tan β·tan α)`
//! — 3 % at β = 2° — unless they are measured in the surface frame.
//!
//! # The joint fit
//!
//! In the surface frame every point i (of any line) satisfies
//!
//! ```text
//! z = T + a·sin(k s) + b·cos(k s),   s = x cos ψ + y sin ψ,  u = −x sin ψ + y cos ψ
//! T = c + g_x x + g_y y + p₂ u²  [+ p₃ u³ + p₄ u⁴]  [+ e_ss s² + e_su s u]
//! ```
//!
//! one plane wave along the rail — wavenumber `k` (λ = 2π/k, fitted as
//! `ω = k cos ψ`, `κ = k sin ψ`), amplitude `√(a² + b²)`, the yaw `ψ` of the
//! lines against the rail — over the rail head's surface written in the
//! rail's own coordinates: `s` along it, `u` across it. A rail head is a
//! surface extruded along the rail (`z(s, u) = h(s) + crown(u)`, in the
//! simulator as on a real rail over one frame), and a rigid turn or tilt of
//! the head keeps it one, so its shape is a polynomial in `u` alone
//! **whatever the yaw**, and the wave's direction is the one that
//! defines `u`: the crown and the yaw are fitted together. The plane takes
//! the head's pitch and roll (and any linear term), `u²` the crown's
//! curvature (three lines), `u³, u⁴` what a circle or a worn head adds
//! beyond the parabola and where the apex is — which the lines can tell
//! apart only when they cross the crown, i.e. when yawed; `s², s u` stand
//! for long-wave geometry along the rail.
//!
//! This replaces a free 2-D polynomial in the points' `(x, y)` (to degree
//! four: 11 terms), which needed `x⁴, x³y, x²y²` at 10° of yaw over a
//! 200 mm crown and, having them, took a share of a long wavelength over
//! 2–3 periods: through the simulator, 100 mm × 50 µm at 10° of yaw had
//! σλ 0.03–0.038 mm against 0.02 for the aligned head. Here at most eight
//! trend terms, none of them along the rail unless the data ask, and the
//! same case is at σλ 0.02.
//!
//! The bracketed groups are rungs of a nested ladder, each kept only if an
//! F test asks for it (F > 12) over the highest rung kept so far; a rung
//! that does not pay is passed over, not the end of the ladder; a rung
//! whose columns the lines cannot tell apart (the column-normalised normal
//! matrix's reciprocal condition under `MIN_RCOND`, e.g. `u³` against
//! `u` with three lines along the rail) is not tried. With two lines there
//! is no `u²` in the first rung (it is a level across), with one line no
//! term across and κ = 0.
//!
//! Measured on a misaligned head's lines computed exactly over a crowned
//! rail (`tests::lines`: three parallel inclined sheets, 280 mm long, 1 µm
//! of noise, yaw 0–15°, pitch and roll ±2°, crowns 200 mm to flat): every
//! case within 0.01 mm and 0.12 µm, all good
//! (`tests::the_misalignment_sweep_is_right`); with the 2-D
//! polynomial, 15° over the 200 mm crown was 0.09–0.16 mm off (flagged).
//!
//! **Uncertainties.** From the Jacobian at the solution, but not as if the
//! points' errors were white: each point's influence on the result,
//! correlated along its line over `HAC_LAG` points (Newey–West,
//! `hac_variance`), because a stripe's position error depends on where
//! it falls on the pixel grid, which changes slowly along a line. Then
//! each line is fitted alone on its corrected profile ([`LineFit`]: the
//! same wave seen by one line), and where the three disagree beyond their
//! own uncertainties (Birge ratio `√(χ²/2)` over 1) the joint uncertainty
//! grows by that ratio: an error common to a line's points (its stripe's
//! sub-pixel systematic where its heights sit on the pixel grid) that no
//! residual shows. Over [`verdict::MAX_BIRGE`] the verdict is doubtful.
//!
//! **Starts and bounds.** Linear in all but ω and κ; refined by the
//! Levenberg–Marquardt of [`crate::model::lm`] from every line's own start: a
//! 2-D polynomial detrend, then `fit`'s sine of each line on what is left
//! gives an ω (κ from the lines' phases against their lateral positions),
//! and so do the highest peaks of the lines' joint periodogram (`spectrum`:
//! what one line's start misses under speckle and over short frames);
//! each rung's linear terms by least squares at that ω and κ. The lowest
//! residual whose yaw is within ±45° wins; a start that runs beyond is
//! discarded.
//!
//! **The verdict** ([`crate::measure::verdict`]): the residual against the noise
//! the points show (measured without a model), the bounds, convergence
//! and outliers give good, doubtful or failed, with the reasons.
//!
//! **Lateral slope.** An inclined laser plane's line moves across the rail
//! as the height changes (`v = v̄ + t·Δh`, `t = tan α`), and where the rail
//! head slopes across it meets higher or lower ground: one line's
//! deviations read `1/(1 − γ t)` of the rail's (±4.5 % for lines 15 mm off
//! the apex of a 300 mm crown at α = 42°). The joint fit models that
//! directly (each point where it is); a profile taken on its own — one
//! line, `cms-host analyze --calibration` — is slid along the local lateral
//! slope `γ_l` back to its line's course first, `h − γ_l·(v − v̂_l)`
//! ([`slide_across`]), `γ_l` from the parabola through the three lines'
//! mean heights: exact to first order in the crown's curvature.
//!
//! **Outliers.** Before any fit, points far from the median of their
//! neighbours along their line are left out (`screen`: a stripe taken in
//! the wrong place that the crown's terms would bend to). A misdetected stripe in one row (a glint, a spurious peak
//! taken for a line) gives a height tens of µm to millimetres off; least
//! squares weighs it by its square, and at the paper's geometry a handful of
//! such points in 9 504 made the wavelength scatter of a 100 mm × 50 µm
//! sample 1.5–5× what the noise allows (residual RMS 8–19 µm instead of
//! 3.7 µm). So the fit is done twice: points whose residual exceeds
//! [`REJECT_SIGMA`] (5) robust σ of the first fit (1.4826 × the median
//! absolute residual) are dropped and everything, the plane included, is
//! fitted again; [`Joint::rejected`] says how many.
//!
//! **The corrected profile** of each line is then `(s, z − (T − c))` with
//! `s = x cos ψ + y sin ψ` the position along the rail: heights normal to
//! the surface, positions along the rail, the three lines in phase.
//!
//! # Cost
//!
//! n points in all: the plane and the start's detrend O(n), the start fits
//! (`fit`, per line), then per start one refinement per rung of the
//! ladder (three), each LM iteration O(n·12²); the uncertainties
//! O(n·(12² + `HAC_LAG`)); the lines' own fits O(n·4²). A
//! paper-geometry image (3 × 3168 points) fits in tens of milliseconds.

mod across;
mod screen;
mod solve;
mod spectrum;
mod surface;
#[cfg(test)]
mod tests;

use serde::Serialize;

use cms_core::triangulation::Triangulator;

use crate::measure::fit::{self, FitError};
use crate::measure::verdict::{self, Evidence, Verdict};
use crate::model::lm;
use crate::model::vec3::{Vec3, axpy, cross, dot, unit};
pub use across::{Across, slide_across};
use solve::fit_once;
use surface::{Surface, evaluate_surface, linear_start, q, sigmas};

/// One laser's profile frame, as used to lift a profile point to 3-D.
#[derive(Debug, Clone, Copy, PartialEq)]
struct LineFrame {
    origin: Vec3,
    along: Vec3,
    /// In-plane direction across the line, scaled so that one unit of height
    /// is `height · across` (i.e. `w/(up·w)`).
    across: Vec3,
}

/// The head frame shared by the lasers of one calibration (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct HeadFrame {
    origin: Vec3,
    axes: [Vec3; 3],
    lines: Vec<LineFrame>,
}

impl HeadFrame {
    /// From the calibration's triangulator: `None` if a laser has no frame
    /// or its plane contains the datum normal's complement (cannot happen
    /// for a triangulator that was built).
    pub fn new(tri: &Triangulator) -> Option<HeadFrame> {
        let mut lines = Vec::new();
        let mut up = [0.0; 3];
        let mut along = [0.0; 3];
        let mut origin = [0.0; 3];
        for k in 0..cms_core::protocol::LASERS {
            let f = tri.frame(k)?;
            let w = cross(f.laser_normal, f.along);
            let s = dot(w, f.up);
            if s.abs() <= 1e-6 || !s.is_finite() {
                return None;
            }
            lines.push(LineFrame { origin: f.origin_mm, along: f.along, across: [w[0] / s, w[1] / s, w[2] / s] });
            (up, along, origin) = (f.up, axpy(1.0, f.along, along), axpy(1.0, f.origin_mm, origin));
        }
        let n = lines.len() as f64;
        let origin = [origin[0] / n, origin[1] / n, origin[2] / n];
        let along = unit(axpy(-dot(along, up), up, along))?;
        let lateral = cross(up, along);
        Some(HeadFrame { origin, axes: [along, lateral, up], lines })
    }

    /// Laser `laser`'s profile point `(along_mm, height_mm)` as `[u, v, h]`
    /// in the head frame, mm. `None` for an unknown laser.
    pub fn point(&self, laser: usize, along_mm: f64, height_mm: f64) -> Option<[f64; 3]> {
        let l = self.lines.get(laser)?;
        let x = axpy(height_mm, l.across, axpy(along_mm, l.along, l.origin));
        let d = axpy(-1.0, self.origin, x);
        Some([dot(d, self.axes[0]), dot(d, self.axes[1]), dot(d, self.axes[2])])
    }
}

/// One line's points in the head frame: `[u, v, h]`, mm.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// Laser index.
    pub laser: usize,
    /// Its points.
    pub points: Vec<[f64; 3]>,
}

/// A line's profile after the surface-normal correction: `s_mm` along the
/// rail, `z_mm` normal to the surface (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Corrected {
    /// Laser index.
    pub laser: usize,
    /// Positions along the rail, mm (from the points' centroid).
    pub s_mm: Vec<f64>,
    /// Heights normal to the surface, mm.
    pub z_mm: Vec<f64>,
    /// This line's offset `c_l` of the joint model, mm.
    pub offset_mm: f64,
}

/// The joint result of the lines of one image.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Joint {
    /// Lines fitted.
    pub lines: usize,
    /// Points fitted.
    pub points: usize,
    /// Corrugation wavelength along the rail, `2π/√(ω² + κ²)`, mm.
    pub wavelength_mm: f64,
    /// Amplitude (half peak-to-peak), mm.
    pub amplitude_mm: f64,
    /// Phase at the centroid, rad.
    pub phase_rad: f64,
    /// The surface normal in the head frame `[u, v, h]` (unit).
    pub normal: [f64; 3],
    /// Pitch of the surface against the head (along), rad: plane and residual.
    pub pitch_rad: f64,
    /// Roll of the surface against the head (across), rad.
    pub roll_rad: f64,
    /// Yaw of the lines against the rail, `atan2(κ, ω)`, rad.
    pub yaw_rad: f64,
    /// Curvature of the surface along the rail `2 e_ss`, 1/mm (long-wave
    /// geometry); 0 when not fitted.
    pub curvature_per_mm: f64,
    /// Curvature of the surface across the rail at the lines' centroid
    /// `2 p₂`, 1/mm (the crown: `−1/R` for a head of radius R); 0 when not
    /// fitted (fewer than three lines, or along the rail with two).
    pub crown_curvature_per_mm: f64,
    /// Whether the trend terms (curvature, per-line slopes) were fitted.
    pub trend: bool,
    /// Root mean square of the residuals, mm.
    pub rms_residual_mm: f64,
    /// One-σ uncertainty of the wavelength, mm.
    pub wavelength_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the amplitude, mm.
    pub amplitude_sigma_mm: Option<f64>,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// Whether the refinement met its convergence test.
    pub converged: bool,
    /// Points rejected as outliers (beyond [`REJECT_SIGMA`] robust σ of the
    /// first fit) and left out of this result.
    pub rejected: usize,
    /// Another start's minimum, as good within the noise, at this
    /// wavelength, mm: the data do not decide between them.
    pub alternative_wavelength_mm: Option<f64>,
    /// Each line's own sine on its corrected profile (along the rail, the
    /// joint surface removed): the same wave, seen by one line.
    pub per_line: Vec<LineFit>,
    /// How far the lines agree, as Birge ratios `√(χ²/(L − 1))` of their
    /// wavelengths and amplitudes against their uncertainties (1 for lines
    /// that agree within the noise; `None` under two line fits).
    pub birge: Option<(f64, f64)>,
    /// Whether to believe it, and why ([`crate::measure::verdict`]).
    pub verdict: Verdict,
}

/// One line's sine on its corrected profile: `z = c + a sin(ω s) + b
/// cos(ω s)` over `(s_mm, z_mm)`, from the joint result; uncertainties as
/// the joint's (`hac_variance`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LineFit {
    /// Laser index.
    pub laser: usize,
    /// Points fitted.
    pub points: usize,
    /// Wavelength along the rail, mm.
    pub wavelength_mm: f64,
    /// Amplitude, mm.
    pub amplitude_mm: f64,
    /// Root mean square of the residuals, mm.
    pub rms_residual_mm: f64,
    /// One-σ uncertainty of the wavelength, mm.
    pub wavelength_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the amplitude, mm.
    pub amplitude_sigma_mm: Option<f64>,
    /// Whether the refinement met its convergence test.
    pub converged: bool,
}

/// Fits the lines of one image jointly (module docs); returns the joint
/// result and the surface-normal corrected profile of each line. Lines with
/// fewer than 8 points are left out; at least one must remain.
pub fn joint_fit(lines: &[Line]) -> Result<(Joint, Vec<Corrected>), FitError> {
    joint_fit_from(lines, None)
}

/// [`joint_fit`] with one more start: a wavelength (mm) known to be near,
/// such as the previous frame's result along the same rail. It is one start
/// among the lines' own, not a prior: the lowest residual still wins.
pub fn joint_fit_from(lines: &[Line], near_mm: Option<f64>) -> Result<(Joint, Vec<Corrected>), FitError> {
    let (mut joint, corrected) = fit_rejecting(lines, near_mm)?;
    joint.per_line = corrected.iter().filter_map(|c| line_fit(c, &joint)).collect();
    joint.birge = birge(&joint.per_line);
    // The lines' disagreement beyond their noise is an error the joint
    // fit's own uncertainty does not see (a systematic of each line's
    // points: where its stripe falls on the pixel grid, its own surface):
    // the uncertainties grow by the Birge ratio when it exceeds 1.
    // Each line's own uncertainty misses the same error: the lines' scatter
    // is its measure for them too.
    if let Some((bl, ba)) = joint.birge {
        let (bl, ba) = (bl.max(1.0), ba.max(1.0));
        joint.wavelength_sigma_mm = joint.wavelength_sigma_mm.map(|s| s * bl);
        joint.amplitude_sigma_mm = joint.amplitude_sigma_mm.map(|s| s * ba);
        for l in &mut joint.per_line {
            l.wavelength_sigma_mm = l.wavelength_sigma_mm.map(|s| s * bl);
            l.amplitude_sigma_mm = l.amplitude_sigma_mm.map(|s| s * ba);
        }
    }
    joint.verdict = judge(&joint, lines, &corrected);
    Ok((joint, corrected))
}

/// Line `c`'s sine on its corrected profile, refined from the joint wave
/// (`None` under 8 points or when it does not fit).
fn line_fit(c: &Corrected, j: &Joint) -> Option<LineFit> {
    if c.s_mm.len() < 8 {
        return None;
    }
    let n = c.s_mm.len();
    let s = Surface {
        normal: [0.0, 0.0, 1.0],
        pitch: 0.0,
        roll: 0.0,
        x: c.s_mm.clone(),
        y: vec![0.0; n],
        z: c.z_mm.clone(),
        line: vec![0; n],
    };
    let mut p0 = vec![0.0; q::N];
    p0[q::OMEGA] = std::f64::consts::TAU / j.wavelength_mm;
    let free = [q::A, q::B, q::OMEGA, q::C];
    let start = linear_start(&s, &p0, &free)?;
    let got = lm::levenberg_marquardt(
        start,
        &free,
        fit::MAX_ITERATIONS,
        &mut lm::WithJacobian::new(|p: &[f64]| evaluate_surface(&s, p, &free)),
    )?;
    let (a, b, w) = (got.p[q::A], got.p[q::B], got.p[q::OMEGA]);
    let amp = a.hypot(b);
    let tau = std::f64::consts::TAU;
    let sig = sigmas(&s, &got.p, &free, got.rss, &[&[(q::OMEGA, -tau / (w * w))], &[(q::A, a / amp), (q::B, b / amp)]]);
    let fit = LineFit {
        laser: c.laser,
        points: n,
        wavelength_mm: tau / w,
        amplitude_mm: amp,
        rms_residual_mm: (got.rss / n as f64).sqrt(),
        wavelength_sigma_mm: sig[0],
        amplitude_sigma_mm: sig[1],
        converged: got.converged,
    };
    (fit.wavelength_mm.is_finite() && fit.wavelength_mm > 0.0 && amp.is_finite()).then_some(fit)
}

/// The Birge ratios of the lines' wavelengths and amplitudes: `√(χ²/(L −
/// 1))` about their weighted mean, `None` under two lines with
/// uncertainties.
fn birge(fits: &[LineFit]) -> Option<(f64, f64)> {
    let ratio = |v: &dyn Fn(&LineFit) -> Option<(f64, f64)>| -> Option<f64> {
        let pts: Vec<(f64, f64)> = fits.iter().filter_map(v).filter(|(_, s)| *s > 0.0 && s.is_finite()).collect();
        if pts.len() < 2 {
            return None;
        }
        let wsum: f64 = pts.iter().map(|(_, s)| 1.0 / (s * s)).sum();
        let mean = pts.iter().map(|(x, s)| x / (s * s)).sum::<f64>() / wsum;
        let chi2: f64 = pts.iter().map(|(x, s)| ((x - mean) / s).powi(2)).sum();
        let r = (chi2 / (pts.len() - 1) as f64).sqrt();
        r.is_finite().then_some(r)
    };
    Some((
        ratio(&|f| f.wavelength_sigma_mm.map(|s| (f.wavelength_mm, s)))?,
        ratio(&|f| f.amplitude_sigma_mm.map(|s| (f.amplitude_mm, s)))?,
    ))
}

/// The verdict on a joint result: its residual against the noise the
/// lines' points show (each line's own, pooled), its bounds, its state.
fn judge(j: &Joint, lines: &[Line], corrected: &[Corrected]) -> Verdict {
    let (mut ss, mut n) = (0.0, 0usize);
    for l in lines.iter().filter(|l| l.points.len() >= 8) {
        let pts: Vec<(f64, f64)> = l.points.iter().map(|p| (p[0], p[2])).collect();
        if let Some(s) = verdict::point_noise(&pts) {
            ss += s * s * pts.len() as f64;
            n += pts.len();
        }
    }
    // The points' errors correlated along a line (speckle) hide from the
    // neighbours `point_noise` compares: the residuals' own noise at the
    // lag where their correlation ends (`verdict::residual_noise`) is the
    // larger then.
    let k = std::f64::consts::TAU / j.wavelength_mm;
    let residuals: Vec<Vec<f64>> = corrected
        .iter()
        .map(|c| {
            c.s_mm
                .iter()
                .zip(&c.z_mm)
                .map(|(s, z)| z - c.offset_mm - j.amplitude_mm * (k * s + j.phase_rad).sin())
                .collect()
        })
        .collect();
    let point = (n > 0).then(|| (ss / n as f64).sqrt());
    let noise_mm = match (point, verdict::residual_noise(&residuals)) {
        (Some(p), Some((r, _))) => Some(p.max(r)),
        (p, r) => p.or(r.map(|r| r.0)),
    };
    let (lo, hi) = corrected
        .iter()
        .flat_map(|c| c.s_mm.iter())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &s| (a.min(s), b.max(s)));
    let longest = corrected.iter().map(|c| c.s_mm.len()).max().unwrap_or(0);
    verdict::judge(&Evidence {
        rms_residual_mm: j.rms_residual_mm,
        noise_mm,
        wavelength_mm: j.wavelength_mm,
        span_mm: hi - lo,
        spacing_mm: (hi - lo) / longest.saturating_sub(1).max(1) as f64,
        yaw_rad: j.yaw_rad,
        converged: j.converged,
        rejected: j.rejected,
        points: j.points + j.rejected,
        alternative_wavelength_mm: j.alternative_wavelength_mm,
        sigma_mm: (j.wavelength_sigma_mm, j.amplitude_sigma_mm),
        amplitude_mm: j.amplitude_mm,
        birge: j.birge.map(|(bl, ba)| {
            // A disagreement that matters (module docs of `verdict`).
            let matters = |sigma: Option<f64>, value: f64, share: f64| sigma.is_some_and(|s| s > share * value);
            (
                if matters(j.wavelength_sigma_mm, j.wavelength_mm, verdict::BIRGE_WAVELENGTH_SHARE) { bl } else { 0.0 },
                if matters(j.amplitude_sigma_mm, j.amplitude_mm, verdict::BIRGE_AMPLITUDE_SHARE) { ba } else { 0.0 },
            )
        }),
    })
}

/// [`fit_once`], then again without the outliers (module docs).
fn fit_rejecting(lines: &[Line], near_mm: Option<f64>) -> Result<(Joint, Vec<Corrected>), FitError> {
    let (lines, screened) = screen::screen(lines);
    let lines = &lines[..];
    let (mut joint, corrected, residuals) = fit_once(lines, near_mm, None)?;
    joint.rejected = screened;
    // Outliers (module docs): points beyond REJECT_SIGMA robust standard
    // deviations of the first fit's residuals are dropped and the whole fit,
    // plane included, is done again on the rest — once: a second pass would
    // only trim the tails of good data.
    let Some(limit) = rejection_limit(&residuals) else { return Ok((joint, corrected)) };
    let mut kept = residuals.iter();
    let inliers: Vec<Line> = lines
        .iter()
        .filter(|l| l.points.len() >= 8)
        .map(|l| Line {
            laser: l.laser,
            points: l.points.iter().filter(|_| kept.next().is_some_and(|r| r.abs() <= limit)).copied().collect(),
        })
        .collect();
    let rejected = residuals.len() - inliers.iter().map(|l| l.points.len()).sum::<usize>();
    if rejected == 0 {
        return Ok((joint, corrected));
    }
    // The first fit's wavelength is one more start: what the outliers
    // left of it is a better guess than a line's own start on the rest.
    let (mut joint, corrected, _) = fit_once(&inliers, near_mm, Some(joint.wavelength_mm))?;
    joint.rejected = rejected + screened;
    Ok((joint, corrected))
}

/// Residuals beyond this many robust standard deviations (1.4826 × the
/// median absolute residual) are outliers: Gaussian noise passes it once in
/// 1.7 million points, a misdetected stripe (a glint, a spurious peak: a
/// height off by tens of µm to millimetres) does not.
pub const REJECT_SIGMA: f64 = 5.0;

/// Residuals within this are never outliers, mm (1 µm: below what the head
/// resolves per point at the paper's geometry, about 3 µm RMS).
pub const REJECT_FLOOR_MM: f64 = 1e-3;

/// The largest residual kept, or `None` if the residuals give no scale.
fn rejection_limit(residuals: &[f64]) -> Option<f64> {
    let mut a: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    if a.len() < 16 {
        return None;
    }
    let mid = a.len() / 2;
    let (_, median, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
    // Never below REJECT_FLOOR_MM: on near-exact data the median residual
    // is rounding and model error, and its tails are not outliers.
    let limit = (REJECT_SIGMA * 1.4826 * *median).max(REJECT_FLOOR_MM);
    limit.is_finite().then_some(limit)
}
