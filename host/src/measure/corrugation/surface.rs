//! The surface the lines lie on: its frame, its terms (the wave and the
//! trend of the nested ladder), their linear and full evaluation, and the
//! uncertainties at a solution.

use super::Line;
use crate::measure::fit::FitError;
use crate::model::vec3::{Vec3, axpy, cross, dot, unit};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// Per line in the surface frame: `(line index, [x, y, z])` points.
pub(super) struct Surface {
    pub(super) normal: Vec3,
    pub(super) pitch: f64,
    pub(super) roll: f64,
    /// `x, y, z` per point and the line it belongs to.
    pub(super) x: Vec<f64>,
    pub(super) y: Vec<f64>,
    pub(super) z: Vec<f64>,
    pub(super) line: Vec<usize>,
}

/// The least-squares plane through all points and every point in its frame
/// (centred on the centroid).
pub(super) fn surface(lines: &[Line]) -> Result<Surface, FitError> {
    let n: usize = lines.iter().map(|l| l.points.len()).sum();
    let all = || lines.iter().flat_map(|l| l.points.iter());
    let c = all().fold([0.0; 3], |s, p| axpy(1.0 / n as f64, *p, s));
    // h = c + p u + q v on centred points: 2 unknowns (q only with two lines).
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for p in all() {
        let row = Vector3::new(p[0] - c[0], p[1] - c[1], 1.0);
        ata += row * row.transpose();
        atb += row * (p[2] - c[2]);
    }
    let across = lines.iter().filter(|l| !l.points.is_empty()).count() > 1 && ata[(1, 1)] > 1e-6 * n as f64;
    let (p, q) = if across {
        let s = ata.lu().solve(&atb).ok_or(FitError::Degenerate("the lines do not span a plane"))?;
        (s[0], s[1])
    } else {
        let d = ata[(0, 0)];
        if d <= 0.0 || !d.is_finite() {
            return Err(FitError::Degenerate("all points at one position"));
        }
        (atb[0] / d, 0.0)
    };
    let normal = unit([-p, -q, 1.0]).ok_or(FitError::Degenerate("surface normal"))?;
    let ex = unit(axpy(-normal[0], normal, [1.0, 0.0, 0.0])).ok_or(FitError::Degenerate("surface frame"))?;
    let ey = cross(normal, ex);
    let mut s = Surface { normal, pitch: p.atan(), roll: q.atan(), x: vec![], y: vec![], z: vec![], line: vec![] };
    for (i, l) in lines.iter().enumerate() {
        for pt in &l.points {
            let d = axpy(-1.0, c, *pt);
            s.x.push(dot(d, ex));
            s.y.push(dot(d, ey));
            s.z.push(dot(d, normal));
            s.line.push(i);
        }
    }
    Ok(s)
}

/// Parameters of the surface model: the wave `[a, b, ω, κ]`, then the
/// coefficients of [`Terms`] from `C`: `[c, g_x, g_y, p₂, p₃, p₄, e_ss,
/// e_su]`.
pub(super) mod q {
    pub const A: usize = 0;
    pub const B: usize = 1;
    pub const OMEGA: usize = 2;
    pub const KAPPA: usize = 3;
    pub const C: usize = 4;
    pub const GX: usize = 5;
    pub const GY: usize = 6;
    pub const U2: usize = 7;
    pub const SS: usize = 10;
    pub const N: usize = C + super::TERMS;
}

/// How many trend terms [`Terms`] has.
pub(super) const TERMS: usize = 8;

