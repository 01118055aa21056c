//! The wire protocol: golden bytes (protocol 5, and protocols 3's and 4's
//! that recordings hold), size bounds, round trips, resynchronisation.

use cms_core::fixed::Px;
use cms_core::peak::{ColumnWindow, Flags};
use cms_core::pipeline::default_detector;
use cms_core::protocol::*;
use heapless::{String, Vec};
use proptest::prelude::*;

fn frame<T: serde::Serialize>(msg: &T) -> std::vec::Vec<u8> {
    let mut out = vec![0u8; MAX_FRAME];
    encode(msg, &mut out).unwrap().to_vec()
}

fn hex(b: &[u8]) -> std::string::String {
    b.iter().map(|x| format!("{x:02x}")).collect::<std::vec::Vec<_>>().join(" ")
}

fn point(row: u16) -> Point {
    Point {
        row,
        position: Px::from_f64(201.5),
        strength: 1500,
        width: Px::from_f64(2.5),
        flags: Flags::NONE,
        metric: None,
    }
}

fn sample_profile() -> Profile {
    let mut lasers = Vec::new();
    let mut pts = Vec::new();
    pts.push(point(0)).unwrap();
    pts.push(Point { metric: Some(Metric { along_um: -1200, height_nm: 35_250 }), flags: Flags::CLIPPED, ..point(1) })
        .unwrap();
    lasers.push(LaserPoints { laser: 0, points: pts }).unwrap();
    Profile {
        seq: 7,
        part: 0,
        parts: 1,
        timestamp_us: 100_000,
        odometer_um: 25_000,
        exposure_us: 200,
        laser_mask: 1,
        lasers,
    }
}

/// Lasers 0 and 2, rows with gaps, both ends of the strength scale (the
/// "profile-rows" golden of `golden.py`).
fn rows_profile() -> Profile {
    let pt = |row, pos, strength, width, flags, metric: Option<(i32, i32)>| Point {
        row,
        position: Px::from_f64(pos),
        strength,
        width: Px::from_f64(width),
        flags: Flags(flags),
        metric: metric.map(|(along_um, height_nm)| Metric { along_um, height_nm }),
    };
    let l0 = [
        pt(3, 310.25, 158, 3.0, 0, Some((-33_947, -142_741))),
        pt(4, 310.0, 157, 3.0625, 0, Some((-33_803, -139_571))),
        pt(7, 309.5, 4095, 3.5, 1, Some((-33_370, -145_075))),
    ];
    let l2 = [pt(4, 512.75, 5, 1.0, 4, None), pt(300, 498.0, 65_535, 6.4375, 0, Some((9000, 7)))];
    let mut lasers = Vec::new();
    lasers.push(LaserPoints { laser: 0, points: Vec::from_slice(&l0).unwrap() }).unwrap();
    lasers.push(LaserPoints { laser: 2, points: Vec::from_slice(&l2).unwrap() }).unwrap();
    Profile {
        seq: 8,
        part: 0,
        parts: 1,
        timestamp_us: 133_333,
        odometer_um: -4,
        exposure_us: 100,
        laser_mask: 5,
        lasers,
    }
}

