//! `cms-host calibrate lasers`: the three laser planes from laser-on /
//! laser-off image pairs of the checkerboard at several poses (paper §6.1).
//!
//! Per pair:
//! 1. the board's inner corners in the lasers-off image, and the board's pose
//!    from them with the calibrated camera ([`super::camera::board_pose`]);
//! 2. the lasers-on image minus the lasers-off image: the laser lines alone,
//!    without the checker's edges (which a row detector would otherwise
//!    take for stripes) and without the lamp;
//! 3. per image row, the stripes by the core detector (`cms_core::peak`, the
//!    head's own);
//! 4. each stripe centre back-projected onto the board plane (undistortion,
//!    ray, plane), kept if it falls on the printed board.
//!
//! **Which stripe is which laser** does not depend on luck: a row counts only
//! when it has exactly one stripe per laser, and the stripes are then
//! numbered left to right — the head's own convention (its lasers are
//! mounted left to right in laser order, and parallel or fanned planes that
//! do not cross in front of the camera keep that order in every row). The
//! fitted planes are then checked against that assumption: a point farther
//! than 5 robust σ from its plane is dropped and counted, and a laser whose
//! points disagree (RMS above `--max-rms-mm`) fails the calibration rather
//! than producing a wrong plane.
//!
//! Per laser, a total-least-squares plane (the smallest-eigenvalue direction
//! of the points' scatter about their centroid) with its RMS residual; one
//! pose gives a line, so at least three poses at different depths must each
//! contribute points, and the fit refuses point sets that are nearly
//! collinear.
//!
//! **Datum** (the rail-top plane heights are measured from): the board plane
//! of one pose (`--datum-pose K`, the board laid on the rail or on a
//! reference block), or else the plane perpendicular to the optical axis
//! through the point where the middle laser's plane crosses it (a head
//! mounted square to the rail, paper §2.2).

use crate::calib::file::{CalibrationFile, HeadSection, LaserSection, PlaneSection};
use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_core::protocol::LASERS;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::input::{Pixels, Rows};
use crate::model::board::{Board, BoardPose};
use crate::model::camera::Intrinsics;

/// Widest image the row detector takes.
const MAX_WIDTH: usize = 8192;

/// Points a laser needs from a pose for the pose to count for it.
const MIN_POINTS_PER_POSE: usize = 10;

/// Options of [`calibrate_lasers`].
#[derive(Clone, Copy, Debug)]
pub struct LaserOptions {
    /// Detector scale range on the board, px.
    pub scales: (f64, f64),
    /// Largest acceptable plane RMS, mm.
    pub max_rms_mm: f64,
    /// Pose (0-based) whose board is the datum.
    pub datum_pose: Option<usize>,
}

impl Default for LaserOptions {
    fn default() -> Self {
        LaserOptions { scales: (1.0, 16.0), max_rms_mm: 0.1, datum_pose: None }
    }
}

/// What one pose gave.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseReport {
    /// The board's pose.
    pub pose: BoardPose,
    /// RMS reprojection error of the board's corners, px.
    pub board_rms_px: f64,
    /// Points per laser on the board.
    pub points: [usize; LASERS],
    /// Stripes far from every laser's line, or a second one near the same line (not used).
    pub ambiguous_rows: usize,
}

/// A fitted laser plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaserPlane {
    /// Unit normal, camera frame, oriented so that `d_mm < 0`.
    pub normal: [f64; 3],
    /// `normal · X = d_mm`.
    pub d_mm: f64,
    /// RMS distance of the points kept, mm.
    pub rms_mm: f64,
    /// Points kept.
    pub points: usize,
    /// Points dropped as outliers.
    pub outliers: usize,
    /// Poses that contributed.
    pub poses: usize,
    /// The points' spread across the laser line: σ along their second
    /// principal direction, mm (a plane needs it well above the RMS).
    pub spread_mm: f64,
    /// Nearest and farthest point along the optical axis, mm.
    pub depth_mm: (f64, f64),
}

/// The result of [`calibrate_lasers`].
#[derive(Clone, Debug, PartialEq)]
pub struct LaserCalibration {
    /// Per laser, left to right.
    pub planes: [LaserPlane; LASERS],
    /// The datum: unit normal towards the camera and `d_mm < 0`.
    pub datum: ([f64; 3], f64),
    /// Per pose (pair), or why it was not used.
    pub poses: Vec<Result<PoseReport, String>>,
}

