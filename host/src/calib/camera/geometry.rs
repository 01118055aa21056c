//! The closed-form start of camera calibration: homographies of the board
//! views, Zhang's conic for the intrinsics, poses from homographies.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, SMatrix, SymmetricEigen, Vector3};

use super::CalibError;
use crate::model::board::BoardPose;

pub(super) fn rodrigues(r: [f64; 3]) -> Matrix3<f64> {
    Rotation3::new(Vector3::new(r[0], r[1], r[2])).into_inner()
}

pub(super) fn rodrigues_inv(m: &Matrix3<f64>) -> [f64; 3] {
    let v = Rotation3::from_matrix_unchecked(*m).scaled_axis();
    [v[0], v[1], v[2]]
}

pub(super) fn pose_from(r: [f64; 3], t: [f64; 3]) -> BoardPose {
    let m = rodrigues(r);
    let mut rot = [[0.0; 3]; 3];
    for (i, row) in rot.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[(i, j)];
        }
    }
    BoardPose { rot, t_mm: t }
}

/// The nearest rotation (Frobenius) to `m`, by SVD.
pub(super) fn orthonormalise(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else { return Matrix3::identity() };
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut d = Matrix3::identity();
        d[(2, 2)] = -1.0;
        r = u * d * vt;
    }
    r
}

/// Hartley conditioning: centroid to the origin, mean distance √2.
pub(super) fn conditioner(pts: &[[f64; 2]]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = (pts.iter().map(|p| p[0]).sum::<f64>() / n, pts.iter().map(|p| p[1]).sum::<f64>() / n);
    let md = pts.iter().map(|p| ((p[0] - mx).powi(2) + (p[1] - my).powi(2)).sqrt()).sum::<f64>() / n;
    let s = if md > 0.0 { std::f64::consts::SQRT_2 / md } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// The homography `dst ~ H · (src, 1)` by the normalised DLT.
pub(super) fn homography(src: &[[f64; 2]], dst: &[[f64; 2]]) -> Result<Matrix3<f64>, CalibError> {
    if src.len() < 4 || src.len() != dst.len() {
        return Err(CalibError::Degenerate("a homography needs 4 points"));
    }
    let (ts, td) = (conditioner(src), conditioner(dst));
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let a = ts * Vector3::new(s[0], s[1], 1.0);
        let b = td * Vector3::new(d[0], d[1], 1.0);
        let (x, y, u, v) = (a[0], a[1], b[0], b[1]);
        let r1 = SMatrix::<f64, 9, 1>::from_column_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u]);
        let r2 = SMatrix::<f64, 9, 1>::from_column_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v]);
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let h = smallest_eigenvector(&DMatrix::from_iterator(9, 9, ata.iter().copied()));
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let tdi = td.try_inverse().ok_or(CalibError::Degenerate("coincident image points"))?;
    let hm = tdi * hn * ts;
    if !hm.iter().all(|v| v.is_finite()) || hm.norm() == 0.0 {
        return Err(CalibError::Degenerate("no homography"));
    }
    Ok(hm / hm.norm())
}

pub(super) fn smallest_eigenvector(m: &DMatrix<f64>) -> DVector<f64> {
    let e = SymmetricEigen::new(m.clone());
    let mut k = 0;
    for i in 1..e.eigenvalues.len() {
        if e.eigenvalues[i] < e.eigenvalues[k] {
            k = i;
        }
    }
    e.eigenvectors.column(k).into_owned()
}

