//! The test device: `cms_core::pipeline::Head` with a camera of Gaussian
//! stripes on the master side of a pty, its frames through an injector.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, mpsc};
use std::thread;
use std::time::{Duration, Instant};

use cms_core::pipeline::{Camera, Head, Identity, LaserDriver, default_detector};
use cms_core::protocol::{
    Command, DeviceMsg, ErrorCode, FrameReader, HeadState, HostMsg, MAX_COMMAND_FRAME, MAX_FRAME, WireError, encode,
};
use cms_study::{Gauss, Rng, clean_row, quantise};

/// Widest row of the test head.
pub(super) const W: usize = 752;

/// Rows of three Gaussian stripes, precomputed (a few noisy frames, cycled).
pub(super) struct TestCamera {
    pub(super) width: u16,
    pub(super) height: u16,
    pub(super) rows: Vec<Vec<u16>>,
    pub(super) next: usize,
    pub(super) odometer_um: i64,
}

impl TestCamera {
    pub(super) fn new(width: u16, height: u16, frames: usize, seed: u64) -> TestCamera {
        let mut rng = Rng::new(seed);
        let w = width as f64;
        let mut rows = Vec::new();
        for f in 0..frames {
            for r in 0..height {
                // A little corrugation: the stripes wander along the rows.
                let d = 3.0 * ((r as f64 + 40.0 * f as f64) * 0.07).sin();
                let stripes = [
                    Gauss { x0: w * 0.25 + d, sigma: 2.5, amplitude: 1500.0 },
                    Gauss { x0: w * 0.5 - d, sigma: 2.2, amplitude: 1300.0 },
                    Gauss { x0: w * 0.75 + 0.5 * d, sigma: 2.8, amplitude: 1700.0 },
                ];
                rows.push(quantise(&clean_row(width as usize, 100.0, &stripes), 8.0, 12, &mut rng));
            }
        }
        TestCamera { width, height, rows, next: 0, odometer_um: 0 }
    }
}

impl Camera for TestCamera {
    type Error = ();
    fn width(&self) -> u16 {
        self.width
    }
    fn height(&self) -> u16 {
        self.height
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, _exposure_us: u32, _laser_mask: u8) -> Result<i64, ()> {
        self.odometer_um += 1_000;
        Ok(self.odometer_um)
    }
    fn read_row(&mut self, row: &mut [u16]) -> Result<(), ()> {
        row.copy_from_slice(&self.rows[self.next % self.rows.len()]);
        self.next += 1;
        Ok(())
    }
}

/// A laser driver that logs every change of its mask.
#[derive(Clone, Default)]
pub(super) struct Lasers(pub(super) Arc<Mutex<Vec<(Instant, u8)>>>);

