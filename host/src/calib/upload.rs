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
use std::time::{Duration, Instant};

use cms_core::fixed::Px;
use cms_core::pipeline::triangulator;
use cms_core::protocol::{DeviceInfo, DeviceMsg, ErrorCode, HostMsg, PROTOCOL_VERSION};

use super::file::CalibrationFile;
use crate::Error;
use crate::link::{Deframer, Link};
use crate::simulate::{self, SimPort};

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
    let r = simulate::with_port(&args.port, &args.sim, |port| -> Result<String, Error> {
        let mut s = Session::open(port, args.baud)?;
        let info = s.info()?;
        if info.protocol != PROTOCOL_VERSION {
            return Err(Error::Input(format!(
                "the head on {port} speaks protocol version {}; this cms-host speaks {PROTOCOL_VERSION}",
                info.protocol
            )));
        }
        let (w, h) = (file.camera.intrinsics.width_px, file.camera.intrinsics.height_px);
        if (u32::from(info.sensor_width), u32::from(info.sensor_height)) != (w, h) {
            return Err(Error::Input(format!(
                "{} is for a {w}×{h} camera; the head on {port} has {}×{}",
                args.file.display(),
                info.sensor_width,
                info.sensor_height
            )));
        }
        s.command(HostMsg::SetCalibration(cal), "the calibration")?;
        let mut note = String::new();
        if let Some(sr) = scales {
            let mut det = info.detector;
            det.scales = sr;
            s.command(HostMsg::SetDetector(det), "the detector's scale range")?;
            note = format!(", detector scales {:.2}–{:.2} px", Px::to_f64(sr.min()), Px::to_f64(sr.max()));
        }
        let after = s.info()?;
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

/// A request/answer conversation with a head.
struct Session {
    link: Link,
    frames: Deframer,
    seq: u16,
    buf: Vec<u8>,
}

impl Session {
    fn open(port: &str, baud: u32) -> Result<Session, Error> {
        let link = Link::open(port, baud).map_err(|e| Error::Input(e.to_string()))?;
        Ok(Session { link, frames: Deframer::new(), seq: 0, buf: vec![0; 4096] })
    }

    fn send(&mut self, msg: HostMsg) -> Result<u16, Error> {
        self.seq = self.seq.wrapping_add(1).max(1);
        match self.link.send(self.seq, msg) {
            Ok(true) => Ok(self.seq),
            Ok(false) => Err(Error::Input(format!("{}: the head does not read its commands", self.link.path()))),
            Err(e) => Err(Error::Input(e.to_string())),
        }
    }

    /// Waits for the first message `pick` takes.
    fn wait<T>(&mut self, what: &str, mut pick: impl FnMut(DeviceMsg) -> Option<T>) -> Result<T, Error> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        while Instant::now() < deadline {
            let n = self.link.read(&mut self.buf).map_err(|e| Error::Input(e.to_string()))?;
            let mut got = None;
            self.frames.feed(&self.buf[..n], |r, _| {
                if got.is_none()
                    && let Ok(m) = r
                {
                    got = pick(m);
                }
            });
            if let Some(v) = got {
                return Ok(v);
            }
        }
        Err(Error::Input(format!("{}: no answer to {what} within {} s", self.link.path(), ANSWER_TIMEOUT.as_secs())))
    }

    fn info(&mut self) -> Result<DeviceInfo, Error> {
        self.send(HostMsg::GetInfo)?;
        self.wait("GetInfo", |m| match m {
            DeviceMsg::Hello(i) => Some(i),
            _ => None,
        })
    }

    fn command(&mut self, msg: HostMsg, what: &str) -> Result<(), Error> {
        let seq = self.send(msg)?;
        let r: Result<(), ErrorCode> = self.wait(what, |m| match m {
            DeviceMsg::Ack(s) if s == seq => Some(Ok(())),
            DeviceMsg::Error { seq: Some(s), code } if s == seq => Some(Err(code)),
            _ => None,
        })?;
        r.map_err(|code| Error::Input(format!("{}: the head refused {what}: {code:?}", self.link.path())))
    }
}
