//! Recordings: the writer, the reader on damaged files, export and info, and
//! a bounded stable-Rust fuzz loop of the frame reader.

use cms_host::progress::Silent;
use std::io::Write;
use std::path::Path;
use std::process::Command as Process;

use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::pipeline::default_detector;
use cms_core::protocol::{
    Command, DeviceInfo, DeviceMsg, FrameReader, HeadState, HostMsg, LaserPoints, MAX_COMMAND_FRAME, MAX_FRAME,
    MAX_READ_FRAME, Metric, PROTOCOL_VERSION, Point, Profile, Status, StoreHealth, WireError, encode,
};
use cms_host::link::Deframer;
use cms_host::recording::{self, HEADER_LEN, Info, Recorder, ScanStats};
use cms_study::Rng;
use proptest::prelude::*;

/// Runs `f` on a thread with a 64 MB stack. Decoding one `DeviceMsg` (46 KB
/// of nested heapless vectors) takes 1–2 MB of stack in an unoptimised build,
/// which with the test's own frames exceeds a test thread's 2 MB.
fn big<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    std::thread::scope(|s| {
        let h = std::thread::Builder::new().stack_size(64 << 20).spawn_scoped(s, f).expect("thread");
        match h.join() {
            Ok(v) => v,
            Err(e) => std::panic::resume_unwind(e),
        }
    })
}

fn frame<T: serde::Serialize>(msg: &T) -> Vec<u8> {
    let mut out = vec![0u8; MAX_FRAME];
    encode(msg, &mut out).unwrap().to_vec()
}

/// A profile as a recording holds it (the wire quantises: `on_wire`).
fn profile(seq: u32, rows: u16) -> DeviceMsg {
    let mut lasers = heapless::Vec::new();
    for k in 0..3u8 {
        let mut points = heapless::Vec::new();
        for r in 0..rows {
            let um = (k == 1 && r == 0).then_some(Metric { along_um: -1200, height_nm: 35_250 });
            points
                .push(Point {
                    row: r,
                    position: Px::from_f64(100.0 + 150.0 * k as f64 + r as f64 * 0.01 + seq as f64 * 0.001),
                    strength: 1000 + r,
                    width: Px::from_f64(2.5),
                    flags: if r == 1 { Flags::LOW_CONFIDENCE } else { Flags::NONE },
                    metric: um,
                })
                .unwrap();
        }
        lasers.push(LaserPoints { laser: k, points }).unwrap();
    }
    DeviceMsg::Profile(
        Profile {
            seq,
            part: 0,
            parts: 1,
            timestamp_us: 1_000 + seq as u64 * 10_000,
            odometer_um: seq as i64 * 2_500 - 1,
            exposure_us: 200,
            laser_mask: 7,
            lasers,
        }
        .on_wire(),
    )
}

fn hello() -> DeviceMsg {
    DeviceMsg::Hello(DeviceInfo {
        firmware: heapless::String::try_from("1.2.3").unwrap(),
        protocol: PROTOCOL_VERSION,
        board: heapless::String::try_from("bench").unwrap(),
        sensor_width: 752,
        sensor_height: 480,
        bits: 12,
        detector: default_detector(),
        calibration_id: 0,
        store: StoreHealth::Volatile,
    })
}

fn status() -> DeviceMsg {
    DeviceMsg::Status(Status {
        state: HeadState::Streaming,
        lasers_on: 7,
        frames: 3,
        frame_rate_millihz: 30_000,
        rows_per_s: 14_400,
        dropped_frames: 2,
        ns_per_row: 900,
        cycles_per_row: 0,
        dropped_rows: 0,
        link_backlog_bytes: 0,
        laser_duty_permille: 0,
        heartbeat_age_ms: 100,
        fault: None,
    })
}

/// A recording's bytes: header and frames; and the frames' byte ranges.
fn recording(msgs: &[DeviceMsg]) -> (Vec<u8>, Vec<std::ops::Range<usize>>) {
    let mut b = recording::header().to_vec();
    let mut ranges = Vec::new();
    for m in msgs {
        let f = frame(m);
        ranges.push(b.len()..b.len() + f.len());
        b.extend_from_slice(&f);
    }
    (b, ranges)
}

