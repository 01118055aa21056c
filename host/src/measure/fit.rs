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

use std::fmt;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix4, Vector3, Vector4};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;
use serde::Serialize;

use crate::model::lm;

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
// IEEE 1057 three- and four-parameter fits

/// Result of the linear (three-parameter) fit at a known ω.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linear {
    /// Sine coefficient a.
    pub sin: f64,
    /// Cosine coefficient b.
    pub cos: f64,
    /// Offset c.
    pub offset: f64,
    /// Residual sum of squares.
    pub rss: f64,
}

/// IEEE 1057 three-parameter fit: linear least squares of
/// `z ≈ a sin ωx + b cos ωx + c`. `None` if the normal equations are singular
/// (ω so low that cos ωx is constant on the data, or fewer than 3 points).
pub fn three_param(x: &[f64], z: &[f64], omega: f64) -> Option<Linear> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    // The sines once (they are most of the cost); the residual is summed
    // from them, not as z·z − p·Aᵀz, which cancels on a near-exact fit.
    let sc: Vec<(f64, f64)> = x.iter().map(|&x| (omega * x).sin_cos()).collect();
    for (&(s, c), &z) in sc.iter().zip(z) {
        let row = Vector3::new(s, c, 1.0);
        ata += row * row.transpose();
        atb += row * z;
    }
    let sol = ata.cholesky()?.solve(&atb);
    let rss = sc.iter().zip(z).map(|(&(s, c), &z)| (z - sol[0] * s - sol[1] * c - sol[2]).powi(2)).sum::<f64>();
    (rss.is_finite() && sol.iter().all(|v| v.is_finite())).then_some(Linear {
        sin: sol[0],
        cos: sol[1],
        offset: sol[2],
        rss,
    })
}

/// Result of the plain IEEE 1057 four-parameter iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FourParam {
    /// Final ω (rad per unit of x).
    pub omega: f64,
    /// Linear parameters and residual at the final ω.
    pub linear: Linear,
    /// Iterations made.
    pub iterations: usize,
    /// Whether the ω update fell below 1e-10 relative before the limit.
    pub converged: bool,
}

/// The plain IEEE 1057 four-parameter iteration from `omega0`: at each step,
/// linear least squares on `[sin ωx, cos ωx, 1, x(a cos ωx − b sin ωx)]`, then
/// `ω += Δω`. No safeguard: it may wander off or diverge (that is why [`fit`]
/// keeps a fallback). `None` if it breaks down (singular system, ω ≤ 0 or not
/// finite).
pub fn four_param_ieee(x: &[f64], z: &[f64], omega0: f64, max_iterations: usize) -> Option<FourParam> {
    let mut omega = omega0;
    let mut lin = three_param(x, z, omega)?;
    for it in 1..=max_iterations {
        let mut ata = Matrix4::zeros();
        let mut atb = Vector4::zeros();
        for (&x, &z) in x.iter().zip(z) {
            let (s, c) = (omega * x).sin_cos();
            let row = Vector4::new(s, c, 1.0, x * (lin.sin * c - lin.cos * s));
            ata += row * row.transpose();
            atb += row * z;
        }
        let sol = ata.cholesky()?.solve(&atb);
        let step = sol[3];
        omega += step;
        if !omega.is_finite() || omega <= 0.0 {
            return None;
        }
        lin = three_param(x, z, omega)?;
        if step.abs() <= 1e-10 * omega {
            return Some(FourParam { omega, linear: lin, iterations: it, converged: true });
        }
    }
    Some(FourParam { omega, linear: lin, iterations: max_iterations, converged: false })
}

// ---------------------------------------------------------------------------
// Jacquelin's non-iterative sinusoidal regression

/// The result of [`jacquelin`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jacquelin {
    /// ω₁, from the integral equation (first step).
    pub omega1: f64,
    /// ω₂, from the linearised arcsine ("sawtooth") regression (second step):
    /// the method's estimate of ω.
    pub omega: f64,
    /// The three-parameter fit at ω₂ (third step).
    pub linear: Linear,
}