/// A laser-off / laser-on pair.
pub struct Pair {
    /// Lasers off.
    pub off: Rows,
    /// Lasers on.
    pub on: Rows,
    /// For messages.
    pub name: String,
}

fn gray(r: &Rows) -> Vec<f32> {
    match r.pixels() {
        Pixels::U8(v) => v.iter().map(|&p| f32::from(p)).collect(),
        Pixels::U16(v) => v.iter().map(|&p| f32::from(p)).collect(),
    }
}

fn value(r: &Rows, i: usize) -> u16 {
    match r.pixels() {
        Pixels::U8(v) => u16::from(v[i]),
        Pixels::U16(v) => v[i],
    }
}

/// Points per laser, camera frame, mm.
type PerLaser = [Vec<[f64; 3]>; LASERS];

/// The stripe points of one pair on the board, camera frame, per laser.
fn pose_points(
    intr: &Intrinsics,
    board: &Board,
    pair: &Pair,
    det: &mut Detector<MAX_WIDTH>,
) -> Result<(PoseReport, PerLaser), String> {
    let (w, h) = (pair.off.width(), pair.off.height());
    if (pair.on.width(), pair.on.height()) != (w, h) {
        return Err(format!("the lasers-on image is {}×{}, the lasers-off {w}×{h}", pair.on.width(), pair.on.height()));
    }
    if (w as u32, h as u32) != (intr.width_px, intr.height_px) {
        return Err(format!("{w}×{h} images; the camera was calibrated at {}×{}", intr.width_px, intr.height_px));
    }
    let corners = super::board::find_corners(&gray(&pair.off), w, h, board).map_err(|e| format!("board: {e}"))?;
    let (pose, board_rms_px) =
        super::camera::board_pose(intr, board, &corners).map_err(|e| format!("board pose: {e}"))?;
    let (n, d) = pose.plane();
    let s = board.square_mm;
    let (x_max, y_max) = (board.cols as f64 * s, board.rows as f64 * s);
    // The lasers-off image's bright level: a stripe counts only where the
    // board under it is uniformly white (on black squares it is 17× weaker,
    // and across a checker edge the reflectance step moves its centre).
    let mut sorted: Vec<u16> = (0..w * h).step_by(7).map(|i| value(&pair.off, i)).collect();
    sorted.sort_unstable();
    let white = f64::from(sorted[sorted.len() * 95 / 100]);
    let uniform_white = |u: f64, v: usize, sigma: f64| {
        let half = (3.0 * sigma + 2.0).ceil() as isize;
        let (c, v) = (u.round() as isize, v as isize);
        let (mut lo, mut hi) = (f64::MAX, 0.0f64);
        for y in (v - 2).max(0)..=(v + 2).min(h as isize - 1) {
            for x in (c - half).max(0)..=(c + half).min(w as isize - 1) {
                let p = f64::from(value(&pair.off, y as usize * w + x as usize));
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        hi >= 0.5 * white && lo >= 0.75 * hi
    };
    // Every row's stripes.
    let mut rows: Vec<Vec<(f64, f64)>> = Vec::with_capacity(h);
    let mut diff = vec![0u16; w];
    for v in 0..h {
        for (u, o) in diff.iter_mut().enumerate() {
            let i = v * w + u;
            *o = value(&pair.on, i).saturating_sub(value(&pair.off, i));
        }
        let mut stripes: Stripes<{ LASERS + 1 }> = Stripes::new();
        // A row the detector cannot take (it validated its configuration) has no stripe.
        let _ = det.detect(&diff, &mut stripes);
        let mut r: Vec<(f64, f64)> = stripes.iter().map(|s| (s.position.to_f64(), s.width.to_f64())).collect();
        r.sort_by(|a, b| a.0.total_cmp(&b.0));
        rows.push(r);
    }
    // Which stripe is which laser: each laser's line across the image,
    // u(v) quadratic, from the rows that show all of them (left to right);
    // then every stripe of every row goes to the nearest line, if near.
    let mut lines = Vec::with_capacity(LASERS);
    for k in 0..LASERS {
        let obs: Vec<(f64, f64)> =
            rows.iter().enumerate().filter(|(_, r)| r.len() == LASERS).map(|(v, r)| (v as f64, r[k].0)).collect();
        if obs.len() < 10 {
            return Err(format!("laser {k}: only {} rows show every laser's stripe", obs.len()));
        }
        lines.push(quadratic(&obs));
    }
    let mut pts: [Vec<[f64; 3]>; LASERS] = Default::default();
    let mut ambiguous = 0;
    for (v, r) in rows.iter().enumerate() {
        let mut taken = [false; LASERS];
        for &(u, sigma) in r {
            let dist: Vec<f64> = lines.iter().map(|c| (eval(c, v as f64) - u).abs()).collect();
            let k = (0..LASERS).min_by(|&a, &b| dist[a].total_cmp(&dist[b])).unwrap_or(0);
            if dist[k] > (2.0 * sigma).max(4.0) || std::mem::replace(&mut taken[k], true) {
                ambiguous += 1;
                continue;
            }
            if !uniform_white(u, v, sigma) {
                continue;
            }
            let ray = intr.unproject(u, v as f64);
            let den = n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2];
            if den.abs() < 1e-9 {
                continue;
            }
            let t = d / den;
            let x = [ray[0] * t, ray[1] * t, ray[2] * t];
            // On the printed board (its outer squares included)?
            let rel = [x[0] - pose.t_mm[0], x[1] - pose.t_mm[1], x[2] - pose.t_mm[2]];
            let r = &pose.rot;
            let bx = r[0][0] * rel[0] + r[1][0] * rel[1] + r[2][0] * rel[2];
            let by = r[0][1] * rel[0] + r[1][1] * rel[1] + r[2][1] * rel[2];
            if t > 0.0 && bx >= -s && bx <= x_max && by >= -s && by <= y_max {
                pts[k].push(x);
            }
        }
    }
    let points = [pts[0].len(), pts[1].len(), pts[2].len()];
    Ok((PoseReport { pose, board_rms_px, points, ambiguous_rows: ambiguous }, pts))
}

/// Least-squares `u = c0 + c1·v + c2·v²` through `(v, u)` points (`v`
/// centred and scaled for conditioning).
fn quadratic(obs: &[(f64, f64)]) -> [f64; 5] {
    let n = obs.len() as f64;
    let mean = obs.iter().map(|o| o.0).sum::<f64>() / n;
    let scale = obs.iter().map(|o| (o.0 - mean).abs()).fold(1.0, f64::max);
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    for &(v, u) in obs {
        let t = (v - mean) / scale;
        let row = Vector3::new(1.0, t, t * t);
        a += row * row.transpose();
        b += row * u;
    }
    let c = a.try_inverse().map_or(Vector3::new(obs[0].1, 0.0, 0.0), |inv| inv * b);
    [c[0], c[1], c[2], mean, scale]
}

fn eval(c: &[f64; 5], v: f64) -> f64 {
    let t = (v - c[3]) / c[4];
    c[0] + t * (c[1] + t * c[2])
}

/// Total-least-squares plane of `pts`: (unit normal with `d < 0`, d, RMS,
/// the middle singular spread in mm — near 0 for collinear points).
fn tls_plane(pts: &[[f64; 3]]) -> ([f64; 3], f64, f64, f64) {
    let n = pts.len() as f64;
    let mut c = Vector3::zeros();
    for p in pts {
        c += Vector3::from(*p);
    }
    c /= n;
    let mut m = Matrix3::zeros();
    for p in pts {
        let q = Vector3::from(*p) - c;
        m += q * q.transpose();
    }
    let eig = SymmetricEigen::new(m / n);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let mut normal: Vector3<f64> = eig.eigenvectors.column(order[0]).into();
    let mut d = normal.dot(&c);
    if d > 0.0 {
        normal = -normal;
        d = -d;
    }
    let rms = eig.eigenvalues[order[0]].max(0.0).sqrt();
    let spread = eig.eigenvalues[order[1]].max(0.0).sqrt();
    ([normal.x, normal.y, normal.z], d, rms, spread)
}

fn fit(k: usize, pts: &[[f64; 3]], poses: usize, max_rms_mm: f64) -> Result<LaserPlane, String> {
    if poses < 3 {
        return Err(format!("laser {k}: points from {poses} poses; a plane needs at least 3 at different depths"));
    }
    let (mut n, mut d, _, spread) = tls_plane(pts);
    if spread < 1.0 {
        return Err(format!(
            "laser {k}: the points are nearly on one line (spread {spread:.2} mm): vary the board's depth"
        ));
    }
    // One robust pass: drop points beyond 5 robust σ (median absolute residual × 1.4826).
    let mut kept: Vec<[f64; 3]> = pts.to_vec();
    let mut res: Vec<f64> = kept.iter().map(|p| (n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - d).abs()).collect();
    let mut sorted = res.clone();
    sorted.sort_by(f64::total_cmp);
    let sigma = 1.4826 * sorted[sorted.len() / 2];
    if sigma > 0.0 {
        let mut i = 0;
        kept.retain(|_| {
            let keep = res[i] <= 5.0 * sigma;
            i += 1;
            keep
        });
        (n, d, _, _) = tls_plane(&kept);
        res = kept.iter().map(|p| n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - d).collect();
    }
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    if rms > max_rms_mm {
        return Err(format!(
            "laser {k}: its points are {rms:.3} mm RMS from their plane (limit {max_rms_mm} mm): stripes assigned to the wrong laser, or a bad camera calibration"
        ));
    }
    let (_, _, _, spread_mm) = tls_plane(&kept);
    let depth_mm = kept.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[2]), hi.max(p[2])));
    Ok(LaserPlane {
        normal: n,
        d_mm: d,
        rms_mm: rms,
        points: kept.len(),
        outliers: pts.len() - kept.len(),
        poses,
        spread_mm,
        depth_mm,
    })
}

