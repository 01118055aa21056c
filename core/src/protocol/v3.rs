//! Protocol version 3's device messages, kept so that recordings made by
//! earlier builds stay readable.
//!
//! What: version 3's encodings of this build's `Profile` (per laser, every
//! point's row, Q16.16 position and width, strength, flags and metric point
//! at full width) and `DeviceMsg`, as serde `remote` definitions: a frame of
//! version 3 decodes straight into the one model of a message. Every other
//! message and every command has the same bytes in versions 3 and 4; only
//! the frame's version byte differs.
//!
//! Why: a recording holds frames exactly as they came off the wire, each
//! with its version byte, so a reader that decodes both versions reads any
//! recording, even one appended to by builds of both versions.
//!
//! Cost: decoding only (the head never writes version 3; [`encode`] is for
//! tests), and a host reader's buffer of [`MAX_FRAME`] (40.6 KB) rather than
//! version 4's.

use heapless::Vec;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{
    Command, DeviceInfo, DeviceMsg, ErrorCode, FromFrame, LASERS, LaserPoints, PROTOCOL_VERSION, Profile, RawRows,
    Status, WireError,
};

/// The version byte of these frames.
pub const VERSION: u8 = 3;

/// Largest version-3 message: a `Profile` with every point at its largest
/// varint and a metric point: 3 lasers × 480 points × 28 bytes + 44 bytes
/// of headers = 40 364.
pub const MAX_MESSAGE: usize = 40_400;
/// Largest version-3 frame (version, message, CRC, COBS overhead, delimiter).
pub const MAX_FRAME: usize = super::frame_bound(MAX_MESSAGE);

/// Version 3's encoding of a [`Profile`]: its fields in order, each laser's
/// points a list, every point with every field (serde's derive, as the
/// type was before version 4).
#[derive(Serialize, Deserialize)]
#[serde(remote = "Profile")]
struct ProfileV3 {
    seq: u32,
    part: u8,
    parts: u8,
    timestamp_us: u64,
    odometer_um: i64,
    exposure_us: u32,
    laser_mask: u8,
    lasers: Vec<LaserPoints, LASERS>,
}

/// Version 3's encoding of a [`DeviceMsg`]: the variants in the same order,
/// the same bytes but the profile's.
#[allow(clippy::large_enum_variant)]
#[derive(Serialize, Deserialize)]
#[serde(remote = "DeviceMsg")]
enum DeviceMsgV3 {
    Hello(DeviceInfo),
    Profile(#[serde(with = "ProfileV3")] Profile),
    Status(Status),
    Ack(u16),
    Error { seq: Option<u16>, code: ErrorCode },
    RawRows(RawRows),
}

/// A [`DeviceMsg`] read from a version-3 frame.
pub(super) struct Read(pub(super) DeviceMsg);

impl<'de> Deserialize<'de> for Read {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Read, D::Error> {
        DeviceMsgV3::deserialize(d).map(Read)
    }
}

/// A [`DeviceMsg`] to write as a version-3 frame.
struct Write<'a>(&'a DeviceMsg);

impl Serialize for Write<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        DeviceMsgV3::serialize(self.0, s)
    }
}

/// A command frame of version 3, 4 or 5 (the same bytes but the version's):
/// what a store written by an earlier build holds (the simulated head keeps
/// its calibration as a `SetCalibration` frame). A head's command reader
/// takes [`Command`], this version's only.
#[derive(Clone, Debug, PartialEq)]
pub struct AnyCommand(pub Command);

impl FromFrame for AnyCommand {
    fn from_payload(version: u8, payload: &[u8]) -> Result<AnyCommand, WireError> {
        match version {
            PROTOCOL_VERSION | super::v4::VERSION | VERSION => super::exactly(payload).map(AnyCommand),
            v => Err(WireError::Version(v)),
        }
    }
}

/// Encodes `msg` as a version-3 frame into `out` (for tests and test data:
/// the head speaks version 5). Returns the frame, delimiter included.
pub fn encode<'a>(msg: &DeviceMsg, out: &'a mut [u8]) -> Result<&'a [u8], WireError> {
    super::encode_version(VERSION, &Write(msg), out)
}

/// Encodes a command as a version-3 frame (an earlier build's stored
/// calibration, for tests).
pub fn encode_command<'a>(cmd: &Command, out: &'a mut [u8]) -> Result<&'a [u8], WireError> {
    super::encode_version(VERSION, cmd, out)
}
