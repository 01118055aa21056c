//! Calibration poses: tilted views spread over the image, each checked for what calibration needs to see.

use super::{BoardRenderer, POSE_STREAM, RenderOptions};
use crate::model::board::{Board, BoardPose};
use crate::model::vec3::{Vec3, dot, normalized};
use crate::sim::scene::Scene;
use crate::sim::scene::noise::Rng;

/// Rotation by `angle` (radians) about the unit axis `a` (Rodrigues).
pub(super) fn rot_axis(a: Vec3, angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    [
        [c + a[0] * a[0] * t, a[0] * a[1] * t - a[2] * s, a[0] * a[2] * t + a[1] * s],
        [a[1] * a[0] * t + a[2] * s, c + a[1] * a[1] * t, a[1] * a[2] * t - a[0] * s],
        [a[2] * a[0] * t - a[1] * s, a[2] * a[1] * t + a[0] * s, c + a[2] * a[2] * t],
    ]
}

pub(super) fn mat_mul3(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    m
}

/// Length of the line `g0 + gx·x + gy·y = 0` inside `[0, wx] × [0, wy]`.
pub(super) fn segment_in_rect(g: [f64; 3], wx: f64, wy: f64) -> f64 {
    let n2 = g[1] * g[1] + g[2] * g[2];
    if n2 < 1e-18 {
        return 0.0;
    }
    let n = n2.sqrt();
    let p = [-g[0] * g[1] / n2, -g[0] * g[2] / n2];
    let d = [-g[2] / n, g[1] / n];
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for (axis, max) in [(0, wx), (1, wy)] {
        if d[axis].abs() < 1e-15 {
            if p[axis] < 0.0 || p[axis] > max {
                return 0.0;
            }
            continue;
        }
        let (t0, t1) = ((0.0 - p[axis]) / d[axis], (max - p[axis]) / d[axis]);
        lo = lo.max(t0.min(t1));
        hi = hi.min(t0.max(t1));
    }
    (hi - lo).max(0.0)
}

/// What a candidate pose is worth: `None` if it breaks a rule, else how
/// well the lasers cross the board (min over lasers of the crossing's
/// length / the inner corners' height, capped at 1).
pub(super) fn pose_quality(r: &BoardRenderer, board: &Board, pose: &BoardPose) -> Option<f64> {
    let cam = &r.cfg.camera;
    let [zmin, zmax] = r.cfg.head.working_range_mm;
    let s = board.square_mm;
    let (wx, wy) = ((board.cols - 1) as f64 * s, (board.rows - 1) as f64 * s);
    let margin = 0.02 * cam.width_px() as f64;
    let inside = |p: [f64; 3]| {
        cam.intrinsics.project(p).is_some_and(|uv| {
            uv[0] >= margin
                && uv[0] <= cam.width_px() as f64 - 1.0 - margin
                && uv[1] >= margin
                && uv[1] <= cam.height_px() as f64 - 1.0 - margin
        })
    };
    // Every inner corner in the working range and in the image; the outer
    // squares' boundary (corners and edge midpoints) in the image.
    for q in board.object_points() {
        let c = pose.to_camera(q);
        if c[2] < zmin || c[2] > zmax || !inside(c) {
            return None;
        }
    }
    let (x0, x1, y0, y1) = (-s, board.cols as f64 * s, -s, board.rows as f64 * s);
    let (xm, ym) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    for q in [[x0, y0], [xm, y0], [x1, y0], [x1, ym], [x1, y1], [xm, y1], [x0, y1], [x0, ym]] {
        if !inside(pose.to_camera([q[0], q[1], 0.0])) {
            return None;
        }
    }
    // Seen from the front, not too obliquely.
    let (n, _) = pose.plane();
    let centre = pose.to_camera([xm, ym, 0.0]);
    if dot(n, normalized(centre)) < 0.42 {
        return None;
    }
    // Every laser crosses the inner corners' area, not at grazing incidence.
    let mut worst: f64 = 1.0;
    for l in r.lasers_for(pose, 0xff) {
        let k = r.planes.iter().position(|p| *p == l.plane).unwrap_or(0);
        if dot(r.beams[k], n).abs() < 0.3 {
            return None;
        }
        worst = worst.min(segment_in_rect(l.g, wx, wy) / wy);
    }
    (worst >= 0.75).then_some(worst.min(1.0))
}

