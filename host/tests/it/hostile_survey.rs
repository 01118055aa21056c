//! Hostile input to the survey layer's joins: what the user said about
//! the runs (their chainages, headings, directions; which recordings) is
//! taken as given and checked against registration, never overridden or
//! averaged away; a typo in a chainage is a gap, not an allocation; runs
//! are numbered from 1 everywhere.

use crate::common::{bin, one_line_error, run};
use cms_host::sim::synthetic::{self, Rail};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A short run over the survey rail (broadband roughness, corrugation from
/// 5 to 15 m): `frames` every 17 mm from the synthetic head's odometer 100
/// mm, its odometer's zero at track position `start_mm`.
fn run_over(dir: &Path, name: &str, frames: u32, tweak: impl FnOnce(&mut synthetic::Options)) -> PathBuf {
    let rail = Rail::Survey { zone_mm: (5_000.0, 15_000.0), wavelength_mm: 50.0, amplitude_um: 20.0 };
    let mut o = synthetic::Options { frames, points_per_line: 240, rail, ..synthetic::Options::default() };
    tweak(&mut o);
    let path = dir.join(name);
    synthetic::write(&path, &o, &cms_host::progress::Silent).unwrap();
    path
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn json(o: &Output) -> Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// `cms-host` with its address space limited to `mb` (what a process
/// that tries to allocate a gap's worth of samples cannot stay under).
fn run_limited(mb: u64, args: &[&str]) -> Output {
    let script = format!("ulimit -v {}; exec \"$0\" \"$@\"", mb * 1024);
    Command::new("sh").arg("-c").arg(script).arg(bin()).args(args).output().unwrap()
}

/// Item: a chainage typo (100 000 km) or runs 100 km apart. The gap between
/// them is not allocated: the line is two sections, each judged on its own,
/// the gap reported, and the whole fits in 1.5 GB of address space (the
/// dense line would need 1.2 GB per line at 100 km, and 800 GB for the typo).
#[test]
fn a_chainage_typo_is_a_gap_not_an_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_over(dir.path(), "a.cmsrec", 600, |_| {});
    let b = run_over(dir.path(), "b.cmsrec", 600, |o| o.seed = 2);
    for far in ["100000+000", "100+000"] {
        let args = ["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", far, "--json"];
        let v = json(&run_limited(1500, &args));
        let far_mm = far.split('+').next().unwrap().parse::<f64>().unwrap() * 1e6;
        let sections = v["sections"].as_array().unwrap();
        assert_eq!(sections.len(), 2, "{far}: {sections:?}");
        assert!((sections[1]["start_mm"].as_f64().unwrap() - far_mm).abs() < 200.0, "{far}: {sections:?}");
        let j = &v["run_joins"][1];
        assert_eq!(
            (j["run"].as_u64(), j["section"].as_u64(), j["registered"].as_bool()),
            (Some(2), Some(2), Some(false))
        );
        assert_eq!(j["moved_mm"], 0.0, "{j}");
        for l in v["lasers"].as_array().unwrap() {
            // Each line of each section is one run's 10 m, never the gap.
            assert!(l["length_mm"].as_f64().unwrap() < 10_300.0, "{l}");
        }
        assert_eq!(v["lasers"].as_array().unwrap().len(), 6);
        // Both sections measured: twice one run's length judged.
        let measured = v["verdict"]["measured_mm"].as_f64().unwrap();
        assert!(measured > 2.0 * 5_000.0 && measured < 2.0 * 10_300.0, "{measured}");
    }
    let o = run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "100+000"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("survey line in 2 sections") && text.contains("not measured: 0+010."), "{text}");
    assert!(text.contains("section 2: 100+000.0"), "{text}");
}

/// Item: two runs whose chainages place them end to end are not averaged as
/// if they overlapped, even where their rail would register (run 2 really
/// starts 7.8 m before run 1's end): placed as given, the disagreement
/// flagged. Its heading was not given, and registration did not find it:
/// the message says neither "found by registration" nor anything it did not do.
#[test]
fn end_to_end_runs_are_not_overlapped_by_registration() {
    let dir = tempfile::tempdir().unwrap();
    // Run 1: track 0.066–20.1 m. Run 2: its odometer's zero at 12.2 m, so it
    // covers 12.27–32.3 m; the user says it starts where run 1 ends.
    let a = run_over(dir.path(), "a.cmsrec", 1176, |_| {});
    let b = run_over(dir.path(), "b.cmsrec", 1176, |o| (o.seed, o.start_mm) = (2, 12_200.0));
    let v = json(&run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "0+020.100", "--json"]));
    let j = &v["run_joins"][1];
    assert_eq!(j["registered"], false, "{j}");
    assert_eq!(j["heading_found"], false, "{j}");
    assert!((j["start_m"].as_f64().unwrap() - 20.1).abs() < 1e-6, "{j}");
    assert!(j["overlap_mm"].as_f64().unwrap() < 100.0, "{j}");
    let moved = j["chainage_disputed"]["registration_moved_mm"].as_f64().unwrap();
    assert!((moved + 7_900.0).abs() < 50.0, "{j}");
    let o = run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "0+020.100"]);
    let text = String::from_utf8_lossy(&o.stdout);
    let line = text.lines().find(|l| l.starts_with("run 2:")).unwrap();
    assert!(line.contains("placed as given") && line.contains("CHAINAGE DISPUTED"), "{line}");
    assert!(!line.contains("found by registration"), "{line}");
    // Given 3 m off but overlapping, it is registered, moved within the
    // tolerance: the user's start said they overlap.
    let v = json(&run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "0+015", "--json"]));
    let j = &v["run_joins"][1];
    assert_eq!(j["registered"], true, "{j}");
    assert!((j["start_m"].as_f64().unwrap() - 12.2).abs() < 0.005, "{j}");
}

