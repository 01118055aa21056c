//! Recordings written by hand: what is too short, and bad input.

use super::frames;
use crate::common::{one_line_error, run};
use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::protocol::{DeviceMsg, LaserPoints, MAX_FRAME, Metric, Point, Profile, encode};
use cms_host::analyze::stitch::FramePoints;
use cms_host::recording;
use std::path::Path;

// ------------------------------------------------------------ recordings

pub(super) fn wire<T: serde::Serialize>(msg: &T) -> Vec<u8> {
    let mut out = vec![0u8; MAX_FRAME];
    encode(msg, &mut out).unwrap().to_vec()
}

/// A recording of `frames` as the head would send them (calibrated points).
pub(super) fn write_recording(path: &Path, frames: &[FramePoints], calibrated: bool) {
    write_recording_with(path, frames, calibrated, |_| Vec::new());
}

/// [`write_recording`] with `after(frame)`'s bytes (host records) written
/// after each frame.
pub(super) fn write_recording_with(
    path: &Path,
    frames: &[FramePoints],
    calibrated: bool,
    mut after: impl FnMut(&FramePoints) -> Vec<u8>,
) {
    let mut bytes = recording::header().to_vec();
    for f in frames {
        let mut p = Profile { seq: f.seq, odometer_um: (f.odometer_mm * 1000.0).round() as i64, ..Profile::EMPTY };
        for (k, pts) in f.lasers.iter().enumerate() {
            let mut lp = LaserPoints { laser: k as u8, points: heapless::Vec::new() };
            for (r, &(a, h)) in pts.iter().enumerate() {
                let metric = calibrated
                    .then(|| Metric { along_um: (a * 1000.0).round() as i32, height_nm: (h * 1000.0).round() as i32 });
                let pt = Point {
                    row: r as u16,
                    position: Px::from_f64(100.0),
                    strength: 100,
                    width: Px::from_f64(3.0),
                    flags: Flags::NONE,
                    metric,
                };
                lp.points.push(pt).unwrap();
            }
            p.lasers.push(lp).unwrap();
        }
        bytes.extend(wire(&DeviceMsg::Profile(p)));
        bytes.extend(after(f));
    }
    std::fs::write(path, bytes).unwrap();
}

/// 600 mm of rail: every EN 13231-3 band and the EN 15610 spectrum say
/// plainly that the record is too short, and for what.
#[test]
fn short_records_say_what_they_are_too_short_for() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("short.cmsrec");
    write_recording(&path, &frames(33.3, 17, &[], 1.0, 5), true);
    let o = run(&["analyze", path.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    let text = String::from_utf8(o.stdout).unwrap();
    println!("{text}");
    for band in ["10–30", "30–100", "100–300", "300–1000"] {
        // Each laser's (indented) table says so, the running band's (the
        // lines' mean) too, and the verdict's once more.
        let lines =
            text.lines().filter(|l| l.contains("is too short for the") && l.contains(&format!("{band} mm band")));
        let (per_line, verdict): (Vec<&str>, Vec<&str>) = lines.partition(|l| l.starts_with("  "));
        assert_eq!((per_line.len(), verdict.len()), (4, 1), "{band}: {text}");
    }
    let spectrum = text.lines().filter(|l| {
        l.contains("EN 15610 roughness not evaluated: record 60") && l.contains("too short for the 1000 mm window")
    });
    assert_eq!(spectrum.count(), 3, "{text}");
    // The JSON says the same per band.
    let o = run(&["analyze", path.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for l in v["lasers"].as_array().unwrap() {
        for b in l["en13231"]["bands"].as_array().unwrap() {
            assert!(b["error"].as_str().unwrap().contains("too short"), "{b}");
        }
        assert!(l["en15610"]["error"].as_str().unwrap().contains("too short"));
    }
}

#[test]
fn bad_input_is_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name);
    let e = one_line_error(&run(&["analyze", "/nonexistent/x.cmsrec"]));
    assert!(e.contains("/nonexistent/x.cmsrec"), "{e}");
    std::fs::write(d("text.cmsrec"), "x_mm,z_mm\n1,2\n").unwrap();
    let e = one_line_error(&run(&["analyze", d("text.cmsrec").to_str().unwrap()]));
    assert!(e.contains("text.cmsrec"), "{e}");
    std::fs::write(d("empty.cmsrec"), recording::header()).unwrap();
    let e = one_line_error(&run(&["analyze", d("empty.cmsrec").to_str().unwrap()]));
    assert!(e.contains("no profiles"), "{e}");
    write_recording(&d("raw.cmsrec"), &frames(33.3, 3, &[], 1.0, 5), false);
    let e = one_line_error(&run(&["analyze", d("raw.cmsrec").to_str().unwrap()]));
    assert!(e.contains("no calibrated points") && e.contains("calibrate upload"), "{e}");
    // Frames a light year apart: refused, not allocated.
    let mut far = frames(33.3, 2, &[], 1.0, 5);
    far[1].odometer_mm = 9.0e15;
    write_recording(&d("far.cmsrec"), &far, true);
    let e = one_line_error(&run(&["analyze", d("far.cmsrec").to_str().unwrap()]));
    assert!(e.contains("odometer"), "{e}");
    // A report directory that cannot be created.
    write_recording(&d("ok.cmsrec"), &frames(33.3, 3, &[], 1.0, 5), true);
    let e = one_line_error(&run(&[
        "analyze",
        d("ok.cmsrec").to_str().unwrap(),
        "--report",
        d("text.cmsrec/sub").to_str().unwrap(),
    ]));
    assert!(e.contains("--report") && e.contains("text.cmsrec/sub: Not a directory"), "{e}");
}