/// `n` board poses for calibrating `scene`'s head with `board`, deterministic
/// in `seed`.
///
/// Each pose: the board tilted by 15–40° about an in-plane axis, the pair
/// (axis direction, tilt) chosen by farthest-point sampling of the board's
/// normal (each pose's normal as far as possible from all earlier ones), so
/// no two views are near parallel — Zhang's method needs non-parallel views
/// — and the set covers every direction evenly; turned ±12° in its
/// plane, its centre at a depth spread over the working range (a
/// low-discrepancy sequence: every `n` covers it evenly) with every inner
/// corner inside the working range, then placed across the image nearest a
/// target point (another low-discrepancy sequence, so the corners cover the
/// image, which the distortion needs) among the placements where the outer
/// squares are inside the image with a 2 % margin, the board faces the
/// camera (< 65° obliquity) and every laser's line crosses at least 3/4 of
/// the inner corners' height at an incidence cosine ≥ 0.3. If no placement
/// qualifies the tilt is reduced by 5° steps (the last resort is the
/// fronto-parallel board at the standoff). The seed jitters angles, depths
/// and targets.
pub fn calibration_poses(scene: &Scene, board: &Board, n: usize, seed: u64) -> Vec<BoardPose> {
    let r = BoardRenderer::new(scene, RenderOptions::default());
    tilts(n, seed).into_iter().enumerate().map(|(k, t)| pose_k(&r, board, k, n, seed, t)).collect()
}

/// The board normal of a tilt `θ` (degrees) about the in-plane axis at
/// azimuth `φ` (radians).
pub(super) fn tilt_normal(phi: f64, theta_deg: f64) -> Vec3 {
    let (st, ct) = theta_deg.to_radians().sin_cos();
    // Rotating ẑ about (cos φ, sin φ, 0).
    [st * phi.sin(), -st * phi.cos(), ct]
}

/// `n` (axis azimuth rad, tilt deg) pairs, tilts in 15–40°, by farthest-point
/// sampling of the board normals over a jittered grid: each new pose's
/// normal is as far as possible from every earlier one.
pub(super) fn tilts(n: usize, seed: u64) -> Vec<(f64, f64)> {
    let mut rng = Rng::for_stream(seed, POSE_STREAM, u64::MAX, 0);
    let mut cand = Vec::new();
    for i in 0..72 {
        for j in 0..6 {
            let phi = (5.0 * i as f64 + 5.0 * rng.uniform()).to_radians();
            let theta = 15.0 + 5.0 * j as f64 + 5.0 * rng.uniform();
            cand.push((phi, theta.min(40.0), tilt_normal(phi, theta.min(40.0))));
        }
    }
    let mut out: Vec<(f64, f64, Vec3)> = Vec::new();
    let first = (rng.next_u64() % cand.len() as u64) as usize;
    for _ in 0..n {
        let pick = if out.is_empty() {
            first
        } else {
            let mut best = (f64::NEG_INFINITY, 0);
            for (i, c) in cand.iter().enumerate() {
                let near = out.iter().map(|o| dot(o.2, c.2)).fold(f64::NEG_INFINITY, f64::max);
                if -near > best.0 {
                    best = (-near, i);
                }
            }
            best.1
        };
        out.push(cand[pick]);
    }
    out.into_iter().map(|(p, t, _)| (p, t)).collect()
}

pub(super) fn frac(x: f64) -> f64 {
    x - x.floor()
}

