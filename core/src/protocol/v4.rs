//! Protocol version 4's device messages, kept so that recordings made by
//! earlier builds stay readable.
//!
//! What: version 4's encoding of `DeviceMsg`, the same as version 5's but
//! for the `Profile` ([`compact`]: row records of byte-aligned varints), as
//! a serde `remote` definition: a frame of version 4 decodes straight into
//! the one model of a message. Every other message and every command has
//! the same bytes in versions 4 and 5; only the frame's version byte
//! differs.
//!
//! Why: a recording holds frames exactly as they came off the wire, each
//! with its version byte, so a reader that decodes every version reads any
//! recording, even one appended to by builds of several versions.
//!
//! Cost: decoding only (the head never writes version 4; [`encode`] is for
//! tests and test data); its frames are bounded by [`MAX_FRAME`].

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{
    DeviceInfo, DeviceMsg, ErrorCode, LASERS, MAX_ROWS_PER_PROFILE, Profile, RawRows, Status, WireError, compact,
};

/// The version byte of these frames.
pub const VERSION: u8 = 4;

/// Largest version-4 message: a `Profile` ([`compact`]) of 1 440 points,
/// each in a record of its own with the largest skip and every field at its
/// largest — the variant, 39 bytes of header and end, 1 440 × (4 + 16) = 28 840.
pub const MAX_MESSAGE: usize = 1
    + compact::MAX_HEADER_BYTES
    + LASERS * MAX_ROWS_PER_PROFILE * (compact::MAX_RECORD_BYTES + compact::MAX_POINT_BYTES);
/// Largest version-4 frame (version, message, CRC, COBS overhead, delimiter).
pub const MAX_FRAME: usize = super::frame_bound(MAX_MESSAGE);

/// Version 4's encoding of a [`DeviceMsg`]: the variants in the same order,
/// the same bytes but the profile's.
#[allow(clippy::large_enum_variant)]
#[derive(Serialize, Deserialize)]
#[serde(remote = "DeviceMsg")]
enum DeviceMsgV4 {
    Hello(DeviceInfo),
    Profile(#[serde(with = "compact")] Profile),
    Status(Status),
    Ack(u16),
    Error { seq: Option<u16>, code: ErrorCode },
    RawRows(RawRows),
}

/// A [`DeviceMsg`] read from a version-4 frame.
pub(super) struct Read(pub(super) DeviceMsg);

impl<'de> Deserialize<'de> for Read {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Read, D::Error> {
        DeviceMsgV4::deserialize(d).map(Read)
    }
}

/// A [`DeviceMsg`] to write as a version-4 frame.
struct Write<'a>(&'a DeviceMsg);

impl Serialize for Write<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        DeviceMsgV4::serialize(self.0, s)
    }
}

/// Encodes `msg` as a version-4 frame into `out` (for tests and test data:
/// the head speaks version 5). Returns the frame, delimiter included.
pub fn encode<'a>(msg: &DeviceMsg, out: &'a mut [u8]) -> Result<&'a [u8], WireError> {
    super::encode_version(VERSION, &Write(msg), out)
}
