//! Recordings of the sensor link: the file format, its writer, its reader,
//! and `cms-host export` / `cms-host info`.
//!
//! # File format (`.cmsrec`, format version 5; versions 1 to 4 are read too)
//!
//! ```text
//! offset 0   8 bytes  magic  "CMSREC" 0x00 0x01
//! offset 8   2 bytes  format version, u16 little-endian (5; 4 without event marks; 3 without host
//!                     records; 2 without the checksum; 1 before survey blocks)
//! offset 10  1 byte   wire protocol version of the writer (cms_core::protocol::PROTOCOL_VERSION)
//! offset 11  1 byte   reserved, written as 0, ignored by readers
//! offset 12  4 bytes  versions 2 to 5: length L of the survey block, u32 little-endian (0: none);
//!                     version 1: reserved (0)
//! offset 16  L bytes  versions 2 to 5: the survey (crate::recording::survey_info), UTF-8 TOML, at most 16 KiB
//! 16 + L     4 bytes  versions 3 to 5: CRC-32 (ISO-HDLC, as the wire's) of bytes 0 to 16 + L, little-endian
//! then       frames   every intact device → host frame, exactly its wire bytes:
//!                     COBS(version ‖ postcard(DeviceMsg) ‖ CRC-32) ‖ 0x00
//!                     and, from version 4, the host's records among them (GNSS fixes; from
//!                     version 5 event marks too, crate::recording::mark):
//!                     COBS(0xC7 ‖ postcard(HostRecord) ‖ CRC-32) ‖ 0x00 (host_record)
//! ```
//!
//! **Versions.** A reader refuses a format newer than its own, naming it
//! (a build of format 4 says "recording format version 5; this cms-host
//! reads versions 1 to 4"), rather than misread what it does not know: a
//! format-4 reader would count a mark as a damaged frame. Appending to an
//! older file keeps its format, and what that format cannot hold (fixes
//! before 4, marks before 5) is refused, not written.
//!
//! **Damage.** Every byte of a file of version 3 or later is under a checksum: the
//! header and survey block under theirs, each frame under its own. A
//! damaged frame is skipped and counted; a damaged header or survey block
//! (a flipped digit of the start chainage would move the run) is reported
//! as damaged — `info` says so, `analyze` refuses to place the run by it —
//! while the frames after it are still read: the reader resynchronises on
//! the first frame delimiter after the header, wherever a damaged length
//! says the block ends. Versions 1 and 2 carry no such checksum: their
//! header and survey are read as they are, and `info` says they are
//! unprotected. A later format's version byte damaged into 1 or 2 is
//! caught all the same: its block still ends with the header's checksum
//! under its real version, so it is read as that version and its survey
//! reported damaged.
//!
//! The survey block says what the recording is of (line, track, rail,
//! start chainage, operator: `listen --survey FILE.toml`); it is written
//! once, when the file is created, and appending to a recording of
//! another survey is refused.
//!
//! Nothing stands between the frames: the wire framing is already
//! self-delimiting (COBS leaves 0x00 only as the delimiter) and checksummed
//! (CRC-32 over version and payload), so the file is read with the same
//! [`FrameReader`](cms_core::protocol::FrameReader) as the link. Every kind
//! of message the head sent is kept — `Hello` (device information), `Profile`,
//! `Status`, `Ack`, `Error`, `RawRows` — in the order received; frames that
//! arrived damaged are not written.
//!
//! **Why a crash cannot corrupt more than the last frame.** The file is only
//! ever appended to. A crash or power loss while writing leaves at worst an
//! unfinished frame at the end (no delimiter, or bytes that fail the CRC);
//! readers report its size once ("N bytes of a truncated frame at the end
//! were ignored") and everything before it is intact. Zeros that a file system
//! may leave after a power loss are empty frames and are skipped. Damage in
//! the middle of a file (a bad sector) costs the frames it touches: the
//! reader resynchronises on the next 0x00.
//!
//! **Appending.** Opening an existing file validates the header and appends;
//! if the file ends inside a frame (the previous writer crashed), one 0x00 is
//! appended first, so the fragment becomes one damaged frame instead of
//! swallowing the first new one. Sessions and reconnects simply continue the
//! frame sequence (a new session starts with the head's `Hello`).
//!
//! **Durability.** Each frame is handed to the operating system as it
//! arrives (one `write(2)` per frame, no buffer in the process), so killing
//! the listener (`kill -9`, a crash, `Ctrl-\`) loses at most the frame
//! it was receiving: every frame `--json` printed is already in the file,
//! since a frame is written before it is printed. The file is committed to
//! the storage device (`fdatasync`) at most [`SYNC_INTERVAL`] after a frame
//! arrived, and at exit: a power loss costs at most the last second. Cost:
//! one system call per frame (a few µs against the ~1 ms the listener
//! spends on a frame) and one `fdatasync` a second.
//!
//! **Duplicates.** A profile message present twice in one session (the same
//! `seq` and `part` since the last `Hello`: a frame written twice) is read
//! once; readers count and report the copies ([`ScanStats::duplicates`],
//! [`warnings`]), so `info`, `export`, `measure` and `analyze` neither count
//! nor use a frame twice.
//!
//! There is no host time stamp on the head's frames: profiles carry the
//! head's exposure time (`timestamp_us`) and odometer, which is what every
//! analysis uses; host records (GNSS fixes) carry the host's arrival time
//! to place them among the frames ([`crate::gnss`]).

