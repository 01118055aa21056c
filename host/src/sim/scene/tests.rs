//! Behaviour of the simulated head: rendered stripes against their truth and
//! against `cms_core`'s detector, triangulation, noise, determinism.

use super::*;
use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Flags, Stripes};

fn scales(min: f64, max: f64) -> ScaleRange {
    ScaleRange::new(Px::from_f64(min), Px::from_f64(max)).unwrap()
}

fn quiet(mut cfg: SimConfig) -> SimConfig {
    cfg.noise = NoiseModel::none();
    cfg
}

fn no_distortion(mut cfg: SimConfig) -> SimConfig {
    let c = &mut cfg.camera.intrinsics;
    (c.k1, c.k2, c.p1, c.p2, c.k3) = (0.0, 0.0, 0.0, 0.0, 0.0);
    cfg
}

/// Detections of a frame matched to its truth: (found, total, errors).
fn match_frame<const W: usize>(
    det: &mut Detector<W>,
    img: &[u16],
    width: usize,
    truth: &FrameTruth,
    lasers: &[usize],
) -> (usize, usize, Vec<f64>) {
    let mut out: Stripes<8> = Stripes::new();
    let (mut found, mut total) = (0, 0);
    let mut errs = Vec::new();
    for (r, row) in img.chunks_exact(width).enumerate() {
        det.detect(row, &mut out).unwrap();
        for &k in lasers {
            let Some(t) = truth.stripes[k][r] else { continue };
            total += 1;
            let best = out.iter().map(|s| s.position.to_f64() - t.column_px).min_by(|a, b| a.abs().total_cmp(&b.abs()));
            if let Some(e) = best.filter(|e| e.abs() < 1.5) {
                found += 1;
                errs.push(e);
            }
        }
    }
    (found, total, errs)
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

#[test]
fn detector_finds_rendered_stripes_reference() {
    let cfg = SimConfig::default();
    let mut scene = Scene::new(cfg).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut det = Detector::<1024>::new(Config::new(scene.bits(), scales(1.5, 4.0))).unwrap();
    let mut img = vec![0u16; w * h];
    let (mut found, mut total) = (0, 0);
    let mut errs = Vec::new();
    let mut per_laser = [const { Vec::new() }; 3];
    for frame in 0..4 {
        let truth = scene.render_frame(frame, scene.all_lasers_mask(), &mut img);
        for (k, pl) in per_laser.iter_mut().enumerate() {
            let (f, t, e) = match_frame(&mut det, &img, w, &truth, &[k]);
            found += f;
            total += t;
            pl.extend_from_slice(&e);
            errs.extend(e);
        }
    }
    let rate = found as f64 / total as f64;
    let bias = errs.iter().sum::<f64>() / errs.len() as f64;
    println!(
        "reference: {found}/{total} stripes found ({:.3} %), RMS error {:.4} px, bias {bias:+.4} px, per laser {:.4} / {:.4} / {:.4} px",
        100.0 * rate,
        rms(&errs),
        rms(&per_laser[0]),
        rms(&per_laser[1]),
        rms(&per_laser[2]),
    );
    assert_eq!(total, 4 * 3 * h, "every row of every frame has three stripes in the image");
    assert!(rate >= 0.99, "found {rate}");
    assert!(rms(&errs) <= 0.05, "RMS {}", rms(&errs));
}

#[test]
fn noise_free_render_is_exactly_centred() {
    // Without noise only quantisation remains: the detector lands within a
    // few thousandths of a pixel of the truth.
    let mut scene = Scene::new(quiet(SimConfig::default())).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut det = Detector::<1024>::new(Config::new(scene.bits(), scales(1.5, 4.0))).unwrap();
    let mut img = vec![0u16; w * h];
    let truth = scene.render_frame(3, scene.all_lasers_mask(), &mut img);
    let (found, total, errs) = match_frame(&mut det, &img, w, &truth, &[0, 1, 2]);
    println!("noise-free: {found}/{total}, RMS {:.4} px", rms(&errs));
    assert_eq!(found, total);
    assert!(rms(&errs) < 0.02, "{}", rms(&errs));
}

#[test]
fn stripe_profile_is_the_gaussian_of_the_truth() {
    let mut cfg = quiet(SimConfig::default());
    cfg.camera.bits = 12;
    let mut scene = Scene::new(cfg).unwrap();
    let mut row = vec![0u16; scene.width()];
    let t = scene.render_row(0, 100, 0b010, &mut row);
    assert!(t.stripes[0].is_none() && t.stripes[2].is_none());
    let s = t.stripes[1].unwrap();
    assert!((s.sigma_px - 3.011).abs() < 0.02, "{s:?}");
    // Integrated over the pixels: total light = peak·σ·√(2π).
    let sum: f64 = row.iter().map(|&v| v as f64).sum();
    let want = s.peak_dn * s.sigma_px * std::f64::consts::TAU.sqrt();
    assert!((sum / want - 1.0).abs() < 0.002, "{sum} vs {want}");
    // Symmetric about the true centre: first moment.
    let m1: f64 = row.iter().enumerate().map(|(i, &v)| i as f64 * v as f64).sum::<f64>() / sum;
    assert!((m1 - s.column_px).abs() < 0.01, "{m1} vs {}", s.column_px);
    // Peak pixel near the truth peak (a pixel-wide box lowers it by ~1 %).
    let max = *row.iter().max().unwrap() as f64;
    assert!(max <= s.peak_dn + 0.5 && max > 0.97 * s.peak_dn, "{max} vs {}", s.peak_dn);
}

#[test]
fn flat_rail_gives_constant_columns() {
    for crown in [None, Some(300.0)] {
        let mut cfg = quiet(no_distortion(SimConfig::default()));
        cfg.rail = RailModel { crown_radius_mm: crown, ..RailModel::flat() };
        let scene = Scene::new(cfg).unwrap();
        let t = scene.frame_truth(5, 0b111);
        for k in 0..3 {
            let cols: Vec<f64> = t.stripes[k].iter().map(|s| s.unwrap().column_px).collect();
            let (lo, hi) = cols.iter().fold((f64::MAX, f64::MIN), |(a, b), &c| (a.min(c), b.max(c)));
            assert!(hi - lo < 1e-9, "laser {k}, crown {crown:?}: {lo}..{hi}");
            let heights = t.stripes[k].iter().map(|s| s.unwrap().height_um);
            assert!(heights.clone().all(|z| (z - t.stripes[k][0].unwrap().height_um).abs() < 1e-9));
        }
        // Lines 10 mm apart: 70 px at 200 mm (plus the crown's effect on the outer ones).
        let c: Vec<f64> = (0..3).map(|k| t.column_px(k, 0).unwrap()).collect();
        assert!((c[1] - c[0] - 70.0).abs() < 1.0 && (c[2] - c[1] - 70.0).abs() < 1.0, "{c:?}");
    }
    // With the lens's distortion the stripes bend, and exactly as the
    // distortion says: undistorted, the column is constant again.
    let mut cfg = quiet(SimConfig::default());
    cfg.rail = RailModel::flat();
    let scene = Scene::new(cfg).unwrap();
    let cam = *scene.camera();
    let t = scene.frame_truth(0, 0b111);
    let mut bends = Vec::new();
    for k in 0..3 {
        let cols: Vec<f64> = t.stripes[k].iter().map(|s| s.unwrap().column_px).collect();
        let bend = cols.iter().fold(f64::MIN, |a, &c| a.max(c)) - cols.iter().fold(f64::MAX, |a, &c| a.min(c));
        bends.push(bend);
        assert!(bend < 1.0, "laser {k}: distortion bends the stripe by {bend} px");
        let und: Vec<f64> = cols
            .iter()
            .enumerate()
            .map(|(r, &u)| cam.intrinsics.unproject(u, r as f64)[0] * cam.intrinsics.fx_px + cam.intrinsics.cx_px)
            .collect();
        let spread = und.iter().fold(f64::MIN, |a, &c| a.max(c)) - und.iter().fold(f64::MAX, |a, &c| a.min(c));
        assert!(spread < 1e-6, "laser {k}: {spread}");
    }
    println!("distortion bends the flat-rail stripes by {bends:.3?} px");
    assert!(bends[0] > 0.05 && bends[2] > 0.05, "{bends:?}");
}

/// A single corrugation component and nothing else.
fn corrugated(amplitude_um: f64, wavelength_mm: f64) -> RailModel {
    RailModel { corrugation: vec![Corrugation { wavelength_mm, amplitude_um, phase_rad: 0.3 }], ..RailModel::flat() }
}

#[test]
fn corrugation_shift_matches_triangulation_closed_form() {
    // Camera straight down, no distortion: a surface point (x, y, z) is at
    // camera (y − y_a, x, Z0 − z); the line of laser k at height z is at
    // y = y_k − z·tan α. Row r sees x = (r − cy)(Z0 − z)/fy with z = h(x):
    // solved here by fixed point, independently of the scene's solver.
    let (a_um, lambda) = (100.0, 50.0);
    let mut cfg = quiet(no_distortion(SimConfig::default()));
    cfg.rail = corrugated(a_um, lambda);
    let scene = Scene::new(cfg.clone()).unwrap();
    let cam = *scene.camera();
    let (z0, tan_a) = (cfg.head.standoff_mm, cfg.head.alpha_deg.to_radians().tan());
    let frame = 2;
    let odo = scene.odometer_mm(frame);
    let h = |x: f64| a_um * 1e-3 * (std::f64::consts::TAU * x / lambda + 0.3).sin();
    let mut worst_exact: f64 = 0.0;
    let mut worst_linear: f64 = 0.0;
    for k in 0..3 {
        let yk = cfg.lasers[k].offset_mm;
        let u_flat = cam.intrinsics.fx_px * yk / z0 + cam.intrinsics.cx_px;
        for r in (0..scene.height()).step_by(7) {
            let mut z = 0.0;
            for _ in 0..50 {
                z = h(odo + (r as f64 - cam.intrinsics.cy_px) * (z0 - z) / cam.intrinsics.fy_px);
            }
            let u = cam.intrinsics.fx_px * (yk - z * tan_a) / (z0 - z) + cam.intrinsics.cx_px;
            let t = scene.stripe_truth(frame, r, k).unwrap();
            worst_exact = worst_exact.max((t.column_px - u).abs());
            assert!((t.height_um - z * 1e3).abs() < 1e-6);
            // First order: Δu = fx·Δz·(y_k − Z0·tan α)/Z0².
            let du = cam.intrinsics.fx_px * z * (yk - z0 * tan_a) / (z0 * z0);
            worst_linear = worst_linear.max((t.column_px - u_flat - du).abs() / (a_um * 1e-3 * 4.9));
        }
    }
    println!("closed form: worst |Δ| {worst_exact:.2e} px; first-order formula within {:.2} %", 100.0 * worst_linear);
    assert!(worst_exact < 1e-6, "{worst_exact}");
    assert!(worst_linear < 0.03, "{worst_linear}");
}

#[test]
fn corrugation_shift_matches_direct_projection_with_distortion() {
    // Reference camera (distortion, off-centre principal point), rail with a
    // crown: project the displaced surface point directly and compare.
    let (a_um, lambda) = (100.0, 50.0);
    let mut cfg = quiet(SimConfig::default());
    cfg.rail = RailModel { crown_radius_mm: Some(300.0), ..corrugated(a_um, lambda) };
    let bumpy = Scene::new(cfg.clone()).unwrap();
    cfg.rail.corrugation.clear();
    let flat = Scene::new(cfg).unwrap();
    let pose = bumpy.camera_pose();
    let cam = *bumpy.camera();
    let frame = 1;
    let (mut worst, mut max_shift): (f64, f64) = (0.0, 0.0);
    for k in 0..3 {
        let plane = pose.plane_to_rail(&bumpy.laser_planes()[k]);
        let n = plane.normal;
        for r in (1..bumpy.height() - 1).step_by(5) {
            let f = flat.stripe_truth(frame, r, k).unwrap();
            let x0 = f.x_mm - bumpy.odometer_mm(frame);
            let dz = bumpy.profile_um(f.x_mm) * 1e-3;
            // The plane at the raised surface (crown included, by Newton).
            let mut y = f.y_mm;
            for _ in 0..20 {
                let crown = (300.0f64 * 300.0 - y * y).sqrt() - 300.0;
                let g = n[0] * x0 + n[1] * y + n[2] * (dz + crown) - plane.d_mm;
                let dg = n[1] - n[2] * y / (300.0f64 * 300.0 - y * y).sqrt();
                y -= g / dg;
            }
            let crown = (300.0f64 * 300.0 - y * y).sqrt() - 300.0;
            let uv = cam.intrinsics.project(pose.rail_to_cam([x0, y, dz + crown])).unwrap();
            // The raised point images a fraction of a row off r: follow the stripe there.
            let t = bumpy.stripe_truth(frame, r, k).unwrap();
            let slope = (bumpy.stripe_truth(frame, r + 1, k).unwrap().column_px
                - bumpy.stripe_truth(frame, r - 1, k).unwrap().column_px)
                / 2.0;
            let u = uv[0] + slope * (r as f64 - uv[1]);
            worst = worst.max((t.column_px - u).abs());
            max_shift = max_shift.max((t.column_px - f.column_px).abs());
        }
    }
    println!("direct projection: worst |Δ| {worst:.2e} px, largest shift {max_shift:.3} px");
    assert!(worst < 2e-3, "{worst}");
    assert!((max_shift - 0.1 * 4.9).abs() < 0.05, "{max_shift}");
}

#[test]
fn detected_corrugation_amplitude_through_triangulation() {
    // End to end: render with noise, detect, triangulate each detection onto
    // the rail, fit the known-wavelength sine: the amplitude comes back.
    let (a_um, lambda) = (50.0, 50.0);
    let cfg = SimConfig {
        rail: RailModel { crown_radius_mm: Some(300.0), ..corrugated(a_um, lambda) },
        ..SimConfig::default()
    };
    let mut scene = Scene::new(cfg).unwrap();
    let pose = scene.camera_pose();
    let (w, h) = (scene.width(), scene.height());
    let mut det = Detector::<1024>::new(Config::new(scene.bits(), scales(1.5, 4.0))).unwrap();
    let mut img = vec![0u16; w * h];
    let mut out: Stripes<8> = Stripes::new();
    let mut z_err = Vec::new();
    // Normal equations of z = a·sin + b·cos + c per laser.
    let mut fits = [[[0.0f64; 4]; 3]; 3];
    for frame in 0..3 {
        let truth = scene.render_frame(frame, 0b111, &mut img);
        let odo = truth.odometer_mm;
        for (r, row) in img.chunks_exact(w).enumerate() {
            det.detect(row, &mut out).unwrap();
            for (k, fit) in fits.iter_mut().enumerate() {
                let t = truth.stripes[k][r].unwrap();
                let Some(s) = out.iter().find(|s| (s.position.to_f64() - t.column_px).abs() < 1.5) else { continue };
                let p = pose.cam_to_rail(scene.triangulate(k, s.position.to_f64(), r as f64).unwrap());
                let crown = (300.0f64 * 300.0 - p[1] * p[1]).sqrt() - 300.0;
                let z = (p[2] - crown) * 1e3; // profile, µm
                z_err.push(z - t.profile_um);
                let ph = std::f64::consts::TAU * (odo + p[0]) / lambda;
                let basis = [ph.sin(), ph.cos(), 1.0];
                for i in 0..3 {
                    for j in 0..3 {
                        fit[i][j] += basis[i] * basis[j];
                    }
                    fit[i][3] += basis[i] * z;
                }
            }
        }
    }
    let amps: Vec<f64> = fits
        .iter()
        .map(|m| {
            let s = solve3(m);
            s[0].hypot(s[1])
        })
        .collect();
    println!(
        "corrugation {a_um} µm @ {lambda} mm: height RMS error {:.2} µm per row, fitted amplitudes {:.2} / {:.2} / {:.2} µm",
        rms(&z_err),
        amps[0],
        amps[1],
        amps[2]
    );
    assert!(rms(&z_err) < 15.0, "{}", rms(&z_err));
    for a in amps {
        assert!((a - a_um).abs() < 2.0, "{a}");
    }
}

/// Gaussian elimination of a 3 × 3 system given as augmented rows.
fn solve3(m: &[[f64; 4]; 3]) -> [f64; 3] {
    let mut a = *m;
    for i in 0..3 {
        let p = (i..3).max_by(|&x, &y| a[x][i].abs().total_cmp(&a[y][i].abs())).unwrap();
        a.swap(i, p);
        for j in i + 1..3 {
            let f = a[j][i] / a[i][i];
            let pivot = a[i];
            for (c, v) in a[j].iter_mut().enumerate().skip(i) {
                *v -= f * pivot[c];
            }
        }
    }
    let mut x = [0.0; 3];
    for i in (0..3).rev() {
        x[i] = (a[i][3] - (i + 1..3).map(|j| a[i][j] * x[j]).sum::<f64>()) / a[i][i];
    }
    x
}

#[test]
fn deterministic_and_row_order_independent() {
    let cfg = SimConfig::default();
    let mut a = Scene::new(cfg.clone()).unwrap();
    let mut b = Scene::new(cfg.clone()).unwrap();
    let n = a.width() * a.height();
    let (mut fa, mut fb) = (vec![0u16; n], vec![0u16; n]);
    let ta = a.render_frame(7, 0b111, &mut fa);
    let tb = b.render_frame(7, 0b111, &mut fb);
    assert_eq!(fa, fb);
    assert_eq!(ta, tb);
    // Rows pulled one at a time, backwards, after another frame: the same.
    let mut other = vec![0u16; n];
    b.render_frame(3, 0b101, &mut other);
    let w = b.width();
    let mut row = vec![0u16; w];
    for r in (0..b.height()).rev() {
        let t = b.render_row(7, r, 0b111, &mut row);
        assert_eq!(&row[..], &fa[r * w..(r + 1) * w], "row {r}");
        for k in 0..3 {
            assert_eq!(t.stripes[k], ta.stripes[k][r]);
        }
    }
    // Another frame and another seed differ.
    assert_ne!(other, fa);
    let mut c = Scene::new(SimConfig { seed: 2, ..cfg }).unwrap();
    let mut fc = vec![0u16; n];
    c.render_frame(7, 0b111, &mut fc);
    assert_ne!(fc, fa);
}

#[test]
fn hot_pixels_are_the_same_in_every_frame() {
    let mut cfg = SimConfig::default();
    cfg.noise.hot_pixel_fraction = 1e-3;
    let mut scene = Scene::new(cfg).unwrap();
    let hot = scene.hot_pixels();
    assert_eq!(hot.len(), (1e-3 * 752.0 * 480.0f64).round() as usize);
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let mut sets = Vec::new();
    for (frame, mask) in [(0, 0), (5, 0), (11, 0), (12, 0b111)] {
        scene.render_frame(frame, mask, &mut img);
        // Bright outliers: well above the ambient light (≤ 17 codes here).
        let bright: Vec<(usize, usize)> = (0..w * h).filter(|&i| img[i] > 28).map(|i| (i / w, i % w)).collect();
        if mask == 0 {
            assert_eq!(bright, hot, "frame {frame}");
        } else {
            // With the lasers on, every hot pixel is still bright.
            assert!(hot.iter().all(|&(r, c)| img[r * w + c] > 28));
        }
        sets.push(bright);
    }
    assert_eq!(sets[0], sets[1]);
    // Another seed, another sensor.
    let other = Scene::new(SimConfig { seed: 99, ..scene.config().clone() }).unwrap();
    assert_ne!(other.hot_pixels(), hot);
}

#[test]
fn lasers_off_is_ambient_and_noise() {
    let mut scene = Scene::new(SimConfig::default()).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let truth = scene.render_frame(0, 0, &mut img);
    assert!(truth.stripes.iter().flatten().all(|s| s.is_none()));
    let ambient_dn = 10.0 * 100.0 / scene.camera().gain_e_per_dn();
    let mean = img.iter().map(|&v| v as f64).sum::<f64>() / img.len() as f64;
    assert!((mean - ambient_dn).abs() < 0.5, "{mean} vs {ambient_dn}");
    let mut det = Detector::<1024>::new(Config::new(8, scales(1.5, 4.0))).unwrap();
    let mut out: Stripes<8> = Stripes::new();
    let mut rows_with_stripes = 0;
    for row in img.chunks_exact(w) {
        det.detect(row, &mut out).unwrap();
        rows_with_stripes += usize::from(!out.is_empty());
    }
    println!("lasers off: mean {mean:.2} codes (ambient {ambient_dn:.2}), {rows_with_stripes} rows with a detection");
    assert!(rows_with_stripes <= h / 100, "{rows_with_stripes}");
    // One laser only: one stripe per row.
    let truth = scene.render_frame(0, 0b100, &mut img);
    let (found, total, _) = match_frame(&mut det, &img, w, &truth, &[2]);
    assert_eq!(total, h);
    assert!(found >= h * 99 / 100);
}

#[test]
fn saturation_and_bit_depth() {
    let mut cfg = SimConfig::default();
    cfg.lasers[0].power_mw = 250.0;
    let mut scene = Scene::new(cfg.clone()).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let truth = scene.render_frame(0, 0b111, &mut img);
    assert!(truth.stripes[0][0].unwrap().peak_dn > 255.0);
    assert_eq!(*img.iter().max().unwrap(), 255);
    let mut det = Detector::<1024>::new(Config::new(8, scales(1.5, 4.0))).unwrap();
    let mut out: Stripes<8> = Stripes::new();
    det.detect(&img[..w], &mut out).unwrap();
    assert!(out.iter().any(|s| s.flags.contains(Flags::SATURATED)));

    // 12 bits: the same scene, 16 times the codes.
    let mut q8 = Scene::new(quiet(SimConfig::default())).unwrap();
    let mut c12 = quiet(SimConfig::default());
    c12.camera.bits = 12;
    let mut q12 = Scene::new(c12).unwrap();
    let (mut r8, mut r12) = (vec![0u16; w], vec![0u16; w]);
    let t8 = q8.render_row(0, 200, 0b111, &mut r8);
    q12.render_row(0, 200, 0b111, &mut r12);
    let (m8, m12) = (*r8.iter().max().unwrap() as f64, *r12.iter().max().unwrap() as f64);
    assert!((m12 / m8 - 4095.0 / 255.0).abs() < 0.15, "{m8} {m12}");
    assert!(r12.iter().all(|&v| v <= 4095));
    assert!((t8.stripes[0].unwrap().peak_dn - 165.8).abs() < 1.0);
    let _ = h;
}

#[test]
fn odometer_moves_the_rail_under_the_head() {
    let mut cfg = quiet(SimConfig::default());
    cfg.rail = RailModel::flat();
    cfg.odometer_start_mm = 1000.0;
    let scene = Scene::new(cfg).unwrap();
    let a = scene.stripe_truth(0, 240, 1).unwrap();
    let b = scene.stripe_truth(3, 240, 1).unwrap();
    assert!((b.x_mm - a.x_mm - 3.0 * 2000.0 / 60.0).abs() < 1e-9);
    assert!((a.x_mm - 1000.0).abs() < 1.0, "{a:?}");
    // Rows run along the rail: 0.143 mm per row.
    let c = scene.stripe_truth(0, 241, 1).unwrap();
    assert!((c.x_mm - a.x_mm - 200.0 / 1400.0).abs() < 1e-3);
}

#[test]
fn shots_set_odometer_and_exposure() {
    let mut scene = Scene::new(quiet(SimConfig::default())).unwrap();
    let nominal = scene.shot(6, 0b111);
    assert_eq!(nominal.odometer_mm, 6.0 * 2000.0 / 60.0);
    assert_eq!(nominal.exposure_us, 100.0);
    // 0.1 s after frame 0 at 2 m/s: 200 mm; twice the exposure, twice the light.
    let long = scene.shot_at(6, 100_000.0, 200.0, 0b111);
    assert!((long.odometer_mm - 200.0).abs() < 1e-9);
    let w = scene.width();
    let (mut a, mut b) = (vec![0u16; w], vec![0u16; w]);
    let ta = scene.render_shot_row(&nominal, 10, &mut a);
    let tb = scene.render_shot_row(&long, 10, &mut b);
    let (pa, pb) = (ta.stripes[2].unwrap(), tb.stripes[2].unwrap());
    assert!((pb.peak_dn / pa.peak_dn - 2.0).abs() < 1e-9);
    assert!((pb.x_mm - 200.0 - (pa.x_mm - nominal.odometer_mm)).abs() < 1e-9);
    let mut c = vec![0u16; w];
    scene.render_row(6, 10, 0b111, &mut c);
    assert_eq!(a, c, "the nominal shot is what render_row renders");
    // No exposure, no light.
    let dark = Shot { exposure_us: 0.0, ..nominal };
    scene.render_shot_row(&dark, 10, &mut c);
    assert!(c.iter().all(|&v| v == 0));
    let truth = scene.render_shot(&long, &mut vec![0u16; w * scene.height()]);
    assert_eq!((truth.odometer_mm, truth.exposure_us), (long.odometer_mm, 200.0));
}

#[test]
fn misaligned_head_still_renders_consistent_truth() {
    // Yaw, pitch, roll and an oblique camera: the truth stays a projection of
    // a point on the laser plane and the surface, and the detector agrees.
    let mut cfg = quiet(SimConfig::default());
    cfg.head.yaw_deg = 5.0;
    cfg.head.pitch_deg = 2.0;
    cfg.head.roll_deg = -3.0;
    cfg.head.camera_tilt_deg = -10.0;
    let mut scene = Scene::new(cfg).unwrap();
    let pose = scene.camera_pose();
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let truth = scene.render_frame(4, 0b111, &mut img);
    for k in 0..3 {
        let plane = scene.laser_planes()[k];
        for r in (0..h).step_by(37) {
            let t = truth.stripes[k][r].unwrap();
            let p = [t.x_mm - truth.odometer_mm, t.y_mm, t.height_um * 1e-3];
            let pc = pose.rail_to_cam(p);
            assert!(plane.distance_mm(pc).abs() < 1e-9);
            let uv = scene.camera().intrinsics.project(pc).unwrap();
            assert!((uv[0] - t.column_px).abs() < 1e-6 && (uv[1] - r as f64).abs() < 1e-6);
            let crown = (300.0f64 * 300.0 - t.y_mm * t.y_mm).sqrt() - 300.0;
            assert!((t.height_um - t.profile_um - crown * 1e3).abs() < 1e-6);
            assert!((t.profile_um - scene.profile_um(t.x_mm)).abs() < 1e-9);
        }
    }
    let mut det = Detector::<1024>::new(Config::new(8, scales(1.5, 4.0))).unwrap();
    let (found, total, errs) = match_frame(&mut det, &img, w, &truth, &[0, 1, 2]);
    assert_eq!(found, total);
    assert!(rms(&errs) < 0.02);
}

#[test]
fn paper_preset() {
    let cfg = SimConfig::paper();
    let range = cfg.optics().scale_range().unwrap();
    assert!((cfg.nominal_sigma_px() - 15.18).abs() < 0.01);
    let mut scene = Scene::new(cfg).unwrap();
    assert_eq!((scene.width(), scene.height()), (4752, 3168));
    let mut det = Detector::<4800>::new(Config::new(8, range)).unwrap();
    let mut row = vec![0u16; scene.width()];
    let mut out: Stripes<8> = Stripes::new();
    let mut errs = Vec::new();
    let mut total = 0;
    for r in (0..scene.height()).step_by(50) {
        let t = scene.render_row(0, r, 0b111, &mut row);
        det.detect(&row, &mut out).unwrap();
        for s in t.stripes.iter().flatten() {
            total += 1;
            assert!(s.sigma_px > range.min().to_f64() && s.sigma_px < range.max().to_f64());
            if let Some(d) = out.iter().find(|d| (d.position.to_f64() - s.column_px).abs() < 3.0) {
                errs.push(d.position.to_f64() - s.column_px);
            }
        }
    }
    println!("paper: {}/{total} found, RMS {:.4} px", errs.len(), rms(&errs));
    assert_eq!(total, 3 * 64);
    assert!(errs.len() >= total * 99 / 100);
    assert!(rms(&errs) < 0.06, "{}", rms(&errs));
}

#[test]
fn rejects_bad_configurations() {
    let err = |f: fn(&mut SimConfig)| {
        let mut c = SimConfig::default();
        f(&mut c);
        Scene::new(c).unwrap_err()
    };
    let e = err(|c| c.camera.intrinsics.fx_px = -1.0);
    assert!(matches!(e, SimError::Field { field: "camera.fx_px", .. }), "{e}");
    assert_eq!(e.to_string(), "camera.fx_px = -1 must be finite and > 0");
    assert_eq!(err(|c| c.camera.bits = 7), SimError::Bits(7));
    assert_eq!(err(|c| c.lasers.clear()), SimError::LaserCount(0));
    assert_eq!(err(|c| c.lasers = vec![c.lasers[0]; 9]), SimError::LaserCount(9));
    assert_eq!(err(|c| c.lasers[2].offset_mm = 400.0), SimError::LaserOutOfView { laser: 2 });
    assert_eq!(err(|c| c.rail.crown_radius_mm = Some(5.0)), SimError::LaserOutOfView { laser: 0 });
    assert!(matches!(err(|c| c.frame_rate_hz = 0.0), SimError::Field { field: "frame_rate_hz", .. }));
    assert!(matches!(err(|c| c.speed_mm_s = f64::NAN), SimError::Field { field: "speed_mm_s", .. }));
    assert!(matches!(err(|c| c.head.alpha_deg = 0.0), SimError::Field { field: "head.alpha_deg", .. }));
    assert!(matches!(err(|c| c.noise.read_noise_e = -1.0), SimError::Field { .. }));
    assert!(matches!(err(|c| c.rail.roughness_min_wavelength_mm = 0.001), SimError::RoughnessBand { .. }));
    assert_eq!(err(|c| c.camera.intrinsics.k1 = -3.0), SimError::Distortion);
    assert!(matches!(err(|c| c.camera.intrinsics.width_px = 2), SimError::ImageSize { .. }));
    for e in [SimError::Distortion, SimError::LaserOutOfView { laser: 1 }, SimError::LaserCount(0)] {
        assert!(!e.to_string().is_empty());
    }
}
