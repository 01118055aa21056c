//! `cms-host measure`: an image of the simulated (reference) head and a
//! recording of its detected peaks, with the head's true calibration; JSON,
//! text and plots; one-line refusals of bad inputs.

use crate::common::cms_host;
use std::path::{Path, PathBuf};

use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_core::protocol::{DeviceMsg, LASERS, LaserPoints, MAX_FRAME, Metric, Point, Profile, encode};
use cms_host::calib::truth::truth;
use cms_host::record::Recorder;
use cms_host::sim::{Corrugation, Scene, SimConfig};

const LAMBDA_MM: f64 = 20.0;
const AMP_UM: f64 = 100.0;

fn config() -> SimConfig {
    let mut cfg = SimConfig::reference();
    cfg.rail.corrugation = vec![Corrugation { wavelength_mm: LAMBDA_MM, amplitude_um: AMP_UM, phase_rad: 0.4 }];
    cfg.rail.roughness_rms_um = 0.0;
    cfg
}

/// Frame 0 as an 8-bit PNG and the true calibration as a file.
fn image_and_calibration(dir: &Path) -> (PathBuf, PathBuf) {
    let mut scene = Scene::new(config()).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut px = vec![0u16; w * h];
    scene.render_frame(0, scene.all_lasers_mask(), &mut px);
    let bytes: Vec<u8> = px.iter().map(|&v| v.min(255) as u8).collect();
    let img = dir.join("frame.png");
    image::save_buffer(&img, &bytes, w as u32, h as u32, image::ExtendedColorType::L8).unwrap();
    let cal = dir.join("cal.toml");
    std::fs::write(&cal, truth(&scene).to_toml()).unwrap();
    (img, cal)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn image_json_text_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let (img, cal) = image_and_calibration(dir.path());
    let plots = dir.path().join("plots");
    let out = cms_host(&["measure", "--calibration", s(&cal), "--json", "--plot", s(&plots), s(&img)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.lines().count(), 1, "{text}");
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let lasers = v["lasers"].as_array().unwrap();
    assert_eq!(lasers.len(), LASERS);
    for l in lasers {
        assert!(l["along_mm"].as_array().unwrap().len() > 400, "{}", l["laser"]);
        let f = &l["fit"];
        assert!((f["wavelength_mm"].as_f64().unwrap() - LAMBDA_MM).abs() < 0.2, "{f}");
        assert_eq!(f["model"], "rotated");
    }
    let j = &v["joint"];
    let (wl, amp) = (j["wavelength_mm"].as_f64().unwrap(), j["amplitude_mm"].as_f64().unwrap());
    println!("joint: λ {wl} mm, A {} µm, rms {} µm", amp * 1e3, j["rms_residual_mm"].as_f64().unwrap() * 1e3);
    assert!((wl - LAMBDA_MM).abs() < 0.05, "{j}");
    assert!((amp * 1e3 - AMP_UM).abs() < 3.0, "{j}");
    assert_eq!(j["lines"], 3);
    assert!(j["yaw_rad"].as_f64().unwrap().abs() < 0.01, "{j}");
    for ext in ["svg", "png"] {
        let p = plots.join(format!("frame.{ext}"));
        assert!(std::fs::metadata(&p).map(|m| m.len() > 1000).unwrap_or(false), "{}", p.display());
    }
    assert!(image::open(plots.join("frame.png")).is_ok());
    let svg = std::fs::read_to_string(plots.join("frame.svg")).unwrap();
    assert!(svg.contains("residual") && svg.contains("joint sine"), "svg labels");

    let out = cms_host(&["measure", "--calibration", s(&cal), s(&img)]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("laser 2:") && text.contains("joint (3 lines"), "{text}");
}

/// A recording of the same head: one frame with the head's metric points,
/// one with raw peaks only (triangulated by `measure`): the same result.
#[test]
fn recording_metric_and_raw_frames() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cal) = image_and_calibration(dir.path());
    let file = CalibFile::load(&cal);
    let rec = dir.path().join("run.cmsrec");
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn({
            let rec = rec.clone();
            move || write_recording(&rec, &file)
        })
        .unwrap()
        .join()
        .unwrap();
    let out = cms_host(&["measure", "--calibration", s(&cal), "--json", s(&rec)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let frames: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(frames.len(), 2, "{text}");
    let wl: Vec<f64> = frames.iter().map(|f| f["joint"]["wavelength_mm"].as_f64().unwrap()).collect();
    assert_eq!(frames[0]["seq"], 7);
    assert!((frames[1]["odometer_mm"].as_f64().unwrap() - 12.5).abs() < 1e-9);
    for w in &wl {
        assert!((w - LAMBDA_MM).abs() < 0.05, "{wl:?}");
    }
    // Metric (µm, nm integers) and f32 triangulation agree closely.
    assert!((wl[0] - wl[1]).abs() < 1e-3, "{wl:?}");
}

struct CalibFile(cms_host::calib::file::CalibrationFile);

impl CalibFile {
    fn load(p: &Path) -> CalibFile {
        CalibFile(cms_host::calib::file::CalibrationFile::load(p).unwrap())
    }
}

fn write_recording(path: &Path, cal: &CalibFile) {
    let mut scene = Scene::new(config()).unwrap();
    let tri = cms_core::pipeline::triangulator(&cal.0.to_head().unwrap()).unwrap();
    let mut det_cfg = Config::new(scene.bits(), config().optics().scale_range().unwrap());
    det_cfg.max_stripes = LASERS as u8;
    det_cfg.select = Select::Strongest;
    let mut det = Box::new(Detector::<1024>::new(det_cfg).unwrap());
    let mut row = vec![0u16; scene.width()];
    let mut lasers: heapless::Vec<LaserPoints, LASERS> = heapless::Vec::new();
    for k in 0..LASERS as u8 {
        lasers.push(LaserPoints { laser: k, points: heapless::Vec::new() }).unwrap();
    }
    for r in 0..scene.height() {
        scene.render_row(0, r, scene.all_lasers_mask(), &mut row);
        let mut st: Stripes<LASERS> = Stripes::new();
        det.detect(&row, &mut st).unwrap();
        if st.len() != LASERS {
            continue;
        }
        st.sort_unstable_by_key(|x| x.position);
        for (k, x) in st.iter().enumerate() {
            let p = tri.profile(k, x.position, r as u16).unwrap();
            let metric =
                Metric { along_um: (p.along_mm * 1e3).round() as i32, height_nm: (p.height_mm * 1e6).round() as i32 };
            let point = Point {
                row: r as u16,
                position: x.position,
                strength: x.strength.min(65535) as u16,
                width: x.width,
                flags: x.flags,
                metric: Some(metric),
            };
            lasers[k].points.push(point).unwrap();
        }
    }
    let with_metric =
        Profile { seq: 7, part: 0, parts: 1, timestamp_us: 0, odometer_um: 0, exposure_us: 100, laser_mask: 7, lasers };
    let mut raw = with_metric.clone();
    raw.seq = 8;
    raw.odometer_um = 12_500;
    for l in raw.lasers.iter_mut() {
        for p in l.points.iter_mut() {
            p.metric = None;
        }
    }
    let mut rec = Recorder::open(path).unwrap();
    for p in [with_metric, raw] {
        let mut scratch = vec![0u8; MAX_FRAME];
        let mut out = vec![0u8; MAX_FRAME];
        rec.write_frame(encode(&DeviceMsg::Profile(p), &mut scratch, &mut out).unwrap()).unwrap();
    }
    rec.finish().unwrap();
}

fn one_line_exit_2(out: &std::process::Output, needle: &str) {
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("error: ") && err.contains(needle), "{err}");
}