/// Protocol 5's predictions at work (the "profile-line" golden of
/// `golden.py`): laser 1's slanted line of 14 points, its metric model, an
/// outlier escaped, flags new and repeated, a point without its metric
/// point, a skip; laser 2 without metric points.
fn line_profile() -> Profile {
    type Raw = (u16, f64, u16, f64, u8, Option<(i32, i32)>);
    let l1: [Raw; 14] = [
        (10, 300.05078125, 150, 2.875, 0, Some((-28568, -141236))),
        (11, 300.5078125, 150, 2.875, 0, Some((-28428, -149833))),
        (12, 300.6875, 150, 2.75, 1, Some((-28286, -152775))),
        (13, 301.0078125, 150, 2.875, 1, Some((-28140, -159162))),
        (14, 301.3515625, 4095, 2.6875, 0, None),
        (15, 301.8984375, 4095, 2.625, 32, Some((-27857, -176365))),
        (16, 302.10546875, 150, 2.6875, 1, Some((-27713, -180134))),
        (17, 302.50390625, 150, 2.8125, 0, Some((-27570, -187688))),
        (18, 303.13671875, 150, 3.0, 0, Some((-27425, -199593))),
        (19, 343.13671875, 150, 2.75, 0, Some((-27284, -959628))),
        (20, 303.52734375, 160, 2.9375, 0, Some((-27138, -207317))),
        (24, 304.109375, 160, 2.625, 0, Some((-26568, -218065))),
        (25, 304.43359375, 150, 2.75, 1, Some((-26424, -224055))),
        (26, 304.890625, 140, 2.6875, 0, Some((-26284, -232856))),
    ];
    let l2: [Raw; 2] = [(12, 512.5, 90, 2.0, 0, None), (13, 512.25, 88, 2.0625, 0, None)];
    let points = |raw: &[Raw]| -> Vec<Point, MAX_ROWS_PER_PROFILE> {
        raw.iter()
            .map(|&(row, pos, strength, width, flags, metric)| Point {
                row,
                position: Px::from_f64(pos),
                strength,
                width: Px::from_f64(width),
                flags: Flags(flags),
                metric: metric.map(|(along_um, height_nm)| Metric { along_um, height_nm }),
            })
            .collect()
    };
    let mut lasers = Vec::new();
    lasers.push(LaserPoints { laser: 1, points: points(&l1) }).unwrap();
    lasers.push(LaserPoints { laser: 2, points: points(&l2) }).unwrap();
    Profile {
        seq: 9,
        part: 0,
        parts: 1,
        timestamp_us: 166_666,
        odometer_um: 70_000,
        exposure_us: 100,
        laser_mask: 6,
        lasers,
    }
}

fn sample_info() -> DeviceInfo {
    DeviceInfo {
        firmware: String::try_from("0.1.0").unwrap(),
        protocol: PROTOCOL_VERSION,
        board: String::try_from("sim").unwrap(),
        sensor_width: 752,
        sensor_height: 480,
        bits: 12,
        detector: default_detector(),
        calibration_id: 0,
        store: StoreHealth::Recovered,
    }
}

/// Every message, one example each, with its exact frame. The bytes were
/// checked independently by `tests/scripts/golden.py` (postcard varints,
/// zlib's CRC-32, COBS written from the spec).
fn goldens() -> std::vec::Vec<(&'static str, std::vec::Vec<u8>)> {
    vec![
        ("ack", frame(&DeviceMsg::Ack(300))),
        ("error", frame(&DeviceMsg::Error { seq: Some(5), code: ErrorCode::HeartbeatLost })),
        ("error-version", frame(&DeviceMsg::Error { seq: None, code: ErrorCode::Version(2) })),
        (
            "status",
            frame(&DeviceMsg::Status(Status {
                state: HeadState::Streaming,
                lasers_on: 7,
                frames: 1000,
                frame_rate_millihz: 30_000,
                rows_per_s: 14_400,
                dropped_frames: 0,
                ns_per_row: 52_000,
                cycles_per_row: 24_960,
                dropped_rows: 3,
                link_backlog_bytes: 4096,
                laser_duty_permille: 6,
                heartbeat_age_ms: 120,
                fault: None,
            })),
        ),
        ("profile", frame(&DeviceMsg::Profile(sample_profile()))),
        ("profile-rows", frame(&DeviceMsg::Profile(rows_profile()))),
        ("profile-line", frame(&DeviceMsg::Profile(line_profile()))),
        ("hello", frame(&DeviceMsg::Hello(sample_info()))),
        (
            "raw",
            frame(&DeviceMsg::RawRows(RawRows {
                capture: 9,
                first_row: 2,
                offset_bytes: 0,
                width: 4,
                height: 3,
                bits: 8,
                data: Vec::from_slice(&[0, 1, 2, 255]).unwrap(),
            })),
        ),
        (
            "start",
            frame(&Command {
                seq: 1,
                msg: HostMsg::Start(Start { rate_hz: 30, laser_mask: 7, pattern: LaserPattern::Sequential }),
            }),
        ),
        ("stop", frame(&Command { seq: 2, msg: HostMsg::Stop })),
        ("exposure", frame(&Command { seq: 3, msg: HostMsg::SetExposure { exposure_us: 250 } })),
        ("detector", frame(&Command { seq: 4, msg: HostMsg::SetDetector(default_detector()) })),
        (
            "calibration",
            frame(&Command {
                seq: 5,
                msg: HostMsg::SetCalibration(Calibration {
                    id: 1,
                    intrinsics: [1400.0, 1400.0, 376.0, 240.0, 0.0],
                    distortion: [0.0; 5],
                    planes: [[0.0, 0.6691306, 0.7431448, 300.0]; LASERS],
                    datum: [0.0, 0.0, -1.0, -200.0],
                }),
            }),
        ),
        ("capture", frame(&Command { seq: 6, msg: HostMsg::CaptureImage(0) })),
        ("info", frame(&Command { seq: 7, msg: HostMsg::GetInfo })),
        ("heartbeat", frame(&Command { seq: 8, msg: HostMsg::Heartbeat })),
        ("trigger", frame(&Command { seq: 9, msg: HostMsg::SetTrigger(Trigger::Distance { every_um: 5000 }) })),
        (
            "windows",
            frame(&Command {
                seq: 10,
                msg: HostMsg::SetWindows([
                    Some(ColumnWindow { first_px: 80, width_px: 96 }),
                    None,
                    Some(ColumnWindow { first_px: 600, width_px: 96 }),
                ]),
            }),
        ),
        ("readout", frame(&Command { seq: 11, msg: HostMsg::SetReadout { first_row: 40, rows: 400, skip: 2 } })),
        ("tracking", frame(&Command { seq: 12, msg: HostMsg::SetTracking { half_width_px: 12 } })),
    ]
}

