//! Closed loop through the simulated head at the paper's geometry (Table 4:
//! 4752 × 3168, f = 5106 px, α = 42°, 2 mm lines, 450 mm): its rows, the
//! core detector's peaks, the core triangulation with the head's true
//! calibration (a calibration file, through the wire's f32 numbers) —
//! against the simulated rail surface.
//!
//! Three parts, to tell the error sources apart:
//! * the true stripe centres: the triangulation alone;
//! * noise-free rows of a rail without crown: plus the detector's bias;
//! * the paper's 30 dB rows: plus the sensor noise, per point and over
//!   1 mm of rail (the sampling of the corrugation analysis).

use cms_core::fixed::Px;
use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_core::pipeline::triangulator;
use cms_core::protocol::LASERS;
use cms_core::triangulation::Triangulator;
use cms_host::sim::calibration::truth::truth;
use cms_host::sim::scene::{Corrugation, NoiseModel, Scene, SimConfig};

fn paper(noise: bool, crown: bool) -> SimConfig {
    let mut cfg = SimConfig::paper();
    cfg.rail.corrugation = vec![Corrugation { wavelength_mm: 50.0, amplitude_um: 100.0, phase_rad: 0.3 }];
    if !noise {
        cfg.noise = NoiseModel::none();
    }
    if !crown {
        cfg.rail.crown_radius_mm = None;
    }
    cfg
}

fn setup(cfg: &SimConfig) -> (Scene, Triangulator) {
    let scene = Scene::new(cfg.clone()).unwrap();
    let tri = triangulator(&truth(&scene).to_head().unwrap()).unwrap();
    (scene, tri)
}

/// Height errors (µm) of the detected peaks of frame 0's `rows`, in order.
fn detected(cfg: &SimConfig, rows: impl Iterator<Item = usize>) -> Vec<[f64; LASERS]> {
    let (mut scene, tri) = setup(cfg);
    let mut det_cfg = Config::new(scene.bits(), cfg.optics().scale_range().unwrap());
    det_cfg.max_stripes = LASERS as u8;
    det_cfg.select = Select::Strongest;
    let mut det = Box::new(Detector::<4800>::new(det_cfg).unwrap());
    let mut row = vec![0u16; scene.width()];
    let mut out = Vec::new();
    for r in rows {
        let t = scene.render_row(0, r, 0b111, &mut row);
        let mut s: Stripes<LASERS> = Stripes::new();
        det.detect(&row, &mut s).unwrap();
        assert_eq!(s.len(), LASERS, "row {r}");
        s.sort_unstable_by_key(|x| x.position);
        let mut e = [0.0; LASERS];
        for (k, stripe) in s.iter().enumerate() {
            let truth = t.stripes[k].unwrap();
            let p = tri.profile(k, stripe.position, r as u16).expect("a point on the rail");
            e[k] = f64::from(p.height_mm) * 1e3 - truth.height_um;
        }
        out.push(e);
    }
    out
}

fn rms<'a>(v: impl IntoIterator<Item = &'a f64>) -> f64 {
    let (s, n) = v.into_iter().fold((0.0, 0usize), |(s, n), e| (s + e * e, n + 1));
    (s / n as f64).sqrt()
}

#[test]
fn true_centres_triangulate_to_the_surface() {
    let cfg = paper(true, true);
    let (scene, tri) = setup(&cfg);
    let (mut dh, mut da) = (Vec::new(), Vec::new());
    for f in 0..3 {
        let odo = scene.odometer_mm(f);
        for r in (0..scene.height()).step_by(7) {
            let t = scene.row_truth(f, r, 0b111);
            for (k, s) in t.stripes.iter().take(LASERS).enumerate() {
                let s = s.unwrap();
                let p = tri.profile(k, Px::from_f64(s.column_px), r as u16).unwrap();
                dh.push(f64::from(p.height_mm) * 1e3 - s.height_um);
                da.push((f64::from(p.along_mm) - (s.x_mm - odo)) * 1e3);
            }
        }
    }
    let max = dh.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    let max_a = da.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    println!(
        "true centres: {} points, height RMS {:.4} µm max {max:.4} µm; along RMS {:.4} µm max {max_a:.4} µm",
        dh.len(),
        rms(&dh),
        rms(&da)
    );
    assert!(max <= 0.2, "height error up to {max} µm");
    assert!(max_a <= 0.5, "along error up to {max_a} µm");
}

#[test]
fn noise_free_rows_of_a_flat_rail() {
    let e = detected(&paper(false, false), (0..3168).step_by(64));
    let h = rms(e.iter().flatten());
    let per_laser: Vec<String> = (0..LASERS)
        .map(|k| {
            let v: Vec<f64> = e.iter().map(|x| x[k]).collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            format!("laser {k}: mean {m:+.3} RMS {:.3}", rms(&v))
        })
        .collect();
    println!("noise-free, no crown: {} points, height RMS {h:.4} µm ({})", e.len() * LASERS, per_laser.join("; "));
    assert!(h <= 1.0, "height RMS {h} µm");
}

/// 30 dB rows (the paper's), crowned rail: per point the sensor noise
/// dominates; over 1 mm of rail (11 rows at 0.088 mm) the surface is
/// reproduced within 1 µm RMS.
#[test]
fn paper_rows_reproduce_the_rail_within_a_micrometre_per_millimetre() {
    const BLOCK: usize = 11;
    let starts: Vec<usize> = (0..10).map(|b| 100 + b * 300).collect();
    let e = detected(&paper(true, true), starts.iter().flat_map(|&s| s..s + BLOCK));
    let per_point = rms(e.iter().flatten());
    let means: Vec<f64> = e
        .chunks(BLOCK)
        .flat_map(|c| (0..LASERS).map(move |k| c.iter().map(|x| x[k]).sum::<f64>() / BLOCK as f64))
        .collect();
    let bias = means.iter().sum::<f64>() / means.len() as f64;
    let per_mm = rms(&means);
    println!(
        "30 dB, crowned rail: {} points, per point RMS {per_point:.3} µm; per 1 mm of rail RMS {per_mm:.3} µm (bias {bias:+.3} µm)",
        e.len() * LASERS
    );
    assert!(per_mm <= 1.0, "per-mm RMS {per_mm} µm");
    assert!(per_point <= 5.0, "per-point RMS {per_point} µm");
}
