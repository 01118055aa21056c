//! The simulated head's server: a pseudo-terminal, the wire protocol, and
//! `cms_core::pipeline::Head` paced in real time.
//!
//! The head's thread runs the loop a firmware's main loop would: read the
//! host's bytes from the pty master, decode commands, let the head handle
//! them, poll the head (it decides when a frame is due from the `Start`
//! rate and the clock) and encode its replies. A writer thread writes them
//! to the master (as a USB peripheral's DMA would, while the next frame is
//! processed); the renderer may have a thread of its own (see `worker`).
//!
//! # Back-pressure
//! The head never blocks on the link. Replies wait in a bounded queue; when
//! nobody reads the slave and the pty's buffer is full, new `Profile`
//! frames are dropped whole (counted in [`ServeSummary::link_dropped_profiles`])
//! rather than stalling the head: the head's watchdog and command handling
//! keep running. Small messages (acks, errors, status) have a larger
//! allowance so a slow reader still sees every answer.

use super::stored;
use std::fs::File;
use std::io::{self, Read as _, Write as _};
use std::os::fd::AsFd as _;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use cms_core::pipeline::{Camera, Head, Identity, LaserDriver};
use cms_core::protocol::{
    Command, DeviceMsg, ErrorCode, FrameReader, HeadState, HostMsg, MAX_COMMAND_FRAME, MAX_FRAME, MAX_ROWS_PER_PROFILE,
    WireError, encode,
};
use cms_core::readout::{Readout, RowSampling};
use nix::poll::{PollFd, PollFlags, PollTimeout};

use super::SimulateError;
use crate::sim::pty::Pty;

/// Longest row the simulated head accepts (the `paper` preset is 4752 px).
pub const MAX_WIDTH: usize = 4800;

/// The identity the simulated head reports in `Hello`.
pub const IDENTITY: Identity = Identity { firmware: env!("CARGO_PKG_VERSION"), board: "cms-sim" };

/// Where the simulated camera's pixels come from: the scene model, or a
/// test pattern.
pub trait RowRenderer {
    /// Image width and height, px.
    fn size(&self) -> (u16, u16);
    /// Bits per pixel.
    fn bits(&self) -> u8;
    /// Starts frame `frame` (0, 1, 2, … in exposure order), exposed
    /// `t_us` after the head started, for `exposure_us`, with the lasers of
    /// `mask` lit. Returns the odometer at exposure, µm.
    fn begin_frame(&mut self, frame: u64, t_us: u64, exposure_us: u32, mask: u8) -> i64;
    /// Row `r` of the current frame into `out` (`width` pixels).
    fn row(&mut self, r: u16, out: &mut [u16]);
    /// The rows frames from the next one on will be asked for, in order
    /// (a renderer that renders ahead renders only these). Default: rows
    /// are rendered when asked for.
    fn set_readout(&mut self, readout: &Readout) {
        let _ = readout;
    }
    /// CPU time spent on threads of its own (zero if it renders on the caller's).
    fn cpu(&self) -> Duration {
        Duration::ZERO
    }
}

/// The most trolley time between two exposures, in frame periods
/// (`NUM / DEN` = 1.5): a head that keeps its rate is never held (its
/// exposures jitter within half a period), one the renderer holds back
/// moves 1.5 periods of travel a frame.
pub const HELD_PERIODS: f64 = HELD_PERIODS_NUM as f64 / HELD_PERIODS_DEN as f64;
const HELD_PERIODS_NUM: u64 = 3;
const HELD_PERIODS_DEN: u64 = 2;

/// The simulated camera: a [`RowRenderer`] behind `cms_core`'s [`Camera`].
///
/// It reads what the real sensor would: the rows of its readout
/// ([`Camera::set_readout`]), skipping the others (it renders only those),
/// so a frame is the subset of a full frame's rows the readout names.
pub struct SimCamera<R> {
    renderer: R,
    start: Instant,
    frame: u64,
    readout: Readout,
    /// The next output row of the exposed frame (an index into `readout`).
    next_row: Option<u16>,
    /// The streaming frame period, µs (`None`: not started).
    period_us: Option<u64>,
    /// Real and trolley time at the last exposure, µs.
    clock: Option<(u64, u64)>,
    /// Real time the trolley waited for the renderer, µs.
    held_us: u64,
}

/// A row was asked for while no frame was exposed, or past the last row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NoFrame;

