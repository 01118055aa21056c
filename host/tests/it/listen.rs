//! `cms-host listen` through a real pseudo-terminal.
//!
//! A device thread runs `cms_core::pipeline::Head` (the firmware's own logic,
//! laser-safety rules included) with a test camera that renders rows of three
//! Gaussian stripes, on the master side of a pty. On their way to the pty the
//! head's frames pass an injector that inserts garbage, flips bits, truncates
//! a frame, unplugs the device and plugs it back, or goes silent.
//!
//! **The replug trick.** A pty's slave path (`/dev/pts/N`) cannot be created
//! again under the same name, so the listener is given a symlink inside a
//! temporary directory. Unplugging removes the symlink and closes the master
//! (the listener's reads fail, the path is gone); plugging back opens a new
//! pty and points the symlink at it (created beside and renamed over, so the
//! listener never sees a half-made link). To the listener it is one path that
//! disappears and comes back, as `/dev/ttyACM0` does on a USB replug.
//!
//! Before unplugging, the device waits until the listener has handed on
//! every frame it wrote intact (the listener's `observe` callback counts
//! them into a [`Tally`] the device waits on): the frames "in the cable" at
//! the moment of the unplug are then none, and every frame the device wrote
//! intact can be required at the other end. (On a real unplug the frame in
//! flight is lost; it arrives truncated or not at all, and is counted or
//! simply absent.)
//!
//! **No sleeps.** Every wait is for an event, with a deadline: the device
//! blocks in `poll(2)` on its pty (for a command, or room to write) with
//! the head's frame tick as the timeout; the test waits for the listener's
//! messages on the tally's condition variable and for the device's first
//! plug on a channel; the unplug lasts until the head has turned its lasers
//! off, the silence until the listener asks again. The only timed waits
//! left are the head's own clock while nothing is connected to it, and the
//! listener's protocol timeouts the tests are about.

use crate::common::bin;
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, mpsc};
use std::thread;
use std::time::{Duration, Instant};

use cms_core::pipeline::{Camera, Head, Identity, LaserDriver, default_detector};
use cms_core::protocol::{
    Command, DeviceMsg, ErrorCode, FrameReader, HeadState, HostMsg, LaserPattern, MAX_COMMAND_FRAME, MAX_FRAME,
    PROTOCOL_VERSION, Start, WireError, encode,
};
use cms_host::device::listen::{ListenError, ListenOptions, Summary, listen_with};
use cms_host::recording;
use cms_study::{Gauss, Rng, clean_row, quantise};

// ------------------------------------------------------------------ device

/// Widest row of the test head.
const W: usize = 752;

/// Rows of three Gaussian stripes, precomputed (a few noisy frames, cycled).
struct TestCamera {
    width: u16,
    height: u16,
    rows: Vec<Vec<u16>>,
    next: usize,
    odometer_um: i64,
}

