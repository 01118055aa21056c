//! One listening session's state: the handshake, the commands in flight,
//! the frames received, the recording and the status line's rates.

use std::io::{self, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use cms_core::pipeline::line::Counts;
use cms_core::protocol::{DeviceMsg, HeadState, HostMsg, Profile, WireError};
use cms_core::readout::Readout;

use crate::analyze::live::LiveEstimate;
use crate::analyze::live::bands::LiveBands;
use crate::gnss::{Placed, Receiver};
use crate::link::{Client, Greeting, Outbox, check_version};
use crate::recording::HostRecord;
use crate::recording::mark::Mark;
use crate::recording::{self, FrameCounter, Recorder};

use super::marks::{MarkInbox, MarkRefused};
use super::{
    HANDSHAKE, LinkPhase, LinkState, ListenError, ListenOptions, Outcome, REOPEN_INTERVAL, STALL_TIMEOUT,
    START_TIMEOUT, STOP_ACK_TIMEOUT, StatusLine, Summary, telemetry,
};

#[derive(Clone, Copy, Debug, Default)]
struct WindowRates {
    frames_per_s: f64,
    points_per_frame: f64,
    /// Points the line pass rejected per frame.
    rejected_per_frame: f64,
}

enum Phase {
    /// `GetInfo` sent, waiting for `Hello`.
    Hello(Greeting),
    /// `Start` sent.
    Starting { sent: Instant },
    /// Streaming.
    Streaming,
}

pub(super) struct Session<'a> {
    opts: &'a ListenOptions,
    port: &'a str,
    out: &'a mut dyn Write,
    observe: &'a mut dyn FnMut(&DeviceMsg),
    recorder: Option<Recorder>,
    sum: Summary,
    counter: FrameCounter,
    phase: Phase,
    start_seq: Option<u16>,
    exposure_seq: Option<u16>,
    windows_seq: Option<u16>,
    tracking_seq: Option<u16>,
    /// The `SetReadout` sent, and what it asked for.
    readout_seq: Option<(u16, Readout)>,
    stop_seq: Option<u16>,
    /// When the stop began (and so when to give up waiting for its Ack).
    stopping: Option<Instant>,
    /// A `Status` arrived after the `Ack` of `Stop`.
    stop_reported: bool,
    fatal: Option<ListenError>,
    greeted: bool,
    last_rx: Instant,
    /// Since when the link has been in trouble (lost, silent, not started).
    trouble: Option<(Instant, String)>,
    first_profile: Option<Instant>,
    last_profile: Option<Instant>,
    head_state: Option<HeadState>,
    // rate window of the status line
    window_start: Instant,
    window_frames: u64,
    window_points: u64,
    window_rejected: u64,
    /// Frames per second and points per frame over the last window.
    window_rates: WindowRates,
    /// The recent calibrated frames, for the corrugation estimate.
    live: LiveEstimate,
    /// The run's EN 13231-3 band figures so far.
    bands: LiveBands,
    /// The GNSS receiver read beside the head.
    pub(super) gnss: Option<Receiver>,
    /// The last profile: when it arrived, its time and odometer (µm).
    last_head: Option<(Instant, u64, i64)>,
    /// The last profile's `seq`.
    last_seq: u32,
    /// Where event marks arrive.
    pub(super) marks: Option<&'a MarkInbox>,
    /// When the last fix arrived.
    last_fix_at: Option<Instant>,
    t0: Instant,
}

