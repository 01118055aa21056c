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
    let out = Command::new("bash")
        .arg(&script)
        .env("CMS_HOST", bin)
        .env("CARGO_TARGET_DIR", target)
        .output()
        .expect("bash runs");
    assert!(
        out.status.success(),
        "{} failed ({}):\n{}\n{}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