/// Protocols 3's and 4's frames (from `golden.py`), what this build reads
/// them as, and their version.
fn goldens_old() -> std::vec::Vec<(&'static str, DeviceMsg, u8)> {
    let info = |protocol| DeviceInfo { protocol, ..sample_info() };
    vec![
        ("profile-v3", DeviceMsg::Profile(sample_profile()), 3),
        ("hello-v3", DeviceMsg::Hello(info(3)), 3),
        ("profile-v4", DeviceMsg::Profile(sample_profile().on_wire()), 4),
        ("profile-rows-v4", DeviceMsg::Profile(rows_profile().on_wire()), 4),
        ("hello-v4", DeviceMsg::Hello(info(4)), 4),
    ]
}

fn golden_lines() -> std::vec::Vec<(std::string::String, std::vec::Vec<u8>)> {
    include_str!("../../golden/frames.txt")
        .lines()
        .map(|l| {
            let (name, bytes) = l.split_once(": ").unwrap();
            (name.to_owned(), bytes.split(' ').map(|b| u8::from_str_radix(b, 16).unwrap()).collect())
        })
        .collect()
}

#[test]
fn goldens_match_the_reference_encoder() {
    let want = include_str!("../../golden/frames.txt");
    let got: std::vec::Vec<_> = goldens().into_iter().map(|(name, bytes)| format!("{name}: {}", hex(&bytes))).collect();
    let want: std::vec::Vec<_> = want.lines().map(str::to_owned).collect();
    assert_eq!(got.len(), 21, "one golden per message kind, three profiles");
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g, w);
    }
    assert_eq!(want.len(), got.len() + goldens_old().len());
}

/// Protocols 3's and 4's frames decode into this build's messages
/// (recordings made before protocol 5), and the encoders kept for tests
/// write them.
#[test]
fn old_goldens_decode_into_the_model() {
    let lines = golden_lines();
    for (name, want, version) in goldens_old() {
        let (_, bytes) = lines.iter().find(|(n, _)| n == name).unwrap();
        let mut f = bytes[..bytes.len() - 1].to_vec();
        assert_eq!(decode_frame::<DeviceMsg>(&mut f).unwrap(), want, "{name}");
        let mut out = vec![0u8; v3::MAX_FRAME];
        let written = if version == 3 { v3::encode(&want, &mut out) } else { v4::encode(&want, &mut out) };
        assert_eq!(written.unwrap(), &bytes[..], "{name}");
        // A host of an earlier protocol is not one the head's command reader obeys.
        let mut c = bytes[..bytes.len() - 1].to_vec();
        assert_eq!(decode_frame::<Command>(&mut c), Err(WireError::Version(version)), "{name}");
    }
}

