//! Recordings of the sensor link: the file format, its writer, its reader,
//! and `cms-host export` / `cms-host info`.
//!
//! # File format (`.cmsrec`, format version 2; version 1 is read too)
//!
//! ```text
//! offset 0   8 bytes  magic  "CMSREC" 0x00 0x01
//! offset 8   2 bytes  format version, u16 little-endian (2; 1 before survey blocks)
//! offset 10  1 byte   wire protocol version of the writer (cms_core::protocol::PROTOCOL_VERSION)
//! offset 11  1 byte   reserved, written as 0, ignored by readers
//! offset 12  4 bytes  version 2: length L of the survey block, u32 little-endian (0: none);
//!                     version 1: reserved (0)
//! offset 16  L bytes  version 2: the survey (crate::recording::survey_info), UTF-8 TOML, at most 16 KiB
//! 16 + L     frames   every intact device → host frame, exactly its wire bytes:
//!                     COBS(version ‖ postcard(DeviceMsg) ‖ CRC-32) ‖ 0x00
//! ```
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
//! There is no host time stamp: profiles carry the head's exposure time
//! (`timestamp_us`) and odometer, which is what every analysis uses.

pub mod survey_info;

use crate::progress::Progress;
use std::fs::{File, OpenOptions};
use std::io::{self, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cms_core::protocol::{DeviceInfo, DeviceMsg, ErrorCode, LASERS, PROTOCOL_VERSION, Profile, WireError};
use serde::Serialize;
use serde::ser::{SerializeSeq, SerializeStruct, Serializer};

use crate::link::{Counters, Deframer};

/// The file name extension of recordings (without the dot).
pub const EXTENSION: &str = "cmsrec";
/// The first 8 bytes of a recording.
pub const MAGIC: [u8; 8] = *b"CMSREC\0\x01";
/// Length of the header.
pub const HEADER_LEN: usize = 16;
/// The format version this build writes (it reads 1 as well).
pub const FORMAT_VERSION: u16 = 2;
/// The largest survey block, bytes.
pub const MAX_SURVEY_BYTES: usize = crate::recording::survey_info::MAX_BYTES;
/// Longest time a written frame waits for its `fdatasync` while recording.
pub const SYNC_INTERVAL: Duration = Duration::from_secs(1);

/// The header of format version 2 without a survey block.
pub fn header() -> [u8; HEADER_LEN] {
    header_with(0)
}

/// The header of format version 2 announcing a survey block of `survey_len` bytes.
fn header_with(survey_len: u32) -> [u8; HEADER_LEN] {
    let mut h = [0u8; HEADER_LEN];
    h[..8].copy_from_slice(&MAGIC);
    h[8..10].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    h[10] = PROTOCOL_VERSION;
    h[12..16].copy_from_slice(&survey_len.to_le_bytes());
    h
}

/// The header and survey block of a new recording.
pub fn header_and_survey(survey: Option<&str>) -> Vec<u8> {
    let text = survey.unwrap_or("").as_bytes();
    let mut out = header_with(text.len() as u32).to_vec();
    out.extend_from_slice(text);
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

/// Checks a header; the error says what is wrong with it.
pub fn parse_header(h: &[u8]) -> Result<Header, String> {
    if h.len() < HEADER_LEN {
        return Err(format!("not a CMS recording: {} bytes, shorter than the {HEADER_LEN}-byte header", h.len()));
    }
    if h[..8] != MAGIC {
        return Err("not a CMS recording: the file does not start with CMSREC".to_string());
    }
    let format = u16::from_le_bytes([h[8], h[9]]);
    if !(1..=FORMAT_VERSION).contains(&format) {
        return Err(format!("recording format version {format}; this cms-host reads versions 1 to {FORMAT_VERSION}"));
    }
    let survey_len = if format >= 2 { u32::from_le_bytes([h[12], h[13], h[14], h[15]]) } else { 0 };
    if survey_len as usize > MAX_SURVEY_BYTES {
        return Err(format!("a survey block of {survey_len} bytes (at most {MAX_SURVEY_BYTES}): not a CMS recording"));
    }
    Ok(Header { format, protocol: h[10], survey_len })
}

/// Reads the survey block after a header (`None` when there is none).
fn read_survey(r: &mut impl Read, h: &Header) -> io::Result<Option<String>> {
    if h.survey_len == 0 {
        return Ok(None);
    }
    let mut text = Vec::with_capacity(h.survey_len as usize);
    r.take(u64::from(h.survey_len)).read_to_end(&mut text)?;
    if text.len() != h.survey_len as usize {
        return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "the survey block is cut short"));
    }
    String::from_utf8(text)
        .map(Some)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "the survey block is not UTF-8"))
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

