//! The Python package (`python/`, `cms`) and its fleet job, through their
//! own test script: a pinned virtual environment, the package built into it
//! from the workspace, a fleet of 100 synthetic recordings analysed on a
//! Dask scheduler and workers started from the command line (and on a
//! LocalCluster), a fleet read from and written to a bucket of an
//! S3-compatible server started here, every recording's figures in the
//! dataset against this binary's `analyze --json`, the DuckDB queries. The
//! script fails (never skips) when Python, a package or the build is
//! missing.

use std::path::Path;
use std::process::Command;

use crate::common::bin;

#[test]
fn the_python_package_and_the_fleet_job_give_the_figures_of_analyze() {
    let bin = Path::new(bin());
    // `…/target/release/cms-host`: the wheel's build shares that target
    // folder's compiled crates (and keeps its venv there).
    let target = bin.parent().and_then(Path::parent).expect("the binary is in a target folder");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../python/tests/run.sh");
    let mut cmd = Command::new("bash");
    // Cargo's variables for this test (CARGO_MANIFEST_DIR, CARGO_PKG_…)
    // would reach the wheel's cargo build, and a build script that reruns
    // when one changes (ring's, on CARGO_MANIFEST_DIR) would make that
    // build compile ring, rustls and cms-host again instead of reusing
    // the test build's.
    for (k, _) in std::env::vars_os() {
        if k.to_str().is_some_and(|k| k.starts_with("CARGO_") && k != "CARGO_HOME") {
            cmd.env_remove(k);
        }
    }
    let out = cmd.arg(&script).env("CMS_HOST", bin).env("CARGO_TARGET_DIR", target).output().expect("bash runs");
    assert!(
        out.status.success(),
        "{} failed ({}):\n{}\n{}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
