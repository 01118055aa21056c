//! Sine fitting of longitudinal rail profiles, and `cms-host fit`.
//!
//! What it is: the corrugation's wavelength and amplitude from a profile
//! `(x_mm, z_mm)`, by least squares on one of two models:
//!
//! * `sine` — IEEE Std 1057's four-parameter model
//!   `z = a·sin ωx + b·cos ωx + c` (amplitude `√(a²+b²)`, phase `atan2(b, a)`);
//! * `rotated` (the paper's, §6) — the same sine in a frame rotated by the
//!   unknown sensor rotation θ: with `x' = x cosθ + z sinθ` and
//!   `z' = −x sinθ + z cosθ`, `z' = a·sin ωx' + b·cos ωx' + c`. Exact, not the
//!   small-angle "sine plus slope" form: at 3° over 300 mm the slope form is
//!   off by the `1 − cosθ` stretch of the wavelength (0.14 %) and more.
//!
//! Several components (`components > 1`) add `a_k sin ω_k x' + b_k cos ω_k x'`
//! terms sharing θ and c.
//!
//! # Design
//!
//! **Residual of the rotated model.** The model is implicit in z. We fit the
//! *vertical* residual `z − ẑ(x)`, where `ẑ(x)` solves
//! `g(z) = −x sinθ + z cosθ − h(x cosθ + z sinθ) = 0` (h the sine sum) by a
//! safeguarded Newton iteration, and take the Jacobian from the implicit
//! function theorem, `∂ẑ/∂p = −(∂g/∂p)/(∂g/∂z)`. Why vertical and not
//! orthogonal distances: the head's noise is along the camera ray, close to z,
//! so this is the maximum-likelihood residual; and g is strictly monotone in
//! z while `|sinθ|·Σ A_k ω_k < cosθ` (slope of the sine in the rotated frame
//! times tanθ below one, i.e. for every corrugation: A ω ≈ 0.01), so ẑ is
//! unique, bracketed by `(x sinθ + c ± ΣA_k)/cosθ`, and Newton converges in
//! 2–3 steps. Outside that region the model is multivalued and the step is
//! rejected. With θ fixed at 0 the same code is the plain sine model
//! (`ẑ = h(x)` after one Newton step), so both models share one solver.
//!
//! **Start values.** ω from an interpolated DFT peak (profile resampled on a
//! uniform grid — the head's profiles are nearly uniform —, detrended,
//! zero-padded ×8, parabolic interpolation of the magnitude) and from the
//! paper's ellipse method on the differenced profile (docs/reference.md §3, lag ≈ λ/4 from
//! the DFT estimate), and Jacquelin's non-iterative estimate (below). Each
//! start runs the plain IEEE 1057 four-parameter
//! iteration. That iteration can diverge (it does on the 15-point public test
//! vector); the fallback cannot: the three-parameter residual `S(ω)` (linear
//! least squares at fixed ω) scanned over the band `[π/span, π/mean spacing]`
//! at 1/8 of its resolution `2π/span`, then golden-section refinement inside
//! the bracket of the best grid point. The lowest `S(ω)` of all candidates
//! wins. For the rotated model, θ starts from the slope of a straight-line
//! fit, the points are rotated by it and the sine start is found on those.
//!
//! **Refinement.** Levenberg–Marquardt ([`crate::model::lm`], Marquardt's diagonal scaling) on all
//! parameters jointly; it only accepts steps that lower the residual, so it
//! cannot diverge. Components beyond the first are started by fitting the
//! residual of the previous ones (dominant first), then refined jointly.
//! Data are centred and scaled isotropically before fitting (the rotated
//! family is invariant under that), so arbitrary finite input neither
//! overflows nor loses precision; the parameters are mapped back afterwards.
//!
//! **Uncertainties.** `σ² (JᵀJ)⁻¹` with `σ² = RSS/(n − p)` and J the Jacobian
//! at the solution on the original data; derived quantities (wavelength,
//! amplitude, phase) by first-order propagation. `None` when JᵀJ is singular.
//!
//! # Cost
//!
//! n points, k components: each LM iteration O(n·(3k+2)²) plus 2–3 Newton
//! steps per point; the zero-padded FFT (`rustfft`) O(M log M) on the resampled profile
//! (M ≤ 2048 points);
//! the fallback scan O(n·G) with G ≤ 4096 grid points. A 400-point profile
//! fits in milliseconds (the whole `cms-host fit` run: ~50 ms).
//!
//! **Two methods.** [`fit`] (`--method lsq`, the default) is least squares
//! as above. [`fit_jacquelin`] (`--method jacquelin`, model `sine` only) is
//! Jacquelin's non-iterative regression through an integral equation
//! ([`jacquelin`]: three linear steps, no start value, no iteration), given
//! as is; it is also one more start value of the least-squares fit.
//!
//! **The public test vector (docs/reference.md §3).** Its ω = 2.02074 is Jacquelin's
//! non-iterative estimate, which [`jacquelin`] reproduces (ω₁ = 2.32536 from
//! the integral equation, ω₂ = 2.02074 from the sawtooth step, offset
//! −0.405617, coefficients 1.27520 and −0.577491), not the least-squares
//! minimum: the residual is lower at ω = 1.98131 (RSS 0.32035 against
//! 0.34552), which is what a least-squares fit (this one, or scipy's) returns. The plain
//! IEEE iteration reaches that minimum from starts within ±40 %, and side
//! minima (ω 4.36, 6.97) from starts 2× off; the scan does not depend on the
//! start.

