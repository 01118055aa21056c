//! `cms-host simulate` end to end: the binary is spawned, its pty is opened
//! like a serial port, and the test speaks the wire protocol to it.

use std::fs::{File, OpenOptions};
use std::io::{BufRead as _, BufReader, Read as _, Write as _};
use std::os::fd::AsFd as _;
use std::os::unix::fs::OpenOptionsExt as _;
use std::process::{Child, Command as Process, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::{Duration, Instant};

use cms_core::protocol::{
    Command, DeviceMsg, ErrorCode, FrameReader, HeadState, HostMsg, LaserPattern, MAX_COMMAND_FRAME, MAX_FRAME,
    Profile, Start, encode,
};
use cms_host::sim::scene::{Scene, Shot};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

const BIN: &str = env!("CARGO_BIN_EXE_cms-host");

/// A running `cms-host simulate` and a connection to its pty. Dropping it
/// kills the child.
struct Sim {
    child: Child,
    port: File,
    rx: Receiver<DeviceMsg>,
    seq: u16,
    path: String,
    beat: Instant,
}

impl Sim {
    /// `simulate ARGS`, in incoherent light unless ARGS give one (the
    /// profiles are compared with the clean stripes' truth).
    fn spawn(args: &[&str]) -> Sim {
        let light = (!args.iter().any(|a| a.starts_with("--light"))).then_some("--light=incoherent");
        let mut child = Process::new(BIN)
            .arg("simulate")
            .args(light)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn cms-host simulate");
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut path = String::new();
        stdout.read_line(&mut path).expect("first line of stdout");
        let path = path.trim().to_string();
        assert!(path.starts_with("/dev/"), "first stdout line is not a device path: {path:?}");
        let port = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY)
            .open(&path)
            .unwrap_or_else(|e| panic!("open {path}: {e}"));
        let mut t = tcgetattr(port.as_fd()).unwrap();
        cfmakeraw(&mut t);
        tcsetattr(port.as_fd(), SetArg::TCSANOW, &t).unwrap();
        let (tx, rx) = channel();
        let mut reader_port = port.try_clone().unwrap();
        std::thread::spawn(move || {
            let mut reader: Box<FrameReader<MAX_FRAME>> = Box::default();
            let mut buf = vec![0u8; 65536];
            loop {
                match reader_port.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => {
                        let mut gone = false;
                        reader.feed::<DeviceMsg, _>(&buf[..n], |m| {
                            let m = m.expect("every frame from the simulator decodes");
                            gone |= tx.send(m).is_err();
                        });
                        if gone {
                            return;
                        }
                    }
                }
            }
        });
        Sim { child, port, rx, seq: 0, path, beat: Instant::now() }
    }

    fn send(&mut self, msg: HostMsg) -> u16 {
        self.seq += 1;
        self.beat = Instant::now(); // any command resets the head's watchdog
        let mut out = [0u8; MAX_COMMAND_FRAME];
        let frame = encode(&Command { seq: self.seq, msg }, &mut out).unwrap();
        self.port.write_all(frame).unwrap();
        self.seq
    }

    /// The next message that `pick` accepts, skipping others, within `timeout`.
    fn expect<T>(&self, timeout: Duration, what: &str, mut pick: impl FnMut(&DeviceMsg) -> Option<T>) -> T {
        let end = Instant::now() + timeout;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(left) {
                Ok(m) => {
                    if let Some(t) = pick(&m) {
                        return t;
                    }
                }
                Err(RecvTimeoutError::Timeout) => panic!("no {what} within {timeout:?}"),
                Err(RecvTimeoutError::Disconnected) => panic!("pty closed while waiting for {what}"),
            }
        }
    }

    fn ack(&self, seq: u16) {
        self.expect(Duration::from_secs(3), "Ack", |m| match m {
            DeviceMsg::Ack(s) if *s == seq => Some(()),
            DeviceMsg::Error { seq: Some(s), code } if *s == seq => panic!("command {seq} failed: {code}"),
            _ => None,
        })
    }

    fn start(&mut self, rate_hz: u16, pattern: LaserPattern) {
        let seq = self.send(HostMsg::Start(Start { rate_hz, laser_mask: 0b111, pattern }));
        self.ack(seq);
    }

    /// `n` profiles, sending a heartbeat every 200 ms meanwhile.
    fn profiles(&mut self, n: usize) -> Vec<Profile> {
        let mut got = Vec::new();
        let end = Instant::now() + Duration::from_secs(20);
        while got.len() < n {
            assert!(Instant::now() < end, "only {} of {n} profiles in 20 s", got.len());
            if self.beat.elapsed() > Duration::from_millis(200) {
                self.send(HostMsg::Heartbeat);
                self.beat = Instant::now();
            }
            match self.rx.recv_timeout(Duration::from_millis(50)) {
                Ok(DeviceMsg::Profile(p)) => got.push(p),
                Ok(DeviceMsg::Error { seq, code }) => panic!("error while streaming: {seq:?} {code}"),
                Ok(_) | Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => panic!("pty closed"),
            }
        }
        got
    }

    /// Sends SIGTERM and returns the exit status and stderr.
    fn terminate(mut self) -> (std::process::ExitStatus, String) {
        nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.child.id() as i32), nix::sys::signal::SIGTERM).unwrap();
        let end = Instant::now() + Duration::from_secs(5);
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            assert!(Instant::now() < end, "simulate did not exit within 5 s of SIGTERM");
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut err = String::new();
        self.child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
        (status, err)
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn hello_reports_the_reference_sensor() {
    let mut sim = Sim::spawn(&["--seed", "1"]);
    sim.send(HostMsg::GetInfo);
    let info = sim.expect(Duration::from_secs(3), "Hello", |m| match m {
        DeviceMsg::Hello(i) => Some(i.clone()),
        _ => None,
    });
    assert_eq!((info.sensor_width, info.sensor_height), (752, 480));
    assert_eq!(info.protocol, cms_core::protocol::PROTOCOL_VERSION);
    assert_eq!(info.board.as_str(), "cms-sim");
    assert_eq!(info.bits, 8);
    assert_eq!(info.detector.bits, 8, "the detector is configured for the camera's bit depth");
    assert!(sim.path.starts_with("/dev/pts/"), "{}", sim.path);
}