impl Session<'_> {
    fn hello(&mut self, out: &mut Outbox, now: Instant) {
        self.phase = Phase::Hello(Greeting::begin(HANDSHAKE, out, now));
    }

    fn start(&mut self, out: &mut Outbox, now: Instant) {
        if let Some(us) = self.opts.exposure_us {
            self.exposure_seq = Some(out.push(HostMsg::SetExposure { exposure_us: us }));
        }
        if let Some(w) = self.opts.windows {
            self.windows_seq = Some(out.push(HostMsg::SetWindows(w)));
        }
        if let Some(px) = self.opts.track_px {
            self.tracking_seq = Some(out.push(HostMsg::SetTracking { half_width_px: px }));
        }
        if let Some(req) = self.opts.readout {
            let height = self.sum.device.as_ref().map_or(0, |d| d.sensor_height);
            match req.on(height) {
                Ok(r) => {
                    let msg = HostMsg::SetReadout { first_row: r.first_row(), rows: r.rows(), skip: r.skip().factor() };
                    self.readout_seq = Some((out.push(msg), r));
                }
                Err(why) => {
                    self.fatal = Some(ListenError::Readout { port: self.port.to_string(), why });
                    return;
                }
            }
        }
        self.start_seq = Some(out.push(HostMsg::Start(self.opts.start)));
        self.sum.asked_rate_hz = Some(self.opts.start.rate_hz);
        self.phase = Phase::Starting { sent: now };
    }

    fn trouble(&mut self, now: Instant, why: String) {
        match &mut self.trouble {
            Some((_, w)) => *w = why,
            None => self.trouble = Some((now, why)),
        }
    }

    fn on_frame(&mut self, r: Result<DeviceMsg, WireError>, raw: &[u8], out: &mut Outbox) {
        let msg = match r {
            Ok(m) => m,
            Err(e) => {
                // A frame of another version is how such a head's Hello
                // shows: the handshake names it if it gives up.
                if let Phase::Hello(g) = &mut self.phase {
                    g.on_frame(self.port, &Err(e));
                }
                return;
            }
        };
        if self.fatal.is_some() || (self.stopping.is_some() && matches!(msg, DeviceMsg::Profile(_))) {
            // Past the requested end: profiles still in flight are dropped.
            return;
        }
        if let Some(rec) = &mut self.recorder {
            match rec.write_frame(raw) {
                Ok(()) => self.sum.recorded += 1,
                Err(e) => {
                    self.fatal = Some(ListenError::Record(e));
                    return;
                }
            }
        }
        (self.observe)(&msg);
        let now = Instant::now();
        match msg {
            DeviceMsg::Hello(info) => {
                if let Err(e) = check_version(self.port, &info) {
                    self.fatal = Some(ListenError::from_handshake(e, self.port));
                    return;
                }
                self.greeted = true;
                self.sum.device = Some(info);
                match self.phase {
                    Phase::Hello(_) if self.stopping.is_none() => self.start(out, now),
                    // An unsolicited Hello while streaming: the head restarted.
                    Phase::Streaming if self.stopping.is_none() => {
                        self.sum.head_restarts += 1;
                        self.start(out, now);
                    }
                    _ => {}
                }
            }
            DeviceMsg::Profile(p) => self.on_profile(&p, now),
            DeviceMsg::Status(s) => {
                self.sum.head_dropped = s.dropped_frames;
                self.sum.lasers_on = Some(s.lasers_on);
                self.sum.head = Some(s);
                self.head_state = Some(s.state);
                if self.sum.stop_acked {
                    // The head's report after the Stop: its lasers now.
                    self.stop_reported = true;
                }
                if s.state != HeadState::Streaming && matches!(self.phase, Phase::Streaming) && self.stopping.is_none()
                {
                    self.sum.head_restarts += 1;
                    self.start(out, now);
                }
            }
            DeviceMsg::Ack(seq) => {
                if Some(seq) == self.start_seq && matches!(self.phase, Phase::Starting { .. }) {
                    self.phase = Phase::Streaming;
                    self.trouble = None;
                    self.last_rx = now;
                } else if Some(seq) == self.stop_seq {
                    self.sum.stop_acked = true;
                } else if let Some((s, r)) = self.readout_seq
                    && s == seq
                {
                    self.sum.readout = Some(r);
                }
            }
            DeviceMsg::Error { seq: Some(seq), code } if Some(seq) == self.start_seq => {
                self.fatal = Some(ListenError::Refused { command: "Start", code });
            }
            DeviceMsg::Error { seq: Some(seq), code } if Some(seq) == self.exposure_seq => {
                self.fatal = Some(ListenError::Refused { command: "SetExposure", code });
            }
            DeviceMsg::Error { seq: Some(seq), code } if Some(seq) == self.windows_seq => {
                self.fatal = Some(ListenError::Refused { command: "SetWindows", code });
            }
            DeviceMsg::Error { seq: Some(seq), code } if Some(seq) == self.tracking_seq => {
                self.fatal = Some(ListenError::Refused { command: "SetTracking", code });
            }
            DeviceMsg::Error { seq: Some(seq), code } if self.readout_seq.is_some_and(|(s, _)| s == seq) => {
                self.fatal = Some(ListenError::Refused { command: "SetReadout", code });
            }
            DeviceMsg::Error { .. } | DeviceMsg::RawRows(_) => {}
        }
    }

    fn on_profile(&mut self, p: &Profile, now: Instant) {
        if let Phase::Starting { .. } = self.phase {
            // Profiles flow, so the Start took even if its Ack was lost.
            self.phase = Phase::Streaming;
            self.trouble = None;
        }
        self.first_profile.get_or_insert(now);
        self.last_profile = Some(now);
        self.last_head = Some((now, p.timestamp_us, p.odometer_um));
        self.last_seq = p.seq;
        self.sum.profiles += 1;
        if let Some(f) = self.live.push(p) {
            self.bands.add(f);
        }
        let n = recording::points(p);
        self.sum.points += n;
        self.window_points += n;
        let line = Counts::of(&p.lasers);
        self.sum.line = self.sum.line.plus(line);
        self.window_rejected += u64::from(line.rejected());
        if self.counter.profile(p) {
            self.sum.frames += 1;
            self.window_frames += 1;
            self.sum.seq = Some(self.sum.seq.map_or((p.seq, p.seq), |(first, _)| (first, p.seq)));
            if self.opts.frames.is_some_and(|n| self.sum.frames >= n) {
                self.stopping.get_or_insert(now);
            }
        }
        if self.opts.json && !self.sum.output_closed {
            let r = recording::write_json_line(self.out, p).and_then(|()| self.out.flush());
            match r {
                Ok(()) => {}
                Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {
                    self.sum.output_closed = true;
                    self.stopping.get_or_insert(now);
                }
                Err(e) => self.fatal = Some(ListenError::Output(e)),
            }
        }
    }

    /// Timeouts of the handshake and the stream (the heartbeats are the
    /// client's). Returns true when the port should be closed and reopened.
    fn timers(&mut self, now: Instant, out: &mut Outbox) -> bool {
        if self.stopping.is_some() {
            return false;
        }
        if let Some((since, why)) = &self.trouble
            && now.duration_since(*since) > self.opts.reconnect_timeout
            && self.greeted
        {
            self.fatal = Some(ListenError::Lost {
                port: self.port.to_string(),
                after: self.opts.reconnect_timeout,
                why: why.clone(),
            });
            return false;
        }
        match &mut self.phase {
            Phase::Hello(g) => match g.poll(self.port, now, self.last_rx, out) {
                Ok(()) => {}
                Err(e) if !self.greeted => self.fatal = Some(ListenError::from_handshake(e, self.port)),
                Err(_) => {
                    self.trouble(now, "no Hello after the head went silent".to_string());
                    return true;
                }
            },
            Phase::Starting { sent } if now.duration_since(*sent) >= START_TIMEOUT => {
                self.trouble(now, "Start was not acknowledged".to_string());
                self.hello(out, now);
            }
            Phase::Streaming if now.duration_since(self.last_rx) >= STALL_TIMEOUT => {
                self.sum.stalls += 1;
                self.trouble(now, format!("no bytes for {} s", STALL_TIMEOUT.as_secs()));
                self.hello(out, now);
            }
            _ => {}
        }
        false
    }

    pub(super) fn link_state(&self, connected: bool) -> LinkState {
        let phase = if self.stopping.is_some() {
            LinkPhase::Stopping
        } else if !connected {
            LinkPhase::Reconnecting
        } else {
            match self.phase {
                Phase::Hello(_) => LinkPhase::Handshake,
                Phase::Starting { .. } => LinkPhase::Starting,
                Phase::Streaming => LinkPhase::Streaming,
            }
        };
        LinkState {
            phase,
            link: self.sum.link,
            reconnects: self.sum.reconnects,
            stalls: self.sum.stalls,
            head_restarts: self.sum.head_restarts,
            frames: self.sum.frames,
            recorded: self.recorder.as_ref().map(|_| self.sum.recorded),
        }
    }

    pub(super) fn status_line(&mut self, now: Instant, connected: bool) -> String {
        let dt = now.duration_since(self.window_start).as_secs_f64();
        if dt >= 1.0 {
            let per = |n: u64| if self.window_frames > 0 { n as f64 / self.window_frames as f64 } else { 0.0 };
            self.window_rates = WindowRates {
                frames_per_s: self.window_frames as f64 / dt,
                points_per_frame: per(self.window_points),
                rejected_per_frame: per(self.window_rejected),
            };
            self.window_start = now;
            self.window_frames = 0;
            self.window_points = 0;
            self.window_rejected = 0;
        }
        let state = if !connected {
            "reconnecting"
        } else {
            match self.phase {
                Phase::Hello(_) => "handshake",
                Phase::Starting { .. } => "starting",
                Phase::Streaming => "streaming",
            }
        };
        let lasers = match self.sum.lasers_on {
            Some(0) => "off".to_string(),
            Some(m) => format!("{m:03b}"),
            None => "?".to_string(),
        };
        // Once calibrated points flow: the sine fit of each laser's last half metre.
        let mut corrugation = self.live.status();
        // And the run's EN 13231-3 bands so far, as analyze would judge them.
        if let Some(b) = self.bands.report() {
            let b = b.status();
            if !b.is_empty() {
                corrugation =
                    if corrugation.is_empty() { b } else { format!("{corrugation} (one sine, a diagnostic); {b}") };
            }
        }
        // The head's own report, once it has one from streaming (the one
        // answering Start has an empty window).
        let mut head = match &self.sum.head {
            Some(h) if h.frames > 0 => format!(", head {}", telemetry(h)),
            _ => String::new(),
        };
        // A simulated head's rate, since the first frame, when the
        // simulator cannot render the rate asked.
        let since = self.first_profile.map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64());
        let rate = if self.sum.frames > 1 && since >= 1.0 { (self.sum.frames - 1) as f64 / since } else { 0.0 };
        if let Some(limit) = self.sum.simulator_limit(rate) {
            head = format!("{head}, {limit}");
        }
        format!(
            "{state}: {:.1} frames/s, {:.0} points/frame ({:.1} rejected), {} frames, CRC errors {}, resyncs {}, dropped {}, reconnects {}, lasers {lasers}{head}{}{}{corrugation}",
            self.window_rates.frames_per_s,
            self.window_rates.points_per_frame,
            self.window_rates.rejected_per_frame,
            self.sum.frames,
            self.sum.link.crc_errors,
            self.sum.link.resyncs(),
            self.sum.head_dropped,
            self.sum.reconnects,
            self.gnss_status(now),
            if corrugation.is_empty() { "" } else { ", " },
        )
    }
}

