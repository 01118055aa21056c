//! Event marks end to end: `listen sim --record` with marks typed on its
//! stdin and one sent to the live page's `POST /marks`, then `info`,
//! `export --format marks` and `analyze --report`, each mark at the
//! chainage of where the head was when it was made (to within one frame's
//! travel); and a recording of format 4 (before marks) still read, and
//! refusing marks when appended to.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use cms_core::protocol::DeviceMsg;
use cms_host::recording::mark::{Mark, MarkKind};
use cms_host::recording::{HostRecord, Item};

use crate::common::{bin, run};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A running `cms-host listen sim …` with its stdin a pipe, its stderr
/// read line by line.
struct Listen {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<String>,
    stderr: JoinHandle<String>,
}

impl Listen {
    fn start(dir: &Path, args: &[&str]) -> Listen {
        let mut child = Command::new(bin())
            .args(["listen", "sim", "--sim-light=incoherent"])
            .args(args)
            .env("CMS_SIM_STATE", dir.join("sim-state"))
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stdin = child.stdin.take().unwrap();
        let err = child.stderr.take().unwrap();
        let (tx, lines) = mpsc::channel();
        let stderr = thread::spawn(move || {
            let mut all = String::new();
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(line.clone());
                all.push_str(&line);
                all.push('\n');
            }
            all
        });
        Listen { child, stdin, lines, stderr }
    }

    /// The next stderr line starting with `prefix` (the lines before it passed over).
    fn wait_for(&self, prefix: &str) -> String {
        loop {
            match self.lines.recv_timeout(Duration::from_secs(60)) {
                Ok(l) if l.starts_with(prefix) => return l,
                Ok(_) => {}
                Err(e) => panic!("no line `{prefix}…` ({e})"),
            }
        }
    }

    /// Types one line on its stdin, and waits for the answer (a line
    /// starting `listen: mark`).
    fn type_line(&mut self, line: &str) -> String {
        writeln!(self.stdin, "{line}").unwrap();
        self.stdin.flush().unwrap();
        self.wait_for("listen: mark")
    }

    fn wait(mut self) -> String {
        drop(self.stdin);
        let status = self.child.wait().unwrap();
        let err = self.stderr.join().unwrap();
        assert!(status.success(), "{err}");
        err
    }
}

