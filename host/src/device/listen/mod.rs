//! `cms-host listen PORT`: talk to the sensor head over its serial link,
//! stream profiles, show the link's health, record and print what arrives.
//!
//! # The conversation
//! The port, the sequence numbers, the handshake's state machine and the
//! heartbeats are [`link::Client`](crate::link::Client)'s, the same client
//! `capture` and `calibrate upload` use; this module drives it in its own
//! loop (see the client's docs for why) and adds the recording, the
//! reconnects and the display.
//!
//! 1. **Handshake**: `GetInfo`, and wait for `Hello` (2 s, three tries); the
//!    head's protocol version must be this build's. Then `SetExposure` (if
//!    asked for) and `Start`, acknowledged by `Ack`.
//! 2. **Streaming**: every 250 ms a `Heartbeat` (the head turns its lasers off
//!    after 1 s without one). Every intact frame is recorded and, with
//!    `--json`, printed; damaged frames are counted by the
//!    [`FrameReader`](cms_core::protocol::FrameReader) and skipped (the
//!    reader resynchronises on the next 0x00).
//! 3. **Stop** (Ctrl-C, `--frames`, `--duration`, or a closed stdout): `Stop`
//!    (lasers off), wait up to 500 ms for its `Ack`, commit the recording,
//!    print a summary on stderr. A session that fails after greeting the head
//!    (the port lost for good) still has its summary: [`session`] returns
//!    both ([`Outcome`]), and the command line prints it before the error.
//!
//! Every intact frame is written to the recording before `--json` prints
//! it, one write per frame ([`Recorder`]): a killed listener's file holds
//! every frame it printed.
//!
//! Event marks (the terminal's, the live page's) reach the session through
//! a bounded queue it empties each turn without waiting, and are recorded
//! at the odometer of the latest profile ([`marks`]).
//!
//! # When the link misbehaves
//! * The head goes silent for 2 s while streaming: handshake again
//!   (`GetInfo` … `Start`), counted as a *stall*.
//! * The head reports that it stopped by itself (a `Status` that is not
//!   streaming: heartbeat lost, a damaged command, a camera fault): `Start`
//!   again, counted as a *head restart*.
//! * The port fails (unplugged: the path vanishes, a read fails or hits end
//!   of file): close it, try to open the same path every 200 ms for up to
//!   `--reconnect-timeout`, handshake again; the recording goes on in the same
//!   file. Counted as a *reconnect*.
//!
//! Nothing that arrives on the link can make the listener panic: every
//! frame is bounds-checked by the framing and decoded by postcard into
//! fixed-capacity types.

pub mod marks;
mod session;

use std::fmt;
use std::io::{self, Write};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use cms_core::peak::ColumnWindow;
use cms_core::pipeline::line::Counts;
use cms_core::protocol::{DeviceInfo, DeviceMsg, ErrorCode, LASERS, LaserPattern, PROTOCOL_VERSION, Start, Status};
use cms_core::readout::{Readout, ReadoutError};

use crate::link::{Client, ClientError, Counters, Handshake, LinkError, Wait};
use crate::recording::{RecordError, Recorder};
use session::Session;

pub use marks::{MARK_QUEUE, MarkInbox, MarkRefused, MarkReply, MarkRequest, MarkSender, mark_channel};

/// How long to wait for `Hello` after each `GetInfo`.
pub const HELLO_TIMEOUT: Duration = Duration::from_secs(2);
/// `GetInfo` requests before giving up.
pub const HELLO_TRIES: u32 = 3;
/// The handshake: [`HELLO_TRIES`] `GetInfo` requests [`HELLO_TIMEOUT`] apart.
pub const HANDSHAKE: Handshake = Handshake { tries: HELLO_TRIES, wait: Wait::Within(HELLO_TIMEOUT) };
/// How long to wait for the `Ack` of `Start`.
pub const START_TIMEOUT: Duration = Duration::from_secs(2);
/// Interval of heartbeats (the head's timeout is 1 s).
pub const HEARTBEAT_INTERVAL: Duration = Duration::from_millis(250);
/// Silence while streaming after which the head is asked again.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(2);
/// Interval of attempts to reopen a lost port.
pub const REOPEN_INTERVAL: Duration = Duration::from_millis(200);
/// How long to wait for the `Ack` of `Stop` (and the `Status` after it)
/// when finishing.
pub const STOP_ACK_TIMEOUT: Duration = Duration::from_millis(500);