/// Per-laser points of a profile, as (row, position px).
fn tracks(p: &Profile) -> Vec<Vec<(u16, f64)>> {
    p.lasers.iter().map(|l| l.points.iter().map(|q| (q.row, q.position.to_f64())).collect()).collect()
}

/// Detected minus true stripe centre over a profile, px.
#[derive(Debug)]
#[allow(dead_code)] // read through Debug
struct Errors {
    n: usize,
    missing: usize,
    mean: f64,
    rms: f64,
    max: f64,
}

/// Compares a profile with the scene's truth at the odometer it reports
/// (the scene of `simulate --seed 1`, the default options).
fn truth_errors(p: &Profile) -> Errors {
    use std::sync::OnceLock;
    static SCENE: OnceLock<Scene> = OnceLock::new();
    let scene = SCENE.get_or_init(|| {
        let args = cms_host::sim::head::HeadOptions { seed: 1, ..Default::default() };
        Scene::new(cms_host::sim::head::sim_config(&args).unwrap()).unwrap()
    });
    let shot = Shot {
        frame_index: p.seq as u64,
        odometer_mm: p.odometer_um as f64 / 1000.0,
        exposure_us: p.exposure_us as f64,
        laser_mask: p.laser_mask,
    };
    let (mut n, mut missing, mut sum, mut sum2, mut max) = (0, 0, 0.0, 0.0, 0.0f64);
    for lp in &p.lasers {
        let mut rows = lp.points.iter().peekable();
        for r in 0..scene.height() {
            let t = scene.shot_row_truth(&shot, r).stripes[lp.laser as usize];
            match (t, rows.next_if(|q| q.row as usize == r)) {
                (Some(t), Some(q)) => {
                    let e = q.position.to_f64() - t.column_px;
                    n += 1;
                    sum += e;
                    sum2 += e * e;
                    max = max.max(e.abs());
                }
                (Some(_), None) => missing += 1,
                (None, Some(q)) => panic!("laser {} row {r}: a point where the scene has no stripe: {q:?}", lp.laser),
                (None, None) => {}
            }
        }
    }
    let nf = n.max(1) as f64;
    Errors { n, missing, mean: sum / nf, rms: (sum2 / nf).sqrt(), max }
}

