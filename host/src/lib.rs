//! `cms-host`: host-side tools of the rail corrugation measurement system.
//!
//! The binary (`src/main.rs`) is a thin `clap` dispatcher; each subcommand
//! lives in its own module here so that it can be tested without spawning a
//! process:
//!
//! * [`analyze`] — `cms-host analyze`: a recording stitched along the track and judged by the rail standards.
//! * [`calib`] — `cms-host calibrate`: camera and laser-plane calibration, the calibration file, upload.
//! * [`capture`] — `cms-host capture`: one full frame from a head as a PNG.
//! * [`closed_loop`] — corrugation measured through the simulated head against its truth (the paper's Table 5 cases).
//! * [`corrugation`] — the lines of one image together: head frame, surface normal (paper §2.2), joint sine fit.
//! * [`error`] — the library's error and what kind of failure each is (the exit status is the command line's).
//! * [`detect`] — `cms-host detect`: laser-stripe positions of image rows as CSV.
//! * [`fit`] — `cms-host fit`: IEEE 1057 and the paper's rotated sine fits of a profile.
//! * [`input`] — reading grayscale PNG/TIFF images and CSV rows.
//! * [`plot`] — SVG and PNG plots with an embedded font.
//! * [`listen`] — `cms-host listen`: handshake, stream, record and show a sensor head's profiles.
//! * [`qemu`] — the emulated head on QEMU: `cms-host listen qemu`, `cms-host bench qemu`.
//! * [`link`] — the serial port (open by path, reconnect) and frame splitting.
//! * [`measure`] — `cms-host measure`: per image or recorded frame, each laser's profile and fit, the joint result, plots.
//! * [`record`] — the recording format, `cms-host export` and `cms-host info`.
//! * [`standards`] — rail-standard analysis of a longitudinal profile: EN 13231-3 bands, EN 15610 roughness.

pub mod analyze;
pub mod calib;
pub mod capture;
pub mod closed_loop;
pub mod corrugation;
pub mod detect;
pub mod error;
pub mod fit;
pub mod input;
pub mod link;
pub mod listen;
pub mod measure;
pub mod plot;
pub mod qemu;
pub mod record;
pub mod sim;
pub mod simulate;
pub mod standards;

pub use error::{Class, Error};