mod export;
pub mod host_record;
mod info;
pub mod mark;
mod reader;
pub mod survey_info;
mod text;
mod writer;

pub use export::{ExportFormat, check_header, export_to, same_file, survey_from, survey_of};
pub use host_record::{HOST_RECORD_TAG, HostRecord, Recorded};
pub use info::{GnssInfo, Info};
pub use reader::{
    FrameCounter, Item, PositionedSession, ScanStats, fixes_of, points, scan_file, scan_file_records_with_progress,
    scan_file_with_progress, scan_reader, scan_records, um_to_mm, warnings,
};
pub use text::{CSV_HEADER, JsonProfile, write_csv, write_json_line};
pub use writer::Recorder;

use std::io::{self, Read};
use std::path::PathBuf;
use std::time::Duration;

use cms_core::protocol::PROTOCOL_VERSION;

/// The file name extension of recordings (without the dot).
pub const EXTENSION: &str = "cmsrec";
/// The first 8 bytes of a recording.
pub const MAGIC: [u8; 8] = *b"CMSREC\0\x01";
/// Length of the header.
pub const HEADER_LEN: usize = 16;

/// Whether `path` is to be read as a recording: named `.cmsrec`, or
/// starting as one does (`CMSREC`), whatever follows. Such a file's errors
/// are a recording's ("not a CMS recording: …"), never another format's.
pub fn taken_for_recording(path: &std::path::Path) -> io::Result<bool> {
    // Opened whatever its name: a missing file is an error, not a recording.
    let mut start = Vec::with_capacity(6);
    std::fs::File::open(path)?.take(6).read_to_end(&mut start)?;
    Ok(path.extension().is_some_and(|e| e.eq_ignore_ascii_case(EXTENSION)) || start == MAGIC[..6])
}
/// The format version this build writes (it reads 1 to 5 as well).
pub const FORMAT_VERSION: u16 = 6;
/// The first format that may hold host records ([`HostRecord`]).
pub const HOST_RECORDS_FORMAT: u16 = 4;
/// The first format that may hold event marks ([`HostRecord::Mark`]).
pub const MARKS_FORMAT: u16 = 5;
/// The first format whose fixes may carry the receiver's own σ
/// ([`HostRecord::frame_in`]).
pub const RECEIVER_SIGMA_FORMAT: u16 = 6;
/// The first format whose header and survey block carry a checksum.
pub const CHECKSUMMED_FORMAT: u16 = 3;
/// Bytes of the header and survey block's checksum.
const BLOCK_CRC_LEN: usize = 4;
/// The largest survey block, bytes.
pub const MAX_SURVEY_BYTES: usize = crate::recording::survey_info::MAX_BYTES;
/// Longest time a written frame waits for its `fdatasync` while recording.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);