#[test]
fn streams_three_stripes_per_frame_in_sequence() {
    let mut sim = Sim::spawn(&["--seed", "1"]);
    sim.start(30, LaserPattern::Simultaneous);
    let ps = sim.profiles(12);
    for w in ps.windows(2) {
        // Sequence numbers count frames sent: none lost on the link.
        assert_eq!(w[1].seq, w[0].seq + 1, "no lost frames");
        // Frames are due on a 33 333 µs grid from the Start; a loaded host
        // makes one late (or skipped), never early or twice in one slot.
        let slot = |p: &Profile| p.timestamp_us / 33_333;
        assert!(slot(&w[1]) > slot(&w[0]), "timestamps {} → {}", w[0].timestamp_us, w[1].timestamp_us);
        assert!(w[1].odometer_um >= w[0].odometer_um, "the head travels forwards");
    }
    for p in &ps {
        assert_eq!((p.part, p.parts, p.laser_mask), (0, 1, 0b111));
        assert_eq!(p.lasers.len(), 3);
        let t = tracks(p);
        for (k, pts) in t.iter().enumerate() {
            assert_eq!(p.lasers[k].laser as usize, k);
            assert!(pts.len() >= 470, "laser {k}: {} of 480 rows", pts.len());
            assert!(pts.windows(2).all(|w| w[0].0 < w[1].0), "ascending rows");
            assert!(pts.iter().all(|&(_, x)| (0.0..752.0).contains(&x)), "inside the image");
            // A stripe is a smooth curve: row-to-row second differences are
            // sub-pixel (noise plus the rail's profile).
            let d2: Vec<f64> = pts.windows(3).map(|w| w[2].1 - 2.0 * w[1].1 + w[0].1).collect();
            let rms = (d2.iter().map(|d| d * d).sum::<f64>() / d2.len() as f64).sqrt();
            assert!(rms < 0.5, "laser {k}: row-to-row jitter {rms:.3} px RMS");
        }
        // Every point where the scene put its stripe.
        // (Measured: 1440 of 1440, RMS 0.016 px, max 0.07 px, bias 0.002 px.)
        let truth = truth_errors(p);
        assert_eq!(truth.missing, 0, "frame {}: {truth:?}", p.seq);
        assert!(truth.rms < 0.05 && truth.max < 0.25 && truth.mean.abs() < 0.01, "frame {}: {truth:?}", p.seq);
        // The stripes keep their order left to right and do not touch.
        let mean = |v: &Vec<(u16, f64)>| v.iter().map(|p| p.1).sum::<f64>() / v.len() as f64;
        let m: Vec<f64> = t.iter().map(mean).collect();
        assert!(m[0] + 20.0 < m[1] && m[1] + 20.0 < m[2], "stripe means {m:?}");
    }
}

#[test]
fn sequential_pattern_lights_one_laser_per_frame() {
    let mut sim = Sim::spawn(&["--seed", "2", "--rate", "60"]);
    sim.start(60, LaserPattern::Sequential);
    let ps = sim.profiles(6);
    for p in &ps {
        assert_eq!(p.lasers.len(), 1, "one laser per frame");
        assert_eq!(p.laser_mask, 1 << p.lasers[0].laser);
        assert!(p.lasers[0].points.len() >= 470, "{} points", p.lasers[0].points.len());
    }
    for w in ps.windows(2) {
        if w[1].seq == w[0].seq + 1 {
            assert_eq!(w[1].lasers[0].laser, (w[0].lasers[0].laser + 1) % 3, "in turn");
        }
    }
}