mod ieee;
mod jacquelin;
mod model;
mod start;
#[cfg(test)]
mod tests;

use std::fmt;

use nalgebra::DMatrix;
use serde::Serialize;

pub use ieee::{FourParam, Linear, four_param_ieee, three_param};
pub use jacquelin::{Jacquelin, jacquelin};
use model::{Params, column_param, evaluate, refine};
pub use start::{dft_omega, ellipse_omega, scan_omega};
use start::{line_fit, sine_start};

/// Most Levenberg–Marquardt iterations of the joint refinement.
pub const MAX_ITERATIONS: usize = 200;
/// Most iterations of the plain IEEE 1057 four-parameter iteration.
pub const IEEE_MAX_ITERATIONS: usize = 50;
/// Most components `fit` takes.
pub const MAX_COMPONENTS: usize = 8;
/// Most resampled points the DFT and ellipse estimates use.
const MAX_RESAMPLED: usize = 2048;
/// Most resampled points of the fallback scan (its grid has 4 × as many bins).
const MAX_SCAN_RESAMPLED: usize = 1 << 20;

/// Why a profile could not be read or fitted.
#[derive(Debug, Clone, PartialEq)]
pub enum FitError {
    /// A line of a profile file is not `x_mm,z_mm` with two finite numbers.
    Line {
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// `x` and `z` have different lengths.
    LengthMismatch {
        /// Points in x.
        x: usize,
        /// Points in z.
        z: usize,
    },
    /// A coordinate is NaN or infinite.
    NonFinite {
        /// 0-based index of the point.
        index: usize,
    },
    /// Fewer points than the model has parameters plus one.
    TooFewPoints {
        /// Points given.
        points: usize,
        /// Points needed.
        needed: usize,
    },
    /// `components` is 0 or more than [`MAX_COMPONENTS`].
    Components(usize),
    /// The data cannot determine a sine (all x equal, flat profile, …).
    Degenerate(&'static str),
    /// The heights span less than [`MIN_HEIGHT_TO_LENGTH`] of the length:
    /// in the fit's common scale they are lost to rounding.
    TooFlat {
        /// Range of z, mm.
        height_mm: f64,
        /// Range of x, mm.
        length_mm: f64,
    },
}

/// Smallest ratio of the range of z to the range of x that the fit
/// resolves. It scales x and z by one factor (the rotated model's rotation
/// must stay a rotation), so z is resolved only to about `ε·range(x)`: on
/// exact sines the rotated fit is exact down to a ratio of 2·10⁻¹³ and
/// wrong (wavelength off by 4·10⁻⁴) at 2·10⁻¹⁴; with x near 10³⁰⁰ and z of
/// 0.1 mm (10⁻³⁰¹) it printed a wavelength 5 times too long and a residual
/// of 0. The limit keeps a margin of 5 below the first good ratio.
pub const MIN_HEIGHT_TO_LENGTH: f64 = 1e-12;

impl fmt::Display for FitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FitError::Line { line, reason } => write!(f, "line {line}: {reason}"),
            FitError::LengthMismatch { x, z } => write!(f, "{x} x values but {z} z values"),
            FitError::NonFinite { index } => write!(f, "point {index} is not finite"),
            FitError::TooFewPoints { points, needed } => {
                write!(f, "{points} points, the model needs at least {needed}")
            }
            FitError::Components(k) => write!(f, "{k} components: expected 1..={MAX_COMPONENTS}"),
            FitError::Degenerate(why) => write!(f, "cannot fit a sine: {why}"),
            FitError::TooFlat { height_mm, length_mm } => write!(
                f,
                "cannot fit a sine: z spans {height_mm:.3e} mm over {length_mm:.3e} mm of x, less than \
                 {MIN_HEIGHT_TO_LENGTH:e} of it: too flat to resolve in double precision (check the units, or \
                 subtract a line first)"
            ),
        }
    }
}

