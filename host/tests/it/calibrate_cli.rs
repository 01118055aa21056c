//! `cms-host calibrate upload|lasers` from the command line, and the
//! calibration file's parser under arbitrary input.

use crate::common::{one_line_error, run};

use cms_host::calib::file::CalibrationFile;
use cms_host::sim::calibration::truth::truth;
use cms_host::sim::scene::{Scene, SimConfig};
use proptest::prelude::*;

/// Upload to the simulated head, which keeps it: a new head on the same
/// state directory streams triangulated points at once, on the rail
/// surface (the reference rail: ±50 µm of corrugation on a 300 mm crown).
#[test]
fn upload_is_kept_across_restarts_and_points_carry_millimetres() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("cal.toml");
    let scene = Scene::new(SimConfig::reference()).unwrap();
    truth(&scene).save(&cal).unwrap();
    let state = dir.path().join("state");
    let (cal_s, state_s) = (cal.to_str().unwrap(), state.to_str().unwrap());
    let up = run(&["calibrate", "upload", cal_s, "sim", "--sim-state", state_s]);
    assert!(up.status.success(), "{up:?}");
    let said = String::from_utf8_lossy(&up.stdout);
    assert!(said.contains("loaded by the head") && said.contains("detector scales"), "{said}");
    assert!(state.join("calibration.frame").exists());

    let l = run(&["listen", "sim", "--sim-light=incoherent", "--sim-state", state_s, "--frames", "3", "--json"]);
    assert!(l.status.success(), "{l:?}");
    let said = String::from_utf8_lossy(&l.stderr);
    assert!(said.contains("restored from") && said.contains("listen: calibration: 0x"), "{said}");
    let mut n = 0;
    for line in String::from_utf8(l.stdout).unwrap().lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        for laser in v["lasers"].as_array().unwrap() {
            for p in laser["points"].as_array().unwrap() {
                let h = p["height_um"].as_f64().expect("a triangulated point");
                let a = p["along_mm"].as_f64().unwrap();
                assert!(h.abs() < 300.0, "height {h} µm");
                assert!(a.abs() < 40.0, "along {a} mm");
                n += 1;
            }
        }
    }
    assert!(n > 3 * 3 * 400, "{n} points");
}

#[test]
fn upload_refuses_bad_files_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Scene::new(SimConfig::reference()).unwrap();
    let good = truth(&scene).to_toml();
    let path = dir.path().join("cal.toml");
    let p = path.to_str().unwrap();
    let state = dir.path().join("state");
    let s = state.to_str().unwrap();

    std::fs::write(&path, good.replace("fx = ", "fx = -")).unwrap();
    let e = one_line_error(&run(&["calibrate", "upload", p, "sim", "--sim-state", s]));
    assert!(e.contains("camera.fx"), "{e}");

    let end = good.find("[datum]").unwrap();
    std::fs::write(&path, &good[..end]).unwrap();
    let e = one_line_error(&run(&["calibrate", "upload", p, "sim", "--sim-state", s]));
    assert!(e.contains("[datum]"), "{e}");

    // A calibration of another camera.
    truth(&Scene::new(SimConfig::paper()).unwrap()).save(&path).unwrap();
    let e = one_line_error(&run(&["calibrate", "upload", p, "sim", "--sim-state", s]));
    assert!(e.contains("4752×3168 camera") && e.contains("752×480"), "{e}");
    assert!(!state.join("calibration.frame").exists(), "nothing kept");

    let e = one_line_error(&run(&["calibrate", "upload", "/nonexistent/cal.toml", "sim"]));
    assert!(e.contains("/nonexistent/cal.toml"), "{e}");
}

#[test]
fn lasers_refuses_bad_arguments_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("cam.toml");
    let scene = Scene::new(SimConfig::reference()).unwrap();
    let mut f = truth(&scene);
    f.lasers.clear();
    f.datum = None;
    f.save(&cam).unwrap();
    let c = cam.to_str().unwrap();
    let out = dir.path().join("cal.toml");
    let o = out.to_str().unwrap();
    let e = one_line_error(&run(&["calibrate", "lasers", "--camera", c, "--out", o, "a.png", "b.png"]));
    assert!(e.contains("[board]"), "{e}");
    let e = one_line_error(&run(&[
        "calibrate",
        "lasers",
        "--camera",
        c,
        "--out",
        o,
        "--board",
        "9x6",
        "--square-mm",
        "6",
        "a.png",
        "b.png",
        "c.png",
    ]));
    assert!(e.contains("3 images"), "{e}");
    let e = one_line_error(&run(&[
        "calibrate",
        "lasers",
        "--camera",
        c,
        "--out",
        o,
        "--board",
        "9x6",
        "--square-mm",
        "6",
        "--scales",
        "4:2",
        "a",
        "b",
        "c",
        "d",
        "e",
        "f",
    ]));
    assert!(e.contains("--scales"), "{e}");
    let e = one_line_error(&run(&[
        "calibrate",
        "lasers",
        "--camera",
        c,
        "--out",
        o,
        "--board",
        "9x6",
        "--square-mm",
        "6",
        "a.png",
        "b.png",
        "c.png",
        "d.png",
        "e.png",
        "f.png",
    ]));
    assert!(e.contains("a.png"), "{e}");
    assert!(!out.exists());
}