// ------------------------------------------------------------------ writer

/// Appends frames to a recording (see the module docs for what reaches the
/// file when).
#[derive(Debug)]
pub struct Recorder {
    /// Unbuffered: each frame is one write.
    out: File,
    path: PathBuf,
    /// When the oldest frame not yet committed was written.
    dirty_since: Option<Instant>,
    frames: u64,
}

impl Recorder {
    /// Creates `path`, or validates its header and appends to it.
    pub fn open(path: &Path) -> Result<Recorder, RecordError> {
        Recorder::open_with_survey(path, None)
    }

    /// [`Recorder::open`], a new file with `survey`'s block; appending to a
    /// file of another survey (or of none, when one is given) is refused.
    pub fn open_with_survey(path: &Path, survey: Option<&str>) -> Result<Recorder, RecordError> {
        let io_err = |what, source| RecordError::Io { path: path.to_path_buf(), what, source };
        let format = |why: String| RecordError::Format { path: path.to_path_buf(), why };
        if survey.is_some_and(|t| t.len() > MAX_SURVEY_BYTES) {
            return Err(format(format!("a survey of more than {MAX_SURVEY_BYTES} bytes")));
        }
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(path)
            .map_err(|e| io_err("cannot open recording", e))?;
        let len = file.metadata().map_err(|e| io_err("cannot read", e))?.len();
        if len == 0 {
            file.write_all(&header_and_survey(survey)).map_err(|e| io_err("cannot write", e))?;
        } else {
            let mut h = Vec::with_capacity(HEADER_LEN);
            (&mut file).take(HEADER_LEN as u64).read_to_end(&mut h).map_err(|e| io_err("cannot read", e))?;
            let header = parse_header(&h).map_err(|why| format(format!("{why}; refusing to append")))?;
            let kept = read_survey(&mut file, &header)
                .map_err(|e| format(format!("survey block: {e}; refusing to append")))?;
            if let Some(t) = survey
                && kept.as_deref() != Some(t)
            {
                return Err(format(match kept {
                    Some(_) => "holds another survey; refusing to append (record this survey to a new file)".into(),
                    None => "holds no survey; refusing to append one (record the survey to a new file)".into(),
                }));
            }
            if len > HEADER_LEN as u64 + u64::from(header.survey_len) {
                let mut last = [0u8];
                file.seek(SeekFrom::End(-1)).map_err(|e| io_err("cannot read", e))?;
                file.read_exact(&mut last).map_err(|e| io_err("cannot read", e))?;
                if last[0] != 0 {
                    // Close the previous writer's unfinished frame.
                    file.write_all(&[0]).map_err(|e| io_err("cannot write", e))?;
                }
            }
        }
        Ok(Recorder { out: file, path: path.to_path_buf(), dirty_since: None, frames: 0 })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames written by this recorder.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    fn err(&self, what: &'static str, source: io::Error) -> RecordError {
        RecordError::Io { path: self.path.clone(), what, source }
    }

    /// Appends one frame's wire bytes (ending with its 0x00 delimiter): in
    /// the file (the operating system's) when this returns.
    pub fn write_frame(&mut self, wire: &[u8]) -> Result<(), RecordError> {
        debug_assert_eq!(wire.last(), Some(&0));
        // One write of the whole frame: a kill between two frames leaves
        // whole frames only (a kill inside leaves a fragment readers skip).
        self.out.write_all(wire).map_err(|e| self.err("cannot write", e))?;
        self.frames += 1;
        self.dirty_since.get_or_insert_with(Instant::now);
        self.tick()
    }

    /// Commits once the oldest uncommitted frame is [`SYNC_INTERVAL`] old.
    /// Call it often (the listener does on every turn of its loop).
    pub fn tick(&mut self) -> Result<(), RecordError> {
        if self.dirty_since.is_some_and(|t| t.elapsed() >= SYNC_INTERVAL) {
            self.sync()?;
        }
        Ok(())
    }

    /// Commits everything written so far.
    pub fn finish(&mut self) -> Result<(), RecordError> {
        self.sync()
    }

    /// Commits to the storage device. A recording into a pipe or a
    /// character device has nothing to commit.
    fn sync(&mut self) -> Result<(), RecordError> {
        self.dirty_since = None;
        match self.out.sync_data() {
            Err(e) if !matches!(e.kind(), io::ErrorKind::InvalidInput | io::ErrorKind::Unsupported) => {
                Err(self.err("cannot commit", e))
            }
            _ => Ok(()),
        }
    }
}

// ------------------------------------------------------------------ reader

/// What reading a recording found besides its messages.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScanStats {
    /// Header.
    pub header: Option<Header>,
    /// Messages decoded.
    pub messages: u64,
    /// Damaged frames in the file (CRC, decoding, over-long).
    pub damaged: u64,
    /// Of those, frames of another protocol version.
    pub other_version: u64,
    /// Bytes of an unfinished frame at the end.
    pub truncated_tail: u64,
    /// Profile messages present twice in one session (the same `seq` and
    /// `part` since the last `Hello`): the second copy is skipped.
    pub duplicates: u64,
    /// Wire bytes of the profile messages read (frames as recorded,
    /// delimiter included; duplicates not counted).
    pub profile_bytes: u64,
    /// The reader's counters.
    pub counters: Counters,
}