impl TestCamera {
    fn new(width: u16, height: u16, frames: usize, seed: u64) -> TestCamera {
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
struct Lasers(Arc<Mutex<Vec<(Instant, u8)>>>);

impl LaserDriver for Lasers {
    fn set(&mut self, mask: u8) {
        let mut log = self.0.lock().unwrap();
        if log.last().is_none_or(|&(_, m)| m != mask) {
            log.push((Instant::now(), mask));
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Damage {
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
struct Plan {
    damage: Vec<(u64, Damage)>,
    /// Unplug after this many profiles, until the head has turned its
    /// lasers off for want of heartbeats.
    unplug: Option<u64>,
    /// Hang up for good after this many profiles: the path removed and the
    /// pty closed, never plugged back.
    hang_up: Option<u64>,
    /// Go silent (neither answer nor run the head; the commands are kept
    /// for later) after this many profiles, until the listener asks again
    /// with `GetInfo`.
    silence: Option<u64>,
    rate_hz: u16,
    width: u16,
    height: u16,
    /// After the first profile, send it again and again (new `seq` each
    /// time) as fast as the pty takes it.
    replay: bool,
}

/// What the device did.
#[derive(Debug, Default)]
struct Report {
    /// Sequence numbers of the profiles written intact, in order.
    sent: Vec<u32>,
    /// Damaged frames written (each one bad frame at the reader).
    damaged: u64,
    /// Encoded size of each intact profile frame, bytes.
    frame_bytes: Vec<usize>,
    lasers: Vec<(Instant, u8)>,
    unplugged: Option<Instant>,
    /// When the head last heard a command before the unplug.
    last_heard: Option<Instant>,
    replugged: Option<Instant>,
    /// Head state and lasers just before the replug.
    before_replug: Option<(HeadState, u8)>,
    /// Head state and lasers at the end.
    end: Option<(HeadState, u8)>,
    /// Commands the head received, and link errors it saw.
    commands: u64,
    bad_commands: u64,
    /// How long the silence lasted.
    silence: Option<Duration>,
}

/// What the listener has handed on so far, for the threads that wait for it.
#[derive(Default)]
struct Tally {
    seen: Mutex<Seen>,
    changed: Condvar,
}

#[derive(Clone, Copy, Debug, Default)]
struct Seen {
    /// Messages handed to `observe`.
    messages: u64,
    /// Of which profiles.
    profiles: u64,
    /// The listener returned.
    done: bool,
}

impl Tally {
    fn update(&self, f: impl FnOnce(&mut Seen)) {
        f(&mut self.seen.lock().unwrap());
        self.changed.notify_all();
    }

    /// Waits until `cond` holds or `deadline` passes; returns what was seen.
    fn wait_until(&self, deadline: Instant, cond: impl Fn(&Seen) -> bool) -> Seen {
        let timeout = deadline.saturating_duration_since(Instant::now());
        let guard = self.seen.lock().unwrap();
        *self.changed.wait_timeout_while(guard, timeout, |s| !cond(s)).unwrap().0
    }
}

/// What the device tells the test, and what it waits on.
struct Hooks {
    /// Sent once the link exists.
    plugged: mpsc::Sender<()>,
    /// The listener's tally, for an unplug that loses nothing in the cable.
    listener: Option<Arc<Tally>>,
}

/// How often the head runs while it has nothing to read: its frame clock
/// (1 ms is the finest `poll(2)` timeout; the fastest plan is 1000 Hz).
const TICK: Duration = Duration::from_millis(1);

struct Pty {
    master: File,
    /// Held open so that the master never sees a hang-up (and reads never
    /// fail with EIO) before the listener has opened the path.
    slave: OwnedFd,
}

/// A new pty in raw mode, its master non-blocking, and `link` pointing at
/// its slave.
fn plug(link: &Path) -> Pty {
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
fn wait_for(fd: &impl AsFd, events: nix::poll::PollFlags, timeout: Duration) -> nix::poll::PollFlags {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    let mut fds = [PollFd::new(fd.as_fd(), events)];
    let timeout = PollTimeout::try_from(timeout.max(Duration::from_millis(1))).unwrap_or(PollTimeout::MAX);
    match poll(&mut fds, timeout) {
        Ok(_) => fds[0].revents().unwrap_or(PollFlags::empty()),
        Err(_) => PollFlags::empty(), // EINTR: the caller looks again
    }
}

fn write_all(master: &mut File, mut bytes: &[u8]) -> io::Result<()> {
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
fn device(link: PathBuf, plan: Plan, stop: Arc<AtomicBool>, hooks: Hooks) -> Report {
    let lasers = Lasers::default();
    let log = lasers.0.clone();
    let identity = Identity { firmware: "0.1.0-test", board: "test-pty" };
    let mut head: Box<Head<W, Lasers>> = Box::new(Head::new(lasers, default_detector(), identity).expect("head"));
    let mut camera = TestCamera::new(plan.width, plan.height, 3, 7);
    let mut rng = Rng::new(99);
    let epoch = Instant::now();
    let mut pty = Some(plug(&link));
    let _ = hooks.plugged.send(());
    let mut cmd_reader: Box<FrameReader<MAX_COMMAND_FRAME>> = Box::new(FrameReader::new());
    let mut frame = vec![0u8; MAX_FRAME];
    let mut rbuf = vec![0u8; 4096];
    let mut report = Report::default();
    let mut produced: u64 = 0;
    let mut outq: Vec<(Option<u32>, Vec<u8>)> = Vec::new();
    let mut cmds: Vec<Result<Command, WireError>> = Vec::new();
    let mut clock_ns = move || epoch.elapsed().as_nanos() as u64;
    let mut silenced = false;
    // Frames written whole and undamaged (what the listener must hand on).
    let mut intact_frames: u64 = 0;
    let mut last_command: Option<Instant> = None;
    let mut template: Option<cms_core::protocol::Profile> = None;
    let mut unplugged = false;
    while !stop.load(Ordering::SeqCst) {
        let now_us = epoch.elapsed().as_micros() as u64;
        if let Some(p) = &mut pty {
            loop {
                match p.master.read(&mut rbuf) {
                    Ok(0) => break,
                    Ok(n) => cmd_reader.feed(&rbuf[..n], |r: Result<Command, WireError>| cmds.push(r)),
                    Err(_) => break, // WouldBlock, or EIO before the listener opened the slave
                }
            }
        }
        {
            let mut reply = |m: &DeviceMsg| {
                let f = encode(m, &mut frame).expect("encode");
                let seq = if let DeviceMsg::Profile(p) = m { Some(p.seq) } else { None };
                outq.push((seq, f.to_vec()));
            };
            for r in cmds.drain(..) {
                match r {
                    Ok(c) => {
                        report.commands += 1;
                        last_command = Some(Instant::now());
                        head.handle(c, now_us, &camera, &mut reply);
                    }
                    Err(e) => {
                        report.bad_commands += 1;
                        let code = if e == WireError::Crc { ErrorCode::Crc } else { ErrorCode::Decode };
                        head.link_error(code, &mut reply);
                    }
                }
            }
            match &mut template {
                // Replay: the head's first profile again and again, as fast
                // as the pty takes it (the link's and listener's capacity).
                Some(p) if head.state() == HeadState::Streaming => {
                    p.seq = p.seq.wrapping_add(1);
                    reply(&DeviceMsg::Profile(p.clone()));
                }
                _ => head.poll(now_us, &mut camera, &mut clock_ns, &mut reply),
            }
        }
        if plan.replay && template.is_none() {
            template = outq.iter().find_map(|(seq, f)| {
                seq.and_then(|_| match cms_core::protocol::decode_frame(&mut f[..f.len() - 1].to_vec()) {
                    Ok(DeviceMsg::Profile(p)) => Some(p),
                    _ => None,
                })
            });
        }
        let idle = outq.is_empty();
        for (seq, mut bytes) in outq.drain(..) {
            let Some(p) = &mut pty else { continue };
            let mut ok = true;
            if let Some(seq) = seq {
                let index = produced;
                produced += 1;
                match plan.damage.iter().find(|(i, _)| *i == index).map(|d| d.1) {
                    None => {}
                    Some(Damage::Garbage) => {
                        let n = 1 + (rng.next_u64() % 40) as usize;
                        let mut g: Vec<u8> = (0..n).map(|_| 1 + (rng.next_u64() % 255) as u8).collect();
                        g.push(0);
                        ok = write_all(&mut p.master, &g).is_ok();
                        report.damaged += 1;
                    }
                    Some(Damage::Flip) => {
                        loop {
                            let i = (rng.next_u64() % (bytes.len() as u64 - 1)) as usize;
                            let b = bytes[i] ^ (1 << (rng.next_u64() % 8));
                            if b != 0 {
                                bytes[i] = b;
                                break;
                            }
                        }
                        report.damaged += 1;
                    }
                    Some(Damage::Truncate) => {
                        let half = bytes.len() / 2;
                        bytes.truncate(half);
                        bytes.push(0);
                        report.damaged += 1;
                    }
                }
                let intact = !plan.damage.iter().any(|&(i, d)| i == index && d != Damage::Garbage);
                ok = ok && write_all(&mut p.master, &bytes).is_ok();
                if ok && intact {
                    report.sent.push(seq);
                    report.frame_bytes.push(bytes.len());
                    intact_frames += 1;
                }
            } else {
                ok = write_all(&mut p.master, &bytes).is_ok();
                intact_frames += u64::from(ok);
            }
            if !ok {
                // The listener is gone: stop writing.
                stop.store(true, Ordering::SeqCst);
            }
        }
        if let Some(after) = plan.silence
            && !silenced
            && produced >= after
            && let Some(p) = &mut pty
        {
            silenced = true;
            // Silent until the listener, hearing nothing, asks again: the
            // commands meanwhile (heartbeats, the GetInfo) are kept and
            // handled afterwards, as a head that stalled would.
            let t = Instant::now();
            let deadline = t + Duration::from_secs(10);
            let mut asked = false;
            while !asked && Instant::now() < deadline {
                wait_for(&p.master, nix::poll::PollFlags::POLLIN, deadline.saturating_duration_since(Instant::now()));
                while let Ok(n @ 1..) = p.master.read(&mut rbuf) {
                    cmd_reader.feed(&rbuf[..n], |r: Result<Command, WireError>| {
                        asked |= matches!(r, Ok(Command { msg: HostMsg::GetInfo, .. }));
                        cmds.push(r);
                    });
                }
            }
            report.silence = Some(t.elapsed());
        }
        if let Some(after) = plan.hang_up
            && produced >= after
            && let Some(p) = pty.take()
        {
            let _ = std::fs::remove_file(&link);
            drop(p);
            report.unplugged = Some(Instant::now());
            continue;
        }
        if pty.is_none() && plan.hang_up.is_some() {
            // Hung up: nothing to wait on until the test ends.
            thread::sleep(TICK);
            continue;
        }
        if let Some(after) = plan.unplug
            && !unplugged
            && produced >= after
            && let Some(p) = pty.take()
        {
            unplugged = true;
            // Let the listener hand on everything first: no frame in the cable.
            let tally = hooks.listener.as_ref().expect("an unplug needs the listener's tally");
            let seen = tally.wait_until(Instant::now() + Duration::from_secs(5), |s| s.messages >= intact_frames);
            assert!(seen.messages >= intact_frames, "the listener handed on {seen:?} of {intact_frames} frames");
            let _ = std::fs::remove_file(&link);
            drop(p);
            let t = Instant::now();
            report.unplugged = Some(t);
            report.last_heard = last_command;
            // Unplugged: the head runs on its clock, hears nothing, and must
            // turn its lasers off after 1 s; whatever it says is lost. Plugged
            // back once it has (or after 5 s, which the test then reports).
            while t.elapsed() < Duration::from_secs(5)
                && !(head.state() == HeadState::Fault && head.lasers_on() == 0)
                && !stop.load(Ordering::SeqCst)
            {
                let now_us = epoch.elapsed().as_micros() as u64;
                head.poll(now_us, &mut camera, &mut clock_ns, &mut |_m: &DeviceMsg| {});
                // Nothing is connected: nothing to wait on but the clock.
                thread::sleep(TICK);
            }
            report.before_replug = Some((head.state(), head.lasers_on()));
            *cmd_reader = FrameReader::new();
            pty = Some(plug(&link));
            report.replugged = Some(Instant::now());
            continue;
        }
        if idle && let Some(p) = &pty {
            // Until a command arrives, or the head's next tick.
            wait_for(&p.master, nix::poll::PollFlags::POLLIN, TICK);
        }
    }
    report.end = Some((head.state(), head.lasers_on()));
    drop(head);
    report.lasers = log.lock().unwrap().clone();
    report
}

struct Run {
    summary: Result<Summary, ListenError>,
    /// Profile sequence numbers the listener handed on, in order.
    seen: Vec<u32>,
    json: Vec<u8>,
    report: Report,
    /// CPU time of the listener's thread, s.
    cpu_s: f64,
    wall_s: f64,
}

fn thread_cpu_s() -> f64 {
    use nix::sys::resource::{UsageWho, getrusage};
    match getrusage(UsageWho::RUSAGE_THREAD) {
        Ok(u) => {
            let t = |tv: nix::sys::time::TimeVal| tv.tv_sec() as f64 + tv.tv_usec() as f64 * 1e-6;
            t(u.user_time()) + t(u.system_time())
        }
        Err(_) => f64::NAN,
    }
}

/// Runs the device with `plan` and the listener with `opts` until the
/// listener has handed on `want` profiles (or `limit` passed), then stops both.
fn run(dir: &Path, plan: Plan, opts: ListenOptions, want: u64, limit: Duration) -> Run {
    let link = dir.join("ttyCMS");
    let dev_stop = Arc::new(AtomicBool::new(false));
    let tally = Arc::new(Tally::default());
    let (plugged, is_plugged) = mpsc::channel();
    let dev = {
        let (link, stop) = (link.clone(), dev_stop.clone());
        let hooks = Hooks { plugged, listener: Some(tally.clone()) };
        thread::Builder::new().stack_size(16 << 20).spawn(move || device(link, plan, stop, hooks)).unwrap()
    };
    is_plugged.recv_timeout(Duration::from_secs(10)).expect("the device creates the link");
    let stop = Arc::new(AtomicBool::new(false));
    let listener = {
        let (stop, tally, port) = (stop.clone(), tally.clone(), link.to_string_lossy().into_owned());
        thread::Builder::new()
            .stack_size(16 << 20)
            .spawn(move || {
                let mut seen = Vec::new();
                let mut json = Vec::new();
                let c0 = thread_cpu_s();
                let t0 = Instant::now();
                let summary = listen_with(&port, &opts, &stop, &mut json, &mut |m| {
                    if let DeviceMsg::Profile(p) = m {
                        seen.push(p.seq);
                    }
                    let profile = matches!(m, DeviceMsg::Profile(_));
                    tally.update(|s| {
                        s.messages += 1;
                        s.profiles += u64::from(profile);
                    });
                });
                let cpu = thread_cpu_s() - c0;
                tally.update(|s| s.done = true);
                (summary, seen, json, cpu, t0.elapsed().as_secs_f64())
            })
            .unwrap()
    };
    tally.wait_until(Instant::now() + limit, |s| s.profiles >= want || s.done);
    stop.store(true, Ordering::SeqCst);
    let (summary, seen, json, cpu_s, wall_s) = listener.join().expect("the listener panicked");
    // The listener has waited for the head's Ack of its Stop and the Status
    // after it, so the head's state is final: end the device.
    dev_stop.store(true, Ordering::SeqCst);
    let report = dev.join().expect("the device panicked");
    Run { summary, seen, json, report, cpu_s, wall_s }
}

fn recorded_profiles(path: &Path) -> (Vec<u32>, recording::ScanStats, usize) {
    let mut seqs = Vec::new();
    let mut hellos = 0;
    let stats = recording::scan_file(path, |m| {
        match m {
            DeviceMsg::Profile(p) => seqs.push(p.seq),
            DeviceMsg::Hello(_) => hellos += 1,
            _ => {}
        }
        Ok(())
    })
    .expect("recording reads");
    (seqs, stats, hellos)
}

fn small_plan() -> Plan {
    Plan { rate_hz: 100, width: 320, height: 64, ..Plan::default() }
}

// ------------------------------------------------------------------ tests

/// Garbage, bit flips, a truncated frame and an unplug/replug on the way:
/// every intact frame arrives (in order, none missing), every damaged one
/// is counted, the recording holds exactly what arrived, the reconnect is
/// counted, and the head's lasers went off while it heard no heartbeat.
#[test]
fn survives_garbage_flips_truncation_and_replug() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let mut plan = small_plan();
    plan.damage = vec![
        (3, Damage::Garbage),
        (5, Damage::Flip),
        (9, Damage::Truncate),
        (12, Damage::Flip),
        (14, Damage::Garbage),
        (20, Damage::Flip),
        (33, Damage::Garbage),
        (40, Damage::Flip),
        (41, Damage::Truncate),
        (47, Damage::Flip),
    ];
    plan.unplug = Some(25);
    let opts = ListenOptions {
        record: Some(rec.clone()),
        json: true,
        start: Start { rate_hz: plan.rate_hz, laser_mask: 0b111, pattern: LaserPattern::Simultaneous },
        ..ListenOptions::default()
    };
    let r = run(dir.path(), plan, opts, 60, Duration::from_secs(60));
    let rep = &r.report;
    let sum = r.summary.as_ref().expect("listen succeeds");

    // Every intact frame decoded, in order, none missing: what the listener
    // handed on is exactly the device's intact frames up to the stop.
    assert!(r.seen.len() >= 60, "only {} profiles arrived", r.seen.len());
    if r.seen[..] != rep.sent[..r.seen.len().min(rep.sent.len())] {
        let first = r.seen.iter().zip(&rep.sent).position(|(a, b)| a != b);
        panic!(
            "intact frames lost or reordered at {first:?}: seen {:?}\nsent {:?}\n{:?}",
            r.seen,
            rep.sent,
            r.summary.as_ref().map(|s| s.to_string())
        );
    }
    assert_eq!(sum.frames, r.seen.len() as u64);
    // Every damaged frame counted, and nothing else.
    assert_eq!(rep.damaged, 10);
    assert_eq!(sum.link.crc_errors + sum.link.decode_errors + sum.link.overflows, rep.damaged, "{sum}");
    // The reconnect.
    assert_eq!(sum.reconnects, 1, "{sum}");
    assert!(rep.unplugged.is_some() && rep.replugged.is_some());
    // Laser safety: no heartbeat for > 1 s while unplugged → lasers off,
    // the head in Fault before the replug.
    let (state, lit) = rep.before_replug.unwrap();
    assert_eq!((state, lit), (HeadState::Fault, 0));
    // The lasers are strobed (lit only during exposures): the last strobe
    // after the last command the head heard comes within the 1 s timeout,
    // and none follows until the replug.
    let heard = rep.last_heard.unwrap();
    let replugged = rep.replugged.unwrap();
    let last_on = rep
        .lasers
        .iter()
        .rfind(|(t, m)| *t > heard && *t < replugged && *m != 0)
        .expect("the head kept strobing after the unplug until the timeout");
    let dt = last_on.0.duration_since(heard);
    assert!(
        dt >= Duration::from_millis(500) && dt < Duration::from_millis(1400),
        "last strobe {dt:?} after the last command the head heard"
    );
    assert!(rep.lasers.iter().any(|(t, m)| *t > rep.replugged.unwrap() && *m == 0b111), "lasers back on after");
    // Clean stop: Stop acknowledged, lasers off, head idle.
    assert!(sum.stop_acked, "{sum}");
    assert_eq!(sum.lasers_on, Some(0), "{sum}");
    assert_eq!(rep.end, Some((HeadState::Idle, 0)));
    // The recording holds every frame that arrived, and two Hellos.
    let (recorded, stats, hellos) = recorded_profiles(&rec);
    assert_eq!(recorded, r.seen);
    assert_eq!(stats.damaged, 0);
    assert_eq!(stats.truncated_tail, 0);
    assert_eq!(hellos, 2);
    // The JSON lines are the same frames.
    let text = String::from_utf8(r.json).unwrap();
    let seqs: Vec<u32> = text
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("a JSON line");
            assert!(v["odometer_mm"].is_f64() && v["timestamp_us"].is_u64() && v["laser_mask"] == 7);
            assert_eq!(v["lasers"].as_array().unwrap().len(), 3);
            v["seq"].as_u64().unwrap() as u32
        })
        .collect();
    assert_eq!(seqs, r.seen);
}

/// A head that goes silent: after 2 s the listener asks again (GetInfo,
/// Start) and the stream resumes without losing an intact frame.
#[test]
fn a_silent_head_is_asked_again() {
    let dir = tempfile::tempdir().unwrap();
    let mut plan = small_plan();
    plan.silence = Some(10);
    let opts = ListenOptions {
        start: Start { rate_hz: plan.rate_hz, laser_mask: 0b101, pattern: LaserPattern::Sequential },
        ..ListenOptions::default()
    };
    let r = run(dir.path(), plan, opts, 40, Duration::from_secs(60));
    let sum = r.summary.expect("listen succeeds");
    assert!(r.seen.len() >= 40);
    assert_eq!(r.seen[..], r.report.sent[..r.seen.len()]);
    assert_eq!(sum.stalls, 1, "{sum}");
    let silence = r.report.silence.expect("the head went silent");
    assert!(silence >= Duration::from_secs(2) && silence < Duration::from_secs(4), "asked again after {silence:?}");
    assert_eq!(sum.reconnects, 0);
    assert_eq!(sum.link.damaged(), 0);
    // Sequential pattern: lasers 0 and 2 in turn, never together.
    assert!(r.report.lasers.iter().all(|&(_, m)| m == 0 || m == 0b001 || m == 0b100), "{:?}", r.report.lasers);
    assert_eq!(r.report.end, Some((HeadState::Idle, 0)));
}

/// One throughput measurement: the reference head's frame (752 × 480, three
/// lasers) through the pty.
fn measure(replay: bool, json: bool, record: bool, want: u64) -> String {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("t.cmsrec");
    let plan = Plan { rate_hz: 1000, width: 752, height: 480, replay, ..Plan::default() };
    let opts = ListenOptions {
        record: record.then(|| rec.clone()),
        json,
        start: Start { rate_hz: plan.rate_hz, laser_mask: 0b111, pattern: LaserPattern::Simultaneous },
        ..ListenOptions::default()
    };
    let r = run(dir.path(), plan, opts, want, Duration::from_secs(120));
    let sum = r.summary.expect("listen succeeds");
    assert!(r.seen.len() as u64 >= want);
    assert_eq!(r.seen[..], r.report.sent[..r.seen.len()]);
    assert_eq!(sum.link.damaged(), 0);
    let bytes = r.report.frame_bytes.iter().sum::<usize>() as f64 / r.report.frame_bytes.len() as f64;
    let fps = sum.frames_per_s();
    let ppf = sum.points as f64 / sum.frames as f64;
    assert!(ppf > 3.0 * 470.0, "the test camera's three stripes are found on nearly every row: {ppf}");
    format!(
        "{} (json {json}, record {record}): {} frames, {fps:.1} frames/s, {:.0} points/s, {ppf:.0} points/frame, \
         {bytes:.0} bytes/frame ({:.2} MB/s), listener CPU {:.3} ms/frame ({:.0} % of one core over {:.2} s)",
        if replay { "replayed frames" } else { "head pipeline  " },
        sum.frames,
        fps * ppf,
        fps * bytes / 1e6,
        r.cpu_s * 1e3 / sum.frames as f64,
        100.0 * r.cpu_s / r.wall_s,
        r.wall_s,
    )
}

/// Sustained rate through the pty, the encoded size per frame and the
/// listener's CPU time per frame: with the head pipeline running the
/// detector on every row, and with frames replayed as fast as the pty takes
/// them (the link's and listener's own capacity). Prints the figures:
/// `cargo test --release -p cms-host --test it listen::throughput -- --nocapture --test-threads 1`.
#[test]
fn throughput_through_the_pty() {
    let n = if cfg!(debug_assertions) { 20 } else { 300 };
    let mut lines = vec![measure(false, true, true, n)];
    if !cfg!(debug_assertions) {
        lines.push(measure(true, true, true, 3 * n));
        lines.push(measure(true, false, false, 3 * n));
    }
    for l in lines {
        eprintln!("throughput: {l}");
    }
}

/// A port that does not exist: a clear error at once.
#[test]
fn a_missing_port_is_a_clear_error() {
    let stop = AtomicBool::new(false);
    let e =
        listen_with("/nonexistent/ttyCMS", &ListenOptions::default(), &stop, &mut io::sink(), &mut |_| {}).unwrap_err();
    let msg = e.to_string();
    assert!(msg.starts_with("cannot open /nonexistent/ttyCMS"), "{msg}");
}

/// A pty whose other side never answers: NoHello after three tries.
#[test]
fn a_silent_port_gives_no_hello() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyMute");
    let _pty = plug(&link);
    let stop = AtomicBool::new(false);
    let opts = ListenOptions::default();
    let t = Instant::now();
    let e = listen_with(link.to_str().unwrap(), &opts, &stop, &mut io::sink(), &mut |_| {}).unwrap_err();
    assert!(matches!(e, ListenError::NoHello { .. }), "{e}");
    assert!(e.to_string().contains("no Hello after 3 GetInfo requests"), "{e}");
    assert!(t.elapsed() >= Duration::from_secs(6) && t.elapsed() < Duration::from_secs(9));
}

// ------------------------------------------------------------------ CLI

/// The device on a thread, served until dropped.
struct Served {
    stop: Arc<AtomicBool>,
    dev: Option<thread::JoinHandle<Report>>,
    link: PathBuf,
}

impl Served {
    fn new(dir: &Path) -> Served {
        Served::with_plan(dir, small_plan())
    }

    fn with_plan(dir: &Path, plan: Plan) -> Served {
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
    fn finish(mut self) -> Report {
        self.stop.store(true, Ordering::SeqCst);
        self.dev.take().unwrap().join().expect("device panicked")
    }
}

/// `cms-host listen PORT --frames 30 --json --record F`, then `info F` and
/// `export F --format csv|jsonl`.
#[test]
fn cli_listen_json_record_info_export() {
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let rec = dir.path().join("cli.cmsrec");
    let out = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--frames", "30", "--json", "--rate", "200", "--record"])
        .arg(&rec)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let report = served.finish();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8(out.stdout).unwrap();
    let seqs: Vec<u64> = stdout
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["seq"].as_u64().unwrap())
        .collect();
    assert_eq!(seqs.len(), 30);
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    assert!(stderr.contains("listen: frames: 30 "), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert!(stderr.contains("listen: calibration: none (positions in pixels only"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));

    let info = Process::new(bin()).arg("info").arg(&rec).output().unwrap();
    assert!(info.status.success());
    let info = String::from_utf8(info.stdout).unwrap();
    assert!(info.contains("frames: 30 (30 profile messages)"), "{info}");
    assert!(info.contains("device: firmware 0.1.0-test, board test-pty"), "{info}");
    assert!(info.contains("damaged frames: 0"), "{info}");

    let csv = Process::new(bin()).args(["export", "--format", "csv"]).arg(&rec).output().unwrap();
    assert!(csv.status.success());
    let csv = String::from_utf8(csv.stdout).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(recording::CSV_HEADER));
    assert_eq!(lines.count(), 30 * 3 * 64, "3 points per row, 64 rows, 30 frames");

    let jl = dir.path().join("out.jsonl");
    let e = Process::new(bin()).args(["export", "--format", "jsonl", "--out"]).arg(&jl).arg(&rec).output().unwrap();
    assert!(e.status.success());
    assert_eq!(std::fs::read_to_string(&jl).unwrap(), stdout);
}

/// Ctrl-C: Stop sent and acknowledged (lasers off), summary printed, exit 0.
#[test]
fn cli_ctrl_c_stops_the_head() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let mut child = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for a few frames.
    let mut stdout = child.stdout.take().unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while got.iter().filter(|&&b| b == b'\n').count() < 5 {
        let n = stdout.read(&mut buf).unwrap();
        assert!(n > 0, "listen ended early");
        got.extend_from_slice(&buf[..n]);
    }
    kill(Pid::from_raw(child.id() as i32), Signal::SIGINT).unwrap();
    let mut rest = Vec::new();
    stdout.read_to_end(&mut rest).unwrap();
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    let report = served.finish();
    assert!(status.success(), "{status:?}: {stderr}");
    assert!(stderr.contains("listen: frames: "), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));
    // The laser log ends with the lasers off.
    assert_eq!(report.lasers.last().map(|l| l.1), Some(0));
}

/// Bad arguments and a missing port: one line on stderr, non-zero exit.
#[test]
fn cli_errors_are_one_line() {
    for (args, needle) in [
        (vec!["listen", "/nonexistent/ttyX"], "cannot open /nonexistent/ttyX"),
        (vec!["listen", "/dev/null", "--lasers", "9"], "laser mask"),
        (vec!["listen", "/dev/null", "--duration", "0"], "seconds"),
        (vec!["info", "/nonexistent/rec"], "cannot open recording"),
    ] {
        let out = Process::new(bin()).args(&args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
}

/// `listen --json | head -1`: the closed pipe ends the listener quietly,
/// with the head stopped.
#[test]
fn cli_closed_stdout_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let mut child = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut buf = [0u8; 1];
    while buf[0] != b'\n' {
        stdout.read_exact(&mut buf).unwrap();
    }
    drop(stdout);
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    let report = served.finish();
    assert!(status.success(), "{status:?}: {stderr}");
    assert!(!stderr.contains("error:"), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));
}

/// An installed `cms-host` (a copy outside the checkout, run from outside
/// it) finds the emulated head's image beside itself or through
/// `CMS_QEMU_IMAGE`, and without one says in one line what to do.
#[test]
fn cli_qemu_image_outside_the_checkout() {
    let dir = tempfile::tempdir().unwrap();
    let installed = dir.path().join("cms-host");
    std::fs::copy(bin(), &installed).unwrap();
    let run = |env: Option<&Path>| {
        let mut cmd = Process::new(&installed);
        cmd.args(["listen", "qemu", "--frames", "1", "--reconnect-timeout", "1"])
            .current_dir(dir.path())
            .env_remove("CMS_QEMU_IMAGE");
        if let Some(p) = env {
            cmd.env("CMS_QEMU_IMAGE", p);
        }
        let out = cmd.stdin(Stdio::null()).output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (code, stderr) = run(None);
    // Which failure status is the command line's (cli::exit); not success.
    assert!(code.is_some_and(|c| c != 0), "{code:?}: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("no emulated head image cms-qemu-head: give --qemu-image FILE, set CMS_QEMU_IMAGE"),
        "{stderr}"
    );
    assert!(stderr.contains("`cd firmware/qemu && cargo build --release`"), "{stderr}");

    let missing = dir.path().join("nowhere.elf");
    let (code, stderr) = run(Some(&missing));
    // Which failure status is the command line's (cli::exit); not success.
    assert!(code.is_some_and(|c| c != 0), "{code:?}: {stderr}");
    assert!(stderr.contains(&format!("emulated head image {} does not exist", missing.display())), "{stderr}");

    // Not an image QEMU can run: what matters is that it was found (QEMU
    // then fails, or is not installed), not the old "no image" error.
    std::fs::write(dir.path().join("cms-qemu-head"), b"not an ELF").unwrap();
    let (code, stderr) = run(None);
    assert_ne!(code, Some(0), "{stderr}");
    assert!(!stderr.contains("no emulated head image"), "the image beside the binary is used: {stderr}");
    assert!(stderr.contains("qemu"), "{stderr}");
}

fn cobs_decode(f: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < f.len() {
        let code = f[i] as usize;
        out.extend_from_slice(&f[i + 1..i + code]);
        i += code;
        if code < 0xFF && i < f.len() {
            out.push(0);
        }
    }
    out
}

fn cobs_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    for &b in raw {
        if b == 0 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
        } else {
            out.push(b);
            if out.len() - code_at == 0xFF {
                out[code_at] = 0xFF;
                code_at = out.len();
                out.push(0);
            }
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out
}

/// A head of another protocol version is refused with both versions named.
#[test]
fn another_protocol_version_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyV2");
    let pty = plug(&link);
    // A Hello framed as the next protocol version (CRC recomputed).
    let mut info = None;
    let head: Head<W, Lasers> =
        Head::new(Lasers::default(), default_detector(), Identity { firmware: "9", board: "v2" }).expect("head");
    info.get_or_insert(head.info(&TestCamera::new(64, 4, 1, 1)));
    let f = {
        let mut out = vec![0u8; MAX_FRAME];
        encode(&DeviceMsg::Hello(info.unwrap()), &mut out).unwrap().to_vec()
    };
    let mut raw = cobs_decode(&f[..f.len() - 1]);
    raw[0] = PROTOCOL_VERSION + 1;
    let n = raw.len() - 4;
    let crc = cms_core::protocol::CRC.checksum(&raw[..n]);
    raw[n..].copy_from_slice(&crc.to_le_bytes());
    let mut v2 = cobs_encode(&raw);
    v2.push(0);
    // The answering thread blocks on the master until a command arrives, and
    // ends at the hang-up when the last slave descriptor closes: the
    // listener's, then this test's own (kept until the listener is done, so
    // the master never hangs up before the listener has opened the path).
    let Pty { mut master, slave } = pty;
    let answer = thread::spawn(move || {
        use nix::poll::PollFlags;
        let mut buf = [0u8; 256];
        loop {
            let ev = wait_for(&master, PollFlags::POLLIN, Duration::from_secs(60));
            if ev.intersects(PollFlags::POLLHUP | PollFlags::POLLERR) || ev.is_empty() {
                break;
            }
            if let Ok(n) = master.read(&mut buf)
                && buf[..n].contains(&0)
            {
                let _ = write_all(&mut master, &v2);
            }
        }
    });
    let opts = ListenOptions::default();
    let e =
        listen_with(link.to_str().unwrap(), &opts, &AtomicBool::new(false), &mut io::sink(), &mut |_| {}).unwrap_err();
    drop(slave);
    answer.join().unwrap();
    assert!(matches!(e, ListenError::Version { theirs, .. } if theirs == PROTOCOL_VERSION + 1), "{e}");
    let want =
        format!("speaks protocol version {}; this cms-host speaks version {PROTOCOL_VERSION}", PROTOCOL_VERSION + 1);
    assert!(e.to_string().contains(&want), "{e}");
}

// ------------------------------------------------------------- robustness

/// Random bytes on the port are CRC errors, not a head of another version:
/// the listener gives up with "no Hello", never "speaks protocol version
/// 51" (the version byte was once checked before the CRC).
#[test]
fn random_bytes_are_not_a_version_mismatch() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyNoise");
    let Pty { mut master, slave } = plug(&link);
    // Garbage (zeros included, so it splits into many "frames") for every
    // command, until the listener hangs up.
    let noise = thread::spawn(move || {
        use nix::poll::PollFlags;
        let mut rng = cms_study::Rng::new(51);
        let mut buf = [0u8; 256];
        loop {
            let ev = wait_for(&master, PollFlags::POLLIN, Duration::from_secs(60));
            if ev.intersects(PollFlags::POLLHUP | PollFlags::POLLERR) || ev.is_empty() {
                break;
            }
            if master.read(&mut buf).is_ok() {
                let g: Vec<u8> = (0..2000).map(|_| (rng.next_u64() % 64) as u8).collect();
                let _ = write_all(&mut master, &g);
            }
        }
    });
    let opts = ListenOptions::default();
    let o = cms_host::device::listen::session(
        link.to_str().unwrap(),
        &opts,
        &AtomicBool::new(false),
        &mut io::sink(),
        &mut |_| {},
        &mut cms_host::device::listen::Quiet,
    );
    drop(slave);
    noise.join().unwrap();
    let e = o.result.unwrap_err();
    assert!(matches!(e, ListenError::NoHello { .. }), "{e}");
    assert!(!e.to_string().contains("protocol version"), "{e}");
}

/// The port hangs up for good while streaming: the listener gives up after
/// `--reconnect-timeout` with exit 3, and still prints its summary first.
#[test]
fn cli_a_hang_up_still_prints_the_summary() {
    let dir = tempfile::tempdir().unwrap();
    let served = Served::with_plan(dir.path(), Plan { hang_up: Some(20), ..small_plan() });
    let out = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json", "--reconnect-timeout", "0.5"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    served.finish();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    let printed = String::from_utf8_lossy(&out.stdout).lines().count();
    assert!(printed > 0);
    assert!(stderr.contains(&format!("listen: frames: {printed} ")), "{stderr}");
    let last = stderr.lines().last().unwrap();
    assert!(last.starts_with("error: lost ") && last.contains("did not come back within 0.5 s"), "{stderr}");
}

/// Profiles `--json` printed, by sequence number.
fn printed_seqs(stdout: &[u8]) -> Vec<u32> {
    String::from_utf8_lossy(stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["seq"].as_u64())
        .map(|s| s as u32)
        .collect()
}

/// Reads `child`'s stdout until `n` whole lines have arrived; returns them.
fn read_lines(stdout: &mut impl Read, n: usize) -> Vec<u8> {
    let mut got = Vec::new();
    let mut buf = [0u8; 65536];
    while got.iter().filter(|&&b| b == b'\n').count() < n {
        let k = stdout.read(&mut buf).unwrap();
        assert!(k > 0, "listen ended early");
        got.extend_from_slice(&buf[..k]);
    }
    got
}

/// Ctrl-C twice within microseconds: still the summary, exit 0, and every
/// frame printed is in the recording (a second press once exited 130 at
/// once, without either).
#[test]
fn cli_ctrl_c_twice_still_ends_with_the_summary() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let rec = dir.path().join("twice.cmsrec");
    let mut child = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json", "--record"])
        .arg(&rec)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut got = read_lines(&mut stdout, 5);
    let pid = Pid::from_raw(child.id() as i32);
    kill(pid, Signal::SIGINT).unwrap();
    kill(pid, Signal::SIGINT).unwrap();
    stdout.read_to_end(&mut got).unwrap();
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    served.finish();
    assert!(status.success(), "{status:?}: {stderr}");
    assert!(stderr.contains("listen: frames: "), "{stderr}");
    let printed = printed_seqs(&got);
    let (recorded, stats, _) = recorded_profiles(&rec);
    assert!(printed.len() >= 5);
    assert!(printed.iter().all(|s| recorded.contains(s)), "printed {printed:?}, recorded {recorded:?}");
    assert_eq!(stats.damaged, 0);
}