impl LaserDriver for Lasers {
    fn set(&mut self, mask: u8) {
        let mut log = self.0.lock().unwrap();
        if log.last().is_none_or(|&(_, m)| m != mask) {
            log.push((Instant::now(), mask));
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Damage {
    /// Nonzero random bytes and a delimiter before the frame.
    Garbage,
    /// One bit of the frame flipped (never into a 0x00).
    Flip,
    /// The first half of the frame, then the delimiter.
    Truncate,
}

/// What the injector does, by index of the profile frames the head produced
/// while plugged in.
#[derive(Clone, Debug, Default)]
pub(super) struct Plan {
    pub(super) damage: Vec<(u64, Damage)>,
    /// Unplug after this many profiles, until the head has turned its
    /// lasers off for want of heartbeats.
    pub(super) unplug: Option<u64>,
    /// Hang up for good after this many profiles: the path removed and the
    /// pty closed, never plugged back.
    pub(super) hang_up: Option<u64>,
    /// Go silent (neither answer nor run the head; the commands are kept
    /// for later) after this many profiles, until the listener asks again
    /// with `GetInfo`.
    pub(super) silence: Option<u64>,
    pub(super) rate_hz: u16,
    pub(super) width: u16,
    pub(super) height: u16,
    /// After the first profile, send it again and again (new `seq` each
    /// time) as fast as the pty takes it.
    pub(super) replay: bool,
}

/// What the device did.
#[derive(Debug, Default)]
pub(super) struct Report {
    /// Sequence numbers of the profiles written intact, in order.
    pub(super) sent: Vec<u32>,
    /// Damaged frames written (each one bad frame at the reader).
    pub(super) damaged: u64,
    /// Encoded size of each intact profile frame, bytes.
    pub(super) frame_bytes: Vec<usize>,
    pub(super) lasers: Vec<(Instant, u8)>,
    pub(super) unplugged: Option<Instant>,
    /// When the head last heard a command before the unplug.
    pub(super) last_heard: Option<Instant>,
    pub(super) replugged: Option<Instant>,
    /// Head state and lasers just before the replug.
    pub(super) before_replug: Option<(HeadState, u8)>,
    /// Head state and lasers at the end.
    pub(super) end: Option<(HeadState, u8)>,
    /// Commands the head received, and link errors it saw.
    pub(super) commands: u64,
    pub(super) bad_commands: u64,
    /// How long the silence lasted.
    pub(super) silence: Option<Duration>,
}

/// What the listener has handed on so far, for the threads that wait for it.
#[derive(Default)]
pub(super) struct Tally {
    pub(super) seen: Mutex<Seen>,
    pub(super) changed: Condvar,
}

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Seen {
    /// Messages handed to `observe`.
    pub(super) messages: u64,
    /// Of which profiles.
    pub(super) profiles: u64,
    /// The listener returned.
    pub(super) done: bool,
}

impl Tally {
    pub(super) fn update(&self, f: impl FnOnce(&mut Seen)) {
        f(&mut self.seen.lock().unwrap());
        self.changed.notify_all();
    }

    /// Waits until `cond` holds or `deadline` passes; returns what was seen.
    pub(super) fn wait_until(&self, deadline: Instant, cond: impl Fn(&Seen) -> bool) -> Seen {
        let timeout = deadline.saturating_duration_since(Instant::now());
        let guard = self.seen.lock().unwrap();
        *self.changed.wait_timeout_while(guard, timeout, |s| !cond(s)).unwrap().0
    }
}

/// What the device tells the test, and what it waits on.
pub(super) struct Hooks {
    /// Sent once the link exists.
    pub(super) plugged: mpsc::Sender<()>,
    /// The listener's tally, for an unplug that loses nothing in the cable.
    pub(super) listener: Option<Arc<Tally>>,
}

/// How often the head runs while it has nothing to read: its frame clock
/// (1 ms is the finest `poll(2)` timeout; the fastest plan is 1000 Hz).
pub(super) const TICK: Duration = Duration::from_millis(1);

pub(super) struct Pty {
    pub(super) master: File,
    /// Held open so that the master never sees a hang-up (and reads never
    /// fail with EIO) before the listener has opened the path.
    pub(super) slave: OwnedFd,
}

/// A new pty in raw mode, its master non-blocking, and `link` pointing at
/// its slave.
pub(super) fn plug(link: &Path) -> Pty {
    use nix::fcntl::{FcntlArg, OFlag, fcntl};
    use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
    let p = nix::pty::openpty(None, None).expect("openpty");
    let mut t = tcgetattr(p.slave.as_fd()).expect("tcgetattr");
    cfmakeraw(&mut t);
    tcsetattr(p.slave.as_fd(), SetArg::TCSANOW, &t).expect("tcsetattr");
    let fl = OFlag::from_bits_retain(fcntl(p.master.as_fd(), FcntlArg::F_GETFL).expect("F_GETFL"));
    fcntl(p.master.as_fd(), FcntlArg::F_SETFL(fl | OFlag::O_NONBLOCK)).expect("F_SETFL");
    let name = nix::unistd::ttyname(p.slave.as_fd()).expect("ttyname");
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp).expect("symlink");
    std::fs::rename(&tmp, link).expect("rename symlink");
    Pty { master: File::from(p.master), slave: p.slave }
}

/// Waits until `fd` has one of `events` (or a hang-up) or `timeout` passes;
/// returns what it has.
pub(super) fn wait_for(fd: &impl AsFd, events: nix::poll::PollFlags, timeout: Duration) -> nix::poll::PollFlags {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    let mut fds = [PollFd::new(fd.as_fd(), events)];
    let timeout = PollTimeout::try_from(timeout.max(Duration::from_millis(1))).unwrap_or(PollTimeout::MAX);
    match poll(&mut fds, timeout) {
        Ok(_) => fds[0].revents().unwrap_or(PollFlags::empty()),
        Err(_) => PollFlags::empty(), // EINTR: the caller looks again
    }
}

pub(super) fn write_all(master: &mut File, mut bytes: &[u8]) -> io::Result<()> {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !bytes.is_empty() {
        match master.write(bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(io::Error::new(io::ErrorKind::TimedOut, "nobody reads the pty"));
                }
                // Until the listener has read enough to make room.
                wait_for(master, nix::poll::PollFlags::POLLOUT, left);
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// The head on the master side of a pty reached through `link`, until
/// `stop`. Writes its frames through the injector of `plan`.
pub(super) fn device(link: PathBuf, plan: Plan, stop: Arc<AtomicBool>, hooks: Hooks) -> Report {
    let mut d = Device::new(link, plan, stop, hooks);
    while !d.stop.load(Ordering::SeqCst) {
        let now_us = d.epoch.elapsed().as_micros() as u64;
        d.read_commands();
        d.run_head(now_us);
        d.keep_template();
        let idle = d.write_out();
        d.go_silent();
        if d.hang_up() || d.unplug_and_replug() {
            continue;
        }
        if idle && let Some(p) = &d.pty {
            // Until a command arrives, or the head's next tick.
            wait_for(&p.master, nix::poll::PollFlags::POLLIN, TICK);
        }
    }
    let Device { head, lasers, mut report, .. } = d;
    report.end = Some((head.state(), head.lasers_on()));
    // The head's drop is the last word on its lasers.
    drop(head);
    report.lasers = lasers.lock().unwrap().clone();
    report
}

/// The test device's state between the turns of its loop.
struct Device {
    link: PathBuf,
    plan: Plan,
    stop: Arc<AtomicBool>,
    hooks: Hooks,
    head: Box<Head<W, Lasers>>,
    lasers: Arc<Mutex<Vec<(Instant, u8)>>>,
    camera: TestCamera,
    rng: Rng,
    epoch: Instant,
    pty: Option<Pty>,
    cmd_reader: Box<FrameReader<MAX_COMMAND_FRAME>>,
    frame: Vec<u8>,
    rbuf: Vec<u8>,
    report: Report,
    /// Profile frames the head produced while plugged in.
    produced: u64,
    /// Frames to write: the profile's `seq` (none for other messages) and the bytes.
    outq: Vec<(Option<u32>, Vec<u8>)>,
    cmds: Vec<Result<Command, WireError>>,
    silenced: bool,
    /// Frames written whole and undamaged (what the listener must hand on).
    intact_frames: u64,
    last_command: Option<Instant>,
    template: Option<cms_core::protocol::Profile>,
    unplugged: bool,
}

impl Device {
    fn new(link: PathBuf, plan: Plan, stop: Arc<AtomicBool>, hooks: Hooks) -> Device {
        let lasers = Lasers::default();
        let log = lasers.0.clone();
        let identity = Identity { firmware: "0.1.0-test", board: "test-pty" };
        let head: Box<Head<W, Lasers>> = Box::new(Head::new(lasers, default_detector(), identity).expect("head"));
        let camera = TestCamera::new(plan.width, plan.height, 3, 7);
        let pty = Some(plug(&link));
        let _ = hooks.plugged.send(());
        Device {
            link,
            plan,
            stop,
            hooks,
            head,
            lasers: log,
            camera,
            rng: Rng::new(99),
            epoch: Instant::now(),
            pty,
            cmd_reader: Box::new(FrameReader::new()),
            frame: vec![0u8; MAX_FRAME],
            rbuf: vec![0u8; 4096],
            report: Report::default(),
            produced: 0,
            outq: Vec::new(),
            cmds: Vec::new(),
            silenced: false,
            intact_frames: 0,
            last_command: None,
            template: None,
            unplugged: false,
        }
    }

    fn clock_ns(&self) -> impl FnMut() -> u64 + use<> {
        let epoch = self.epoch;
        move || epoch.elapsed().as_nanos() as u64
    }

    /// Whatever the listener has sent.
    fn read_commands(&mut self) {
        let Some(p) = &mut self.pty else { return };
        loop {
            match p.master.read(&mut self.rbuf) {
                Ok(0) => break,
                Ok(n) => self.cmd_reader.feed(&self.rbuf[..n], |r: Result<Command, WireError>| self.cmds.push(r)),
                Err(_) => break, // WouldBlock, or EIO before the listener opened the slave
            }
        }
    }

    /// The commands handled, then one turn of the head (or, replaying, its
    /// first profile again).
    fn run_head(&mut self, now_us: u64) {
        let mut clock_ns = self.clock_ns();
        let (frame, outq) = (&mut self.frame, &mut self.outq);
        let mut reply = |m: &DeviceMsg| {
            let f = encode(m, frame).expect("encode");
            let seq = if let DeviceMsg::Profile(p) = m { Some(p.seq) } else { None };
            outq.push((seq, f.to_vec()));
        };
        for r in self.cmds.drain(..) {
            match r {
                Ok(c) => {
                    self.report.commands += 1;
                    self.last_command = Some(Instant::now());
                    self.head.handle(c, now_us, &self.camera, &mut reply);
                }
                Err(e) => {
                    self.report.bad_commands += 1;
                    let code = if e == WireError::Crc { ErrorCode::Crc } else { ErrorCode::Decode };
                    self.head.link_error(code, &mut reply);
                }
            }
        }
        match &mut self.template {
            // Replay: the head's first profile again and again, as fast
            // as the pty takes it (the link's and listener's capacity).
            Some(p) if self.head.state() == HeadState::Streaming => {
                p.seq = p.seq.wrapping_add(1);
                reply(&DeviceMsg::Profile(p.clone()));
            }
            _ => self.head.poll(now_us, &mut self.camera, &mut clock_ns, &mut reply),
        }
    }

    /// Replaying: the first profile the head produced, kept.
    fn keep_template(&mut self) {
        if self.plan.replay && self.template.is_none() {
            self.template = self.outq.iter().find_map(|(seq, f)| {
                seq.and_then(|_| match cms_core::protocol::decode_frame(&mut f[..f.len() - 1].to_vec()) {
                    Ok(DeviceMsg::Profile(p)) => Some(p),
                    _ => None,
                })
            });
        }
    }

    /// The queued frames written, damaged as the plan says; whether there
    /// were none.
    fn write_out(&mut self) -> bool {
        let idle = self.outq.is_empty();
        let outq = std::mem::take(&mut self.outq);
        for (seq, bytes) in outq {
            if self.pty.is_none() {
                continue;
            }
            let ok = match seq {
                Some(seq) => self.write_profile(seq, bytes),
                None => {
                    let p = self.pty.as_mut().expect("plugged");
                    let ok = write_all(&mut p.master, &bytes).is_ok();
                    self.intact_frames += u64::from(ok);
                    ok
                }
            };
            if !ok {
                // The listener is gone: stop writing.
                self.stop.store(true, Ordering::SeqCst);
            }
        }
        idle
    }

    /// One profile frame through the injector; whether the write worked.
    fn write_profile(&mut self, seq: u32, mut bytes: Vec<u8>) -> bool {
        let index = self.produced;
        self.produced += 1;
        let p = self.pty.as_mut().expect("plugged");
        let mut ok = true;
        match self.plan.damage.iter().find(|(i, _)| *i == index).map(|d| d.1) {
            None => {}
            Some(Damage::Garbage) => {
                let n = 1 + (self.rng.next_u64() % 40) as usize;
                let mut g: Vec<u8> = (0..n).map(|_| 1 + (self.rng.next_u64() % 255) as u8).collect();
                g.push(0);
                ok = write_all(&mut p.master, &g).is_ok();
                self.report.damaged += 1;
            }
            Some(Damage::Flip) => {
                loop {
                    let i = (self.rng.next_u64() % (bytes.len() as u64 - 1)) as usize;
                    let b = bytes[i] ^ (1 << (self.rng.next_u64() % 8));
                    if b != 0 {
                        bytes[i] = b;
                        break;
                    }
                }
                self.report.damaged += 1;
            }
            Some(Damage::Truncate) => {
                let half = bytes.len() / 2;
                bytes.truncate(half);
                bytes.push(0);
                self.report.damaged += 1;
            }
        }
        let intact = !self.plan.damage.iter().any(|&(i, d)| i == index && d != Damage::Garbage);
        ok = ok && write_all(&mut p.master, &bytes).is_ok();
        if ok && intact {
            self.report.sent.push(seq);
            self.report.frame_bytes.push(bytes.len());
            self.intact_frames += 1;
        }
        ok
    }

    /// Silent until the listener, hearing nothing, asks again: the commands
    /// meanwhile (heartbeats, the GetInfo) are kept and handled afterwards,
    /// as a head that stalled would.
    fn go_silent(&mut self) {
        let Some(after) = self.plan.silence else { return };
        if self.silenced || self.produced < after {
            return;
        }
        let Some(p) = &mut self.pty else { return };
        self.silenced = true;
        let t = Instant::now();
        let deadline = t + Duration::from_secs(10);
        let mut asked = false;
        while !asked && Instant::now() < deadline {
            wait_for(&p.master, nix::poll::PollFlags::POLLIN, deadline.saturating_duration_since(Instant::now()));
            while let Ok(n @ 1..) = p.master.read(&mut self.rbuf) {
                self.cmd_reader.feed(&self.rbuf[..n], |r: Result<Command, WireError>| {
                    asked |= matches!(r, Ok(Command { msg: HostMsg::GetInfo, .. }));
                    self.cmds.push(r);
                });
            }
        }
        self.report.silence = Some(t.elapsed());
    }

    /// Hangs up for good once the plan says; whether the loop skips the
    /// rest of this turn.
    fn hang_up(&mut self) -> bool {
        let Some(after) = self.plan.hang_up else { return false };
        if self.produced >= after
            && let Some(p) = self.pty.take()
        {
            let _ = std::fs::remove_file(&self.link);
            drop(p);
            self.report.unplugged = Some(Instant::now());
            return true;
        }
        if self.pty.is_none() {
            // Hung up: nothing to wait on until the test ends.
            thread::sleep(TICK);
            return true;
        }
        false
    }

    /// Unplugs once the plan says, with no frame in the cable, runs the head
    /// unplugged until its lasers are off, and plugs it back; whether it did.
    fn unplug_and_replug(&mut self) -> bool {
        let Some(after) = self.plan.unplug else { return false };
        if self.unplugged || self.produced < after {
            return false;
        }
        let Some(p) = self.pty.take() else { return false };
        self.unplugged = true;
        // Let the listener hand on everything first: no frame in the cable.
        let tally = self.hooks.listener.as_ref().expect("an unplug needs the listener's tally");
        let want = self.intact_frames;
        let seen = tally.wait_until(Instant::now() + Duration::from_secs(5), |s| s.messages >= want);
        assert!(seen.messages >= want, "the listener handed on {seen:?} of {want} frames");
        let _ = std::fs::remove_file(&self.link);
        drop(p);
        let t = Instant::now();
        self.report.unplugged = Some(t);
        self.report.last_heard = self.last_command;
        // Unplugged: the head runs on its clock, hears nothing, and must
        // turn its lasers off after 1 s; whatever it says is lost. Plugged
        // back once it has (or after 5 s, which the test then reports).
        let mut clock_ns = self.clock_ns();
        while t.elapsed() < Duration::from_secs(5)
            && !(self.head.state() == HeadState::Fault && self.head.lasers_on() == 0)
            && !self.stop.load(Ordering::SeqCst)
        {
            let now_us = self.epoch.elapsed().as_micros() as u64;
            self.head.poll(now_us, &mut self.camera, &mut clock_ns, &mut |_m: &DeviceMsg| {});
            // Nothing is connected: nothing to wait on but the clock.
            thread::sleep(TICK);
        }
        self.report.before_replug = Some((self.head.state(), self.head.lasers_on()));
        *self.cmd_reader = FrameReader::new();
        self.pty = Some(plug(&self.link));
        self.report.replugged = Some(Instant::now());
        true
    }
}

/// The device on a thread, served until dropped.
pub(super) struct Served {
    pub(super) stop: Arc<AtomicBool>,
    pub(super) dev: Option<thread::JoinHandle<Report>>,
    pub(super) link: PathBuf,
}

impl Served {
    pub(super) fn new(dir: &Path) -> Served {
        Served::with_plan(dir, small_plan())
    }

    pub(super) fn with_plan(dir: &Path, plan: Plan) -> Served {
        let link = dir.join("ttyCLI");
        let stop = Arc::new(AtomicBool::new(false));
        let (plugged, is_plugged) = mpsc::channel();
        let dev = {
            let (link, stop) = (link.clone(), stop.clone());
            let hooks = Hooks { plugged, listener: None };
            thread::Builder::new().stack_size(16 << 20).spawn(move || device(link, plan, stop, hooks)).unwrap()
        };
        is_plugged.recv_timeout(Duration::from_secs(10)).expect("the device creates the link");
        Served { stop, dev: Some(dev), link }
    }

    /// Ends the device once the listener process has exited (having had
    /// its Stop acknowledged, which the tests check on its stderr).
    pub(super) fn finish(mut self) -> Report {
        self.stop.store(true, Ordering::SeqCst);
        self.dev.take().unwrap().join().expect("device panicked")
    }
}

/// A small, fast plan: 320 × 64 rows at 100 Hz.
pub(super) fn small_plan() -> Plan {
    Plan { rate_hz: 100, width: 320, height: 64, ..Plan::default() }
}
