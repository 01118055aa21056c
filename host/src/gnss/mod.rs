//! Positions from a GNSS receiver: NMEA 0183 sentences read from the
//! receiver's own serial port, one [`Fix`] per epoch, and where each fix
//! lies on a track register's centreline.
//!
//! # What is read
//! A receiver sends, once per epoch (1–20 Hz), a `GGA` (time, position,
//! fix quality, satellites, HDOP, altitude) or a `GNS`, usually an `RMC`
//! (date, status, speed and course over ground) and a `VTG` (speed and
//! course), often a `GST` (its own σ) and a `ZDA` (date), in an order of
//! its maker's, and on the same port proprietary sentences and binary
//! frames of its own protocols. [`framing`] cuts the port's bytes into
//! sentences and frames (each frame by its own sync, length and
//! checksum: skipped, counted as other); [`sentence`] checks each
//! sentence's checksum and reads it (a damaged sentence is counted and
//! dropped, never half-used); [`epoch`] gathers one epoch's sentences by
//! their UTC time into a [`Fix`] (see [`Assembler`]). Every talker (`GP`,
//! `GN`, `GL`, `GA`, `GB`, ...) is taken.
//!
//! # Time alignment
//! A fix is placed against the head's frames by **host receive times**:
//! the listener stamps every frame and every fix with the same monotonic
//! clock as they arrive, and records each fix with the head's time
//! (`timestamp_us`) and odometer of the profile received just before it,
//! and the host time between the two ([`Placed`]). The receiver's own UTC
//! is kept beside it. What this does not remove is the receiver's output
//! latency (the sentence leaves the receiver 20–100 ms after its epoch,
//! depending on the model): a fixed lag, which at a trolley's 1 m/s is
//! 20–100 mm along the track, at 50 km/h 0.3–1.4 m. The register check
//! ([`register`]) takes it into its tolerance.

pub mod epoch;
pub mod framing;
pub mod receiver;
pub mod register;
pub mod sentence;
#[cfg(test)]
mod streams;

pub use epoch::Assembler;
pub use receiver::{Receiver, ReceiverError, ReceiverStats};
pub use sentence::SentenceError;

use serde::{Deserialize, Serialize};

/// What kind of solution a fix is (the `GGA` quality field).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Quality {
    /// No position (quality 0).
    Invalid,
    /// Autonomous GNSS (1): metres.
    Autonomous,
    /// Differential / SBAS (2): about a metre.
    Differential,
    /// PPS (3).
    Pps,
    /// RTK with fixed ambiguities (4): centimetres.
    RtkFixed,
    /// RTK float (5): decimetres.
    RtkFloat,
    /// Dead reckoning (6): the receiver's own estimate, no satellites.
    Estimated,
    /// Entered by hand (7).
    Manual,
    /// Simulation mode of the receiver (8).
    Simulation,
}

impl Quality {
    /// From the `GGA` quality digit.
    pub fn from_digit(d: u8) -> Option<Quality> {
        Some(match d {
            0 => Quality::Invalid,
            1 => Quality::Autonomous,
            2 => Quality::Differential,
            3 => Quality::Pps,
            4 => Quality::RtkFixed,
            5 => Quality::RtkFloat,
            6 => Quality::Estimated,
            7 => Quality::Manual,
            8 => Quality::Simulation,
            _ => return None,
        })
    }

    /// The `GGA` quality digit.
    pub fn digit(self) -> u8 {
        match self {
            Quality::Invalid => 0,
            Quality::Autonomous => 1,
            Quality::Differential => 2,
            Quality::Pps => 3,
            Quality::RtkFixed => 4,
            Quality::RtkFloat => 5,
            Quality::Estimated => 6,
            Quality::Manual => 7,
            Quality::Simulation => 8,
        }
    }

    /// Whether the position comes from satellites (not estimated, typed
    /// in or simulated by the receiver itself).
    pub fn is_measured(self) -> bool {
        matches!(
            self,
            Quality::Autonomous | Quality::Differential | Quality::Pps | Quality::RtkFixed | Quality::RtkFloat
        )
    }

    /// A typical horizontal standard uncertainty of this kind of
    /// solution, m (with HDOP 1): what the register check assumes when the
    /// receiver says nothing better.
    pub fn typical_sigma_m(self) -> f64 {
        match self {
            Quality::RtkFixed => 0.02,
            Quality::RtkFloat => 0.3,
            Quality::Differential => 0.7,
            _ => 2.5,
        }
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Invalid => "invalid",
            Quality::Autonomous => "autonomous",
            Quality::Differential => "differential",
            Quality::Pps => "PPS",
            Quality::RtkFixed => "RTK fixed",
            Quality::RtkFloat => "RTK float",
            Quality::Estimated => "estimated",
            Quality::Manual => "manual",
            Quality::Simulation => "simulation",
        }
    }
}

/// One epoch of a receiver: where it was, how well it knew it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fix {
    /// UTC of the epoch, milliseconds since midnight (the `GGA` time).
    pub utc_ms_of_day: Option<u32>,
    /// UTC date of the epoch (year, month, day), from the `RMC`.
    pub date: Option<(u16, u8, u8)>,
    /// Latitude, degrees north (WGS 84).
    pub lat_deg: f64,
    /// Longitude, degrees east (WGS 84).
    pub lon_deg: f64,
    /// Height above mean sea level, m.
    pub altitude_m: Option<f64>,
    /// The solution's kind.
    pub quality: Quality,
    /// Satellites used.
    pub satellites: Option<u8>,
    /// Horizontal dilution of precision.
    pub hdop: Option<f64>,
    /// Speed over ground, mm/s (`RMC` or `VTG`).
    pub speed_mm_s: Option<f64>,
    /// Course over ground, degrees clockwise from true north.
    pub course_deg: Option<f64>,
    /// The receiver's own horizontal standard uncertainty, m: its `GST`'s
    /// error ellipse semi-major σ (the largest in any direction). Recorded
    /// from format 6 on.
    pub receiver_sigma_m: Option<f64>,
}

impl Fix {
    /// The horizontal standard uncertainty assumed for this fix, m: the
    /// receiver's own when it gave one, else the solution's typical
    /// uncertainty scaled by its HDOP (at least 1).
    pub fn sigma_m(&self) -> f64 {
        match self.receiver_sigma_m {
            Some(s) if s.is_finite() && s > 0.0 => s,
            _ => self.quality.typical_sigma_m() * self.hdop.unwrap_or(1.0).max(1.0),
        }
    }
}

/// A fix as recorded: where it falls among the head's frames on the
/// host's clock (see the module docs, "Time alignment").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placed {
    /// Host time of arrival, µs since the listener started.
    pub host_us: u64,
    /// The head's time (`timestamp_us`) of the profile received last
    /// before this fix, plus the host time since that profile arrived:
    /// the fix's time on the head's clock (`None`: no profile yet).
    pub head_us: Option<u64>,
    /// The odometer of that profile, µm.
    pub odometer_um: Option<i64>,
    /// The fix.
    pub fix: Fix,
}
