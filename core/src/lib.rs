//! `cms-core`: the hardware-independent heart of the rail corrugation
//! measurement system (CMS).
//!
//! `no_std`, no allocator, no `unsafe`. The sensor head's firmware and the
//! host tools both build on it, so a stripe found on the microcontroller and
//! one found by `cms-host detect` come from the same integers.
//!
//! * [`fixed`] — the fixed-point types every interface uses (`Px`, Q16.16 pixels).
//! * [`peak`] — laser-stripe detection in one image row: the multi-scale
//!   Ricker CWT detector (default), the paper's Eq. (12)–(13) as written, and
//!   the Table 2 baselines.
//! * [`optics`] — the detector's scale range from the head's geometry (Eq. 10–11).
//! * [`triangulation`] — stripe centre → camera-frame point and profile
//!   coordinates (mm), `f32` per point within 0.1 µm of `f64`.
//! * [`protocol`] — the head ↔ host wire protocol: postcard messages in
//!   CRC-checked, COBS-delimited frames.
//! * [`pipeline`] — the sensor head's logic without its hardware: rows in,
//!   profiles out, commands, and the laser-safety rules.
//! * [`readout`] — which sensor rows a frame reads: a row window and a row
//!   skip (row pitch along the rail traded for frames per second).
//! * [`duty`] — the lasers' enforced maximum duty cycle.
//! * [`odometer`] — wheel-encoder counts → travelled distance, and the
//!   frame-every-N-mm trigger.
//! * [`persist`] — calibration and settings in two CRC-checked flash slots
//!   that survive a power cut during a write.
//! * [`synthetic`] — an integer-only synthetic scene (stripes over a
//!   corrugated rail): the emulated head's camera, bit-identical on any target.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod duty;
pub mod fixed;
pub mod odometer;
pub mod optics;
pub mod peak;
pub mod persist;
pub mod pipeline;
pub mod protocol;
pub mod readout;
pub mod synthetic;
pub mod triangulation;
