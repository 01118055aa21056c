//! Levenberg–Marquardt refinement of the intrinsics, distortion and board
//! poses over a set of views, and the covariance at the solution.

use nalgebra::Matrix3;

use super::geometry::{focal_only, homography, pose_from, pose_from_homography, zhang};
use super::{CalibError, CalibOptions, CameraCalibration, Covariance, Sigma};
use crate::model::board::Board;
use crate::model::camera::Intrinsics;
use crate::model::lm::{self, Problem as _};

/// The free intrinsic parameters and how they map to [`Intrinsics`].
#[derive(Clone, Copy)]
pub(super) struct Layout {
    fix_skew: bool,
    aspect: Option<f64>,
    fix_k3: bool,
    fix_tangential: bool,
    width: u32,
    height: u32,
}

impl Layout {
    /// For each free parameter, its index in [`INTRINSIC_NAMES`] (`fy` for
    /// the one focal length of a fixed aspect ratio).
    fn names(&self) -> Vec<usize> {
        let mut v = match self.aspect {
            Some(_) => vec![1],
            None => vec![0, 1],
        };
        v.extend([2, 3]);
        if !self.fix_skew {
            v.push(4);
        }
        v.extend([5, 6]);
        if !self.fix_tangential {
            v.extend([7, 8]);
        }
        if !self.fix_k3 {
            v.push(9);
        }
        v
    }

    fn n(&self) -> usize {
        self.names().len()
    }

    fn pack(&self, k: &Intrinsics) -> Vec<f64> {
        let all = [k.fx_px, k.fy_px, k.cx_px, k.cy_px, k.skew_px, k.k1, k.k2, k.p1, k.p2, k.k3];
        self.names().into_iter().map(|i| all[i]).collect()
    }

    fn unpack(&self, v: &[f64]) -> Intrinsics {
        let mut all = [0.0; 10];
        for (&i, &x) in self.names().iter().zip(v) {
            all[i] = x;
        }
        if let Some(a) = self.aspect {
            all[0] = a * all[1];
        }
        let [fx_px, fy_px, cx_px, cy_px, skew_px, k1, k2, p1, p2, k3] = all;
        Intrinsics {
            width_px: self.width,
            height_px: self.height,
            fx_px,
            fy_px,
            cx_px,
            cy_px,
            skew_px,
            k1,
            k2,
            p1,
            p2,
            k3,
        }
    }
}

/// Writes the reprojection residuals (projected − observed, px) of one view.
pub(super) fn view_residuals(k: &Intrinsics, pose: &[f64], obj: &[[f64; 3]], obs: &[[f64; 2]], out: &mut [f64]) {
    let p = pose_from([pose[0], pose[1], pose[2]], [pose[3], pose[4], pose[5]]);
    for (n, (o, m)) in obj.iter().zip(obs).enumerate() {
        let c = p.to_camera(*o);
        // Behind the camera: a large finite residual keeps LM away.
        let q = k.project(c).unwrap_or([m[0] + 1e6, m[1] + 1e6]);
        out[2 * n] = q[0] - m[0];
        out[2 * n + 1] = q[1] - m[1];
    }
}

pub(super) fn rms_of(res: &[f64]) -> f64 {
    (res.iter().map(|v| v * v).sum::<f64>() / (res.len() / 2).max(1) as f64).sqrt()
}

pub(super) fn calibrate_subset(
    board: &Board,
    views: &[Vec<[f64; 2]>],
    used: &[usize],
    width: u32,
    height: u32,
    opts: &CalibOptions,
) -> Result<CameraCalibration, CalibError> {
    if used.len() < 3 {
        return Err(CalibError::TooFewViews { got: used.len() });
    }
    if width == 0 || height == 0 {
        return Err(CalibError::Degenerate("empty image"));
    }
    let obj = board.object_points();
    let plane: Vec<[f64; 2]> = obj.iter().map(|p| [p[0], p[1]]).collect();
    let k0 = initial_intrinsics(&plane, views, used, width, height, opts)?;
    let kmat = Matrix3::new(k0.fx_px, k0.skew_px, k0.cx_px, 0.0, k0.fy_px, k0.cy_px, 0.0, 0.0, 1.0);
    let layout = Layout {
        fix_skew: opts.fix_skew,
        aspect: opts.fix_aspect,
        fix_k3: opts.fix_k3,
        fix_tangential: opts.fix_tangential,
        width,
        height,
    };
    let ni = layout.n();
    let mut x = layout.pack(&k0);
    for &v in used {
        let (r, t) = pose_from_homography(&kmat, &homography(&plane, &views[v])?)?;
        x.extend(r);
        x.extend(t);
    }
    let npts = obj.len();
    let n_res = 2 * npts * used.len();
    let residuals = |x: &[f64], out: &mut [f64]| {
        let k = layout.unpack(&x[..ni]);
        for (n, &v) in used.iter().enumerate() {
            let pose = &x[ni + 6 * n..ni + 6 * n + 6];
            view_residuals(&k, pose, &obj, &views[v], &mut out[2 * npts * n..2 * npts * (n + 1)]);
        }
    };
    let free: Vec<usize> = (0..x.len()).collect();
    let fit =
        lm::levenberg_marquardt(x, &free, opts.max_iterations, &mut lm::CentralDifferences::new(n_res, residuals))
            .ok_or(CalibError::Degenerate("the fit diverged"))?;
    let (x, iterations) = (fit.p, fit.iterations);
    let mut res = vec![0.0; n_res];
    residuals(&x, &mut res);
    if !res.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Degenerate("the fit diverged"));
    }
    let intrinsics = layout.unpack(&x[..ni]);
    let per_view_rms_px = (0..used.len()).map(|n| rms_of(&res[2 * npts * n..2 * npts * (n + 1)])).collect();
    let poses = (0..used.len())
        .map(|n| {
            let p = &x[ni + 6 * n..ni + 6 * n + 6];
            pose_from([p[0], p[1], p[2]], [p[3], p[4], p[5]])
        })
        .collect();
    let (covariance, sigma) = uncertainty(&layout, &x, &res, n_res, residuals)?;
    let max_radius_px = used
        .iter()
        .flat_map(|&v| views[v].iter())
        .map(|p| (p[0] - intrinsics.cx_px).hypot(p[1] - intrinsics.cy_px))
        .fold(0.0, f64::max);
    Ok(CameraCalibration {
        intrinsics,
        rms_px: rms_of(&res),
        views_used: used.to_vec(),
        views_rejected: Vec::new(),
        per_view_rms_px,
        poses,
        iterations,
        duplicates: Vec::new(),
        fixed: Vec::new(),
        sigma,
        covariance,
        max_radius_px,
    })
}

