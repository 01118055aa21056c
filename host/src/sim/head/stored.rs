//! The simulated head's non-volatile memory: the calibration it keeps across
//! restarts, as the real head keeps it in flash.
//!
//! The file holds one wire frame of `SetCalibration` (protocol version and
//! CRC-32 included; one of protocol 3, an earlier build's, reads too), so a damaged or foreign file is detected, reported and
//! not used; it is written atomically ([`crate::output`]: a temporary file,
//! `fsync`, rename), so a crash during a write leaves the previous
//! calibration.

use std::io;
use std::path::{Path, PathBuf};

use cms_core::protocol::v3::AnyCommand;
use cms_core::protocol::{Calibration, Command, HostMsg, MAX_COMMAND_FRAME, WireError, decode_frame, encode};

/// The calibration file inside a state directory.
pub const FILE_NAME: &str = "calibration.frame";

/// The default state directory: `$CMS_SIM_STATE`, else
/// `$XDG_STATE_HOME/cms-host/sim-head`, else `~/.local/state/cms-host/sim-head`.
pub fn default_dir() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os("CMS_SIM_STATE") {
        return Some(PathBuf::from(d));
    }
    let base = match std::env::var_os("XDG_STATE_HOME") {
        Some(x) if !x.is_empty() => PathBuf::from(x),
        _ => PathBuf::from(std::env::var_os("HOME")?).join(".local/state"),
    };
    Some(base.join("cms-host/sim-head"))
}

/// Why the stored calibration could not be read or kept.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoredError {
    /// The file is not one calibration record (`detail` says how, with
    /// its leading space).
    #[error("{}: not a calibration record{detail}", path.display())]
    NotARecord {
        /// The file.
        path: PathBuf,
        /// How it is not one.
        detail: String,
    },
    /// The record's frame is damaged.
    #[error("{}: damaged calibration record ({source})", path.display())]
    Damaged {
        /// The file.
        path: PathBuf,
        /// The frame's error.
        source: WireError,
    },
    /// The file could not be read.
    #[error(transparent)]
    Read(#[from] crate::input::InputError),
    /// The calibration could not be encoded.
    #[error("encoding the calibration: {0}")]
    Encode(WireError),
    /// The folder could not be made.
    #[error("{}: {source}", path.display())]
    CreateDir {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] crate::output::OutputError),
}

/// The stored calibration, `None` if there is none.
pub fn load(path: &Path) -> Result<Option<Calibration>, StoredError> {
    // One frame at most (and one byte more, to tell a longer file).
    let mut bytes = match crate::input::read_capped(path, MAX_COMMAND_FRAME as u64 + 1) {
        Ok(b) => b,
        Err(crate::input::InputError { kind: crate::input::InputErrorKind::Io(e), .. })
            if e.kind() == io::ErrorKind::NotFound =>
        {
            return Ok(None);
        }
        Err(crate::input::InputError { kind: crate::input::InputErrorKind::TooBig { .. }, .. }) => {
            return Err(StoredError::NotARecord { path: path.to_path_buf(), detail: " (longer than a frame)".into() });
        }
        Err(e) => return Err(e.into()),
    };
    if bytes.len() > MAX_COMMAND_FRAME || bytes.last() != Some(&0) {
        let detail = format!(" ({} bytes)", bytes.len());
        return Err(StoredError::NotARecord { path: path.to_path_buf(), detail });
    }
    let n = bytes.len() - 1;
    // A record of protocol 3 (an earlier build's) reads too: the command's
    // bytes are the same.
    match decode_frame::<AnyCommand>(&mut bytes[..n]) {
        Ok(AnyCommand(Command { msg: HostMsg::SetCalibration(c), .. })) => Ok(Some(c)),
        Ok(_) => Err(StoredError::NotARecord { path: path.to_path_buf(), detail: String::new() }),
        Err(source) => Err(StoredError::Damaged { path: path.to_path_buf(), source }),
    }
}

/// Stores a calibration (atomically: temporary file, then rename).
pub fn save(path: &Path, c: &Calibration) -> Result<(), StoredError> {
    let mut frame = [0u8; MAX_COMMAND_FRAME];
    let bytes =
        encode(&Command { seq: 0, msg: HostMsg::SetCalibration(*c) }, &mut frame).map_err(StoredError::Encode)?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| StoredError::CreateDir { path: dir.to_path_buf(), source })?;
    }
    Ok(crate::output::write_atomically(path, |w| w.write_all(bytes))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal() -> Calibration {
        Calibration {
            id: 42,
            intrinsics: [1400.0, 1400.0, 379.2, 236.8, 0.0],
            distortion: [-0.09, 0.12, 2e-4, -1.5e-4, 0.0],
            planes: [[0.743_144_8, 0.0, -0.669_130_6, -133.8]; 3],
            datum: [0.0, 0.0, -1.0, -200.0],
        }
    }

    #[test]
    fn round_trip_missing_and_damaged() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub").join(FILE_NAME);
        assert_eq!(load(&path).unwrap(), None);
        save(&path, &cal()).unwrap();
        assert_eq!(load(&path).unwrap(), Some(cal()));
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[5] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        let e = load(&path).unwrap_err();
        assert!(e.to_string().contains("damaged"), "{e}");
        std::fs::write(&path, b"hello").unwrap();
        assert!(load(&path).unwrap_err().to_string().contains("not a calibration record"));
    }

    /// A record an earlier build wrote (protocol 3) still loads.
    #[test]
    fn a_protocol_3_record_loads() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE_NAME);
        let mut frame = [0u8; MAX_COMMAND_FRAME];
        let cmd = Command { seq: 0, msg: HostMsg::SetCalibration(cal()) };
        let bytes = cms_core::protocol::v3::encode_command(&cmd, &mut frame).unwrap();
        assert_eq!(bytes[1], 3, "the version byte (after COBS's first code byte)");
        std::fs::write(&path, bytes).unwrap();
        assert_eq!(load(&path).unwrap(), Some(cal()));
    }
}
