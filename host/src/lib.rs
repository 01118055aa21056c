//! `cms-host`: the host side of the rail corrugation measurement system, as
//! a library. It knows no command line: the `cms-host` binary's `cli` layer
//! (clap arguments, printing, progress, exit statuses) sits on top of it and
//! passes plain options in. The folders, from the bottom layer up (a module
//! imports only from its own layer or those below it):
//!
//! **Shared ground**
//! * [`model`] — the camera model, the checkerboard and its pose, the
//!   Levenberg–Marquardt solver.
//! * [`error`] — the library's error and what kind of failure each is.
//! * [`output`] — every output file written atomically, and only as a regular file; folders of files (`analyze --report`) as output sets put in place whole.
//! * [`plot`] — SVG and PNG plots with an embedded font.
//! * [`progress`] — how far a long job has got (the command line draws it).
//!
//! **Data**
//! * [`link`] — the serial link to a head: the port, frame splitting, the client.
//! * [`gnss`] — a GNSS receiver's NMEA fixes, and chainage from a track register.
//! * [`input`] — grayscale images and CSV rows; stripe detection on them.
//! * [`recording`] — the recording format, its reader, export and `info`; survey metadata.
//! * [`calib`] — checkerboard corners, camera and laser-plane calibration, the calibration file.
//!
//! **Measuring and judging**
//! * [`measure`] — per image or recorded frame: each laser's sine fit, the
//!   joint corrugation fit, verdicts, the live estimate.
//! * [`analyze`] — a recording stitched along the track, judged by EN 13231-3 and EN 15610.
//! * [`report`] — the analysis written out: report, plots, CSV and Parquet exports.
//!
//! **Heads**
//! * [`sim`] — everything simulated: the scene, the simulated head, closed
//!   loops against the truth, calibration images, synthetic recordings.
//! * [`device`] — sessions with a head: listen, capture, upload, the emulated head.
//! * [`serve`] — `listen --serve`: the live view in a browser, served beside the recording.
//!
//! **Benchmarks**
//! * [`bench`](mod@bench) — `cms-host bench`: detection accuracy against the Cramér–Rao
//!   bound, speed, corrugation through the simulated head.

pub mod analyze;
pub mod bench;
pub mod calib;
pub mod device;
pub mod error;
pub mod gnss;
pub mod input;
pub mod link;
pub mod measure;
pub mod model;
pub mod output;
pub mod plot;
pub mod progress;
pub mod recording;
pub mod report;
pub mod serve;
pub mod sim;

pub use error::{Class, Error};