/// The reference head's true calibration with its laser planes replaced.
fn with_planes(planes: [([f64; 3], f64); 3]) -> CalibrationFile {
    let mut f = truth(&Scene::new(SimConfig::reference()).unwrap());
    for (l, (n, d)) in f.lasers.iter_mut().zip(planes) {
        [l.nx, l.ny, l.nz] = n;
        l.d_mm = d;
    }
    f
}

/// The reference head's planes: parallel, 8.2 mm apart along their normal.
fn reference_planes() -> [([f64; 3], f64); 3] {
    let f = truth(&Scene::new(SimConfig::reference()).unwrap());
    std::array::from_fn(|k| ([f.lasers[k].nx, f.lasers[k].ny, f.lasers[k].nz], f.lasers[k].d_mm))
}

/// A plane turned about the camera's y axis by `deg`, about the point where
/// it meets the optical axis.
fn turned(p: ([f64; 3], f64), deg: f64) -> ([f64; 3], f64) {
    let (n, d) = p;
    let t = deg.to_radians();
    let m = [n[0] * t.cos() + n[2] * t.sin(), n[1], -n[0] * t.sin() + n[2] * t.cos()];
    (m, m[2] * d / n[2])
}

/// Three identical laser planes (and planes that cross, or are out of laser
/// order, in the working depth) are refused by the file's reader — so by
/// `measure`, `analyze`, `calibrate upload` — and by the head's own check;
/// before, `measure` gave a 0.00 µm amplitude and `analyze` "pass yes".
#[test]
fn laser_planes_must_be_distinct_ordered_and_apart() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cal.toml");
    let p = path.to_str().unwrap();
    let r = reference_planes();
    let write = |f: &CalibrationFile| std::fs::write(&path, f.to_toml()).unwrap();

    // The reference calibration passes (the baseline of the cases below).
    assert!(CalibrationFile::parse(&with_planes(r).to_toml(), "ok.toml").is_ok());

    let same = with_planes([r[0], r[0], r[0]]);
    let msg = same.to_head().unwrap();
    let head = cms_core::pipeline::triangulator(&msg).unwrap_err();
    assert!(matches!(head, cms_core::pipeline::CalibrationError::LinesTooClose { left: 0, .. }), "{head:?}");
    write(&same);
    let e = one_line_error(&run(&["calibrate", "upload", p, "sim"]));
    assert!(e.contains("laser planes 0 and 1 cross, coincide or are out of laser order"), "{e}");
    let e = one_line_error(&run(&["measure", "--calibration", p, "/nonexistent/x.png"]));
    assert!(e.contains("cal.toml") && e.contains("laser planes 0 and 1"), "{e}");
    // The calibration is checked before the recording is read.
    let e = one_line_error(&run(&["analyze", "/nonexistent/x.cmsrec", "--calibration", p]));
    assert!(e.contains("cal.toml") && e.contains("laser planes 0 and 1"), "{e}");

    // Laser 2 turned by −10° about its point on the optical axis: it crosses
    // laser 1 at 228 mm, inside the 150–250 mm working depth (and the
    // [head] range 170–230 mm).
    let crossing = with_planes([r[0], r[1], turned(r[2], -10.0)]);
    let e = CalibrationFile::parse(&crossing.to_toml(), "x.toml").unwrap_err().0;
    assert!(e.starts_with("x.toml: ") && e.contains("laser planes 1 and 2 cross"), "{e}");
    assert!(cms_core::pipeline::triangulator(&crossing.to_head().unwrap()).is_err());
    // Turned by +6°: they cross at 126 mm, outside it, and are ≥ 37 px apart within.
    let fanned = with_planes([r[0], r[1], turned(r[2], 6.0)]);
    assert!(CalibrationFile::parse(&fanned.to_toml(), "x.toml").is_ok());

    // Lasers 0 and 2 swapped: stripes are numbered left to right.
    let swapped = with_planes([r[2], r[1], r[0]]);
    let e = CalibrationFile::parse(&swapped.to_toml(), "x.toml").unwrap_err().0;
    assert!(e.contains("laser planes 0 and 1") && e.contains("out of laser order"), "{e}");

    // Two lines 3–5 px apart: too close to tell apart.
    let near = with_planes([r[0], (r[1].0, r[0].1 + 0.4), r[2]]);
    let e = CalibrationFile::parse(&near.to_toml(), "x.toml").unwrap_err().0;
    assert!(e.contains("px apart") && e.contains("at least 8 px"), "{e}");
}