fn scan(bytes: &[u8]) -> (Vec<DeviceMsg>, ScanStats) {
    let mut got = Vec::new();
    let s = recording::scan_reader(Path::new("mem"), bytes, |m| {
        got.push(m.clone());
        Ok(())
    })
    .expect("a valid header");
    (got, s)
}

fn seqs(msgs: &[DeviceMsg]) -> Vec<u32> {
    msgs.iter().filter_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.seq) } else { None }).collect()
}

// ------------------------------------------------------------------ writer

/// Creating writes the header once; reopening validates it and appends.
#[test]
fn create_then_append() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.cmsrec");
        let mut r = Recorder::open(&path).unwrap();
        r.write_frame(&frame(&hello())).unwrap();
        r.write_frame(&frame(&profile(0, 4))).unwrap();
        r.finish().unwrap();
        drop(r);
        let mut r = Recorder::open(&path).unwrap();
        r.write_frame(&frame(&profile(1, 4))).unwrap();
        r.finish().unwrap();
        drop(r);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"CMSREC\0\x01");
        assert_eq!(bytes.windows(8).filter(|w| w == b"CMSREC\0\x01").count(), 1);
        let (msgs, s) = scan(&bytes);
        assert_eq!(msgs.len(), 3);
        assert_eq!(seqs(&msgs), [0, 1]);
        assert_eq!((s.damaged, s.truncated_tail), (0, 0));
    })
}

/// Appending to a file whose writer crashed mid-frame closes the fragment
/// first: it becomes one damaged frame and the new frames are all intact.
#[test]
fn append_after_a_crash_mid_frame() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.cmsrec");
        let (mut bytes, _) = recording(&[profile(0, 8), profile(1, 8)]);
        let f = frame(&profile(2, 8));
        bytes.extend_from_slice(&f[..f.len() / 2]);
        std::fs::write(&path, &bytes).unwrap();
        let (_, s) = scan(&bytes);
        assert_eq!(s.truncated_tail, (f.len() / 2) as u64);

        let mut r = Recorder::open(&path).unwrap();
        r.write_frame(&frame(&profile(3, 8))).unwrap();
        r.finish().unwrap();
        let (msgs, s) = scan(&std::fs::read(&path).unwrap());
        assert_eq!(seqs(&msgs), [0, 1, 3]);
        assert_eq!((s.damaged, s.truncated_tail), (1, 0));
    })
}

/// A file that is not a recording is refused and left untouched.
#[test]
fn refuses_to_append_to_a_foreign_file() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        for (name, content) in [("short", &b"CMSREC"[..]), ("text", &b"hello world, not a recording"[..])] {
            let path = dir.path().join(name);
            std::fs::write(&path, content).unwrap();
            let e = Recorder::open(&path).unwrap_err().to_string();
            assert!(e.contains("not a CMS recording") && e.contains("refusing to append"), "{e}");
            assert_eq!(std::fs::read(&path).unwrap(), content);
        }
        let path = dir.path().join("v9");
        let mut h = recording::header();
        h[8] = 9;
        std::fs::write(&path, h).unwrap();
        let e = Recorder::open(&path).unwrap_err().to_string();
        assert!(e.contains("format version 9"), "{e}");
    })
}

/// Every frame is in the file when `write_frame` returns, without `tick`
/// or `finish`: a writer that dies (no destructor) leaves a valid file
/// holding every frame it wrote.
#[test]
fn every_frame_is_in_the_file_at_once_and_survives_a_crash() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.cmsrec");
        let mut r = Recorder::open(&path).unwrap();
        for s in 0..5 {
            r.write_frame(&frame(&profile(s, 16))).unwrap();
            let now = std::fs::read(&path).unwrap();
            assert_eq!(seqs(&scan(&now).0), (0..=s).collect::<Vec<_>>());
        }
        r.write_frame(&frame(&profile(5, 16))).unwrap();
        std::mem::forget(r); // a crash: nothing is ever finished
        let (msgs, s) = scan(&std::fs::read(&path).unwrap());
        assert_eq!(seqs(&msgs), [0, 1, 2, 3, 4, 5]);
        assert_eq!((s.damaged, s.truncated_tail), (0, 0));
    })
}

