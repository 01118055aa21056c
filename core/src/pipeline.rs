//! The sensor head without its hardware: commands in, rows in, profiles out,
//! and the laser-safety rules — written once for the firmware and the
//! simulated head.
//!
//! # Laser safety (50 mW, class 3B)
//! The head owns the laser driver ([`LaserDriver`]) and is the only code that
//! switches it, so no caller can forget a rule:
//!
//! * off at construction (before anything else can happen);
//! * on only while [`HeadState::Streaming`], only the lasers of the
//!   current frame (one at a time in the sequential pattern), and only for
//!   that frame's exposure (strobed: off again before its rows are read);
//! * never beyond the duty-cycle limit ([`crate::duty`]): `Start` and
//!   `SetExposure` refuse a steady exposure × rate above it, and every strobe
//!   is booked against it (a refused strobe drops the frame, lasers off);
//! * off on `Stop`, on every error while streaming (the head goes to
//!   [`HeadState::Fault`]), on a camera fault, and when no command or
//!   heartbeat has arrived for more than [`HEARTBEAT_TIMEOUT_US`] (1 s);
//! * off when the head is dropped.
//!
//! # Cost
//! Per row: the detector (see `peak`), plus a stripe-to-laser assignment of at
//! most 3 × 3 comparisons. Profiles are built in place in the head. Per
//! frame: the line pass ([`mod@line`]) over each laser's points, which flags
//! glints, ghosts and points off the line before the profile goes out.
//!
//! # Triggers and persistence
//! Frames come every `1 / rate_hz` ([`Trigger::Timed`]) or every N µm of
//! odometer travel ([`Trigger::Distance`], at most `rate_hz`; travel faster
//! than that drops frames, counted). Calibration, exposure, detector and
//! trigger are what a head keeps in flash ([`Stored`]): the head marks them
//! changed and the firmware writes them when [`Head::take_store_request`]
//! says so (the write itself is `persist`'s).
//!
//! # Readout
//! A frame reads the rows of the [`Readout`] `SetReadout` set before its
//! `Start` (every row otherwise; captures always every row): the head sets
//! it on the camera ([`Camera::set_readout`], lasers off) when it changes,
//! numbers each point by its sensor row, and triangulates a binned row at
//! its rows' centre ([`RowSampling`]).

use crate::duty::DutyLimit;
use crate::fixed::{Px, Q16_16};
use crate::odometer::DistanceTrigger;
use crate::peak::{ColumnWindow, Config, Detector, Select, Stripes, Track, Windows};
use crate::persist::Stored;
use crate::protocol::{
    Calibration, DeviceInfo, DeviceMsg, ErrorCode, HeadState, LASERS, LaserPattern, LaserPoints, MAX_ROWS_PER_PROFILE,
    PROTOCOL_VERSION, Profile, RAW_CHUNK_BYTES, RawRows, Start, Status, StoreHealth, Trigger,
};
use crate::readout::{Readout, RowSampling};
use crate::triangulation::Triangulator;
use heapless::{String, Vec};

mod assign;
mod calibration;
mod command;
pub mod line;
pub use assign::assign;
use assign::triangulate;
pub use calibration::{
    CalibrationError, MIN_LINE_SEPARATION_PX, WORKING_DEPTH_FRACTION, calibration_is_valid, check_laser_lines,
    triangulator, working_depth_mm,
};

/// Longest silence from the host before the lasers go off, µs.
pub const HEARTBEAT_TIMEOUT_US: u64 = 1_000_000;
/// Interval of `Status` messages while streaming, µs.
pub const STATUS_INTERVAL_US: u64 = 1_000_000;
/// Exposure limits, µs.
pub const EXPOSURE_RANGE_US: (u32, u32) = (1, 1_000_000);

/// The laser enables. `set(0)` must switch every laser off.
pub trait LaserDriver {
    /// Drives the enables: bit k lit ⇔ laser k on.
    fn set(&mut self, mask: u8);
}