impl std::error::Error for FitError {}

/// The fitted model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// The paper's sine in a frame rotated by the unknown sensor rotation.
    Rotated,
    /// IEEE Std 1057 four-parameter sine (no rotation).
    Sine,
}

/// Where the winning start value of ω came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Start {
    /// IEEE 1057 iteration started at the interpolated DFT peak.
    Dft,
    /// IEEE 1057 iteration started at the ellipse-method estimate.
    Ellipse,
    /// The scan and golden-section search of the three-parameter residual.
    Scan,
    /// Jacquelin's non-iterative estimate ([`jacquelin`]), as is or as the
    /// start of the IEEE 1057 iteration.
    Jacquelin,
}

/// How `cms-host fit` estimates the parameters: [`fit`] or [`fit_jacquelin`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FitMethod {
    /// Least squares: the best of several starts refined by Levenberg–Marquardt (the default).
    #[default]
    Lsq,
    /// Jacquelin's non-iterative integral-equation regression, not refined
    /// (model `sine`, one component only).
    Jacquelin,
}

/// Options of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// Which model.
    pub model: Model,
    /// How many sine components (1..=[`MAX_COMPONENTS`]).
    pub components: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options { model: Model::Rotated, components: 1 }
    }
}

/// One sine component `a·sin ωx' + b·cos ωx' = A·sin(ωx' + φ)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Component {
    /// `ω`, the angular wavenumber, rad/mm.
    pub omega_rad_per_mm: f64,
    /// `2π/ω`, mm (along the rotated axis x' for the rotated model).
    pub wavelength_mm: f64,
    /// `A = √(a²+b²)`: half the peak-to-peak, mm.
    pub amplitude_mm: f64,
    /// `φ = atan2(b, a)`, rad, at x' = 0.
    pub phase_rad: f64,
    /// `a`, the sine coefficient, mm.
    pub sin_mm: f64,
    /// `b`, the cosine coefficient, mm.
    pub cos_mm: f64,
    /// One-σ uncertainty of the wavelength, mm.
    pub wavelength_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the amplitude, mm.
    pub amplitude_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the phase, rad.
    pub phase_sigma_rad: Option<f64>,
}