impl<R: RowRenderer> SimCamera<R> {
    /// A camera whose clock (the odometer's time base) starts at `start`.
    pub fn new(renderer: R, start: Instant) -> Self {
        let readout = Readout::full(renderer.size().1);
        SimCamera { renderer, start, frame: 0, readout, next_row: None, period_us: None, clock: None, held_us: 0 }
    }

    /// The host started streaming at `rate_hz`. A real trolley moves while
    /// its camera films at that rate; a simulated one whose frames take
    /// longer to render than a period would move past them unfilmed and
    /// leave gaps a real head never has, so the trolley's clock advances at
    /// most [`HELD_PERIODS`] periods between two exposures: it waits for the
    /// renderer, and its frames overlap as the asked speed and rate make
    /// them.
    pub fn streaming_at(&mut self, rate_hz: u16) {
        self.period_us = (rate_hz > 0).then(|| 1_000_000 / u64::from(rate_hz));
    }

    /// Real time the trolley waited for the renderer.
    pub fn held(&self) -> Duration {
        Duration::from_micros(self.held_us)
    }

    /// The trolley's clock at an exposure at real time `real_us`.
    fn trolley_us(&mut self, real_us: u64) -> u64 {
        let t = match self.clock {
            None => real_us,
            Some((r0, t0)) => {
                let dt = real_us.saturating_sub(r0);
                let step = self.period_us.map_or(dt, |p| dt.min(p * HELD_PERIODS_NUM / HELD_PERIODS_DEN));
                self.held_us += dt - step;
                t0 + step
            }
        };
        self.clock = Some((real_us, t));
        t
    }

    /// Frames exposed so far.
    pub fn frames(&self) -> u64 {
        self.frame
    }

    /// The renderer.
    pub fn renderer(&self) -> &R {
        &self.renderer
    }
}

impl<R: RowRenderer> Camera for SimCamera<R> {
    type Error = NoFrame;
    fn width(&self) -> u16 {
        self.renderer.size().0
    }
    fn height(&self) -> u16 {
        self.renderer.size().1
    }
    fn bits(&self) -> u8 {
        self.renderer.bits()
    }
    fn expose(&mut self, exposure_us: u32, laser_mask: u8) -> Result<i64, NoFrame> {
        let real_us = self.start.elapsed().as_micros() as u64;
        let t_us = self.trolley_us(real_us);
        let odometer = self.renderer.begin_frame(self.frame, t_us, exposure_us, laser_mask);
        self.frame += 1;
        self.next_row = Some(0);
        Ok(odometer)
    }
    fn read_row(&mut self, row: &mut [u16]) -> Result<(), NoFrame> {
        let i = self.next_row.ok_or(NoFrame)?;
        if i >= self.readout.rows_read() {
            self.next_row = None;
            return Err(NoFrame);
        }
        self.renderer.row(self.readout.sensor_row(i), row);
        self.next_row = Some(i + 1);
        Ok(())
    }
    fn set_readout(&mut self, readout: &Readout) -> Result<RowSampling, NoFrame> {
        if readout.end_row() > self.height() {
            return Err(NoFrame);
        }
        self.readout = *readout;
        self.renderer.set_readout(readout);
        Ok(RowSampling::Skip)
    }
}

/// The simulated laser enables: they remember the mask (the head is the
/// only caller, and it applies the safety rules).
#[derive(Debug, Default)]
pub struct SimLasers {
    mask: u8,
    lit_since_take: std::cell::Cell<u8>,
    switches: u64,
}

impl SimLasers {
    /// Lasers lit now.
    pub fn mask(&self) -> u8 {
        self.mask
    }
    /// Number of changes of the mask.
    pub fn switches(&self) -> u64 {
        self.switches
    }
    /// Every laser lit at some point since the previous call.
    fn take_lit(&self) -> u8 {
        self.lit_since_take.replace(self.mask)
    }
}

impl LaserDriver for SimLasers {
    fn set(&mut self, mask: u8) {
        if mask != self.mask {
            self.switches += 1;
        }
        self.mask = mask;
        self.lit_since_take.set(self.lit_since_take.get() | mask);
    }
}

