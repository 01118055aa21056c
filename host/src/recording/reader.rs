//! Reading a recording back: every message once, what was damaged, counted.

use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::Path;

use cms_core::protocol::{DeviceMsg, Profile, WireError};

use super::{HEADER_LEN, Header, HostRecord, RecordError, Recorded, parse_header, read_block};
use crate::link::{Counters, Deframer};
use crate::progress::Progress;

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
    /// The header's survey block is damaged (cut short, not UTF-8, or its
    /// checksum does not match): its survey is not to be used.
    pub survey_damaged: bool,
    /// Host records read (GNSS fixes).
    pub host_records: u64,
}

/// One frame of a recording as read.
#[derive(Clone, Copy, Debug)]
pub enum Item<'a> {
    /// A message of the head.
    Device(&'a DeviceMsg),
    /// A record of the host.
    Host(&'a HostRecord),
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
    r: impl Read,
    mut on_msg: impl FnMut(&DeviceMsg) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    scan_records(path, r, |item| match item {
        Item::Device(m) => on_msg(m),
        Item::Host(_) => Ok(()),
    })
}

/// [`scan_reader`] with the host's records too ([`Item::Host`]), in file
/// order among the head's messages.
pub fn scan_records(
    path: &Path,
    mut r: impl Read,
    mut on_item: impl FnMut(Item<'_>) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    let io_err = |source| RecordError::Io { path: path.to_path_buf(), what: "cannot read", source };
    let mut h = Vec::with_capacity(HEADER_LEN);
    (&mut r).take(HEADER_LEN as u64).read_to_end(&mut h).map_err(io_err)?;
    let header =
        parse_header(&h).map_err(|why| RecordError::Format { path: path.to_path_buf(), why: why.to_string() })?;
    // The survey is read by `survey_of`; here the block is passed over, or,
    // damaged, read as frames: a damaged length may have taken frames in.
    let block = read_block(&mut r, &h, &header).map_err(io_err)?;
    let header = block.header;
    let mut stats = ScanStats { header: Some(header), survey_damaged: block.damage.is_some(), ..ScanStats::default() };
    let mut d = Deframer::new();
    let mut buf = vec![0u8; 64 << 10];
    let mut failed: Option<io::Error> = None;
    let mut seen: std::collections::HashSet<u64> = std::collections::HashSet::new();
    // A delimiter where the block says it ends: with the length intact the
    // first frame starts there whole; with a damaged length at most the
    // frame it cuts is lost.
    // A block the file's end cut short has no frames after it: its bytes
    // are a truncated tail.
    let mut cut_short = 0;
    let mut first = match block.damage {
        Some((_, mut bytes)) if bytes.len() as u64 >= header.block_len() => {
            bytes.push(0);
            Some(bytes)
        }
        Some((_, bytes)) => {
            cut_short = bytes.len() as u64;
            None
        }
        None => Some(block.after).filter(|b| !b.is_empty()),
    };
    loop {
        let n = match first.take() {
            Some(bytes) => {
                let n = bytes.len();
                buf[..n].copy_from_slice(&bytes);
                n
            }
            None => match r.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(io_err(e)),
            },
        };
        d.feed_as(&buf[..n], |res: Result<Recorded, WireError>, raw| {
            if failed.is_some() {
                return;
            }
            match res {
                Ok(Recorded::Host(rec)) => {
                    stats.host_records += 1;
                    if let Err(e) = on_item(Item::Host(&rec)) {
                        failed = Some(e);
                    }
                }
                Ok(Recorded::Device(msg)) => {
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
                    if let Err(e) = on_item(Item::Device(&msg)) {
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
    stats.truncated_tail = d.pending() + cut_short;
    Ok(stats)
}

/// [`scan_file`], telling `progress` the bytes read.
pub fn scan_file_with_progress(
    path: &Path,
    progress: &dyn Progress,
    mut on_msg: impl FnMut(&DeviceMsg) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    scan_file_records_with_progress(path, progress, |item| match item {
        Item::Device(m) => on_msg(m),
        Item::Host(_) => Ok(()),
    })
}

/// [`scan_file_with_progress`] with the host's records too.
pub fn scan_file_records_with_progress(
    path: &Path,
    progress: &dyn Progress,
    on_item: impl FnMut(Item<'_>) -> io::Result<()>,
) -> Result<ScanStats, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let total = f.metadata().map(|m| m.len()).unwrap_or(0);
    progress.begin(&format!("reading {}", path.display()), total, "B");
    let counted = Counted { inner: f, done: 0, progress };
    let r = scan_records(path, BufReader::with_capacity(256 << 10, counted), on_item);
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

/// One head session of a recording (from a `Hello` to the next): its
/// GNSS fixes in file order and its profiles' `(timestamp_us,
/// odometer_mm)` sorted by time. A head that restarts starts its clock
/// again, so fixes are only ever placed among their own session's frames.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PositionedSession {
    /// The fixes.
    pub fixes: Vec<crate::gnss::Placed>,
    /// The first part of every profile: its time and odometer.
    pub profiles: Vec<(u64, f64)>,
}

/// The GNSS fixes of a recording with its profiles' times and odometers,
/// per head session (sessions without a fix left out), and what reading
/// found.
pub fn fixes_of(path: &Path) -> Result<(Vec<PositionedSession>, ScanStats), RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let mut sessions = vec![PositionedSession::default()];
    let stats = scan_records(path, BufReader::with_capacity(256 << 10, f), |item| {
        let s = sessions.last_mut().expect("one session at least");
        match item {
            Item::Host(HostRecord::Fix(p)) => s.fixes.push(p.clone()),
            Item::Host(_) => {}
            Item::Device(DeviceMsg::Hello(_)) if !s.profiles.is_empty() || !s.fixes.is_empty() => {
                sessions.push(PositionedSession::default());
            }
            Item::Device(DeviceMsg::Profile(p)) if p.part == 0 => {
                s.profiles.push((p.timestamp_us, p.odometer_um as f64 / 1000.0));
            }
            Item::Device(_) => {}
        }
        Ok(())
    })?;
    sessions.retain(|s| !s.fixes.is_empty());
    for s in &mut sessions {
        s.profiles.sort_by_key(|p| p.0);
    }
    Ok((sessions, stats))
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
    if s.survey_damaged {
        w.push(format!("warning: {name}: the survey block is damaged; its survey is not used"));
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