/// Jacquelin's non-iterative sinusoidal regression ("Régressions et
/// équations intégrales", 2009, the chapter on sinusoids) of
/// `z ≈ c + a sin ωx + b cos ωx`, in three linear steps, no iteration:
///
/// 1. **Integral equation.** A sinusoid solves
///    `z(x) = −ω² ∬ z + P₂(x)` (P₂ a quadratic), so with the cumulative
///    trapezoidal integrals `S_k = S_{k−1} + ½(z_k + z_{k−1})(x_k − x_{k−1})`,
///    `SS_k` likewise of S (points sorted by x), the linear least squares
///    `z_k ≈ A·SS_k + B x_k² + C x_k + D` gives `ω₁ = √−A`, and the offset and
///    coefficients follow from A…D.
/// 2. **Sawtooth.** With `ρ₁ = √(a₁² + b₁²)` and `φ₁ = atan2(b₁, a₁)` (a₁, b₁
///    the sine and cosine coefficients, c₁ the offset), each
///    point's phase is unwrapped: `K_k = round((ω₁x_k + φ₁)/π)`,
///    `θ_k = (−1)^K_k · arcsin((z_k − c₁)/ρ₁) + πK_k` (clamped at ±π/2), and
///    the straight line `θ_k ≈ ω₂x_k + φ₂` gives ω₂.
/// 3. The three-parameter fit ([`three_param`]) at ω₂.
///
/// ω₂ is *not* the least-squares ω (the residual is generally lower nearby;
/// [`fit`] uses it as one more start value and refines). On the public test
/// vector of docs/reference.md §3 it gives ω = 2.02074, offset −0.405617, coefficients
/// 1.27520 and −0.577491. Its weakness is step 1's numerical integration: it
/// needs several points per period (ω₁ is biased by about 1/n² at n points
/// per period on uniform data), which step 2 largely removes.
///
/// The steps run on x centred and scaled to [−1, 1] (the integral equation is
/// invariant under that, and x⁴ of raw millimetres would be ill-conditioned).
/// `None` when A ≥ 0 (no oscillation found), for fewer than 5 points, or when
/// a system is singular. Cost O(n log n) (the sort).
pub fn jacquelin(x: &[f64], z: &[f64]) -> Option<Jacquelin> {
    if x.len() != z.len() || x.len() < 5 {
        return None;
    }
    let mut pts: Vec<(f64, f64)> = x.iter().copied().zip(z.iter().copied()).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (lo, hi) = (pts[0].0, pts[pts.len() - 1].0);
    let (mid, half) = (lo / 2.0 + hi / 2.0, hi / 2.0 - lo / 2.0);
    if !(half > 0.0 && half.is_finite()) {
        return None;
    }
    let t: Vec<f64> = pts.iter().map(|p| (p.0 - mid) / half).collect();
    let y: Vec<f64> = pts.iter().map(|p| p.1).collect();
    // Step 1: the integral equation.
    let (mut s, mut ss) = (0.0, 0.0);
    let mut ata = Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for k in 0..t.len() {
        if k > 0 {
            let dt = t[k] - t[k - 1];
            let s_next = s + 0.5 * (y[k] + y[k - 1]) * dt;
            ss += 0.5 * (s_next + s) * dt;
            s = s_next;
        }
        let row = Vector4::new(ss, t[k] * t[k], t[k], 1.0);
        ata += row * row.transpose();
        atb += row * y[k];
    }
    let sol = ata.lu().solve(&atb)?;
    let (a_, b_, c_, d_) = (sol[0], sol[1], sol[2], sol[3]);
    if a_.partial_cmp(&0.0) != Some(std::cmp::Ordering::Less) {
        return None;
    }
    let w1 = (-a_).sqrt();
    let offset1 = 2.0 * b_ / (w1 * w1);
    let t1 = t[0];
    let p = b_ * t1 * t1 + c_ * t1 + d_ - offset1;
    let q = (c_ + 2.0 * b_ * t1) / w1;
    let (st, ct) = (w1 * t1).sin_cos();
    let (sin1, cos1) = (p * st + q * ct, p * ct - q * st);
    // Step 2: the sawtooth made straight.
    let rho = sin1.hypot(cos1);
    let phi = cos1.atan2(sin1);
    if !(rho > 0.0 && rho.is_finite() && offset1.is_finite()) {
        return None;
    }
    let theta: Vec<f64> = t
        .iter()
        .zip(&y)
        .map(|(&t, &y)| {
            let k = ((w1 * t + phi) / std::f64::consts::PI).round();
            let u = (y - offset1) / rho;
            let base = if u.abs() < 1.0 { u.asin() } else { std::f64::consts::FRAC_PI_2.copysign(u) };
            let sign = if k.rem_euclid(2.0) == 0.0 { 1.0 } else { -1.0 };
            sign * base + std::f64::consts::PI * k
        })
        .collect();
    let (w2, _) = line_fit(&t, &theta)?;
    let omega = w2.abs() / half;
    // Step 3: the three-parameter fit on the original data.
    let linear = three_param(x, z, omega)?;
    (omega.is_finite() && omega > 0.0).then_some(Jacquelin { omega1: w1 / half, omega, linear })
}