/// Where rows come from (the camera, or the simulated one).
pub trait Camera {
    /// Why a frame failed.
    type Error;
    /// Row length, px.
    fn width(&self) -> u16;
    /// Rows per frame.
    fn height(&self) -> u16;
    /// Bits per pixel.
    fn bits(&self) -> u8;
    /// Exposes one frame (lasers already lit by the head). Returns the
    /// odometer at exposure, µm.
    fn expose(&mut self, exposure_us: u32, laser_mask: u8) -> Result<i64, Self::Error>;
    /// The next row of the exposed frame, `width` pixels.
    fn read_row(&mut self, row: &mut [u16]) -> Result<(), Self::Error>;
    /// The odometer now, µm, if the head has one (needed by
    /// [`Trigger::Distance`]).
    fn odometer_um(&self) -> Option<i64> {
        None
    }
    /// Rows lost before processing since start (DMA overrun).
    fn dropped_rows(&self) -> u32 {
        0
    }
    /// Most rows an image capture takes from one exposure. A camera that
    /// cannot hold a frame (the board's DMA ring holds 8 rows, and the link
    /// is far slower than the sensor) gives a band it can buffer: the head
    /// then captures the image band by band, one exposure each, and sends a
    /// band out before it exposes the next. Default: the whole frame.
    fn capture_band_rows(&self) -> u16 {
        self.height()
    }
    /// After a capture's exposure (lasers already off): keep rows
    /// `first..first + rows` of the exposed frame for [`Camera::read_row`],
    /// passing over the rows before them (`scratch`: one row of `width`
    /// pixels). Default: read past the rows before the band.
    fn start_band(&mut self, first: u16, rows: u16, scratch: &mut [u16]) -> Result<(), Self::Error> {
        let _ = rows;
        for _ in 0..first {
            self.read_row(scratch)?;
        }
        Ok(())
    }
    /// Reads the rows of `readout` (validated against [`Camera::height`])
    /// from the next exposure on, until told otherwise; says how
    /// ([`RowSampling`]). The head calls it, lasers off, before an exposure
    /// whose readout differs from the last one set: a streaming frame's
    /// (`SetReadout`), and a capture's (every row). Default: whole frames
    /// whatever the readout, and the head passes over the rows it does not
    /// read.
    fn set_readout(&mut self, readout: &Readout) -> Result<RowSampling, Self::Error> {
        let _ = readout;
        Ok(RowSampling::WholeFrame)
    }
}

/// An image capture under way: the next band starts at `next_row`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct CaptureJob {
    seq: u16,
    mask: u8,
    next_row: u16,
}

/// Fixed facts about the head for `Hello`.
#[derive(Clone, Debug)]
pub struct Identity {
    /// Firmware version.
    pub firmware: &'static str,
    /// Board name.
    pub board: &'static str,
}

