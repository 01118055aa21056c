//! Hostile input to the survey layer, as a careless or malicious user gives
//! it: values that look like numbers but are not what the option means,
//! files a spreadsheet or a hand wrote, text that would drive the terminal.
//! Each gets a one-line error naming the value and exit status 2, or is
//! read as the user meant it — never ignored, never a silent change.

use crate::common::run;
use std::path::Path;
use std::process::Output;

/// Asserts exit status 2 with one `error: ` line (clap adds its usage
/// lines, `listen` its summary), and returns that line.
fn one_line_error(o: &Output) -> String {
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    let e = String::from_utf8_lossy(&o.stderr);
    let errors: Vec<&str> = e.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(errors.len(), 1, "{e}");
    errors[0].to_string()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A profile CSV of `metres` at 1 mm: a 50 mm corrugation of 20 µm.
fn profile_csv(path: &Path, header: &str, metres: usize) {
    let mut t = format!("{header}\n");
    for i in 0..metres * 1000 {
        let x = i as f64;
        t += &format!("{x},{:.3}\n", 20.0 * (std::f64::consts::TAU * x / 50.0).sin());
    }
    std::fs::write(path, t).unwrap();
}

#[test]
fn chainages_are_plain_km_plus_metres() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("p.csv");
    profile_csv(&csv, "x_mm,height_um", 3);
    for bad in ["--5", "12+1e2", "1e3", "12+-3", "inf", "12+1000"] {
        let e = one_line_error(&run(&["analyze", s(&csv), &format!("--chainage={bad}")]));
        assert!(e.contains(bad), "{bad}: {e}");
    }
    let o = run(&["analyze", s(&csv), "--chainage", "12+345.5", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn lengths_outside_their_meaning_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("p.csv");
    profile_csv(&csv, "x_mm,height_um", 3);
    for (flag, value) in [
        ("--block-m", "1e6"),
        ("--block-m", "0.5"),
        ("--search-m", "0"),
        ("--search-m", "5000"),
        ("--dx-mm", "0.001"),
        ("--dx-mm", "50"),
        ("--segment-mm", "10"),
        ("--segment-mm", "nan"),
    ] {
        let e = one_line_error(&run(&["analyze", s(&csv), flag, value]));
        assert!(e.contains(value) && e.contains(flag), "{flag} {value}: {e}");
    }
    for value in ["2.3", "1e9", "-3"] {
        let e = one_line_error(&run(&["bench", "annex-a", &format!("--length-m={value}")]));
        assert!(e.contains(value) && e.contains("2.4 to 100"), "--length-m {value}: {e}");
    }
}

/// A spreadsheet's byte-order mark is not part of the header; heights no
/// rail has are refused with their line; options only recordings have are
/// refused for a profile, not ignored.
#[test]
fn profile_files_as_spreadsheets_and_hands_write_them() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("bom.csv");
    profile_csv(&csv, "\u{feff}x_mm,height_um", 3);
    let o = run(&["analyze", s(&csv), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["lasers"].as_array().unwrap().len(), 1, "{v}");

    let huge = dir.path().join("huge.csv");
    std::fs::write(&huge, "x_mm,height_um\n0,1\n1,1e300\n2,-1e300\n").unwrap();
    let e = one_line_error(&run(&["analyze", s(&huge)]));
    assert!(e.contains("line 3") && e.contains("1e300"), "{e}");

    for flag in [["--direction", "reverse"], ["--register", "none"]] {
        let e = one_line_error(&run(&["analyze", s(&csv), flag[0], flag[1]]));
        assert!(e.contains(flag[0]) && e.contains("applies to recordings"), "{e}");
    }
}

/// A survey's text reaches the terminal and the report shown, never acted
/// on: an escape that would clear the screen or retitle the terminal is
/// printed as `\u{1b}`.
#[test]
fn survey_text_cannot_drive_the_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let survey = dir.path().join("survey.toml");
    std::fs::write(&survey, "line = \"LN\\u001b[2J 7\"\nnotes = \"pass 2\\u001b]0;owned\\u0007\\u009b31m\\u202e\"\n")
        .unwrap();
    let rec = dir.path().join("run.cmsrec");
    let state = dir.path().join("state");
    let l = run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--sim-state",
        s(&state),
        "--frames",
        "12",
        "--record",
        s(&rec),
        "--survey",
        s(&survey),
    ]);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    let acts = |t: &str| t.chars().any(|c| (c.is_control() && c != '\n' && c != '\t') || c == '\u{202e}');
    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(!acts(&info) && info.contains("\\u{9b}31m"), "{info:?}");
    let report = dir.path().join("report");
    let o = run(&["analyze", s(&rec), "--report", s(&report)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(!acts(&text) && text.contains("notes: pass 2\\u{1b}]0;owned"), "{text:?}");
    for f in ["report.md", "report.html", "summary.txt"] {
        let t = std::fs::read_to_string(report.join(f)).unwrap();
        assert!(!acts(&t), "{f}: {t:?}");
    }
}

/// Settings beyond what the head takes are the user's to fix (exit 2, the
/// option named), not a broken link (3).
#[test]
fn settings_the_head_refuses_are_bad_usage() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let e =
        one_line_error(&run(&["listen", "sim", "--sim-state", s(&state), "--frames", "2", "--window", "0:700-1000"]));
    assert!(e.contains("SetWindows") && e.contains("--window"), "{e}");
    let e =
        one_line_error(&run(&["listen", "sim", "--sim-state", s(&state), "--frames", "2", "--exposure", "1000000"]));
    assert!(e.contains("--exposure"), "{e}");
}