/// What to do.
#[derive(Clone, Debug)]
pub struct ListenOptions {
    /// Stop after this many complete frames.
    pub frames: Option<u64>,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Record into (append to) this file.
    pub record: Option<PathBuf>,
    /// The survey a new recording's header carries (validated TOML,
    /// [`crate::recording::survey_info`]); appending to one of another survey is refused.
    pub survey: Option<String>,
    /// One JSON object per profile message on the output.
    pub json: bool,
    /// Baud rate (a USB CDC head ignores it).
    pub baud: u32,
    /// Streaming parameters sent with `Start`.
    pub start: Start,
    /// Exposure to set before starting, µs.
    pub exposure_us: Option<u32>,
    /// Search windows per laser to set (`SetWindows`) before starting;
    /// `None` sets none (the head keeps what it has; full rows after a
    /// restart).
    pub windows: Option<[Option<ColumnWindow>; LASERS]>,
    /// The sensor rows to read (`SetReadout` before starting: first row,
    /// rows, skip); `None` sets none (the head keeps what it has; every
    /// row after a restart).
    pub readout: Option<RowsRequest>,
    /// Windows that follow their lines (`SetTracking` before starting):
    /// how far from the last row's stripe a row looks, px; `None` sets
    /// nothing (the head keeps what it has; off after a restart).
    pub track_px: Option<u16>,
    /// How long a lost port may stay away.
    pub reconnect_timeout: Duration,
    /// A GNSS receiver to read beside the head: its fixes go into the
    /// recording among the frames ([`crate::gnss`]).
    pub gnss: Option<GnssPort>,
    /// What the status line's EN 13231-3 band figures evaluate (the
    /// edition's limits).
    pub live_bands: crate::analyze::live::bands::LiveOptions,
}

/// A GNSS receiver's serial port.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GnssPort {
    /// Its device path.
    pub path: String,
    /// Its baud rate.
    pub baud: u32,
}

impl Default for ListenOptions {
    fn default() -> Self {
        ListenOptions {
            frames: None,
            duration: None,
            record: None,
            survey: None,
            json: false,
            baud: 115_200,
            start: Start { rate_hz: 30, laser_mask: 0b111, pattern: LaserPattern::Simultaneous },
            exposure_us: None,
            windows: None,
            readout: None,
            track_px: None,
            reconnect_timeout: Duration::from_secs(30),
            gnss: None,
            live_bands: crate::analyze::live::bands::LiveOptions::default(),
        }
    }
}

/// The readout `listen` asks the head for (`HostMsg::SetReadout`): sensor
/// rows `first_row .. first_row + rows`, one in `skip`. Checked against
/// the sensor's height in the head's `Hello` before it is sent (and by the
/// head again).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RowsRequest {
    /// First sensor row.
    pub first_row: u16,
    /// Sensor rows of the window; `None`: up to the sensor's last row.
    pub rows: Option<u16>,
    /// Read one row in `skip` (1, 2 or 4).
    pub skip: u8,
}

impl RowsRequest {
    /// The readout on a sensor `sensor_rows` high.
    pub fn on(&self, sensor_rows: u16) -> Result<Readout, ReadoutError> {
        let rows = self.rows.unwrap_or(sensor_rows.saturating_sub(self.first_row));
        Readout::from_factor(self.first_row, rows, self.skip, sensor_rows)
    }
}

