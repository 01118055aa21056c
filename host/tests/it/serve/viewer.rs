//! `cms-host view`: a recording in a real headless Chromium (the live
//! view's [`Browser`]): the page shows `analyze --json`'s figures of the
//! same recording and options, zooms and scrubs, asks nothing of any other
//! server, and its screenshot is kept (`$CARGO_TARGET_TMPDIR/viewer.png`;
//! with `CMS_DOCS_FIGURES=1` also `docs/figures/viewer.png`). Hostile
//! requests get a 4xx and the viewer goes on.

use std::io::{Read as _, Write as _};
use std::time::Instant;

use serde_json::Value;

use super::browser::Browser;
use super::*;
use crate::common::run;

/// A `cms-host view … --serve 127.0.0.1:0` process and its address.
struct View {
    child: Child,
    host: String,
}

impl View {
    fn start(args: &[&str]) -> View {
        let mut child = Command::new(bin())
            .arg("view")
            .args(args)
            .args(if args.contains(&"--serve") { &[][..] } else { &["--serve", "127.0.0.1:0"][..] })
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let err = child.stderr.take().unwrap();
        let (tx, rx) = mpsc::channel();
        thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let host = loop {
            let line = rx.recv_timeout(Duration::from_secs(120)).expect("view names its address");
            if let Some(rest) = line.strip_prefix("view: on http://") {
                break rest.split('/').next().unwrap().replace("0.0.0.0:", "127.0.0.1:");
            }
        };
        View { child, host }
    }

    /// `GET path`'s JSON body.
    fn json(&self, path: &str) -> Value {
        let mut s = std::net::TcpStream::connect(&self.host).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        write!(s, "GET {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n", self.host).unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        let (head, body) = out.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 200"), "{path}: {head}");
        serde_json::from_str(body).unwrap_or_else(|e| panic!("{path}: {e}: {body}"))
    }

    /// One raw HTTP/1.1 exchange: the status code.
    fn status(&self, request: &str) -> u16 {
        let mut s = std::net::TcpStream::connect(&self.host).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        s.write_all(request.replace("HOST", &self.host).as_bytes()).unwrap();
        let mut out = String::new();
        let _ = s.read_to_string(&mut out);
        out.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or_else(|| panic!("no status: {out:?}"))
    }
}

