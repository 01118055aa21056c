//! `cms-host listen` as a user runs it, against the test device.

use crate::common::bin;
use std::io::{self, Read};
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::sync::atomic::AtomicBool;
use std::thread;
use std::time::Duration;

use cms_core::pipeline::{Head, Identity, default_detector};
use cms_core::protocol::{DeviceMsg, HeadState, MAX_FRAME, PROTOCOL_VERSION, encode};
use cms_host::device::listen::{ListenError, ListenOptions, listen_with};
use cms_host::recording;

use super::*;

/// `cms-host listen PORT --frames 30 --json --record F`, then `info F` and
/// `export F --format csv|jsonl`.
#[test]
fn cli_listen_json_record_info_export() {
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let rec = dir.path().join("cli.cmsrec");
    let out = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--frames", "30", "--json", "--rate", "200", "--record"])
        .arg(&rec)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let report = served.finish();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8(out.stdout).unwrap();
    let seqs: Vec<u64> = stdout
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["seq"].as_u64().unwrap())
        .collect();
    assert_eq!(seqs.len(), 30);
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    assert!(stderr.contains("listen: frames: 30 "), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert!(stderr.contains("listen: calibration: none (positions in pixels only"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));

    let info = Process::new(bin()).arg("info").arg(&rec).output().unwrap();
    assert!(info.status.success());
    let info = String::from_utf8(info.stdout).unwrap();
    assert!(info.contains("frames: 30 (30 profile messages)"), "{info}");
    assert!(info.contains("device: firmware 0.1.0-test, board test-pty"), "{info}");
    assert!(info.contains("damaged frames: 0"), "{info}");

    let csv = Process::new(bin()).args(["export", "--format", "csv"]).arg(&rec).output().unwrap();
    assert!(csv.status.success());
    let csv = String::from_utf8(csv.stdout).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(recording::CSV_HEADER));
    assert_eq!(lines.count(), 30 * 3 * 64, "3 points per row, 64 rows, 30 frames");

    let jl = dir.path().join("out.jsonl");
    let e = Process::new(bin()).args(["export", "--format", "jsonl", "--out"]).arg(&jl).arg(&rec).output().unwrap();
    assert!(e.status.success());
    assert_eq!(std::fs::read_to_string(&jl).unwrap(), stdout);
}

/// Ctrl-C: Stop sent and acknowledged (lasers off), summary printed, exit 0.
#[test]
fn cli_ctrl_c_stops_the_head() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let mut child = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for a few frames.
    let mut stdout = child.stdout.take().unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while got.iter().filter(|&&b| b == b'\n').count() < 5 {
        let n = stdout.read(&mut buf).unwrap();
        assert!(n > 0, "listen ended early");
        got.extend_from_slice(&buf[..n]);
    }
    kill(Pid::from_raw(child.id() as i32), Signal::SIGINT).unwrap();
    let mut rest = Vec::new();
    stdout.read_to_end(&mut rest).unwrap();
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    let report = served.finish();
    assert!(status.success(), "{status:?}: {stderr}");
    assert!(stderr.contains("listen: frames: "), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));
    // The laser log ends with the lasers off.
    assert_eq!(report.lasers.last().map(|l| l.1), Some(0));
}