/// Why the laser planes could not be calibrated; each says the option,
/// the laser or the image pair concerned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LaserCalibError {
    /// The detector's scale range (`--scales`).
    #[error("--scales: {0}")]
    Scales(cms_core::optics::OpticsError),
    /// The detector refused its configuration for images of this depth.
    #[error("detector for {bits}-bit images: {source}")]
    Detector {
        /// The images' bit depth.
        bits: u8,
        /// The detector's error.
        source: cms_core::peak::Error,
    },
    /// A laser's points make no plane.
    #[error("{0}")]
    Plane(String),
    /// The pose chosen for the datum (`--datum-pose`, from 1) is not usable.
    #[error("--datum-pose {pose}: {why}")]
    DatumPose {
        /// The pose, from 1.
        pose: usize,
        /// Why.
        why: String,
    },
    /// No datum without `--datum-pose`.
    #[error("the middle laser's plane contains the optical axis: give --datum-pose")]
    NoDatum,
    /// The completed file gives no calibration message for the head.
    #[error(transparent)]
    File(crate::calib::file::FileError),
    /// The head's triangulation cannot use the fitted planes.
    #[error("the fitted planes are unusable: {0}")]
    Unusable(String),
}

/// Calibrates the laser planes from image pairs of `board` seen by a camera
/// with intrinsics `intr`.
pub fn calibrate_lasers(
    intr: &Intrinsics,
    board: &Board,
    pairs: &[Pair],
    opts: &LaserOptions,
) -> Result<LaserCalibration, LaserCalibError> {
    let scales =
        ScaleRange::new(Px::from_f64(opts.scales.0), Px::from_f64(opts.scales.1)).map_err(LaserCalibError::Scales)?;
    let bits = pairs.first().map_or(8, |p| p.on.bits());
    let mut cfg = Config::new(bits, scales);
    cfg.max_stripes = LASERS as u8 + 1; // one more than lasers: a spurious stripe makes the row ambiguous
    cfg.select = Select::Strongest;
    let mut det: Box<Detector<MAX_WIDTH>> =
        Box::new(Detector::new(cfg).map_err(|source| LaserCalibError::Detector { bits, source })?);
    let mut all: [Vec<[f64; 3]>; LASERS] = Default::default();
    let mut contributing = [0usize; LASERS];
    let mut poses = Vec::new();
    for pair in pairs {
        if pair.off.width() > MAX_WIDTH {
            poses.push(Err(format!("{}: wider than {MAX_WIDTH} px", pair.name)));
            continue;
        }
        match pose_points(intr, board, pair, &mut det) {
            Ok((report, pts)) => {
                for (k, p) in pts.into_iter().enumerate() {
                    if p.len() >= MIN_POINTS_PER_POSE {
                        contributing[k] += 1;
                        all[k].extend(p);
                    }
                }
                poses.push(Ok(report));
            }
            Err(e) => poses.push(Err(format!("{}: {e}", pair.name))),
        }
    }
    let mut planes = Vec::with_capacity(LASERS);
    for k in 0..LASERS {
        planes.push(fit(k, &all[k], contributing[k], opts.max_rms_mm).map_err(LaserCalibError::Plane)?);
    }
    let planes: [LaserPlane; LASERS] = [planes[0], planes[1], planes[2]];
    let datum = match opts.datum_pose {
        Some(i) => match poses.get(i) {
            Some(Ok(r)) => {
                let (n, d) = r.pose.plane();
                if d > 0.0 { ([-n[0], -n[1], -n[2]], -d) } else { (n, d) }
            }
            Some(Err(e)) => return Err(LaserCalibError::DatumPose { pose: i + 1, why: e.clone() }),
            None => {
                let why = format!("there are {} pairs", poses.len());
                return Err(LaserCalibError::DatumPose { pose: i + 1, why });
            }
        },
        None => {
            let m = &planes[LASERS / 2];
            if m.normal[2].abs() < 1e-6 {
                return Err(LaserCalibError::NoDatum);
            }
            ([0.0, 0.0, -1.0], -(m.d_mm / m.normal[2]).abs())
        }
    };
    Ok(LaserCalibration { planes, datum, poses })
}