/// Reads a recording from `r` (header first) and calls `on_msg` with every
/// intact message, in file order, except a profile message already seen in
/// the same session (the same `seq` and `part` since the last `Hello`: a
/// frame written twice would otherwise be counted, measured and exported
/// twice), which is counted in [`ScanStats::duplicates`]. Stops at the
/// first error of `on_msg`. Never panics, whatever the bytes.
///
/// The duplicate check keeps one 8-byte key per profile message of the
/// session (about 1 MB for 10⁵ frames): a head restarted mid-recording
/// starts its `seq` again, after a `Hello`, so the set is cleared there.
pub fn scan_reader(
    path: &Path,
    mut r: impl Read,
    mut on_msg: impl FnMut(&DeviceMsg) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    let io_err = |source| RecordError::Io { path: path.to_path_buf(), what: "cannot read", source };
    let mut h = Vec::with_capacity(HEADER_LEN);
    (&mut r).take(HEADER_LEN as u64).read_to_end(&mut h).map_err(io_err)?;
    let header = parse_header(&h).map_err(|why| RecordError::Format { path: path.to_path_buf(), why })?;
    // The survey block is read by `survey_of`; here it is passed over.
    read_survey(&mut r, &header)
        .map_err(|e| RecordError::Format { path: path.to_path_buf(), why: format!("survey block: {e}") })?;
    let mut stats = ScanStats { header: Some(header), ..ScanStats::default() };
    let mut d = Deframer::new();
    let mut buf = vec![0u8; 64 << 10];
    let mut failed: Option<io::Error> = None;
    let mut seen: std::collections::HashSet<u64> = std::collections::HashSet::new();
    loop {
        let n = match r.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(io_err(e)),
        };
        d.feed(&buf[..n], |res, raw| {
            if failed.is_some() {
                return;
            }
            match res {
                Ok(msg) => {
                    stats.messages += 1;
                    match &msg {
                        DeviceMsg::Hello(_) => seen.clear(),
                        DeviceMsg::Profile(p) if !seen.insert(u64::from(p.seq) << 8 | u64::from(p.part)) => {
                            stats.duplicates += 1;
                            return;
                        }
                        _ => {}
                    }
                    if matches!(msg, DeviceMsg::Profile(_)) {
                        stats.profile_bytes += raw.len() as u64;
                    }
                    if let Err(e) = on_msg(&msg) {
                        failed = Some(e);
                    }
                }
                Err(WireError::Version(_)) => stats.other_version += 1,
                Err(_) => {}
            }
        });
        if let Some(e) = failed {
            return Err(RecordError::Output(e));
        }
    }
    stats.counters = d.counters();
    stats.damaged = stats.counters.damaged();
    stats.truncated_tail = d.pending();
    Ok(stats)
}