/// The answer to a `POST /marks` of `body`: status code and body.
fn post_mark(host: &str, body: &str) -> (u16, String) {
    let mut c = TcpStream::connect(host).unwrap();
    c.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let req = format!(
        "POST /marks HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    c.write_all(req.as_bytes()).unwrap();
    let mut got = String::new();
    c.read_to_string(&mut got).unwrap();
    let code = got.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let body = got.split_once("\r\n\r\n").map_or("", |(_, b)| b).to_string();
    (code, body)
}

/// The recording's marks, and its frames' `(seq, timestamp_us, odometer_um)` in order.
fn read(path: &Path) -> (Vec<Mark>, Vec<(u32, u64, i64)>) {
    let (mut marks, mut frames) = (Vec::new(), Vec::new());
    let f = std::fs::File::open(path).unwrap();
    cms_host::recording::scan_records(path, f, |item| {
        match item {
            Item::Host(HostRecord::Mark(m)) => marks.push(m.clone()),
            Item::Device(DeviceMsg::Profile(p)) if p.part == 0 => frames.push((p.seq, p.timestamp_us, p.odometer_um)),
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    (marks, frames)
}

/// The odometer of the frame the head had last taken when the mark was
/// made (by the mark's time on the head's clock: the frame before it and
/// the host time since), and the travel of one frame there (µm). The mark
/// is at that frame, or at one before it when that frame was still on
/// its way over the link.
fn odometer_at(m: &Mark, frames: &[(u32, u64, i64)]) -> (i64, i64) {
    let t = m.head_us + m.after_us;
    let i = frames.iter().rposition(|f| f.1 <= t).unwrap().clamp(1, frames.len() - 2);
    let step = |a: usize, b: usize| (frames[b].2 - frames[a].2).abs();
    (frames[i].2, step(i - 1, i).max(step(i, i + 1)))
}

fn survey(dir: &Path) -> PathBuf {
    let p = dir.join("survey.toml");
    std::fs::write(&p, "line = \"A\"\ntrack = \"1\"\nstart_chainage = \"41+100\"\nchainage = \"down\"\n").unwrap();
    p
}

#[test]
fn marks_typed_on_the_terminal_appear_in_the_report_at_their_chainage() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let sv = survey(dir.path());
    let mut l = Listen::start(
        dir.path(),
        &["--frames", "150", "--sim-speed-mm-s", "1000", "--record", s(&rec), "--survey", s(&sv)],
    );
    l.wait_for("streaming: ");
    assert!(l.type_line("w").starts_with("listen: mark: weld at odometer "));
    let bad = l.type_line("x marks the spot");
    assert!(bad.starts_with("listen: mark not recorded: `x` is no mark"), "{bad}");
    let bad = l.type_line("n");
    assert!(bad.starts_with("listen: mark not recorded: a note mark needs text"), "{bad}");
    l.wait_for("streaming: ");
    let k = l.type_line("k 12.300");
    assert!(k.starts_with("listen: mark: kilometre_post \"12.300\" at odometer "), "{k}");
    l.wait_for("streaming: ");
    assert!(l.type_line("d squat, gauge corner").starts_with("listen: mark: defect"));
    let err = l.wait();
    assert!(err.contains("listen: marks: 3 recorded, 0 refused"), "{err}");

    let (marks, frames) = read(&rec);
    let kinds: Vec<MarkKind> = marks.iter().map(|m| m.kind).collect();
    assert_eq!(kinds, [MarkKind::Weld, MarkKind::KilometrePost, MarkKind::Defect]);
    assert_eq!(marks[2].text, "squat, gauge corner");
    for m in &marks {
        // The frame it names is the one it took its odometer from, and the
        // head was there when it was made, to within one frame's travel.
        let f = frames.iter().find(|f| f.0 == m.seq).unwrap();
        assert_eq!(f.2, m.odometer_um);
        let (at, travel) = odometer_at(m, &frames);
        assert!(travel > 0 && (m.odometer_um - at).abs() <= travel, "{m:?}: frame odometer {at}, travel {travel}");
    }

    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(info.contains("format: 6 ") && info.contains("marks: 3\n"), "{info}");
    assert!(info.contains("mark: kilometre_post \"12.300\" at odometer "), "{info}");
    let o = run(&["export", s(&rec), "--format", "marks", "--out", "-"]);
    let csv = String::from_utf8(o.stdout).unwrap();
    assert_eq!(csv.lines().count(), 4, "{csv}");
    assert!(csv.contains("\nweld,\"\",") && csv.contains("\ndefect,\"squat, gauge corner\","), "{csv}");

    let report = dir.path().join("report");
    let o = run(&["analyze", s(&rec), "--report", s(&report)]);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("\nmarks: 3\n"), "{out}");
    let table = std::fs::read_to_string(report.join("marks.csv")).unwrap();
    let rows: Vec<Vec<&str>> = table.lines().skip(1).map(|l| l.splitn(5, ',').collect()).collect();
    assert_eq!(rows.len(), 3, "{table}");
    // Chainage runs down from 41+100: in chainage order the last mark first.
    assert_eq!(rows.iter().map(|r| r[3]).collect::<Vec<_>>(), ["defect", "kilometre_post", "weld"], "{table}");
    for (row, m) in rows.iter().zip(marks.iter().rev()) {
        let chainage_mm: f64 = row[0].parse().unwrap();
        let (at, travel) = odometer_at(m, &frames);
        let head_mm = 41_100_000.0 - at as f64 / 1000.0;
        // The frame last received may trail the head's last by what the
        // link still holds: on a loaded machine a frame and a little more.
        assert!((chainage_mm - head_mm).abs() <= 2.0 * travel as f64 / 1000.0, "{row:?}: the head at {head_mm} mm");
        assert!((chainage_mm - (41_100_000.0 - m.odometer_mm())).abs() < 1e-3, "{row:?}");
        assert!(out.contains(&format!("  {} {}", row[1], m.kind)), "{out}");
    }
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    let section = html.split("<section id=\"marks\">").nth(1).unwrap().split("</section>").next().unwrap();
    assert!(section.contains("<table class=\"marks\">"), "{section}");
    // The label's cell is a number's (right-aligned) in the report's tables.
    let km = format!("<td>{}</td><td>kilometre post</td><td class=\"num\">12.300</td>", rows[1][1]);
    assert!(section.contains(&km), "{section}");
    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    assert!(md.contains("## Marks") && md.contains("| defect | squat, gauge corner |"), "{md}");
}

#[test]
fn a_mark_from_the_page_is_recorded_where_the_head_was() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("live.cmsrec");
    let sv = survey(dir.path());
    let l = Listen::start(
        dir.path(),
        &[
            "--frames",
            "120",
            "--record",
            s(&rec),
            "--survey",
            s(&sv),
            "--serve",
            "127.0.0.1:0",
            "--sim-speed-mm-s",
            "1000",
        ],
    );
    let url = l.wait_for("listen: live view on ");
    let host = url["listen: live view on http://".len()..].split('/').next().unwrap().to_string();
    l.wait_for("streaming: ");
    let (code, body) = post_mark(&host, r#"{"kind":"joint","text":"IRJ 4"}"#);
    assert_eq!(code, 201, "{body}");
    let answer: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!((answer["kind"].as_str(), answer["text"].as_str()), (Some("joint"), Some("IRJ 4")));
    for (bad, want) in [
        (r#"{"kind":"joint","colour":"red"}"#, 400),
        (r#"{"kind":"rail"}"#, 422),
        (r#"{"kind":"note","text":"a\u0007b"}"#, 422),
    ] {
        assert_eq!(post_mark(&host, bad).0, want, "{bad}");
    }
    let err = l.wait();
    assert!(err.contains("listen: marks: 1 recorded"), "{err}");
    let (marks, frames) = read(&rec);
    assert_eq!(marks.len(), 1);
    let m = &marks[0];
    assert_eq!((m.kind, m.text.as_str()), (MarkKind::Joint, "IRJ 4"));
    assert_eq!(answer["odometer_mm"].as_f64(), Some(m.odometer_mm()));
    let (at, travel) = odometer_at(m, &frames);
    assert!((m.odometer_um - at).abs() <= travel, "{m:?}: the head at {at}, travel {travel}");
    // The page's chainage is the report's.
    let report = dir.path().join("report");
    assert!(run(&["analyze", s(&rec), "--report", s(&report)]).status.success());
    let table = std::fs::read_to_string(report.join("marks.csv")).unwrap();
    let row = table.lines().nth(1).unwrap();
    assert_eq!(row.split(',').nth(1), answer["chainage"].as_str(), "{table}");
}

/// Rewrites a recording's format version to 4 (the header's checksum made
/// again): what a build of format 4 wrote, byte for byte, since formats 5
/// and 6 only add what such a file does not hold (marks, and fixes with
/// the receiver's σ, which the simulated receiver does not send).
fn as_format_4(path: &Path) {
    let mut b = std::fs::read(path).unwrap();
    assert_eq!(u16::from_le_bytes([b[8], b[9]]), 6);
    let survey_len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    b[8] = 4;
    let end = 16 + survey_len;
    let crc = cms_core::protocol::CRC.checksum(&b[..end]);
    b[end..end + 4].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(path, b).unwrap();
}

#[test]
fn a_format_4_recording_still_reads_and_takes_no_marks() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("old.cmsrec");
    let o = run(&["listen", "sim", "--sim-light=incoherent", "--gnss", "sim", "--frames", "60", "--record", s(&rec)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    as_format_4(&rec);
    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(info.contains("format: 4 ") && info.contains("frames: 60 "), "{info}");
    assert!(
        info.contains("gnss: ") && !info.contains("gnss: no fixes") && info.contains("damaged frames: 0"),
        "{info}"
    );
    assert!(!info.contains("marks"), "{info}");
    let o = run(&["analyze", s(&rec)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!String::from_utf8_lossy(&o.stdout).contains("marks:"));
    let o = run(&["export", s(&rec), "--format", "marks", "--out", "-"]);
    assert_eq!(String::from_utf8(o.stdout).unwrap(), "kind,text,odometer_mm,seq,head_us,host_us,after_us\n");

    // Appended to, it stays format 4: a mark is refused, not written where
    // a format-4 reader would take it for damage.
    let mut l = Listen::start(dir.path(), &["--frames", "60", "--record", s(&rec)]);
    l.wait_for("streaming: ");
    let no = l.type_line("w");
    assert!(no.starts_with("listen: mark not recorded: the recording is of format 4, which holds no marks"), "{no}");
    let err = l.wait();
    assert!(err.contains("listen: marks: 0 recorded, 1 refused"), "{err}");
    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(
        info.contains("format: 4 ") && info.contains("frames: 120 ") && info.contains("damaged frames: 0"),
        "{info}"
    );
}