/// How the server behaves.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Log laser on/off changes to stderr.
    pub log_lasers: bool,
    /// Bytes of `Profile` frames that may wait for the reader before new
    /// ones are dropped (small messages get four times as much).
    pub queue_bytes: usize,
    /// The camera's highest frame rate: a `Start` asking for more is refused
    /// by the head (`OutOfRange`).
    pub max_rate_hz: u16,
    /// Exposure the head starts with (the camera's nominal one), µs; `None`
    /// keeps the head's default.
    pub exposure_us: Option<u32>,
    /// Where the head keeps its calibration across restarts (the real
    /// head's flash); `None`: it forgets it.
    pub calibration_file: Option<std::path::PathBuf>,
    /// The calibration the head left the factory with: loaded when none
    /// is kept (or the kept one is unusable).
    pub factory_calibration: Option<cms_core::protocol::Calibration>,
}

impl Default for ServeOptions {
    fn default() -> Self {
        ServeOptions {
            log_lasers: true,
            queue_bytes: 2 * MAX_FRAME,
            max_rate_hz: 1000,
            exposure_us: None,
            calibration_file: None,
            factory_calibration: None,
        }
    }
}

/// What a server did, for the closing line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ServeSummary {
    /// Wall time served.
    pub elapsed: Duration,
    /// CPU time of the serving thread (commands, detection, framing, pty).
    pub cpu: Duration,
    /// CPU time of the renderer's own thread.
    pub render_cpu: Duration,
    /// Frames the head produced (`Status::frames`).
    pub frames: u64,
    /// Frames the head dropped as a head would (the laser duty limit): its
    /// `Status::dropped_frames` as sent, without [`ServeSummary::sim_late`].
    pub head_dropped: u64,
    /// Frames whose time passed while the simulator was still rendering and
    /// detecting the one before: the simulator's limit on this computer,
    /// not the head's: left out of the `Status` it sends.
    pub sim_late: u64,
    /// The rate the host's last `Start` asked for, Hz (0: never started).
    pub asked_rate_hz: u16,
    /// `Profile` messages queued for the link.
    pub profiles_sent: u64,
    /// `Profile` messages dropped because nobody read the pty.
    pub link_dropped_profiles: u64,
    /// Other messages dropped for the same reason.
    pub link_dropped_other: u64,
    /// Bytes written to the pty.
    pub bytes_written: u64,
    /// Commands decoded.
    pub commands: u64,
    /// Host frames that failed to decode (CRC, COBS, version, payload, overflow).
    pub link_errors: u64,
    /// Lasers lit when the server stopped (before the head was dropped).
    pub lasers_at_exit: u8,
    /// Real time the trolley waited for the renderer ([`SimCamera::streaming_at`]).
    pub trolley_held: Duration,
}

impl ServeSummary {
    /// CPU time per produced frame, every thread of the head.
    pub fn cpu_per_frame(&self) -> Duration {
        (self.cpu + self.render_cpu) / (self.frames.max(1) as u32)
    }
}

impl std::fmt::Display for ServeSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let secs = self.elapsed.as_secs_f64();
        let limit = if self.sim_late > 0 {
            format!(
                ", {} frame times passed while rendering (the simulator's limit at {} frames/s asked, not the head's)",
                self.sim_late, self.asked_rate_hz
            )
        } else {
            String::new()
        };
        write!(
            f,
            "served {:.1} s: {} frames ({:.1}/s){limit}, {} dropped by the head, {} profiles dropped on the link, \
             {} commands, {} bad host frames, {:.1} MB sent, CPU {:.2} ms/frame (head {:.2} + render {:.2}); \
             trolley held {:.1} s for the renderer; lasers off",
            secs,
            self.frames,
            self.frames as f64 / secs.max(1e-9),
            self.head_dropped,
            self.link_dropped_profiles,
            self.commands,
            self.link_errors,
            self.bytes_written as f64 / 1e6,
            self.cpu_per_frame().as_secs_f64() * 1e3,
            self.cpu.as_secs_f64() * 1e3 / self.frames.max(1) as f64,
            self.render_cpu.as_secs_f64() * 1e3 / self.frames.max(1) as f64,
            self.trolley_held.as_secs_f64(),
        )
    }
}

/// State shared by the head's thread and the pty writer.
#[derive(Default)]
struct LinkShared {
    /// Bytes handed to the writer and not yet written.
    queued: AtomicUsize,
    /// Bytes written to the pty.
    written: AtomicU64,
    /// The server is stopping: give up on a pty nobody reads.
    closing: AtomicBool,
    /// Why the writer stopped, if it failed.
    error: Mutex<Option<io::Error>>,
}

