//! Recordings of the simulated head analysed end to end, surveys of runs, profile files, EN 15610 against an independent implementation.

use super::{frames, write_recording};
use crate::common::{one_line_error, run};
use cms_host::analyze::standards::detection::Verdict;
use cms_host::recording;
use cms_host::sim::calibration::truth::truth;
use cms_host::sim::head::{CorrugationSpec, HeadOptions, sim_config};
use cms_host::sim::scene::Scene;
use std::path::{Path, PathBuf};

// ------------------------------------------------------------ the sim

/// The simulated head's options of the recording test.
pub(super) fn sim_args(state: &Path) -> HeadOptions {
    HeadOptions {
        speed_mm_s: Some(SIM_SPEED_MM_S),
        corrugation: vec![CorrugationSpec { wavelength_mm: 50.0, amplitude_um: 30.0, phase_deg: 0.0 }],
        roughness_um: Some(1.0),
        rate: 1000,
        state: Some(state.to_path_buf()),
        ..HeadOptions::default()
    }
}

/// Travel speed of the simulated recordings: 16.7 mm per frame at 30 Hz,
/// so that up to three frames in a row may drop (a busy machine) without a
/// gap in the 68.6 mm frames.
pub(super) const SIM_SPEED_MM_S: f64 = 500.0;

/// A calibrated simulated head (its true calibration), recorded for
/// `secs` at 0.5 m/s over a rail with 30 µm of corrugation at 50 mm and 1 µm
/// RMS roughness; returns the recording and listen's stderr.
pub(super) fn sim_recording(dir: &Path, secs: &str) -> (PathBuf, String) {
    let state = dir.join("state");
    let cal = dir.join("cal.toml");
    let scene = Scene::new(sim_config(&sim_args(&state)).unwrap()).unwrap();
    truth(&scene).save(&cal).unwrap();
    let s = state.to_str().unwrap();
    let up = run(&["calibrate", "upload", cal.to_str().unwrap(), "sim", "--sim-state", s]);
    assert!(up.status.success(), "{up:?}");
    let rec = dir.join("sim.cmsrec");
    let l = run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--sim-state",
        s,
        "--sim-speed-mm-s",
        &SIM_SPEED_MM_S.to_string(),
        "--sim-corrugation",
        "50:30",
        "--sim-roughness-um",
        "1",
        "--duration",
        secs,
        "--record",
        rec.to_str().unwrap(),
    ]);
    assert!(l.status.success(), "{l:?}");
    (rec, String::from_utf8_lossy(&l.stderr).to_string())
}