/// [`scan_file`], telling `progress` the bytes read.
pub fn scan_file_with_progress(
    path: &Path,
    progress: &dyn Progress,
    on_msg: impl FnMut(&DeviceMsg) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let total = f.metadata().map(|m| m.len()).unwrap_or(0);
    progress.begin(&format!("reading {}", path.display()), total, "B");
    let counted = Counted { inner: f, done: 0, progress };
    let r = scan_reader(path, BufReader::with_capacity(256 << 10, counted), on_msg);
    progress.end();
    r
}

/// A reader that tells a [`Progress`] how many bytes it has read.
struct Counted<'a, R> {
    inner: R,
    done: u64,
    progress: &'a dyn Progress,
}

impl<R: Read> Read for Counted<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.done += n as u64;
        self.progress.set(self.done);
        Ok(n)
    }
}

/// [`scan_reader`] on a file.
pub fn scan_file(path: &Path, on_msg: impl FnMut(&DeviceMsg) -> io::Result<()>) -> Result<ScanStats, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    scan_reader(path, BufReader::with_capacity(256 << 10, f), on_msg)
}

/// Notes on stderr about what reading skipped, one line each.
pub fn warnings(path: &Path, s: &ScanStats) -> Vec<String> {
    let name = path.display();
    let mut w = Vec::new();
    if s.damaged > 0 {
        let other = if s.other_version > 0 {
            format!(" ({} of another protocol version)", s.other_version)
        } else {
            String::new()
        };
        w.push(format!("warning: {name}: {} damaged frames were skipped{other}", s.damaged));
    }
    if s.truncated_tail > 0 {
        w.push(format!("warning: {name}: {} bytes of a truncated frame at the end were ignored", s.truncated_tail));
    }
    if s.duplicates > 0 {
        w.push(format!(
            "warning: {name}: {} profile messages present twice (same seq and part in one session) were skipped",
            s.duplicates
        ));
    }
    w
}

// ------------------------------------------------------------------ frames

/// Counts complete frames from their profile parts (a frame of a sensor
/// taller than one message arrives as `parts` messages in order).
#[derive(Clone, Copy, Debug, Default)]
pub struct FrameCounter {
    seq: Option<u32>,
    next_part: u8,
}

impl FrameCounter {
    /// Feeds one profile; true when it completes a frame (every part of its
    /// `seq` received, in order).
    pub fn profile(&mut self, p: &Profile) -> bool {
        if self.seq != Some(p.seq) || p.part == 0 {
            self.seq = Some(p.seq);
            self.next_part = 0;
        }
        if p.part != self.next_part {
            // A part was lost: this frame cannot complete.
            self.next_part = u8::MAX;
            return false;
        }
        self.next_part = self.next_part.saturating_add(1);
        p.part.checked_add(1) == Some(p.parts)
    }
}

/// Points of a profile, over its lasers.
pub fn points(p: &Profile) -> u64 {
    p.lasers.iter().map(|l| l.points.len() as u64).sum()
}

/// Micrometres as exact decimal millimetres.
pub fn um_to_mm(um: i64) -> String {
    let sign = if um < 0 { "-" } else { "" };
    let a = um.unsigned_abs();
    format!("{sign}{}.{:03}", a / 1000, a % 1000)
}

// ------------------------------------------------------------------ JSON

struct JsonPoints<'a>(&'a cms_core::protocol::LaserPoints);
struct JsonLasers<'a>(&'a Profile);
/// One profile message as the JSON object of `listen --json` and
/// `export --format jsonl`.
pub struct JsonProfile<'a>(pub &'a Profile);

impl Serialize for JsonProfile<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let p = self.0;
        let mut o = s.serialize_struct("Profile", 9)?;
        o.serialize_field("seq", &p.seq)?;
        o.serialize_field("part", &p.part)?;
        o.serialize_field("parts", &p.parts)?;
        o.serialize_field("timestamp_us", &p.timestamp_us)?;
        o.serialize_field("odometer_mm", &(p.odometer_um as f64 / 1000.0))?;
        o.serialize_field("exposure_us", &p.exposure_us)?;
        o.serialize_field("laser_mask", &p.laser_mask)?;
        o.serialize_field("lasers", &JsonLasers(p))?;
        o.end()
    }
}

impl Serialize for JsonLasers<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.lasers.len()))?;
        for l in &self.0.lasers {
            seq.serialize_element(&JsonLaser(l))?;
        }
        seq.end()
    }
}

struct JsonLaser<'a>(&'a cms_core::protocol::LaserPoints);

