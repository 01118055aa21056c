//! The host's nonlinear least-squares solver: Levenberg–Marquardt with
//! Marquardt's diagonal scaling, for the sine fits ([`crate::measure::fit`], the joint
//! fit of [`crate::measure::corrugation`]) and camera calibration
//! ([`crate::calib::camera`]).
//!
//! **The rule.** Solve `(JᵀJ + μ·diag(JᵀJ)) δ = −Jᵀr` by Cholesky (the
//! diagonal floored at `10⁻¹⁵·max diag` so a parameter the data do not
//! constrain cannot make it singular); accept the step only if it lowers
//! `|r|²` (then `μ ÷ 3`, down to 10⁻¹²), otherwise reject it (`μ × 4`). So it
//! cannot diverge; a model that is undefined at the trial point (the
//! problem's `residuals` returns `None`, e.g. the rotated sine where it is
//! not single-valued) is a rejected step, not a failure. Marquardt's scaling
//! makes the step invariant to each parameter's units (pixels and
//! distortion coefficients, millimetres and radians). It stops when a step
//! changes every parameter by less than 10⁻¹¹ of its size or lowers `|r|²`
//! by less than 10⁻¹⁴ of it, or — at the minimum, where round-off rejects
//! every step — when the gradient is negligible.
//!
//! **Why not the `levenberg-marquardt` crate.** It is MINPACK's `lmder`
//! (Moré's trust region), a sound solver, but (a) it ends the whole
//! minimisation with `User("residuals")` the first time the residuals are
//! undefined at a trial point, which the rotated sine fit needs to survive;
//! (b) its different step rule would move every figure the fits print —
//! `cms-host fit` prints its parameters and iteration count, the joint fit
//! of `corrugation` its F test on two nested fits — where this solver
//! leaves them bit-identical; (c) it needs nalgebra 0.34 (the host is on
//! 0.33, so it also brings an upgrade).
//!
//! **One rule for both.** This is the solver `fit` had, made generic.
//! Calibration had its own (λ ×10 / ÷10, one Jacobian per outer step, its
//! own stopping test); on this one it reaches the same minimum. Measured on
//! the calibration tests (release, 2 loaded cores): OpenCV's 13 photographs
//! fx, fy, cx, cy and the RMS unchanged to the printed digit, k3 0.09300 →
//! 0.09301; 15 trial steps where the old counted 8 outer steps, the solve
//! ~30 ms longer (~60 ms); the 24-view simulated calibration unchanged to the
//! printed digit (intrinsics −0.0022 %, +0.0005 %, −0.0208 %, +0.0544 %) and
//! its test no slower (≈5.0 s against 5.2 s), because JᵀJ is formed only
//! after an accepted step; the synthetic renders' fx moves by 6·10⁻⁸ px.
//!
//! **Cost.** Per iteration one Jacobian (`m × n`), `JᵀJ` (`O(m·n²)`) and one
//! Cholesky (`O(n³)`) per trial; dense throughout, which is right for the
//! fits (n ≤ 20) and for calibration up to ~100 views (88 unknowns and 1404
//! residuals for 13 views); beyond that a Schur complement on the poses
//! would pay.

use nalgebra::{DMatrix, DVector};

/// A least-squares problem for [`levenberg_marquardt`].
pub trait Problem {
    /// The residuals at parameters `p` (all of them, free or fixed); `None`
    /// where the model is undefined.
    fn residuals(&mut self, p: &[f64]) -> Option<DVector<f64>>;

    /// The Jacobian of the residuals at `p`, column `k` the derivative by
    /// `p[free[k]]`; `None` where it is undefined. Called only at the point of
    /// the last successful [`Problem::residuals`] call (so an implementation
    /// may compute both together and keep the Jacobian).
    fn jacobian(&mut self, p: &[f64]) -> Option<DMatrix<f64>>;
}

/// Outcome of [`levenberg_marquardt`].
#[derive(Clone, Debug, PartialEq)]
pub struct Lm {
    /// The parameters.
    pub p: Vec<f64>,
    /// Residual sum of squares at `p`.
    pub rss: f64,
    /// Iterations made (trial steps, accepted or not).
    pub iterations: usize,
    /// Whether the convergence test was met.
    pub converged: bool,
}