/// Tracking follows one line per window: windows that share columns would
/// give every line's stripes to one laser and drop the others, so the
/// combination is refused before anything streams; without tracking the
/// same windows stream every laser.
#[test]
fn tracking_overlapping_windows_is_refused_not_lossy() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let cal = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/v3/cal.toml");
    let st = s(&state);
    let e = one_line_error(&run(&[
        "listen",
        "sim",
        "--sim-state",
        st,
        "--windows-from",
        cal,
        "--track",
        "8",
        "--frames",
        "2",
    ]));
    assert!(e.contains("--track") && e.contains("overlap") && e.contains("laser 0"), "{e}");
    let manual = ["--window", "0:250-400", "--window", "1:330-450", "--window", "2:440-520", "--track", "8"];
    let e = one_line_error(&run(&[&["listen", "sim", "--sim-state", st, "--frames", "2"][..], &manual].concat()));
    assert!(e.contains("laser 0") && e.contains("laser 1"), "{e}");
    let o = run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--sim-state",
        st,
        "--windows-from",
        cal,
        "--frames",
        "3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for line in String::from_utf8(o.stdout).unwrap().lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        for l in v["lasers"].as_array().unwrap() {
            assert!(l["points"].as_array().unwrap().len() >= 470, "laser {}", l["laser"]);
        }
    }
}