/// The result of [`fit`]. The top-level wavelength, amplitude and phase are
/// those of the dominant (largest-amplitude) component, `components[0]`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fit {
    /// The model fitted.
    pub model: Model,
    /// Least squares, or Jacquelin's non-iterative estimate.
    pub method: FitMethod,
    /// Points fitted.
    pub points: usize,
    /// Dominant component's wavelength, mm.
    pub wavelength_mm: f64,
    /// Dominant component's amplitude (half peak-to-peak), mm.
    pub amplitude_mm: f64,
    /// Dominant component's phase, rad.
    pub phase_rad: f64,
    /// `c`, the offset (in the rotated frame for the rotated model), mm.
    pub offset_mm: f64,
    /// θ, the sensor rotation, rad (0 for the sine model).
    pub rotation_rad: f64,
    /// Root mean square of the residuals `z − ẑ`, mm.
    pub rms_residual_mm: f64,
    /// One-σ uncertainty of the dominant wavelength, mm.
    pub wavelength_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the dominant amplitude, mm.
    pub amplitude_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the dominant phase, rad.
    pub phase_sigma_rad: Option<f64>,
    /// One-σ uncertainty of the offset, mm.
    pub offset_sigma_mm: Option<f64>,
    /// One-σ uncertainty of the rotation, rad (`None` for the sine model).
    pub rotation_sigma_rad: Option<f64>,
    /// All components, largest amplitude first.
    pub components: Vec<Component>,
    /// Where the dominant component's start value came from.
    pub start: Start,
    /// Levenberg–Marquardt iterations of the joint refinement.
    pub iterations: usize,
    /// Whether the refinement met its convergence test.
    pub converged: bool,
}

// ---------------------------------------------------------------------------
// Profile files

/// A profile: `x_mm[i], z_mm[i]` is one point.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ProfilePoints {
    /// Longitudinal positions, mm.
    pub x_mm: Vec<f64>,
    /// Heights, mm.
    pub z_mm: Vec<f64>,
}

/// Parses a profile CSV: lines `x_mm,z_mm` (two finite numbers, spaces
/// around fields allowed, `\n` or `\r\n`), blank lines and `#` comments
/// skipped, an optional header (a first line whose fields are not numbers).
pub fn parse_profile(text: &str) -> Result<ProfilePoints, FitError> {
    let mut p = ProfilePoints::default();
    let mut first = true;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let bad = |reason: String| FitError::Line { line: i + 1, reason };
        if fields.len() != 2 {
            return Err(bad(format!("expected 2 fields x_mm,z_mm, found {}", fields.len())));
        }
        let values: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        if first && values.iter().all(Option::is_none) {
            first = false;
            continue; // the header
        }
        first = false;
        let mut xz = [0.0; 2];
        for ((v, f), out) in values.iter().zip(&fields).zip(&mut xz) {
            match v {
                Some(v) if v.is_finite() => *out = *v,
                _ => return Err(bad(format!("`{}` is not a finite number", crate::input::one_line(f, 40)))),
            }
        }
        p.x_mm.push(xz[0]);
        p.z_mm.push(xz[1]);
    }
    Ok(p)
}

// ---------------------------------------------------------------------------
// The fit

