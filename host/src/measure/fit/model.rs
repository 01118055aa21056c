//! The exact (rotated) sine model, its residuals and Jacobian, and its Levenberg–Marquardt refinement.

use super::MAX_ITERATIONS;
use crate::model::lm;
use nalgebra::{DMatrix, DVector};

/// Parameters `[c, θ, a_1, b_1, ω_1, a_2, …]`.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Params(pub(super) Vec<f64>);

impl Params {
    pub(super) fn comps(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        self.0[2..].chunks_exact(3).map(|c| (c[0], c[1], c[2]))
    }
}

/// Residuals `z − ẑ(x)` and, if `jac`, their Jacobian (columns: the free
/// parameters, θ left out when `fit_rotation` is false). `None` where the
/// model is not single-valued in z.
pub(super) fn evaluate(
    x: &[f64],
    z: &[f64],
    p: &Params,
    fit_rotation: bool,
    jac: bool,
) -> Option<(DVector<f64>, DMatrix<f64>)> {
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
pub(super) fn column_param(k: usize, skip: usize) -> usize {
    if k == 0 { 0 } else { k + skip }
}

/// Outcome of the Levenberg–Marquardt refinement.
pub(super) struct Refined {
    pub(super) p: Params,
    pub(super) rss: f64,
    pub(super) iterations: usize,
    pub(super) converged: bool,
}

/// Levenberg–Marquardt on the model of [`evaluate`].
pub(super) fn refine(x: &[f64], z: &[f64], p0: Params, fit_rotation: bool) -> Option<Refined> {
    let free: Vec<usize> = (0..p0.0.len()).filter(|&i| fit_rotation || i != 1).collect();
    let mut problem = lm::WithJacobian::new(|p: &[f64]| evaluate(x, z, &Params(p.to_vec()), fit_rotation, true));
    lm::levenberg_marquardt(p0.0, &free, MAX_ITERATIONS, &mut problem).map(|o| Refined {
        p: Params(o.p),
        rss: o.rss,
        iterations: o.iterations,
        converged: o.converged,
    })
}
