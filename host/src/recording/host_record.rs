//! Records the host adds to a recording beside the head's frames: GNSS
//! fixes (`listen --gnss`, format 4 on) and event marks (format 5 on,
//! [`crate::recording::mark`]).
//!
//! A host record is framed exactly as a head's frame — COBS(tag ‖
//! postcard(record) ‖ CRC-32) ‖ 0x00 — with [`HOST_RECORD_TAG`] where a
//! head's frame has its protocol version. So it is under the same
//! checksum, found by the same resynchronisation, and a reader that does
//! not know it (a build before format 4) counts it as a frame of another
//! version and skips it. A build of format 4 would take a mark for a
//! damaged record, which is why marks come with format 5, which such a
//! build refuses to read at all (it names the version), and are never
//! appended to a file of format 4 or older. A fix with the receiver's own
//! σ ([`crate::gnss::Fix::receiver_sigma_m`]) is a record of its own kind
//! (format 6 on); a fix without one is written as format 4 wrote it, and
//! into a file of format 4 or 5 every fix is, without its σ.

use cms_core::protocol::{DeviceMsg, FromFrame, WireError};
use serde::{Deserialize, Serialize};

use crate::gnss::Placed;
use crate::recording::mark::Mark;

/// The first byte of a host record's frame, in place of the protocol
/// version (no protocol version is this high).
pub const HOST_RECORD_TAG: u8 = 0xC7;

/// A record of the host's.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum HostRecord {
    /// A GNSS fix, placed on the host's clock among the head's frames.
    Fix(Placed),
    /// An event mark (format 5 on).
    Mark(Mark),
}

/// A fix as format 4 writes it: [`crate::gnss::Fix`] without the
/// receiver's σ, field for field.
#[derive(Serialize, Deserialize)]
struct Fix4 {
    utc_ms_of_day: Option<u32>,
    date: Option<(u16, u8, u8)>,
    lat_deg: f64,
    lon_deg: f64,
    altitude_m: Option<f64>,
    quality: crate::gnss::Quality,
    satellites: Option<u8>,
    hdop: Option<f64>,
    speed_mm_s: Option<f64>,
    course_deg: Option<f64>,
}

/// [`Placed`] as format 4 writes it.
#[derive(Serialize, Deserialize)]
struct Placed4 {
    host_us: u64,
    head_us: Option<u64>,
    odometer_um: Option<i64>,
    fix: Fix4,
}

/// The records as they are on the wire, in the order of their tags.
#[derive(Serialize, Deserialize)]
enum Wire {
    Fix(Placed4),
    Mark(Mark),
    /// A fix with the receiver's own σ (format 6 on).
    FixWithSigma(Placed),
}

impl From<Placed4> for Placed {
    fn from(p: Placed4) -> Placed {
        let f = p.fix;
        Placed {
            host_us: p.host_us,
            head_us: p.head_us,
            odometer_um: p.odometer_um,
            fix: crate::gnss::Fix {
                utc_ms_of_day: f.utc_ms_of_day,
                date: f.date,
                lat_deg: f.lat_deg,
                lon_deg: f.lon_deg,
                altitude_m: f.altitude_m,
                quality: f.quality,
                satellites: f.satellites,
                hdop: f.hdop,
                speed_mm_s: f.speed_mm_s,
                course_deg: f.course_deg,
                receiver_sigma_m: None,
            },
        }
    }
}

fn placed4(p: &Placed) -> Placed4 {
    let f = &p.fix;
    Placed4 {
        host_us: p.host_us,
        head_us: p.head_us,
        odometer_um: p.odometer_um,
        fix: Fix4 {
            utc_ms_of_day: f.utc_ms_of_day,
            date: f.date,
            lat_deg: f.lat_deg,
            lon_deg: f.lon_deg,
            altitude_m: f.altitude_m,
            quality: f.quality,
            satellites: f.satellites,
            hdop: f.hdop,
            speed_mm_s: f.speed_mm_s,
            course_deg: f.course_deg,
        },
    }
}

impl HostRecord {
    /// The record's frame as this build's format writes it: what goes
    /// into the file, delimiter included.
    pub fn frame(&self) -> Vec<u8> {
        self.frame_in(crate::recording::FORMAT_VERSION)
    }

