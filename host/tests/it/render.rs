//! `cms-host calibrate render` and the simulated head's board images:
//! laser stripes where the ray–plane–board intersection puts them, the files
//! the command writes, its refusals.

use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Stripes};
use cms_host::Error;
use cms_host::sim::calibration::board::{self, BoardRenderer, RenderOptions};
use cms_host::sim::calibration::images::{self, Options};
use cms_host::sim::head::Preset;
use cms_host::sim::scene::{NoiseModel, Scene, SimConfig};

fn args(out: &std::path::Path, poses: usize) -> Options {
    Options { preset: Preset::Reference, poses, seed: 3, noiseless: false, out: out.to_path_buf() }
}

/// On a noiseless laser-on minus laser-off difference, the detector's
/// stripe centres (rows where the stripe lies on one white square) are where
/// the laser plane meets the board along each row.
#[test]
fn laser_stripes_where_the_planes_cut_the_board() {
    let mut cfg = SimConfig::reference();
    cfg.noise = NoiseModel::none();
    let scene = Scene::new(cfg).unwrap();
    let opts = RenderOptions::default();
    let r = BoardRenderer::new(&scene, opts);
    let brd = board::board_for(scene.config());
    let cam = *scene.camera();
    let (w, h) = (cam.width_px(), cam.height_px());
    let scales = ScaleRange::new(Px::from_f64(1.5), Px::from_f64(8.0)).unwrap();
    let mut det = Box::new(Detector::<1024>::new(Config::new(8, scales)).unwrap());
    let mut out: Stripes<8> = Stripes::new();
    let mut errs = Vec::new();
    let mut per_laser = [0usize; 3];
    for (k, pose) in board::calibration_poses(&scene, &brd, 4, 5).iter().enumerate() {
        let t = std::time::Instant::now();
        let on = r.render(&brd, pose, scene.all_lasers_mask(), 1);
        eprintln!("reference image: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
        let off = r.render(&brd, pose, 0, 2);
        assert_eq!((on.width, on.height, on.bits), (w, h, 8));
        let diff: Vec<u16> = on.pixels.iter().zip(&off.pixels).map(|(&a, &b)| a.saturating_sub(b)).collect();
        for row in 0..h {
            det.detect(&diff[row * w..(row + 1) * w], &mut out).unwrap();
            for (l, plane) in scene.laser_planes().iter().enumerate() {
                let Some(u) = board::laser_column(&cam, plane, pose, row as f64) else { continue };
                // Only where ±4 stripe σ (σ ≈ 3 px) along the row, and 2 rows
                // above and below (pixel footprint and lens blur), lie on one
                // white square.
                let sq_at = |u: f64, v: f64| {
                    board::board_point(&cam, pose, u, v).map(|b| {
                        let (a, c) = ((b[0] / brd.square_mm).floor() as i64, (b[1] / brd.square_mm).floor() as i64);
                        let on_checker = (-1..brd.cols as i64).contains(&a) && (-1..brd.rows as i64).contains(&c);
                        // White squares and the one-square white margin.
                        let on_paper = (-2..=brd.cols as i64).contains(&a) && (-2..=brd.rows as i64).contains(&c);
                        (a, c, on_paper && (!on_checker || (a + c).rem_euclid(2) == 1))
                    })
                };
                let sq = |u: f64| sq_at(u, row as f64);
                let reach = 12.0;
                let centre = sq(u);
                let Some((a0, c0, true)) = centre else { continue };
                let uniform = (-40..=40).all(|i| {
                    let x = u + reach * i as f64 / 40.0;
                    x > 2.0
                        && x < w as f64 - 3.0
                        && [-2.0, 0.0, 2.0]
                            .iter()
                            .all(|dv| sq_at(x, row as f64 + dv).is_some_and(|(a, c, _)| (a, c) == (a0, c0)))
                });
                if !uniform {
                    continue;
                }
                let best = out.iter().map(|s| s.position.to_f64() - u).min_by(|a, b| a.abs().total_cmp(&b.abs()));
                let e = best.unwrap_or_else(|| panic!("pose {k}, row {row}, laser {l}: no stripe near {u:.3}"));
                assert!(e.abs() < 0.3, "pose {k}, row {row}, laser {l}: {e:+.4} px");
                errs.push(e);
                per_laser[l] += 1;
            }
        }
    }
    let n = errs.len() as f64;
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let bias = errs.iter().sum::<f64>() / n;
    eprintln!("stripes: RMS {rms:.4} px, bias {bias:+.4} px over {n} rows (per laser {per_laser:?})");
    assert!(per_laser.iter().all(|&c| c >= 50), "{per_laser:?}");
    assert!(rms < 0.05 && bias.abs() < 0.02, "RMS {rms}, bias {bias}");
}

#[test]
fn cli_writes_images_and_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("render");
    images::render(&args(&out, 2)).unwrap();
    for k in 0..2 {
        for name in [format!("board-{k:02}.png"), format!("lasers-{k:02}.png")] {
            let img = image::open(out.join(&name)).unwrap();
            assert_eq!(img.color(), image::ColorType::L8, "{name}");
            assert_eq!((img.width(), img.height()), (752, 480), "{name}");
        }
    }
    let board = image::open(out.join("board-00.png")).unwrap().into_luma8();
    let lasers = image::open(out.join("lasers-00.png")).unwrap().into_luma8();
    // The lasers add light; the noise differs between the two.
    let sum = |i: &image::GrayImage| i.pixels().map(|p| p.0[0] as u64).sum::<u64>();
    assert!(sum(&lasers) > sum(&board) + 100_000);
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("truth.json")).unwrap()).unwrap();
    assert_eq!(truth["preset"], "reference");
    assert_eq!(truth["intrinsics"]["fx"], 1400.0);
    assert_eq!(truth["intrinsics"]["k1"], -0.09);
    assert_eq!(truth["board"]["cols"], 9);
    assert_eq!(truth["board"]["rows"], 6);
    assert_eq!(truth["board"]["square_mm"], 6.0);
    assert_eq!(truth["image"]["bits"], 8);
    let lasers = truth["lasers"].as_array().unwrap();
    assert_eq!(lasers.len(), 3);
    let scene = Scene::new(SimConfig { seed: 3, ..SimConfig::reference() }).unwrap();
    for (l, p) in lasers.iter().zip(scene.laser_planes()) {
        assert!((l["d_mm"].as_f64().unwrap() - p.d_mm).abs() < 1e-9);
    }
    let poses = truth["poses"].as_array().unwrap();
    assert_eq!(poses.len(), 2);
    let brd = board::board_for(scene.config());
    let want = board::calibration_poses(&scene, &brd, 2, 3);
    for (p, w) in poses.iter().zip(&want) {
        let t: Vec<f64> = p["t_mm"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert!(t.iter().zip(w.t_mm).all(|(a, b)| (a - b).abs() < 1e-9), "{t:?}");
        assert!((p["rot"][2][2].as_f64().unwrap() - w.rot[2][2]).abs() < 1e-12);
    }
    assert_eq!(poses[1]["lasers_image"], "lasers-01.png");
}

#[test]
fn cli_refuses_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    for n in [0, 101] {
        match images::render(&args(dir.path(), n)) {
            Err(Error::Input(m)) => assert!(m.contains("--poses"), "{m}"),
            r => panic!("{n} poses: {r:?}"),
        }
    }
    let file = dir.path().join("file");
    std::fs::write(&file, "x").unwrap();
    match images::render(&args(&file, 1)) {
        Err(Error::Input(m)) => assert!(m.contains("not a directory") && !m.contains('\n'), "{m}"),
        r => panic!("{r:?}"),
    }
}