/// Why listening failed.
#[derive(Debug, thiserror::Error)]
pub enum ListenError {
    /// The port could not be opened at all.
    #[error(transparent)]
    Open(LinkError),
    /// The head never answered `GetInfo`.
    #[error(
        "no answer from {port}: no Hello after {HELLO_TRIES} GetInfo requests {} s apart (is it a CMS sensor head, and is the baud rate right?)",
        HELLO_TIMEOUT.as_secs()
    )]
    NoHello {
        /// The port.
        port: String,
    },
    /// The head speaks another protocol version.
    #[error("the head on {port} speaks protocol version {theirs}; this cms-host speaks version {PROTOCOL_VERSION}")]
    Version {
        /// The port.
        port: String,
        /// The head's version.
        theirs: u8,
    },
    /// The row readout asked for does not fit the head's sensor.
    #[error("--rows/--row-skip on the head of {port}: {why}")]
    Readout {
        /// The port.
        port: String,
        /// Why.
        why: ReadoutError,
    },
    /// The head refused a command of the handshake.
    #[error("the head refused {command}: {code}{}", refused_hint(command, *code))]
    Refused {
        /// The command.
        command: &'static str,
        /// Why.
        code: ErrorCode,
    },
    /// The port went away (or the head stopped answering) and did not come
    /// back in time.
    #[error("lost {port} and it did not come back within {} s ({why})", after.as_secs_f64())]
    Lost {
        /// The port.
        port: String,
        /// How long it was given.
        after: Duration,
        /// The last thing that went wrong.
        why: String,
    },
    /// The recording failed.
    #[error("recording: {0}")]
    Record(#[source] RecordError),
    /// The GNSS receiver's port could not be read.
    #[error(transparent)]
    Gnss(crate::gnss::ReceiverError),
    /// A recording that cannot hold the GNSS fixes asked for.
    #[error("--gnss with --record {}: recording format {format} holds no GNSS fixes (format {}); record to a new file", path.display(), crate::recording::HOST_RECORDS_FORMAT)]
    NoFixesInFormat {
        /// The recording.
        path: PathBuf,
        /// Its format.
        format: u16,
    },
    /// Writing the JSON output failed (not a closed pipe, which just stops).
    #[error("writing output: {0}")]
    Output(#[source] io::Error),
}

/// The first two lasers whose search windows share columns, if any.
/// Tracking follows one line per window and takes a stripe in the columns
/// two windows share for the first of them, so the second loses its line:
/// windows that overlap cannot be tracked.
pub fn overlapping_windows(windows: &[Option<ColumnWindow>; LASERS]) -> Option<(usize, usize)> {
    (0..LASERS).flat_map(|a| (a + 1..LASERS).map(move |b| (a, b))).find(|&(a, b)| match (windows[a], windows[b]) {
        (Some(x), Some(y)) => u32::from(x.first_px) < y.end_px() && u32::from(y.first_px) < x.end_px(),
        _ => false,
    })
}

/// Which option set what the head refused as out of range.
fn refused_hint(command: &str, code: ErrorCode) -> &'static str {
    match (command, code) {
        ("SetWindows", ErrorCode::OutOfRange) => " (a --window or --windows-from beyond the head's sensor)",
        ("SetExposure" | "Start", ErrorCode::OutOfRange) => {
            " (--exposure × --rate above the lasers' duty limit, or a rate the head does not run at)"
        }
        ("SetTracking", ErrorCode::OutOfRange) => " (--track)",
        _ => "",
    }
}

impl crate::error::Classify for ListenError {
    fn class(&self) -> crate::Class {
        match self {
            ListenError::Output(_) => crate::Class::Output,
            ListenError::Record(r) => crate::error::Classify::class(r),
            ListenError::Readout { .. } | ListenError::NoFixesInFormat { .. } => crate::Class::Input,
            ListenError::Gnss(g) => crate::error::Classify::class(g),
            // What the user asked for (an exposure, a window, a rate) is
            // beyond what the head takes: bad usage, not a broken link.
            ListenError::Refused { code: ErrorCode::OutOfRange | ErrorCode::InvalidConfig, .. } => crate::Class::Input,
            _ => crate::Class::Device,
        }
    }
}

impl ListenError {
    /// The listener's words for a handshake that failed before the head
    /// was ever greeted.
    fn from_handshake(e: ClientError, port: &str) -> ListenError {
        match e {
            ClientError::Version { port, theirs } => ListenError::Version { port, theirs },
            _ => ListenError::NoHello { port: port.to_string() },
        }
    }
}

/// What a listening session did.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Complete frames received (all parts).
    pub frames: u64,
    /// Profile messages received.
    pub profiles: u64,
    /// Points received.
    pub points: u64,
    /// What the head's line pass flagged in them.
    pub line: Counts,
    /// First and last sequence number of a complete frame.
    pub seq: Option<(u32, u32)>,
    /// Link counters over all connections.
    pub link: Counters,
    /// Ports reopened after a failure.
    pub reconnects: u32,
    /// Handshakes repeated because the head went silent.
    pub stalls: u32,
    /// Restarts after the head stopped by itself.
    pub head_restarts: u32,
    /// Frames the head dropped (its last `Status`).
    pub head_dropped: u32,
    /// The frame rate the `Start` asked for, Hz.
    pub asked_rate_hz: Option<u16>,
    /// Lasers lit according to the head's last `Status`.
    pub lasers_on: Option<u8>,
    /// The head's last `Status` (its telemetry).
    pub head: Option<Status>,
    /// The head's description.
    pub device: Option<DeviceInfo>,
    /// The row readout the head acknowledged (`SetReadout`; `None`: none
    /// asked for).
    pub readout: Option<Readout>,
    /// Frames written to the recording.
    pub recorded: u64,
    /// Whether the head acknowledged the final `Stop`.
    pub stop_acked: bool,
    /// The output pipe was closed by its reader.
    pub output_closed: bool,
    /// From the call to the end.
    pub elapsed: Duration,
    /// From the first to the last profile.
    pub streaming: Duration,
    /// The GNSS receiver's part, when one was read.
    pub gnss: Option<GnssSummary>,
    /// Event marks recorded and refused, when marks were taken.
    pub marks: Option<(u64, u64)>,
}