/// An output set never goes into the folder of one of its inputs (the
/// report writes a `profile.csv` of its own): refused before any work, the
/// input untouched, whatever name the folder is given by.
#[test]
fn an_output_folder_never_holds_an_input() {
    let dir = tempfile::tempdir().unwrap();
    let clob = dir.path().join("clob");
    std::fs::create_dir(&clob).unwrap();
    let csv = clob.join("profile.csv");
    profile_csv(&csv, "x_mm,height_um", 3);
    let before = std::fs::read(&csv).unwrap();
    let via = format!("{}/../clob/.", clob.display());
    for (flag, out) in [("--report", s(&clob)), ("--parquet", s(&clob)), ("--report", via.as_str())] {
        let e = one_line_error(&run(&["analyze", s(&csv), flag, out]));
        assert!(e.contains(flag) && e.contains("holds the input"), "{e}");
    }
    assert_eq!(std::fs::read(&csv).unwrap(), before);
    assert_eq!(std::fs::read_dir(&clob).unwrap().count(), 1);
    let o = run(&["analyze", s(&csv), "--report", s(&dir.path().join("report"))]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A survey "file" that never ends (a device) is refused by its size, at
/// once; so is one that is not text.
#[test]
fn a_survey_file_is_read_within_its_limit() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let rec = dir.path().join("r.cmsrec");
    let base = ["listen", "sim", "--sim-state", s(&state), "--frames", "1", "--record", s(&rec), "--survey"];
    let e = one_line_error(&run(&[&base[..], &["/dev/zero"]].concat()));
    assert!(e.contains("/dev/zero") && e.contains("at most 16384"), "{e}");
    let big = dir.path().join("big.toml");
    std::fs::write(&big, format!("notes = \"{}\"\n", "x".repeat(20_000))).unwrap();
    let e = one_line_error(&run(&[&base[..], &[s(&big)]].concat()));
    assert!(e.contains("at most 16384"), "{e}");
    assert!(!rec.exists());
}

/// A profile CSV of `lines` lines over `metres` at 1 mm, each a
/// corrugation of its own wavelength.
fn lines_csv(path: &Path, lines: usize, metres: usize) {
    use std::fmt::Write as _;
    let mut t = String::from("x_mm");
    for k in 0..lines {
        let _ = write!(t, ",height_um_{k}");
    }
    t.push('\n');
    for i in 0..metres * 1000 {
        let x = i as f64;
        let _ = write!(t, "{x}");
        for k in 0..lines {
            let _ = write!(t, ",{:.3}", 20.0 * (std::f64::consts::TAU * x / (40.0 + 10.0 * k as f64)).sin());
        }
        t.push('\n');
    }
    std::fs::write(path, t).unwrap();
}

/// Every file of a folder, by name.
fn files_of(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().into_string().unwrap(), std::fs::read(e.path()).unwrap())
        })
        .collect()
}

/// The names in a folder.
fn names_in(dir: &Path) -> Vec<String> {
    let mut n: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    n.sort();
    n
}