// ---------------------------------------------------------------------------
// Start values of ω

/// The profile resampled on a uniform grid over its x span (linear
/// interpolation between x-sorted points): `(x0, dx, values)`.
fn resample(x: &[f64], z: &[f64]) -> Option<(f64, f64, Vec<f64>)> {
    resample_to(x, z, MAX_RESAMPLED)
}

/// [`resample`] on at most `cap` samples.
fn resample_to(x: &[f64], z: &[f64], cap: usize) -> Option<(f64, f64, Vec<f64>)> {
    let mut pts: Vec<(f64, f64)> = x.iter().copied().zip(z.iter().copied()).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (x0, x1) = (pts.first()?.0, pts.last()?.0);
    let m = pts.len().clamp(2, cap.max(2));
    let dx = (x1 - x0) / (m - 1) as f64;
    if !(dx > 0.0 && dx.is_finite()) {
        return None;
    }
    let mut out = Vec::with_capacity(m);
    let mut j = 0;
    for i in 0..m {
        let t = x0 + dx * i as f64;
        while j + 2 < pts.len() && pts[j + 1].0 < t {
            j += 1;
        }
        let (a, b) = (pts[j], pts[(j + 1).min(pts.len() - 1)]);
        let w = if b.0 > a.0 { ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0) } else { 0.0 };
        out.push(a.1 + w * (b.1 - a.1));
    }
    Some((x0, dx, out))
}

/// Slope and intercept of the least-squares straight line.
fn line_fit(x: &[f64], z: &[f64]) -> Option<(f64, f64)> {
    let n = x.len() as f64;
    let (mx, mz) = (x.iter().sum::<f64>() / n, z.iter().sum::<f64>() / n);
    let sxx: f64 = x.iter().map(|x| (x - mx).powi(2)).sum();
    let sxz: f64 = x.iter().zip(z).map(|(x, z)| (x - mx) * (z - mz)).sum();
    let slope = sxz / sxx;
    (slope.is_finite() && sxx > 0.0).then_some((slope, mz - slope * mx))
}

/// ω at the interpolated peak of the DFT magnitude of the detrended,
/// uniformly resampled profile (zero-padded ×8: bins of `2π/(8·span)`),
/// over wavelengths from two samples up to twice the span.
pub fn dft_omega(x: &[f64], z: &[f64]) -> Option<f64> {
    let (_, dx, mut v) = resample(x, z)?;
    let t: Vec<f64> = (0..v.len()).map(|i| i as f64).collect();
    let (slope, icpt) = line_fit(&t, &v)?;
    for (i, v) in v.iter_mut().enumerate() {
        *v -= icpt + slope * i as f64;
    }
    let m = v.len() as f64;
    // Zero-padded ×8: bin j of the 8M-point FFT is j/8 cycles per record;
    // bins 4..=4M are 0.5 .. M/2 cycles per record in steps of 1/8.
    let len = 8 * v.len();
    let mut buf = vec![Complex::new(0.0, 0.0); len];
    for (b, &v) in buf.iter_mut().zip(&v) {
        b.re = v;
    }
    FftPlanner::<f64>::new().plan_fft_forward(len).process(&mut buf);
    let bins: Vec<f64> = (4..=(4 * v.len())).map(|j| j as f64 / 8.0).collect();
    let mag: Vec<f64> = buf[4..=(4 * v.len())].iter().map(|c| c.norm()).collect();
    let k = (0..mag.len()).max_by(|&a, &b| mag[a].total_cmp(&mag[b]))?;
    let mut f = bins[k];
    if k > 0 && k + 1 < mag.len() {
        let (a, b, c) = (mag[k - 1], mag[k], mag[k + 1]);
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            f += 0.5 * (a - c) / den / 8.0;
        }
    }
    let omega = 2.0 * std::f64::consts::PI * f / (m * dx);
    (omega.is_finite() && omega > 0.0).then_some(omega)
}