/// Encodes replies and hands them to the writer thread, which writes them
/// to the pty while the head goes on with the next frame (written between
/// frames only, a pty of a few tens of KB would cap the link at one
/// buffer-full per frame).
struct PtyOutbox {
    frame: Vec<u8>,
    tx: Option<mpsc::Sender<Vec<u8>>>,
    shared: Arc<LinkShared>,
    writer: Option<std::thread::JoinHandle<()>>,
    cap: usize,
    profiles_sent: u64,
    dropped_profiles: u64,
    dropped_other: u64,
}

impl PtyOutbox {
    fn new(master: &File, cap: usize) -> Result<Self, SimulateError> {
        let file = master.try_clone().map_err(|e| SimulateError::Io("duplicating the pty master", e))?;
        let shared = Arc::new(LinkShared::default());
        let (tx, rx) = mpsc::channel();
        let sh = shared.clone();
        let writer = std::thread::Builder::new()
            .name("cms-sim-write".into())
            .spawn(move || write_loop(file, rx, &sh))
            .map_err(|e| SimulateError::Io("starting the pty writer", e))?;
        Ok(PtyOutbox {
            frame: vec![0; MAX_FRAME],
            tx: Some(tx),
            shared,
            writer: Some(writer),
            cap,
            profiles_sent: 0,
            dropped_profiles: 0,
            dropped_other: 0,
        })
    }

    fn push(&mut self, msg: &DeviceMsg) {
        let profile = matches!(msg, DeviceMsg::Profile(_));
        let Ok(bytes) = encode(msg, &mut self.frame) else {
            // Cannot happen: MAX_FRAME bounds every message (core's test).
            self.dropped_other += 1;
            return;
        };
        let cap = if profile { self.cap } else { 4 * self.cap };
        // An image capture answers an explicit command and is larger than
        // the queue (a 12-bit frame is 0.7 MB): its chunks wait for the
        // reader (up to 5 s of no progress) instead of being dropped.
        if matches!(msg, DeviceMsg::RawRows(_)) {
            let mut last = self.shared.queued.load(Ordering::Acquire);
            let mut since = std::time::Instant::now();
            while self.shared.queued.load(Ordering::Acquire) + bytes.len() > cap
                && since.elapsed() < std::time::Duration::from_secs(5)
                && self.shared.error.lock().is_ok_and(|e| e.is_none())
            {
                std::thread::sleep(std::time::Duration::from_millis(1));
                let now = self.shared.queued.load(Ordering::Acquire);
                if now < last {
                    since = std::time::Instant::now();
                }
                last = now;
            }
        }
        let queued = self.shared.queued.load(Ordering::Acquire);
        let sent = queued + bytes.len() <= cap
            && self.tx.as_ref().is_some_and(|tx| {
                self.shared.queued.fetch_add(bytes.len(), Ordering::AcqRel);
                tx.send(bytes.to_vec()).is_ok()
            });
        match (sent, profile) {
            (true, true) => self.profiles_sent += 1,
            (true, false) => {}
            (false, true) => self.dropped_profiles += 1,
            (false, false) => self.dropped_other += 1,
        }
    }

    /// Why the writer failed, if it did.
    fn failed(&self) -> Option<io::Error> {
        self.shared.error.lock().ok()?.take()
    }

    /// Lets the writer finish what the pty takes within a moment, then stops it.
    fn close(&mut self) -> u64 {
        self.shared.closing.store(true, Ordering::Release);
        self.tx = None;
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
        self.shared.written.load(Ordering::Acquire)
    }
}

impl Drop for PtyOutbox {
    fn drop(&mut self) {
        self.close();
    }
}