/// What a decoder gets back is the point quantised ([`Point::on_wire`]).
#[test]
fn goldens_decode_to_their_quantised_values() {
    for p in [sample_profile(), rows_profile(), line_profile()] {
        let mut f = frame(&DeviceMsg::Profile(p.clone()));
        f.pop();
        assert_eq!(decode_frame::<DeviceMsg>(&mut f).unwrap(), DeviceMsg::Profile(p.on_wire()));
    }
    let p = rows_profile().on_wire();
    assert_eq!(p.lasers[0].points[2].strength, 4032, "4095 is (16 + 15)·2⁷ + 2⁶");
    assert_eq!(p.lasers[1].points[1].strength, 64_512);
    assert_eq!(p.lasers[0].points[0].metric.unwrap().height_nm, -142_700);
}

/// A laser's points out of row order, or two in one row, do not encode.
#[test]
fn profiles_out_of_row_order_are_refused() {
    for rows in [[5u16, 3], [4, 4]] {
        let mut p = sample_profile();
        p.lasers[0].points[0].row = rows[0];
        p.lasers[0].points[1].row = rows[1];
        let mut out = vec![0u8; MAX_FRAME];
        assert_eq!(encode(&DeviceMsg::Profile(p), &mut out), Err(WireError::Unencodable), "{rows:?}");
    }
}

/// Every strength code stands for a strength that encodes to it, and every
/// strength is within its code's step (1/16 of the value or less).
#[test]
fn strength_codes_invert() {
    for c in 0..=u8::MAX {
        match compact::strength_from_code(c) {
            Some(s) => assert_eq!(compact::strength_code(s), c),
            None => assert!(c > compact::MAX_STRENGTH_CODE),
        }
    }
    for s in 0..=u16::MAX {
        let back = compact::strength_from_code(compact::strength_code(s)).unwrap();
        assert!(u32::from(s.abs_diff(back)) * 32 <= u32::from(s).max(16), "{s} → {back}");
    }
}

#[test]
fn goldens_decode_back() {
    for (name, mut bytes) in goldens() {
        assert_eq!(bytes.pop(), Some(0), "{name}: frames end in the delimiter");
        assert!(!bytes.contains(&0), "{name}: no zero inside a COBS frame");
        let ok = if matches!(
            name,
            "start"
                | "stop"
                | "exposure"
                | "detector"
                | "calibration"
                | "capture"
                | "info"
                | "heartbeat"
                | "trigger"
                | "windows"
                | "readout"
                | "tracking"
        ) {
            decode_frame::<Command>(&mut bytes).is_ok()
        } else {
            decode_frame::<DeviceMsg>(&mut bytes).is_ok()
        };
        assert!(ok, "{name}");
    }
}