impl<'a> Session<'a> {
    /// A session that has just sent its first `GetInfo` (through `outbox`).
    pub(super) fn new(
        opts: &'a ListenOptions,
        port: &'a str,
        out: &'a mut dyn Write,
        observe: &'a mut dyn FnMut(&DeviceMsg),
        recorder: Option<Recorder>,
        outbox: &mut Outbox,
        t0: Instant,
    ) -> Self {
        Session {
            opts,
            port,
            out,
            observe,
            recorder,
            sum: Summary::default(),
            counter: FrameCounter::default(),
            phase: Phase::Hello(Greeting::begin(HANDSHAKE, outbox, t0)),
            start_seq: None,
            exposure_seq: None,
            windows_seq: None,
            tracking_seq: None,
            readout_seq: None,
            stop_seq: None,
            stopping: None,
            stop_reported: false,
            fatal: None,
            greeted: false,
            last_rx: t0,
            trouble: Some((t0, "never started".to_string())),
            first_profile: None,
            last_profile: None,
            head_state: None,
            window_start: t0,
            window_frames: 0,
            window_points: 0,
            window_rejected: 0,
            window_rates: WindowRates::default(),
            live: LiveEstimate::default(),
            bands: LiveBands::new(opts.live_bands),
            gnss: None,
            last_head: None,
            last_seq: 0,
            marks: None,
            last_fix_at: None,
            t0,
        }
    }

