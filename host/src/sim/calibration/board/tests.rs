//! Board images against their geometry, and poses a calibration can use.

use super::poses::pose_quality;
use super::*;
use crate::sim::scene::NoiseModel;
use crate::sim::scene::Scene;

fn quiet_scene(mut cfg: SimConfig) -> Scene {
    cfg.noise = NoiseModel::none();
    Scene::new(cfg).unwrap()
}

#[test]
fn boards_for_the_presets() {
    assert_eq!(board_for(&SimConfig::reference()), Board { cols: 9, rows: 6, square_mm: 6.0 });
    assert_eq!(board_for(&SimConfig::paper()), Board { cols: 9, rows: 6, square_mm: 21.5 });
}

/// Every pose keeps its rules, tilts 15–40° about varied axes and the
/// depths span the working range; lasers are left to right in index order.
fn check_poses(cfg: SimConfig, n: usize) {
    let scene = Scene::new(cfg).unwrap();
    let board = board_for(scene.config());
    let r = BoardRenderer::new(&scene, RenderOptions::default());
    let poses = calibration_poses(&scene, &board, n, 7);
    let (mut zs, mut normals) = (Vec::new(), Vec::<Vec3>::new());
    for (k, p) in poses.iter().enumerate() {
        let q = pose_quality(&r, &board, p);
        assert!(q.is_some(), "pose {k} breaks the rules");
        let (nrm, _) = p.plane();
        let tilt = nrm[2].acos().to_degrees();
        assert!((14.0..=41.0).contains(&tilt), "pose {k}: tilt {tilt}");
        for m in &normals {
            let angle = dot(*m, nrm).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(angle > 5.0, "pose {k} nearly parallel to another ({angle:.1}°)");
        }
        normals.push(nrm);
        let c = [0.5 * 8.0 * board.square_mm, 0.5 * 5.0 * board.square_mm, 0.0];
        zs.extend(board.object_points().into_iter().map(|q| p.to_camera(q)[2]));
        // Laser order: left to right along a middle row of the board.
        let cam = scene.camera();
        let mid = p.to_camera(c);
        let row = cam.intrinsics.project(mid).unwrap()[1];
        let cols: Vec<f64> = scene.laser_planes().iter().map(|pl| laser_column(cam, pl, p, row).unwrap()).collect();
        assert!(cols.windows(2).all(|w| w[0] < w[1]), "pose {k}: {cols:?}");
    }
    let [lo, hi] = scene.config().head.working_range_mm;
    let spread =
        zs.iter().copied().fold(f64::NEG_INFINITY, f64::max) - zs.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(spread > 0.75 * (hi - lo), "corners' depth spread {spread} mm");
}

#[test]
fn poses_reference() {
    check_poses(SimConfig::reference(), 16);
}

#[test]
fn poses_paper() {
    check_poses(SimConfig::paper(), 12);
}

/// Without blur, a pixel's lamp signal is the board's reflectance
/// averaged over the pixel: compare with dense supersampling through
/// the camera model (each sample cast on its own).
#[test]
fn area_coverage_matches_supersampling() {
    let scene = quiet_scene(SimConfig::reference());
    let opts = RenderOptions { psf_sigma_px: 0.0, ..RenderOptions::default() };
    let r = BoardRenderer::new(&scene, opts);
    let board = board_for(scene.config());
    let pose = calibration_poses(&scene, &board, 3, 1)[1];
    let sig = r.signal_e(&board, &pose, 0);
    let cam = scene.camera();
    let lamp = opts.lamp_fraction * cam.full_well_e;
    let w = cam.width_px();
    let n = 32;
    let (mut worst, mut count) = (0.0f64, 0);
    for q in board.object_points().iter().step_by(5) {
        let uv = cam.intrinsics.project(pose.to_camera(*q)).unwrap();
        for dv in -2..=2 {
            for du in -2..=2 {
                let (pu, pv) = (uv[0].round() as i64 + du, uv[1].round() as i64 + dv);
                let mut acc = 0.0;
                for i in 0..n {
                    for j in 0..n {
                        let u = pu as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                        let v = pv as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                        let b = board_point(cam, &pose, u, v).unwrap();
                        let s = board.square_mm;
                        acc += r
                            .square(&board, (b[0] / s).floor() as i64, (b[1] / s).floor() as i64)
                            .unwrap_or(opts.background);
                    }
                }
                let want = acc / (n * n) as f64;
                let got = sig[pv as usize * w + pu as usize] as f64 / lamp;
                worst = worst.max((got - want).abs() / (opts.white - opts.black));
                count += 1;
            }
        }
    }
    // A 32 × 32 grid resolves coverage to about 1/64 of the contrast.
    assert!(worst < 0.025, "worst coverage error {worst} of the contrast over {count} pixels");
}