/// docs/link-and-recordings.md: "Zeros a file system may leave after a
/// power loss are empty frames and are skipped." A recording with a block
/// of zeros where its tail was lost, then appended to, reads every frame
/// before and after the zeros, none counted damaged or truncated.
#[test]
fn zeros_a_power_loss_leaves_are_skipped_not_damage() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("z.cmsrec");
        let mut r = Recorder::open(&path).unwrap();
        for s in 0..3 {
            r.write_frame(&frame(&profile(s, 8))).unwrap();
        }
        r.finish().unwrap();
        drop(r);
        let mut f = std::fs::OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(&[0u8; 4096]).unwrap();
        drop(f);
        let mut r = Recorder::open(&path).unwrap();
        for s in 3..5 {
            r.write_frame(&frame(&profile(s, 8))).unwrap();
        }
        r.finish().unwrap();
        let (msgs, s) = scan(&std::fs::read(&path).unwrap());
        assert_eq!(seqs(&msgs), [0, 1, 2, 3, 4]);
        assert_eq!((s.damaged, s.truncated_tail), (0, 0), "{s:?}");
        assert!(recording::warnings(&path, &s).is_empty());
    })
}

/// docs/link-and-recordings.md, `export`: "Damaged frames in the file are
/// skipped and counted on stderr; a truncated last frame is reported once;
/// everything else is exported and the exit status is 0."
#[test]
fn export_skips_and_counts_damaged_frames_and_exits_0() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let msgs: Vec<DeviceMsg> = (0..5).map(|s| profile(s, 3)).collect();
        let (mut bytes, ranges) = recording(&msgs);
        // Frames 1 and 3 damaged in their middle, then a cut last frame.
        for k in [1, 3] {
            let mid = (ranges[k].start + ranges[k].end) / 2;
            bytes[mid] ^= 0x5a;
        }
        let cut = frame(&profile(5, 3));
        bytes.extend_from_slice(&cut[..20]);
        let path = write_file(dir.path(), "d.cmsrec", &bytes);
        let out = Process::new(env!("CARGO_BIN_EXE_cms-host"))
            .args(["export", "--format", "csv"])
            .arg(&path)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(0), "{out:?}");
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert_eq!(stderr.matches("2 damaged frames were skipped").count(), 1, "{stderr}");
        assert_eq!(stderr.matches("20 bytes of a truncated frame at the end were ignored").count(), 1, "{stderr}");
        assert_eq!(stderr.lines().count(), 2, "{stderr}");
        let csv = String::from_utf8(out.stdout).unwrap();
        let seqs: std::collections::BTreeSet<&str> = csv.lines().skip(1).filter_map(|l| l.split(',').next()).collect();
        assert_eq!(seqs.into_iter().collect::<Vec<_>>(), ["0", "2", "4"]);
    })
}

// ------------------------------------------------------------------ reader

/// Cut at every byte: never a panic; every frame that ends before the cut
/// is recovered; the rest is reported as a truncated tail.
#[test]
fn truncated_at_every_byte() {
    big(|| {
        let msgs = [hello(), profile(0, 3), status(), profile(1, 3), DeviceMsg::Ack(4)];
        let (bytes, ranges) = recording(&msgs);
        for cut in HEADER_LEN..=bytes.len() {
            let (got, s) = scan(&bytes[..cut]);
            let whole = ranges.iter().filter(|r| r.end <= cut).count();
            assert_eq!(got[..], msgs[..whole], "cut {cut}");
            // Before the first frame: the header and its (empty) survey block,
            // a cut inside which leaves a truncated tail after the header.
            let first = ranges[0].start;
            let tail_start = ranges.iter().filter(|r| r.end <= cut).map(|r| r.end).max().unwrap_or(if cut < first {
                HEADER_LEN
            } else {
                first
            });
            assert_eq!(s.truncated_tail, (cut - tail_start) as u64, "cut {cut}");
            assert_eq!(s.damaged, 0);
        }
        for cut in 0..HEADER_LEN {
            let e = recording::scan_reader(Path::new("x"), &bytes[..cut], |_| Ok(())).unwrap_err();
            assert!(e.to_string().contains("shorter than the 16-byte header"), "{e}");
        }
    })
}

