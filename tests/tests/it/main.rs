//! Behaviour tests of `cms-core` on the host, one test binary (linking one
//! binary, not one per file, is what keeps `cargo test` fast): accuracy
//! against the Cramér–Rao bound, the f64 reference, robustness, properties,
//! protocol goldens, the pipeline's safety rules, persistence, and the
//! emulated head end to end.

mod accuracy;
mod front_end;
mod odometer;
mod persist;
mod pipeline;
mod properties;
mod protocol;
mod qemu;
mod robustness;
mod triangulation;