#[test]
fn a_start_faster_than_the_camera_is_refused() {
    let mut sim = Sim::spawn(&["--rate", "50"]);
    let seq = sim.send(HostMsg::Start(Start { rate_hz: 51, laser_mask: 0b111, pattern: LaserPattern::Simultaneous }));
    let code = sim.expect(Duration::from_secs(3), "Error", |m| match m {
        DeviceMsg::Error { seq: Some(s), code } if *s == seq => Some(*code),
        DeviceMsg::Ack(s) if *s == seq => panic!("a Start above --rate was accepted"),
        _ => None,
    });
    assert_eq!(code, ErrorCode::OutOfRange);
    sim.start(50, LaserPattern::Simultaneous);
    sim.profiles(2);
}

#[test]
fn missing_heartbeat_turns_the_lasers_off_within_1_3_s() {
    let mut sim = Sim::spawn(&["--seed", "1"]);
    sim.start(30, LaserPattern::Simultaneous);
    let last = Instant::now();
    sim.expect(Duration::from_secs(2), "Error HeartbeatLost", |m| match m {
        DeviceMsg::Error { seq: None, code: ErrorCode::HeartbeatLost } => Some(()),
        DeviceMsg::Error { seq, code } => panic!("unexpected error {seq:?} {code}"),
        _ => None,
    });
    let status = sim.expect(Duration::from_millis(500), "Status", |m| match m {
        DeviceMsg::Status(s) => Some(*s),
        _ => None,
    });
    let t = last.elapsed();
    // The head checks its watchdog between frames: allow one frame's
    // processing (tiny when optimised, ~0.25 s in a debug build).
    let frame = Duration::from_nanos(status.ns_per_row as u64 * 480);
    assert!(t < Duration::from_millis(1300) + frame && t > Duration::from_millis(900), "after {t:?}");
    assert_eq!(status.lasers_on, 0);
    assert_eq!(status.state, HeadState::Fault);
    assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
    // And no more profiles.
    std::thread::sleep(Duration::from_millis(200));
    while sim.rx.try_recv().is_ok() {}
    assert!(sim.rx.recv_timeout(Duration::from_millis(300)).is_err(), "silence after the fault");
}

#[test]
fn stop_is_acknowledged_and_turns_the_lasers_off() {
    let mut sim = Sim::spawn(&["--seed", "3"]);
    sim.start(30, LaserPattern::Simultaneous);
    sim.profiles(3);
    let seq = sim.send(HostMsg::Stop);
    sim.ack(seq);
    let status = sim.expect(Duration::from_secs(1), "Status", |m| match m {
        DeviceMsg::Status(s) => Some(*s),
        _ => None,
    });
    assert_eq!((status.state, status.lasers_on, status.fault), (HeadState::Idle, 0, None));
    assert!(status.frames >= 3);
    let (code, err) = sim.terminate();
    assert!(code.success(), "{code:?}: {err}");
    assert!(err.contains("info: lasers: 0b111"), "laser log: {err}");
    assert!(err.lines().last().is_some_and(|l| l.starts_with("simulate: served") && l.contains("lasers off")), "{err}");
}

#[test]
fn a_damaged_command_while_streaming_is_a_fault() {
    let mut sim = Sim::spawn(&["--seed", "1"]);
    sim.start(30, LaserPattern::Simultaneous);
    sim.port.write_all(&[0x05, 0x01, 0x02, 0x03, 0x04, 0x00]).unwrap();
    let code = sim.expect(Duration::from_secs(2), "Error", |m| match m {
        DeviceMsg::Error { seq: None, code } => Some(*code),
        _ => None,
    });
    assert!(matches!(code, ErrorCode::Crc | ErrorCode::Decode), "{code:?}");
    let status = sim.expect(Duration::from_millis(500), "Status", |m| match m {
        DeviceMsg::Status(s) => Some(*s),
        _ => None,
    });
    assert_eq!((status.state, status.lasers_on), (HeadState::Fault, 0));
    // The host can start again.
    sim.start(30, LaserPattern::Simultaneous);
    sim.profiles(2);
}