impl Serialize for JsonLaser<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut o = s.serialize_struct("Laser", 2)?;
        o.serialize_field("laser", &self.0.laser)?;
        o.serialize_field("points", &JsonPoints(self.0))?;
        o.end()
    }
}

#[derive(Serialize)]
struct JsonPoint {
    row: u16,
    position_px: f64,
    strength: u16,
    width_px: f64,
    flags: u8,
    #[serde(skip_serializing_if = "Option::is_none")]
    along_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    height_um: Option<f64>,
}

impl Serialize for JsonPoints<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.points.len()))?;
        for p in &self.0.points {
            seq.serialize_element(&JsonPoint {
                row: p.row,
                position_px: p.position.to_f64(),
                strength: p.strength,
                width_px: p.width.to_f64(),
                flags: p.flags.0,
                along_mm: p.metric.map(|m| f64::from(m.along_um) / 1e3),
                height_um: p.metric.map(|m| f64::from(m.height_nm) / 1e3),
            })?;
        }
        seq.end()
    }
}

/// Writes one profile as a JSON line (the object, then `\n`).
pub fn write_json_line(out: &mut dyn Write, p: &Profile) -> io::Result<()> {
    serde_json::to_writer(&mut *out, &JsonProfile(p)).map_err(io::Error::from)?;
    out.write_all(b"\n")
}

/// The CSV header of `export --format csv`.
pub const CSV_HEADER: &str =
    "seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um";

/// Writes one profile as CSV lines, one per point. Positions and widths in
/// pixels with 5 decimals (exact for Q16.16: they read back to the same value);
/// `along_mm` and `height_um` exact decimals of the wire's µm and nm, empty
/// for a head without a calibration.
pub fn write_csv(out: &mut dyn Write, p: &Profile) -> io::Result<()> {
    let odo = um_to_mm(p.odometer_um);
    for l in &p.lasers {
        for q in &l.points {
            let (along, height) = match q.metric {
                Some(m) => (um_to_mm(m.along_um.into()), um_to_mm(m.height_nm.into())),
                None => (String::new(), String::new()),
            };
            writeln!(
                out,
                "{},{},{},{odo},{},{},{},{},{},{},{along},{height}",
                p.seq, p.part, p.timestamp_us, l.laser, q.row, q.position, q.strength, q.width, q.flags.0
            )?;
        }
    }
    Ok(())
}

// ------------------------------------------------------------------ export

/// What [`export_to`] writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// One line per point: `seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um`.
    Csv,
    /// One JSON object per profile message, as `listen --json`.
    Jsonl,
}

/// Opens a recording and checks its header (before an export creates its
/// output, say).
pub fn check_header(path: &Path) -> Result<Header, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let mut h = Vec::new();
    f.take(HEADER_LEN as u64).read_to_end(&mut h).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot read",
        source,
    })?;
    parse_header(&h).map_err(|why| RecordError::Format { path: path.to_path_buf(), why })
}

/// The survey block of a recording, as stored (`None`: version 1, or none given).
pub fn survey_of(path: &Path) -> Result<Option<String>, RecordError> {
    let mut f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let header = check_header(path)?;
    f.seek(SeekFrom::Start(HEADER_LEN as u64)).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot read",
        source,
    })?;
    read_survey(&mut f, &header)
        .map_err(|e| RecordError::Format { path: path.to_path_buf(), why: format!("survey block: {e}") })
}

/// Whether two paths name the same existing file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => false,
    }
}

/// Exports the profiles of a recording to `out`; returns what reading found.
pub fn export_to(
    path: &Path,
    format: ExportFormat,
    out: &mut dyn Write,
    progress: &dyn Progress,
) -> Result<ScanStats, RecordError> {
    if format == ExportFormat::Csv {
        writeln!(out, "{CSV_HEADER}").map_err(RecordError::Output)?;
    }
    let stats = scan_file_with_progress(path, progress, |msg| match msg {
        DeviceMsg::Profile(p) => match format {
            ExportFormat::Csv => write_csv(out, p),
            ExportFormat::Jsonl => write_json_line(out, p),
        },
        _ => Ok(()),
    })?;
    out.flush().map_err(RecordError::Output)?;
    Ok(stats)
}

// ------------------------------------------------------------------ info

