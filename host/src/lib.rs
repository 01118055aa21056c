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

use std::fmt;
use std::io::Write as _;
use std::process::ExitCode;

/// Why a subcommand failed, and so how the process exits.
#[derive(Debug)]
pub enum CliError {
    /// A bad option value or a bad input file: exit status 2.
    Usage(String),
    /// Writing the output failed: exit status 1 (a closed pipe exits quietly
    /// with status 0, see [`CliError::report`]).
    Output(std::io::Error),
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CliError::Usage(m) => f.write_str(m),
            CliError::Output(e) => write!(f, "writing output: {e}"),
        }
    }
}

impl From<input::InputError> for CliError {
    fn from(e: input::InputError) -> Self {
        CliError::Usage(e.to_string())
    }
}

impl From<link::ClientError> for CliError {
    fn from(e: link::ClientError) -> Self {
        CliError::Usage(e.to_string())
    }
}

impl From<std::io::Error> for CliError {
    fn from(e: std::io::Error) -> Self {
        CliError::Output(e)
    }
}

impl CliError {
    /// Prints the error as one `error: ` line on stderr (nothing for a closed
    /// output pipe) and returns the exit status.
    pub fn report(&self) -> ExitCode {
        if let CliError::Output(e) = self
            && e.kind() == std::io::ErrorKind::BrokenPipe
        {
            return ExitCode::SUCCESS;
        }
        let msg = input::one_line(&self.to_string(), 2000);
        // Not eprintln!: it panics if stderr is closed.
        let _ = writeln!(std::io::stderr(), "error: {msg}");
        match self {
            CliError::Usage(_) => ExitCode::from(2),
            CliError::Output(_) => ExitCode::from(1),
        }
    }
}