/// The closed-form start: Zhang's intrinsics from the views' homographies
/// (normalised for conditioning), or, where they do not give a plausible
/// camera, focal lengths alone with the principal point at the centre.
fn initial_intrinsics(
    plane: &[[f64; 2]],
    views: &[Vec<[f64; 2]>],
    used: &[usize],
    width: u32,
    height: u32,
    opts: &CalibOptions,
) -> Result<Intrinsics, CalibError> {
    let (w, h) = (width as f64, height as f64);
    // Image normalisation for Zhang's conic: centre to 0, larger side to 1.
    let s = 1.0 / w.max(h);
    let norm = Matrix3::new(s, 0.0, -0.5 * s * w, 0.0, s, -0.5 * s * h, 0.0, 0.0, 1.0);
    let mut hs = Vec::with_capacity(used.len());
    for &v in used {
        let hm = homography(plane, &views[v])?;
        let hn = norm * hm;
        hs.push(hn / hn.norm());
    }
    let kz = zhang(&hs, opts.fix_skew).and_then(|kn| {
        let k = norm.try_inverse()? * kn;
        let ok = k[(0, 0)] > 0.0
            && k[(1, 1)] > 0.0
            && (0.0..w).contains(&k[(0, 2)])
            && (0.0..h).contains(&k[(1, 2)])
            && (k[(0, 0)] / k[(1, 1)]).ln().abs() < 0.7;
        ok.then_some(k)
    });
    let (mut fx, mut fy, cx, cy, skew) = match kz {
        Some(k) => (k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)], k[(0, 1)]),
        None => {
            // Homographies with the principal point (image centre) at the origin, in pixels.
            let c = Matrix3::new(1.0, 0.0, -0.5 * (w - 1.0), 0.0, 1.0, -0.5 * (h - 1.0), 0.0, 0.0, 1.0);
            let hc: Vec<Matrix3<f64>> = hs.iter().map(|hn| c * norm.try_inverse().unwrap_or_default() * hn).collect();
            let (fx, fy) = focal_only(&hc, opts.fix_aspect)
                .ok_or(CalibError::Degenerate("no focal length fits the views (too few tilted views?)"))?;
            (fx, fy, 0.5 * (w - 1.0), 0.5 * (h - 1.0), 0.0)
        }
    };
    if let Some(a) = opts.fix_aspect {
        let f = (fx * fy / a).sqrt();
        fx = a * f;
        fy = f;
    }
    Ok(Intrinsics {
        width_px: width,
        height_px: height,
        fx_px: fx,
        fy_px: fy,
        cx_px: cx,
        cy_px: cy,
        skew_px: if opts.fix_skew { 0.0 } else { skew },
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        k3: 0.0,
    })
}

/// The covariance σ²·(JᵀJ)⁻¹ of the intrinsics at the solution `x`, σ²
/// from the residuals `res`, and each one's σ.
fn uncertainty(
    layout: &Layout,
    x: &[f64],
    res: &[f64],
    n_res: usize,
    residuals: impl Fn(&[f64], &mut [f64]),
) -> Result<(Covariance, Sigma), CalibError> {
    let j = lm::CentralDifferences::new(n_res, residuals)
        .jacobian(x)
        .ok_or(CalibError::Degenerate("the Jacobian at the solution is not finite"))?;
    let dof = n_res.saturating_sub(x.len()).max(1);
    let s2 = res.iter().map(|v| v * v).sum::<f64>() / dof as f64;
    let inv = j.tr_mul(&j).cholesky().map(|c| c.inverse()).ok_or_else(|| {
        CalibError::Uncertain("the normal matrix is singular: some parameter is not determined".into())
    })?;
    let names = layout.names();
    let mut covariance = Covariance::default();
    let mut sigma = Sigma::default();
    for (a, &ia) in names.iter().enumerate() {
        for (b, &ib) in names.iter().enumerate() {
            covariance.0[ia][ib] = s2 * inv[(a, b)];
        }
        sigma.0[ia] = Some((s2 * inv[(a, a)]).max(0.0).sqrt());
    }
    if let Some(r) = layout.aspect {
        // fx = r·fy: its σ and covariances follow fy's.
        for i in 0..10 {
            covariance.0[0][i] = r * covariance.0[1][i];
            covariance.0[i][0] = r * covariance.0[i][1];
        }
        covariance.0[0][0] = r * r * covariance.0[1][1];
        sigma.0[0] = sigma.0[1].map(|s| r * s);
    }
    Ok((covariance, sigma))
}
