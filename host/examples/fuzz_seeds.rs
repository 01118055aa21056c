//! Writes the seed corpus of the `decode` fuzz target: real frames of every
//! device message and every command, produced by `cms_core::pipeline::Head`
//! (the firmware's logic) with a small camera of three Gaussian stripes.
//!
//! ```text
//! cargo run -p cms-host --example fuzz_seeds -- fuzz/corpus/decode
//! ```
//!
//! One frame per file (named after its message; a few profiles in
//! protocol 4 too, as older recordings hold them), plus a few streams of
//! several frames (a handshake, a stream with garbage between frames).
//! Deterministic: the same files on every run.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use cms_core::pipeline::{Camera, Head, Identity, LaserDriver, default_detector};
use cms_core::protocol::{
    Calibration, Command, DeviceMsg, HostMsg, LaserPattern, MAX_FRAME, PROTOCOL_VERSION, Start, Trigger, encode, v4,
};
use cms_study::{Gauss, Rng, clean_row, quantise};

struct Cam {
    rows: Vec<Vec<u16>>,
    next: usize,
    odometer_um: i64,
}

impl Camera for Cam {
    type Error = ();
    fn width(&self) -> u16 {
        160
    }
    fn height(&self) -> u16 {
        12
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, _: u32, _: u8) -> Result<i64, ()> {
        self.odometer_um += 1_250;
        Ok(self.odometer_um)
    }
    fn read_row(&mut self, row: &mut [u16]) -> Result<(), ()> {
        row.copy_from_slice(&self.rows[self.next % self.rows.len()]);
        self.next += 1;
        Ok(())
    }
}

struct NoLasers;
impl LaserDriver for NoLasers {
    fn set(&mut self, _: u8) {}
}

fn frame<T: serde::Serialize>(m: &T) -> Result<Vec<u8>, String> {
    let mut out = vec![0u8; MAX_FRAME];
    encode(m, &mut out).map(|f| f.to_vec()).map_err(|e| format!("encoding: {e}"))
}

fn kind(m: &DeviceMsg) -> &'static str {
    match m {
        DeviceMsg::Hello(_) => "hello",
        DeviceMsg::Profile(_) => "profile",
        DeviceMsg::Status(_) => "status",
        DeviceMsg::Ack(_) => "ack",
        DeviceMsg::Error { .. } => "error",
        DeviceMsg::RawRows(_) => "rawrows",
    }
}

/// A seed file: its name and bytes.
type Seed = (String, Vec<u8>);

/// The seeds' head: a 160-pixel camera of 12 rows with three stripes.
fn seed_head() -> Result<(Box<Head<160, NoLasers>>, Cam), String> {
    let mut rng = Rng::new(1);
    let rows = (0..12)
        .map(|r| {
            let d = (r as f64 * 0.5).sin();
            let g = [
                Gauss { x0: 40.0 + d, sigma: 2.0, amplitude: 1200.0 },
                Gauss { x0: 80.0 - d, sigma: 2.5, amplitude: 1500.0 },
                Gauss { x0: 120.0 + d, sigma: 3.0, amplitude: 1800.0 },
            ];
            quantise(&clean_row(160, 100.0, &g), 6.0, 12, &mut rng)
        })
        .collect();
    let cam = Cam { rows, next: 0, odometer_um: 0 };
    let identity = Identity { firmware: "0.1.0", board: "seed" };
    let head: Box<Head<160, NoLasers>> =
        Box::new(Head::new(NoLasers, default_detector(), identity).map_err(|e| format!("head: {e:?}"))?);
    Ok((head, cam))
}

/// Every command the head takes, a few it refuses among them.
fn commands() -> [HostMsg; 18] {
    let calibration = Calibration {
        id: 7,
        intrinsics: [1400.0, 1400.0, 376.0, 240.0, 0.0],
        distortion: [-0.1, 0.01, 0.0, 0.0, 0.0],
        // Planes leaning 42° from the optical axis, lines 10 mm apart on a
        // rail top 200 mm below the camera.
        planes: [
            [0.743_144_8, 0.0, -0.669_130_6, -141.257_57],
            [0.743_144_8, 0.0, -0.669_130_6, -133.826_12],
            [0.743_144_8, 0.0, -0.669_130_6, -126.394_67],
        ],
        datum: [0.0, 0.0, -1.0, -200.0],
    };
    [
        HostMsg::GetInfo,
        HostMsg::SetExposure { exposure_us: 300 },
        HostMsg::SetDetector(default_detector()),
        HostMsg::SetCalibration(calibration),
        HostMsg::SetTrigger(Trigger::Distance { every_um: 5_000 }),
        HostMsg::SetTrigger(Trigger::Timed),
        HostMsg::GetInfo,
        HostMsg::Start(Start { rate_hz: 100, laser_mask: 0b111, pattern: LaserPattern::Simultaneous }),
        HostMsg::Heartbeat,
        HostMsg::Stop,
        HostMsg::Start(Start { rate_hz: 100, laser_mask: 0b101, pattern: LaserPattern::Sequential }),
        HostMsg::Stop,
        HostMsg::CaptureImage(0b010),
        HostMsg::Start(Start { rate_hz: 0, laser_mask: 0, pattern: LaserPattern::Simultaneous }), // refused
        HostMsg::SetReadout { first_row: 2, rows: 8, skip: 2 },
        HostMsg::SetReadout { first_row: 0, rows: 12, skip: 3 }, // refused
        HostMsg::SetTracking { half_width_px: 8 },
        HostMsg::SetTracking { half_width_px: 1 }, // refused
    ]
}

