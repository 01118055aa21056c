//! Durability of `listen --record`: the recording committed to disk
//! within a second of each frame and at every exit, checked on the real
//! listener's system calls.

use std::path::Path;
use std::process::Command as Process;

use cms_host::recording;

/// Seconds of the day of an `strace -tt` line (`[PID] HH:MM:SS.micros call…`).
fn strace_time(line: &str) -> Option<f64> {
    let t = line.split_whitespace().find(|w| w.matches(':').count() == 2)?;
    let mut hms = t.split(':').map(|v| v.parse::<f64>());
    Some(hms.next()?.ok()? * 3600.0 + hms.next()?.ok()? * 60.0 + hms.next()?.ok()?)
}

/// docs/link-and-recordings.md, "Durability": `listen --record` commits the
/// file with `fdatasync` at most 1 s after a frame was written and at every
/// exit, Ctrl-C included. Checked on the real listener's system calls
/// (`strace`): every write to the recording is followed by an `fdatasync`
/// of it within 1 s (and a quarter, for the loop's turn and strace's
/// delays), and the last call on the file is an `fdatasync` — after a
/// `--duration` and after SIGINT alike.
#[test]
fn a_recording_is_committed_within_a_second_of_each_frame_and_at_exit() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    assert!(
        Process::new("strace").arg("-V").output().is_ok_and(|o| o.status.success()),
        "this test needs strace (apt-get install strace; .ci/run installs it)"
    );
    for interrupt in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        let (rec, log) = (dir.path().join("r.cmsrec"), dir.path().join("strace.log"));
        let state = dir.path().join("state");
        let duration = if interrupt { "60" } else { "3" };
        let mut child = Process::new("strace")
            // The main thread only (no -f): it opens, writes and commits the
            // recording, and the simulated head's threads would interleave
            // their calls with its own (`<unfinished ...>` lines).
            .args(["-tt", "-e", "trace=openat,write,fdatasync", "-o"])
            .arg(&log)
            .arg(env!("CARGO_BIN_EXE_cms-host"))
            .args(["listen", "sim", "--sim-light=incoherent", "--lasers", "1", "--duration", duration, "--sim-state"])
            .arg(&state)
            .arg("--record")
            .arg(&rec)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        if interrupt {
            // The event: 20 frames in the file; then Ctrl-C to the listener
            // (strace's child).
            let children = format!("/proc/{0}/task/{0}/children", child.id());
            loop {
                // The file exists before its header is written: until then it is no recording yet.
                let n = std::fs::read(&rec)
                    .ok()
                    .and_then(|b| recording::scan_reader(Path::new("mem"), &b[..], |_| Ok(())).ok())
                    .map_or(0, |s| s.messages);
                if n >= 20 {
                    break;
                }
                assert!(child.try_wait().unwrap().is_none(), "the listener ended early");
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            let pid: i32 =
                std::fs::read_to_string(&children).unwrap().split_whitespace().next().unwrap().parse().unwrap();
            kill(Pid::from_raw(pid), Signal::SIGINT).unwrap();
        }
        assert!(child.wait().unwrap().success(), "interrupted: {interrupt}");
        let text = std::fs::read_to_string(&log).unwrap();
        let name = format!("\"{}\"", rec.display());
        let fd = text
            .lines()
            .find(|l| l.contains("openat(") && l.contains(&name))
            .and_then(|l| l.rsplit("= ").next())
            .map(|fd| fd.trim().to_string())
            .expect("the recording opened");
        let (write, sync) = (format!("write({fd}, "), format!("fdatasync({fd}"));
        let mut calls: Vec<(f64, bool)> = Vec::new(); // (time, is a sync)
        for l in text.lines() {
            if l.contains(&write) || l.contains(&sync) {
                calls.push((strace_time(l).unwrap(), l.contains(&sync)));
            }
        }
        let writes = calls.iter().filter(|c| !c.1).count();
        assert!(writes >= 20, "{writes} writes (interrupted: {interrupt})");
        assert!(
            calls.last().is_some_and(|c| c.1),
            "the last call on the file is no fdatasync (interrupted: {interrupt})"
        );
        for (i, &(t, is_sync)) in calls.iter().enumerate() {
            if !is_sync {
                let next = calls[i..].iter().find(|c| c.1).unwrap().0;
                assert!(next - t <= 1.25, "a write at {t:.3} s committed {:.3} s later", next - t);
            }
        }
    }
}