/// Every writer reads back what it writes: a `[head]` range no detector
/// scale fits (`--range-mm 1e300:1e301` wrote a file every reader refused)
/// is not written.
#[test]
fn the_writer_refuses_what_its_readers_would() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cal.toml");
    let mut f = truth(&Scene::new(SimConfig::reference()).unwrap());
    f.head.as_mut().unwrap().range_min_mm = 1e300;
    f.head.as_mut().unwrap().range_max_mm = 1e301;
    let e = f.save(&path).unwrap_err().to_string();
    assert!(e.contains("cal.toml: [head]") && e.contains("not written"), "{e}");
    assert!(!path.exists() && !dir.path().join("cal.toml.partial").exists());
    // The readers refuse it too, in the same words.
    std::fs::write(&path, f.to_toml()).unwrap();
    let e = one_line_error(&run(&["calibrate", "upload", path.to_str().unwrap(), "sim"]));
    assert!(e.contains("[head] range 1e300–1e301 mm reaches beyond the depths"), "{e}");
}

/// The whole chain from the simulated head's 24 calibration views on the
/// command line: `calibrate camera` prints σ of every intrinsic (measured
/// here), fixes k3 (the corners reach only 0.3 f off-axis) and writes
/// `[camera_sigma]`; `calibrate lasers` prints each plane's residual and
/// spread; with `--range-mm 1e300:1e301` it writes nothing.
#[test]
fn cli_chain_on_the_simulated_head() {
    let dir = tempfile::tempdir().unwrap();
    let imgs = dir.path().join("imgs");
    let i = imgs.to_str().unwrap();
    let r = run(&["calibrate", "render", "--poses", "24", "--seed", "1", "--out", i]);
    assert!(r.status.success(), "{r:?}");
    let cam = dir.path().join("cam.toml");
    let boards: Vec<String> = (0..24).map(|k| imgs.join(format!("board-{k:02}.png")).display().to_string()).collect();
    let mut args = vec!["calibrate", "camera", "--board", "9x6", "--square-mm", "6", "--out", cam.to_str().unwrap()];
    args.extend(boards.iter().map(String::as_str));
    let r = run(&args);
    let out = String::from_utf8_lossy(&r.stdout).to_string();
    assert!(r.status.success(), "{out} {}", String::from_utf8_lossy(&r.stderr));
    println!("{out}");
    assert!(out.contains("k3 fixed at 0: the corners reach"), "{out}");
    let f = CalibrationFile::load(&cam).unwrap();
    let s = f.camera_sigma.unwrap();
    let fx = f.camera.intrinsics.fx_px;
    assert!(s.fx_px.unwrap() < 0.002 * fx && s.k3.is_none(), "{s:?}");

    let mut pairs = Vec::new();
    for k in 0..24 {
        pairs.push(imgs.join(format!("board-{k:02}.png")).display().to_string());
        pairs.push(imgs.join(format!("lasers-{k:02}.png")).display().to_string());
    }
    let cal = dir.path().join("cal.toml");
    let lasers = |extra: &[&str]| {
        let mut a = vec!["calibrate", "lasers", "--camera", cam.to_str().unwrap(), "--out", cal.to_str().unwrap()];
        a.extend(extra);
        a.extend(pairs.iter().map(String::as_str));
        run(&a)
    };
    let e = one_line_error(&lasers(&["--laser-diameter-mm", "0.75", "--range-mm", "1e300:1e301"]));
    assert!(e.contains("[head]") && e.contains("not written"), "{e}");
    assert!(!cal.exists());
    let r = lasers(&["--laser-diameter-mm", "0.75", "--range-mm", "170:230"]);
    let out = String::from_utf8_lossy(&r.stdout).to_string();
    assert!(r.status.success(), "{out} {}", String::from_utf8_lossy(&r.stderr));
    println!("{out}");
    for k in 0..3 {
        let line = out.lines().find(|l| l.starts_with(&format!("laser {k}: n = "))).unwrap();
        assert!(line.contains(" mm RMS") || line.contains("RMS "), "{line}");
        assert!(line.contains("mm across the line, depths "), "{line}");
    }
    let f = CalibrationFile::load(&cal).unwrap();
    for l in &f.lasers {
        assert!(l.spread_mm.unwrap() > 1.0 && l.depth_min_mm.unwrap() < l.depth_max_mm.unwrap(), "{l:?}");
    }
}