#[test]
fn sigterm_with_lasers_on_exits_cleanly() {
    let mut sim = Sim::spawn(&[]);
    sim.start(30, LaserPattern::Simultaneous);
    sim.profiles(2);
    let (code, err) = sim.terminate();
    assert!(code.success(), "{code:?}: {err}");
    assert!(err.contains("info: lasers off"), "{err}");
    assert!(err.contains("simulate: served"), "{err}");
}

#[test]
fn bad_options_exit_2_with_one_line() {
    for args in [
        &["--rate", "0"][..],
        &["--rate", "abc"],
        &["--bits", "9"],
        &["--preset", "huge"],
        &["--corrugation", "50"],
        &["--corrugation", "-5:30"],
        &["--corrugation", "50:nan"],
        &["--laser-gain", "1,2"],
        &["--laser-gain", "1,x,1"],
        &["--hot-pixels", "1.5"],
        &["--noise", "-1"],
        &["--seed", "-1"],
        &["--speed-mm-s", "inf"],
    ] {
        let out = Process::new(BIN).arg("simulate").args(args).stdin(Stdio::null()).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(out.stdout.is_empty(), "{args:?}: no pty path on a usage error");
        assert!(err.starts_with("error: "), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn in_process_head_serves_through_its_pty() {
    let (path, handle) = cms_host::sim::head::spawn_on_pty(&cms_host::sim::head::HeadOptions::default()).unwrap();
    assert!(handle.is_running());
    let port = OpenOptions::new().read(true).write(true).custom_flags(nix::libc::O_NOCTTY).open(&path).unwrap();
    let mut t = tcgetattr(port.as_fd()).unwrap();
    cfmakeraw(&mut t);
    tcsetattr(port.as_fd(), SetArg::TCSANOW, &t).unwrap();
    let mut out = [0u8; MAX_COMMAND_FRAME];
    let frame = encode(&Command { seq: 7, msg: HostMsg::GetInfo }, &mut out).unwrap();
    (&port).write_all(frame).unwrap();
    let mut reader: Box<FrameReader<MAX_FRAME>> = Box::default();
    let mut buf = [0u8; 4096];
    let mut hello = None;
    while hello.is_none() {
        let n = (&port).read(&mut buf).unwrap();
        reader.feed::<DeviceMsg, _>(&buf[..n], |m| {
            if let Ok(DeviceMsg::Hello(i)) = m {
                hello = Some(i);
            }
        });
    }
    assert_eq!(hello.unwrap().sensor_width, 752);
    let summary = handle.stop().unwrap();
    assert_eq!(summary.commands, 1);
    assert_eq!(summary.lasers_at_exit, 0);
}

#[test]
fn paper_preset_streams_a_frame_in_parts() {
    let mut sim = Sim::spawn(&["--preset", "paper", "--rate", "4"]);
    sim.send(HostMsg::GetInfo);
    let info = sim.expect(Duration::from_secs(5), "Hello", |m| match m {
        DeviceMsg::Hello(i) => Some(i.clone()),
        _ => None,
    });
    assert_eq!((info.sensor_width, info.sensor_height), (4752, 3168));
    if cfg!(debug_assertions) {
        // 15 Mpx a frame: a minute per frame unoptimised (CI tests --release).
        eprintln!("paper preset streaming: checked in optimised builds only");
        return;
    }
    sim.start(2, LaserPattern::Simultaneous);
    // One whole frame: 3168 rows in 7 parts of up to 480.
    let parts = sim.profiles(7);
    let first = parts.iter().position(|p| p.part == 0).expect("a frame's first part");
    let frame: Vec<&Profile> = parts[first..].iter().take_while(|p| p.seq == parts[first].seq).collect();
    assert_eq!((first, frame.len()), (0, 7), "the first frame whole");
    for (k, p) in frame.iter().enumerate() {
        assert_eq!((p.part as usize, p.parts), (k, 7));
        let rows = (3168 - 480 * k).min(480);
        for l in &p.lasers {
            assert!(l.points.iter().all(|q| (q.row as usize) / 480 == k), "rows of part {k}");
            assert!(l.points.len() * 10 > rows * 9, "part {k} laser {}: {} points", l.laser, l.points.len());
            // σ ≈ 15 px (12.4–19.5 over the working range). A saturated
            // point's width comes from its saturated run (a hot pixel on
            // the stripe's crest can saturate it): not a σ.
            let w: Vec<f64> = l
                .points
                .iter()
                .filter(|q| !q.flags.contains(cms_core::peak::Flags::SATURATED))
                .map(|q| q.width.to_f64())
                .collect();
            let (lo, hi) = w.iter().fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(lo > 10.0 && hi < 22.0, "σ ≈ 15 px: {lo}..{hi}");
        }
    }
    assert!(parts.iter().all(|p| p.parts == 7 && p.lasers.len() == 3));
}

#[test]
fn listen_sim_crosses_the_pty() {
    let out = Process::new(BIN)
        .args(["listen", "sim", "--sim-light=incoherent", "--frames", "30", "--json", "--sim-seed", "4"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    let seqs: Vec<u64> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["seq"].as_u64().unwrap())
        .collect();
    assert_eq!(seqs.len(), 30);
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
    let sim = err.lines().find(|l| l.starts_with("sim: served")).unwrap_or_else(|| panic!("no sim summary: {err}"));
    assert!(sim.ends_with("lasers off"), "{sim}");
    // The head's telemetry from its last status (the one after Stop: its
    // window may be a few ms since the last periodic status, so its rates
    // may be 0; the live line in host/tests/it/analyze/sim.rs checks them).
    let head = err.lines().find(|l| l.starts_with("listen: head (last status): ")).unwrap_or_else(|| panic!("{err}"));
    let rows_per_s: Result<u64, _> = head.split(": ").nth(2).unwrap().split(' ').next().unwrap().parse();
    assert!(rows_per_s.is_ok() && head.contains(" ns/row") && head.contains(" rows lost, backlog "), "{head}");
    assert!(head.contains("laser duty "), "{head}");
    // The simulator's options need PORT sim.
    let out = Process::new(BIN).args(["listen", "/dev/null", "--sim-seed", "3"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).starts_with("error: --sim-seed"));
}

/// A simulated head asked for more frames than its renderer makes runs at
/// the rate it sustains: the frames it could not render in time are not
/// called dropped (the head's count stays 0), the summary names the rate
/// as the simulator's limit, and the `sim:` line counts them as such.
#[test]
fn a_rate_the_simulator_cannot_render_is_named_as_its_own_limit() {
    let out = Process::new(BIN)
        .args(["listen", "sim", "--sim-light=incoherent", "--rate", "1000", "--duration", "3"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(err.contains("head dropped frames: 0"), "{err}");
    // In the summary and on the status line.
    let limit = err.lines().find(|l| l.starts_with("listen: simulator: rendering ")).unwrap_or_else(|| panic!("{err}"));
    assert!(limit.ends_with("frames/s of 1000 (the simulator's limit, not the head's)"), "{limit}");
    let status: Vec<&str> = err.lines().filter(|l| l.starts_with("streaming: ")).collect();
    assert!(status.iter().all(|l| l.contains(", dropped 0,")), "{err}");
    assert!(status.iter().any(|l| l.contains("frames/s of 1000 (the simulator's limit, not the head's)")), "{err}");
    let sim = err.lines().find(|l| l.starts_with("sim: served")).unwrap_or_else(|| panic!("{err}"));
    assert!(sim.contains("frame times passed while rendering (the simulator's limit at 1000 frames/s asked"), "{sim}");
    assert!(sim.contains(", 0 dropped by the head,"), "{sim}");
}
