//! Bad bytes, hang-ups and signals: the listener still ends cleanly and
//! says what it got.

use crate::common::bin;
use std::io::{self, Read};
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::sync::atomic::AtomicBool;
use std::thread;
use std::time::Duration;

use cms_host::device::listen::{ListenError, ListenOptions};

use super::*;

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
            .args(["listen", "sim", "--sim-light=incoherent", "--json", "--rate", "100", "--record"])
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
        let mut args = vec!["listen", "sim", "--sim-light=incoherent", "--frames", "2", "--json"];
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
    let out = crate::common::run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--frames",
        "2",
        "--windows-from",
        cal.to_str().unwrap(),
    ]);
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
        let mut args =
            vec!["listen", "sim", "--sim-light=incoherent", "--frames", "2", "--json", "--sim-speed-mm-s", "0"];
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
        let mut args =
            vec!["listen", "sim", "--sim-light=incoherent", "--frames", "2", "--json", "--sim-speed-mm-s", "0"];
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
