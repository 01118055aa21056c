//! The benchmarks of `cms-host bench`, as a library: each takes validated
//! options, writes its files and returns its report; the command line only
//! parses arguments and prints.
//!
//! * [`accuracy`] — Monte-Carlo study of every detection method against
//!   the Cramér–Rao bound (docs/reference.md §1), and the paper's own
//!   synthetic protocol (§6.2, Table 3) beside random sub-pixel offsets.
//! * [`speed`] — nanoseconds per row of every method, methods interleaved.
//! * [`render`] — milliseconds of rendering a frame of the simulated head's
//!   scene under a light model.
//! * [`corrugation`] — the closed loop of [`crate::sim::closed_loop`]: the
//!   paper's four corrugation samples through the simulated head.
//! * [`floor`] — the noise floor over a smooth rail against the head's
//!   optics and timing ([`crate::sim::floor`]).
//! * [`rails`] — measured rails' roughness spectra laid on the simulated
//!   rail, measured as `listen sim` does and judged as `analyze` does.
//!
//! `bench qemu` is the emulated head's ([`crate::device::qemu`]); `bench
//! annex-a` and `bench recording` are the simulator's
//! ([`crate::sim::annex_a`], [`crate::sim::synthetic`]).

pub mod accuracy;
pub mod corrugation;
pub mod floor;
pub mod rails;
pub mod render;
pub mod speckle;
pub mod speed;

use std::path::{Path, PathBuf};

use crate::output::OutputError;

/// Why a benchmark could not run or write its files.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BenchError {
    /// Options that do not make a benchmark.
    #[error("{0}")]
    Options(String),
    /// The output folder could not be made.
    #[error("creating {}: {source}", path.display())]
    CreateDir {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// An output file could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A plot could not be drawn.
    #[error("plotting {}: {why}", path.display())]
    Plot {
        /// The plot's file.
        path: PathBuf,
        /// What the plotting library said.
        why: String,
    },
    /// The detector refused a method's configuration, or a row.
    #[error("configuring {method}: {source}")]
    Detector {
        /// The method's name.
        method: &'static str,
        /// The detector's error.
        source: cms_core::peak::Error,
    },
    /// The detector failed on a row.
    #[error("detecting with {method}: {source}")]
    Detect {
        /// The method's name.
        method: &'static str,
        /// The detector's error.
        source: cms_core::peak::Error,
    },
    /// The closed loop failed.
    #[error(transparent)]
    ClosedLoop(#[from] crate::sim::closed_loop::ClosedLoopError),
}

impl crate::error::Classify for BenchError {
    fn class(&self) -> crate::Class {
        match self {
            BenchError::Options(_) => crate::Class::Input,
            BenchError::Output(e) => e.class(),
            BenchError::CreateDir { .. } | BenchError::Plot { .. } => crate::Class::Output,
            BenchError::Detector { .. } | BenchError::Detect { .. } | BenchError::ClosedLoop(_) => crate::Class::Other,
        }
    }
}

/// Worker threads: as asked, or one a core.
pub fn threads(opt: Option<usize>) -> usize {
    opt.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Creates `dir` (and its parents) for a benchmark's files.
fn create_dir(dir: &Path) -> Result<(), BenchError> {
    std::fs::create_dir_all(dir).map_err(|source| BenchError::CreateDir { path: dir.to_path_buf(), source })
}

/// Writes one of a benchmark's files whole ([`crate::output`]).
fn put(path: &Path, text: &str) -> Result<(), BenchError> {
    Ok(crate::output::write_atomically(path, |w| w.write_all(text.as_bytes()))?)
}