/// The start of a new recording without a survey: the header and the
/// checksum of its empty survey block; the frames follow.
pub fn header() -> Vec<u8> {
    header_and_survey(None)
}

/// The header of the current format announcing a survey block of `survey_len` bytes.
fn header_with(survey_len: u32) -> [u8; HEADER_LEN] {
    let mut h = [0u8; HEADER_LEN];
    h[..8].copy_from_slice(&MAGIC);
    h[8..10].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    h[10] = PROTOCOL_VERSION;
    h[12..16].copy_from_slice(&survey_len.to_le_bytes());
    h
}

/// The header, survey block and their checksum of a new recording.
pub fn header_and_survey(survey: Option<&str>) -> Vec<u8> {
    let text = survey.unwrap_or("").as_bytes();
    let mut out = header_with(text.len() as u32).to_vec();
    out.extend_from_slice(text);
    let crc = cms_core::protocol::CRC.checksum(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// What a valid header says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Format version.
    pub format: u16,
    /// Wire protocol version of the writer.
    pub protocol: u8,
    /// Length of the survey block that follows the header, bytes.
    pub survey_len: u32,
}

impl Header {
    /// Bytes between the header and the first frame: the survey block
    /// and, from format 3, its checksum.
    pub fn block_len(&self) -> u64 {
        u64::from(self.survey_len) + if self.checksummed() { BLOCK_CRC_LEN as u64 } else { 0 }
    }

    /// Whether the header and survey block carry a checksum (format 3 on).
    pub fn checksummed(&self) -> bool {
        self.format >= CHECKSUMMED_FORMAT
    }

    /// Whether host records may follow (format 4 on).
    pub fn holds_host_records(&self) -> bool {
        self.format >= HOST_RECORDS_FORMAT
    }

    /// Whether event marks may follow (format 5 on).
    pub fn holds_marks(&self) -> bool {
        self.format >= MARKS_FORMAT
    }
}

/// Why a header is not one this build reads.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HeaderError {
    /// Fewer bytes than a header.
    #[error("not a CMS recording: {0} bytes, shorter than the {HEADER_LEN}-byte header")]
    Short(usize),
    /// Another file's first bytes.
    #[error("not a CMS recording: the file does not start with CMSREC")]
    Magic,
    /// A format version this build does not know.
    #[error("recording format version {0}; this cms-host reads versions 1 to {FORMAT_VERSION}")]
    Version(u16),
    /// A survey block longer than any this format allows.
    #[error("a survey block of {0} bytes (at most {MAX_SURVEY_BYTES}): not a CMS recording")]
    SurveyLength(u32),
}

/// Checks a header; the error says what is wrong with it.
pub fn parse_header(h: &[u8]) -> Result<Header, HeaderError> {
    if h.len() < HEADER_LEN {
        return Err(HeaderError::Short(h.len()));
    }
    if h[..8] != MAGIC {
        return Err(HeaderError::Magic);
    }
    let format = u16::from_le_bytes([h[8], h[9]]);
    if !(1..=FORMAT_VERSION).contains(&format) {
        return Err(HeaderError::Version(format));
    }
    let survey_len = if format >= 2 { u32::from_le_bytes([h[12], h[13], h[14], h[15]]) } else { 0 };
    if survey_len as usize > MAX_SURVEY_BYTES {
        return Err(HeaderError::SurveyLength(survey_len));
    }
    Ok(Header { format, protocol: h[10], survey_len })
}

/// The survey block after a header, as read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Block {
    /// The header as its checksum proves it: the one parsed, or, where a
    /// damaged version byte says format 1 or 2, the checksummed format
    /// the header's checksum was made with.
    pub header: Header,
    /// The survey's text (`None`: none, or the block is damaged).
    pub survey: Option<String>,
    /// Why the block cannot be trusted, with the bytes read for it (the
    /// frames' reader starts on them: a damaged length may have taken
    /// frames into the block).
    pub damage: Option<(String, Vec<u8>)>,
    /// Bytes read past an intact block while looking for a checksum there:
    /// the start of the frames.
    pub after: Vec<u8>,
}

