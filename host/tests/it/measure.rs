//! `cms-host measure`: an image of the simulated (reference) head and a
//! recording of its detected peaks, with the head's true calibration; JSON,
//! text and plots; one-line refusals of bad inputs.

use crate::common::cms_host;
use std::path::{Path, PathBuf};

use cms_core::peak::{Config, Detector, Select, Stripes};
use cms_core::protocol::{DeviceMsg, LASERS, LaserPoints, MAX_FRAME, Metric, Point, Profile, encode};
use cms_host::recording::Recorder;
use cms_host::sim::calibration::truth::truth;
use cms_host::sim::scene::{Corrugation, Scene, SimConfig};

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
        // Along the rail, on the corrected profile: the model holds.
        let g = &l["surface_fit"];
        assert!((g["wavelength_mm"].as_f64().unwrap() - LAMBDA_MM).abs() < 0.05, "{g}");
        assert!(g["wavelength_sigma_mm"].as_f64().unwrap() > 0.0, "{g}");
        assert!(l["surface_verdict"]["level"].is_string(), "{l}");
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
    assert!(
        text.contains("laser 2 along the rail:")
            && text.contains("laser 2 own frame:")
            && text.contains("joint (3 lines"),
        "{text}"
    );
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
        let mut out = vec![0u8; MAX_FRAME];
        rec.write_frame(encode(&DeviceMsg::Profile(p), &mut out).unwrap()).unwrap();
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

// ------------------------------------------------------------ inputs that do not belong together

/// A `Hello` of the reference head (752 × 480) with calibration `id`.
fn hello(id: u32) -> DeviceMsg {
    DeviceMsg::Hello(cms_core::protocol::DeviceInfo {
        firmware: heapless::String::try_from("1.0.0").unwrap(),
        protocol: cms_core::protocol::PROTOCOL_VERSION,
        board: heapless::String::try_from("sim").unwrap(),
        sensor_width: 752,
        sensor_height: 480,
        bits: 8,
        detector: cms_core::pipeline::default_detector(),
        calibration_id: id,
        store: cms_core::protocol::StoreHealth::Volatile,
    })
}

fn wire(msg: &DeviceMsg) -> Vec<u8> {
    let mut out = vec![0u8; MAX_FRAME];
    encode(msg, &mut out).unwrap().to_vec()
}

/// The two-frame recording of [`recording_metric_and_raw_frames`] with a
/// `Hello` of calibration `id` first.
fn recording_with_hello(dir: &Path, cal: &Path, id: u32) -> (PathBuf, Vec<u8>) {
    let file = CalibFile::load(cal);
    let plain = dir.join("plain.cmsrec");
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn({
            let plain = plain.clone();
            move || write_recording(&plain, &file)
        })
        .unwrap()
        .join()
        .unwrap();
    let body = std::fs::read(&plain).unwrap();
    // The frames start after the header and its survey block's checksum.
    let start = cms_host::recording::header().len();
    let mut bytes = body[..start].to_vec();
    bytes.extend(wire(&hello(id)));
    bytes.extend(&body[start..]);
    let rec = dir.join(format!("hello-{id}.cmsrec"));
    std::fs::write(&rec, &bytes).unwrap();
    (rec, bytes)
}

/// A calibration for a camera of another size than the data's is refused:
/// an image (752 × 480) against a 4000- or 100-px-wide camera, a recording
/// whose `Hello` says 752 × 480 against them; the same calibration's own
/// size is measured.
#[test]
fn camera_size_must_match_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let (img, cal) = image_and_calibration(dir.path());
    let text = std::fs::read_to_string(&cal).unwrap();
    let id = CalibFile::load(&cal).0.head_id();
    let (rec, _) = recording_with_hello(dir.path(), &cal, id);
    let ok = cms_host(&["measure", "--calibration", s(&cal), s(&rec)]);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    for width in [4000, 700] {
        let other = dir.path().join(format!("w{width}.toml"));
        // The same id as the head's, so that only the size differs.
        std::fs::write(&other, format!("id = {id}\n{}", text.replace("width = 752", &format!("width = {width}"))))
            .unwrap();
        let o = cms_host(&["measure", "--calibration", s(&other), s(&img)]);
        one_line_exit_2(&o, &format!("frame.png is 752×480 px, but {} is for a {width}×480 camera", s(&other)));
        let o = cms_host(&["measure", "--calibration", s(&other), s(&rec)]);
        one_line_exit_2(&o, &format!("is for a {width}×480 camera, but {} was recorded by a 752×480 one", s(&rec)));
        let o = cms_host(&["analyze", s(&rec), "--calibration", s(&other)]);
        one_line_exit_2(&o, &format!("is for a {width}×480 camera, but {} was recorded by a 752×480 one", s(&rec)));
    }
}

