//! A listening session against the test device: damage, unplugs, silence,
//! throughput.

use std::io::{self};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use cms_core::protocol::{HeadState, LaserPattern, Start};
use cms_host::device::listen::{ListenError, ListenOptions, listen_with};

use super::*;

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