/// The paper's ellipse method (docs/reference.md §3): on the uniformly resampled,
/// differenced profile `d[n] = y[n+k] − y[n]` (which removes the rotation's
/// trend), the points `(d[n], d[n+k])` lie on the ellipse
/// `u² − 2uv·cos(ωk) + v² = const`; a linear least-squares fit of that
/// symmetric conic (with a free centre) gives `cos(ωk)`. The lag k is the sample count
/// nearest a quarter of the wavelength `2π/omega_prior`, kept below half of
/// it (where `acos` is unambiguous).
pub fn ellipse_omega(x: &[f64], z: &[f64], omega_prior: f64) -> Option<f64> {
    let (_, dx, v) = resample(x, z)?;
    let quarter = std::f64::consts::FRAC_PI_2 / omega_prior / dx;
    let k = (quarter.round() as usize).max(1);
    if !(quarter.is_finite() && (k as f64) < 2.0 * quarter) || v.len() < 2 * k + 6 {
        return None;
    }
    let d: Vec<f64> = (0..v.len() - k).map(|n| v[n + k] - v[n]).collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let scale = d.iter().map(|d| (d - mean).abs()).fold(0.0, f64::max);
    if scale.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    // Both axes carry the same sinusoid, so the conic is symmetric:
    // u² + v² = 2C·uv + E·u + F·v + G, linear in (C, E, F, G), C = cos ωk.
    let mut ata = Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for n in 0..d.len() - k {
        let (u, w) = ((d[n] - mean) / scale, (d[n + k] - mean) / scale);
        let row = Vector4::new(2.0 * u * w, u, w, 1.0);
        ata += row * row.transpose();
        atb += row * (u * u + w * w);
    }
    let cos_wk = ata.cholesky()?.solve(&atb)[0];
    if !cos_wk.is_finite() || cos_wk.abs() >= 1.0 {
        return None;
    }
    let omega = cos_wk.acos() / (k as f64 * dx);
    (omega.is_finite() && omega > 0.0).then_some(omega)
}