/// The largest message of each kind fits `MAX_MESSAGE` / `MAX_FRAME`, and
/// every command fits `MAX_COMMAND_FRAME`: the buffers are sized from these.
#[test]
fn encoded_sizes_are_bounded() {
    let worst_point = Point {
        row: u16::MAX,
        position: Px(i32::MIN),
        strength: u16::MAX,
        width: Px(i32::MIN),
        flags: Flags(u8::MAX),
        metric: Some(Metric { along_um: i32::MIN, height_nm: i32::MIN }),
    };
    // Every point in a record of its own (laser k in rows k, k + 3, …, then
    // the last one 65 535 − 2 + k after a long skip), its position and
    // height swinging between their extremes, its along 2³⁰ off the linear
    // prediction: every field at its longest varint.
    let mut lasers = Vec::new();
    for k in 0..LASERS as u8 {
        let mut points = Vec::new();
        let mut along = [0i32; 2];
        for i in 0..MAX_ROWS_PER_PROFILE {
            let row =
                if i + 1 == MAX_ROWS_PER_PROFILE { u16::MAX - 2 + u16::from(k) } else { (3 * i) as u16 + u16::from(k) };
            let (position, height_nm) = if i % 2 == 0 { (Px(i32::MIN), i32::MIN) } else { (Px(i32::MAX), i32::MAX) };
            let predicted = match i {
                0 => 0,
                1 => along[1],
                _ => along[1].wrapping_mul(2).wrapping_sub(along[0]),
            };
            let along_um = predicted.wrapping_add(1 << 30);
            along = [along[1], along_um];
            points.push(Point { row, position, metric: Some(Metric { along_um, height_nm }), ..worst_point }).unwrap();
        }
        lasers.push(LaserPoints { laser: k, points }).unwrap();
    }
    let profile = DeviceMsg::Profile(Profile {
        seq: u32::MAX,
        part: u8::MAX,
        parts: u8::MAX,
        timestamp_us: u64::MAX,
        odometer_um: i64::MIN,
        exposure_us: u32::MAX,
        laser_mask: u8::MAX,
        lasers,
    });
    // In protocol 4 (recordings): its own bound, short of it by the skips
    // alone (the bound gives every record a 3-byte skip, and 65 535 rows
    // leave room for one such a laser; the others skip nothing here).
    let mut out = vec![0u8; v3::MAX_FRAME];
    let n = v4::encode(&profile, &mut out).unwrap().len();
    assert!(n <= v4::MAX_FRAME, "profile {n} > {}", v4::MAX_FRAME);
    assert!(n + 3 * LASERS * MAX_ROWS_PER_PROFILE > v4::MAX_MESSAGE - 100, "v4::MAX_MESSAGE is not tight: {n}");
    // And in protocol 3 (host readers are sized by MAX_READ_FRAME).
    let n = v3::encode(&profile, &mut out).unwrap().len();
    assert!(n <= v3::MAX_FRAME, "{n}");
    const { assert!(v3::MAX_FRAME <= MAX_READ_FRAME && v4::MAX_FRAME <= MAX_READ_FRAME && MAX_FRAME <= MAX_READ_FRAME) };
    assert!(frame(&profile).len() <= MAX_FRAME);
    let n = postcard::to_slice(&worst_packed_profile(), &mut out).unwrap().len();
    assert!(n <= MAX_MESSAGE, "profile {n} > {MAX_MESSAGE}");
    // The bound has every field escaped; the Rice codes adapt to the swings
    // (their parameter follows the mean), so this profile reaches 60 % of
    // it: every record's head at its longest, the flags new, the fields at
    // their parameter's length.
    assert!(n > MAX_MESSAGE / 2, "MAX_MESSAGE is not tight: {n} of {MAX_MESSAGE}");
    assert!(frame(&worst_packed_profile()).len() <= MAX_FRAME);

    let mut info = sample_info();
    info.firmware = String::try_from("0123456789abcdef").unwrap();
    info.board = String::try_from("0123456789abcdefghijklmn").unwrap();
    info.calibration_id = u32::MAX;
    assert!(frame(&DeviceMsg::Hello(info)).len() <= MAX_FRAME);
    let raw_rows = DeviceMsg::RawRows(RawRows {
        capture: u16::MAX,
        first_row: u16::MAX,
        offset_bytes: u32::MAX,
        width: u16::MAX,
        height: u16::MAX,
        bits: 16,
        data: Vec::from_slice(&[0xff; RAW_CHUNK_BYTES]).unwrap(),
    });
    assert!(frame(&raw_rows).len() <= MAX_FRAME);
    let cal = Command {
        seq: u16::MAX,
        msg: HostMsg::SetCalibration(Calibration {
            id: u32::MAX,
            intrinsics: [f32::MAX; 5],
            distortion: [f32::MAX; 5],
            planes: [[f32::MAX; 4]; 3],
            datum: [f32::MAX; 4],
        }),
    };
    let mut det = default_detector();
    det.threshold_sigma_q8 = u16::MAX;
    det.saturation = u16::MAX;
    let det = Command { seq: u16::MAX, msg: HostMsg::SetDetector(det) };
    let trig = Command { seq: u16::MAX, msg: HostMsg::SetTrigger(Trigger::Distance { every_um: u32::MAX }) };
    for c in [cal, det, trig, Command { seq: u16::MAX, msg: HostMsg::SetExposure { exposure_us: u32::MAX } }] {
        let len = frame(&c).len();
        assert!(len <= MAX_COMMAND_FRAME, "{c:?}: {len}");
    }
}