#[test]
fn bad_inputs_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (img, cal) = image_and_calibration(dir.path());
    let missing = dir.path().join("missing.toml");
    one_line_exit_2(&cms_host(&["measure", "--calibration", s(&missing), s(&img)]), "missing.toml");
    // A camera-only calibration cannot triangulate.
    let cam_only = dir.path().join("cam.toml");
    let text = std::fs::read_to_string(&cal).unwrap();
    let cut = text.find("[datum]").unwrap();
    std::fs::write(&cam_only, &text[..cut]).unwrap();
    one_line_exit_2(&cms_host(&["measure", "--calibration", s(&cam_only), s(&img)]), "cam.toml");
    // Not an image.
    let junk = dir.path().join("junk.png");
    std::fs::write(&junk, b"not a png").unwrap();
    one_line_exit_2(&cms_host(&["measure", "--calibration", s(&cal), s(&junk)]), "junk.png");
    // A recording without a complete frame.
    let empty = dir.path().join("empty.cmsrec");
    Recorder::open(&empty).unwrap().finish().unwrap();
    one_line_exit_2(&cms_host(&["measure", "--calibration", s(&cal), s(&empty)]), "no complete frame");
    // No input at all: clap's usage error, exit 2.
    assert_eq!(cms_host(&["measure", "--calibration", s(&cal)]).status.code(), Some(2));
}
