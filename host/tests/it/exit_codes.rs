//! The documented exit statuses, one class at a time: 0 success, 2 a bad
//! input (missing, a directory, unreadable), 3 the device or the link, 1 an
//! output that cannot be written. Every failure is one `error:` line that
//! names what was wrong.

use std::fs::{self, File};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};

use super::common::{bin, one_line_error, one_line_failure, run};

const REC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/v3/calibrated.cmsrec");
const CAL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/v3/cal.toml");

/// Every command that reads an input file, with `{}` where the file goes.
const READERS: [&[&str]; 7] = [
    &["info", "{}"],
    &["export", "--format", "csv", "{}"],
    &["analyze", "{}"],
    &["measure", "--calibration", CAL, "{}"],
    &["measure", "--calibration", "{}", REC],
    &["detect", "{}"],
    &["fit", "{}"],
];

fn with(args: &[&str], file: &str) -> Vec<String> {
    args.iter().map(|a| if *a == "{}" { file.to_string() } else { a.to_string() }).collect()
}

#[test]
fn success_is_0() {
    let o = run(&["info", REC]);
    assert_eq!(o.status.code(), Some(0), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("frames"), "{o:?}");
}

#[test]
fn a_missing_input_is_2_and_named() {
    let dir = tempfile::tempdir().unwrap();
    for ext in ["cmsrec", "png", "csv", "toml"] {
        let missing = dir.path().join(format!("missing.{ext}"));
        let missing = missing.to_str().unwrap();
        for args in READERS {
            let argv = with(args, missing);
            let o = run(&argv.iter().map(String::as_str).collect::<Vec<_>>());
            let e = one_line_error(&o);
            assert!(e.contains("missing."), "{argv:?}: {e}");
        }
    }
}

#[test]
fn a_directory_given_as_an_input_file_is_2() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["d.cmsrec", "d.png", "d.csv", "d.toml"] {
        let d = dir.path().join(name);
        fs::create_dir(&d).unwrap();
        for args in READERS {
            let argv = with(args, d.to_str().unwrap());
            let o = run(&argv.iter().map(String::as_str).collect::<Vec<_>>());
            let e = one_line_error(&o);
            assert!(e.contains(name), "{argv:?}: {e}");
        }
    }
}

/// Permission denied: a file of mode 000. Root reads any file, so as root
/// the command runs as `nobody` (which cannot read it either).
#[test]
fn an_unreadable_input_is_2() {
    let dir = tempfile::tempdir().unwrap();
    fs::set_permissions(dir.path(), fs::Permissions::from_mode(0o755)).unwrap();
    let f = dir.path().join("locked.cmsrec");
    fs::copy(REC, &f).unwrap();
    fs::set_permissions(&f, fs::Permissions::from_mode(0o000)).unwrap();
    let mut cmd = Command::new(bin());
    cmd.args(["info", f.to_str().unwrap()]).env("CMS_SIM_STATE", "/nonexistent/never-used");
    if nix::unistd::geteuid().is_root() {
        cmd.uid(65534).gid(65534);
    }
    let o = cmd.output().unwrap();
    let e = one_line_error(&o);
    assert!(e.contains("locked.cmsrec") && e.contains("ermission denied"), "{e}");
}

#[test]
fn a_device_that_is_not_there_is_3() {
    let o = run(&["listen", "/nonexistent/ttyCMS0", "--duration", "1"]);
    let e = one_line_failure(&o, 3);
    assert!(e.contains("/nonexistent/ttyCMS0"), "{e}");
}

#[test]
fn an_output_that_cannot_be_written_is_1() {
    let full = File::options().write(true).open("/dev/full").unwrap();
    let o = Command::new(bin()).args(["export", "--format", "csv", REC]).stdout(Stdio::from(full)).output().unwrap();
    let e = one_line_failure(&o, 1);
    assert!(e.contains("writing output"), "{e}");
}

/// A bad roughness spectrum for the simulated rail (`simulate
/// --roughness-spectrum`, `listen sim --sim-roughness-spectrum`, `bench
/// rails --spectrum`) is refused before anything runs: exit 2, one line
/// naming the file, the line and what is wrong.
#[test]
fn a_bad_roughness_spectrum_is_2_naming_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("rail.csv");
    fs::write(&bad, "# a ground rail\nwavelength_mm,level_db\n16,-3\n33,-5\n").unwrap();
    let bad = bad.to_str().unwrap();
    for args in [
        vec!["simulate", "--roughness-spectrum", bad],
        vec!["listen", "sim", "--frames", "1", "--sim-roughness-spectrum", bad],
        vec!["bench", "rails", "--spectrum", bad, "--out", dir.path().to_str().unwrap()],
    ] {
        let e = one_line_error(&run(&args));
        assert!(e.contains("rail.csv, line 4: wavelength 33 mm is not a standard third octave"), "{args:?}: {e}");
    }
}