/// Protocol 5's most expensive profile we know: every point in a record of
/// its own after a skip, its flags new, every field swinging between its
/// extremes (a prediction from the last ones is as far off as can be).
fn worst_packed_profile() -> DeviceMsg {
    let mut lasers = Vec::new();
    for k in 0..LASERS as u8 {
        let points = (0..MAX_ROWS_PER_PROFILE)
            .map(|i| {
                let hi = (i / 2 + usize::from(k)) % 2 == 0;
                let pick = |a, b| if hi { a } else { b };
                Point {
                    row: (6 * i) as u16 + 2 * u16::from(k),
                    position: Px(pick(i32::MAX, i32::MIN)),
                    strength: if hi { u16::MAX } else { 0 },
                    width: Px(pick(i32::MAX, 0)),
                    flags: Flags(if i % 2 == 0 { 0x55 } else { 0xaa }),
                    metric: Some(Metric { along_um: pick(i32::MAX, i32::MIN), height_nm: pick(i32::MAX, i32::MIN) }),
                }
            })
            .collect();
        lasers.push(LaserPoints { laser: k, points }).unwrap();
    }
    DeviceMsg::Profile(Profile {
        seq: u32::MAX,
        part: u8::MAX,
        parts: u8::MAX,
        timestamp_us: u64::MAX,
        odometer_um: i64::MIN,
        exposure_us: u32::MAX,
        laser_mask: u8::MAX,
        lasers,
    })
}

#[test]
fn reader_resynchronises_after_garbage_and_counts_damage() {
    let good = frame(&DeviceMsg::Ack(1));
    let mut stream = std::vec::Vec::new();
    stream.extend_from_slice(&[0x13, 0x37, 0xff]); // garbage before the first delimiter
    stream.push(0);
    stream.extend_from_slice(&good);
    let mut flipped = frame(&DeviceMsg::Ack(2));
    flipped[3] ^= 0x10; // a flipped bit: CRC
    stream.extend_from_slice(&flipped);
    let truncated = frame(&DeviceMsg::Ack(3));
    stream.extend_from_slice(&truncated[..truncated.len() / 2]); // cut short, then the next frame
    stream.extend_from_slice(&frame(&DeviceMsg::Ack(4)));
    stream.extend_from_slice(&vec![0x55; 300]); // longer than the reader's buffer
    stream.push(0);
    stream.extend_from_slice(&frame(&DeviceMsg::Ack(5)));
    let mut reader = FrameReader::<128>::new();
    let mut got = std::vec::Vec::new();
    let mut errors = std::vec::Vec::new();
    // Byte by byte and in odd chunks alike.
    for chunk in stream.chunks(7) {
        reader.feed::<DeviceMsg, _>(chunk, |r| match r {
            Ok(DeviceMsg::Ack(s)) => got.push(s),
            Ok(m) => panic!("{m:?}"),
            Err(e) => errors.push(e),
        });
    }
    assert_eq!(got, vec![1, 5]);
    let st = reader.stats();
    assert_eq!(st.frames, 2);
    assert_eq!(st.crc_errors, 1);
    assert_eq!(st.overflows, 1);
    // garbage (bad COBS/too short), and the truncated frame merged with Ack(4)
    assert_eq!(st.decode_errors, 2, "{errors:?}");
}

#[test]
fn version_mismatch_is_reported_as_such() {
    let mut scratch = [0u8; 64];
    scratch[0] = PROTOCOL_VERSION + 1;
    let n = postcard::to_slice(&DeviceMsg::Ack(1), &mut scratch[1..]).unwrap().len();
    let crc = CRC.checksum(&scratch[..1 + n]);
    scratch[1 + n..5 + n].copy_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; 64];
    let m = cobs::encode(&scratch[..5 + n], &mut out);
    assert_eq!(decode_frame::<DeviceMsg>(&mut out[..m]), Err(WireError::Version(PROTOCOL_VERSION + 1)));
}

