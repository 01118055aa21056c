//! Everything simulated: a physical model of the head over a rail, and what
//! is built on it to check the instrument against a known truth.
//!
//! * [`scene`] — the scene: rail, lasers, camera and sensor noise, rendered
//!   row by row with its truth.
//! * [`gnss`] — a simulated GNSS receiver riding with the simulated head
//!   along a track register's centreline (`listen sim --gnss sim`).
//! * [`pty`] — the pseudo-terminal a simulated device serves on.
//! * [`head`] — the simulated head: `cms_core::pipeline::Head` on a
//!   pseudo-terminal, fed by [`scene`] (`cms-host simulate`, `listen sim`).
//! * [`calibration`] — calibration images of the simulated head and its
//!   true calibration.
//! * [`closed_loop`] — corrugation measured through the simulated head
//!   against its truth (`bench corrugation`).
//! * [`real_light`] — the reference head through speckle, oxidation,
//!   grease, glints and ghost lines, points and corrugation against the
//!   truth (`bench speckle`).
//! * [`floor`] — the noise floor closed loop: the head over a smooth or
//!   corrugated rail under a chosen light, judged as `analyze` judges
//!   (`bench floor`).
//! * [`annex_a`] — EN 13231-3 Annex A: the simulated head over a reference
//!   beam (`bench annex-a`).
//! * [`synthetic`] — a calibrated recording of any length over a known rail,
//!   for benchmarks at survey scale.

pub mod annex_a;
pub mod calibration;
pub mod closed_loop;
pub mod floor;
pub mod gnss;
pub mod head;
pub mod pty;
pub mod real_light;
pub mod repeat;
pub mod scene;
pub mod synthetic;

use std::io;

/// Why a simulated device (the head, its GNSS receiver) could not start
/// or stopped.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    /// A bad option (exit status 2).
    #[error("{0}")]
    Usage(String),
    /// A system call on the pty or the terminal failed (exit status 1).
    #[error("{0}: {1}")]
    Io(&'static str, #[source] io::Error),
}

impl crate::error::Classify for SimulateError {
    fn class(&self) -> crate::Class {
        match self {
            SimulateError::Usage(_) => crate::Class::Input,
            _ => crate::Class::Other,
        }
    }
}