fn soup() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        proptest::collection::vec(any::<u8>(), 0..3000),
        // Mostly non-zero: long "frames" that test the overflow path cheaply.
        proptest::collection::vec(1u8..=255, 0..3000),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Arbitrary bytes after valid frames never panic the reader, and every
    /// valid frame before them is recovered.
    #[test]
    fn soup_after_valid_frames(n in 0usize..6, junk in soup()) {
        let msgs: Vec<DeviceMsg> = (0..n as u32).map(|s| profile(s, 5)).chain([hello(), status()]).collect();
        let (mut bytes, _) = recording(&msgs);
        bytes.extend_from_slice(&junk);
        let (got, s) = big(|| scan(&bytes));
        prop_assert!(got.len() >= msgs.len());
        prop_assert_eq!(&got[..msgs.len()], &msgs[..]);
        let tail = junk.iter().rev().take_while(|&&b| b != 0).count() as u64;
        prop_assert_eq!(s.truncated_tail, tail);
    }

    /// One byte overwritten anywhere after the header: only the frame that
    /// holds it (or the two its delimiter joined) can be lost.
    #[test]
    fn one_bad_byte_costs_at_most_its_frames(at in any::<prop::sample::Index>(), v in any::<u8>()) {
        let msgs: Vec<DeviceMsg> = (0..6u32).map(|s| profile(s, 4)).collect();
        let (mut bytes, ranges) = recording(&msgs);
        let p = HEADER_LEN + at.index(bytes.len() - HEADER_LEN);
        bytes[p] = v;
        let (got, s) = big(|| scan(&bytes));
        for (m, r) in msgs.iter().zip(&ranges) {
            // The frame holding p, and the next one when p was a delimiter.
            let touched = r.contains(&p) || r.start == p + 1;
            if !touched {
                prop_assert!(got.contains(m), "frame {:?} lost for a byte at {p}", r);
            }
        }
        prop_assert!(got.iter().all(|m| msgs.contains(m)));
        prop_assert!(s.damaged <= 2);
    }
}

/// A recording with a survey that places its run, and its messages.
fn surveyed() -> (Vec<u8>, Vec<DeviceMsg>, &'static str) {
    let survey = "line = \"LN 7\"\nstart_chainage = \"12+345.600\"\nchainage = \"down\"\n";
    let msgs: Vec<DeviceMsg> =
        [hello()].into_iter().chain((0..5u32).map(|s| profile(s, 4))).chain([status()]).collect();
    let mut bytes = recording::header_and_survey(Some(survey));
    for m in &msgs {
        bytes.extend_from_slice(&frame(m));
    }
    (bytes, msgs, survey)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Damage anywhere — header, survey block, its checksum, frames, one to
    /// three bytes — never yields a value that differs from the undamaged
    /// recording's: the file is refused, or each message read is one that
    /// was written and the survey read is the one written (or reported
    /// damaged); whatever is missing is reported as damage.
    #[test]
    fn damage_anywhere_never_yields_a_wrong_value(
        flips in prop::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..=3),
    ) {
        let (mut bytes, msgs, survey) = surveyed();
        for (at, x) in &flips {
            let i = at.index(bytes.len());
            bytes[i] ^= x;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(dir.path(), "d.cmsrec", &bytes);
        let mut got = Vec::new();
        let read = big(|| recording::scan_file(&path, |m| {
            got.push(m.clone());
            Ok(())
        }));
        let Ok(stats) = read else { return Ok(()) };
        prop_assert!(got.iter().all(|m| msgs.contains(m)), "a message read that was not written");
        match recording::survey_of(&path) {
            // A flipped version byte may make it format 2 (its survey has no checksum) or 1 (no survey).
            Ok(Some(_)) if stats.header.is_some_and(|h| h.format < recording::CHECKSUMMED_FORMAT) => {}
            Ok(Some(t)) => prop_assert_eq!(t.as_str(), survey),
            Ok(None) => prop_assert!(stats.header.is_some_and(|h| h.format == 1)),
            Err(e) => prop_assert!(e.to_string().contains("survey block"), "{e}"),
        }
        let lost = msgs.iter().filter(|m| !got.contains(m)).count();
        prop_assert!(lost == 0 || stats.damaged > 0 || stats.truncated_tail > 0, "{lost} lost unreported: {stats:?}");
    }
}

