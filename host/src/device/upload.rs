//! `cms-host calibrate upload CAL.toml PORT`: sends a calibration to a sensor
//! head (PORT `sim`: the simulated head, which keeps it in its state
//! directory as the real head keeps it in flash).
//!
//! The exchange: `GetInfo` → `Hello` (the camera's size must be the file's);
//! `SetCalibration` → `Ack` (the head validates the numbers itself and
//! refuses them with `InvalidConfig`); with a `[head]` section, the detector's
//! scale range from the calibration (paper Eq. 10–11) by `SetDetector`; and a
//! last `GetInfo` to see the head report the new calibration's id.

use std::path::PathBuf;
use std::time::Duration;

use cms_core::fixed::Px;
use cms_core::pipeline::triangulator;
use cms_core::protocol::HostMsg;

use crate::Error;
use crate::calib::file::CalibrationFile;
use crate::link::{Client, ClientError, Handshake, Wait};
use crate::sim::head::{self, SimPort};

/// How long to wait for each answer.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(2);

/// What to upload, and where.
#[derive(Debug, Clone)]
pub struct Options {
    /// The calibration file (from `calibrate lasers`).
    pub file: PathBuf,
    /// Serial port of the head, or `sim`.
    pub port: String,
    /// Baud rate (ignored by USB CDC heads).
    pub baud: u32,
    /// The simulated head's options, for PORT `sim`.
    pub sim: SimPort,
}

/// `calibrate upload`: sends the calibration (and the detector's scale
/// range of its `[head]` section) and checks that the head took it; returns
/// the line to tell the user.
pub fn upload(args: &Options) -> Result<String, Error> {
    let file = CalibrationFile::load(&args.file)?;
    let cal = file.to_head().map_err(|e| Error::Input(format!("{}: {e}", args.file.display())))?;
    // The head would refuse it; say why here, in words.
    let tri = triangulator(&cal)
        .map_err(|e| Error::Input(format!("{}: the head would refuse it: {e}", args.file.display())))?;
    let scales = match file.head {
        Some(h) => Some(
            tri.scale_range(h.laser_diameter_mm, (h.range_min_mm, h.range_max_mm))
                .map_err(|e| Error::Input(format!("{}: [head]: {e}", args.file.display())))?,
        ),
        None => None,
    };
    let r = head::with_port(&args.port, &args.sim, |port| -> Result<String, Error> {
        let mut client = Client::open(port, args.baud).map_err(ClientError::from)?;
        let info = client.handshake(Handshake { tries: 1, wait: Wait::Within(ANSWER_TIMEOUT) })?;
        let (w, h) = (file.camera.intrinsics.width_px, file.camera.intrinsics.height_px);
        if (u32::from(info.sensor_width), u32::from(info.sensor_height)) != (w, h) {
            return Err(Error::Input(format!(
                "{} is for a {w}×{h} camera; the head on {port} has {}×{}",
                args.file.display(),
                info.sensor_width,
                info.sensor_height
            )));
        }
        command(&mut client, HostMsg::SetCalibration(cal), "the calibration")?;
        let mut note = String::new();
        if let Some(sr) = scales {
            let mut det = info.detector;
            det.scales = sr;
            command(&mut client, HostMsg::SetDetector(det), "the detector's scale range")?;
            note = format!(", detector scales {:.2}–{:.2} px", Px::to_f64(sr.min()), Px::to_f64(sr.max()));
        }
        let after = client.info(Wait::Within(ANSWER_TIMEOUT))?;
        if after.calibration_id != cal.id {
            return Err(Error::Input(format!(
                "the head on {port} acknowledged the calibration but reports id {:#010x}, not {:#010x}",
                after.calibration_id, cal.id
            )));
        }
        Ok(format!("calibration {:#010x} loaded by the head on {port}{note}", cal.id))
    })
    .map_err(|e| Error::Input(e.to_string()))??;
    Ok(r)
}

/// `msg`, and its `Ack` within [`ANSWER_TIMEOUT`]; a refusal names the
/// head's code as this command always has (`InvalidConfig`, …).
fn command(client: &mut Client, msg: HostMsg, what: &str) -> Result<(), Error> {
    client.request(msg, what, Wait::Within(ANSWER_TIMEOUT)).map_err(|e| match e {
        ClientError::Refused { port, what, code } => Error::Input(format!("{port}: the head refused {what}: {code:?}")),
        e => e.into(),
    })
}
