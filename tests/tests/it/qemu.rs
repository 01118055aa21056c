//! End to end on the emulated head: the firmware of `firmware/qemu` runs
//! `cms_core::pipeline::Head` on a Cortex-M under QEMU and streams frames
//! over the emulated UART; `cms-host`'s listener receives them through the
//! pseudo-terminal exactly as from a device; and every profile is checked
//! against the host's own run of the same pipeline on the same rows — every
//! peak's position, strength, width and flags, and the laser each was given
//! to, bit for bit.
//!
//! The rows are `cms_core::synthetic`'s: an integer-only scene that both
//! sides compute from what a `Profile` carries (odometer, laser mask,
//! exposure), so the host regenerates each received frame whatever the
//! emulator's timing was (which frames the head skipped, where it was).
//!
//! Needs `qemu-system-arm` (`.ci/run` installs it); builds the image with
//! cargo in `firmware/qemu` if it is missing or stale.

use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use cms_core::pipeline::{Head, Identity, LaserDriver, default_detector};
use cms_core::protocol::{
    Command, DeviceInfo, DeviceMsg, HeadState, HostMsg, LaserPattern, PROTOCOL_VERSION, Profile, Start, Status,
};
use cms_core::synthetic::{Scene, SceneCamera, SceneConfig};
use cms_host::device::listen::{ListenOptions, RowsRequest, Summary, listen_with};
use cms_host::device::qemu::{self, Machine, Qemu};
use cms_host::link::{Client, ClientError, Wait};

/// The emulated head's scene seed (`SCENE_SEED` in firmware/qemu/src/bin/head.rs).
const SCENE_SEED: u32 = 1;
/// Row length of the emulated sensor.
const WIDTH: usize = 752;

/// What one session with the emulated head brought back.
struct Session {
    info: DeviceInfo,
    profiles: Vec<Profile>,
    summary: Summary,
    /// The head's report after a last `Stop`.
    after_stop: Status,
    /// The readout the listener set (`None`: every row).
    readout: Option<RowsRequest>,
}

/// One emulated head at a time: two QEMUs on a 2-core machine slow each
/// other's frames (480 rows of about 110 000 instructions) towards the
/// listener's 2 s stall limit.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Starts the emulated head on `machine`, listens for `frames` frames with
/// `start`, and stops QEMU.
fn listen_to_qemu(machine: Machine, start: Start, frames: u64) -> Session {
    listen_to_qemu_reading(machine, start, frames, None)
}

/// [`listen_to_qemu`] with the listener's `SetReadout` (`None`: none).
fn listen_to_qemu_reading(machine: Machine, start: Start, frames: u64, readout: Option<RowsRequest>) -> Session {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let image = match qemu::find_image(qemu::HEAD_BIN, None) {
        Ok(i) => i,
        Err(e) => panic!("{e}"),
    };
    let mut q = match Qemu::start(machine, &image) {
        Ok(q) => q,
        Err(e) => panic!("{e}"),
    };
    let port = q.pty().to_str().expect("pty paths are ASCII").to_string();
    if let Err(e) = q.resume() {
        panic!("{e}");
    }
    let opts = ListenOptions { frames: Some(frames), start, readout, ..ListenOptions::default() };
    let mut info = None;
    let mut profiles = Vec::new();
    let summary = listen_with(&port, &opts, &AtomicBool::new(false), &mut std::io::sink(), &mut |m| match m {
        DeviceMsg::Hello(i) => info = Some(i.clone()),
        DeviceMsg::Profile(p) => profiles.push(p.clone()),
        _ => {}
    });
    // The listener gives the head 500 ms to report the lasers off after its
    // Stop; an emulated head busy with a frame may take longer. Ask again,
    // without a deadline that the emulator's speed could beat.
    let after_stop = status_after_stop(&port);
    let early = q.exited();
    let stderr = q.stderr_tail();
    q.stop();
    let summary = match summary {
        Ok(s) => s,
        Err(e) => panic!("listening to the emulated head: {e} (QEMU exited early: {early:?}; {stderr})"),
    };
    assert_eq!(early, None, "QEMU exited by itself: {stderr}");
    Session { info: info.expect("the head said Hello"), profiles, summary, after_stop, readout }
}

/// Sends `Stop` and returns the `Status` that follows its `Ack`.
fn status_after_stop(port: &str) -> Status {
    let mut client = Client::open(port, 115_200).expect("the pty opens again");
    let seq = client.send(HostMsg::Stop).expect("the head takes a Stop");
    let mut acked = false;
    let status = client.until("Stop", Wait::Within(Duration::from_secs(30)), |m| {
        Ok::<_, ClientError>(match m {
            DeviceMsg::Ack(s) if s == seq => {
                acked = true;
                None
            }
            DeviceMsg::Status(st) if acked => Some(st),
            _ => None,
        })
    });
    status.expect("a Status after the Ack of Stop within 30 s")
}

/// The laser enables of the host's replay (nothing to drive).
struct NoLasers;

impl LaserDriver for NoLasers {
    fn set(&mut self, _mask: u8) {}
}