/// A rerun over an existing report replaces it whole: a report of three
/// lines, then one of one line, leaves no `bands_laser2.csv` of the first;
/// the folder holds what a report into a new folder holds, and nothing is
/// left beside it. A folder holding what no report writes (a user's notes,
/// a report where Parquet files alone should go) is refused before the
/// work, untouched.
#[test]
fn a_rerun_replaces_an_output_set_whole() {
    let dir = tempfile::tempdir().unwrap();
    let (three, one) = (dir.path().join("three.csv"), dir.path().join("one.csv"));
    lines_csv(&three, 3, 3);
    lines_csv(&one, 1, 3);
    let out = dir.path().join("out");
    let o = run(&["analyze", s(&three), "--report", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("bands_laser2.csv").exists());
    let o = run(&["analyze", s(&one), "--report", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fresh = dir.path().join("fresh");
    assert!(run(&["analyze", s(&one), "--report", s(&fresh)]).status.success());
    assert_eq!(names_in(&out), names_in(&fresh));
    assert!(!out.join("bands_laser1.csv").exists() && !out.join("bands_laser2.csv").exists());
    assert_eq!(std::fs::read(out.join("profile.csv")).unwrap(), std::fs::read(fresh.join("profile.csv")).unwrap());
    assert_eq!(names_in(dir.path()), ["fresh", "one.csv", "out", "three.csv"], "nothing left beside the sets");

    // The same for --parquet, and a report folder is no Parquet set.
    let pq = dir.path().join("pq");
    std::fs::create_dir(&pq).unwrap();
    std::fs::write(pq.join("zones.parquet"), b"old").unwrap();
    assert!(run(&["analyze", s(&one), "--parquet", s(&pq)]).status.success());
    assert_eq!(
        names_in(&pq),
        ["blocks.parquet", "fixes.parquet", "profile.parquet", "third_octaves.parquet", "zones.parquet"]
    );
    assert_ne!(std::fs::read(pq.join("zones.parquet")).unwrap(), b"old");
    let before = files_of(&out);
    let e = one_line_error(&run(&["analyze", s(&one), "--parquet", s(&out)]));
    assert!(
        e.contains("--parquet") && e.contains("no file of this output set") && e.contains("refusing to replace it"),
        "{e}"
    );
    assert_eq!(files_of(&out), before);

    // A user's file in the folder: refused, kept.
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let e = one_line_error(&run(&["analyze", s(&one), "--report", s(&out)]));
    assert!(e.contains("--report") && e.contains("holds notes.txt"), "{e}");
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"mine");
    std::fs::remove_file(out.join("notes.txt")).unwrap();

    // One folder for both: the report (which holds the Parquet files), once;
    // one inside the other: refused (each is replaced whole).
    let o = run(&["analyze", s(&one), "--report", s(&out), "--parquet", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(names_in(&out), names_in(&fresh));
    let inner = out.join("pq");
    let e = one_line_error(&run(&["analyze", s(&one), "--report", s(&out), "--parquet", s(&inner)]));
    assert!(e.contains("one folder inside the other"), "{e}");
    let file = dir.path().join("one.csv");
    let e = one_line_error(&run(&["analyze", s(&three), "--parquet", s(&file)]));
    assert!(e.contains("a regular file, not a directory"), "{e}");
}

/// `analyze --report` killed (SIGKILL) while it writes a large report over
/// an old one: the folder holds the old report whole, byte for byte, or the
/// new one whole — never a mix; at most a hidden folder of the unfinished
/// set is left beside it, and a rerun completes.
#[test]
fn an_interrupted_report_leaves_the_old_set_or_the_new_whole() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let dir = tempfile::tempdir().unwrap();
    let (small, big) = (dir.path().join("small.csv"), dir.path().join("big.csv"));
    lines_csv(&small, 1, 3);
    lines_csv(&big, 3, 150);
    let out = dir.path().join("out");
    assert!(run(&["analyze", s(&small), "--report", s(&out)]).status.success());
    let old = files_of(&out);
    let mut child = std::process::Command::new(crate::common::bin())
        .args(["analyze", s(&big), "--report", s(&out)])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // The event: the hidden folder of the new set holds its first file.
    let hidden = |d: &Path| {
        std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.file_name().unwrap().to_str().unwrap().starts_with(".out."))
    };
    let caught = loop {
        if child.try_wait().unwrap().is_some() {
            break false;
        }
        if let Some(h) = hidden(dir.path())
            && std::fs::read_dir(&h).is_ok_and(|mut r| r.next().is_some())
        {
            kill(Pid::from_raw(child.id() as i32), Signal::SIGKILL).unwrap();
            break true;
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    child.wait().unwrap();
    assert!(caught, "the report was written before the test saw it begin");
    let now = files_of(&out);
    if now != old {
        // The kill came after the exchange: the new set, whole.
        let fresh = dir.path().join("fresh");
        assert!(run(&["analyze", s(&big), "--report", s(&fresh)]).status.success());
        assert_eq!(now, files_of(&fresh), "neither the old report nor the new one");
        std::fs::remove_dir_all(&fresh).unwrap();
    }
    let beside: Vec<String> = names_in(dir.path()).into_iter().filter(|n| n.starts_with('.')).collect();
    assert!(beside.len() <= 1 && beside.iter().all(|n| n.starts_with(".out.") && n.ends_with(".tmp")), "{beside:?}");
    let o = run(&["analyze", s(&big), "--report", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("bands_laser2.csv").exists() && !files_of(&out).keys().any(|n| n.starts_with('.')));
}