/// The trend's terms at one point, in the rail's own coordinates: `s`
/// along the rail (the wave's direction, `(ω x + κ y)/k`) and `u` across
/// it (`(−κ x + ω y)/k`), so that the crown is a polynomial in `u` alone
/// whatever the yaw: `[1, x, y, u², u³, u⁴, s², s u]`. With their
/// derivatives in `u` and `s` (the ω and κ columns of the Jacobian go
/// through them: `∂u/∂ω = s sin ψ/k`, `∂u/∂κ = −s cos ψ/k`, `∂s/∂ω = −u
/// sin ψ/k`, `∂s/∂κ = u cos ψ/k`).
pub(super) struct Terms {
    pub(super) t: [f64; TERMS],
    /// `∂t/∂u`, `∂t/∂s` per term.
    pub(super) du: [f64; TERMS],
    pub(super) ds: [f64; TERMS],
    pub(super) u: f64,
    pub(super) s: f64,
}

/// The wave's direction from `(ω, κ)`: `(k, cos ψ, sin ψ)`, the rail's
/// axis (`(1, 0)` for no wave), found once per evaluation, not per point.
pub(super) fn direction(omega: f64, kappa: f64) -> (f64, f64, f64) {
    let k = omega.hypot(kappa);
    let (cp, sp) = if k > 0.0 { (omega / k, kappa / k) } else { (1.0, 0.0) };
    (k, cp, sp)
}

impl Terms {
    /// At `(x, y)` for the direction `(cos ψ, sin ψ)` of [`direction`].
    pub(super) fn at(x: f64, y: f64, (cp, sp): (f64, f64)) -> Terms {
        let (s, u) = (x * cp + y * sp, -x * sp + y * cp);
        let u2 = u * u;
        Terms {
            t: [1.0, x, y, u2, u2 * u, u2 * u2, s * s, s * u],
            du: [0.0, 0.0, 0.0, 2.0 * u, 3.0 * u2, 4.0 * u2 * u, 0.0, s],
            ds: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0 * s, u],
            u,
            s,
        }
    }

    pub(super) fn trend(&self, c: &[f64]) -> f64 {
        self.t.iter().zip(c).map(|(t, c)| t * c).sum()
    }
}

/// Residuals `z − ẑ` of the surface model and, over `free`, their Jacobian:
/// `ẑ = T(x, y) + a sin(ωx + κy) + b cos(ωx + κy)`, `T` over [`Terms`].
pub(super) fn evaluate_surface(s: &Surface, p: &[f64], free: &[usize]) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let (a, b, w, kappa) = (p[q::A], p[q::B], p[q::OMEGA], p[q::KAPPA]);
    let (k, cp, sp) = direction(w, kappa);
    let n = s.x.len();
    let mut r = DVector::zeros(n);
    let mut j = DMatrix::zeros(n, free.len());
    let mut col = [0.0; q::N];
    let coef = &p[q::C..q::N];
    for i in 0..n {
        let (x, y) = (s.x[i], s.y[i]);
        let t = Terms::at(x, y, (cp, sp));
        let (sn, cs) = (w * x + kappa * y).sin_cos();
        r[i] = s.z[i] - (t.trend(coef) + a * sn + b * cs);
        let slope = a * cs - b * sn;
        // The trend's dependence on the direction (module docs).
        let dt_du: f64 = t.du.iter().zip(coef).map(|(d, c)| d * c).sum();
        let dt_ds: f64 = t.ds.iter().zip(coef).map(|(d, c)| d * c).sum();
        let (du_dw, du_dk) = if k > 0.0 { (t.s * sp / k, -t.s * cp / k) } else { (0.0, 0.0) };
        let (ds_dw, ds_dk) = if k > 0.0 { (-t.u * sp / k, t.u * cp / k) } else { (0.0, 0.0) };
        col[q::A] = -sn;
        col[q::B] = -cs;
        col[q::OMEGA] = -x * slope - dt_du * du_dw - dt_ds * ds_dw;
        col[q::KAPPA] = -y * slope - dt_du * du_dk - dt_ds * ds_dk;
        for (k, t) in t.t.iter().enumerate() {
            col[q::C + k] = -t;
        }
        for (k, &f) in free.iter().enumerate() {
            j[(i, k)] = col[f];
        }
    }
    (r.iter().all(|v| v.is_finite()) && j.iter().all(|v| v.is_finite())).then_some((r, j))
}