/// A damaged frame is a CRC error whatever its first byte says: the
/// version is believed only once the CRC holds (garbage on the port was
/// once reported as "a head of protocol version 51").
#[test]
fn a_damaged_frame_of_another_version_is_a_crc_error() {
    let mut scratch = [0u8; 64];
    scratch[0] = 51;
    let n = postcard::to_slice(&DeviceMsg::Ack(1), &mut scratch[1..]).unwrap().len();
    let crc = CRC.checksum(&scratch[..1 + n]) ^ 1;
    scratch[1 + n..5 + n].copy_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; 64];
    let m = cobs::encode(&scratch[..5 + n], &mut out);
    assert_eq!(decode_frame::<DeviceMsg>(&mut out[..m]), Err(WireError::Crc));

    // A reader fed random frames (well-formed COBS, so each reaches the
    // version and CRC checks) counts CRC errors, never a version.
    let mut reader = FrameReader::<512>::new();
    let mut versions = 0;
    let mut garbage = std::vec::Vec::new();
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    for k in 0..100 {
        let raw: std::vec::Vec<u8> = (0..10 + k % 30)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        let mut enc = vec![0u8; raw.len() + 2];
        let m = cobs::encode(&raw, &mut enc);
        garbage.extend_from_slice(&enc[..m]);
        garbage.push(0);
    }
    reader.feed::<DeviceMsg, _>(&garbage, |r| versions += u32::from(matches!(r, Err(WireError::Version(_)))));
    assert_eq!(versions, 0);
    assert_eq!(reader.stats().crc_errors, 100, "{:?}", reader.stats());
}

fn arb_point() -> impl Strategy<Value = Point> {
    (
        any::<u16>(),
        any::<i32>(),
        any::<u16>(),
        any::<i32>(),
        any::<u8>(),
        proptest::option::of((any::<i32>(), any::<i32>())),
    )
        .prop_map(|(row, p, s, w, f, um)| Point {
            row,
            position: Px(p),
            strength: s,
            width: Px(w),
            flags: Flags(f),
            metric: um.map(|(a, h)| Metric { along_um: a, height_nm: h }),
        })
}

/// Any points, each laser's in ascending rows (what the head sends):
/// sorted and deduplicated by row.
fn arb_profile() -> impl Strategy<Value = Profile> {
    (
        any::<u32>(),
        any::<u64>(),
        any::<i64>(),
        any::<u32>(),
        any::<u8>(),
        proptest::collection::vec(proptest::collection::vec(arb_point(), 0..40), 0..=3),
    )
        .prop_map(|(seq, t, o, e, m, mut lasers)| {
            for pts in lasers.iter_mut() {
                pts.sort_by_key(|p| p.row);
                pts.dedup_by_key(|p| p.row);
            }
            (seq, t, o, e, m, lasers)
        })
        .prop_map(|(seq, t, o, e, m, lasers)| Profile {
            seq,
            part: 0,
            parts: 1,
            timestamp_us: t,
            odometer_um: o,
            exposure_us: e,
            laser_mask: m,
            lasers: lasers
                .into_iter()
                .enumerate()
                .map(|(k, pts)| LaserPoints { laser: k as u8, points: Vec::from_slice(&pts).unwrap() })
                .collect(),
        })
}