/// What came from the GNSS receiver.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GnssSummary {
    /// Its port.
    pub port: String,
    /// Fixes written to the recording (or received, without one).
    pub fixes: u64,
    /// The reader's counters.
    pub stats: crate::gnss::ReceiverStats,
    /// The last fix.
    pub last: Option<crate::gnss::Fix>,
}

impl fmt::Display for GnssSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let last = match &self.last {
            Some(x) => format!(
                ", last {} with {} satellites, HDOP {}",
                x.quality.name(),
                x.satellites.map_or("?".into(), |n| n.to_string()),
                x.hdop.map_or("?".into(), |h| format!("{h:.1}"))
            ),
            None => ", no fix".to_string(),
        };
        let s = &self.stats;
        write!(
            f,
            "gnss {}: {} fixes{last}; {} sentences damaged, {} other sentences and frames, {} epochs without a position, {} fixes dropped, {} outages",
            self.port, self.fixes, s.damaged, s.other, s.no_position, s.dropped, s.outages
        )?;
        if s.stray_bytes > 0 {
            write!(f, ", {} stray bytes", s.stray_bytes)?;
        }
        Ok(())
    }
}

impl Summary {
    /// Resynchronisations: decode errors and overflows.
    pub fn resyncs(&self) -> u64 {
        self.link.resyncs()
    }

    /// Frames per second while streaming.
    pub fn frames_per_s(&self) -> f64 {
        let t = self.streaming.as_secs_f64();
        if self.frames > 1 && t > 0.0 { (self.frames - 1) as f64 / t } else { 0.0 }
    }

    /// Whether the head is the simulated one (its `Hello`'s board).
    pub fn simulated(&self) -> bool {
        self.device.as_ref().is_some_and(|d| d.board.as_str() == crate::sim::head::server::IDENTITY.board)
    }

    /// For a simulated head streaming `frames_per_s` under
    /// [`SIM_RATE_SHORT`] of the rate asked: the rate, named as the
    /// simulator's limit. The simulated head does not count the frames it
    /// could not render in time as dropped (they are this computer's, not
    /// a head's or the link's), so this is where they show.
    pub fn simulator_limit(&self, frames_per_s: f64) -> Option<String> {
        let asked = f64::from(self.asked_rate_hz?);
        (self.simulated() && frames_per_s > 0.0 && frames_per_s < SIM_RATE_SHORT * asked).then(|| {
            format!(
                "simulator: rendering {frames_per_s:.1} frames/s of {asked} (the simulator's limit, not the head's)"
            )
        })
    }
}

