//! What the behaviour tests share: the `cms-host` binary and how its
//! failures look.

use std::process::{Command, Output};

/// The `cms-host` binary under test.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_cms-host")
}

/// Runs `cms-host` with a state directory that must never be used (a test
/// that wants the simulated head's kept calibration says where).
pub fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).env("CMS_SIM_STATE", "/nonexistent/never-used").output().unwrap()
}

/// Runs `cms-host` as a user would, environment untouched.
pub fn cms_host(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().unwrap()
}

/// Asserts a bad-input failure (exit status 2) with one `error: ` line on
/// stderr (besides the simulated head's `sim:`/`info:` lines), and returns it.
pub fn one_line_error(o: &Output) -> String {
    one_line_failure(o, 2)
}

/// Asserts a failure with exit status `code` and one `error: ` line on
/// stderr (besides the simulated head's `sim:`/`info:` lines), and returns it.
pub fn one_line_failure(o: &Output, code: i32) -> String {
    assert_eq!(o.status.code(), Some(code), "{o:?}");
    let e = String::from_utf8_lossy(&o.stderr).to_string();
    let lines: Vec<&str> = e.lines().filter(|l| !l.starts_with("info:") && !l.starts_with("sim: ")).collect();
    assert_eq!(lines.len(), 1, "{e}");
    assert!(lines[0].starts_with("error: "), "{e}");
    lines[0].to_string()
}