/// The head's logic. `W` is the longest row it can process.
pub struct Head<const W: usize, L: LaserDriver> {
    lasers: L,
    lit: u8,
    state: HeadState,
    fault: Option<ErrorCode>,
    detector: Detector<W>,
    start: Start,
    exposure_us: u32,
    calibration: Option<(Calibration, Triangulator)>,
    identity: Identity,
    last_heard_us: u64,
    next_frame_us: u64,
    next_status_us: u64,
    epoch_us: u64,
    frame_seq: u32,
    sequential_next: u8,
    capture: Option<CaptureJob>,
    track: [Px; LASERS],
    /// Search windows per laser (`SetWindows`), and those of the lit
    /// lasers for the current frame (`None`: full-row search).
    windows: [Option<ColumnWindow>; LASERS],
    frame_windows: Option<Windows>,
    /// Windows that follow their lines (`SetTracking`; `None`: off),
    /// reset at every frame.
    tracking: Option<Track>,
    /// The readout `SetReadout` asked for (`None`: every row), the one in
    /// force since `Start`, and the one last set on the camera with how the
    /// camera honours it.
    readout: Option<Readout>,
    frame_readout: Option<Readout>,
    camera_readout: Option<(Readout, RowSampling)>,
    // statistics since the last Status
    frames: u32,
    window_frames: u32,
    window_rows: u32,
    window_ns: u64,
    window_start_us: u64,
    dropped: u32,
    /// The part of `dropped` whose time passed before the head came to
    /// them (its processing or its camera slower than the rate).
    late: u32,
    window_on_us: u64,
    duty: DutyLimit,
    trigger: Trigger,
    distance: Option<DistanceTrigger>,
    cpu_hz: u32,
    link_backlog: u32,
    store: StoreHealth,
    store_dirty: bool,
    dropped_rows: u32,
    row: [u16; W],
    profile: Profile,
    /// The line pass's scratch, the part's second candidates, and what the
    /// pass found in the last frame.
    line: line::LineCheck,
    seconds: line::Seconds,
    line_counts: line::Counts,
}

impl<const W: usize, L: LaserDriver> Drop for Head<W, L> {
    fn drop(&mut self) {
        self.lasers.set(0);
    }
}

impl<const W: usize, L: LaserDriver> Head<W, L> {
    /// A head with the lasers off, idle, with a validated detector.
    pub fn new(mut lasers: L, detector: Config, identity: Identity) -> Result<Self, crate::peak::Error> {
        lasers.set(0);
        let detector = Detector::new(detector)?;
        Ok(Head {
            lasers,
            lit: 0,
            state: HeadState::Idle,
            fault: None,
            detector,
            start: Start { rate_hz: 10, laser_mask: 0b111, pattern: LaserPattern::Simultaneous },
            exposure_us: 200,
            calibration: None,
            identity,
            last_heard_us: 0,
            next_frame_us: 0,
            next_status_us: 0,
            epoch_us: 0,
            frame_seq: 0,
            sequential_next: 0,
            capture: None,
            track: [Px::ZERO; LASERS],
            windows: [None; LASERS],
            frame_windows: None,
            tracking: None,
            readout: None,
            frame_readout: None,
            camera_readout: None,
            frames: 0,
            window_frames: 0,
            window_rows: 0,
            window_ns: 0,
            window_start_us: 0,
            dropped: 0,
            late: 0,
            window_on_us: 0,
            duty: DutyLimit::default(),
            trigger: Trigger::Timed,
            distance: None,
            cpu_hz: 0,
            link_backlog: 0,
            store: StoreHealth::Volatile,
            store_dirty: false,
            dropped_rows: 0,
            row: [0; W],
            profile: Profile::empty(),
            line: line::LineCheck::default(),
            seconds: line::Seconds::new(),
            line_counts: line::Counts::default(),
        })
    }

    /// State.
    pub fn state(&self) -> HeadState {
        self.state
    }

    /// Frames dropped because their time passed before the head came to
    /// them — its processing, or its camera, slower than the rate: a part
    /// of `Status::dropped_frames` (the simulated head names it as its
    /// renderer's limit instead).
    pub fn late_frames(&self) -> u32 {
        self.late
    }

    /// Lasers currently lit.
    pub fn lasers_on(&self) -> u8 {
        self.lit
    }

    /// Validates and keeps a calibration (also how a head restores the one
    /// it stored before a restart). Points carry `metric` from then on.
    pub fn load_calibration(&mut self, c: Calibration) -> Result<(), CalibrationError> {
        let t = triangulator(&c)?;
        self.calibration = Some((c, t));
        Ok(())
    }

