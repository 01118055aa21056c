//! `cms-host`: the host side of the rail corrugation measurement system, as
//! a library. It knows no command line: the `cms-host` binary's `cli` layer
//! (clap arguments, printing, progress, exit statuses) sits on top of it and
//! passes plain options in. Modules, from the wire up:
//!
//! **Talking to a head**
//! * [`link`] — the serial port (open by path, reconnect) and frame splitting.
//! * [`listen`] — a streaming session: handshake, start, profiles, heartbeat, recording, summary.
//! * [`capture`] — one full frame from a head (what the sensor sees).
//! * [`upload`] — a calibration file sent to a head (`cms-host calibrate upload`).
//! * [`simulate`] — the simulated head: `cms_core::pipeline::Head` on a pseudo-terminal, fed by [`sim`].
//! * [`qemu`] — the emulated head: the firmware's `Head` on QEMU's Cortex-M boards, and its benchmark.
//!
//! **Data**
//! * [`record`] — the recording format, its reader, export and `info`.
//! * [`survey_info`] — what a recording is of: line, track, rail, chainage, operator (`listen --survey`).
//! * [`input`] — grayscale PNG/TIFF images and CSV rows.
//! * [`detect`] — laser-stripe positions of image rows, as CSV.
//! * [`synthetic`] — a calibrated recording of any length over a known rail, for benchmarks at survey scale.
//!
//! **Models**
//! * [`camera`] — the `f64` camera model: pinhole, skew, Brown–Conrady distortion (OpenCV's), and its one conversion to the head's `f32` model.
//! * [`board`] — the checkerboard target and its pose, shared by calibration and the simulator.
//! * [`lm`] — Levenberg–Marquardt, the one nonlinear least-squares solver (fits, calibration).
//! * [`sim`] — the scene: rail, lasers, camera and sensor noise, rendered row by row with its truth.
//! * [`calib`] — checkerboard corners, camera and laser-plane calibration, the calibration file.
//! * [`fit`] — IEEE 1057 and the paper's rotated sine fits of a profile.
//! * [`corrugation`] — the lines of one frame together: head frame, surface normal (paper §2.2), joint fit.
//! * [`measure`] — per image or recorded frame: each laser's profile and fit, the joint result, plots.
//! * [`verdict`] — whether a fitted result is to be believed: good, doubtful or failed, and why.
//! * [`closed_loop`] — corrugation measured through the simulated head against its truth (`bench corrugation`, tests).
//! * [`reference_beam`] — EN 13231-3 Annex A: the simulated head over a reference beam, band RMS differences (`bench annex-a`).
//!
//! **Judging the rail**
//! * [`standards`] — EN 13231-3 wavelength bands, EN 15610 roughness.
//! * [`analyze`] — a recording stitched along the track, judged by the standards; the report.
//! * [`plot`] — SVG and PNG plots with an embedded font.
//! * [`output`] — every output file written atomically, and only as a regular file.
//! * [`progress`] — how far a long job has got (the command line draws it).
//!
//! * [`error`] — the library's error and what kind of failure each is.

pub mod analyze;
pub mod board;
pub mod calib;
pub mod camera;
pub mod capture;
pub mod closed_loop;
pub mod corrugation;
pub mod detect;
pub mod error;
pub mod fit;
pub mod input;
pub mod link;
pub mod listen;
pub mod lm;
pub mod measure;
pub mod output;
pub mod plot;
pub mod progress;
pub mod qemu;
pub mod record;
pub mod reference_beam;
pub mod sim;
pub mod simulate;
pub mod standards;
pub mod survey_info;
pub mod synthetic;
pub mod upload;
pub mod verdict;

pub use error::{Class, Error};