/// Board pose from a homography `H ~ K [r1 r2 t]`.
pub(super) fn pose_from_homography(k: &Matrix3<f64>, h: &Matrix3<f64>) -> Result<([f64; 3], [f64; 3]), CalibError> {
    let ki = k.try_inverse().ok_or(CalibError::Degenerate("singular camera matrix"))?;
    let m = ki * h;
    let (c1, c2, c3) = (m.column(0).into_owned(), m.column(1).into_owned(), m.column(2).into_owned());
    let n = 0.5 * (c1.norm() + c2.norm());
    if n.is_nan() || n <= 0.0 {
        return Err(CalibError::Degenerate("degenerate homography"));
    }
    // The board is in front of the camera: t_z > 0 fixes H's sign.
    let lambda = if c3[2] < 0.0 { -1.0 / n } else { 1.0 / n };
    let r1 = c1 * lambda;
    let r2 = c2 * lambda;
    let r3 = r1.cross(&r2);
    let r = orthonormalise(&Matrix3::from_columns(&[r1, r2, r3]));
    let t = c3 * lambda;
    Ok((rodrigues_inv(&r), [t[0], t[1], t[2]]))
}

pub(super) fn v_ij(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (a, b) = (h.column(i), h.column(j));
    [
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[1] * b[1],
        a[2] * b[0] + a[0] * b[2],
        a[2] * b[1] + a[1] * b[2],
        a[2] * b[2],
    ]
}

/// Zhang's closed form on homographies of a normalised image; `None` when
/// degenerate.
pub(super) fn zhang(hs: &[Matrix3<f64>], fix_skew: bool) -> Option<Matrix3<f64>> {
    let mut rows: Vec<[f64; 6]> = Vec::new();
    for h in hs {
        let v12 = v_ij(h, 0, 1);
        let (v11, v22) = (v_ij(h, 0, 0), v_ij(h, 1, 1));
        rows.push(v12);
        rows.push(std::array::from_fn(|k| v11[k] - v22[k]));
    }
    let mut vtv = DMatrix::<f64>::zeros(6, 6);
    for r in &rows {
        let v = DVector::from_column_slice(r);
        vtv += &v * v.transpose();
    }
    if fix_skew {
        // B₁₂ = 0 (zero skew), weighted to dominate.
        vtv[(1, 1)] += 1e3 * vtv.trace().max(1e-30);
    }
    let b = smallest_eigenvector(&vtv);
    let b = if b[0] < 0.0 { -b } else { b };
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if !(b11 > 0.0 && den > 0.0) {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    if (lambda / b11).is_nan() || lambda / b11 <= 0.0 {
        return None;
    }
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = if fix_skew { 0.0 } else { -b12 * alpha * alpha * beta / lambda };
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    let k = Matrix3::new(alpha, gamma, u0, 0.0, beta, v0, 0.0, 0.0, 1.0);
    k.iter().all(|v| v.is_finite()).then_some(k)
}

/// OpenCV's initialisation: principal point given, zero skew, focal lengths
/// by least squares on Zhang's constraints.
pub(super) fn focal_only(hs: &[Matrix3<f64>], aspect: Option<f64>) -> Option<(f64, f64)> {
    // Unknowns a = 1/fx², b = 1/fy²: rows [p, q] · [a, b] = −c.
    let (mut m11, mut m12, mut m22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for h in hs {
        let (h1, h2) = (h.column(0), h.column(1));
        for (p, q, c) in [
            (h1[0] * h2[0], h1[1] * h2[1], h1[2] * h2[2]),
            (h1[0] * h1[0] - h2[0] * h2[0], h1[1] * h1[1] - h2[1] * h2[1], h1[2] * h1[2] - h2[2] * h2[2]),
        ] {
            m11 += p * p;
            m12 += p * q;
            m22 += q * q;
            r1 -= p * c;
            r2 -= q * c;
        }
    }
    let (a, b) = match aspect {
        // fx = s·fy: a = b / s², one unknown b.
        Some(s) => {
            let w = 1.0 / (s * s);
            let b = (w * r1 + r2) / (w * w * m11 + 2.0 * w * m12 + m22);
            (w * b, b)
        }
        None => {
            let det = m11 * m22 - m12 * m12;
            ((m22 * r1 - m12 * r2) / det, (m11 * r2 - m12 * r1) / det)
        }
    };
    (a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite()).then(|| (1.0 / a.sqrt(), 1.0 / b.sqrt()))
}
