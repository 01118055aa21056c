//! The geometry and the solver that calibration, measurement and the
//! simulator share, so that none of them imports another for it.
//!
//! * [`camera`] — the `f64` camera model: pinhole, skew, Brown–Conrady
//!   distortion (OpenCV's), and its one conversion to the head's `f32` model.
//! * [`board`] — the checkerboard target and its pose.
//! * [`head`] — the sensor head's geometry, its lens and sensor.
//! * [`lm`] — Levenberg–Marquardt, the one nonlinear least-squares solver.
//! * [`optics`] — the F-number and wavelength that set a recording's speckle.
//! * [`vec3`] — 3-vectors as `[f64; 3]`: dot, cross, unit, ….

pub mod board;
pub mod camera;
pub mod head;
pub mod lm;
pub mod optics;
pub mod vec3;