    /// The calibration in use.
    pub fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref().map(|c| &c.0)
    }

    /// The triangulator of the calibration in use.
    pub fn triangulator(&self) -> Option<&Triangulator> {
        self.calibration.as_ref().map(|c| &c.1)
    }

    /// What a head keeps across restarts.
    pub fn stored(&self) -> Stored {
        Stored {
            calibration: self.calibration.as_ref().map(|c| c.0),
            exposure_us: self.exposure_us,
            detector: *self.detector.config(),
            trigger: self.trigger,
        }
    }

    /// Restores what [`Head::stored`] gave before a restart. Settings that
    /// fail validation are not used: the head keeps its defaults for them,
    /// and a refused calibration makes the store health `Refused`.
    pub fn restore(&mut self, s: &Stored, health: StoreHealth) {
        self.store = health;
        if (EXPOSURE_RANGE_US.0..=EXPOSURE_RANGE_US.1).contains(&s.exposure_us) {
            self.exposure_us = s.exposure_us;
        }
        if let Ok(d) = Detector::new(s.detector) {
            self.detector = d;
        }
        if valid_trigger(s.trigger) {
            self.trigger = s.trigger;
        }
        if let Some(c) = s.calibration
            && self.load_calibration(c).is_err()
        {
            self.store = StoreHealth::Refused;
        }
    }

    /// Records what the head's flash held at start-up when nothing could be
    /// restored (`Missing`, `Corrupt`), for `Hello`.
    pub fn set_store_health(&mut self, health: StoreHealth) {
        self.store = health;
    }

    /// What should be written to flash now, if anything changed since the
    /// last call. Only asked for while idle (a flash erase stalls the bus).
    pub fn take_store_request(&mut self) -> Option<Stored> {
        if self.state == HeadState::Streaming || !self.store_dirty {
            return None;
        }
        self.store_dirty = false;
        Some(self.stored())
    }

    /// The core clock, Hz, so that `Status` gives cycles per row (the
    /// processing clock passed to [`Head::poll`] must then count ns of it).
    pub fn set_cpu_hz(&mut self, hz: u32) {
        self.cpu_hz = hz;
    }

    /// Bytes waiting to go out on the link (for `Status`).
    pub fn set_link_backlog(&mut self, bytes: u32) {
        self.link_backlog = bytes;
    }

    /// The duty-cycle limiter (for inspection).
    pub fn duty_limit(&self) -> &DutyLimit {
        &self.duty
    }

    /// What the line pass flagged in the last frame ([`mod@line`]): the
    /// counts its profiles' flags carry.
    pub fn line_counts(&self) -> line::Counts {
        self.line_counts
    }

    /// The laser driver (for inspection by tests and the simulator).
    pub fn laser_driver(&self) -> &L {
        &self.lasers
    }

    fn set_lasers(&mut self, mask: u8) {
        let mask = if self.state == HeadState::Streaming { mask } else { 0 };
        self.lit = mask;
        self.lasers.set(mask);
    }

    fn fail(&mut self, code: ErrorCode, seq: Option<u16>, reply: &mut impl FnMut(&DeviceMsg)) {
        let was_streaming = self.state == HeadState::Streaming;
        if was_streaming {
            self.state = HeadState::Fault;
            self.fault = Some(code);
        }
        self.set_lasers(0);
        reply(&DeviceMsg::Error { seq, code });
        if was_streaming {
            reply(&DeviceMsg::Status(self.status(self.last_heard_us)));
        }
    }

    /// The `Hello` message.
    pub fn info<C: Camera>(&self, camera: &C) -> DeviceInfo {
        let mut firmware = String::new();
        let _ = firmware.push_str(&self.identity.firmware[..self.identity.firmware.len().min(16)]);
        let mut board = String::new();
        let _ = board.push_str(&self.identity.board[..self.identity.board.len().min(24)]);
        DeviceInfo {
            firmware,
            protocol: PROTOCOL_VERSION,
            board,
            sensor_width: camera.width(),
            sensor_height: camera.height(),
            bits: camera.bits(),
            detector: *self.detector.config(),
            calibration_id: self.calibration.as_ref().map_or(0, |c| c.0.id),
            store: self.store,
        }
    }

    /// A framing error from the host's side of the link: reported, and while
    /// streaming it is a fault (lasers off).
    pub fn link_error(&mut self, code: ErrorCode, reply: &mut impl FnMut(&DeviceMsg)) {
        self.fail(code, None, reply);
    }

    /// The settings could not be written to flash (or the flash is not
    /// usable): reported as `Error { seq: None, code: Storage }` (only asked
    /// for while idle, so no fault). Built here at run time: a `&DeviceMsg`
    /// of constants written in the firmware is promoted to a static of the
    /// message's full size (about 40 KB of flash).
    pub fn storage_error(&mut self, reply: &mut impl FnMut(&DeviceMsg)) {
        self.fail(ErrorCode::Storage, None, reply);
    }

    /// Runs the head: the heartbeat watchdog, a due frame, a pending capture,
    /// a due status. `now_us` is the head's clock; `clock_ns` measures
    /// processing time.
    pub fn poll<C: Camera>(
        &mut self,
        now_us: u64,
        camera: &mut C,
        clock_ns: &mut impl FnMut() -> u64,
        reply: &mut impl FnMut(&DeviceMsg),
    ) {
        if self.state == HeadState::Streaming && now_us.saturating_sub(self.last_heard_us) > HEARTBEAT_TIMEOUT_US {
            return self.fail(ErrorCode::HeartbeatLost, None, reply);
        }
        if let Some(job) = self.capture.take() {
            self.capture_band(job, now_us, camera, reply);
        }
        let period = 1_000_000 / self.start.rate_hz as u64;
        if self.state == HeadState::Streaming
            && let Some(trigger) = self.distance.as_mut()
        {
            // Distance trigger: a frame per boundary crossed, no faster than
            // the rate; boundaries passed over (or too soon) are dropped.
            let fired = camera.odometer_um().and_then(|p| trigger.poll(p));
            if let Some(skipped) = fired {
                self.dropped = self.dropped.wrapping_add(skipped);
                if now_us >= self.next_frame_us {
                    self.next_frame_us = now_us + period;
                    self.frame(now_us, camera, clock_ns, reply);
                } else {
                    self.dropped = self.dropped.wrapping_add(1);
                }
            }
        } else if self.state == HeadState::Streaming && now_us >= self.next_frame_us {
            // Frames whose time has already passed are dropped, not queued.
            let late = (now_us - self.next_frame_us) / period;
            self.dropped = self.dropped.wrapping_add(late as u32);
            self.late = self.late.wrapping_add(late as u32);
            self.next_frame_us += (late + 1) * period;
            self.frame(now_us, camera, clock_ns, reply);
        }
        self.dropped_rows = camera.dropped_rows();
        if self.state == HeadState::Streaming && now_us >= self.next_status_us {
            self.next_status_us = now_us + STATUS_INTERVAL_US;
            reply(&DeviceMsg::Status(self.status(now_us)));
            self.window_start_us = now_us;
            self.window_frames = 0;
            self.window_rows = 0;
            self.window_ns = 0;
            self.window_on_us = 0;
        }
    }

    fn frame<C: Camera>(
        &mut self,
        now_us: u64,
        camera: &mut C,
        clock_ns: &mut impl FnMut() -> u64,
        reply: &mut impl FnMut(&DeviceMsg),
    ) {
        let mask = self.frame_lasers();
        // The rows this frame reads, set on the camera (lasers off) if they
        // are not the ones it has.
        let readout = self.frame_readout.unwrap_or(Readout::full(camera.height()));
        let Ok(sampling) = self.apply_readout(readout, camera) else {
            return self.fail(ErrorCode::SensorFault, None, reply);
        };
        if !self.duty.request(now_us, self.exposure_us) {
            // Over the duty-cycle limit: no strobe, no frame.
            self.dropped = self.dropped.wrapping_add(1);
            return;
        }
        // Strobe: lit for the exposure only, off before the rows are read.
        self.set_lasers(mask);
        let exposed = camera.expose(self.exposure_us, mask);
        self.set_lasers(0);
        self.window_on_us += self.exposure_us as u64;
        let odometer_um = match exposed {
            Ok(o) => o,
            Err(_) => return self.fail(ErrorCode::SensorFault, None, reply),
        };
        let width = camera.width() as usize;
        let height = readout.rows_read() as usize;
        let parts = height.div_ceil(MAX_ROWS_PER_PROFILE).clamp(1, 255) as u8;
        let mut next_sensor_row = 0u16;
        self.profile.seq = self.frame_seq;
        self.profile.parts = parts;
        self.profile.timestamp_us = now_us - self.epoch_us;
        self.profile.odometer_um = odometer_um;
        self.profile.exposure_us = self.exposure_us;
        self.profile.laser_mask = mask;
        let t0 = clock_ns();
        // A new frame (exposure and lasers may have changed): the detector
        // measures the noise afresh on its first row.
        self.detector.refresh_noise();
        // The lit lasers' windows, if every lit laser has one (validated by
        // SetWindows against this camera's width).
        let lit_windows: Option<Vec<ColumnWindow, LASERS>> =
            (0..LASERS).filter(|&k| mask & (1 << k) != 0).map(|k| self.windows[k]).collect();
        self.frame_windows = lit_windows.and_then(|w| Windows::new(&w, width as u16).ok());
        // The lines may have moved between frames (other lasers lit, a
        // new exposure): the first row screens every window.
        if let Some(t) = &mut self.tracking {
            t.reset();
        }
        for part in 0..parts {
            self.profile.part = part;
            self.profile.lasers.clear();
            for k in 0..LASERS as u8 {
                if mask & (1 << k) != 0 {
                    let _ = self.profile.lasers.push(LaserPoints { laser: k, points: Vec::new() });
                }
            }
            let first = part as usize * MAX_ROWS_PER_PROFILE;
            let last = (first + MAX_ROWS_PER_PROFILE).min(height);
            self.seconds.clear();
            if self.measure_rows(camera, (readout, sampling), first..last, &mut next_sensor_row).is_err() {
                return self.fail(ErrorCode::SensorFault, None, reply);
            }
            // The part's lines as a whole: what is not a line is flagged.
            let rules = line::Rules::new(self.detector.config(), self.calibration.as_ref().map(|c| &c.0));
            let counts = self.line.check(&rules, &mut self.profile.lasers, &self.seconds);
            self.line_counts = if part == 0 { counts } else { self.line_counts.plus(counts) };
            // Lend the profile to the message without copying it twice.
            let msg = DeviceMsg::Profile(core::mem::replace(&mut self.profile, Profile::empty()));
            reply(&msg);
            if let DeviceMsg::Profile(p) = msg {
                self.profile = p;
            }
        }
        let dt = clock_ns().saturating_sub(t0);
        self.frame_seq = self.frame_seq.wrapping_add(1);
        self.frames = self.frames.wrapping_add(1);
        self.window_frames = self.window_frames.wrapping_add(1);
        self.window_rows = self.window_rows.wrapping_add(height as u32);
        self.window_ns = self.window_ns.wrapping_add(dt);
    }

    /// The lasers a frame lights: every laser of the mask, or the next of
    /// them in turn.
    fn frame_lasers(&mut self) -> u8 {
        match self.start.pattern {
            LaserPattern::Simultaneous => self.start.laser_mask,
            LaserPattern::Sequential => {
                // The next laser of the mask, in turn.
                let mut k = self.sequential_next;
                while self.start.laser_mask & (1 << k) == 0 {
                    k = (k + 1) % LASERS as u8;
                }
                self.sequential_next = (k + 1) % LASERS as u8;
                1 << k
            }
        }
    }

    /// Reads the frame's rows `rows` (indices into the readout; the sensor
    /// row of the next one to read in `next_sensor_row`), finds their
    /// stripes and adds their points to the profile's lasers. `Err`: the
    /// camera or the detector failed (a sensor fault).
    fn measure_rows<C: Camera>(
        &mut self,
        camera: &mut C,
        (readout, sampling): (Readout, RowSampling),
        rows: core::ops::Range<usize>,
        next_sensor_row: &mut u16,
    ) -> Result<(), ()> {
        let width = camera.width() as usize;
        let lit = self.profile.laser_mask.count_ones() as usize;
        // A binned row is triangulated at its rows' centre; a whole-frame
        // camera's rows outside the readout are passed over unprocessed.
        let centre = if sampling == RowSampling::Bin { readout.bin_centre_q16() } else { Q16_16::ZERO };
        for i in rows {
            let r = readout.sensor_row(i as u16);
            if sampling == RowSampling::WholeFrame {
                while *next_sensor_row < r {
                    camera.read_row(&mut self.row[..width]).map_err(|_| ())?;
                    *next_sensor_row += 1;
                }
                *next_sensor_row += 1;
            }
            camera.read_row(&mut self.row[..width]).map_err(|_| ())?;
            let mut stripes: Stripes<LASERS> = Stripes::new();
            let found = match (&self.frame_windows, &mut self.tracking) {
                (None, _) => self.detector.detect(&self.row[..width], &mut stripes),
                (Some(w), None) => self.detector.detect_in(&self.row[..width], w, &mut stripes),
                (Some(w), Some(t)) => self.detector.detect_tracked(&self.row[..width], w, t, &mut stripes),
            };
            found.map_err(|_| ())?;
            assign(&stripes, lit, &mut self.track, &mut self.profile.lasers, r, &mut self.seconds);
            if let Some((_, t)) = &self.calibration {
                triangulate(t, &mut self.profile.lasers, &mut self.seconds, r, centre);
            }
        }
        Ok(())
    }

    /// One band of an image capture (the whole image for a camera that
    /// holds a frame): when the link buffer is empty (the previous band, or
    /// for the first band whatever streaming left in it, has gone out: a
    /// band is sized to fit an empty buffer, not a part-full one) and the
    /// duty limit allows the exposure, expose with the capture's lasers lit
    /// for the exposure only, then send the band's rows as `RawRows` chunks.
    /// Until then the job waits, lasers off, for a later poll; `Stop`
    /// cancels it. Only the first band fails on the duty limit (as a capture
    /// always did); later ones wait for it, as they wait for the link.
    fn capture_band<C: Camera>(
        &mut self,
        mut job: CaptureJob,
        now_us: u64,
        camera: &mut C,
        reply: &mut impl FnMut(&DeviceMsg),
    ) {
        let (width, height, bits) = (camera.width(), camera.height(), camera.bits());
        let first = job.next_row == 0;
        if self.link_backlog > 0 {
            self.capture = Some(job);
            return;
        }
        if job.mask != 0 && !self.duty.request(now_us, self.exposure_us) {
            if first {
                return self.fail(ErrorCode::OutOfRange, Some(job.seq), reply);
            }
            self.capture = Some(job);
            return;
        }
        // A capture is of every row, whatever the streaming readout.
        if self.apply_readout(Readout::full(height), camera).is_err() {
            return self.fail(ErrorCode::SensorFault, Some(job.seq), reply);
        }
        self.state = HeadState::Streaming;
        self.set_lasers(job.mask);
        let exposed = camera.expose(self.exposure_us, job.mask);
        self.state = HeadState::Idle;
        self.set_lasers(0);
        let rows = camera.capture_band_rows().clamp(1, height.max(1)).min(height.saturating_sub(job.next_row));
        if exposed.is_err() || camera.start_band(job.next_row, rows, &mut self.row[..width as usize]).is_err() {
            return self.fail(ErrorCode::SensorFault, Some(job.seq), reply);
        }
        let bpp = if bits > 8 { 2 } else { 1 };
        for r in job.next_row..job.next_row + rows {
            if camera.read_row(&mut self.row[..width as usize]).is_err() {
                return self.fail(ErrorCode::SensorFault, Some(job.seq), reply);
            }
            let seq = job.seq;
            let mut chunk =
                RawRows { capture: seq, first_row: r, offset_bytes: 0, width, height, bits, data: Vec::new() };
            for (i, &p) in self.row[..width as usize].iter().enumerate() {
                if chunk.data.len() + bpp > RAW_CHUNK_BYTES {
                    let next = (i * bpp) as u32;
                    let full = core::mem::replace(
                        &mut chunk,
                        RawRows {
                            capture: seq,
                            first_row: r,
                            offset_bytes: next,
                            width,
                            height,
                            bits,
                            data: Vec::new(),
                        },
                    );
                    reply(&DeviceMsg::RawRows(full));
                }
                if bpp == 2 {
                    let _ = chunk.data.extend_from_slice(&p.to_le_bytes());
                } else {
                    let _ = chunk.data.push(p as u8);
                }
            }
            reply(&DeviceMsg::RawRows(chunk));
        }
        job.next_row += rows;
        if job.next_row < height {
            self.capture = Some(job);
        }
    }

    /// Sets `readout` on the camera unless it is the one it has (called
    /// with the lasers off, before an exposure).
    fn apply_readout<C: Camera>(&mut self, readout: Readout, camera: &mut C) -> Result<RowSampling, C::Error> {
        if let Some((r, s)) = self.camera_readout
            && r == readout
        {
            return Ok(s);
        }
        self.camera_readout = None;
        let s = camera.set_readout(&readout)?;
        self.camera_readout = Some((readout, s));
        Ok(s)
    }

    /// The readout in force while streaming (every row unless `SetReadout`
    /// said otherwise before the `Start`).
    pub fn streaming_readout(&self) -> Option<Readout> {
        self.frame_readout
    }

    /// The current status.
    pub fn status(&self, now_us: u64) -> Status {
        let span_us = now_us.saturating_sub(self.window_start_us).max(1);
        let ns_per_row = self.window_ns / self.window_rows.max(1) as u64;
        let streaming = self.state == HeadState::Streaming;
        Status {
            state: self.state,
            lasers_on: if streaming { self.start.laser_mask } else { 0 },
            frames: self.frames,
            frame_rate_millihz: ((self.window_frames as u64 * 1_000_000_000) / span_us) as u32,
            rows_per_s: ((self.window_rows as u64 * 1_000_000) / span_us) as u32,
            dropped_frames: self.dropped,
            ns_per_row: ns_per_row.min(u32::MAX as u64) as u32,
            cycles_per_row: (ns_per_row * self.cpu_hz as u64 / 1_000_000_000).min(u32::MAX as u64) as u32,
            dropped_rows: self.dropped_rows,
            link_backlog_bytes: self.link_backlog,
            laser_duty_permille: (self.window_on_us * 1000 / span_us).min(1000) as u16,
            heartbeat_age_ms: (now_us.saturating_sub(self.last_heard_us) / 1000) as u32,
            fault: self.fault,
        }
    }
}

/// A trigger the head accepts: a distance trigger needs a non-zero interval.
fn valid_trigger(t: Trigger) -> bool {
    !matches!(t, Trigger::Distance { every_um: 0 })
}

/// The detector configuration a head starts with: 12-bit pixels, stripes
/// σ 1.5–4 px, the three strongest.
pub fn default_detector() -> Config {
    let scales = crate::optics::ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).expect("constant range is valid");
    let mut c = Config::new(12, scales);
    c.max_stripes = LASERS as u8;
    c.select = Select::Strongest;
    c
}
