//! Jacquelin's non-iterative sinusoidal regression (integral equations).

use super::{Linear, line_fit, three_param};
use nalgebra::{Matrix4, Vector4};

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
/// [`fit`](super::fit) uses it as one more start value and refines). On the public test
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
