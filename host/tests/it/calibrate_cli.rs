//! `cms-host calibrate upload|lasers` from the command line, and the
//! calibration file's parser under arbitrary input.

use crate::common::{one_line_error, run};

use cms_host::calib::file::CalibrationFile;
use cms_host::calib::truth::truth;
use cms_host::sim::{Scene, SimConfig};
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

    let l = run(&["listen", "sim", "--sim-state", state_s, "--frames", "3", "--json"]);
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