/// Bad arguments and a missing port: one line on stderr, non-zero exit.
#[test]
fn cli_errors_are_one_line() {
    for (args, needle) in [
        (vec!["listen", "/nonexistent/ttyX"], "cannot open /nonexistent/ttyX"),
        (vec!["listen", "/dev/null", "--lasers", "9"], "laser mask"),
        (vec!["listen", "/dev/null", "--duration", "0"], "seconds"),
        (vec!["info", "/nonexistent/rec"], "cannot open recording"),
    ] {
        let out = Process::new(bin()).args(&args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
}

/// `listen --json | head -1`: the closed pipe ends the listener quietly,
/// with the head stopped.
#[test]
fn cli_closed_stdout_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let served = Served::new(dir.path());
    let mut child = Process::new(bin())
        .args(["listen", served.link.to_str().unwrap(), "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut buf = [0u8; 1];
    while buf[0] != b'\n' {
        stdout.read_exact(&mut buf).unwrap();
    }
    drop(stdout);
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    let report = served.finish();
    assert!(status.success(), "{status:?}: {stderr}");
    assert!(!stderr.contains("error:"), "{stderr}");
    assert!(stderr.contains("listen: lasers: off (stop acknowledged)"), "{stderr}");
    assert_eq!(report.end, Some((HeadState::Idle, 0)));
}

/// An installed `cms-host` (a copy outside the checkout, run from outside
/// it) finds the emulated head's image beside itself or through
/// `CMS_QEMU_IMAGE`, and without one says in one line what to do.
#[test]
fn cli_qemu_image_outside_the_checkout() {
    let dir = tempfile::tempdir().unwrap();
    let installed = dir.path().join("cms-host");
    std::fs::copy(bin(), &installed).unwrap();
    let run = |env: Option<&Path>| {
        let mut cmd = Process::new(&installed);
        cmd.args(["listen", "qemu", "--frames", "1", "--reconnect-timeout", "1"])
            .current_dir(dir.path())
            .env_remove("CMS_QEMU_IMAGE");
        if let Some(p) = env {
            cmd.env("CMS_QEMU_IMAGE", p);
        }
        let out = cmd.stdin(Stdio::null()).output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (code, stderr) = run(None);
    // Which failure status is the command line's (cli::exit); not success.
    assert!(code.is_some_and(|c| c != 0), "{code:?}: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("no emulated head image cms-qemu-head: give --qemu-image FILE, set CMS_QEMU_IMAGE"),
        "{stderr}"
    );
    assert!(stderr.contains("`cd firmware/qemu && cargo build --release`"), "{stderr}");

    let missing = dir.path().join("nowhere.elf");
    let (code, stderr) = run(Some(&missing));
    // Which failure status is the command line's (cli::exit); not success.
    assert!(code.is_some_and(|c| c != 0), "{code:?}: {stderr}");
    assert!(stderr.contains(&format!("emulated head image {} does not exist", missing.display())), "{stderr}");

    // Not an image QEMU can run: what matters is that it was found (QEMU
    // then fails, or is not installed), not the old "no image" error.
    std::fs::write(dir.path().join("cms-qemu-head"), b"not an ELF").unwrap();
    let (code, stderr) = run(None);
    assert_ne!(code, Some(0), "{stderr}");
    assert!(!stderr.contains("no emulated head image"), "the image beside the binary is used: {stderr}");
    assert!(stderr.contains("qemu"), "{stderr}");
}

fn cobs_decode(f: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < f.len() {
        let code = f[i] as usize;
        out.extend_from_slice(&f[i + 1..i + code]);
        i += code;
        if code < 0xFF && i < f.len() {
            out.push(0);
        }
    }
    out
}

fn cobs_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    for &b in raw {
        if b == 0 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
        } else {
            out.push(b);
            if out.len() - code_at == 0xFF {
                out[code_at] = 0xFF;
                code_at = out.len();
                out.push(0);
            }
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out
}

/// A head of another protocol version is refused with both versions named.
#[test]
fn another_protocol_version_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyV2");
    let pty = plug(&link);
    // A Hello framed as the next protocol version (CRC recomputed).
    let mut info = None;
    let head: Head<W, Lasers> =
        Head::new(Lasers::default(), default_detector(), Identity { firmware: "9", board: "v2" }).expect("head");
    info.get_or_insert(head.info(&TestCamera::new(64, 4, 1, 1)));
    let f = {
        let mut out = vec![0u8; MAX_FRAME];
        encode(&DeviceMsg::Hello(info.unwrap()), &mut out).unwrap().to_vec()
    };
    let mut raw = cobs_decode(&f[..f.len() - 1]);
    raw[0] = PROTOCOL_VERSION + 1;
    let n = raw.len() - 4;
    let crc = cms_core::protocol::CRC.checksum(&raw[..n]);
    raw[n..].copy_from_slice(&crc.to_le_bytes());
    let mut v2 = cobs_encode(&raw);
    v2.push(0);
    // The answering thread blocks on the master until a command arrives, and
    // ends at the hang-up when the last slave descriptor closes: the
    // listener's, then this test's own (kept until the listener is done, so
    // the master never hangs up before the listener has opened the path).
    let Pty { mut master, slave } = pty;
    let answer = thread::spawn(move || {
        use nix::poll::PollFlags;
        let mut buf = [0u8; 256];
        loop {
            let ev = wait_for(&master, PollFlags::POLLIN, Duration::from_secs(60));
            if ev.intersects(PollFlags::POLLHUP | PollFlags::POLLERR) || ev.is_empty() {
                break;
            }
            if let Ok(n) = master.read(&mut buf)
                && buf[..n].contains(&0)
            {
                let _ = write_all(&mut master, &v2);
            }
        }
    });
    let opts = ListenOptions::default();
    let e =
        listen_with(link.to_str().unwrap(), &opts, &AtomicBool::new(false), &mut io::sink(), &mut |_| {}).unwrap_err();
    drop(slave);
    answer.join().unwrap();
    assert!(matches!(e, ListenError::Version { theirs, .. } if theirs == PROTOCOL_VERSION + 1), "{e}");
    let want =
        format!("speaks protocol version {}; this cms-host speaks version {PROTOCOL_VERSION}", PROTOCOL_VERSION + 1);
    assert!(e.to_string().contains(&want), "{e}");
}