/// Item: recordings from different heads are refused unless asked for,
/// naming both runs from 1; asked for, the report says so.
#[test]
fn runs_of_different_heads_are_refused_unless_asked() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_over(dir.path(), "a.cmsrec", 600, |_| {});
    let b =
        run_over(dir.path(), "b.cmsrec", 600, |o| (o.seed, o.start_mm, o.calibration_id) = (2, 5_000.0, 0x0bad_cafe));
    let e = one_line_error(&run(&["analyze", s(&a), s(&b)]));
    assert!(e.contains("run 2 (") && e.contains("run 1 (") && e.contains("another head"), "{e}");
    assert!(e.contains("0x0badcafe") && e.contains("--allow-mixed-heads"), "{e}");
    let o = run(&["analyze", s(&a), s(&b), "--allow-mixed-heads"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("recorded by another head than run 1"), "{text}");
}

/// Item: the same recording given twice — the same file, or a copy — is
/// refused unless asked for; asked for, the report says so. A run forced to
/// the other heading against itself is flagged, not merged silently.
#[test]
fn the_same_recording_twice_is_refused_unless_asked() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_over(dir.path(), "a.cmsrec", 600, |_| {});
    let copy = dir.path().join("copy.cmsrec");
    std::fs::copy(&a, &copy).unwrap();
    for second in [&a, &copy] {
        let e = one_line_error(&run(&["analyze", s(&a), s(second)]));
        assert!(e.contains("run 2 (") && e.contains("the same recording as run 1"), "{e}");
    }
    let v = json(&run(&["analyze", s(&a), s(&copy), "--allow-repeated-runs", "--json"]));
    assert_eq!(v["runs"][1]["repeats_run"], 1, "{}", v["runs"]);
    // Given twice, the second forced to run down from where the first
    // starts: its rail matches itself only up; flagged.
    let args = ["analyze", s(&a), s(&a), "--allow-repeated-runs", "--chainage", "0+000", "--chainage", "0+010:down"];
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("the same recording as run 1, joined as asked"), "{text}");
    let line = text.lines().find(|l| l.starts_with("run 2:")).unwrap();
    assert!(line.contains("chainage down") && line.contains("HEADING DISPUTED"), "{line}");
}

/// Item: a direction forced against the frames (the head mounted forward,
/// `--direction reverse`) is used as given and flagged; the right one is not.
#[test]
fn a_forced_direction_is_checked_against_the_frames() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_over(dir.path(), "a.cmsrec", 600, |_| {});
    let v = json(&run(&["analyze", s(&a), "--direction", "reverse", "--json"]));
    assert_eq!(v["direction"], "reverse");
    let d = &v["run_joins"][0]["direction_disputed"];
    assert!(d["other_um"].as_f64().unwrap() < 0.8 * d["given_um"].as_f64().unwrap(), "{d}");
    let text = String::from_utf8_lossy(&run(&["analyze", s(&a), "--direction", "reverse"]).stdout).to_string();
    assert!(text.contains("run 1:") && text.contains("DIRECTION DISPUTED"), "{text}");
    let v = json(&run(&["analyze", s(&a), "--direction", "forward", "--json"]));
    assert_eq!(v["run_joins"][0]["direction_disputed"], Value::Null, "{}", v["run_joins"]);
}

/// Item: runs are numbered from 1 in every message: the join's errors, the
/// placement lines, the JSON.
#[test]
fn runs_are_numbered_from_one_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_over(dir.path(), "a.cmsrec", 600, |_| {});
    let b = run_over(dir.path(), "b.cmsrec", 600, |o| (o.seed, o.start_mm) = (2, 50_000.0));
    // Run 2 overlaps nothing and has no start: the error names run 2.
    let e = one_line_error(&run(&["analyze", s(&a), s(&b)]));
    assert!(e.contains("run 2 matches no earlier run"), "{e}");
    let v = json(&run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "0+050", "--json"]));
    let runs: Vec<u64> = v["run_joins"].as_array().unwrap().iter().map(|j| j["run"].as_u64().unwrap()).collect();
    assert_eq!(runs, [1, 2]);
    let text =
        String::from_utf8_lossy(&run(&["analyze", s(&a), s(&b), "--chainage", "0+000", "--chainage", "0+050"]).stdout)
            .to_string();
    assert!(text.contains("\nrun 1: ") && text.contains("\nrun 2: ") && !text.contains("run 0"), "{text}");
}