/// Five seconds at 0.5 m/s (up to 2.5 m of rail, frames every 17 mm):
/// the stitched profiles follow the simulated rail; the corrugation lands
/// in the 30–100 mm band and in the 50 mm one-third octave; `listen` showed
/// the estimate live. The simulated head runs in real time, so a machine
/// too busy to render it leaves holes; a recording whose longest run is
/// under the 1 m the spectrum needs is made again (three tries).
#[test]
fn sim_recording_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, listen_err, v) = (0..3)
        .find_map(|attempt| {
            let sub = dir.path().join(format!("try{attempt}"));
            std::fs::create_dir_all(&sub).unwrap();
            let (rec, err) = sim_recording(&sub, "5");
            let o = run(&["analyze", rec.to_str().unwrap(), "--json"]);
            assert!(o.status.success(), "{o:?}");
            let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
            let whole = v["lasers"].as_array().unwrap().iter().all(|l| l["en15610"]["error"].is_null());
            if !whole {
                println!("try {attempt}: no 1 m run: {}", v["lasers"][0]["gaps"]);
            }
            whole.then_some((rec, err, v))
        })
        .expect("a recording with 1 m of continuous rail in three tries");
    // listen's status line: the corrugation per laser once calibrated.
    let status: Vec<&str> = listen_err.lines().filter(|l| l.contains("corrugation")).collect();
    println!("{}", status.join("\n"));
    let last = status.last().expect("a status line with the corrugation estimate");
    // … and the head's telemetry (protocol v3 status) before it.
    assert!(last.contains(", head ") && last.contains(" ns/row") && last.contains("laser duty"), "{last}");
    let rows_per_s: u64 = last.split(", head ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(rows_per_s > 0, "{last}");
    for k in 0..3 {
        let tag = format!("L{k} ");
        let at = last.find(&tag).unwrap_or_else(|| panic!("{last}"));
        let rest = &last[at + tag.len()..];
        let wl: f64 = rest.split(" mm").next().unwrap().trim().parse().unwrap();
        let amp: f64 = rest.split('/').nth(1).unwrap().trim().split(' ').next().unwrap().parse().unwrap();
        assert!((wl - 50.0).abs() < 1.0 && (amp - 30.0).abs() < 3.0, "{last}");
    }

    let report = dir.path().join("report");
    let o = run(&["analyze", rec.to_str().unwrap(), "--report", report.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    let text = String::from_utf8(o.stdout).unwrap();
    println!("{text}");
    assert!(text.contains("x = odometer + along (chosen from the data"), "{text}");

    assert_eq!(v["direction"], "forward");
    let lasers = v["lasers"].as_array().unwrap();
    assert_eq!(lasers.len(), 3);
    for l in lasers {
        assert!(l["covered_mm"].as_f64().unwrap() > 1000.0, "{l}");
        let bands = l["en13231"]["bands"].as_array().unwrap();
        // 30 µm at 50 mm: mean peak-to-peak 0.060 mm in 30–100, little elsewhere.
        let pp = |i: usize| bands[i]["average_mean_pp_mm"].as_f64().unwrap();
        assert!((pp(1) - 0.060).abs() < 0.006, "{}", bands[1]);
        assert!(pp(0) < 0.015, "{bands:?}");
        // 100–300 mm needs 2.2 m of continuous rail: evaluated or said so.
        match bands[2]["error"].as_str() {
            Some(e) => assert!(e.contains("too short"), "{e}"),
            None => assert!(pp(2) < 0.015, "{bands:?}"),
        }
        assert_eq!(bands[1]["exceeding_percent"], 100.0);
        assert!(bands[3]["error"].as_str().unwrap().contains("too short"));
        assert!(l["registration_residual_median_um"].as_f64().unwrap() < 3.0, "{l}");
        let r = &l["en15610"];
        assert_eq!(r["peak_wavelength_mm"], 50.0, "{r}");
        // 30 µm → 10·lg(450) = 26.5 dB in its band.
        let b50 = r["bands"].as_array().unwrap().iter().find(|b| b["nominal_wavelength_mm"] == 50.0).unwrap();
        let lvl = b50["level_db"].as_f64().unwrap();
        assert!((lvl - 26.5).abs() < 1.0, "{lvl}");
        assert_eq!(b50["decision"]["verdict"], "EXCEEDS");
    }

    // The stitched profiles against the simulated rail.
    let scene = Scene::new(sim_config(&sim_args(&dir.path().join("state"))).unwrap()).unwrap();
    let csv = std::fs::read_to_string(report.join("profile.csv")).unwrap();
    let mut cols: Vec<Vec<(f64, f64)>> = vec![Vec::new(); 3];
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let x: f64 = f[0].parse().unwrap();
        for k in 0..3 {
            if let Ok(z) = f[k + 1].parse::<f64>() {
                cols[k].push((x, z - scene.profile_um(x)));
            }
        }
    }
    for (k, c) in cols.iter().enumerate() {
        // Per continuous run: fit the level and slope (unknown to any
        // registration), then compare.
        let (mut ss, mut n) = (0.0, 0usize);
        for d in c.chunk_by(|a, b| b.0 - a.0 < 1.5) {
            let m = d.len() as f64;
            let (xm, ym) = (d.iter().map(|p| p.0).sum::<f64>() / m, d.iter().map(|p| p.1).sum::<f64>() / m);
            let sxx = d.iter().map(|p| (p.0 - xm).powi(2)).sum::<f64>().max(1e-9);
            let b = d.iter().map(|p| (p.0 - xm) * (p.1 - ym)).sum::<f64>() / sxx;
            ss += d.iter().map(|p| (p.1 - ym - b * (p.0 - xm)).powi(2)).sum::<f64>();
            n += d.len();
        }
        let e = (ss / n as f64).sqrt();
        println!("laser {k}: stitched − true rail over {n} samples: RMS {e:.3} µm");
        assert!(e < 2.0, "laser {k}: {e} µm");
    }
    for f in ["report.html", "report.md", "profile.svg", "profile.png", "spectrum.png", "bands_laser1.png"] {
        assert!(report.join(f).metadata().unwrap().len() > 1000, "{f}");
    }
    let png = std::fs::read(report.join("spectrum.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");

    // With the calibration the outer lines lose their lateral-slope scale
    // (10 mm off the apex of a 300 mm crown, planes at 35°: ∓2.3 %): the
    // three lasers agree on the 30–100 mm band.
    let cal = rec.parent().unwrap().join("cal.toml");
    let o = run(&["analyze", rec.to_str().unwrap(), "--json", "--calibration", cal.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    let w: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(w["slid_across_frames"], v["frames"], "{}", w["slid_across_frames"]);
    let pp = |v: &serde_json::Value| -> Vec<f64> {
        (0..3).map(|k| v["lasers"][k]["en13231"]["bands"][1]["average_mean_pp_mm"].as_f64().unwrap()).collect()
    };
    let spread = |p: &[f64]| p.iter().fold(f64::MIN, |m, &x| m.max(x)) - p.iter().fold(f64::MAX, |m, &x| m.min(x));
    let (raw, slid) = (pp(&v), pp(&w));
    println!("30–100 mm mean peak-to-peak per laser (mm): as measured {raw:.5?}, slid across {slid:.5?}");
    assert!(spread(&slid) < 0.5 * spread(&raw) && spread(&slid) < 0.0015, "{raw:?} → {slid:?}");
    for p in &slid {
        assert!((p - 0.060).abs() < 0.002, "{slid:?}");
    }
    // Another head's calibration is refused, in one line.
    let text = std::fs::read_to_string(&cal).unwrap();
    let other = dir.path().join("other.toml");
    std::fs::write(&other, format!("id = 12345\n{text}")).unwrap();
    let e = one_line_error(&run(&["analyze", rec.to_str().unwrap(), "--calibration", other.to_str().unwrap()]));
    assert!(e.contains("0x00003039") && e.contains("recorded with calibration"), "{e}");
}

/// A frame present twice is analysed once, and said; a damaged
/// one is said too.
#[test]
fn duplicated_and_damaged_frames_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dup.cmsrec");
    write_recording(&path, &frames(33.3, 4, &[], 1.0, 5), true);
    let mut bytes = std::fs::read(&path).unwrap();
    // Frame 3 again (a writer retrying), then one damaged frame.
    let first = recording::header().len();
    let body = &bytes[first..];
    let starts: Vec<usize> =
        std::iter::once(0).chain(body.iter().enumerate().filter(|(_, b)| **b == 0).map(|(i, _)| i + 1)).collect();
    let last = bytes[first + starts[3]..first + starts[4]].to_vec();
    bytes.extend(&last);
    let mut broken = last.clone();
    broken[5] ^= 0x40;
    bytes.extend(&broken);
    std::fs::write(&path, &bytes).unwrap();
    let o = run(&["analyze", path.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{o:?}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (v["frames"].as_u64(), v["duplicate_profiles"].as_u64(), v["damaged_frames"].as_u64()),
        (Some(4), Some(1), Some(1))
    );
    let o = run(&["analyze", path.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("1 profile messages present twice") && text.contains("1 damaged frames"), "{text}");
}

/// The reduced scale benchmark: a synthetic survey (`bench recording`,
/// 2 000 frames every 17 mm: 34 m) streams through `analyze` in one pass,
/// and the known rail comes out: 30 µm at 50 mm is 0.060 mm peak to peak
/// in the 30–100 mm band, 20 µm at 200 mm 0.040 mm in the 100–300 mm one,
/// every frame registered, no gap; the 50 mm one-third octave is the
/// spectrum's peak. docs/benchmarks.md has the full-size figures.
#[test]
fn a_synthetic_survey_streams_through_analyze() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("survey.cmsrec");
    let r = rec.to_str().unwrap();
    let o = run(&["bench", "recording", "--frames", "2000", "--out", r]);
    assert!(o.status.success(), "{o:?}");
    let o = run(&["analyze", r, "--json"]);
    assert!(o.status.success(), "{o:?}");
    assert!(o.stderr.is_empty(), "no progress drawn off a terminal: {}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["frames"], 2000);
    assert_eq!(v["direction"], "forward");
    for l in v["lasers"].as_array().unwrap() {
        assert_eq!(l["registered"], 1999, "{l}");
        assert!(l["gaps"].as_array().unwrap().is_empty());
        let band = |lo: f64| {
            let b = l["en13231"]["bands"].as_array().unwrap().iter().find(|b| b["lo_mm"] == lo).unwrap();
            b["average_mean_pp_mm"].as_f64().unwrap()
        };
        assert!((band(30.0) - 0.060).abs() < 0.002, "{}", band(30.0));
        assert!((band(100.0) - 0.040).abs() < 0.002, "{}", band(100.0));
        assert_eq!(l["en15610"]["peak_wavelength_mm"], 50.0, "{l}");
    }
}

/// Two synthetic runs of one survey (`cms_host::sim::synthetic`, a rail with
/// broadband roughness and 80 m of 40 µm peak-to-peak corrugation at
/// 50 mm from chainage 0+060 to 0+140): the first driven up from 0+000 for
/// 110 m, the second started at 0+200, 20 m before where the first ended
/// seen from its end, and driven down to 0+090. Given a start 3 m off and
/// no heading for the second, `analyze RUN1 RUN2` finds both, joins them
/// into 200 m with the overlap registered to the noise, and finds the zone.
pub(super) fn survey_runs(dir: &Path, points_per_line: u16) -> (PathBuf, PathBuf) {
    use cms_host::sim::synthetic::{self, Rail};
    let rail = Rail::Survey { zone_mm: (60_000.0, 140_000.0), wavelength_mm: 50.0, amplitude_um: 20.0 };
    let frames = (110_000.0 / 17.0) as u32;
    let base = synthetic::Options { frames, points_per_line, rail, ..synthetic::Options::default() };
    // The synthetic head's odometer starts at 100 mm.
    let one = synthetic::Options { seed: 1, ..base.clone() };
    let two = synthetic::Options { start_mm: 200_100.0, reverse: true, seed: 2, ..base };
    let (a, b) = (dir.join("run1.cmsrec"), dir.join("run2.cmsrec"));
    synthetic::write(&a, &one, &cms_host::progress::Silent).unwrap();
    synthetic::write(&b, &two, &cms_host::progress::Silent).unwrap();
    (a, b)
}

#[test]
fn two_runs_of_a_survey_are_joined_on_chainage() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = survey_runs(dir.path(), 240);
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
    // The second run's start entered 3.1 m off, its heading not at all.
    let o = run(&["analyze", a, b, "--chainage", "0+000", "--chainage", "0+197", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let j = &v["run_joins"][1];
    println!("second run: {j}");
    assert_eq!(j["heading"], "down");
    assert_eq!(j["heading_found"], true);
    assert_eq!(j["ambiguous"], false);
    // Its odometer's zero is at 0+200.100 (the synthetic head's odometer starts at 100 mm).
    let start = j["start_m"].as_f64().unwrap();
    assert!((start - 200.1).abs() < 0.002, "{start}");
    assert!((j["overlap_mm"].as_f64().unwrap() - 20_000.0).abs() < 200.0, "{j}");
    let residual = j["residual_um"].as_f64().unwrap();
    assert!(residual <= 2.0, "registration residual {residual} µm");
    for l in v["lasers"].as_array().unwrap() {
        assert!(l["gaps"].as_array().unwrap().is_empty(), "continuous: {}", l["gaps"]);
        assert!(l["length_mm"].as_f64().unwrap() >= 199_900.0, "{}", l["length_mm"]);
    }
    // The zone: 0+060 to 0+140 in 30–100 mm, 0.040 mm peak to peak; nothing else.
    let verdict = &v["verdict"];
    let zones = verdict["zones"].as_array().unwrap();
    println!("zones: {zones:?}");
    assert_eq!(zones.len(), 1, "{zones:?}");
    let z = &zones[0];
    assert_eq!(z["lo_mm"], 30.0);
    let (zs, ze) = (z["start_mm"].as_f64().unwrap(), z["end_mm"].as_f64().unwrap());
    assert!((zs - 60_000.0).abs() <= 1000.0 && (ze - 140_000.0).abs() <= 1000.0, "{zs} {ze}");
    // 0.040 mm of corrugation plus the roughness the 30–100 mm band passes (a few µm).
    let pp = z["worst_pp_mm"].as_f64().unwrap();
    assert!((0.040..0.055).contains(&pp), "{z}");
    let exceeding = z["exceeding_mm"].as_f64().unwrap();
    assert!((exceeding - 80_000.0).abs() <= 0.02 * 80_000.0, "{exceeding}");
    // The table: 30–100 mm fails, the others pass; 80 m of the measured length to reprofile.
    let bands = verdict["bands"].as_array().unwrap();
    for bnd in bands {
        let lo = bnd["lo_mm"].as_f64().unwrap();
        let measured = bnd["measured_mm"].as_f64().unwrap();
        assert!(measured > 150_000.0, "{bnd}");
        assert_eq!(bnd["passes"], lo != 30.0, "{bnd}");
    }
    let reprofile = verdict["reprofile_mm"].as_f64().unwrap();
    assert!((reprofile - 80_000.0).abs() <= 0.02 * 80_000.0, "{reprofile}");
    // The text says so too.
    let o = run(&["analyze", a, b, "--chainage", "0+000", "--chainage", "0+197"]);
    let text = String::from_utf8_lossy(&o.stdout);
    println!("{text}");
    assert!(
        text.contains("km should be reprofiled") && text.contains("0+06") && text.contains("EN 13231-3:2006"),
        "{text}"
    );
}

/// `analyze PROFILE.csv` is the same analysis as a recording's: the
/// stitched profile a report exports (`profile.csv`), read back, gives the
/// same EN 13231-3 bands and EN 15610 spectrum.
#[test]
fn a_profile_file_gives_the_same_analysis_as_its_recording() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("survey.cmsrec");
    let r = rec.to_str().unwrap();
    let o = run(&["bench", "recording", "--frames", "800", "--out", r]);
    assert!(o.status.success(), "{o:?}");
    let report = dir.path().join("report");
    let o = run(&["analyze", r, "--json", "--report", report.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    let from_rec: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let csv = report.join("profile.csv");
    let o = run(&["analyze", csv.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from_csv: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(from_csv["resampled"], false);
    let (a, b) = (from_rec["lasers"].as_array().unwrap(), from_csv["lasers"].as_array().unwrap());
    assert_eq!(a.len(), b.len());
    let mut compared = 0;
    for (la, lb) in a.iter().zip(b) {
        assert_eq!(la["x0_mm"], lb["x0_mm"]);
        assert_eq!(la["samples"], lb["samples"]);
        for (ba, bb) in
            la["en13231"]["bands"].as_array().unwrap().iter().zip(lb["en13231"]["bands"].as_array().unwrap())
        {
            for key in ["average_mean_pp_mm", "worst_max_pp_mm", "rms_mm", "exceeding_percent"] {
                match (ba[key].as_f64(), bb[key].as_f64()) {
                    (Some(x), Some(y)) => {
                        assert!((x - y).abs() <= 1e-6 * x.abs().max(1.0), "{key}: {x} vs {y}");
                        compared += 1;
                    }
                    (x, y) => assert_eq!(x, y, "{key}: {ba} vs {bb}"),
                }
            }
        }
        let (sa, sb) = (la["en15610"]["bands"].as_array().unwrap(), lb["en15610"]["bands"].as_array().unwrap());
        assert_eq!(sa.len(), sb.len());
        for (x, y) in sa.iter().zip(sb) {
            let (x, y) = (x["level_db"].as_f64().unwrap(), y["level_db"].as_f64().unwrap());
            assert!((x - y).abs() < 0.01, "{x} vs {y} dB");
            compared += 1;
        }
    }
    assert!(compared > 50, "{compared}");
}

/// EN 15610 against an independent implementation of the same definition
/// (`tests/scripts/en15610_reference.py`, plain Python: spike removal,
/// the wheel centre's path, one-third octaves) on a profile of sines from
/// 5 to 300 mm, broadband roughness, spikes and pits: within 0.5 dB in
/// every band either evaluates, through `analyze PROFILE.csv --json --dx-mm 1`.
#[test]
fn en15610_levels_agree_with_an_independent_implementation() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/standards");
    let profile = data.join("en15610_profile.csv");
    let o = run(&["analyze", profile.to_str().unwrap(), "--json", "--dx-mm", "1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ours: Vec<(f64, f64)> = v["lasers"][0]["en15610"]["bands"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| (b["nominal_wavelength_mm"].as_f64().unwrap(), b["level_db"].as_f64().unwrap()))
        .collect();
    let reference: Vec<(f64, f64)> = std::fs::read_to_string(data.join("en15610_levels.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with('n'))
        .map(|l| {
            let (w, d) = l.split_once(',').unwrap();
            (w.parse().unwrap(), d.parse().unwrap())
        })
        .collect();
    assert_eq!(ours.len(), reference.len(), "{ours:?} vs {reference:?}");
    println!("spikes removed: {}", v["lasers"][0]["en15610"]["spikes_removed"]);
    let mut worst = 0.0f64;
    for ((w, ours), (rw, theirs)) in ours.iter().zip(&reference) {
        assert!((w - rw).abs() < 1e-9, "{w} vs {rw}");
        println!("{w:>6} mm: ours {ours:8.3} dB, independent {theirs:8.3} dB, {:+.3}", ours - theirs);
        worst = worst.max((ours - theirs).abs());
    }
    println!("largest difference {worst:.3} dB");
    assert!(worst <= 0.5, "{worst} dB");
}

/// `listen --survey FILE.toml` stores the survey in the recording's header
/// (format 2 on): `info` shows it, `analyze` names it and places the run by
/// its start chainage and direction; appending to the recording with
/// another survey is refused, and a bad survey file is a one-line error.
#[test]
fn a_survey_file_travels_with_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    let survey = dir.path().join("survey.toml");
    std::fs::write(
        &survey,
        "line = \"LN 1234\"\ntrack = \"up main\"\nrail = \"left\"\nstart_chainage = \"12+345.600\"\nchainage = \"down\"\noperator = \"A. Engineer\"\n",
    )
    .unwrap();
    let rec = dir.path().join("run.cmsrec");
    let (r, s) = (rec.to_str().unwrap(), survey.to_str().unwrap());
    let state = dir.path().join("state");
    let st = state.to_str().unwrap();
    let l = run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--sim-state",
        st,
        "--frames",
        "20",
        "--record",
        r,
        "--survey",
        s,
    ]);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    let info = String::from_utf8(run(&["info", r]).stdout).unwrap();
    assert!(info.contains("format: 6 (wire protocol 5)\n") && info.contains("survey: line = \"LN 1234\""), "{info}");
    let o = run(&["analyze", r, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["survey"]["line"], "LN 1234");
    assert_eq!(v["run_joins"][0]["heading"], "down");
    assert!((v["run_joins"][0]["start_m"].as_f64().unwrap() - 12_345.6).abs() < 1e-6);
    // Down from 12+345.600: the profile lies just below it.
    let x0 = v["lasers"][0]["x0_mm"].as_f64().unwrap();
    assert!(x0 < 12_345_600.0 && x0 > 12_345_600.0 - 5_000.0, "{x0}");
    let text = String::from_utf8(run(&["analyze", r]).stdout).unwrap();
    assert!(
        text.contains("survey: line LN 1234, track up main, left rail, odometer 0 at 12+345.600, chainage down"),
        "{text}"
    );
    // Another survey on the same file is refused; so is a bad file.
    std::fs::write(&survey, "line = \"LN 9\"\n").unwrap();
    let e = one_line_error(&run(&["listen", "sim", "--sim-state", st, "--frames", "2", "--record", r, "--survey", s]));
    assert!(e.contains("another survey"), "{e}");
    std::fs::write(&survey, "lnie = \"LN 9\"\n").unwrap();
    let e = one_line_error(&run(&["listen", "sim", "--sim-state", st, "--frames", "2", "--record", r, "--survey", s]));
    assert!(e.contains("lnie"), "{e}");
}

/// `listen sim` records the optics its light is rendered with (the survey
/// block's `[optics]`): `info` shows them and `analyze` checks the floor
/// against them (`noise.predicted`); a recording in incoherent light does
/// not say, and `analyze` says its floor is not checked unless `--optics`
/// gives them; bad optics are a one-line error.
#[test]
fn a_recording_says_what_optics_it_was_made_with() {
    let dir = tempfile::tempdir().unwrap();
    let (laser, plain) = (dir.path().join("laser.cmsrec"), dir.path().join("plain.cmsrec"));
    let (lr, pr) = (laser.to_str().unwrap(), plain.to_str().unwrap());
    let state = dir.path().join("state");
    let st = state.to_str().unwrap();
    // Optics given that are the head's own (the push-trolley light's) are
    // recorded as its own.
    for (r, light) in [(lr, ["--optics=2.8@685", "--sim-light=speckle=2.8"]), (pr, ["--sim-light=incoherent", ""])] {
        let mut args = vec!["listen", "sim", "--sim-state", st, "--frames", "12", "--record", r];
        args.extend(light.into_iter().filter(|a| !a.is_empty()));
        let l = run(&args);
        assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    }
    let info = String::from_utf8(run(&["info", lr]).stdout).unwrap();
    assert!(info.contains("optics: F/2.8, 685 nm"), "{info}");
    assert!(!String::from_utf8(run(&["info", pr]).stdout).unwrap().contains("optics"));
    let json = |args: &[&str]| -> serde_json::Value {
        let o = run(args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let p = &json(&["analyze", lr, "--json"])["noise"]["predicted"];
    assert_eq!(
        (p["checked"].as_bool(), p["f_number"].as_f64(), p["source"].as_str()),
        (Some(true), Some(2.8), Some("recorded"))
    );
    assert!((p["point_um"].as_f64().unwrap() - 43.08).abs() < 0.01, "{p}");
    assert!(p["speed_mm_s"].as_f64().unwrap() > 0.0 && p["exposure_us"].as_f64().unwrap() > 0.0, "{p}");
    let text = String::from_utf8(run(&["analyze", pr]).stdout).unwrap();
    assert!(text.contains("optics not recorded: the floor is not checked"), "{text}");
    let p = &json(&["analyze", pr, "--json", "--optics", "F/4@685"])["noise"]["predicted"];
    assert_eq!(
        (p["checked"].as_bool(), p["f_number"].as_f64(), p["source"].as_str()),
        (Some(true), Some(4.0), Some("given"))
    );
    let bad = run(&["analyze", pr, "--optics", "0.3@685"]);
    let e = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(2), "{e}");
    assert!(e.starts_with("error: ") && e.contains("f_number 0.3: a lens's F-number is 0.7 to 64"), "{e}");
}

/// `listen sim --optics` other than the simulated head's light is refused
/// before the head starts (one line naming both; nothing recorded), in
/// laser light, told or by default, and in incoherent light.
#[test]
fn optics_that_are_not_the_simulated_heads_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("x.cmsrec");
    let r = rec.to_str().unwrap();
    let refused = |extra: &[&str]| {
        let mut args = vec!["listen", "sim", "--frames", "2", "--record", r];
        args.extend(extra);
        let e = one_line_error(&run(&args));
        assert!(!rec.exists(), "{extra:?}: nothing recorded");
        e
    };
    let e = refused(&["--optics", "4@685"]);
    assert!(
        e.contains(
            "--optics says the optics are F/4, 685 nm, the simulated head renders F/1.4, 685 nm (its default light)"
        ),
        "{e}"
    );
    assert!(e.contains("--sim-light speckle=4"), "{e}");
    let e = refused(&["--optics", "2.8@650", "--sim-light", "speckle=2.8"]);
    assert!(e.contains("F/2.8, 650 nm, the simulated head renders F/2.8, 685 nm (its --sim-light)"), "{e}");
    let e = refused(&["--optics", "2.8@685", "--sim-light", "incoherent"]);
    assert!(e.contains("the simulated head renders incoherent light"), "{e}");
}

/// The README's main job within its own limits: `listen sim` at its
/// default speed, recorded for two seconds, then `analyze`. The default
/// travel is under the live page's limit for the reference head's 68.6 mm
/// frames, and every join the head travelled less than that limit's frame
/// step to (less one 1 mm sample) registers: the page's limit is the one
/// `analyze` needs. (A machine too busy to render the real-time head in
/// time leaves longer steps; those may be unregistered.)
#[test]
fn the_main_job_registers_every_join() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("sim.cmsrec");
    let state = dir.path().join("state");
    let l = run(&[
        "listen",
        "sim",
        "--sim-state",
        state.to_str().unwrap(),
        "--duration",
        "2",
        "--record",
        rec.to_str().unwrap(),
    ]);
    assert!(l.status.success(), "{l:?}");
    let rate_hz = 30.0;
    let limit_mm_s = cms_host::serve::speed_limit_mm_s(68.6, rate_hz).unwrap();
    assert!(cms_host::sim::head::DEFAULT_SPEED_MM_S < limit_mm_s, "{limit_mm_s}");
    let mut odometer_mm = std::collections::BTreeMap::new();
    recording::scan_file(&rec, |m| {
        if let cms_core::protocol::DeviceMsg::Profile(p) = m {
            odometer_mm.insert(p.seq, p.odometer_um as f64 / 1000.0);
        }
        Ok(())
    })
    .unwrap();
    let o = run(&["analyze", rec.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let lasers = a["lasers"].as_array().unwrap();
    assert_eq!(lasers.len(), 3, "{a}");
    let within = limit_mm_s / rate_hz - 1.0;
    let steps: Vec<f64> = odometer_mm.values().collect::<Vec<_>>().windows(2).map(|w| w[1] - w[0]).collect();
    assert!(steps.iter().any(|&s| s <= within), "no step within the limit: {steps:?}");
    for l in lasers {
        for j in l["unregistered_joins"].as_array().unwrap() {
            let seq = j["seq"].as_u64().unwrap() as u32;
            let here = odometer_mm[&seq];
            let before = odometer_mm.range(..seq).next_back().map(|(_, &o)| o);
            let step = before.map_or(f64::INFINITY, |b| here - b);
            assert!(step > within, "frame {seq}, {step:.1} mm after the one before (limit {within:.1} mm): {j}");
        }
    }
}

// ------------------------------------------------------------ the noise floor

/// The simulated head at the recommended push-trolley setting (F/2.8 laser
/// light, 100 µs, 1.5 m/s) over a perfectly smooth rail: every band and
/// one-third octave carries its floor, within a factor 2 (6 dB) of what
/// the smooth rail reads; nothing fails, nothing exceeds, nothing is to
/// be reprofiled. The reduced version of `cms-host bench floor`.
#[test]
fn a_smooth_rail_under_laser_light_reads_its_floor_and_never_fails() {
    use cms_host::analyze::standards::en13231::BANDS;
    use cms_host::bench::floor::{measured, measured_spectrum};
    let a = cms_host::sim::floor::run(&cms_host::sim::floor::Setting::push_trolley(1500.0)).unwrap();
    let f = a.floor.as_ref().expect("three lines: the floor is known");
    for (b, band) in BANDS.iter().enumerate().take(2) {
        let (rms, pp) = measured(&a, b).unwrap();
        let fl = f.band(b).unwrap();
        for (what, got, want) in [("RMS", fl.rms_mm, rms), ("mean p-p", fl.average_mean_pp_mm, pp)] {
            assert!(
                (0.5..2.0).contains(&(got / want)),
                "{}: floor {what} {got} mm, smooth rail {want} mm",
                band.name()
            );
        }
        // Speckle is not common to the lines.
        assert!(fl.coherence < 0.2, "{}: coherence {}", band.name(), fl.coherence);
    }
    let floor = f.spectrum.as_ref().unwrap();
    let read = measured_spectrum(&a).unwrap();
    for b in &read.bands {
        let fb = floor.bands.iter().find(|x| x.k == b.k).unwrap();
        assert!(
            (b.level_db - fb.level_db).abs() <= 6.0,
            "{} mm: {} dB read, floor {} dB",
            b.nominal_wavelength_mm,
            b.level_db,
            fb.level_db
        );
        assert_ne!(b.verdict(), Some(Verdict::Exceeds), "{b:?}");
    }
    // The floor is what the optics predict: speckle at F/2.8 and 685 nm,
    // sensor noise (docs/noise-floor.md#the-floor-the-optics-predict).
    let check = cms_host::bench::floor::predicted(&cms_host::sim::floor::Setting::push_trolley(1500.0), Some(f));
    for (b, c) in check.expect("laser light: a prediction").iter().enumerate().take(2) {
        let c = c.expect("the floor of the band is measured");
        assert_eq!(c.agreement, cms_host::analyze::optics_floor::Agreement::Agrees, "{}: {c:?}", BANDS[b].name());
    }
    // So is every one-third octave's: the noise passes EN 15610's steps
    // linearly. One line's floor agrees (within 6 dB) in each, 1.5 dB on
    // average; each line's own within 3 dB from 40 mm down. Longer third
    // octaves hold a few Welch segments of this 2 m record, and a line's
    // own floor there (the pairs' differences) scatters by up to 10 dB.
    {
        use cms_host::analyze::optics_floor::{Agreement, Motion, OpticsCheck, OpticsSource};
        let s = cms_host::sim::floor::Setting::push_trolley(1500.0);
        let optics = cms_host::model::optics::Optics::new(2.8, 685.0).unwrap();
        let motion = Motion { exposure_us: s.exposure_us, speed_mm_s: s.speed_mm_s };
        let OpticsCheck::Checked { octaves, line_octaves, .. } =
            OpticsCheck::of(optics, OpticsSource::Given, s.config().head_lens(), motion, Some(f))
        else {
            panic!("laser light: a prediction")
        };
        assert!(octaves.len() >= 15 && line_octaves.len() == 3, "{octaves:?}");
        assert!(octaves.iter().all(|(_, c)| c.agreement == Agreement::Agrees), "{octaves:?}");
        let mean = octaves.iter().map(|(_, c)| c.ratio_db).sum::<f64>() / octaves.len() as f64;
        assert!(mean.abs() < 1.5, "{mean} dB: {octaves:?}");
        for (mm, c) in line_octaves.iter().flat_map(|(_, c)| c).filter(|(mm, _)| *mm <= 40.0) {
            assert!(c.ratio_db.abs() < 3.0, "{mm} mm: {c:?}");
        }
    }
    let v = &a.verdict;
    assert_eq!(v.reprofile_mm, 0.0, "{v:?}");
    assert!(v.zones.is_empty(), "{:?}", v.zones);
    assert!(v.rows.iter().all(|r| r.passes(v.options.edition) != Some(false)), "{:?}", v.rows);
    assert!(v.blocks.iter().all(|b| b.iso3095.as_ref().is_none_or(|i| i.exceeded_mm.is_empty())), "{:?}", v.blocks);
    for l in &a.lasers {
        for (r, j) in l.bands.as_ref().unwrap().bands.iter().zip(&l.judgements) {
            if let Ok(st) = &r.outcome {
                assert!(
                    st.passes || j.not_judged.is_some(),
                    "laser {}: {} fails on noise",
                    l.stitched.laser,
                    r.band.name()
                );
            }
        }
        let exceeding: Vec<_> = l
            .roughness
            .as_ref()
            .unwrap()
            .spectrum
            .bands
            .iter()
            .filter(|b| b.verdict() == Some(Verdict::Exceeds))
            .collect();
        assert!(exceeding.is_empty(), "laser {}: {exceeding:?}", l.stitched.laser);
    }
}

/// The same light over a rail corrugated over the limits in two bands
/// (20 mm × 15 µm, 60 mm × 20 µm): both bands judged, and failed, on the
/// running band; the floor where the smooth rail has it.
#[test]
fn corrugation_over_the_limits_under_laser_light_is_judged_and_fails() {
    use cms_host::sim::floor::{Setting, run};
    use cms_host::sim::scene::Corrugation;
    let mut s = Setting::push_trolley(1500.0);
    s.corrugation = vec![
        Corrugation { wavelength_mm: 20.0, amplitude_um: 15.0, phase_rad: 0.0 },
        Corrugation { wavelength_mm: 60.0, amplitude_um: 20.0, phase_rad: 1.0 },
    ];
    let a = run(&s).unwrap();
    let v = &a.verdict;
    for row in &v.rows[..2] {
        eprintln!("{row:?}");
        assert!(row.judgement.not_judged.is_none(), "{row:?}");
        assert_eq!(row.passes(v.options.edition), Some(false), "{row:?}");
    }
    assert!(v.reprofile_mm > 0.5 * v.measured_mm, "{} of {}", v.reprofile_mm, v.measured_mm);
    let f = a.floor.as_ref().unwrap();
    for b in 0..2 {
        let fl = f.band(b).unwrap();
        // The smooth rail's floor at this setting: 7.1 / 4.1 µm RMS (docs/benchmarks.md).
        assert!(fl.rms_mm < [0.011, 0.0065][b], "band {b}: {fl:?}");
        assert!(fl.coherence > 0.5, "band {b}: the corrugation is common to the lines: {fl:?}");
    }
}