/// The commands' frames, named, and every message the head answered with
/// (the heartbeat rule's Error and Status at the end).
fn drive(head: &mut Head<160, NoLasers>, cam: &mut Cam) -> Result<(Vec<Seed>, Vec<DeviceMsg>), String> {
    let mut msgs: Vec<DeviceMsg> = Vec::new();
    let mut clock = || 0u64;
    let mut cmd_frames = Vec::new();
    let mut t = 0u64;
    for (seq, c) in commands().into_iter().enumerate() {
        let cmd = Command { seq: seq as u16, msg: c };
        cmd_frames.push((format!("cmd-{seq:02}"), frame(&cmd)?));
        t += 10_000;
        let streaming = matches!(cmd.msg, HostMsg::Start(_));
        head.handle(cmd, t, cam, &mut |m: &DeviceMsg| msgs.push(m.clone()));
        let polls = if streaming { 4 } else { 1 };
        for _ in 0..polls {
            t += 10_000;
            head.poll(t, cam, &mut clock, &mut |m: &DeviceMsg| msgs.push(m.clone()));
        }
    }
    // Silence: the heartbeat rule's Error and Status.
    head.handle(
        Command {
            seq: 99,
            msg: HostMsg::Start(Start { rate_hz: 10, laser_mask: 1, pattern: LaserPattern::Simultaneous }),
        },
        t,
        cam,
        &mut |m: &DeviceMsg| msgs.push(m.clone()),
    );
    head.poll(t + 2_000_000, cam, &mut clock, &mut |m: &DeviceMsg| msgs.push(m.clone()));

    Ok((cmd_frames, msgs))
}

/// The seed files: a few frames of each message kind, the commands, and
/// streams with garbage, a cut frame and another protocol version.
fn seed_files(cmd_frames: &[Seed], msgs: &[DeviceMsg]) -> Result<Vec<Seed>, String> {
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let mut count = std::collections::BTreeMap::<&str, usize>::new();
    for m in msgs {
        let k = kind(m);
        let n = count.entry(k).or_default();
        *n += 1;
        // A few of each kind are enough.
        if *n <= 3 {
            files.push((format!("dev-{k}-{n}"), frame(m)?));
        }
    }
    // Profiles of protocol 4, as recordings made before protocol 5 hold them.
    for (n, m) in msgs.iter().filter(|m| matches!(m, DeviceMsg::Profile(_))).take(3).enumerate() {
        let mut out = vec![0u8; v4::MAX_FRAME];
        let f = v4::encode(m, &mut out).map_err(|e| format!("cannot encode a version-4 profile: {e}"))?;
        files.push((format!("dev-profile-v4-{}", n + 1), f.to_vec()));
    }
    files.extend(cmd_frames.iter().cloned());
    // Streams: a handshake, and profiles with garbage and a cut frame.
    let mut stream = Vec::new();
    for m in msgs.iter().take(8) {
        stream.extend(frame(m)?);
    }
    files.push(("stream-handshake".into(), stream));
    let profiles: Vec<Vec<u8>> =
        msgs.iter().filter(|m| matches!(m, DeviceMsg::Profile(_))).take(3).map(frame).collect::<Result<_, _>>()?;
    let mut noisy = b"\x13\x37garbage\0".to_vec();
    for p in &profiles {
        noisy.extend_from_slice(p);
        noisy.extend_from_slice(&p[..p.len() / 3]);
        noisy.push(0);
    }
    files.push(("stream-noisy".into(), noisy));
    // A frame of another protocol version (re-framed by hand).
    let mut other = frame(&DeviceMsg::Ack(1))?;
    if other.len() > 2 && other[1] == PROTOCOL_VERSION {
        other[1] = PROTOCOL_VERSION + 1;
    }
    files.push(("dev-other-version".into(), other));
    Ok(files)
}

fn run(dir: &Path) -> Result<usize, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let (mut head, mut cam) = seed_head()?;
    let (cmd_frames, msgs) = drive(&mut head, &mut cam)?;
    let files = seed_files(&cmd_frames, &msgs)?;
    for (name, bytes) in &files {
        let p: PathBuf = dir.join(name);
        std::fs::write(&p, bytes).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    }
    Ok(files.len())
}

fn main() -> ExitCode {
    let dir = std::env::args_os().nth(1).map(PathBuf::from).unwrap_or_else(|| PathBuf::from("fuzz/corpus/decode"));
    match run(&dir) {
        Ok(n) => {
            println!("{n} seed files in {}", dir.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
