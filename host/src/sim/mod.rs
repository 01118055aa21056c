//! Everything simulated: a physical model of the head over a rail, and what
//! is built on it to check the instrument against a known truth.
//!
//! * [`scene`] — the scene: rail, lasers, camera and sensor noise, rendered
//!   row by row with its truth.
//! * [`gnss`] — a simulated GNSS receiver riding with the simulated head
//!   along a track register's centreline (`listen sim --gnss sim`).
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
pub mod real_light;
pub mod scene;
pub mod synthetic;