/// What `cms-host info` reports.
#[derive(Clone, Debug, Default)]
pub struct Info {
    /// What reading found.
    pub scan: ScanStats,
    /// The survey block, as stored.
    pub survey: Option<String>,
    /// Complete frames.
    pub frames: u64,
    /// Profile messages (parts).
    pub profiles: u64,
    /// Points, over all profiles.
    pub points: u64,
    /// Points per laser.
    pub laser_points: [u64; LASERS],
    /// Union of the profiles' laser masks.
    pub lasers: u8,
    /// First and last profile time stamp, µs.
    pub time_us: Option<(u64, u64)>,
    /// Least and greatest odometer, µm.
    pub odometer_um: Option<(i64, i64)>,
    /// First and last sequence number.
    pub seq: Option<(u32, u32)>,
    /// Frames missing from the sequence numbers (gaps).
    pub seq_gaps: u64,
    /// `Hello` messages (one per session or reconnect).
    pub hellos: u64,
    /// The last device information.
    pub device: Option<DeviceInfo>,
    /// `Status` messages, and the last one's dropped-frame count.
    pub statuses: u64,
    /// Frames the head dropped, from its last status.
    pub head_dropped: Option<u32>,
    /// Errors the head reported.
    pub head_errors: Vec<ErrorCode>,
    /// `RawRows` chunks.
    pub raw_chunks: u64,
}

