//! Calibration of the sensor head: camera intrinsics from checkerboard
//! photographs, laser planes from laser lines on the board, the calibration
//! file (its upload to a head is [`crate::device::upload`]).
//!
//! * [`board`] — checkerboard inner-corner detection with sub-pixel refinement.
//! * [`camera`] — Zhang's closed-form initialisation and Levenberg–Marquardt
//!   refinement of intrinsics, distortion and board poses; board pose from
//!   corners with known intrinsics; `cms-host calibrate camera`.
//! * [`lasers`] — laser planes from laser-on/laser-off pairs; `cms-host calibrate lasers`.
//! * [`file`](mod@file) — the TOML calibration file: versioned, units in
//!   the keys, validated on load.
//!
//! The true calibration of a simulated head, and calibration images rendered
//! from it, are the simulator's ([`crate::sim::calibration`]).
//!
//! They share OpenCV's conventions: the camera model and frame of
//! [`crate::model::camera`], the board frame and pose of [`crate::model::board`].

pub mod board;
pub mod camera;
pub mod file;
pub mod lasers;