/// Reads the block after the header `raw` (parsed as `h`): the survey
/// text and, from format 3, the checksum over header and text. A block cut
/// short, not UTF-8 or failing its checksum is damage, not an error: only
/// the reading itself fails with an error.
///
/// Formats 1 and 2 carry no checksum, so one flipped bit of a later
/// format's version byte (6 → 2) would otherwise make a checksummed file
/// read as an unprotected one, its checksum taken for frame bytes and its
/// host records for damage. Where the four bytes after such a block are
/// the checksum of the header under a checksummed version, the version
/// byte is what is damaged: the block is reported damaged and read as that
/// version. By chance a real format-2 file does so once in 2³⁰.
pub(crate) fn read_block(r: &mut impl Read, raw: &[u8], h: &Header) -> io::Result<Block> {
    let mut bytes = Vec::with_capacity(h.block_len() as usize);
    r.take(h.block_len()).read_to_end(&mut bytes)?;
    let damaged = |header: Header, why: &str, bytes: Vec<u8>| Block {
        header,
        survey: None,
        damage: Some((why.to_string(), bytes)),
        after: Vec::new(),
    };
    if bytes.len() as u64 != h.block_len() {
        return Ok(damaged(*h, "cut short", bytes));
    }
    let mut after = Vec::new();
    if !h.checksummed() {
        let claimed = u32::from_le_bytes([raw[12], raw[13], raw[14], raw[15]]);
        if claimed as usize <= MAX_SURVEY_BYTES {
            let extra = u64::from(claimed.saturating_sub(h.survey_len)) + BLOCK_CRC_LEN as u64;
            r.take(extra).read_to_end(&mut after)?;
            let mut all = bytes.clone();
            all.extend_from_slice(&after);
            if let Some(format) = checksummed_version_of(raw, claimed, &all) {
                let why = format!(
                    "damaged: its format version reads {}, but its checksum is of format {format}; read as format {format}",
                    h.format
                );
                return Ok(damaged(Header { format, survey_len: claimed, ..*h }, &why, all));
            }
        }
    }
    let text_len = h.survey_len as usize;
    if h.checksummed() {
        let mut digest = cms_core::protocol::CRC.digest();
        digest.update(&raw[..HEADER_LEN]);
        digest.update(&bytes[..text_len]);
        let stored = u32::from_le_bytes(bytes[text_len..].try_into().expect("four checksum bytes"));
        if digest.finalize() != stored {
            return Ok(damaged(*h, "damaged (its checksum does not match)", bytes));
        }
    }
    let survey = match (text_len, std::str::from_utf8(&bytes[..text_len])) {
        (0, _) => None,
        (_, Ok(t)) => Some(t.to_string()),
        (_, Err(_)) => return Ok(damaged(*h, "not UTF-8", bytes)),
    };
    Ok(Block { header: *h, survey, damage: None, after })
}

/// The checksummed format whose header checksum `block` ends with, for the
/// header `raw` announcing `survey_len` bytes of survey, if any.
fn checksummed_version_of(raw: &[u8], survey_len: u32, block: &[u8]) -> Option<u16> {
    let text_len = survey_len as usize;
    let stored = u32::from_le_bytes(block.get(text_len..text_len + BLOCK_CRC_LEN)?.try_into().ok()?);
    (CHECKSUMMED_FORMAT..=FORMAT_VERSION).find(|v| {
        let mut h: [u8; HEADER_LEN] = raw[..HEADER_LEN].try_into().expect("a whole header");
        h[8..10].copy_from_slice(&v.to_le_bytes());
        let mut digest = cms_core::protocol::CRC.digest();
        digest.update(&h);
        digest.update(&block[..text_len]);
        digest.finalize() == stored
    })
}

/// Why a recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Opening, reading or writing the file failed.
    #[error("{what} {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// Why.
        source: io::Error,
    },
    /// The file is not a recording this build can read.
    #[error("{}: {why}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// Writing the export failed.
    #[error("writing output: {0}")]
    Output(#[source] io::Error),
}