/// The survey block's checksum catches a flipped digit of the start
/// chainage (which would move the run): `info` says the survey is damaged
/// and still counts every frame; `analyze` refuses to place the run.
#[test]
fn a_damaged_survey_is_reported_and_its_frames_kept() {
    let (mut bytes, msgs, _) = surveyed();
    let at = bytes.windows(3).position(|w| w == b"345").unwrap();
    bytes[at] = b'9';
    let dir = tempfile::tempdir().unwrap();
    let path = write_file(dir.path(), "s.cmsrec", &bytes);
    let info = Info::of_file(&path, &Silent).unwrap();
    let text = info.report(&path);
    assert!(text.contains("survey: survey block: damaged (its checksum does not match); not used"), "{text}");
    assert_eq!(info.frames, 5, "{text}");
    let (got, s) = big(|| scan(&bytes));
    assert_eq!((got, s.survey_damaged), (msgs, true));
    let o = Process::new(env!("CARGO_BIN_EXE_cms-host")).args(["analyze", path.to_str().unwrap()]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("survey block: damaged"), "{o:?}");
}

/// A damaged version byte that makes a checksummed recording read as
/// format 2 or 1 (no checksum) is caught by the checksum it still ends its
/// block with: read as its own format, its survey reported damaged, every
/// frame kept.
#[test]
fn a_damaged_version_byte_is_caught_by_the_header_checksum() {
    for claimed in [2u8, 1] {
        let (mut bytes, msgs, _) = surveyed();
        assert_eq!(bytes[8], recording::FORMAT_VERSION as u8);
        bytes[8] = claimed;
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(dir.path(), "v.cmsrec", &bytes);
        let info = Info::of_file(&path, &Silent).unwrap();
        let text = info.report(&path);
        let want = format!(
            "its format version reads {claimed}, but its checksum is of format {0}; read as format {0}",
            recording::FORMAT_VERSION
        );
        assert!(text.contains(&want), "{text}");
        assert!(text.contains(&format!("format: {} (wire", recording::FORMAT_VERSION)), "{text}");
        assert_eq!(info.frames, 5, "{text}");
        let (got, s) = big(|| scan(&bytes));
        assert_eq!((got, s.survey_damaged), (msgs, true));
    }
    // A real format-2 file (no checksum after its survey) still reads as one, whole.
    let (bytes, msgs, survey) = surveyed();
    let mut v2 = bytes[..recording::HEADER_LEN + survey.len()].to_vec();
    v2[8] = 2;
    v2.extend_from_slice(&bytes[recording::HEADER_LEN + survey.len() + 4..]);
    let (got, s) = big(|| scan(&v2));
    assert_eq!((got, s.survey_damaged, s.damaged), (msgs, false, 0));
    assert_eq!(s.header.map(|h| h.format), Some(2));
}

// ------------------------------------------------------------------ export, info