impl Info {
    /// Accumulates one message.
    pub fn add(&mut self, msg: &DeviceMsg, counter: &mut FrameCounter) {
        match msg {
            DeviceMsg::Hello(i) => {
                self.hellos += 1;
                self.device = Some(i.clone());
            }
            DeviceMsg::Profile(p) => {
                self.profiles += 1;
                let n = points(p);
                self.points += n;
                for l in &p.lasers {
                    if let Some(c) = self.laser_points.get_mut(l.laser as usize) {
                        *c += l.points.len() as u64;
                    }
                }
                self.lasers |= p.laser_mask;
                let t = p.timestamp_us;
                self.time_us = Some(self.time_us.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
                let o = p.odometer_um;
                self.odometer_um = Some(self.odometer_um.map_or((o, o), |(a, b)| (a.min(o), b.max(o))));
                if counter.profile(p) {
                    self.frames += 1;
                    if let Some((_, last)) = self.seq
                        && p.seq > last
                    {
                        self.seq_gaps += u64::from(p.seq - last - 1);
                    }
                    self.seq = Some(self.seq.map_or((p.seq, p.seq), |(first, _)| (first, p.seq)));
                }
            }
            DeviceMsg::Status(s) => {
                self.statuses += 1;
                self.head_dropped = Some(s.dropped_frames);
            }
            DeviceMsg::Error { code, .. } => self.head_errors.push(*code),
            DeviceMsg::Ack(_) => {}
            DeviceMsg::RawRows(_) => self.raw_chunks += 1,
        }
    }

    /// Reads a recording.
    pub fn of_file(path: &Path, progress: &dyn Progress) -> Result<Info, RecordError> {
        let mut info = Info::default();
        let mut counter = FrameCounter::default();
        info.scan = scan_file_with_progress(path, progress, |m| {
            info.add(m, &mut counter);
            Ok(())
        })?;
        info.survey = survey_of(path)?;
        Ok(info)
    }

    /// The report, `key: value` lines.
    pub fn report(&self, path: &Path) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(s, "file: {}", path.display());
        if let Some(h) = self.scan.header {
            let _ = writeln!(s, "format: {} (wire protocol {})", h.format, h.protocol);
        }
        if let Some(t) = &self.survey {
            let kv: Vec<&str> = t.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
            let _ = writeln!(s, "survey: {}", kv.join("; "));
        }
        let _ = writeln!(s, "frames: {} ({} profile messages)", self.frames, self.profiles);
        match self.time_us {
            Some((a, b)) => {
                let _ = writeln!(
                    s,
                    "time: {:.6} s to {:.6} s (span {:.6} s)",
                    a as f64 / 1e6,
                    b as f64 / 1e6,
                    (b - a) as f64 / 1e6
                );
            }
            None => s.push_str("time: -\n"),
        }
        match self.odometer_um {
            Some((a, b)) => {
                let span = i64::try_from(b.abs_diff(a)).unwrap_or(i64::MAX);
                let _ = writeln!(s, "distance: {} mm to {} mm (span {} mm)", um_to_mm(a), um_to_mm(b), um_to_mm(span));
            }
            None => s.push_str("distance: -\n"),
        }
        match self.seq {
            Some((a, b)) => {
                let _ = writeln!(s, "seq: {a} to {b}, {} missing", self.seq_gaps);
            }
            None => s.push_str("seq: -\n"),
        }
        let lasers: Vec<String> = (0..LASERS)
            .filter(|&k| self.lasers & (1 << k) != 0)
            .map(|k| format!("{k} ({} points)", self.laser_points[k]))
            .collect();
        let _ = writeln!(s, "lasers: {}", if lasers.is_empty() { "-".to_string() } else { lasers.join(", ") });
        let per = if self.frames > 0 { self.points as f64 / self.frames as f64 } else { 0.0 };
        let _ = writeln!(s, "points: {} ({per:.1} per frame)", self.points);
        if self.points > 0 {
            let b = self.scan.profile_bytes;
            let _ = writeln!(s, "profile bytes: {b} ({:.2} per point, frames included)", b as f64 / self.points as f64);
        }
        match &self.device {
            Some(d) => {
                let _ = writeln!(
                    s,
                    "device: firmware {}, board {}, protocol {}, sensor {}x{} at {} bits, calibration {}",
                    crate::input::one_line(&d.firmware, 16),
                    crate::input::one_line(&d.board, 24),
                    d.protocol,
                    d.sensor_width,
                    d.sensor_height,
                    d.bits,
                    if d.calibration_id == 0 { "none".to_string() } else { format!("{:#010x}", d.calibration_id) }
                );
            }
            None => s.push_str("device: no Hello recorded\n"),
        }
        let _ = writeln!(s, "sessions: {} (Hello messages)", self.hellos);
        if let Some(d) = self.head_dropped {
            let _ = writeln!(s, "head dropped frames: {d} (last status)");
        }
        if !self.head_errors.is_empty() {
            let list: Vec<String> = self.head_errors.iter().map(|c| c.to_string()).collect();
            let _ = writeln!(s, "head errors: {} ({})", self.head_errors.len(), list.join("; "));
        }
        if self.raw_chunks > 0 {
            let _ = writeln!(s, "raw image chunks: {}", self.raw_chunks);
        }
        let _ = writeln!(s, "damaged frames: {}", self.scan.damaged);
        let _ = writeln!(s, "duplicated profile messages (skipped): {}", self.scan.duplicates);
        let _ = writeln!(s, "truncated bytes at the end: {}", self.scan.truncated_tail);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip_and_refusals() {
        let h = header();
        assert_eq!(&h[..8], b"CMSREC\0\x01");
        assert_eq!(parse_header(&h).unwrap(), Header { format: 2, protocol: PROTOCOL_VERSION, survey_len: 0 });
        assert!(parse_header(&h[..10]).unwrap_err().contains("shorter"));
        let mut bad = h;
        bad[0] = b'X';
        assert!(parse_header(&bad).unwrap_err().contains("CMSREC"));
        let mut v3 = h;
        v3[8] = 3;
        assert!(parse_header(&v3).unwrap_err().contains("version 3"));
        // Version 1: the same header, its reserved bytes never a survey length.
        let mut v1 = h;
        v1[8] = 1;
        v1[12] = 0x55;
        assert_eq!(parse_header(&v1).unwrap(), Header { format: 1, protocol: PROTOCOL_VERSION, survey_len: 0 });
        // A survey block: its length after the header, then the text.
        let with = header_and_survey(Some("line = \"A\"\n"));
        assert_eq!(&with[12..16], &11u32.to_le_bytes());
        assert_eq!(&with[16..], b"line = \"A\"\n");
        let mut huge = h;
        huge[12..16].copy_from_slice(&(MAX_SURVEY_BYTES as u32 + 1).to_le_bytes());
        assert!(parse_header(&huge).unwrap_err().contains("survey block"));
    }

    #[test]
    fn millimetres_are_exact() {
        assert_eq!(um_to_mm(0), "0.000");
        assert_eq!(um_to_mm(25_000), "25.000");
        assert_eq!(um_to_mm(-1), "-0.001");
        assert_eq!(um_to_mm(i64::MIN), "-9223372036854775.808");
    }
}