/// Gradient-orthogonality corner refinement (as OpenCV's cornerSubPix).
fn refine_corner(img: &[f32], w: usize, guess: [f64; 2], half: i64) -> [f64; 2] {
    let mut c = guess;
    for _ in 0..50 {
        let (cx, cy) = (c[0].round() as i64, c[1].round() as i64);
        let (mut a, mut b, mut d, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for y in cy - half..=cy + half {
            for x in cx - half..=cx + half {
                let at = |x: i64, y: i64| img[y as usize * w + x as usize] as f64;
                let gx = 0.5 * (at(x + 1, y) - at(x - 1, y));
                let gy = 0.5 * (at(x, y + 1) - at(x, y - 1));
                let (xx, yy) = (x as f64, y as f64);
                let wgt = (-((xx - c[0]).powi(2) + (yy - c[1]).powi(2)) / (2.0 * (half as f64 / 2.0).powi(2))).exp();
                let (gxx, gxy, gyy) = (gx * gx * wgt, gx * gy * wgt, gy * gy * wgt);
                a += gxx;
                b += gxy;
                d += gyy;
                bx += gxx * xx + gxy * yy;
                by += gxy * xx + gyy * yy;
            }
        }
        let det = a * d - b * b;
        let n = [(d * bx - b * by) / det, (a * by - b * bx) / det];
        let step = ((n[0] - c[0]).powi(2) + (n[1] - c[1]).powi(2)).sqrt();
        c = n;
        if step < 1e-6 {
            break;
        }
    }
    c
}

/// The rendered saddle points are where the camera model projects the
/// board's corners (noise-free signal, with the lens blur).
#[test]
fn corners_where_the_model_projects_them() {
    let scene = quiet_scene(SimConfig::reference());
    let r = BoardRenderer::new(&scene, RenderOptions::default());
    let board = board_for(scene.config());
    let cam = scene.camera();
    let (mut errs, mut sum) = (Vec::new(), [0.0, 0.0]);
    for pose in calibration_poses(&scene, &board, 4, 3) {
        let t = std::time::Instant::now();
        let sig = r.signal_e(&board, &pose, 0);
        eprintln!("reference signal: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
        for q in board.object_points() {
            let uv = cam.intrinsics.project(pose.to_camera(q)).unwrap();
            let got = refine_corner(&sig, cam.width_px(), [uv[0] + 0.6, uv[1] - 0.4], 8);
            errs.push((got[0] - uv[0]).hypot(got[1] - uv[1]));
            sum[0] += got[0] - uv[0];
            sum[1] += got[1] - uv[1];
        }
    }
    let n = errs.len() as f64;
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let max = errs.iter().copied().fold(0.0, f64::max);
    let bias = [sum[0] / n, sum[1] / n];
    eprintln!("corners: RMS {rms:.4} px, max {max:.4} px, bias {bias:.4?} px over {n}");
    // The refinement itself (central-difference gradients) has about
    // 0.02 px RMS of pixel-locking error even on a fronto-parallel board
    // without distortion, where the rendering is exact; no bias.
    assert!(rms < 0.035 && max < 0.08, "RMS {rms}, max {max}");
    assert!(bias[0].abs() < 0.005 && bias[1].abs() < 0.005, "bias {bias:?}");
}

/// A board lying where the nominal rail top is shows the lasers as the
/// head sees them on the rail: same stripe centre and σ (plus the lens
/// blur), peak × white × laser gain.
#[test]
fn stripes_on_rail_plane_match_the_sim() {
    let mut cfg = SimConfig::reference();
    cfg.rail = crate::sim::scene::RailModel::flat();
    cfg.noise = NoiseModel::none();
    let scene = Scene::new(cfg).unwrap();
    let opts = RenderOptions { psf_sigma_px: 0.0, white: 1.0, black: 1.0, laser_gain: 1.0, ..Default::default() };
    let r = BoardRenderer::new(&scene, opts);
    // The rail top as a board: board x along the rail's y (columns),
    // board y along the rail's x (rows), z down into the rail.
    let p = scene.camera_pose();
    let ex = mat_t_vec(&p.rot, [0.0, 1.0, 0.0]);
    let ey = mat_t_vec(&p.rot, [1.0, 0.0, 0.0]);
    let ez = mat_t_vec(&p.rot, [0.0, 0.0, -1.0]);
    let board = Board { cols: 30, rows: 30, square_mm: 5.0 };
    let origin = p.rail_to_cam([-75.0, -75.0, 0.0]);
    let pose = BoardPose { rot: [[ex[0], ey[0], ez[0]], [ex[1], ey[1], ez[1]], [ex[2], ey[2], ez[2]]], t_mm: origin };
    let on = r.signal_e(&board, &pose, 1 << 1);
    let off = r.signal_e(&board, &pose, 0);
    let w = scene.width();
    let row = 240;
    let truth = scene.stripe_truth(0, row, 1).unwrap();
    let d: Vec<f64> = (0..w).map(|i| (on[row * w + i] - off[row * w + i]) as f64).collect();
    let lo = (truth.column_px - 6.0 * truth.sigma_px) as usize;
    let hi = (truth.column_px + 6.0 * truth.sigma_px) as usize;
    let m0: f64 = d[lo..=hi].iter().sum();
    let m1: f64 = (lo..=hi).map(|i| i as f64 * d[i]).sum::<f64>() / m0;
    let var: f64 = (lo..=hi).map(|i| (i as f64 - m1).powi(2) * d[i]).sum::<f64>() / m0;
    let sigma = (var - 1.0 / 12.0).sqrt();
    let peak_e = truth.peak_dn * scene.camera().gain_e_per_dn();
    let got_peak = m0 / (sigma * std::f64::consts::TAU.sqrt());
    eprintln!(
        "rail plane: centre {m1:.4} vs {:.4}, σ {sigma:.4} vs {:.4}, peak {got_peak:.1} vs {peak_e:.1} e",
        truth.column_px, truth.sigma_px
    );
    assert!((m1 - truth.column_px).abs() < 0.02);
    assert!((sigma / truth.sigma_px - 1.0).abs() < 0.01);
    assert!((got_peak / peak_e - 1.0).abs() < 0.01);
}