fn write_file(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Exact CSV and JSON of a known profile.
#[test]
fn export_formats() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let (bytes, _) = recording(&[hello(), profile(2, 2), status()]);
        let path = write_file(dir.path(), "e.cmsrec", &bytes);
        let mut csv = Vec::new();
        recording::export_to(&path, recording::ExportFormat::Csv, &mut csv, &Silent).unwrap();
        let csv = String::from_utf8(csv).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], recording::CSV_HEADER);
        assert!(recording::CSV_HEADER.ends_with(",flags,along_mm,height_um"));
        assert_eq!(lines.len(), 1 + 3 * 2);
        assert_eq!(lines[1], "2,0,21000,4.999,0,0,100.00391,1008,2.50000,0,,");
        assert_eq!(lines[3], "2,0,21000,4.999,1,0,250.00391,1008,2.50000,0,-1.200,35.300");
        assert_eq!(lines[4], "2,0,21000,4.999,1,1,250.01172,1008,2.50000,4,,");
        let mut jl = Vec::new();
        recording::export_to(&path, recording::ExportFormat::Jsonl, &mut jl, &Silent).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&jl).unwrap();
        assert_eq!(v["seq"], 2);
        assert_eq!(v["timestamp_us"], 21000);
        assert_eq!(v["odometer_mm"], 4.999);
        assert_eq!(v["laser_mask"], 7);
        let p = &v["lasers"][1]["points"][0];
        assert_eq!(p["row"], 0);
        assert_eq!(p["flags"], 0);
        assert_eq!(p["width_px"], 2.5);
        assert_eq!(p["along_mm"], -1.2);
        assert_eq!(p["height_um"], 35.3, "0.1 µm on the wire");
        assert_eq!(p["position_px"], 250.00390625, "1/256 px on the wire");
        assert!(v["lasers"][0]["points"][0].get("along_mm").is_none());
    })
}

/// `cms-host export` of a file with a truncated last frame: everything
/// before it exported, one line on stderr, exit 0. `info` reports it too.
#[test]
fn cli_export_and_info_of_a_truncated_file() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let msgs: Vec<DeviceMsg> = [hello()].into_iter().chain((0..4).map(|s| profile(s, 3))).collect();
        let (mut bytes, _) = recording(&msgs);
        let f = frame(&profile(4, 3));
        bytes.extend_from_slice(&f[..37]);
        let path = write_file(dir.path(), "t.cmsrec", &bytes);
        let bin = env!("CARGO_BIN_EXE_cms-host");
        let out = Process::new(bin).args(["export", "--format", "csv"]).arg(&path).output().unwrap();
        assert!(out.status.success());
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert_eq!(stderr.matches("37 bytes of a truncated frame at the end were ignored").count(), 1, "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert_eq!(String::from_utf8(out.stdout).unwrap().lines().count(), 1 + 4 * 3 * 3);

        let out = Process::new(bin).arg("info").arg(&path).output().unwrap();
        assert!(out.status.success());
        let info = String::from_utf8(out.stdout).unwrap();
        for needle in [
            "frames: 4 (4 profile messages)",
            "time: 0.001000 s to 0.031000 s (span 0.030000 s)",
            "distance: -0.001 mm to 7.499 mm (span 7.500 mm)",
            "seq: 0 to 3, 0 missing",
            "lasers: 0 (12 points), 1 (12 points), 2 (12 points)",
            "points: 36 (9.0 per frame)",
            &format!(
                "device: firmware 1.2.3, board bench, protocol {PROTOCOL_VERSION}, sensor 752x480 at 12 bits, calibration none"
            ),
            "damaged frames: 0",
            "truncated bytes at the end: 37",
        ] {
            assert!(info.contains(needle), "{needle:?} not in\n{info}");
        }

        // Not a recording: one error line, exit 2, no output file created.
        let bad = write_file(dir.path(), "bad.bin", b"\x89PNG\r\n\x1a\n........");
        let o = dir.path().join("o.csv");
        let out = Process::new(bin).args(["export", "--format", "csv", "--out"]).arg(&o).arg(&bad).output().unwrap();
        assert_eq!(out.status.code(), Some(2));
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert!(stderr.starts_with("error: ") && stderr.contains("not a CMS recording"), "{stderr}");
        assert_eq!(stderr.lines().count(), 1);
        assert!(!o.exists());

        // --out naming the recording itself is refused, the recording kept.
        let out =
            Process::new(bin).args(["export", "--format", "csv", "--out"]).arg(&path).arg(&path).output().unwrap();
        assert_eq!(out.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&out.stderr).contains("refusing to overwrite"));
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
    })
}