/// The fallback that cannot diverge: the three-parameter residual `S(ω)`
/// at every bin of the ×8 zero-padded spectrum (steps of `2π/(8·span)`)
/// over `[omega_lo, omega_hi]`, then golden-section search of
/// [`three_param`] on the points themselves in the bracket around the best
/// of the three deepest minima. Returns `(ω, S(ω))`.
///
/// `S(ω)` on the grid is exact for the profile resampled uniformly (on as
/// many samples as it has points, up to 2^20): with `t = i·dx` every sum
/// the normal equations need is a DFT bin (`Σ z e^{−iωt}`, one FFT for all
/// of them) or a geometric series (`Σ e^{−iωt}`, `Σ e^{−2iωt}`), so the
/// whole scan costs one FFT of 8 × the points and a 3 × 3 solve per bin,
/// not one pass over the points per grid step: 10⁶ points in well under a
/// second, where evaluating [`three_param`] on 4 096 grid steps took 95 s
/// (and under-resolved the grid besides). Points that are not evenly
/// spaced are interpolated for the grid only; the three candidates are
/// judged, and the minimum refined, on the points.
pub fn scan_omega(x: &[f64], z: &[f64], omega_lo: f64, omega_hi: f64) -> Option<(f64, f64)> {
    let (lo_x, hi_x) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let span = hi_x - lo_x;
    if !(span > 0.0 && omega_hi > omega_lo && omega_lo > 0.0) {
        return None;
    }
    let (_, dx, v) = resample_to(x, z, MAX_SCAN_RESAMPLED)?;
    let m = v.len();
    let len = 8 * m;
    let mut buf = vec![Complex::new(0.0, 0.0); len];
    for (b, &v) in buf.iter_mut().zip(&v) {
        b.re = v;
    }
    FftPlanner::<f64>::new().plan_fft_forward(len).process(&mut buf);
    let (zsum, zz) = (v.iter().sum::<f64>(), v.iter().map(|v| v * v).sum::<f64>());
    let mf = m as f64;
    // Σ_{i<m} e^{iθi}, with the θ → 0 (mod 2π) limit.
    let geometric = |theta: f64| -> Complex<f64> {
        let one = Complex::new(1.0, 0.0);
        let den = one - Complex::from_polar(1.0, theta);
        if den.norm() < 1e-12 { Complex::new(mf, 0.0) } else { (one - Complex::from_polar(1.0, theta * mf)) / den }
    };
    let omega_of = |j: usize| std::f64::consts::TAU * j as f64 / (len as f64 * dx);
    let j_lo = ((omega_lo / omega_of(1)).ceil() as usize).max(1);
    let j_hi = ((omega_hi / omega_of(1)).floor() as usize).min(len / 2);
    if j_lo > j_hi {
        return None;
    }
    // S at bin j: z·z − p·(Aᵀz), (AᵀA) p = Aᵀz with A = [sin ωt, cos ωt, 1].
    let s_at = |j: usize| -> f64 {
        let theta = std::f64::consts::TAU * j as f64 / len as f64;
        let (g1, g2) = (geometric(theta), geometric(2.0 * theta));
        let (sum_c, sum_s) = (g1.re, g1.im);
        let (ss, cc, sc) = (0.5 * (mf - g2.re), 0.5 * (mf + g2.re), 0.5 * g2.im);
        // buf[j] = Σ z e^{−iθi}: Σ z cos = re, Σ z sin = −im.
        let (zc, zs) = (buf[j].re, -buf[j].im);
        let ata = Matrix3::new(ss, sc, sum_s, sc, cc, sum_c, sum_s, sum_c, mf);
        let atb = Vector3::new(zs, zc, zsum);
        ata.cholesky().map_or(f64::INFINITY, |c| zz - c.solve(&atb).dot(&atb))
    };
    let s: Vec<f64> = (j_lo..=j_hi).map(s_at).collect();
    // The three deepest local minima of the grid.
    let mut minima: Vec<usize> = (0..s.len())
        .filter(|&i| s[i].is_finite() && (i == 0 || s[i] <= s[i - 1]) && (i + 1 == s.len() || s[i] <= s[i + 1]))
        .collect();
    minima.sort_by(|&a, &b| s[a].total_cmp(&s[b]));
    minima.truncate(3);
    let rss = |w: f64| three_param(x, z, w).map_or(f64::INFINITY, |l| l.rss);
    let clamp = |w: f64| w.clamp(omega_lo, omega_hi);
    let (best_w, best_s) =
        minima.iter().map(|&i| (omega_of(j_lo + i), rss(omega_of(j_lo + i)))).min_by(|p, q| p.1.total_cmp(&q.1))?;
    if !best_s.is_finite() {
        return None;
    }
    let step = omega_of(1);
    let (mut a, mut b) = (clamp(best_w - step), clamp(best_w + step));
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (rss(c), rss(d));
    while b - a > 1e-13 * b.abs() + f64::MIN_POSITIVE {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = rss(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = rss(d);
        }
    }
    let w = 0.5 * (a + b);
    [(w, rss(w)), (best_w, best_s)].into_iter().min_by(|p, q| p.1.total_cmp(&q.1))
}