/// The linear parameters over `free` (all but ω and κ) by least squares
/// at `p`'s ω and κ: a start for the refinement, or `None` when the
/// columns are not independent (reciprocal condition of the
/// column-normalised normal matrix under `MIN_RCOND`: the lines cannot
/// tell those terms apart, e.g. `u³` from `u` with three lines along the
/// rail).
pub(super) fn linear_start(s: &Surface, p: &[f64], free: &[usize]) -> Option<Vec<f64>> {
    let lin: Vec<usize> = free.iter().copied().filter(|&f| f != q::OMEGA && f != q::KAPPA).collect();
    let m = lin.len();
    let (w, kappa) = (p[q::OMEGA], p[q::KAPPA]);
    let (_, cp, sp) = direction(w, kappa);
    let mut ata = DMatrix::<f64>::zeros(m, m);
    let mut atb = DVector::<f64>::zeros(m);
    let mut row = vec![0.0; m];
    for i in 0..s.x.len() {
        let t = Terms::at(s.x[i], s.y[i], (cp, sp));
        let (sn, cs) = (w * s.x[i] + kappa * s.y[i]).sin_cos();
        for (r, &f) in row.iter_mut().zip(&lin) {
            *r = match f {
                q::A => sn,
                q::B => cs,
                f => t.t[f - q::C],
            };
        }
        for a in 0..m {
            atb[a] += row[a] * s.z[i];
            for b in 0..m {
                ata[(a, b)] += row[a] * row[b];
            }
        }
    }
    let d: Vec<f64> = (0..m).map(|k| ata[(k, k)].sqrt()).collect();
    if d.iter().any(|v| v.is_nan() || *v <= 0.0 || v.is_infinite()) {
        return None;
    }
    let scaled = DMatrix::from_fn(m, m, |a, b| ata[(a, b)] / (d[a] * d[b]));
    let eig = scaled.clone().symmetric_eigen().eigenvalues;
    let (lo, hi) = eig.iter().fold((f64::INFINITY, 0.0f64), |(l, h), &e| (l.min(e), h.max(e)));
    if lo.is_nan() || lo <= MIN_RCOND * hi {
        return None;
    }
    let rhs = DVector::from_fn(m, |a, _| atb[a] / d[a]);
    let sol = scaled.cholesky()?.solve(&rhs);
    let mut out = p.to_vec();
    for (k, &f) in lin.iter().enumerate() {
        out[f] = sol[k] / d[k];
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// The smallest reciprocal condition of a rung's linear columns
/// ([`linear_start`]), at the start and at the solution: under it the rung
/// is not taken. Three lines along the rail (no yaw) see the crown at
/// three lateral places only, and `u³`, `u⁴` are then told from `u`, `u²`
/// only by the lines' lateral wander and fanning (tenths of a millimetre:
/// an inclined plane's line moves across as its height changes), which
/// puts the condition at 1e-5–1e-4: formally solvable, and the slope
/// across (the roll) then trades against `u³` (the reference head's
/// recording showed 1.4° of roll that was not there, `u³` and `u` each
/// 0.25 mm at the outer lines and cancelling). Over a 280 mm frame the
/// condition is 1e-3 at 0.5° of yaw, 8e-3 at 2°.
pub(super) const MIN_RCOND: f64 = 1e-3;

/// A 2-D polynomial detrend in the points' `(x, y)` (to degree four along,
/// two across), used only to find the starts: what is left holds the wave.
pub(super) fn start_detrend(s: &Surface, across: usize) -> Option<Vec<f64>> {
    let terms = |x: f64, y: f64| -> Vec<f64> {
        let x2 = x * x;
        let mut t = vec![1.0, x, x2, x2 * x, x2 * x2];
        if across > 0 {
            t.extend([y, x * y, x2 * y, x2 * x * y]);
        }
        if across > 1 {
            t.extend([y * y, x2 * y * y]);
        }
        t
    };
    let m = terms(0.0, 0.0).len();
    let mut ata = DMatrix::<f64>::zeros(m, m);
    let mut atb = DVector::<f64>::zeros(m);
    for i in 0..s.x.len() {
        let t = terms(s.x[i], s.y[i]);
        for a in 0..m {
            atb[a] += t[a] * s.z[i];
            for b in 0..m {
                ata[(a, b)] += t[a] * t[b];
            }
        }
    }
    let sol = ata.lu().solve(&atb)?;
    let rest: Vec<f64> = (0..s.x.len())
        .map(|i| s.z[i] - terms(s.x[i], s.y[i]).iter().zip(sol.iter()).map(|(t, c)| t * c).sum::<f64>())
        .collect();
    rest.iter().all(|v| v.is_finite()).then_some(rest)
}

/// The one-σ uncertainties of quantities derived from the parameters
/// (one gradient over them each) of a least-squares solution `p` over
/// `free` with residual sum `rss`: the residuals' own correlation along each
/// line (`hac_variance`), never below the white-noise figure `σ² gᵀ
/// (JᵀJ)⁻¹ g`. `None` where the normal matrix is singular.
pub(super) fn sigmas(s: &Surface, p: &[f64], free: &[usize], rss: f64, grads: &[&[(usize, f64)]]) -> Vec<Option<f64>> {
    let n = s.x.len();
    let sigma2 = rss / n.saturating_sub(free.len()).max(1) as f64;
    let jac = evaluate_surface(s, p, free);
    let inv = jac.as_ref().and_then(|(_, j)| j.tr_mul(j).cholesky()).map(|c| c.inverse());
    let one = |grad: &[(usize, f64)]| -> Option<f64> {
        let (inv, (r, j)) = (inv.as_ref()?, jac.as_ref()?);
        if grad.is_empty() {
            return None;
        }
        let mut g = DVector::zeros(free.len());
        for &(i, gi) in grad {
            g[free.iter().position(|&f| f == i)?] = gi;
        }
        let w = inv * g;
        let jw = j * &w;
        let white = sigma2 * jw.norm_squared();
        let influence: Vec<f64> = jw.iter().zip(r.iter()).map(|(a, b)| a * b).collect();
        let v = hac_variance(&influence, &s.line).max(white);
        (v >= 0.0 && v.is_finite()).then(|| v.sqrt())
    };
    grads.iter().map(|g| one(g)).collect()
}

/// The variance of `Σ h_i` when the `h_i` (one point's influence on a
/// result, in the order of the points along each line) are correlated
/// along a line: `Σ_l Σ_{|i−j| ≤ L} (1 − |i−j|/(L+1)) h_i h_j` over the
/// pairs of one line (Newey–West, Bartlett weights). The points' errors are
/// not white: the stripe position's error depends on where the stripe
/// falls on the pixel grid, which changes slowly along a line, and
/// residuals averaged over 100 rows scatter 1.4–1.8× what white noise of
/// their RMS would give (the simulated paper head at 30 dB); the white
/// figure then claims 1.5–2× too little. `L` = `HAC_LAG` points.
pub(super) fn hac_variance(h: &[f64], line: &[usize]) -> f64 {
    let mut v = 0.0;
    for (i, (&hi, &li)) in h.iter().zip(line).enumerate() {
        v += hi * hi;
        let ahead = h[i + 1..].iter().zip(&line[i + 1..]).take(HAC_LAG).take_while(|(_, l)| **l == li);
        for (lag, (&hj, _)) in (1..).zip(ahead) {
            v += 2.0 * (1.0 - lag as f64 / (HAC_LAG + 1) as f64) * hi * hj;
        }
    }
    v
}

/// The Newey–West lag, points along a line: longer than the correlation
/// of the pixel grid's error (tens of rows), short against a line.
pub(super) const HAC_LAG: usize = 64;
