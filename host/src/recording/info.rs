//! `cms-host info`: what a recording holds.

use std::path::Path;

use cms_core::pipeline::line::Counts;
use cms_core::protocol::{DeviceInfo, DeviceMsg, ErrorCode, LASERS};

use super::mark::Mark;
use super::{FrameCounter, HostRecord, Item, RecordError, ScanStats, points, survey_of, um_to_mm};
use crate::gnss::{Fix, Placed};
use crate::progress::Progress;

/// What `cms-host info` reports.
#[derive(Clone, Debug, Default)]
pub struct Info {
    /// What reading found.
    pub scan: ScanStats,
    /// The survey block, as stored.
    pub survey: Option<String>,
    /// Why the survey block is not to be trusted (damaged).
    pub survey_damage: Option<String>,
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
    /// What the head's line pass flagged, over all profiles.
    pub line: Counts,
    /// The most points one frame had rejected by it.
    pub line_worst_frame: u32,
    /// The rejections of the frame being read.
    line_frame: u32,
    /// The GNSS fixes recorded.
    pub gnss: GnssInfo,
    /// The event marks recorded, in file order.
    pub marks: Vec<Mark>,
}

/// What a recording's GNSS fixes say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GnssInfo {
    /// Fixes recorded.
    pub fixes: u64,
    /// Of those, by the `GGA` quality digit (0 to 8).
    pub by_quality: [u64; 9],
    /// Of those, placed among the head's frames (a profile before them).
    pub placed: u64,
    /// The first fix.
    pub first: Option<Fix>,
    /// The last fix.
    pub last: Option<Fix>,
}

impl GnssInfo {
    /// Accumulates one recorded fix.
    pub fn add(&mut self, p: &Placed) {
        self.fixes += 1;
        self.by_quality[usize::from(p.fix.quality.digit()).min(8)] += 1;
        self.placed += u64::from(p.head_us.is_some());
        self.first.get_or_insert_with(|| p.fix.clone());
        self.last = Some(p.fix.clone());
    }

    /// The `gnss:` line of `info`.
    pub fn line(&self) -> String {
        if self.fixes == 0 {
            return "gnss: no fixes".to_string();
        }
        let kinds: Vec<String> = (0..9u8)
            .filter(|&d| self.by_quality[usize::from(d)] > 0)
            .map(|d| {
                let name = crate::gnss::Quality::from_digit(d).map_or("?", |q| q.name());
                format!("{} {name}", self.by_quality[usize::from(d)])
            })
            .collect();
        let at = |f: &Option<Fix>| f.as_ref().map_or("-".to_string(), |f| format!("{:.7} {:.7}", f.lat_deg, f.lon_deg));
        format!(
            "gnss: {} fixes ({}), {} placed among the frames; first at {}, last at {} (lat lon, degrees)",
            self.fixes,
            kinds.join(", "),
            self.placed,
            at(&self.first),
            at(&self.last)
        )
    }
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
                let line = Counts::of(&p.lasers);
                self.line = self.line.plus(line);
                self.line_frame = if p.part == 0 { line.rejected() } else { self.line_frame + line.rejected() };
                self.line_worst_frame = self.line_worst_frame.max(self.line_frame);
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
        info.scan = super::reader::scan_file_records_with_progress(path, progress, |item| {
            match item {
                Item::Device(m) => info.add(m, &mut counter),
                Item::Host(HostRecord::Fix(p)) => info.gnss.add(p),
                Item::Host(HostRecord::Mark(m)) => info.marks.push(m.clone()),
            }
            Ok(())
        })?;
        // A damaged survey block is reported, not a reason to say nothing
        // of the frames.
        match survey_of(path) {
            Ok(s) => info.survey = s,
            Err(RecordError::Format { why, .. }) => info.survey_damage = Some(why),
            Err(e) => return Err(e),
        }
        Ok(info)
    }

    /// The line pass's line of the report: its counts, per frame, and the
    /// worst frame.
    pub fn line_report(&self) -> String {
        let f = self.frames.max(1) as f64;
        let c = &self.line;
        format!(
            "line pass: {} glint, {} ghost, {} off-line points rejected ({:.2} / {:.2} / {:.2} per frame, at most {} in a frame), {} kept with a second candidate dropped ({:.2} per frame)",
            c.glint,
            c.ghost,
            c.off_line,
            f64::from(c.glint) / f,
            f64::from(c.ghost) / f,
            f64::from(c.off_line) / f,
            self.line_worst_frame,
            c.second_dropped,
            f64::from(c.second_dropped) / f,
        )
    }

    /// The report, `key: value` lines.
    pub fn report(&self, path: &Path) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        // A name or a stored survey may hold anything: shown, not acted on.
        let _ = writeln!(s, "file: {}", crate::output::printable(&path.display().to_string()));
        if let Some(h) = self.scan.header {
            let unprotected = if h.checksummed() { "" } else { "; header and survey without a checksum" };
            let _ = writeln!(s, "format: {} (wire protocol {}{unprotected})", h.format, h.protocol);
        }
        if let Some(why) = &self.survey_damage {
            let _ = writeln!(s, "survey: {why}; not used");
        }
        if let Some(t) = &self.survey {
            let kv: Vec<&str> = t.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
            let _ = writeln!(s, "survey: {}", crate::output::printable(&kv.join("; ")));
            if let Some(o) = super::survey_info::Survey::parse(t).ok().and_then(|sv| sv.optics) {
                let _ = writeln!(s, "optics: {o} (what analyze checks the noise floor against)");
            }
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
        let _ = writeln!(s, "{}", self.line_report());
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
        if self.gnss.fixes > 0 || self.scan.header.is_some_and(|h| h.holds_host_records()) {
            let _ = writeln!(s, "{}", self.gnss.line());
        }
        if !self.marks.is_empty() || self.scan.header.is_some_and(|h| h.holds_marks()) {
            let _ = writeln!(s, "marks: {}", self.marks.len());
            for m in &self.marks {
                let _ = writeln!(s, "mark: {}", super::mark::describe(m));
            }
        }
        let _ = writeln!(s, "damaged frames: {}", self.scan.damaged);
        let _ = writeln!(s, "duplicated profile messages (skipped): {}", self.scan.duplicates);
        let _ = writeln!(s, "truncated bytes at the end: {}", self.scan.truncated_tail);
        s
    }
}