/// A simulated head streaming under this share of the asked rate has its
/// rate named as the simulator's limit: a second's count of frames varies
/// by one in thirty (3 %) at the default rate without anything lost.
pub const SIM_RATE_SHORT: f64 = 0.97;

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "frames: {} ({} profile messages, {} points, {:.1} points/frame)",
            self.frames,
            self.profiles,
            self.points,
            if self.frames > 0 { self.points as f64 / self.frames as f64 } else { 0.0 }
        )?;
        let per = |n: u32| if self.frames > 0 { f64::from(n) / self.frames as f64 } else { 0.0 };
        writeln!(
            f,
            "line pass: {} glint, {} ghost, {} off-line points rejected ({:.2} / {:.2} / {:.2} per frame), {} kept with a second candidate dropped",
            self.line.glint,
            self.line.ghost,
            self.line.off_line,
            per(self.line.glint),
            per(self.line.ghost),
            per(self.line.off_line),
            self.line.second_dropped
        )?;
        writeln!(f, "elapsed: {:.3} s, {:.2} frames/s", self.elapsed.as_secs_f64(), self.frames_per_s())?;
        if let Some(limit) = self.simulator_limit(self.frames_per_s()) {
            writeln!(f, "{limit}")?;
        }
        writeln!(
            f,
            "link: {} CRC errors, {} resyncs ({} decode errors, {} overflows), {} bytes discarded",
            self.link.crc_errors,
            self.resyncs(),
            self.link.decode_errors,
            self.link.overflows,
            self.link.discarded_bytes
        )?;
        writeln!(
            f,
            "reconnects: {}, stalls: {}, head restarts: {}, head dropped frames: {}",
            self.reconnects, self.stalls, self.head_restarts, self.head_dropped
        )?;
        match self.device.as_ref().map(|d| d.calibration_id) {
            Some(0) => writeln!(f, "calibration: none (positions in pixels only: see cms-host calibrate)")?,
            Some(id) => writeln!(f, "calibration: {id:#010x} (points in mm along the line, heights in µm)")?,
            None => {}
        }
        if let Some(r) = &self.readout {
            writeln!(
                f,
                "rows: sensor rows {}..{}, one in {} ({} a frame)",
                r.first_row(),
                r.end_row(),
                r.skip().factor(),
                r.rows_read()
            )?;
        }
        if let Some(h) = &self.head {
            writeln!(f, "head (last status): {}", telemetry(h))?;
        }
        let lasers = match self.lasers_on {
            Some(0) => "off".to_string(),
            Some(m) => format!("ON ({m:#05b})"),
            None => "unknown".to_string(),
        };
        if let Some(g) = &self.gnss {
            writeln!(f, "{g}")?;
        }
        if let Some((kept, refused)) = self.marks {
            writeln!(f, "marks: {kept} recorded, {refused} refused")?;
        }
        write!(f, "lasers: {lasers}{}", if self.stop_acked { " (stop acknowledged)" } else { "" })
    }
}

/// The head's telemetry from its `Status`, compact: processing per row (ns,
/// and core cycles where the head knows its clock), rows lost to the
/// camera's DMA, link backlog, laser duty over the status window, and a
/// fault if there is one.
pub fn telemetry(s: &Status) -> String {
    let cycles = if s.cycles_per_row > 0 { format!(" ({} cycles)", s.cycles_per_row) } else { String::new() };
    let fault = s.fault.map(|f| format!(", fault {f:?}")).unwrap_or_default();
    format!(
        "{} rows/s, {} ns/row{cycles}, {} rows lost, backlog {} B, laser duty {:.1} %{fault}",
        s.rows_per_s,
        s.ns_per_row,
        s.dropped_rows,
        s.link_backlog_bytes,
        f64::from(s.laser_duty_permille) / 10.0
    )
}

/// Where a session stands with its head.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum LinkPhase {
    /// `GetInfo` sent, waiting for `Hello`.
    #[default]
    Handshake,
    /// `Start` sent, waiting for its `Ack` or the first profile.
    Starting,
    /// Profiles flowing.
    Streaming,
    /// The port is lost; trying to open it again.
    Reconnecting,
    /// The session is ending (`Stop` sent or about to be).
    Stopping,
}

impl LinkPhase {
    /// "handshake", "starting", "streaming", "reconnecting", "stopping".
    pub fn name(self) -> &'static str {
        match self {
            LinkPhase::Handshake => "handshake",
            LinkPhase::Starting => "starting",
            LinkPhase::Streaming => "streaming",
            LinkPhase::Reconnecting => "reconnecting",
            LinkPhase::Stopping => "stopping",
        }
    }
}

/// The session's state that its messages do not carry: the link's phase
/// and counters, what was recorded (a live view shows it beside the
/// frames).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkState {
    /// Where the session stands.
    pub phase: LinkPhase,
    /// Link counters over all connections.
    pub link: Counters,
    /// Ports reopened after a failure.
    pub reconnects: u32,
    /// Handshakes repeated because the head went silent.
    pub stalls: u32,
    /// Restarts after the head stopped by itself.
    pub head_restarts: u32,
    /// Complete frames received.
    pub frames: u64,
    /// Messages written to the recording (profiles and the head's
    /// others); `None`: not recording.
    pub recorded: Option<u64>,
}

/// Where the session's live status line goes (the command line draws it;
/// the session only says when one is due and what it reads), and its
/// [`LinkState`] for a live view.
pub trait StatusLine {
    /// Whether a new line is due at `now`.
    fn due(&self, now: Instant) -> bool;
    /// Shows `line` (the status at `now`).
    fn show(&mut self, now: Instant, line: String);
    /// Whether the session's [`LinkState`] is wanted at `now` (never,
    /// unless a live view asks for it at its display rate).
    fn state_due(&self, _now: Instant) -> bool {
        false
    }
    /// The session's state at `now`; must not block (it is called from the
    /// loop that reads the port).
    fn state(&mut self, _now: Instant, _state: &LinkState) {}
    /// The session has ended.
    fn finish(&mut self) {}
}