/// Minimises `|r(p)|²` over the parameters `p[free[k]]` from `p0` (see the
/// [module](self) for the rule), in at most `max_iterations` trial steps.
/// `None` if the model is undefined at `p0`.
pub fn levenberg_marquardt(
    p0: Vec<f64>,
    free: &[usize],
    max_iterations: usize,
    problem: &mut impl Problem,
) -> Option<Lm> {
    let r = problem.residuals(&p0)?;
    let j = problem.jacobian(&p0)?;
    let mut p = p0;
    let mut rss = r.norm_squared();
    let mut mu = 1e-3;
    // The normal equations change only when a step is accepted: a rejected
    // step retries with more damping on the same JᵀJ and Jᵀr.
    let normal = |j: &DMatrix<f64>, r: &DVector<f64>| {
        let jtj = j.tr_mul(j);
        let g = j.tr_mul(r);
        let floor = jtj.diagonal().max() * 1e-15 + f64::MIN_POSITIVE;
        let scale = jtj.norm();
        (jtj, g, floor, scale)
    };
    let (mut jtj, mut g, mut floor, mut jtj_norm) = normal(&j, &r);
    for it in 1..=max_iterations {
        let mut a = jtj.clone();
        for k in 0..a.nrows() {
            a[(k, k)] += mu * jtj[(k, k)].max(floor);
        }
        let Some(chol) = a.cholesky() else {
            mu *= 4.0;
            continue;
        };
        let delta = -chol.solve(&g);
        let mut trial = p.clone();
        for (k, d) in delta.iter().enumerate() {
            trial[free[k]] += d;
        }
        let small = delta.iter().enumerate().all(|(k, d)| d.abs() <= 1e-11 * (p[free[k]].abs() + 1e-9));
        let accepted = problem
            .residuals(&trial)
            .filter(|r2| r2.norm_squared() < rss)
            .and_then(|r2| Some((problem.jacobian(&trial)?, r2)));
        match accepted {
            Some((j2, r2)) => {
                let new = r2.norm_squared();
                let tiny = rss - new <= 1e-14 * rss;
                (p, rss) = (trial, new);
                mu = (mu / 3.0).max(1e-12);
                if small || tiny {
                    return Some(Lm { p, rss, iterations: it, converged: true });
                }
                (jtj, g, floor, jtj_norm) = normal(&j2, &r2);
            }
            None => {
                // At the minimum, round-off rejects every step: a negligible
                // step or gradient then means converged.
                // (A small step under heavy damping proves nothing.)
                if (small && mu <= 1.0) || g.norm() <= 1e-12 * (jtj_norm * rss).sqrt() || stationary(&jtj, &g, rss) {
                    return Some(Lm { p, rss, iterations: it, converged: true });
                }
                mu *= 4.0;
                if mu > 1e20 {
                    return Some(Lm { p, rss, iterations: it, converged: false });
                }
            }
        }
    }
    Some(Lm { p, rss, iterations: max_iterations, converged: false })
}

/// Whether the undamped Gauss–Newton step from here would lower the
/// residual sum of squares by under 1e-9 of it (`gᵀ(JᵀJ)⁻¹g`, its
/// predicted decrease): the minimum to far within the noise, even when
/// round-off rejects every trial step and the gradient is not below the
/// strict test (many free parameters, a residual far above zero).
fn stationary(jtj: &DMatrix<f64>, g: &DVector<f64>, rss: f64) -> bool {
    jtj.clone().cholesky().is_some_and(|c| {
        let pred = g.dot(&c.solve(g));
        pred.is_finite() && pred <= 1e-9 * rss
    })
}

/// A [`Problem`] whose residuals and Jacobian one function computes
/// together (as the sine fits' do): `eval(p)` returns both.
pub struct WithJacobian<F> {
    eval: F,
    jacobian: Option<DMatrix<f64>>,
}

impl<F> WithJacobian<F>
where
    F: FnMut(&[f64]) -> Option<(DVector<f64>, DMatrix<f64>)>,
{
    /// The problem of `eval`.
    pub fn new(eval: F) -> Self {
        WithJacobian { eval, jacobian: None }
    }
}