/// `info` counts gaps in the sequence numbers and damaged frames.
#[test]
fn info_counts_gaps_and_damage() {
    big(|| {
        let dir = tempfile::tempdir().unwrap();
        let (mut bytes, ranges) = recording(&[profile(0, 2), profile(1, 2), profile(5, 2), profile(6, 2)]);
        bytes[ranges[1].start + 3] ^= 0x10; // frame 1 damaged
        let path = write_file(dir.path(), "g.cmsrec", &bytes);
        let info = Info::of_file(&path, &Silent).unwrap();
        assert_eq!(info.frames, 3);
        assert_eq!(info.seq_gaps, 4);
        assert_eq!(info.scan.damaged, 1);
        assert!(info.device.is_none());
        assert!(info.report(&path).contains("device: no Hello recorded"));

        // Extreme odometer values (a corrupt head) do not overflow the report.
        let mut far = Vec::new();
        for (seq, odo) in [(0, i64::MIN), (1, i64::MAX)] {
            let DeviceMsg::Profile(mut p) = profile(seq, 1) else { unreachable!() };
            p.odometer_um = odo;
            far.push(DeviceMsg::Profile(p));
        }
        let path = write_file(dir.path(), "far.cmsrec", &recording(&far).0);
        let report = Info::of_file(&path, &Silent).unwrap().report(&path);
        assert!(report.contains("span 9223372036854775.807 mm"), "{report}");
    })
}

// ------------------------------------------------------------------ fuzz (stable)

/// Mutates a stream of valid frames: bit flips, byte changes, insertions,
/// deletions, zeros, cuts, random runs (some longer than a frame).
fn mutate(rng: &mut Rng, data: &mut Vec<u8>) {
    let n = 1 + rng.next_u64() % 8;
    for _ in 0..n {
        let len = data.len().max(1);
        let at = (rng.next_u64() as usize) % len;
        match rng.next_u64() % 7 {
            0 if !data.is_empty() => data[at] ^= 1 << (rng.next_u64() % 8),
            1 if !data.is_empty() => data[at] = rng.next_u64() as u8,
            2 => data.insert(at.min(data.len()), rng.next_u64() as u8),
            3 if !data.is_empty() => {
                data.remove(at);
            }
            4 if !data.is_empty() => data[at] = 0,
            5 => data.truncate(at),
            _ => {
                let run = (rng.next_u64() % 2000) as usize;
                let zero_free = rng.next_u64().is_multiple_of(2);
                let bytes: Vec<u8> = (0..run)
                    .map(|_| {
                        let b = rng.next_u64() as u8;
                        if zero_free { b | 1 } else { b }
                    })
                    .collect();
                let at = at.min(data.len());
                data.splice(at..at, bytes);
            }
        }
    }
}

/// Feeds `data` in random chunks to both readers and checks the counters.
fn check_readers(rng: &mut Rng, data: &[u8]) {
    let mut dev: Box<FrameReader<MAX_FRAME>> = Box::new(FrameReader::new());
    let mut cmd: Box<FrameReader<MAX_COMMAND_FRAME>> = Box::new(FrameReader::new());
    let mut deframer = Deframer::new();
    let (mut ok, mut err, mut cmd_calls) = (0u32, 0u32, 0u32);
    let mut rest = data;
    while !rest.is_empty() {
        let k = (1 + rng.next_u64() % 4096) as usize;
        let (chunk, r) = rest.split_at(k.min(rest.len()));
        rest = r;
        dev.feed(chunk, |r: Result<DeviceMsg, WireError>| match r {
            Ok(m) => {
                ok += 1;
                // A decoded message re-encodes to a frame that decodes to itself.
                let f = frame(&m);
                let mut again = f[..f.len() - 1].to_vec();
                assert_eq!(cms_core::protocol::decode_frame::<DeviceMsg>(&mut again).unwrap(), m);
            }
            Err(_) => err += 1,
        });
        cmd.feed(chunk, |_r: Result<Command, WireError>| cmd_calls += 1);
        deframer.feed(chunk, |r, raw| {
            if r.is_ok() {
                // The wire bytes handed on decode on their own.
                let mut f = raw[..raw.len() - 1].to_vec();
                assert!(cms_core::protocol::decode_frame::<DeviceMsg>(&mut f).is_ok());
                assert_eq!(raw.last(), Some(&0));
            }
        });
    }
    let s = dev.stats();
    assert_eq!(s.frames, ok);
    assert_eq!(s.crc_errors + s.decode_errors + s.overflows, err);
    let c = cmd.stats();
    assert_eq!(c.frames + c.crc_errors + c.decode_errors + c.overflows, cmd_calls);
    let d = deframer.counters();
    assert_eq!(d.frames, u64::from(s.frames));
    assert_eq!(d.damaged(), u64::from(err));
}

