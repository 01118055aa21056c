//! Calibration images from the simulated head, and the calibration they
//! should give.
//!
//! * [`board`] — a checkerboard seen by the head's camera, lit by a lamp
//!   and, optionally, by the head's lasers.
//! * [`images`] — `cms-host calibrate render`: a set of such images with the
//!   truth beside them.
//! * [`truth`] — the true calibration of a simulated head, as a calibration
//!   file.

pub mod board;
pub mod images;
pub mod truth;
