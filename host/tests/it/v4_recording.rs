//! A recording made by protocol version 4 (`tests/data/v4/`: four frames of
//! the calibrated simulated head under incoherent light, recorded before
//! protocol version 5) stays readable: `info` prints what that build
//! printed, and `export` (CSV and JSON lines) writes the same points, byte
//! for byte (compared by length and FNV-1a hash; 0.35 and 0.67 MB).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::bin;

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v4")
}

/// Runs `cms-host` in the data directory (the outputs name the files as given).
fn run_in_data(args: &[&str]) -> Output {
    let o = Command::new(bin()).args(args).current_dir(data()).output().unwrap();
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    o
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

#[test]
fn info_reads_a_v4_recording() {
    let o = run_in_data(&["info", "calibrated.cmsrec"]);
    let want = std::fs::read_to_string(data().join("info.txt")).unwrap();
    assert_eq!(String::from_utf8_lossy(&o.stdout), want);
}

#[test]
fn export_reads_a_v4_recording() {
    for (format, len, hash) in [("csv", 354_887, 0xd36d_703e_facc_54d1), ("jsonl", 666_080, 0x761d_5a26_1a55_4249)] {
        let o = run_in_data(&["export", "calibrated.cmsrec", "--format", format, "--out", "-"]);
        assert_eq!((o.stdout.len(), fnv1a(&o.stdout)), (len, hash), "{format}");
    }
}