impl<F> Problem for WithJacobian<F>
where
    F: FnMut(&[f64]) -> Option<(DVector<f64>, DMatrix<f64>)>,
{
    fn residuals(&mut self, p: &[f64]) -> Option<DVector<f64>> {
        let (r, j) = (self.eval)(p)?;
        self.jacobian = Some(j);
        Some(r)
    }

    fn jacobian(&mut self, _p: &[f64]) -> Option<DMatrix<f64>> {
        self.jacobian.take()
    }
}

/// A [`Problem`] with every parameter free and the Jacobian by central
/// differences (step `10⁻⁶·max(|p_k|, 10⁻²)`): for smooth, cheap residuals
/// such as reprojection errors. `residuals(p, out)` writes the `m`
/// residuals into `out`.
pub struct CentralDifferences<F> {
    residuals: F,
    m: usize,
    plus: Vec<f64>,
    minus: Vec<f64>,
}

impl<F> CentralDifferences<F>
where
    F: FnMut(&[f64], &mut [f64]),
{
    /// The problem of `m` residuals computed by `residuals`.
    pub fn new(m: usize, residuals: F) -> Self {
        CentralDifferences { residuals, m, plus: vec![0.0; m], minus: vec![0.0; m] }
    }
}

impl<F> Problem for CentralDifferences<F>
where
    F: FnMut(&[f64], &mut [f64]),
{
    fn residuals(&mut self, p: &[f64]) -> Option<DVector<f64>> {
        let mut r = DVector::zeros(self.m);
        (self.residuals)(p, r.as_mut_slice());
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&mut self, p: &[f64]) -> Option<DMatrix<f64>> {
        let mut j = DMatrix::zeros(self.m, p.len());
        let mut x = p.to_vec();
        for k in 0..p.len() {
            let h = 1e-6 * p[k].abs().max(1e-2);
            x[k] = p[k] + h;
            (self.residuals)(&x, &mut self.plus);
            x[k] = p[k] - h;
            (self.residuals)(&x, &mut self.minus);
            x[k] = p[k];
            for (i, (a, b)) in self.plus.iter().zip(&self.minus).enumerate() {
                j[(i, k)] = (a - b) / (2.0 * h);
            }
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock's valley as residuals `(10(y − x²), 1 − x)`.
    fn rosenbrock(p: &[f64], out: &mut [f64]) {
        out[0] = 10.0 * (p[1] - p[0] * p[0]);
        out[1] = 1.0 - p[0];
    }

    #[test]
    fn finds_the_rosenbrock_minimum_with_either_jacobian() {
        let exact = |p: &[f64]| {
            let mut r = DVector::zeros(2);
            rosenbrock(p, r.as_mut_slice());
            Some((r, DMatrix::from_row_slice(2, 2, &[-20.0 * p[0], 10.0, -1.0, 0.0])))
        };
        let a = levenberg_marquardt(vec![-1.2, 1.0], &[0, 1], 200, &mut WithJacobian::new(exact)).unwrap();
        let b =
            levenberg_marquardt(vec![-1.2, 1.0], &[0, 1], 200, &mut CentralDifferences::new(2, rosenbrock)).unwrap();
        for f in [&a, &b] {
            assert!(f.converged && (f.p[0] - 1.0).abs() < 1e-9 && (f.p[1] - 1.0).abs() < 1e-9, "{f:?}");
        }
    }

    #[test]
    fn undefined_trial_points_are_rejected_steps_and_fixed_parameters_stay() {
        // Minimum of (p0 − 3)² + (p2 − 1)², undefined for 2.9 < p0 < 2.99,
        // where the first step (to 2.957) lands; p1 is fixed.
        let eval = |p: &[f64]| {
            (!(2.9..2.99).contains(&p[0])).then(|| {
                (DVector::from_vec(vec![p[0] - 3.0, p[2] - 1.0]), DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 1.0]))
            })
        };
        let f = levenberg_marquardt(vec![-40.0, 7.0, 0.0], &[0, 2], 200, &mut WithJacobian::new(eval)).unwrap();
        assert!(f.converged && (f.p[0] - 3.0).abs() < 1e-9 && f.p[1] == 7.0 && (f.p[2] - 1.0).abs() < 1e-9, "{f:?}");
        assert!(f.iterations > 2, "the rejected first step counts: {f:?}");
        assert!(levenberg_marquardt(vec![2.95, 0.0, 0.0], &[0, 2], 200, &mut WithJacobian::new(eval)).is_none());
    }
}