    /// The record's frame for a file of `format`.
    pub fn frame_in(&self, format: u16) -> Vec<u8> {
        let wire = match self {
            HostRecord::Fix(p)
                if p.fix.receiver_sigma_m.is_some() && format >= crate::recording::RECEIVER_SIGMA_FORMAT =>
            {
                Wire::FixWithSigma(p.clone())
            }
            HostRecord::Fix(p) => Wire::Fix(placed4(p)),
            HostRecord::Mark(m) => Wire::Mark(m.clone()),
        };
        let mut body = vec![HOST_RECORD_TAG];
        // A record of plain numbers and enums always serialises.
        body.extend(postcard::to_allocvec(&wire).expect("a host record serialises"));
        let crc = cms_core::protocol::CRC.checksum(&body);
        body.extend_from_slice(&crc.to_le_bytes());
        let mut frame = cobs::encode_vec(&body);
        frame.push(0);
        frame
    }
}

/// What a frame of a recording holds: a head's message or a host record.
#[allow(clippy::large_enum_variant)] // as DeviceMsg: read one at a time
#[derive(Clone, Debug, PartialEq)]
pub enum Recorded {
    /// A message of the head.
    Device(DeviceMsg),
    /// A record of the host.
    Host(HostRecord),
}

impl FromFrame for Recorded {
    fn from_payload(version: u8, payload: &[u8]) -> Result<Recorded, WireError> {
        if version != HOST_RECORD_TAG {
            return DeviceMsg::from_payload(version, payload).map(Recorded::Device);
        }
        match postcard::take_from_bytes::<Wire>(payload) {
            // A mark's text is checked as when it was made: the checksum
            // vouches for the bytes, not for what a writer put in them.
            Ok((Wire::Mark(m), [])) if !m.is_valid() => Err(WireError::Decode),
            Ok((Wire::Mark(m), [])) => Ok(Recorded::Host(HostRecord::Mark(m))),
            Ok((Wire::Fix(p), [])) => Ok(Recorded::Host(HostRecord::Fix(p.into()))),
            Ok((Wire::FixWithSigma(p), [])) => Ok(Recorded::Host(HostRecord::Fix(p))),
            _ => Err(WireError::Decode),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gnss::{Fix, Quality};
    use cms_core::protocol::decode_frame;

    pub(crate) fn placed() -> Placed {
        Placed {
            host_us: 1_250_000,
            head_us: Some(1_200_000),
            odometer_um: Some(600_000),
            fix: Fix {
                utc_ms_of_day: Some(36_930_200),
                date: Some((2026, 12, 4)),
                lat_deg: 52.0,
                lon_deg: 5.5,
                altitude_m: Some(1.5),
                quality: Quality::RtkFixed,
                satellites: Some(14),
                hdop: Some(0.5),
                speed_mm_s: Some(500.0),
                course_deg: Some(90.0),
                receiver_sigma_m: None,
            },
        }
    }

    /// Byte for byte: the frame of a fix, as format 4 writes it.
    #[test]
    fn a_fix_frame_is_golden() {
        let frame = HostRecord::Fix(placed()).frame();
        let hex: String = frame.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex, GOLDEN);
        let mut body = frame[..frame.len() - 1].to_vec();
        assert_eq!(decode_frame::<Recorded>(&mut body), Ok(Recorded::Host(HostRecord::Fix(placed()))));
        // A head's frame reads as the head's.
        let mut buf = [0u8; 64];
        let msg = DeviceMsg::Ack(7);
        let mut f = cms_core::protocol::encode(&msg, &mut buf).unwrap().to_vec();
        f.pop();
        assert_eq!(decode_frame::<Recorded>(&mut f), Ok(Recorded::Device(msg)));
    }

    /// Byte for byte: a fix with the receiver's σ, as format 6 writes it;
    /// into a file of format 5 it goes as format 4's fix, without its σ.
    #[test]
    fn a_fix_with_the_receivers_sigma_is_golden() {
        let mut p = placed();
        p.fix.receiver_sigma_m = Some(0.0125);
        let frame = HostRecord::Fix(p.clone()).frame();
        let hex: String = frame.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex, SIGMA_GOLDEN);
        let mut body = frame[..frame.len() - 1].to_vec();
        assert_eq!(decode_frame::<Recorded>(&mut body), Ok(Recorded::Host(HostRecord::Fix(p.clone()))));
        assert_eq!(HostRecord::Fix(p).frame_in(5), HostRecord::Fix(placed()).frame());
    }

