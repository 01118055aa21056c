//! IEEE 1057 three- and four-parameter sine fits at a known or refined ω.

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

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
/// `ω += Δω`. No safeguard: it may wander off or diverge (that is why [`fit`](super::fit)
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
