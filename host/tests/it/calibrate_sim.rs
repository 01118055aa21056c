//! The whole calibration chain against the simulated head's truth: images
//! rendered by the simulated head (reference preset, 24 poses, with the
//! sensor's noise), `calibrate camera` (corners, Zhang, LM), `calibrate
//! lasers` (pairs, back-projection, TLS planes), compared with the head's
//! true intrinsics and laser planes. The done-when: intrinsics within 0.2 %,
//! each plane's normal within 0.02° and offset within 0.02 mm.

use cms_host::calib::board::find_corners;
use cms_host::calib::camera::{CalibOptions, calibrate};
use cms_host::calib::lasers::{LaserOptions, Pair, calibrate_lasers};
use cms_host::input::Rows;
use cms_host::model::board::Board;
use cms_host::sim::calibration::board::{BoardImage, board_for, calibration_poses, render_board};
use cms_host::sim::scene::{Scene, SimConfig};

fn rows(img: BoardImage) -> Rows {
    if img.bits <= 8 {
        Rows::from_u8(img.width, img.height, img.pixels.iter().map(|&p| p as u8).collect()).unwrap()
    } else {
        Rows::from_u16(img.width, img.height, img.pixels, img.bits).unwrap()
    }
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt() * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
    (d.abs() / n).min(1.0).acos().to_degrees()
}

#[test]
fn calibration_from_simulated_images_matches_the_truth() {
    let scene = Scene::new(SimConfig::reference()).unwrap();
    let board: Board = board_for(scene.config());
    let poses = calibration_poses(&scene, &board, 24, 1);
    let truth = scene.camera().intrinsics;
    let mut views = Vec::new();
    let mut pairs = Vec::new();
    for (k, pose) in poses.iter().enumerate() {
        let off = render_board(&scene, &board, pose, 0, 2 * k as u64);
        let on = render_board(&scene, &board, pose, 0b111, 2 * k as u64 + 1);
        let gray: Vec<f32> = off.pixels.iter().map(|&p| f32::from(p)).collect();
        views.push(find_corners(&gray, off.width, off.height, &board).unwrap());
        pairs.push(Pair { off: rows(off), on: rows(on), name: format!("pose {k}") });
    }
    let cam = calibrate(&board, &views, truth.width_px, truth.height_px, &CalibOptions::default()).unwrap();
    let i = &cam.intrinsics;
    let rel = |got: f64, want: f64| (got - want) / want * 100.0;
    let errs =
        [rel(i.fx_px, truth.fx_px), rel(i.fy_px, truth.fy_px), rel(i.cx_px, truth.cx_px), rel(i.cy_px, truth.cy_px)];
    println!(
        "intrinsics: fx {:+.4} %, fy {:+.4} %, cx {:+.4} %, cy {:+.4} %; RMS {:.4} px",
        errs[0], errs[1], errs[2], errs[3], cam.rms_px
    );
    for e in errs {
        assert!(e.abs() <= 0.2, "intrinsics off by {e} %");
    }

    let lasers = calibrate_lasers(i, &board, &pairs, &LaserOptions::default()).unwrap();
    for (k, (fit, want)) in lasers.planes.iter().zip(scene.laser_planes()).enumerate() {
        let angle = angle_deg(fit.normal, want.normal);
        // The offset where it matters: the fitted plane's distance from the
        // true plane's point on the optical axis (the middle of the image).
        let z = want.d_mm / want.normal[2];
        let offset = fit.normal[2] * z - fit.d_mm;
        println!(
            "laser {k}: normal {angle:.4}° off, offset {offset:+.4} mm at the optical axis; RMS {:.4} mm over {} points from {} poses",
            fit.rms_mm, fit.points, fit.poses
        );
        assert!(angle <= 0.02, "laser {k}: normal {angle}° off");
        assert!(offset.abs() <= 0.02, "laser {k}: offset {offset} mm");
    }
}