/// The best start of one sine on `(x, z)`: IEEE iterations from the DFT and
/// ellipse estimates and the fallback scan; the lowest three-parameter
/// residual wins.
fn sine_start(x: &[f64], z: &[f64]) -> Option<(f64, Linear, Start)> {
    let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let span = hi - lo;
    let band = (std::f64::consts::PI / span, std::f64::consts::PI * (x.len() - 1) as f64 / span);
    let in_band = |w: f64| w >= band.0 * (1.0 - 1e-9) && w <= band.1 * (1.0 + 1e-9);
    let dft = dft_omega(x, z);
    let ellipse = dft.and_then(|w| ellipse_omega(x, z, w));
    let jacq = jacquelin(x, z);
    let mut best: Option<(f64, Linear, Start)> = None;
    let mut consider = |w: f64, lin: Linear, start: Start| {
        if best.as_ref().is_none_or(|b| lin.rss < b.1.rss) {
            best = Some((w, lin, start));
        }
    };
    if let Some(j) = jacq
        && in_band(j.omega)
    {
        consider(j.omega, j.linear, Start::Jacquelin);
    }
    for (w0, start) in [(dft, Start::Dft), (ellipse, Start::Ellipse), (jacq.map(|j| j.omega), Start::Jacquelin)] {
        if let Some(r) = w0.and_then(|w0| four_param_ieee(x, z, w0, IEEE_MAX_ITERATIONS))
            && r.converged
            && in_band(r.omega)
        {
            consider(r.omega, r.linear, start);
        }
    }
    if let Some((w, _)) = scan_omega(x, z, band.0, band.1)
        && let Some(lin) = three_param(x, z, w)
    {
        consider(w, lin, Start::Scan);
    }
    best
}

// ---------------------------------------------------------------------------
// The exact (rotated) model and Levenberg–Marquardt

/// Parameters `[c, θ, a_1, b_1, ω_1, a_2, …]`.
#[derive(Debug, Clone, PartialEq)]
struct Params(Vec<f64>);

impl Params {
    fn comps(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        self.0[2..].chunks_exact(3).map(|c| (c[0], c[1], c[2]))
    }
}

/// Residuals `z − ẑ(x)` and, if `jac`, their Jacobian (columns: the free
/// parameters, θ left out when `fit_rotation` is false). `None` where the
/// model is not single-valued in z.
fn evaluate(x: &[f64], z: &[f64], p: &Params, fit_rotation: bool, jac: bool) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let (c0, theta) = (p.0[0], p.0[1]);
    let (si, co) = theta.sin_cos();
    let amp_sum: f64 = p.comps().map(|(a, b, _)| a.hypot(b)).sum();
    let slope_sum: f64 = p.comps().map(|(a, b, w)| a.hypot(b) * w.abs()).sum();
    if !(co > 0.0 && si.abs() * slope_sum < co * (1.0 - 1e-9) && amp_sum.is_finite()) {
        return None;
    }
    let h = |xr: f64| -> (f64, f64) {
        // (h(x'), h'(x'))
        p.comps().fold((c0, 0.0), |(v, d), (a, b, w)| {
            let (s, c) = (w * xr).sin_cos();
            (v + a * s + b * c, d + w * (a * c - b * s))
        })
    };
    let skip = usize::from(!fit_rotation);
    let cols = p.0.len() - skip;
    let mut r = DVector::zeros(x.len());
    let mut j = DMatrix::zeros(if jac { x.len() } else { 0 }, cols);
    for (i, (&x, &zm)) in x.iter().zip(z).enumerate() {
        // Safeguarded Newton on g(z) = −x sinθ + z cosθ − h(x cosθ + z sinθ),
        // increasing in z, bracketed by (x sinθ + c ± Σ A)/cosθ.
        let (mut lo, mut hi) = ((x * si + c0 - amp_sum) / co, (x * si + c0 + amp_sum) / co);
        let mut zh = zm.clamp(lo, hi);
        for _ in 0..60 {
            let (hv, hd) = h(x * co + zh * si);
            let g = -x * si + zh * co - hv;
            let gz = co - si * hd;
            if g == 0.0 {
                break;
            } else if g > 0.0 {
                hi = zh;
            } else {
                lo = zh;
            }
            let mut next = zh - g / gz;
            if !(next >= lo && next <= hi) {
                next = 0.5 * (lo + hi);
            }
            let done = (next - zh).abs() <= 1e-15 * (1.0 + zh.abs());
            zh = next;
            if done {
                break;
            }
        }
        r[i] = zm - zh;
        if jac {
            let xr = x * co + zh * si;
            let zr = -x * si + zh * co;
            let (_, hd) = h(xr);
            let gz = co - si * hd;
            // dr/dp = (∂g/∂p)/(∂g/∂z), from ẑ's implicit definition.
            j[(i, 0)] = -1.0 / gz;
            if fit_rotation {
                j[(i, 1)] = (-xr - hd * zr) / gz;
            }
            for (k, (a, b, w)) in p.comps().enumerate() {
                let (s, c) = (w * xr).sin_cos();
                let col = 2 - skip + 3 * k;
                j[(i, col)] = -s / gz;
                j[(i, col + 1)] = -c / gz;
                j[(i, col + 2)] = -xr * (a * c - b * s) / gz;
            }
        }
    }
    (r.iter().all(|v| v.is_finite()) && j.iter().all(|v| v.is_finite())).then_some((r, j))
}