impl crate::error::Classify for RecordError {
    fn class(&self) -> crate::Class {
        match self {
            RecordError::Output(_) => crate::Class::Output,
            // A recording that cannot be opened or read is a bad input file.
            RecordError::Io { .. } | RecordError::Format { .. } => crate::Class::Input,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip_and_refusals() {
        let h: [u8; HEADER_LEN] = header()[..HEADER_LEN].try_into().unwrap();
        assert_eq!(&h[..8], b"CMSREC\0\x01");
        assert_eq!(parse_header(&h).unwrap(), Header { format: 6, protocol: PROTOCOL_VERSION, survey_len: 0 });
        assert!(parse_header(&h[..10]).unwrap_err().to_string().contains("shorter"));
        let mut bad = h;
        bad[0] = b'X';
        assert!(parse_header(&bad).unwrap_err().to_string().contains("CMSREC"));
        let mut v7 = h;
        v7[8] = 7;
        assert!(parse_header(&v7).unwrap_err().to_string().contains("version 7; this cms-host reads versions 1 to 6"));
        // Every older format is still read.
        let mut v5 = h;
        v5[8] = 5;
        assert!(parse_header(&v5).unwrap().holds_marks());
        for old in 1..=4u8 {
            let mut v = h;
            v[8] = old;
            assert_eq!(parse_header(&v).unwrap().format, u16::from(old));
            assert!(!parse_header(&v).unwrap().holds_marks());
        }
        // Version 1: the same header, its reserved bytes never a survey length.
        let mut v1 = h;
        v1[8] = 1;
        v1[12] = 0x55;
        assert_eq!(parse_header(&v1).unwrap(), Header { format: 1, protocol: PROTOCOL_VERSION, survey_len: 0 });
        // A survey block: its length after the header, then the text.
        let with = header_and_survey(Some("line = \"A\"\n"));
        assert_eq!(&with[12..16], &11u32.to_le_bytes());
        assert_eq!(&with[16..27], b"line = \"A\"\n");
        // Byte for byte: the checksum of header and text, little-endian.
        assert_eq!(&with[27..], &cms_core::protocol::CRC.checksum(&with[..27]).to_le_bytes());
        assert_eq!(header().len(), HEADER_LEN + 4);
        let mut huge = h;
        huge[12..16].copy_from_slice(&(MAX_SURVEY_BYTES as u32 + 1).to_le_bytes());
        assert!(parse_header(&huge).unwrap_err().to_string().contains("survey block"));
    }

    /// Format 2 (no checksum) is still read, as it is; format 3's block is
    /// checked, and its damage reported with the bytes read for it.
    #[test]
    fn survey_blocks_of_both_formats() {
        let text = "line = \"A\"\n";
        let mut v2 = header_with(text.len() as u32).to_vec();
        v2[8] = 2;
        v2.extend_from_slice(text.as_bytes());
        let h = parse_header(&v2).unwrap();
        assert!(!h.checksummed() && h.block_len() == 11);
        let b = read_block(&mut &v2[HEADER_LEN..], &v2, &h).unwrap();
        assert_eq!((b.survey.as_deref(), b.damage), (Some(text), None));

        let v3 = header_and_survey(Some(text));
        let h = parse_header(&v3).unwrap();
        assert!(h.checksummed() && h.block_len() == 15);
        assert_eq!(read_block(&mut &v3[HEADER_LEN..], &v3, &h).unwrap().survey.as_deref(), Some(text));
        for i in 0..v3.len() {
            let mut bad = v3.clone();
            bad[i] ^= 0x04;
            let Ok(h) = parse_header(&bad) else { continue };
            let b = read_block(&mut &bad[HEADER_LEN..], &bad, &h).unwrap();
            assert!(b.survey.is_none() || h.format < 3, "byte {i}: {b:?}");
        }
    }

    #[test]
    fn millimetres_are_exact() {
        assert_eq!(um_to_mm(0), "0.000");
        assert_eq!(um_to_mm(25_000), "25.000");
        assert_eq!(um_to_mm(-1), "-0.001");
        assert_eq!(um_to_mm(i64::MIN), "-9223372036854775.808");
    }
}