    /// The receiver's fixes since the last turn: placed on the head's
    /// clock by the host's (see [`crate::gnss`], "Time alignment") and
    /// recorded.
    fn gnss_step(&mut self) {
        let Some(rx) = &self.gnss else { return };
        let fixes: Vec<_> = rx.drain().collect();
        let g = self.sum.gnss.get_or_insert_with(|| crate::device::listen::GnssSummary {
            port: rx.port().to_string(),
            ..Default::default()
        });
        g.stats = rx.stats();
        for (at, fix) in fixes {
            let head_us = self.last_head.map(|(arrived, ts, _)| {
                if at >= arrived {
                    ts.saturating_add((at - arrived).as_micros() as u64)
                } else {
                    ts.saturating_sub((arrived - at).as_micros() as u64)
                }
            });
            let placed = Placed {
                host_us: at.saturating_duration_since(self.t0).as_micros() as u64,
                head_us,
                odometer_um: self.last_head.map(|h| h.2),
                fix,
            };
            self.last_fix_at = Some(at);
            if let Some(rec) = &mut self.recorder
                && let Err(e) = rec.write_host_record(&HostRecord::Fix(placed.clone()))
            {
                self.fatal = Some(ListenError::Record(e));
                return;
            }
            g.fixes += 1;
            g.last = Some(placed.fix);
        }
    }

