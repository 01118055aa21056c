//! A recording made by protocol version 3 (`tests/data/v3/`: four frames of
//! the calibrated simulated head, recorded before protocol version 4) stays
//! readable by every command that reads recordings: `info`, `export` (CSV
//! and JSON lines), `measure` and `analyze` print what they printed then.
//! The expected outputs were made by that build, except `analyze.txt`,
//! made again when `analyze` began to print chainage, the EN 13231-3
//! verdict and the noise floor's check against the optics (the same
//! frames, read from the same file: `info` and `export` still match the
//! version-3 build exactly); the exports are compared by length and
//! FNV-1a hash (they are 0.36 and 0.79 MB).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::bin;

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v3")
}

/// Runs `cms-host` in the data directory (the outputs name the files as given).
fn run_in_data(args: &[&str]) -> Output {
    let o = Command::new(bin()).args(args).current_dir(data()).output().unwrap();
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    o
}

fn expected(name: &str) -> String {
    std::fs::read_to_string(data().join(name)).unwrap()
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

#[test]
fn info_reads_a_v3_recording() {
    let o = run_in_data(&["info", "calibrated.cmsrec"]);
    let out = String::from_utf8_lossy(&o.stdout);
    // Everything the version-3 build printed, and the wire cost and the
    // line pass's counts (none: that head had no line pass) it did not.
    let new = |l: &str| l.starts_with("profile bytes: ") || l.starts_with("line pass: ");
    let old: String = out.lines().filter(|l| !new(l)).map(|l| format!("{l}\n")).collect();
    assert_eq!(old, expected("info.txt"));
    assert!(out.contains("profile bytes: 102741 (17.84 per point, frames included)"), "{out}");
    assert!(out.contains("line pass: 0 glint, 0 ghost, 0 off-line points rejected"), "{out}");
}

#[test]
fn export_reads_a_v3_recording() {
    // The JSON lines as the version-3 build wrote them, once the line
    // pass's counts (all zero) each line now ends with are taken off.
    const LINE: &str = r#","line":{"glint":0,"ghost":0,"off_line":0,"second_dropped":0}}"#;
    for (format, len, hash) in [("csv", 355_302, 0xa349_26db_97cf_d53d), ("jsonl", 786_780, 0xb436_b4c7_f118_6578)] {
        let o = run_in_data(&["export", "calibrated.cmsrec", "--format", format, "--out", "-"]);
        let mut out = String::from_utf8(o.stdout).unwrap();
        if format == "jsonl" {
            assert!(out.lines().all(|l| l.ends_with(LINE)), "{format}");
            out = out.replace(&format!("{LINE}\n"), "}\n");
        }
        assert_eq!((out.len(), fnv1a(out.as_bytes())), (len, hash), "{format}");
    }
}

#[test]
fn measure_and_analyze_read_a_v3_recording() {
    let o = run_in_data(&["measure", "--calibration", "cal.toml", "calibrated.cmsrec"]);
    assert_eq!(String::from_utf8_lossy(&o.stdout), expected("measure.txt"));
    let o = run_in_data(&["analyze", "calibrated.cmsrec"]);
    assert_eq!(String::from_utf8_lossy(&o.stdout), expected("analyze.txt"));
}