proptest! {
    /// A profile decodes to its quantised self, which encodes to the same bytes.
    #[test]
    fn profiles_round_trip(p in arb_profile()) {
        let f0 = frame(&DeviceMsg::Profile(p.clone()));
        let mut f = f0.clone();
        f.pop();
        let back = decode_frame::<DeviceMsg>(&mut f).unwrap();
        prop_assert_eq!(&back, &DeviceMsg::Profile(p.on_wire()));
        prop_assert_eq!(frame(&back), f0);
    }

    /// A protocol-4 profile (a recording's), whatever its points, decodes
    /// to its quantised self.
    #[test]
    fn v4_profiles_decode_to_their_quantised_values(p in arb_profile()) {
        let mut out = vec![0u8; v4::MAX_FRAME];
        let mut f = v4::encode(&DeviceMsg::Profile(p.clone()), &mut out).unwrap().to_vec();
        f.pop();
        prop_assert_eq!(decode_frame::<DeviceMsg>(&mut f).unwrap(), DeviceMsg::Profile(p.on_wire()));
    }

    /// A protocol-3 profile, whatever its points, decodes unchanged.
    #[test]
    fn v3_profiles_decode_unchanged(p in arb_profile(), shuffle in any::<bool>()) {
        let mut p = p;
        if shuffle {
            for lp in p.lasers.iter_mut() {
                lp.points.reverse();
            }
        }
        let mut out = vec![0u8; v3::MAX_FRAME];
        let mut f = v3::encode(&DeviceMsg::Profile(p.clone()), &mut out).unwrap().to_vec();
        f.pop();
        prop_assert_eq!(decode_frame::<DeviceMsg>(&mut f).unwrap(), DeviceMsg::Profile(p));
    }

    /// Calibrated-head-like profiles cost at most 4 bytes a point (their
    /// heights' noise does not follow the position: the model cannot help).
    #[test]
    fn smooth_profiles_cost_under_four_bytes_a_point(x0 in 100.0f64..600.0, slope in -0.5f64..0.5, seed in any::<u64>()) {
        let mut rng = seed | 1;
        let mut noise = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % 2001) as f64 / 1000.0 - 1.0
        };
        let mut lasers = Vec::new();
        for k in 0..LASERS as u8 {
            let points = (0..MAX_ROWS_PER_PROFILE as u16)
                .map(|r| Point {
                    row: r,
                    position: Px::from_f64(x0 + 100.0 * f64::from(k) + slope * f64::from(r) + 0.05 * noise()),
                    strength: 150 + (noise() * 10.0) as u16,
                    width: Px::from_f64(3.0 + 0.05 * noise()),
                    flags: Flags::NONE,
                    metric: Some(Metric {
                        along_um: -34_000 + 144 * i32::from(r) + (3.0 * noise()) as i32,
                        height_nm: -140_000 + (1500.0 * noise()) as i32,
                    }),
                })
                .collect();
            lasers.push(LaserPoints { laser: k, points }).unwrap();
        }
        let n = frame(&DeviceMsg::Profile(Profile { lasers, ..Profile::EMPTY })).len();
        prop_assert!(n <= 4 * LASERS * MAX_ROWS_PER_PROFILE, "{} bytes", n);
    }

    #[test]
    fn commands_round_trip(seq in any::<u16>(), rate in any::<u16>(), mask in any::<u8>(), exp in any::<u32>(), which in 0u8..7) {
        let msg = match which {
            0 => HostMsg::Start(Start { rate_hz: rate, laser_mask: mask, pattern: LaserPattern::Simultaneous }),
            1 => HostMsg::SetExposure { exposure_us: exp },
            2 => HostMsg::CaptureImage(mask),
            3 => HostMsg::Stop,
            4 => HostMsg::Heartbeat,
            5 => HostMsg::SetTrigger(if exp % 2 == 0 { Trigger::Timed } else { Trigger::Distance { every_um: exp } }),
            _ => HostMsg::GetInfo,
        };
        let c = Command { seq, msg };
        let mut f = frame(&c);
        f.pop();
        prop_assert_eq!(decode_frame::<Command>(&mut f).unwrap(), c);
    }

    /// A version mismatch is reported only for a frame whose CRC holds.
    #[test]
    fn a_version_is_reported_only_with_its_crc(bytes in proptest::collection::vec(1u8.., 5..200)) {
        let mut f = bytes.clone();
        if let Err(WireError::Version(v)) = decode_frame::<DeviceMsg>(&mut f) {
            let mut raw = bytes.clone();
            let n = cobs::decode_in_place(&mut raw).unwrap();
            let (body, crc) = raw[..n].split_at(n - 4);
            prop_assert_eq!(CRC.checksum(body), u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]));
            prop_assert_eq!(v, raw[0]);
        }
    }

    /// Random bytes never panic the reader, and whatever it accepts passed the CRC.
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4000)) {
        let mut reader = FrameReader::<512>::new();
        let mut ok = 0u32;
        reader.feed::<DeviceMsg, _>(&bytes, |r| if r.is_ok() { ok += 1 });
        let st = reader.stats();
        prop_assert_eq!(st.frames, ok);
    }

    /// A valid frame after any garbage and a delimiter is always recovered.
    #[test]
    fn valid_frame_after_garbage_is_recovered(garbage in proptest::collection::vec(any::<u8>(), 0..600), seq in any::<u16>()) {
        let mut stream = garbage;
        stream.push(0);
        stream.extend_from_slice(&frame(&DeviceMsg::Ack(seq)));
        let mut reader = FrameReader::<512>::new();
        let mut last = None;
        reader.feed::<DeviceMsg, _>(&stream, |r| if let Ok(DeviceMsg::Ack(s)) = r { last = Some(s) });
        prop_assert_eq!(last, Some(seq));
    }
}