impl Drop for View {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// What the page shows, read from its elements.
const SHOWN: &str = r#"
const t = (id) => document.getElementById(id).textContent;
const rows = (id) => [...document.querySelectorAll('#' + id + ' tbody tr')].map((r) => [...r.cells].map((c) => c.textContent));
return { reprofile: t('reprofile'), measured: t('measured'), frames: t('frames'), kept: t('kept'),
         zones: rows('zones'), blocks: rows('blocks'), bands: rows('bands'), edition: t('edition'),
         iso: rows('iso3095'), iso_head: [...document.querySelectorAll('#iso3095 thead th')].map((c) => c.textContent),
         range: t('range'), frame: t('frameno'), odometer: t('frameodo') };
"#;

/// The viewer's ISO 3095 table: each line's and the energy average's
/// verdict word per third octave is `analyze --json`'s, and where not
/// within the rail's level is shown.
fn iso3095_shown_is_analyzes(shown: &Value, a: &Value) {
    let head: Vec<&str> = shown["iso_head"].as_array().unwrap().iter().map(|h| h.as_str().unwrap()).collect();
    assert!(head.len() > 3 && head.contains(&"energy average"), "{head:?}");
    let rows = shown["iso"].as_array().unwrap();
    assert!(!rows.is_empty());
    let mut words = std::collections::BTreeSet::new();
    for r in rows {
        let section = r[0].as_str().unwrap();
        let spectrum = |name: &str| -> &Value {
            // Numbers in the JSON, text in the page's table.
            let text = |v: &Value| v.to_string();
            let same = |v: &Value| text(&v["section"]) == section;
            match name.strip_prefix("laser ") {
                Some(k) => {
                    &a["lasers"].as_array().unwrap().iter().find(|l| same(l) && text(&l["laser"]) == k).unwrap()["en15610"]
                }
                None => &a["noise"]["running_bands"].as_array().unwrap().iter().find(|rb| same(rb)).unwrap()["en15610"],
            }
        };
        for (name, cell) in head[3..].iter().zip(&r.as_array().unwrap()[3..]) {
            let cell = cell.as_str().unwrap();
            let bands = spectrum(name)["bands"].as_array().unwrap();
            let band =
                bands.iter().find(|b| format!("{} mm", b["nominal_wavelength_mm"].as_f64().unwrap()) == r[1]).unwrap();
            let d = &band["decision"];
            let word = d["verdict"].as_str().unwrap();
            assert_eq!(cell.split(':').next(), Some(word), "{name} at {}: {cell} vs {d}", r[1]);
            if let (false, Some(rail)) = (word == "within", d["rail_db"].as_f64()) {
                assert!(cell.contains(&format!("rail {rail:.1} [")), "{cell} vs {d}");
            }
            words.insert(word.to_string());
        }
    }
    assert!(words.contains("EXCEEDS"), "{words:?}");
}

/// The viewer of a synthetic 20 m run (30 µm at 50 mm: zones over the
/// 30–100 mm limit) shows `analyze --json`'s verdict, zones, blocks and
/// frame count; zooming asks the server again and narrows the range shown;
/// the slider shows another frame, the recording's; nothing is requested
/// but from the viewer.
#[test]
fn the_viewer_shows_what_analyze_finds() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let r = rec.to_str().unwrap();
    let o = run(&["bench", "recording", "--frames", "1200", "--out", r]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["analyze", r, "--block-m", "5", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a: Value = serde_json::from_slice(&o.stdout).unwrap();
    let v = &a["verdict"];

    let view = View::start(&[r, "--block-m", "5"]);
    let url = format!("http://{}/", view.host);
    let b = Browser::start();
    let started = Instant::now();
    b.goto(&url);
    b.wait_for(
        "return document.body.dataset.loaded === '1' && document.body.dataset.profiles === '1' && document.body.dataset.frame === '0'",
        Duration::from_secs(30),
        "analysis, profile and first frame",
    );
    let load_s = started.elapsed().as_secs_f64();
    let shown = b.eval(SHOWN);
    eprintln!("viewer loaded in {load_s:.2} s; shown: {shown}");

    // analyze's figures.
    assert_eq!(shown["reprofile"], format!("{:.1} m", v["reprofile_mm"].as_f64().unwrap() / 1000.0));
    assert_eq!(shown["measured"], format!("{:.1} m", v["measured_mm"].as_f64().unwrap() / 1000.0));
    assert_eq!(shown["edition"], v["edition"]);
    assert_eq!(shown["frames"], a["frames"].to_string());
    let zones = v["zones"].as_array().unwrap();
    assert!(!zones.is_empty());
    let shown_zones = shown["zones"].as_array().unwrap();
    assert_eq!(shown_zones.len(), zones.len());
    for (s, z) in shown_zones.iter().zip(zones) {
        assert_eq!(s[1], z["start_chainage"], "{s} {z}");
        assert_eq!(s[2], z["end_chainage"], "{s} {z}");
        assert_eq!(s[4], format!("{:.1} µm", z["worst_pp_mm"].as_f64().unwrap() * 1000.0));
    }
    let blocks = v["blocks"].as_array().unwrap();
    let shown_blocks = shown["blocks"].as_array().unwrap();
    assert_eq!(shown_blocks.len(), blocks.len());
    for (s, j) in shown_blocks.iter().zip(blocks) {
        let rms = j["rms_mm"][1].as_f64().map_or("–".to_string(), |mm| format!("{:.1}", mm * 1000.0));
        assert_eq!(s[3], rms, "{s} {j}");
        let verdict = j["iso3095"]["verdict"].as_str().unwrap_or("no spectrum");
        assert!(s[6].as_str().unwrap().starts_with(verdict), "{s} {j}");
    }
    iso3095_shown_is_analyzes(&shown, &a);
    assert_eq!(shown["bands"].as_array().unwrap().len(), v["bands"].as_array().unwrap().len());

    // Zoom: the server is asked again, the range narrows.
    b.eval("document.getElementById('zoomin').click(); return true;");
    b.wait_for("return document.body.dataset.profiles === '2'", Duration::from_secs(10), "zoomed profile");
    let zoomed = b.eval(SHOWN);
    assert_ne!(zoomed["range"], shown["range"]);
    // Scrub to the last kept frame: the recording's 1200th.
    b.eval("const s = document.getElementById('scrub'); s.value = s.max; s.dispatchEvent(new Event('input')); return true;");
    b.wait_for("return document.body.dataset.frame === '1199'", Duration::from_secs(10), "the scrubbed frame");
    let last = b.eval(SHOWN);
    assert_eq!(last["frame"], "1199 of 1200");
    let png = b.screenshot();
    let urls = b.requested();
    drop(b);

    let own = format!("http://{}/", view.host);
    assert!(urls.iter().any(|u| u.starts_with(&format!("{own}api/profile"))), "{urls:?}");
    for u in &urls {
        let internal = ["chrome:", "chrome-untrusted:", "about:", "data:", "blob:"].iter().any(|s| u.starts_with(s));
        assert!(internal || u.starts_with(&own), "the browser asked {u} (of {urls:?})");
    }
    std::fs::write(PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("viewer.png"), &png).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 20_000, "screenshot of {} bytes", png.len());
    if std::env::var_os("CMS_DOCS_FIGURES").is_some() {
        std::fs::write(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/figures/viewer.png"), &png).unwrap();
    }

    // Hostile requests: refused, and the viewer still answers.
    let get = |path: &str| format!("GET {path} HTTP/1.1\r\nHost: HOST\r\nConnection: close\r\n\r\n");
    assert_eq!(view.status(&get("/api/profile?from_mm=5&to_mm=1&bins=10")), 400);
    assert_eq!(view.status(&get("/api/profile?from_mm=0&to_mm=1e3&bins=999999")), 400);
    assert_eq!(view.status(&get("/api/frame?i=nope")), 400);
    assert_eq!(view.status(&get("/api/frame?i=99999")), 404);
    assert_eq!(view.status(&get("/etc/passwd")), 404);
    assert_eq!(
        view.status("POST /api/analysis HTTP/1.1\r\nHost: HOST\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"),
        405
    );
    assert_eq!(view.status("GET / HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n"), 421);
    assert_eq!(view.status("garbage\r\n\r\n"), 400);
    assert_eq!(view.status(&get("/api/frame?i=0")), 200);
}

/// A file that is not a recording: one line, exit status 2, no server.
#[test]
fn the_viewer_refuses_what_is_not_a_recording() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("x.cmsrec");
    std::fs::write(&bad, b"not a recording at all").unwrap();
    let o = run(&["view", bad.to_str().unwrap(), "--serve", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// `view DIR` of `analyze --report DIR` shows the analysis the report
/// holds — `analyze --json`'s object — and the same profile as `view` of
/// the recording (every bin's lowest and highest height of every line);
/// its frames while the recording is where the report says, and says why
/// there are none once it has moved; an analysis option with a report
/// folder is refused, not ignored.
#[test]
fn the_viewer_of_a_report_folder_shows_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let report = dir.path().join("report");
    let (r, d) = (rec.to_str().unwrap(), report.to_str().unwrap());
    let o = run(&["bench", "recording", "--frames", "600", "--out", r]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["analyze", r, "--block-m", "2", "--json", "--report", d]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a: Value = serde_json::from_slice(&o.stdout).unwrap();

    let q = "/api/profile?from_mm=100.25&to_mm=9000.75&bins=777";
    let (of_rec, of_report) = (View::start(&[r, "--block-m", "2"]), View::start(&[d]));
    let (m1, m2) = (of_rec.json("/api/analysis"), of_report.json("/api/analysis"));
    assert_eq!(m2["analysis"], a);
    assert_eq!(m1["analysis"], a);
    assert_eq!(m2["frames_kept"], m1["frames_kept"]);
    assert_eq!(m2["frames_total"], 600);
    let (p1, p2) = (of_rec.json(q), of_report.json(q));
    assert_eq!(p1["lines"].as_array().unwrap().len(), 3);
    assert_eq!(p1, p2);
    assert_eq!(of_rec.json("/api/frame?i=599"), of_report.json("/api/frame?i=599"));
    drop((of_rec, of_report));

    std::fs::rename(&rec, dir.path().join("moved.cmsrec")).unwrap();
    let moved = View::start(&[d]);
    let m = moved.json("/api/analysis");
    assert_eq!(m["frames_kept"], 0);
    assert!(m["frames_note"].as_str().unwrap().contains("is not at the path the report names"), "{m}");
    assert_eq!(moved.json(q), p1);
    drop(moved);

    let o = run(&["view", d, "--block-m", "7", "--serve", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--block-m") && err.lines().count() == 1, "{err}");
}

/// Off loopback the viewer asks for its token (`--serve-token` here):
/// without it the page and the API are 401, with a wrong one 403; the
/// address printed carries it, and with it (in the address, then as the
/// cookie it sets, or as a bearer) the analysis is served.
#[test]
fn off_loopback_the_viewer_asks_for_its_token() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let r = rec.to_str().unwrap();
    let o = run(&["bench", "recording", "--frames", "300", "--out", r]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let view = View::start(&[r, "--serve", "0.0.0.0:0", "--serve-token", "viewer-token-0123456789"]);
    let port = view.host.rsplit(':').next().unwrap().to_string();
    let get = |path: &str, extra: &str| {
        format!("GET {path} HTTP/1.1\r\nHost: survey-laptop.example:{port}\r\n{extra}Connection: close\r\n\r\n")
    };
    assert_eq!(view.status(&get("/", "")), 401);
    assert_eq!(view.status(&get("/api/analysis", "")), 401);
    assert_eq!(view.status(&get("/api/profile?from_mm=0&to_mm=1000&bins=10", "")), 401);
    assert_eq!(view.status(&get("/api/frame?i=0", "Authorization: Bearer viewer-token-wrong-0000\r\n")), 403);
    assert_eq!(view.status(&get("/?token=viewer-token-0123456789", "")), 200);
    assert_eq!(
        view.status(&get("/api/frame?i=0", &format!("Cookie: cms_view_{port}=viewer-token-0123456789\r\n"))),
        200
    );
    assert_eq!(view.status(&get("/api/analysis", "Authorization: Bearer viewer-token-0123456789\r\n")), 200);
}