/// Runs the host's own `Head` on the rows of every received frame and
/// compares its profile with the received one. Returns the peaks compared.
fn replay(s: &Session, start: Start) -> usize {
    let identity = Identity { firmware: "host-replay", board: "host" };
    let mut head: Box<Head<WIDTH, NoLasers>> = match Head::new(NoLasers, s.info.detector, identity) {
        Ok(h) => Box::new(h),
        Err(e) => panic!("the head's detector configuration is refused on the host: {e}"),
    };
    let scene = Scene::new(SceneConfig::reference(SCENE_SEED)).expect("reference scene");
    let mut camera = SceneCamera::new(scene);
    let mut sink = |_: &DeviceMsg| {};
    if let Some(r) = s.readout.map(|r| r.on(480).expect("a readout of the 480-row scene")) {
        let msg = HostMsg::SetReadout { first_row: r.first_row(), rows: r.rows(), skip: r.skip().factor() };
        head.handle(Command { seq: 1, msg }, 0, &camera, &mut sink);
    }
    head.handle(Command { seq: 1, msg: HostMsg::Start(start) }, 0, &camera, &mut sink);
    assert_eq!(head.state(), HeadState::Streaming);
    let period_us = 1_000_000 / start.rate_hz as u64;
    let mut peaks = 0;
    for (i, got) in s.profiles.iter().enumerate() {
        assert_eq!(got.parts, 1, "480 rows fit one profile");
        let t = (i as u64 + 1) * period_us;
        camera.travel_to(got.odometer_um);
        head.handle(Command { seq: 2, msg: HostMsg::Heartbeat }, t, &camera, &mut sink);
        let mut mine = Vec::new();
        head.poll(t, &mut camera, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(p) = m {
                mine.push(p.clone());
            }
        });
        assert_eq!(mine.len(), 1, "frame {i}: the replay made one profile");
        // What the link carries: the wire quantises positions, strengths,
        // widths and heights; the emulated head's values are those, decoded.
        let mut want = mine.remove(0).on_wire();
        // The only field that depends on the clock.
        want.timestamp_us = got.timestamp_us;
        if want != *got {
            for (a, b) in want.lasers.iter().zip(&got.lasers) {
                for (p, q) in a.points.iter().zip(&b.points) {
                    assert_eq!(p, q, "frame {i} (seq {}), laser {}: first differing point", got.seq, a.laser);
                }
            }
            assert_eq!(want, *got, "frame {i}: profile header or point counts differ");
        }
        peaks += got.lasers.iter().map(|l| l.points.len()).sum::<usize>();
    }
    peaks
}

fn check_session(s: &Session, start: Start, frames: u64, board: &str) -> usize {
    assert_eq!(s.info.protocol, PROTOCOL_VERSION);
    assert_eq!(s.info.board.as_str(), board);
    assert_eq!((s.info.sensor_width, s.info.sensor_height, s.info.bits), (752, 480, 12));
    assert_eq!(s.info.detector, default_detector());
    assert_eq!(s.summary.frames, frames);
    assert_eq!(s.profiles.len() as u64, frames, "one profile per frame");
    let l = &s.summary.link;
    assert_eq!((l.crc_errors, l.decode_errors, l.overflows, l.discarded_bytes), (0, 0, 0, 0), "a clean link");
    let sum = &s.summary;
    assert_eq!((sum.reconnects, sum.stalls, sum.head_restarts), (0, 0, 0), "{sum}");
    assert_eq!((s.after_stop.state, s.after_stop.lasers_on), (HeadState::Idle, 0), "lasers off after a stop");
    // Consecutive frames of the head, travelling forwards.
    for (k, w) in s.profiles.windows(2).enumerate() {
        assert_eq!(w[1].seq, w[0].seq + 1, "frame {k}");
        assert!(w[1].odometer_um > w[0].odometer_um, "frame {k}: the head travels");
    }
    let peaks = replay(s, start);
    // Every lit laser's stripe is found in every row read of this scene.
    let rows = s.readout.map_or(480, |r| usize::from(r.on(480).unwrap().rows_read()));
    let lit_per_frame: usize = s.profiles.iter().map(|p| p.laser_mask.count_ones() as usize * rows).sum();
    assert_eq!(peaks, lit_per_frame, "a peak per lit laser per row");
    peaks
}

#[test]
fn every_peak_of_the_emulated_m4_equals_the_hosts() {
    let start = Start { rate_hz: 30, laser_mask: 0b111, pattern: LaserPattern::Simultaneous };
    let s = listen_to_qemu(Machine::An386, start, 4);
    let peaks = check_session(&s, start, 4, "qemu-mps2-an386");
    assert_eq!(peaks, 4 * 3 * 480);
    eprintln!("mps2-an386: {} frames, {peaks} peaks equal to the host's", s.profiles.len());
}

#[test]
fn every_peak_of_the_emulated_m7_equals_the_hosts_with_lasers_in_turn() {
    let start = Start { rate_hz: 20, laser_mask: 0b101, pattern: LaserPattern::Sequential };
    let s = listen_to_qemu(Machine::An500, start, 4);
    let masks: Vec<u8> = s.profiles.iter().map(|p| p.laser_mask).collect();
    assert_eq!(masks, [0b001, 0b100, 0b001, 0b100], "one laser per frame, in turn");
    let peaks = check_session(&s, start, 4, "qemu-mps2-an500");
    eprintln!("mps2-an500: {} frames, {peaks} peaks equal to the host's", s.profiles.len());
}

/// `SetReadout` on the emulated head: rows 40..440 one in two, each frame
/// 200 rows a laser at sensor rows 40, 42, …, 438, bit for bit the host's
/// run of the same readout.
#[test]
fn the_emulated_head_reads_a_row_window_one_row_in_two() {
    let start = Start { rate_hz: 30, laser_mask: 0b111, pattern: LaserPattern::Simultaneous };
    let readout = RowsRequest { first_row: 40, rows: Some(400), skip: 2 };
    let s = listen_to_qemu_reading(Machine::An386, start, 3, Some(readout));
    let peaks = check_session(&s, start, 3, "qemu-mps2-an386");
    assert_eq!(peaks, 3 * 3 * 200);
    for p in &s.profiles {
        assert!(p.lasers.iter().all(|l| l.points.iter().map(|q| q.row).eq((40..440).step_by(2))), "seq {}", p.seq);
    }
}
