//! Sessions with a sensor head over its link ([`crate::link`]): the real
//! one on a serial port, the simulated one ([`crate::sim::head`]) or the
//! emulated one ([`qemu`]).
//!
//! * [`listen`] — a streaming session: handshake, start, profiles,
//!   heartbeat, recording, summary.
//! * [`capture`] — one full frame from a head (what the sensor sees).
//! * [`upload`] — a calibration file sent to a head.
//! * [`qemu`] — the emulated head: the firmware's `Head` on QEMU's Cortex-M
//!   boards, and its instructions-per-row benchmark.

pub mod capture;
pub mod listen;
pub mod qemu;
pub mod upload;