fn valid() -> String {
    truth(&Scene::new(SimConfig::reference()).unwrap()).to_toml()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Any text: a file or a one-line error, never a panic.
    #[test]
    fn parser_never_panics(text in "\\PC{0,400}") {
        if let Err(e) = CalibrationFile::parse(&text, "x.toml") {
            prop_assert!(!e.0.contains('\n'));
        }
    }

    /// A valid file with one value replaced by anything: a file whose
    /// numbers pass validation again, or a one-line error naming the file.
    #[test]
    fn mutated_files_are_validated(line in 0usize..60, value in prop_oneof![
        any::<f64>().prop_map(|v| format!("{v:?}")),
        Just("nan".to_string()), Just("inf".to_string()), Just("-0.0".to_string()),
        Just("\"x\"".to_string()), Just("[1, 2]".to_string()), "[a-z0-9.+-]{0,12}",
    ]) {
        let text = valid();
        let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
        let i = line % lines.len();
        if let Some((k, _)) = lines[i].split_once(" = ") {
            lines[i] = format!("{k} = {value}");
        }
        match CalibrationFile::parse(&lines.join("\n"), "x.toml") {
            Ok(f) => {
                let again = CalibrationFile::parse(&f.to_toml(), "again.toml");
                prop_assert!(again.is_ok(), "{:?}", again);
            }
            Err(e) => {
                prop_assert!(!e.0.contains('\n'));
                prop_assert!(e.0.starts_with("x.toml"));
            }
        }
    }
}

/// Messages that name what is wrong: a plane through the camera (it holds
/// the optical axis: the camera sees it edge on), a plane parallel to the
/// optical axis whose line the camera never sees, and a `[head]` range
/// wider than the depths at which the lines are in view (blamed on the
/// range, with the depths that would do, not on the image nor on the
/// detector's scale range).
#[test]
fn degenerate_planes_and_ranges_are_named() {
    let r = reference_planes();
    let err = |f: &CalibrationFile| CalibrationFile::parse(&f.to_toml(), "x.toml").unwrap_err().0;
    let n = r[1].0;
    let l = (n[0] * n[0] + n[1] * n[1]).sqrt();
    let e = err(&with_planes([r[0], ([n[0] / l, n[1] / l, 0.0], 0.0), r[2]]));
    assert!(e.contains("(id 1)") && e.contains("d_mm = 0 puts the camera on the laser plane"), "{e}");
    let e = err(&with_planes([r[0], ([n[0] / l, n[1] / l, 0.0], r[1].1), r[2]]));
    assert!(e.contains("laser plane 1 puts its line outside the image"), "{e}");
    let mut wide = truth(&Scene::new(SimConfig::reference()).unwrap());
    wide.head.as_mut().unwrap().range_min_mm = 10.0;
    wide.head.as_mut().unwrap().range_max_mm = 5000.0;
    let e = err(&wide);
    assert!(e.starts_with("x.toml: [head] range 10.0–5000.0 mm reaches beyond the depths"), "{e}");
    assert!(e.contains("along the optical axis") && e.contains("narrow range_min_mm/range_max_mm"), "{e}");
    // The depths it names do: a range inside them is accepted.
    let seen: Vec<f64> =
        e.split(['(', ' ', '–']).filter_map(|w| w.parse::<f64>().ok()).filter(|&v| v != 10.0 && v != 5000.0).collect();
    assert!(seen.len() >= 2, "{e}");
    let mut ok = truth(&Scene::new(SimConfig::reference()).unwrap());
    let h = ok.head.as_mut().unwrap();
    (h.range_min_mm, h.range_max_mm) = (h.range_min_mm.max(seen[0] + 1.0), h.range_max_mm.min(seen[1] - 1.0));
    assert!(CalibrationFile::parse(&ok.to_toml(), "x.toml").is_ok(), "{:?}", ok.head);
}