/// Fits `opts.components` sines (model `opts.model`) to the points
/// `(x_mm[i], z_mm[i])`. See the module documentation for the method.
pub fn fit(x_mm: &[f64], z_mm: &[f64], opts: &Options) -> Result<Fit, FitError> {
    let k = opts.components;
    if k == 0 || k > MAX_COMPONENTS {
        return Err(FitError::Components(k));
    }
    let fit_rotation = opts.model == Model::Rotated;
    let n_params = 3 * k + 1 + usize::from(fit_rotation);
    check_points(x_mm, z_mm, n_params + 1)?;
    // Centre and scale isotropically (halves first: no overflow).
    let range = |v: &[f64]| v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let ((x_lo, x_hi), (z_lo, z_hi)) = (range(x_mm), range(z_mm));
    let (x0, z0) = (x_lo / 2.0 + x_hi / 2.0, z_lo / 2.0 + z_hi / 2.0);
    let (xs, zs) = (x_hi / 2.0 - x_lo / 2.0, z_hi / 2.0 - z_lo / 2.0);
    if xs.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(FitError::Degenerate("all x are equal"));
    }
    if zs.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(FitError::Degenerate("the profile is flat"));
    }
    if zs < MIN_HEIGHT_TO_LENGTH * xs {
        // Ranges are doubled from halves (above), so neither overflows here.
        return Err(FitError::TooFlat { height_mm: 2.0 * zs, length_mm: 2.0 * xs });
    }
    let s = xs.max(zs);
    let x: Vec<f64> = x_mm.iter().map(|v| (v - x0) / s).collect();
    let z: Vec<f64> = z_mm.iter().map(|v| (v - z0) / s).collect();
    if x.iter().chain(&z).any(|v| !v.is_finite()) {
        return Err(FitError::Degenerate("coordinates out of range"));
    }

    // Start values: θ from the straight line, then components one by one on
    // the rotated points (dominant first), each on the previous residual.
    let theta0 = if fit_rotation { line_fit(&x, &z).map_or(0.0, |(slope, _)| slope.atan()) } else { 0.0 };
    let (si, co) = theta0.sin_cos();
    let xr: Vec<f64> = x.iter().zip(&z).map(|(x, z)| x * co + z * si).collect();
    let mut zr: Vec<f64> = x.iter().zip(&z).map(|(x, z)| -x * si + z * co).collect();
    let mut params = vec![0.0, theta0];
    let mut first_start = Start::Scan;
    for c in 0..k {
        let (w, lin, start) = sine_start(&xr, &zr).ok_or(FitError::Degenerate("no sine found in the profile"))?;
        if c == 0 {
            first_start = start;
        }
        params[0] += lin.offset;
        params.extend([lin.sin, lin.cos, w]);
        for (zr, xr) in zr.iter_mut().zip(&xr) {
            let (s, c) = (w * xr).sin_cos();
            *zr -= lin.sin * s + lin.cos * c + lin.offset;
        }
    }
    let refined =
        refine(&x, &z, Params(params), fit_rotation).ok_or(FitError::Degenerate("the model is not single-valued"))?;

    // Back to the original coordinates (module docs): ω/s, s·(a, b) turned by
    // δ = ω·X0, c = Z0 + s·c.
    let p = &refined.p.0;
    let theta = p[1];
    let (si, co) = theta.sin_cos();
    let (xr0, zr0) = (x0 * co + z0 * si, -x0 * si + z0 * co);
    let mut out = vec![zr0 + s * p[0], theta];
    for (a, b, w) in refined.p.comps() {
        let omega = w / s;
        let (sd, cd) = (omega * xr0).sin_cos();
        out.extend([s * (a * cd + b * sd), s * (b * cd - a * sd), omega]);
    }
    if out.iter().any(|v| !v.is_finite()) {
        return Err(FitError::Degenerate("parameters out of range"));
    }
    let out = Params(out);
    let n = x_mm.len();
    let rss = refined.rss * s * s;
    let cov = covariance(x_mm, z_mm, &out, fit_rotation, rss / (n - n_params) as f64);
    let f = report(opts.model, n, &out, cov.as_ref(), rss, first_start, refined.iterations, refined.converged);
    let values = [f.wavelength_mm, f.amplitude_mm, f.phase_rad, f.offset_mm, f.rotation_rad, f.rms_residual_mm];
    let comps = f.components.iter().flat_map(|c| [c.wavelength_mm, c.amplitude_mm, c.phase_rad]);
    if values.into_iter().chain(comps).any(|v| !v.is_finite()) {
        return Err(FitError::Degenerate("values out of range"));
    }
    Ok(f)
}

/// Equal lengths, finite coordinates, at least `needed` points.
fn check_points(x_mm: &[f64], z_mm: &[f64], needed: usize) -> Result<(), FitError> {
    if x_mm.len() != z_mm.len() {
        return Err(FitError::LengthMismatch { x: x_mm.len(), z: z_mm.len() });
    }
    if let Some(index) = x_mm.iter().zip(z_mm).position(|(x, z)| !(x.is_finite() && z.is_finite())) {
        return Err(FitError::NonFinite { index });
    }
    if x_mm.len() < needed {
        return Err(FitError::TooFewPoints { points: x_mm.len(), needed });
    }
    Ok(())
}