/// `measure` refuses a calibration whose id differs from the recording's
/// (as `analyze` does, with the same check); a head without a calibration
/// (id 0, raw peaks) is measured with it.
#[test]
fn calibration_id_must_match_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cal) = image_and_calibration(dir.path());
    let (rec, _) = recording_with_hello(dir.path(), &cal, 0x1234_5678);
    let o = cms_host(&["measure", "--calibration", s(&cal), s(&rec)]);
    one_line_exit_2(&o, "was recorded with calibration 0x12345678");
    let (none, _) = recording_with_hello(dir.path(), &cal, 0);
    let o = cms_host(&["measure", "--calibration", s(&cal), s(&none)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Damaged and duplicated frames are reported by `measure` (it skipped
/// damaged ones without a word, and measured a frame present twice twice).
#[test]
fn damaged_and_duplicated_frames_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cal) = image_and_calibration(dir.path());
    let id = CalibFile::load(&cal).0.head_id();
    let (_, bytes) = recording_with_hello(dir.path(), &cal, id);
    // The frames: header, Hello, frame 7, frame 8. Frame 8 written twice
    // (as a writer retrying would), then frame 7's first data byte flipped.
    let ends: Vec<usize> = bytes.iter().enumerate().filter(|(_, b)| **b == 0).map(|(i, _)| i + 1).collect();
    let frames: Vec<usize> = ends.into_iter().filter(|&e| e > cms_host::recording::header().len()).collect();
    let (f7, f8) = (frames[0]..frames[1], frames[1]..frames[2]);
    let mut dup = bytes.clone();
    dup.extend_from_slice(&bytes[f8.clone()]);
    let path = dir.path().join("dup.cmsrec");
    std::fs::write(&path, &dup).unwrap();
    let o = cms_host(&["measure", "--calibration", s(&cal), "--json", s(&path)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 profile messages present twice"), "{err}");
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 2, "frame 8 once");
    let mut damaged = dup.clone();
    damaged[f7.start + 3] ^= 0x10;
    let _ = f8;
    let path = dir.path().join("damaged.cmsrec");
    std::fs::write(&path, &damaged).unwrap();
    let o = cms_host(&["measure", "--calibration", s(&cal), "--json", s(&path)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 damaged frames were skipped"), "{err}");
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 1, "frame 8 only");
    // `info` counts it once and says so; `export` writes it once and says so.
    let o = cms_host(&["info", s(&path)]);
    let report = String::from_utf8_lossy(&o.stdout);
    assert!(report.contains("frames: 1 (1 profile messages)"), "{report}");
    assert!(report.contains("duplicated profile messages (skipped): 1"), "{report}");
    let o = cms_host(&["export", "--format", "jsonl", s(&path)]);
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 1);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("present twice") && err.contains("damaged"), "{err}");
}

/// Every result carries its verdict: the text ends each fit with it, the
/// JSON has it with the points' noise; `--strict` turns a result that is
/// not good into exit status 1 after printing everything. A frame whose
/// surface no model here follows (its calibrated points given a 60 µm step
/// halfway along every line) is doubtful or failed, with the misfit as its
/// reason.
#[test]
fn results_carry_a_verdict_and_strict_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let (img, cal) = image_and_calibration(dir.path());
    let out = cms_host(&["measure", "--calibration", s(&cal), s(&img)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let joint = text.lines().find(|l| l.trim_start().starts_with("joint")).unwrap();
    assert!(joint.ends_with("; good"), "{text}");
    let json = cms_host(&["measure", "--calibration", s(&cal), "--json", s(&img)]);
    let v: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(v["joint"]["verdict"]["level"], "good", "{v}");
    assert!(v["joint"]["verdict"]["noise_um"].as_f64().unwrap() > 0.0, "{v}");
    let strict = cms_host(&["measure", "--strict", "--calibration", s(&cal), s(&img)]);
    let all_good = !text.contains("; doubtful") && !text.contains("; failed");
    assert_eq!(strict.status.code(), Some(if all_good { 0 } else { 1 }), "{text}");
    if !all_good {
        assert!(String::from_utf8_lossy(&strict.stderr).contains("--strict: "), "{strict:?}");
    }
}

#[test]
fn a_frame_with_a_step_is_not_good_and_strict_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cal) = image_and_calibration(dir.path());
    let id = CalibFile::load(&cal).0.head_id();
    let (rec, _) = recording_with_hello(dir.path(), &cal, id);
    let mut bytes = cms_host::recording::header().to_vec();
    cms_host::recording::scan_file(&rec, |msg| {
        let mut msg = msg.clone();
        if let DeviceMsg::Profile(p) = &mut msg {
            for l in p.lasers.iter_mut() {
                for pt in l.points.iter_mut().filter(|pt| pt.row >= 240) {
                    if let Some(m) = &mut pt.metric {
                        m.height_nm += 60_000;
                    }
                }
            }
        }
        bytes.extend(wire(&msg));
        Ok(())
    })
    .unwrap();
    let stepped = dir.path().join("stepped.cmsrec");
    std::fs::write(&stepped, bytes).unwrap();
    let out = cms_host(&["measure", "--strict", "--calibration", s(&cal), s(&stepped)]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    let joint = text.lines().find(|l| l.trim_start().starts_with("joint")).unwrap();
    assert!(joint.contains("; doubtful: residual") || joint.contains("; failed: residual"), "{text}");
    assert!(joint.contains("the model does not fit"), "{text}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.starts_with("error: --strict: ") && err.contains("results are not good"), "{err}");
}

/// `measure` reads the light off the image: a speckled laser line is
/// measured with the centroid and an incoherent one with the CWT (`auto`,
/// the default), `--method` overrides it, and a speckled image keeps a
/// point in nearly every row of every line, with the joint result's
/// interval holding the truth.
#[test]
fn the_light_picks_the_method() {
    use cms_host::sim::scene::LightModel;
    let dir = tempfile::tempdir().unwrap();
    let (clean, cal) = image_and_calibration(dir.path());
    let mut cfg = config();
    cfg.light = LightModel::speckle(8.0);
    let mut scene = Scene::new(cfg).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut px = vec![0u16; w * h];
    scene.render_frame(0, scene.all_lasers_mask(), &mut px);
    let bytes: Vec<u8> = px.iter().map(|&v| v.min(255) as u8).collect();
    let speckled = dir.path().join("speckled.png");
    image::save_buffer(&speckled, &bytes, w as u32, h as u32, image::ExtendedColorType::L8).unwrap();

    let json = |args: &[&str]| -> serde_json::Value {
        let out = cms_host(&[&["measure", "--calibration", s(&cal), "--json"], args].concat());
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_str(String::from_utf8(out.stdout).unwrap().trim()).unwrap()
    };
    let v = json(&[s(&clean)]);
    assert_eq!(v["detection"]["method"], "cwt", "{}", v["detection"]);
    assert_eq!(v["detection"]["light"]["speckled"], false, "{}", v["detection"]);
    let v = json(&[s(&speckled)]);
    let d = &v["detection"];
    assert_eq!(d["method"], "centroid", "{d}");
    assert_eq!(d["light"]["speckled"], true, "{d}");
    assert!(d["light"]["change"].as_f64().unwrap() > 0.2, "{d}");
    for l in v["lasers"].as_array().unwrap() {
        let n = l["along_mm"].as_array().unwrap().len();
        assert!(n * 10 >= h * 9, "laser {}: {n} points of {h} rows", l["laser"]);
    }
    let j = &v["joint"];
    let (wl, sl) = (j["wavelength_mm"].as_f64().unwrap(), j["wavelength_sigma_mm"].as_f64().unwrap());
    let (amp, sa) = (j["amplitude_mm"].as_f64().unwrap(), j["amplitude_sigma_mm"].as_f64().unwrap());
    println!("speckled: λ {wl} ± {sl} mm, A {} ± {} µm, {}", amp * 1e3, sa * 1e3, j["verdict"]);
    assert!((wl - LAMBDA_MM).abs() <= 3.0 * sl && (amp * 1e3 - AMP_UM).abs() <= 3.0 * sa * 1e3, "{j}");

    let v = json(&["--method", "cwt", s(&speckled)]);
    assert_eq!(v["detection"]["method"], "cwt");
    assert!(v["detection"]["light"].is_null(), "{}", v["detection"]);
    let out = cms_host(&["measure", "--calibration", s(&cal), "--method", "centriod", s(&speckled)]);
    assert_eq!(out.status.code(), Some(2));
}
