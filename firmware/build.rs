//! Link setup for the sensor-head firmware.
//!
//! * `memory.x` lives at the repository root (one memory map for the head).
//!   It is copied into `OUT_DIR`, which goes on the linker's search path, so
//!   cortex-m-rt's `link.x` (`INCLUDE memory.x`) finds it whatever the
//!   working directory of the build.
//! * The linker scripts are passed here with `rustc-link-arg-bins`, never
//!   through a `rustflags` entry: a root `rustflags = ["-Tdefmt.x"]` would
//!   break every binary that does not link defmt (docs/reference.md §5).
//! * `DEFMT_LOG` defaults to `info` for this crate when the caller does not
//!   set it, so `cd firmware && cargo build` and `cargo fw` (root alias)
//!   produce the same logs.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR is set by cargo"));
    let memory = manifest.join("..").join("memory.x");
    if let Err(e) = fs::copy(&memory, out.join("memory.x")) {
        panic!("cannot copy {} to OUT_DIR: {e}", memory.display());
    }
    println!("cargo::rustc-link-search={}", out.display());
    println!("cargo::rerun-if-changed={}", memory.display());
    println!("cargo::rerun-if-changed=build.rs");

    println!("cargo::rustc-link-arg-bins=--nmagic");
    println!("cargo::rustc-link-arg-bins=-Tlink.x");
    println!("cargo::rustc-link-arg-bins=-Tdefmt.x");

    println!("cargo::rerun-if-env-changed=DEFMT_LOG");
    if env::var_os("DEFMT_LOG").is_none() {
        println!("cargo::rustc-env=DEFMT_LOG=info");
    }
}