/// The parameter index of Jacobian column `k` (θ's column is left out when
/// `skip` is 1).
fn column_param(k: usize, skip: usize) -> usize {
    if k == 0 { 0 } else { k + skip }
}

/// Outcome of the Levenberg–Marquardt refinement.
struct Refined {
    p: Params,
    rss: f64,
    iterations: usize,
    converged: bool,
}

/// Levenberg–Marquardt on the model of [`evaluate`].
fn refine(x: &[f64], z: &[f64], p0: Params, fit_rotation: bool) -> Option<Refined> {
    let free: Vec<usize> = (0..p0.0.len()).filter(|&i| fit_rotation || i != 1).collect();
    let mut problem = lm::WithJacobian::new(|p: &[f64]| evaluate(x, z, &Params(p.to_vec()), fit_rotation, true));
    lm::levenberg_marquardt(p0.0, &free, MAX_ITERATIONS, &mut problem).map(|o| Refined {
        p: Params(o.p),
        rss: o.rss,
        iterations: o.iterations,
        converged: o.converged,
    })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn synth(lambda: f64, amp: f64, phase: f64, c: f64, theta: f64, n: usize, dx: f64) -> (Vec<f64>, Vec<f64>) {
        // Exact rotated sine, points taken along x' then rotated back.
        let w = std::f64::consts::TAU / lambda;
        let (si, co) = theta.sin_cos();
        (0..n)
            .map(|i| {
                let xr = 10.0 + dx * i as f64;
                let zr = amp * (w * xr + phase).sin() + c;
                (xr * co - zr * si, xr * si + zr * co)
            })
            .unzip()
    }

    #[test]
    fn three_param_is_exact_on_a_noiseless_sine() {
        let x: Vec<f64> = (0..50).map(|i| i as f64 * 0.3).collect();
        let z: Vec<f64> = x.iter().map(|x| 2.0 * (0.7 * x).sin() - 0.5 * (0.7 * x).cos() + 1.0).collect();
        let l = three_param(&x, &z, 0.7).unwrap();
        assert!((l.sin - 2.0).abs() < 1e-12 && (l.cos + 0.5).abs() < 1e-12 && (l.offset - 1.0).abs() < 1e-12);
        assert!(l.rss < 1e-20);
    }

    #[test]
    fn start_estimates_are_close_on_a_rotated_profile() {
        let (x, z) = synth(50.0, 0.1, 0.3, 0.0, 0.02, 300, 1.0);
        let w = std::f64::consts::TAU / 50.0;
        let dft = dft_omega(&x, &z).unwrap();
        assert!((dft / w - 1.0).abs() < 0.02, "dft {dft} vs {w}");
        let ell = ellipse_omega(&x, &z, dft).unwrap();
        assert!((ell / w - 1.0).abs() < 0.02, "ellipse {ell} vs {w}");
        // The scan on a trend would fit the trend: on the level profile.
        let (x, z) = synth(50.0, 0.1, 0.3, 0.0, 0.0, 300, 1.0);
        let (scan, _) = scan_omega(&x, &z, 0.01, 3.0).unwrap();
        assert!((scan / w - 1.0).abs() < 0.01, "scan {scan} vs {w}");
    }

    /// A short wavelength in a long record: its minimum of `S(ω)` is
    /// 2π/span wide, under a twentieth of the 4 096-step grid the scan once
    /// had for 20 000 points up to the Nyquist limit; every bin finds it,
    /// on evenly and unevenly spaced points alike.
    #[test]
    fn the_scan_resolves_a_short_wavelength_in_a_long_record() {
        let w = std::f64::consts::TAU / 0.537;
        for jitter in [0.0, 0.3] {
            let mut state = 0x9e37_79b9_7f4a_7c15u64;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            let x: Vec<f64> = (0..20_000).map(|i| 0.01 * (i as f64 + jitter * next())).collect();
            let z: Vec<f64> = x.iter().map(|&x| 0.02 * (w * x + 0.4).sin() + 0.001 * next()).collect();
            let band = (std::f64::consts::PI / 200.0, std::f64::consts::PI * 19_999.0 / 200.0);
            let (scan, _) = scan_omega(&x, &z, band.0, band.1).unwrap();
            assert!((scan / w - 1.0).abs() < 1e-4, "jitter {jitter}: scan {scan} vs {w}");
        }
    }

    #[test]
    fn jacquelin_is_close_on_a_sampled_sine() {
        // 50 points per period, uniform; step 2 removes most of step 1's
        // integration bias.
        let x: Vec<f64> = (0..300).map(|i| 3.0 + i as f64).collect();
        let w = std::f64::consts::TAU / 50.0;
        let z: Vec<f64> = x.iter().map(|x| 0.1 * (w * x + 0.4).sin() + 2.0).collect();
        let j = jacquelin(&x, &z).unwrap();
        assert!((j.omega / w - 1.0).abs() < 1e-3, "{j:?}");
        assert!((j.linear.offset - 2.0).abs() < 1e-3 && (j.linear.sin.hypot(j.linear.cos) - 0.1).abs() < 1e-3);
        // No oscillation: a straight line gives none or an error, never a panic.
        let line: Vec<f64> = x.iter().map(|x| 0.5 * x).collect();
        if let Some(j) = jacquelin(&x, &line) {
            assert!(j.omega.is_finite());
        }
        assert!(jacquelin(&x[..4], &z[..4]).is_none());
    }

    #[test]
    fn rotated_fit_is_exact_on_exact_data() {
        let (x, z) = synth(100.0, 0.08, 1.0, 0.5, 0.05, 350, 0.9);
        let f = fit(&x, &z, &Options::default()).unwrap();
        assert!(f.converged);
        assert!((f.wavelength_mm - 100.0).abs() < 1e-8, "{f:?}");
        assert!((f.amplitude_mm - 0.08).abs() < 1e-10, "{f:?}");
        assert!((f.rotation_rad - 0.05).abs() < 1e-10, "{f:?}");
        assert!((f.offset_mm - 0.5).abs() < 1e-9, "{f:?}");
        assert!((f.phase_rad - 1.0).abs() < 1e-7, "{f:?}");
    }

    #[test]
    fn two_components() {
        let x: Vec<f64> = (0..400).map(|i| i as f64).collect();
        let tau = std::f64::consts::TAU;
        let z: Vec<f64> =
            x.iter().map(|x| 0.1 * (tau * x / 50.0).sin() + 0.04 * (tau * x / 130.0 + 0.4).cos() + 0.01 * x).collect();
        let f = fit(&x, &z, &Options { model: Model::Rotated, components: 2 }).unwrap();
        assert!(f.converged);
        // 50 mm along x is 50·(cosθ + 0.01·sinθ) ≈ 50.0025 mm along the
        // rotated axis: a slope is a shear, not a rotation.
        assert!((f.components[0].wavelength_mm - 50.0025).abs() < 1e-3, "{f:?}");
        assert!((f.components[1].wavelength_mm - 130.0).abs() < 1e-2, "{f:?}");
        // A plain slope is only approximately a rotation: the exact model
        // still has to fit it to the noise-free level.
        assert!(f.rms_residual_mm < 1e-3, "{f:?}");
    }

    #[test]
    fn parser() {
        let p = parse_profile("x_mm,z_mm\r\n1, 2\n\n# c\n3,4.5\n").unwrap();
        assert_eq!(p.x_mm, [1.0, 3.0]);
        assert_eq!(p.z_mm, [2.0, 4.5]);
        assert_eq!(
            parse_profile("1,2\n3,x\n"),
            Err(FitError::Line { line: 2, reason: "`x` is not a finite number".into() })
        );
        assert!(matches!(parse_profile("1,2,3"), Err(FitError::Line { line: 1, .. })));
        assert!(matches!(parse_profile("1,2\nx_mm,z_mm"), Err(FitError::Line { line: 2, .. })));
        assert!(matches!(parse_profile("1,inf"), Err(FitError::Line { line: 1, .. })));
    }
}