    /// Every flipped bit of a fix's frame is found by its checksum (or its framing).
    #[test]
    fn a_damaged_fix_is_never_read() {
        let frame = HostRecord::Fix(placed()).frame();
        for i in 0..frame.len() - 1 {
            for bit in 0..8 {
                let mut f = frame[..frame.len() - 1].to_vec();
                f[i] ^= 1 << bit;
                if f.contains(&0) {
                    continue; // the reader splits it at the zero: two damaged frames
                }
                assert!(decode_frame::<Recorded>(&mut f).is_err(), "byte {i} bit {bit}");
            }
        }
    }

    pub(crate) fn mark() -> Mark {
        Mark {
            kind: crate::recording::mark::MarkKind::KilometrePost,
            text: "12.300".into(),
            host_us: 2_000_000,
            seq: 60,
            head_us: 1_980_000,
            odometer_um: -1_234_567,
            after_us: 12_000,
        }
    }

    /// Byte for byte: the frame of a mark, as format 5 writes it.
    #[test]
    fn a_mark_frame_is_golden() {
        let frame = HostRecord::Mark(mark()).frame();
        let hex: String = frame.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex, MARK_GOLDEN);
        let mut body = frame[..frame.len() - 1].to_vec();
        assert_eq!(decode_frame::<Recorded>(&mut body), Ok(Recorded::Host(HostRecord::Mark(mark()))));
        for i in 0..frame.len() - 1 {
            for bit in 0..8 {
                let mut f = frame[..frame.len() - 1].to_vec();
                f[i] ^= 1 << bit;
                if !f.contains(&0) {
                    assert!(decode_frame::<Recorded>(&mut f).is_err(), "byte {i} bit {bit}");
                }
            }
        }
    }

    /// A mark whose text breaks the rules is not read, whatever its checksum.
    #[test]
    fn a_mark_with_bad_text_is_damaged() {
        for text in ["a\u{1b}[2J".to_string(), "x".repeat(crate::recording::mark::MAX_TEXT_CHARS + 1), " pad".into()] {
            let frame = HostRecord::Mark(Mark { text, ..mark() }).frame();
            let mut body = frame[..frame.len() - 1].to_vec();
            assert_eq!(decode_frame::<Recorded>(&mut body), Err(WireError::Decode));
        }
    }

    // COBS of: 0xC7, variant 1 (Mark), kind 2 (KilometrePost), text length 6 and "12.300", host_us
    // 2 000 000, seq 60, head_us 1 980 000, odometer_um -1 234 567 (zigzag), after_us 12 000, then the CRC-32.
    const MARK_GOLDEN: &str = "1cc701020631322e33303080897a3ce0ec788dda9601e05d1dae158800";

    // COBS of: 0xC7, variant 0 (Fix), host_us 1 250 000 (varint d0 a5 4c), head_us Some(1 200 000),
    // odometer_um Some(600 000) (zigzag), utc_ms_of_day Some(36 930 200), date Some(2026, 12, 4), the
    // f64s little-endian, quality 4 (RtkFixed), ..., then the CRC-32.
    // As GOLDEN, variant 2 (FixWithSigma), and after the course Some(0.0125) before the CRC-32.
    const SIGMA_GOLDEN: &str = "18c702d0a54c01809f4901809f49019885ce1101ea0f0c040101010101034a40010101010104164001010101010107f83f04010e01010101010104e03f010101010105407f40010101010111805640019a9999999999893fb9718da400";

    const GOLDEN: &str = "02c716d0a54c01809f4901809f49019885ce1101ea0f0c040101010101034a40010101010104164001010101010107f83f04010e01010101010104e03f010101010105407f40010101010108805640e283525300";
}