/// No status line.
#[derive(Clone, Copy, Debug, Default)]
pub struct Quiet;

impl StatusLine for Quiet {
    fn due(&self, _: Instant) -> bool {
        false
    }
    fn show(&mut self, _: Instant, _: String) {}
}

/// How a session ended: what it did, and why it ended early if it did.
/// A session that fails after streaming (the port lost for good, the
/// recording's disk full) still has a summary worth printing.
#[derive(Debug)]
pub struct Outcome {
    /// What the session did, up to its end.
    pub summary: Summary,
    /// The failure that ended it, if any.
    pub result: Result<(), ListenError>,
}

impl Outcome {
    fn failed(e: ListenError) -> Outcome {
        Outcome { summary: Summary::default(), result: Err(e) }
    }

    /// Whether a head was ever greeted (else there is nothing to sum up).
    pub fn greeted(&self) -> bool {
        self.summary.device.is_some()
    }
}

/// [`session`] without a status line, its summary only when it did not fail.
pub fn listen_with(
    port: &str,
    opts: &ListenOptions,
    stop: &AtomicBool,
    out: &mut dyn Write,
    observe: &mut dyn FnMut(&DeviceMsg),
) -> Result<Summary, ListenError> {
    let o = session(port, opts, stop, out, observe, &mut Quiet);
    o.result.map(|()| o.summary)
}

/// Listens on `port` (a device path), writing the `--json` lines to `out`,
/// showing `observe` every message it keeps (the recorded ones) in order
/// and `status` the live status line. Returns when `opts` says so, when
/// `stop` becomes true (Ctrl-C), or when `out` is closed; the head is
/// stopped first.
pub fn session(
    port: &str,
    opts: &ListenOptions,
    stop: &AtomicBool,
    out: &mut dyn Write,
    observe: &mut dyn FnMut(&DeviceMsg),
    status: &mut dyn StatusLine,
) -> Outcome {
    session_with_marks(port, opts, stop, out, observe, status, None)
}

/// [`session`], taking the event marks that arrive in `marks` (see
/// [`mark_channel`]) into the recording; the marks still waiting when it
/// ends are taken before the recording is committed.
pub fn session_with_marks(
    port: &str,
    opts: &ListenOptions,
    stop: &AtomicBool,
    out: &mut dyn Write,
    observe: &mut dyn FnMut(&DeviceMsg),
    status: &mut dyn StatusLine,
    marks: Option<&MarkInbox>,
) -> Outcome {
    let t0 = Instant::now();
    let recorder = match &opts.record {
        Some(path) => match Recorder::open_with_survey(path, opts.survey.as_deref()) {
            Ok(r) => Some(r),
            Err(e) => return Outcome::failed(ListenError::Record(e)),
        },
        None => None,
    };
    if let (Some(_), Some(rec)) = (&opts.gnss, &recorder)
        && !rec.holds_host_records()
    {
        return Outcome::failed(ListenError::NoFixesInFormat { path: rec.path().to_path_buf(), format: rec.format() });
    }
    let gnss = match &opts.gnss {
        Some(g) => match crate::gnss::Receiver::start(&g.path, g.baud) {
            Ok(r) => Some(r),
            Err(e) => return Outcome::failed(ListenError::Gnss(e)),
        },
        None => None,
    };
    let mut client = match Client::open(port, opts.baud) {
        Ok(c) => c.with_heartbeat(HEARTBEAT_INTERVAL),
        Err(e) => return Outcome::failed(ListenError::Open(e)),
    };
    let mut s = Session::new(opts, port, out, observe, recorder, client.outbox(), t0);
    s.gnss = gnss;
    s.marks = marks;
    let mut last_open_try = t0;
    let result = loop {
        let now = Instant::now();
        if let Some(end) = s.step(&mut client, stop, now, t0, &mut last_open_try) {
            break end;
        }
        if status.due(now) {
            let line = s.status_line(now, client.is_open());
            status.show(now, line);
        }
        if status.state_due(now) {
            status.state(now, &s.link_state(client.is_open()));
        }
    };
    s.finish(&mut client, result, status, t0)
}