    /// The marks waiting: each placed at the latest profile, recorded and
    /// answered. Never waits.
    fn marks_step(&mut self) {
        let Some(inbox) = self.marks else { return };
        if self.recorder.is_some() {
            self.sum.marks.get_or_insert((0, 0));
        }
        for req in inbox.0.try_iter() {
            self.sum.marks.get_or_insert((0, 0));
            let placed = match (&mut self.recorder, self.last_head) {
                _ if self.fatal.is_some() => Err(MarkRefused::Busy),
                (None, _) => Err(MarkRefused::NotRecording),
                (Some(rec), _) if !rec.holds_marks() => Err(MarkRefused::Format(rec.format())),
                (_, None) => Err(MarkRefused::NoFrame),
                (Some(rec), Some((arrived, head_us, odometer_um))) => {
                    let at = Instant::now();
                    let mark = Mark {
                        kind: req.entry.kind,
                        text: req.entry.text,
                        host_us: at.saturating_duration_since(self.t0).as_micros() as u64,
                        seq: self.last_seq,
                        head_us,
                        odometer_um,
                        after_us: at.saturating_duration_since(arrived).as_micros() as u64,
                    };
                    match rec.write_host_record(&HostRecord::Mark(mark.clone())) {
                        Ok(()) => Ok(mark),
                        Err(e) => {
                            let why = e.to_string();
                            self.fatal = Some(ListenError::Record(e));
                            Err(MarkRefused::Write(why))
                        }
                    }
                }
            };
            if let Some((kept, refused)) = &mut self.sum.marks {
                if placed.is_ok() { *kept += 1 } else { *refused += 1 }
            }
            (req.reply)(placed);
        }
    }

    /// The status line's GNSS part.
    fn gnss_status(&self, now: Instant) -> String {
        let Some(g) = &self.sum.gnss else { return String::new() };
        match (&g.last, self.last_fix_at) {
            (Some(f), Some(at)) if now.saturating_duration_since(at) < Duration::from_secs(2) => {
                format!(", GNSS {} {} sats", f.quality.name(), f.satellites.map_or("?".into(), |n| n.to_string()))
            }
            (_, Some(at)) => format!(", GNSS: no fix for {:.0} s", now.saturating_duration_since(at).as_secs_f64()),
            _ => ", GNSS: no fix yet".to_string(),
        }
    }

    /// One turn of the session's loop at `now`: the end and the wait for
    /// Stop's Ack, frames received, a lost port reopened, timers, commands
    /// sent, the recording synced. `Some` when the session is over.
    pub(super) fn step(
        &mut self,
        client: &mut Client,
        stop: &AtomicBool,
        now: Instant,
        t0: Instant,
        last_open_try: &mut Instant,
    ) -> Option<Result<(), ListenError>> {
        if let Some(e) = self.fatal.take() {
            return Some(Err(e));
        }
        if let Some(end) = self.ending(client, stop, now, t0) {
            return Some(end);
        }
        if client.is_open() {
            // A failed port is closed by the client (the frame in progress
            // and the queued commands dropped).
            match client.receive(|r, raw, out| self.on_frame(r, raw, out)) {
                Ok(0) => {}
                Ok(_) => {
                    self.last_rx = Instant::now();
                    self.sum.link = client.counters();
                }
                Err(e) => self.trouble(now, e.to_string()),
            }
        } else if let Some(lost) = self.reopen(client, now, last_open_try) {
            return Some(Err(lost));
        }
        if client.is_open() && self.timers(now, client.outbox()) {
            // The head stays silent: close the port and open it again.
            client.close();
            *last_open_try = now;
        }
        // Commands the head did not take are lost: the heartbeats and the
        // handshake's retries cover them.
        if let Err(e) = client.transmit(now) {
            self.trouble(now, e.to_string());
        }
        self.gnss_step();
        self.marks_step();
        if let Some(rec) = &mut self.recorder
            && let Err(e) = rec.tick()
        {
            self.fatal = Some(ListenError::Record(e));
        }
        None
    }