/// `kill -9` during `listen sim --record --json`: the recording holds at
/// least every frame printed but the one in flight (it holds all of them:
/// frames are written before they are printed). A few tries, each killed
/// after a different number of frames.
#[test]
fn cli_kill_9_loses_at_most_the_frame_in_flight() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let dir = tempfile::tempdir().unwrap();
    for (k, n) in [7usize, 13, 22, 31, 40].into_iter().enumerate() {
        let rec = dir.path().join(format!("kill{k}.cmsrec"));
        let mut child = Process::new(bin())
            .args(["listen", "sim", "--json", "--rate", "100", "--record"])
            .arg(&rec)
            .env("CMS_SIM_STATE", dir.path().join("sim-state"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut stdout = child.stdout.take().unwrap();
        let got = read_lines(&mut stdout, n);
        kill(Pid::from_raw(child.id() as i32), Signal::SIGKILL).unwrap();
        let _ = child.wait();
        // The whole lines printed before the kill.
        let whole = &got[..=got.iter().rposition(|&b| b == b'\n').unwrap()];
        let printed = printed_seqs(whole);
        let (recorded, stats, _) = recorded_profiles(&rec);
        let kept = printed.iter().filter(|s| recorded.contains(s)).count();
        eprintln!(
            "kill -9 try {k}: {} printed, {} recorded, {kept} of the printed kept, {} truncated bytes",
            printed.len(),
            recorded.len(),
            stats.truncated_tail
        );
        assert!(printed.len() >= n);
        assert!(kept + 1 >= printed.len(), "try {k}: printed {printed:?}, recorded {recorded:?}");
    }
}

/// The last JSON frame of a `listen … --json` run that must succeed.
fn last_json_frame(args: &[&str]) -> serde_json::Value {
    let out = crate::common::run(args);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    let last = String::from_utf8(out.stdout).unwrap().lines().last().unwrap().to_owned();
    serde_json::from_str(&last).unwrap()
}

/// `--window`: the simulated head seeks each laser's stripes in its window
/// only (its lines stand near columns 310, 379 and 450): windows around
/// them keep every point; laser 1's window moved off its line loses them.
#[test]
fn cli_listen_sets_search_windows() {
    let points = |windows: &[&str]| -> Vec<usize> {
        let mut args = vec!["listen", "sim", "--frames", "2", "--json"];
        for w in windows {
            args.extend(["--window", w]);
        }
        let v = last_json_frame(&args);
        v["lasers"].as_array().unwrap().iter().map(|l| l["points"].as_array().unwrap().len()).collect()
    };
    assert_eq!(points(&["0:278-342", "1:347-411", "2:418-482"]), [480, 480, 480]);
    // Two stripes a row for three lit lasers: the head gives each to the
    // laser whose last position is nearest (`pipeline::assign`), not by
    // window; one laser gets none.
    let moved = points(&["0:278-342", "1:600-664", "2:418-482"]);
    assert_eq!(moved.iter().sum::<usize>(), 960, "{moved:?}");
    assert!(moved.contains(&0), "{moved:?}");
    // Windows from the calibration's working range hold every line.
    let cal = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v3/cal.toml");
    assert_eq!(points(&[]), [480, 480, 480]);
    let out = crate::common::run(&["listen", "sim", "--frames", "2", "--windows-from", cal.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("listen: search windows from "), "{err}");
    assert!(err.contains("listen: frames: 2 "), "{err}");
    // A window the head refuses (past the 752-px row) ends the listener.
    let out = crate::common::run(&["listen", "sim", "--frames", "2", "--window", "0:700-800"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("SetWindows"), "{}", String::from_utf8_lossy(&out.stderr));
}

/// `--track PX` with windows: the simulated head's windows follow their
/// lines and keep every point, the lines' positions those of the same
/// windows untracked (the head standing still, so two runs see the same
/// rail; its noise differs, so within 0.05 px); a track the head does not
/// take, or one without windows, is bad usage (exit 2, one `error:` line).
#[test]
fn cli_listen_tracks_search_windows() {
    let run = |extra: &[&str]| -> Vec<Vec<f64>> {
        let mut args = vec!["listen", "sim", "--frames", "2", "--json", "--sim-speed-mm-s", "0"];
        args.extend(["--window", "0:278-342", "--window", "1:347-411", "--window", "2:418-482"]);
        args.extend(extra);
        let v = last_json_frame(&args);
        v["lasers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| l["points"].as_array().unwrap().iter().map(|p| p["position_px"].as_f64().unwrap()).collect())
            .collect()
    };
    let (plain, tracked) = (run(&[]), run(&["--track", "8"]));
    assert!(tracked.iter().all(|l| l.len() == 480), "every row of every line");
    for (a, b) in plain.iter().zip(&tracked) {
        let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst <= 0.05, "{worst} px");
    }
    for (args, needle) in [
        (vec!["--window", "0:278-342", "--track", "1"], "a track is 0 (off) or 2..=64"),
        (vec!["--window", "0:278-342", "--track", "x"], "a track is"),
        (vec!["--track", "8"], "--track follows search windows"),
    ] {
        let mut a = vec!["listen", "sim", "--frames", "2"];
        a.extend(args.iter().copied());
        let out = crate::common::run(&a);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error: ")).collect();
        assert!(errors.len() == 1 && errors[0].contains(needle), "{args:?}: {stderr}");
    }
}

/// `--rows FIRST:COUNT` / `--row-skip N` on the simulated head (standing
/// still, so two runs see the same rail): one row in two gives half the
/// rows a frame, numbered by their sensor rows, at the full readout's
/// metric positions along the rail (and heights) within the noise; a
/// window one in four gives its rows only. Values that cannot be a
/// readout are bad usage (exit 2, one `error:` line): a skip of 3 or a
/// malformed window at once, a window that does not fit the head's 480
/// rows once the head has said its height.
#[test]
fn cli_listen_reads_a_row_window_and_a_row_skip() {
    type Points = Vec<std::collections::BTreeMap<u64, (f64, f64)>>;
    let frame = |extra: &[&str]| -> Points {
        let mut args = vec!["listen", "sim", "--frames", "2", "--json", "--sim-speed-mm-s", "0"];
        args.extend(extra);
        let v = last_json_frame(&args);
        v["lasers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| {
                let point = |p: &serde_json::Value| {
                    let f = |k: &str| p[k].as_f64().unwrap_or_else(|| panic!("{k} of {p}"));
                    (p["row"].as_u64().unwrap(), (f("along_mm"), f("height_um")))
                };
                l["points"].as_array().unwrap().iter().map(point).collect()
            })
            .collect()
    };
    let full = frame(&[]);
    assert!(full.iter().all(|l| l.keys().copied().eq(0..480)), "every row of every laser");
    let half = frame(&["--row-skip", "2"]);
    let mut worst = (0.0f64, 0.0f64);
    for (k, l) in half.iter().enumerate() {
        assert!(l.keys().copied().eq((0..480).step_by(2)), "laser {k}: {:?}", l.keys().collect::<Vec<_>>());
        for (r, &(along, height)) in l {
            let (a, h) = full[k][r];
            worst = (worst.0.max((along - a).abs()), worst.1.max((height - h).abs()));
        }
    }
    // Rows are 0.144 mm apart along the rail: the same row lands within a
    // few µm (the stripe's noise moves it across the row, not along); the
    // heights differ by the two frames' noise.
    assert!(worst.0 <= 0.005 && worst.1 <= 20.0, "worst along {} mm, height {} µm", worst.0, worst.1);
    let pitch = half[1][&2].0 - half[1][&0].0;
    assert!((0.2..0.4).contains(&pitch.abs()), "two rows along the rail: {pitch} mm");
    let window = frame(&["--rows", "100:200", "--row-skip", "4"]);
    assert!(window.iter().all(|l| l.keys().copied().eq((100..300).step_by(4))), "{:?}", window[0].keys());
    let out = crate::common::run(&["listen", "sim", "--frames", "1", "--rows", "100:200", "--row-skip", "4"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("listen: rows: sensor rows 100..300, one in 4 (50 a frame)"), "{stderr}");

    for (args, needle) in [
        (["--rows", "0:480", "--row-skip", "3"], "row skip is 1, 2 or 4"),
        (["--rows", "0-480", "--row-skip", "1"], "FIRST:COUNT"),
        (["--rows", "0:479", "--row-skip", "2"], "whole number"),
        (["--rows", "400:200", "--row-skip", "1"], "ends past"),
    ] {
        let mut a = vec!["listen", "sim", "--frames", "2"];
        a.extend(args);
        let out = crate::common::run(&a);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error: ")).collect();
        assert!(errors.len() == 1 && errors[0].contains(needle), "{args:?}: {stderr}");
    }
}