/// The stable-Rust stand-in for `cargo fuzz run decode`: a seeded, bounded
/// stream of several million mutated and random bytes through
/// `FrameReader<MAX_FRAME>` (device messages), `FrameReader<MAX_COMMAND_FRAME>`
/// (commands) and the host's `Deframer`. No panic; the counters account for
/// every frame; decoded messages round-trip.
#[test]
fn fuzz_frame_readers_bounded() {
    big(|| {
        let mut rng = Rng::new(0x5eed_f022);
        let valid: Vec<Vec<u8>> = vec![
            frame(&hello()),
            frame(&profile(9, 40)),
            frame(&status()),
            frame(&DeviceMsg::Ack(3)),
            frame(&DeviceMsg::Error { seq: None, code: cms_core::protocol::ErrorCode::HeartbeatLost }),
            frame(&Command { seq: 1, msg: HostMsg::GetInfo }),
            frame(&Command { seq: 2, msg: HostMsg::SetExposure { exposure_us: 150 } }),
        ];
        let budget: usize = if cfg!(debug_assertions) { 4 << 20 } else { 32 << 20 };
        let mut total = 0usize;
        while total < budget {
            let mut data = Vec::new();
            for _ in 0..1 + rng.next_u64() % 12 {
                data.extend_from_slice(&valid[(rng.next_u64() % valid.len() as u64) as usize]);
            }
            if rng.next_u64().is_multiple_of(8) {
                // Pure noise now and then.
                data = (0..rng.next_u64() % 8192).map(|_| rng.next_u64() as u8).collect();
            } else {
                mutate(&mut rng, &mut data);
            }
            total += data.len();
            check_readers(&mut rng, &data);
        }
        // One frame longer than MAX_READ_FRAME, then a valid one: overflow counted,
        // the valid one still read.
        let mut big = vec![0x42u8; MAX_READ_FRAME + 10];
        big.push(0);
        big.extend_from_slice(&valid[0]);
        let mut d = Deframer::new();
        let mut oks = 0;
        d.feed(&big, |r, _| oks += r.is_ok() as u32);
        assert_eq!((oks, d.counters().overflows), (1, 1));
        let _ = std::io::stderr().flush();
    })
}

/// The fuzz target's seed corpus (`fuzz/corpus/decode`, written by
/// `cargo run -p cms-host --example fuzz_seeds`) still decodes with this
/// protocol: device frames as `DeviceMsg`, commands as `Command`.
#[test]
fn fuzz_seed_corpus_is_current() {
    big(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/decode");
        for name in ["dev-hello-1", "dev-profile-1", "dev-status-1", "dev-ack-1", "dev-error-1", "dev-rawrows-1"] {
            let f = std::fs::read(dir.join(name)).unwrap();
            let mut d = Deframer::new();
            let mut ok = 0;
            d.feed(&f, |r, _| ok += r.is_ok() as u32);
            assert_eq!(ok, 1, "{name}: regenerate the seeds (see docs/fuzzing.md)");
        }
        for k in 0..12 {
            let f = std::fs::read(dir.join(format!("cmd-{k:02}"))).unwrap();
            let mut r: Box<FrameReader<MAX_COMMAND_FRAME>> = Box::new(FrameReader::new());
            let mut ok = 0;
            r.feed(&f, |c: Result<Command, WireError>| ok += c.is_ok() as u32);
            assert_eq!(ok, 1, "cmd-{k:02}: regenerate the seeds (see docs/fuzzing.md)");
        }
    })
}