    /// The end (Ctrl-C or the duration), and the wait for Stop's Ack.
    fn ending(
        &mut self,
        client: &mut Client,
        stop: &AtomicBool,
        now: Instant,
        t0: Instant,
    ) -> Option<Result<(), ListenError>> {
        if self.stopping.is_none()
            && (stop.load(Ordering::SeqCst) || self.opts.duration.is_some_and(|d| now.duration_since(t0) >= d))
        {
            self.stopping = Some(now);
        }
        let since = self.stopping?;
        if self.stop_seq.is_none() {
            if self.start_seq.is_none() || !client.is_open() {
                return Some(Ok(()));
            }
            self.stop_seq = Some(client.outbox().push(HostMsg::Stop));
        }
        // The head answers Stop with Ack and then a Status (lasers off).
        if self.stop_reported || !client.is_open() || now.duration_since(since) >= STOP_ACK_TIMEOUT {
            return Some(Ok(()));
        }
        None
    }

    /// A lost port tried again every [`REOPEN_INTERVAL`]; the error when it
    /// has been in trouble longer than the reconnect timeout.
    fn reopen(&mut self, client: &mut Client, now: Instant, last_open_try: &mut Instant) -> Option<ListenError> {
        if now.duration_since(*last_open_try) >= REOPEN_INTERVAL {
            *last_open_try = now;
            if client.reopen().is_ok() {
                self.sum.reconnects += 1;
                self.last_rx = now;
                self.hello(client.outbox(), now);
            }
        } else {
            // A device path coming back gives no event to wait on; the
            // loop also watches Ctrl-C and redraws the status meanwhile.
            std::thread::sleep(Duration::from_millis(20));
        }
        if !client.is_open()
            && let Some((since, why)) = &self.trouble
            && now.duration_since(*since) > self.opts.reconnect_timeout
        {
            return Some(ListenError::Lost {
                port: self.port.to_string(),
                after: self.opts.reconnect_timeout,
                why: why.clone(),
            });
        }
        None
    }

    /// The session's end, however it came: the lasers off, the recording
    /// flushed, the summary completed.
    pub(super) fn finish(
        mut self,
        client: &mut Client,
        result: Result<(), ListenError>,
        status: &mut dyn StatusLine,
        t0: Instant,
    ) -> Outcome {
        // Whatever happened, the lasers go off: a last Stop if the port is open
        // (without waiting), and the head's own 1 s heartbeat rule otherwise.
        // Commands still queued (decided on the last frames) are dropped first.
        if result.is_err() && client.is_open() && self.start_seq.is_some() && self.stop_seq.is_none() {
            client.outbox().clear();
            client.outbox().push(HostMsg::Stop);
            let _ = client.transmit(Instant::now());
        }
        status.finish();
        // The fixes and marks that arrived up to the end are kept.
        self.gnss_step();
        self.marks_step();
        if let Some(g) = &mut self.sum.gnss
            && let Some(rx) = &self.gnss
        {
            g.stats = rx.stats();
        }
        let flushed = match &mut self.recorder {
            Some(rec) => rec.finish().map_err(ListenError::Record),
            None => Ok(()),
        };
        self.sum.link = client.counters();
        self.sum.elapsed = t0.elapsed();
        if let (Some(a), Some(b)) = (self.first_profile, self.last_profile) {
            self.sum.streaming = b.duration_since(a);
        }
        Outcome { summary: self.sum, result: result.and(flushed) }
    }
}