/// Jacquelin's non-iterative estimate ([`jacquelin`]) of the plain sine
/// (model `sine`, one component), reported as a [`Fit`] without refinement:
/// `iterations` 0, `converged` true (nothing to converge), `start`
/// [`Start::Jacquelin`], and no uncertainties (the Jacobian formula holds at
/// the least-squares minimum, which this is not).
pub fn fit_jacquelin(x_mm: &[f64], z_mm: &[f64]) -> Result<Fit, FitError> {
    check_points(x_mm, z_mm, 5)?;
    let j = jacquelin(x_mm, z_mm).ok_or(FitError::Degenerate("Jacquelin's method found no oscillation"))?;
    let p = Params(vec![j.linear.offset, 0.0, j.linear.sin, j.linear.cos, j.omega]);
    let mut f = report(Model::Sine, x_mm.len(), &p, None, j.linear.rss, Start::Jacquelin, 0, true);
    f.method = FitMethod::Jacquelin;
    Ok(f)
}

/// `σ² (JᵀJ)⁻¹` at `p` on the original data, in the full parameter layout
/// (θ's row and column zero when it is not fitted). `None` if singular or not
/// finite.
fn covariance(x: &[f64], z: &[f64], p: &Params, fit_rotation: bool, sigma2: f64) -> Option<DMatrix<f64>> {
    let (_, j) = evaluate(x, z, p, fit_rotation, true)?;
    let inv = j.tr_mul(&j).cholesky()?.inverse() * sigma2;
    let skip = usize::from(!fit_rotation);
    let m = p.0.len();
    let mut full = DMatrix::zeros(m, m);
    for r in 0..inv.nrows() {
        for c in 0..inv.ncols() {
            full[(column_param(r, skip), column_param(c, skip))] = inv[(r, c)];
        }
    }
    full.iter().all(|v| v.is_finite()).then_some(full)
}

#[allow(clippy::too_many_arguments)]
fn report(
    model: Model,
    points: usize,
    p: &Params,
    cov: Option<&DMatrix<f64>>,
    rss: f64,
    start: Start,
    iterations: usize,
    converged: bool,
) -> Fit {
    let sigma = |grad: &[(usize, f64)]| -> Option<f64> {
        let cov = cov?;
        let mut v = 0.0;
        for &(i, gi) in grad {
            for &(j, gj) in grad {
                v += gi * gj * cov[(i, j)];
            }
        }
        (v >= 0.0 && v.is_finite()).then(|| v.sqrt())
    };
    let mut components: Vec<Component> = p
        .comps()
        .enumerate()
        .map(|(k, (a, b, w))| {
            let (ia, ib, iw) = (2 + 3 * k, 3 + 3 * k, 4 + 3 * k);
            let amp = a.hypot(b);
            let tau = std::f64::consts::TAU;
            Component {
                omega_rad_per_mm: w.abs(),
                wavelength_mm: tau / w.abs(),
                amplitude_mm: amp,
                phase_rad: b.atan2(a),
                sin_mm: a,
                cos_mm: b,
                wavelength_sigma_mm: sigma(&[(iw, tau / (w * w))]),
                amplitude_sigma_mm: (amp > 0.0).then(|| sigma(&[(ia, a / amp), (ib, b / amp)])).flatten(),
                phase_sigma_rad: (amp > 0.0).then(|| sigma(&[(ia, -b / (amp * amp)), (ib, a / (amp * amp))])).flatten(),
            }
        })
        .collect();
    components.sort_by(|a, b| b.amplitude_mm.total_cmp(&a.amplitude_mm));
    let d = &components[0];
    Fit {
        model,
        method: FitMethod::Lsq,
        points,
        wavelength_mm: d.wavelength_mm,
        amplitude_mm: d.amplitude_mm,
        phase_rad: d.phase_rad,
        offset_mm: p.0[0],
        rotation_rad: p.0[1],
        rms_residual_mm: (rss / points as f64).sqrt(),
        wavelength_sigma_mm: d.wavelength_sigma_mm,
        amplitude_sigma_mm: d.amplitude_sigma_mm,
        phase_sigma_rad: d.phase_sigma_rad,
        offset_sigma_mm: sigma(&[(0, 1.0)]),
        rotation_sigma_rad: if model == Model::Rotated { sigma(&[(1, 1.0)]) } else { None },
        components,
        start,
        iterations,
        converged,
    }
}