impl LaserCalibration {
    /// Completes a camera-only calibration `file` with these planes, their
    /// datum and, if given, the `[head]` section; refuses planes the head's
    /// triangulation could not use (the head would refuse them too).
    pub fn complete(&self, file: &mut CalibrationFile, head: Option<HeadSection>) -> Result<(), LaserCalibError> {
        let (n, d_mm) = self.datum;
        file.datum = Some(PlaneSection { nx: n[0], ny: n[1], nz: n[2], d_mm });
        file.lasers = self
            .planes
            .iter()
            .enumerate()
            .map(|(k, l)| LaserSection {
                id: k as u32,
                nx: l.normal[0],
                ny: l.normal[1],
                nz: l.normal[2],
                d_mm: l.d_mm,
                rms_mm: l.rms_mm,
                points: Some(l.points as u64),
                spread_mm: Some(l.spread_mm),
                depth_min_mm: Some(l.depth_mm.0),
                depth_max_mm: Some(l.depth_mm.1),
            })
            .collect();
        if head.is_some() {
            file.head = head;
        }
        let msg = file.to_head().map_err(LaserCalibError::File)?;
        cms_core::pipeline::triangulator(&msg).map_err(|e| LaserCalibError::Unusable(e.to_string()))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tls_plane_recovers_a_known_plane_and_refuses_a_line() {
        let n = [0.8f64, 0.0, -0.6];
        let d = -120.0;
        // Points on the plane: X = p0 + a·e1 + b·e2, with a little deterministic "noise".
        let p0 = [n[0] * d, n[1] * d, n[2] * d];
        let (e1, e2) = ([0.6, 0.0, 0.8], [0.0, 1.0, 0.0]);
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..5 {
                let (a, b) = (i as f64 - 20.0, 4.0 * j as f64);
                let wobble = 0.01 * ((i * 7 + j * 3) % 5) as f64 - 0.02;
                pts.push([0, 1, 2].map(|k| p0[k] + a * e1[k] + b * e2[k] + wobble * n[k]));
            }
        }
        let (m, dd, rms, spread) = tls_plane(&pts);
        assert!((m[0] - 0.8).abs() < 1e-4 && m[1].abs() < 1e-4 && (m[2] + 0.6).abs() < 1e-4, "{m:?}");
        assert!((dd - d).abs() < 0.01 && dd < 0.0, "{dd}");
        assert!(rms > 0.005 && rms < 0.02, "{rms}");
        assert!(spread > 1.0);
        let line: Vec<[f64; 3]> = (0..50).map(|i| [0, 1, 2].map(|k| p0[k] + i as f64 * e1[k])).collect();
        let e = fit(0, &line, 3, 0.1).unwrap_err();
        assert!(e.contains("nearly on one line"), "{e}");
        assert!(fit(0, &pts, 2, 0.1).unwrap_err().contains("2 poses"));
        let p = fit(1, &pts, 3, 0.1).unwrap();
        assert_eq!((p.points, p.outliers), (200, 0));
        assert!(fit(1, &pts, 3, 0.001).unwrap_err().contains("wrong laser"));
    }

    #[test]
    fn quadratic_fits_a_curved_line() {
        let obs: Vec<(f64, f64)> =
            (0..480).step_by(5).map(|v| (v as f64, 300.0 + 0.1 * v as f64 - 2e-4 * (v * v) as f64)).collect();
        let c = quadratic(&obs);
        for v in [0.0, 123.0, 479.0] {
            assert!((eval(&c, v) - (300.0 + 0.1 * v - 2e-4 * v * v)).abs() < 1e-9);
        }
    }
}