pub(super) fn pose_k(
    r: &BoardRenderer,
    board: &Board,
    k: usize,
    n: usize,
    seed: u64,
    (phi, theta0): (f64, f64),
) -> BoardPose {
    let cam = &r.cfg.camera;
    let [zmin, zmax] = r.cfg.head.working_range_mm;
    let mut rng = Rng::for_stream(seed, POSE_STREAM, k as u64, 0);
    let mut jit = |a: f64| a * (2.0 * rng.uniform() - 1.0);
    let kf = k as f64;
    let gamma = (12.0 * (2.0 * frac(0.1 + kf * 0.414_213_562) - 1.0) + jit(2.0)).to_radians();
    let q = (frac(0.5 + kf * 0.618_033_989) + jit(0.5 / n.max(1) as f64)).clamp(0.0, 1.0);
    let target = [
        (0.2 + 0.6 * frac(0.3 + kf * 0.324_717_957 + jit(0.05))) * (cam.width_px() - 1) as f64,
        (0.2 + 0.6 * frac(0.7 + kf * 0.732_050_808 + jit(0.05))) * (cam.height_px() - 1) as f64,
    ];
    let s = board.square_mm;
    let centre_b = [0.5 * (board.cols - 1) as f64 * s, 0.5 * (board.rows - 1) as f64 * s, 0.0];
    let axis = [phi.cos(), phi.sin(), 0.0];
    let rz = rot_axis([0.0, 0.0, 1.0], gamma);
    let diag = ((cam.width_px() * cam.width_px() + cam.height_px() * cam.height_px()) as f64).sqrt();
    let mut theta = theta0;
    loop {
        let rot = mat_mul3(&rot_axis(axis, theta.to_radians()), &rz);
        let rc = |p: [f64; 3]| {
            let d = [p[0] - centre_b[0], p[1] - centre_b[1], p[2]];
            [
                rot[0][0] * d[0] + rot[0][1] * d[1] + rot[0][2] * d[2],
                rot[1][0] * d[0] + rot[1][1] * d[1] + rot[1][2] * d[2],
                rot[2][0] * d[0] + rot[2][1] * d[1] + rot[2][2] * d[2],
            ]
        };
        let dz: Vec<f64> = board.object_points().into_iter().map(|p| rc(p)[2]).collect();
        let lo = zmin - dz.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = zmax - dz.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if lo <= hi {
            let zc = lo + q * (hi - lo);
            let mut best: Option<(f64, BoardPose)> = None;
            let (nx, ny) = (48, 24);
            for iy in 0..=ny {
                for ix in 0..=nx {
                    let u = (ix as f64 / nx as f64) * (cam.width_px() - 1) as f64;
                    let v = (iy as f64 / ny as f64) * (cam.height_px() - 1) as f64;
                    let ray = cam.intrinsics.unproject(u, v);
                    let c = [ray[0] * zc, ray[1] * zc, zc];
                    let off = rc([0.0, 0.0, 0.0]);
                    let pose = BoardPose { rot, t_mm: [c[0] + off[0], c[1] + off[1], c[2] + off[2]] };
                    let Some(quality) = pose_quality(r, board, &pose) else { continue };
                    let dist = ((u - target[0]).powi(2) + (v - target[1]).powi(2)).sqrt() / diag;
                    let score = dist - 0.5 * quality;
                    if best.as_ref().is_none_or(|b| score < b.0) {
                        best = Some((score, pose));
                    }
                }
            }
            if let Some((_, pose)) = best {
                return pose;
            }
        }
        if theta <= 0.0 {
            break;
        }
        theta = (theta - 5.0).max(0.0);
    }
    // Last resort: fronto-parallel at the standoff, centred on the image.
    let z = r.cfg.head.standoff_mm;
    BoardPose { rot: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], t_mm: [-centre_b[0], -centre_b[1], z] }
}