/// The writer thread: every frame whole and in order, waiting for the pty
/// to drain (non-blocking writes + poll, so that it can give up when the
/// server stops and nobody reads).
fn write_loop(mut file: File, rx: mpsc::Receiver<Vec<u8>>, shared: &LinkShared) {
    const GIVE_UP: Duration = Duration::from_millis(200);
    let mut closing_since: Option<Instant> = None;
    while let Ok(buf) = rx.recv() {
        let mut off = 0;
        while off < buf.len() {
            if shared.closing.load(Ordering::Acquire)
                && closing_since.get_or_insert_with(Instant::now).elapsed() > GIVE_UP
            {
                return;
            }
            match file.write(&buf[off..]) {
                Ok(n) => {
                    off += n;
                    shared.written.fetch_add(n as u64, Ordering::AcqRel);
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                // Full (or, EIO, no slave open: cannot happen while the
                // server holds one): wait for room.
                Err(e) if e.kind() == io::ErrorKind::WouldBlock || e.raw_os_error() == Some(nix::libc::EIO) => {
                    let mut fds = [PollFd::new(file.as_fd(), PollFlags::POLLOUT)];
                    let _ = nix::poll::poll(&mut fds, PollTimeout::from(20u16));
                    if fds[0].revents().is_some_and(|r| r.intersects(PollFlags::POLLHUP | PollFlags::POLLERR)) {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                }
                Err(e) => {
                    if let Ok(mut slot) = shared.error.lock() {
                        *slot = Some(e);
                    }
                    return;
                }
            }
        }
        shared.queued.fetch_sub(buf.len(), Ordering::AcqRel);
    }
}

/// The head's `Status` as the simulated head sends it. The frames the head
/// was late for ([`Head::late_frames`]) are the simulator's: this computer
/// rendering and detecting slower than the rate (the server never waits
/// for the link), not a head's processing — the simulated camera runs at
/// the rate the simulator sustains. They leave `dropped_frames` (which
/// keeps what a real head drops), the host names the rate it sees as the
/// simulator's, and the `sim:` line counts them ([`ServeSummary::sim_late`]).
fn sim_status(s: &cms_core::protocol::Status, late: u32) -> DeviceMsg {
    DeviceMsg::Status(cms_core::protocol::Status { dropped_frames: s.dropped_frames.wrapping_sub(late), ..*s })
}

/// Pushes the head's replies, its `Status` as [`sim_status`] makes it.
fn push_reply(out: &mut PtyOutbox, m: &DeviceMsg, late: u32) {
    match m {
        DeviceMsg::Status(s) => out.push(&sim_status(s, late)),
        m => out.push(m),
    }
}

fn wire_to_code(e: WireError) -> ErrorCode {
    match e {
        WireError::Crc => ErrorCode::Crc,
        WireError::Version(v) => ErrorCode::Version(v),
        _ => ErrorCode::Decode,
    }
}

pub(super) fn thread_cpu() -> Duration {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID).map(Duration::from).unwrap_or_default()
}

fn log(msg: std::fmt::Arguments) {
    // Not eprintln!: it panics when stderr is closed.
    let _ = writeln!(io::stderr(), "info: {msg}");
}

/// Serves the protocol on `pty` until `stop` is set: the simulated head's
/// main loop (see the module documentation).
pub fn serve<R: RowRenderer>(
    mut pty: Pty,
    renderer: R,
    detector: cms_core::peak::Config,
    stop: &AtomicBool,
    opts: &ServeOptions,
) -> Result<ServeSummary, SimulateError> {
    let start = Instant::now();
    let cpu0 = thread_cpu();
    let mut camera = SimCamera::new(renderer, start);
    if camera.width() as usize > MAX_WIDTH {
        return Err(SimulateError::Usage(format!(
            "image width {} px exceeds the simulated head's {MAX_WIDTH} px",
            camera.width()
        )));
    }
    let mut head: Box<Head<MAX_WIDTH, SimLasers>> = Box::new(
        Head::new(SimLasers::default(), detector, IDENTITY)
            .map_err(|e| SimulateError::Usage(format!("detector configuration: {e}")))?,
    );
    if let Some(us) = opts.exposure_us {
        // The head has no exposure setting but the command's: give it the
        // camera's nominal exposure as a host would (the Ack goes nowhere).
        head.handle(Command { seq: 0, msg: HostMsg::SetExposure { exposure_us: us } }, 0, &camera, &mut |_| {});
    }
    restore_calibration(&mut head, opts);
    // A tall sensor sends a frame in several parts: room for all of them.
    let parts = (camera.height() as usize).div_ceil(MAX_ROWS_PER_PROFILE).max(1);
    let mut out = PtyOutbox::new(&pty.master, opts.queue_bytes.max(MAX_FRAME) * parts)?;
    let mut reader: Box<FrameReader<MAX_COMMAND_FRAME>> = Box::default();
    let mut rx = vec![0u8; 4096];
    let mut decoded: Vec<Result<Command, WireError>> = Vec::new();
    let mut clock_ns = || start.elapsed().as_nanos() as u64;
    let (mut lit_acc, mut logged) = (0u8, 0u8);
    let mut summary = ServeSummary::default();

    while !stop.load(Ordering::Relaxed) {
        // Host → head.
        read_commands(&mut pty, &mut reader, &mut rx, &mut decoded)?;
        let now_us = start.elapsed().as_micros() as u64;
        for r in decoded.drain(..) {
            if let Ok(Command { msg: HostMsg::Start(st), .. }) = &r {
                camera.streaming_at(st.rate_hz);
                summary.asked_rate_hz = st.rate_hz;
            }
            handle_command(&mut head, r, now_us, &camera, &mut out, opts, &mut summary);
        }
        // The head: watchdog, due frame, status (sent once the frames it
        // was late for in this turn are known).
        let mut status = None;
        head.poll(now_us, &mut camera, &mut clock_ns, &mut |m| match m {
            DeviceMsg::Status(s) => status = Some(*s),
            m => out.push(m),
        });
        if let Some(s) = status {
            out.push(&sim_status(&s, head.late_frames()));
        }

        // The simulated lasers' log: the set lit while streaming, then off.
        let lit = head.laser_driver().take_lit();
        if head.state() == HeadState::Streaming {
            lit_acc |= lit;
            if lit_acc != logged && opts.log_lasers {
                log(format_args!("lasers: {lit_acc:#05b}"));
            }
            logged = lit_acc;
        } else {
            debug_assert_eq!(head.lasers_on(), 0, "lasers lit while not streaming");
            if logged != 0 && opts.log_lasers {
                log(format_args!("lasers off"));
            }
            (lit_acc, logged) = (0, 0);
        }

        if let Some(e) = out.failed() {
            return Err(SimulateError::Io("writing the pty", e));
        }

        wait_for_host(&pty, head.state() == HeadState::Streaming)?;
    }

    let now_us = start.elapsed().as_micros() as u64;
    let status = head.status(now_us);
    summary.elapsed = start.elapsed();
    summary.cpu = thread_cpu().saturating_sub(cpu0);
    summary.frames = status.frames as u64;
    summary.sim_late = u64::from(head.late_frames());
    summary.head_dropped = u64::from(status.dropped_frames.wrapping_sub(head.late_frames()));
    summary.profiles_sent = out.profiles_sent;
    summary.link_dropped_profiles = out.dropped_profiles;
    summary.link_dropped_other = out.dropped_other;
    summary.lasers_at_exit = head.lasers_on();
    summary.render_cpu = camera.renderer().cpu();
    summary.trolley_held = camera.held();
    drop(head); // lasers off (the head's Drop)
    if logged != 0 && opts.log_lasers {
        log(format_args!("lasers off"));
    }
    // Best effort: the last replies (a Stop's ack) if the pty takes them.
    summary.bytes_written = out.close();
    Ok(summary)
}

/// The calibration kept in the state file, else the factory one.
fn restore_calibration(head: &mut Head<MAX_WIDTH, SimLasers>, opts: &ServeOptions) {
    let mut kept = false;
    if let Some(path) = &opts.calibration_file {
        match stored::load(path) {
            Ok(Some(c)) => match head.load_calibration(c) {
                Ok(()) => {
                    kept = true;
                    log(format_args!("calibration {:#010x} restored from {}", c.id, path.display()));
                }
                Err(e) => log(format_args!("stored calibration in {} not used: {e}", path.display())),
            },
            Ok(None) => {}
            Err(e) => log(format_args!("stored calibration not used: {e}")),
        }
    }
    if !kept && let Some(c) = opts.factory_calibration {
        match head.load_calibration(c) {
            Ok(()) => log(format_args!("factory calibration {:#010x} loaded", c.id)),
            Err(e) => log(format_args!("factory calibration not used: {e}")),
        }
    }
}

/// Whatever the host has written, decoded into `decoded`.
fn read_commands(
    pty: &mut Pty,
    reader: &mut FrameReader<MAX_COMMAND_FRAME>,
    rx: &mut [u8],
    decoded: &mut Vec<Result<Command, WireError>>,
) -> Result<(), SimulateError> {
    loop {
        match pty.master.read(rx) {
            Ok(0) => break,
            Ok(n) => {
                reader.feed::<Command, _>(&rx[..n], |r| decoded.push(r));
                if n < rx.len() {
                    break;
                }
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
            Err(e) if e.raw_os_error() == Some(nix::libc::EIO) => break,
            Err(e) => return Err(SimulateError::Io("reading the pty", e)),
        }
    }
    Ok(())
}

/// One decoded command handled by the head (a start faster than the
/// camera refused as out of range), the calibration kept when it changes;
/// or the link error it was.
fn handle_command<R: RowRenderer>(
    head: &mut Head<MAX_WIDTH, SimLasers>,
    r: Result<Command, WireError>,
    now_us: u64,
    camera: &SimCamera<R>,
    out: &mut PtyOutbox,
    opts: &ServeOptions,
    summary: &mut ServeSummary,
) {
    match r {
        Ok(mut cmd) => {
            summary.commands += 1;
            if let HostMsg::Start(s) = &mut cmd.msg
                && s.rate_hz > opts.max_rate_hz
            {
                // Faster than the camera: let the head refuse it
                // (and apply its fault rules) as out of range.
                s.rate_hz = 0;
            }
            let kept = head.calibration().copied();
            // An upload is kept even when it equals the factory calibration.
            let upload = matches!(cmd.msg, HostMsg::SetCalibration(_));
            let late = head.late_frames();
            head.handle(cmd, now_us, camera, &mut |m| push_reply(out, m, late));
            if let (Some(path), Some(c)) = (&opts.calibration_file, head.calibration())
                && (upload || Some(*c) != kept)
                && let Err(e) = stored::save(path, c)
            {
                log(format_args!("keeping the calibration: {e}"));
            }
        }
        Err(e) => {
            summary.link_errors += 1;
            let late = head.late_frames();
            head.link_error(wire_to_code(e), &mut |m| push_reply(out, m, late));
        }
    }
}

/// Sleeps until the host writes or the next tick: 1 ms while streaming
/// (frame times are the head's business), 20 ms idle.
fn wait_for_host(pty: &Pty, streaming: bool) -> Result<(), SimulateError> {
    let tick: u16 = if streaming { 1 } else { 20 };
    let mut fds = [PollFd::new(pty.master.as_fd(), PollFlags::POLLIN)];
    match nix::poll::poll(&mut fds, PollTimeout::from(tick)) {
        Ok(_) | Err(nix::Error::EINTR) => {}
        Err(e) => return Err(SimulateError::Io("poll on the pty", e.into())),
    }
    // A hung-up or failing master would make poll return at once: pace it.
    if fds[0].revents().is_some_and(|r| r.intersects(PollFlags::POLLHUP | PollFlags::POLLERR)) {
        std::thread::sleep(Duration::from_millis(tick as u64));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A renderer of dark rows whose odometer is its trolley time (µm per µs).
    struct Dark;

    impl RowRenderer for Dark {
        fn size(&self) -> (u16, u16) {
            (8, 4)
        }
        fn bits(&self) -> u8 {
            10
        }
        fn begin_frame(&mut self, _frame: u64, t_us: u64, _exposure_us: u32, _mask: u8) -> i64 {
            t_us as i64
        }
        fn row(&mut self, _r: u16, out: &mut [u16]) {
            out.fill(0);
        }
    }

    /// A head that keeps its rate is never held; one the renderer holds
    /// back moves at most 1.5 periods of travel a frame, and the wait is
    /// counted. Before streaming starts the clock is real time.
    #[test]
    fn the_trolley_waits_for_the_renderer() {
        let mut c = SimCamera::new(Dark, Instant::now());
        assert_eq!((c.trolley_us(0), c.trolley_us(500_000)), (0, 500_000));
        c.streaming_at(30);
        let p = 33_333;
        let mut real = 500_000;
        for jitter in [0, 10_000, -10_000, 16_000] {
            let t0 = c.clock.unwrap().1;
            real = (real as i64 + p as i64 + jitter) as u64;
            assert_eq!(c.trolley_us(real) - t0, (p as i64 + jitter) as u64);
        }
        assert_eq!(c.held(), Duration::ZERO);
        let t0 = c.clock.unwrap().1;
        assert_eq!(c.trolley_us(real + 300_000) - t0, p * 3 / 2);
        assert_eq!(c.held(), Duration::from_micros(300_000 - p * 3 / 2));
        c.streaming_at(0);
        let t0 = c.clock.unwrap().1;
        assert_eq!(c.trolley_us(real + 400_000) - t0, 100_000);
    }
}
