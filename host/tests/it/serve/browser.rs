//! The live view in a real headless Chromium, driven over WebDriver
//! (chromedriver, through `fantoccini`): the page shows live frames, its
//! figures are the recording's, it asks nothing of any other server, and
//! its screenshot is kept (`$CARGO_TARGET_TMPDIR/live-view.png`; with
//! `CMS_DOCS_FIGURES=1` also `docs/figures/live-view.png`, the README's).
//!
//! Without Chromium and chromedriver the test fails, naming the packages:
//! it never passes by skipping.

use std::net::TcpListener;
use std::time::Instant;

use fantoccini::wd::WebDriverCompatibleCommand;
use serde_json::{Value, json};

use super::*;

/// How to install what the test needs.
const INSTALL: &str = "apt-get install chromium chromium-driver";

/// Chromium's flags here: headless as root, and none of its own traffic
/// (without the background-networking flags it reaches out at start).
const FLAGS: &[&str] = &[
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1280,1300",
];

/// `name` on the PATH (or one of `also`).
fn tool(name: &str, also: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path).map(|d| d.join(name)).chain(also.iter().map(PathBuf::from)).find(|p| p.is_file())
}

/// Chromium's legacy log of the session (`goog:loggingPrefs`), which
/// fantoccini has no call for.
#[derive(Debug)]
struct PerformanceLog;

impl WebDriverCompatibleCommand for PerformanceLog {
    fn endpoint(&self, base: &url::Url, session: Option<&str>) -> Result<url::Url, url::ParseError> {
        base.join(&format!("session/{}/se/log", session.unwrap_or("")))
    }

    fn method_and_body(&self, _: &url::Url) -> (http::Method, Option<String>) {
        (http::Method::POST, Some(r#"{"type":"performance"}"#.to_string()))
    }
}

/// A chromedriver with one Chromium session.
pub(super) struct Browser {
    rt: tokio::runtime::Runtime,
    client: Option<fantoccini::Client>,
    driver: Child,
    _profile: tempfile::TempDir,
}

impl Browser {
    pub(super) fn start() -> Browser {
        Browser::start_with(&[])
    }

    /// Chromium with `extra` flags besides [`FLAGS`].
    pub(super) fn start_with(extra: &[&str]) -> Browser {
        let chromium = tool("chromium", &["/usr/bin/chromium", "/usr/bin/chromium-browser"])
            .unwrap_or_else(|| panic!("no chromium: the live view's test needs a real browser ({INSTALL})"));
        let chromedriver = tool("chromedriver", &["/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver"])
            .unwrap_or_else(|| panic!("no chromedriver: the live view's test needs it to drive Chromium ({INSTALL})"));
        let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let driver = Command::new(chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("chromedriver does not start ({e}; {INSTALL})"));
        let deadline = Instant::now() + Duration::from_secs(30);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "chromedriver does not listen on {port}");
            thread::sleep(Duration::from_millis(50));
        }
        let profile = tempfile::tempdir().unwrap();
        let mut args: Vec<String> = FLAGS.iter().chain(extra).map(|s| s.to_string()).collect();
        args.push(format!("--user-data-dir={}", profile.path().display()));
        let caps = json!({
            "browserName": "chrome",
            "goog:chromeOptions": { "binary": chromium, "args": args },
            "goog:loggingPrefs": { "performance": "ALL" },
        });
        let Value::Object(caps) = caps else { unreachable!() };
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        let connector = hyper_util::client::legacy::connect::HttpConnector::new();
        let client = rt
            .block_on(
                fantoccini::ClientBuilder::new(connector)
                    .capabilities(caps)
                    .connect(&format!("http://127.0.0.1:{port}")),
            )
            .unwrap_or_else(|e| panic!("Chromium does not start under chromedriver: {e} ({INSTALL})"));
        Browser { rt, client: Some(client), driver, _profile: profile }
    }

    fn client(&self) -> &fantoccini::Client {
        self.client.as_ref().unwrap()
    }

    pub(super) fn goto(&self, url: &str) {
        self.rt.block_on(self.client().goto(url)).unwrap();
    }

    /// Runs `script` (a function body) in the page.
    pub(super) fn eval(&self, script: &str) -> Value {
        self.rt.block_on(self.client().execute(script, vec![])).unwrap_or_else(|e| panic!("{script}: {e}"))
    }

    /// Waits until `script` returns true in the page.
    pub(super) fn wait_for(&self, script: &str, within: Duration, what: &str) {
        let deadline = Instant::now() + within;
        while self.eval(script) != Value::Bool(true) {
            assert!(Instant::now() < deadline, "the page shows no {what} within {} s", within.as_secs());
            thread::sleep(Duration::from_millis(100));
        }
    }

    pub(super) fn screenshot(&self) -> Vec<u8> {
        self.rt.block_on(self.client().screenshot()).unwrap()
    }

    /// Every URL the browser requested or opened a socket to since the last call.
    pub(super) fn requested(&self) -> Vec<String> {
        let log = self.rt.block_on(self.client().issue_cmd(PerformanceLog)).expect("chromedriver gives its log");
        let mut urls = Vec::new();
        for entry in log.as_array().into_iter().flatten() {
            let Some(text) = entry["message"].as_str() else { continue };
            let Ok(m) = serde_json::from_str::<Value>(text) else { continue };
            let m = &m["message"];
            match m["method"].as_str() {
                Some("Network.requestWillBeSent") => {
                    urls.extend(m["params"]["request"]["url"].as_str().map(String::from))
                }
                Some("Network.webSocketCreated") => urls.extend(m["params"]["url"].as_str().map(String::from)),
                _ => {}
            }
        }
        urls
    }

    /// Opens another window and switches to it.
    fn new_window(&self) {
        let w = self.rt.block_on(self.client().new_window(false)).unwrap();
        self.rt.block_on(self.client().switch_to_window(w.handle)).unwrap();
    }

    fn windows(&self) -> Vec<fantoccini::wd::WindowHandle> {
        self.rt.block_on(self.client().windows()).unwrap()
    }

    fn switch(&self, w: &fantoccini::wd::WindowHandle) {
        self.rt.block_on(self.client().switch_to_window(w.clone())).unwrap();
    }

    /// Stops (`SIGSTOP`) or resumes (`SIGCONT`) every Chromium process of
    /// this browser: a browser frozen whole, its sockets open and unread.
    fn signal_all(&self, signal: nix::sys::signal::Signal) {
        for pid in descendants(self.driver.id() as i32) {
            let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), signal);
        }
    }
}

/// Every process below `root` (from /proc/PID/stat's parent field).
fn descendants(root: i32) -> Vec<i32> {
    let parents: Vec<(i32, i32)> = std::fs::read_dir("/proc")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let pid: i32 = e.file_name().to_str()?.parse().ok()?;
            let stat = std::fs::read_to_string(e.path().join("stat")).ok()?;
            // `pid (comm) state ppid …`; comm may hold spaces and parentheses.
            let ppid = stat.rsplit_once(')')?.1.split_whitespace().nth(1)?.parse().ok()?;
            Some((pid, ppid))
        })
        .collect();
    let mut out = vec![];
    let mut todo = vec![root];
    while let Some(p) = todo.pop() {
        for &(c, pp) in &parents {
            if pp == p {
                out.push(c);
                todo.push(c);
            }
        }
    }
    out
}

impl Drop for Browser {
    fn drop(&mut self) {
        if let Some(c) = self.client.take() {
            let _ = self.rt.block_on(c.close());
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// What the page shows, read in one go (so of one update).
const SHOWN: &str = r#"
const t = (id) => document.getElementById(id).textContent;
const bands = [...document.querySelectorAll('#bandtable tbody tr')].map((r) => ({ state: r.dataset.state, cells: [...r.cells].map((c) => c.textContent) }));
// Anything red (the failed verdict's colours) among the lines and the bands.
const red = [...document.querySelectorAll('#bands *, #lines *')].filter((e) => {
  const s = getComputedStyle(e);
  return s.backgroundColor === 'rgb(255, 227, 224)' || s.color === 'rgb(179, 38, 30)';
}).length;
const lines = [...document.querySelectorAll('#lines .line')].map((l) => {
  const q = (c) => l.querySelector(c).textContent;
  return { laser: Number(l.querySelector('.k').textContent), kept: q('.kept'), rejected: q('.rejected'),
           saturated: q('.saturated'), strength: q('.strength'), wavelength: q('.wavelength'),
           amplitude: q('.amplitude'), verdict: q('.verdict'), reasons: q('.reasons') };
});
// The ISO 3095 panel: its columns, and per third octave each cell's verdict and words.
const isoHead = [...document.querySelectorAll('#isotable thead th')].map((c) => c.textContent);
const iso = [...document.querySelectorAll('#isotable tbody tr')].map((r) => ({ state: r.dataset.state,
  cells: [...r.cells].map((c) => ({ text: c.textContent, verdict: c.dataset.verdict || null, tip: c.title })) }));
return { isoHead, iso, isoVerdicts: t('isoverdicts'), isoStretch: t('isostretch'), seq: t('seq'), frames: t('frames'), fps: t('fps'), odometer: t('odometer'), lost: t('lost'),
         damaged: t('damaged'), speed: t('speed'), speedlimit: t('speedlimit'), speedwarn: t('speedwarn'),
         phase: t('phase'), lasers: t('lasers'), updates: t('updates'), lines, bands, red };
"#;

/// CPU time of process `pid` (every thread: the listener, the simulated
/// head, the view), s.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let f: Vec<&str> = stat.rsplit_once(')').map_or("", |r| r.1).split_whitespace().collect();
    // utime and stime, fields 14 and 15 (11 and 12 after the state), in ticks.
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

/// The number at the start of a shown figure ("50.0 mm" → 50).
fn number(v: &Value) -> f64 {
    let s = v.as_str().unwrap_or_else(|| panic!("{v}"));
    s.split_whitespace().next().and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("not a number: {s:?}"))
}

/// `listen sim --serve` shown in Chromium: live updates; the frame shown
/// is the recording's own (sequence number, odometer, every laser's kept,
/// rejected and saturated points and mean strength); the estimate near
/// the simulated rail's 50 mm × 30 µm; the speed under its limit; no
/// request to anything but the server; a screenshot kept.
#[test]
fn a_real_browser_shows_the_recorded_frames_live() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start(
        dir.path(),
        &["--sim-corrugation", "50:30", "--sim-roughness-um", "0.5", "--sim-speed-mm-s", "1000"],
    );
    let b = Browser::start();
    b.goto(&listen.url);
    let load_ms = number(&Value::String(
        b.eval("const n = performance.getEntriesByType('navigation')[0]; return String(n.loadEventEnd - n.startTime);")
            .as_str()
            .unwrap()
            .to_string(),
    ));
    b.wait_for(
        "return window.cmsView().updates >= 30 && document.querySelectorAll('#lines .verdict[data-fit]').length === 3 && [...document.querySelectorAll('#bandtable tbody tr')].some((r) => r.dataset.state === 'over') && document.querySelectorAll('#isotable tbody tr[data-state=evaluated]').length > 0",
        Duration::from_secs(90),
        "live frames, corrugation estimates, the band table and the ISO 3095 panel",
    );
    let shown = b.eval(SHOWN);
    // Two event marks: the Weld button clicked, then D typed with the text box filled.
    b.eval("document.querySelector('#marks button[data-kind=weld]').click(); return null;");
    b.wait_for("return window.cmsView().marks === 1", Duration::from_secs(30), "a weld marked");
    b.eval("document.getElementById('marktext').value = 'squat'; document.dispatchEvent(new KeyboardEvent('keydown', { key: 'd' })); return null;");
    b.wait_for("return window.cmsView().marks === 2", Duration::from_secs(30), "a defect marked");
    let marked = b.eval("return document.getElementById('markresult').textContent;");
    let png = b.screenshot();
    let urls = b.requested();
    drop(b);
    let (url, host, rec_path) = (listen.url.clone(), listen.host.clone(), listen.rec.clone());
    let (status, stderr) = listen.interrupt();
    assert!(status.success(), "{stderr}");
    eprintln!("page loaded in {load_ms:.0} ms; shown: {shown}");

    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("live-view.png");
    std::fs::write(&out, &png).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 20_000, "screenshot of {} bytes", png.len());
    if std::env::var_os("CMS_DOCS_FIGURES").is_some() {
        let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/figures/live-view.png");
        std::fs::write(docs, &png).unwrap();
    }

    // Nothing over the network but to the server itself (the browser's
    // own chrome:, about: and data: pages go nowhere).
    let own = [url, format!("ws://{host}/")];
    assert!(urls.iter().any(|u| u.starts_with(&own[1])), "no socket seen in {urls:?}");
    for u in &urls {
        let internal = ["chrome:", "chrome-untrusted:", "about:", "data:", "blob:"].iter().any(|s| u.starts_with(s));
        assert!(internal || own.iter().any(|o| u.starts_with(o.as_str())), "the browser asked {u} (of {urls:?})");
    }
    eprintln!("requests: {urls:?}");

    // The frame shown is the recording's, and so are the frames shown lost
    // (a loaded machine's pty may overflow: the head drops frames then).
    let (frames, order) = recorded(&rec_path);
    let seq: u32 = shown["seq"].as_str().unwrap().parse().unwrap();
    let upto: Vec<u32> = order.iter().copied().filter(|&s| s <= seq).collect();
    assert_eq!(shown["lost"], gaps(&upto).to_string(), "{order:?}");
    let rec = frames.get(&seq).unwrap_or_else(|| panic!("frame {seq} shown is not recorded"));
    assert_eq!(shown["odometer"].as_str().unwrap(), format!("{:.3} m", rec.odometer_um as f64 / 1e6));
    let lines = shown["lines"].as_array().unwrap();
    assert_eq!(lines.len(), rec.lasers.len());
    for l in lines {
        let k = l["laser"].as_u64().unwrap() as u8;
        let (kept, rejected, saturated, strength) = rec.lasers[&k];
        assert_eq!(l["kept"], kept.to_string(), "laser {k}");
        assert_eq!(l["rejected"], rejected.to_string(), "laser {k}");
        assert_eq!(l["saturated"], saturated.to_string(), "laser {k}");
        assert_eq!(l["strength"], format!("{:.0}", strength as f64 / kept as f64), "laser {k}");
        assert!((number(&l["wavelength"]) - 50.0).abs() < 1.0, "laser {k}: {l}");
        assert!((number(&l["amplitude"]) - 30.0).abs() < 2.0, "laser {k}: {l}");
    }
    // The band table: every band, the rail's 60 µm peak-to-peak over the
    // 30–100 mm limit; nothing red, the one sine a diagnostic.
    let bands = shown["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 4, "{shown}");
    assert_eq!(bands[1]["state"], "over", "{shown}");
    assert_eq!(bands[1]["cells"][0], "30–100 mm", "{shown}");
    assert_eq!(shown["red"], 0, "{shown}");
    // The ISO 3095 panel: every line and the energy average, every third
    // octave 5–250 mm with its verdict; the rail's 50 mm wave EXCEEDS on
    // each, with the rail's level and interval; within words the level and floor.
    assert_eq!(shown["isoHead"], serde_json::json!(["third octave", "limit", "L0", "L1", "L2", "energy average"]));
    let iso = shown["iso"].as_array().unwrap();
    let row =
        |w: &str| iso.iter().find(|r| r["cells"][0]["text"] == w).unwrap_or_else(|| panic!("no {w} row: {shown}"));
    for w in ["250 mm", "100 mm", "50 mm", "20 mm", "10 mm", "5 mm"] {
        let cells = row(w)["cells"].as_array().unwrap();
        assert_eq!(cells.len(), 6, "{w}: {cells:?}");
        for c in &cells[2..] {
            let (v, text) = (c["verdict"].as_str().unwrap(), c["text"].as_str().unwrap());
            assert!(["within", "EXCEEDS", "not judged"].contains(&v), "{w}: {c}");
            let figures = text.contains("(level ") && text.contains(", floor ") && text.ends_with(" dB)");
            assert!(
                text.starts_with(&format!("{v}{}", if v == "within" { " (" } else { ": rail " })) && figures,
                "{w}: {c}"
            );
            assert!(c["tip"].as_str().unwrap().starts_with(v), "{w}: {c}");
        }
    }
    for c in &row("50 mm")["cells"].as_array().unwrap()[2..] {
        assert_eq!(c["verdict"], "EXCEEDS", "{c}");
    }
    let verdicts = shown["isoVerdicts"].as_str().unwrap();
    assert!(verdicts.contains("energy average: EXCEEDS at ") && verdicts.contains("50"), "{verdicts}");
    assert!(shown["isoStretch"].as_str().unwrap().contains("without a gap; judged in "), "{shown}");
    // The run's own counts: no frame damaged, all shown up to then.
    let shown_frames: u64 = shown["frames"].as_str().unwrap().parse().unwrap();
    assert!(shown_frames as usize <= frames.len() && shown_frames > 30, "{shown}");
    assert_eq!(shown["damaged"], "0");
    assert!(stderr.contains("listen: link: 0 CRC errors, 0 resyncs"), "{stderr}");
    assert_eq!(shown["phase"], "streaming");
    assert!(shown["lasers"].as_str().unwrap().starts_with("ON 111"), "{shown}");
    // 1 m/s, under the limit of 66 mm of overlap-free stretch a frame.
    assert!((number(&shown["speed"]) - 1.0).abs() < 0.05, "{shown}");
    assert!(number(&shown["speedlimit"]) > 1.0, "{shown}");
    assert_eq!(shown["speedwarn"], "");
    assert!(view_figure(&stderr, "updates to 1 pages") >= 30, "{stderr}");
    // The marks the page made are the recording's.
    assert!(marked.as_str().unwrap().starts_with("defect “squat” marked at odometer "), "{marked}");
    let mut marks = Vec::new();
    cms_host::recording::scan_records(&rec_path, std::fs::File::open(&rec_path).unwrap(), |item| {
        if let cms_host::recording::Item::Host(cms_host::recording::HostRecord::Mark(m)) = item {
            marks.push((m.kind.name(), m.text.clone()));
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(marks, [("weld", String::new()), ("defect", "squat".to_string())]);
    assert!(stderr.contains("listen: marks: 2 recorded, 0 refused"), "{stderr}");
}

/// Updates a second of every page but the frozen one, and the run's
/// recording, over `CMS_BENCH_SECS` (60) seconds of `listen sim --serve
/// --record` with four live pages in one Chromium and a fifth in another
/// Chromium frozen whole (every process stopped: its socket open, never
/// read, as a tablet that hangs or sleeps). A benchmark, run by hand:
/// `cargo test --release -p cms-host --test it serve::browser::bench -- --ignored --nocapture`.
#[test]
#[ignore = "a benchmark: run by hand (docs/live-view.md)"]
fn bench_five_pages_one_frozen() {
    let secs: u64 = std::env::var("CMS_BENCH_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(60);
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start(dir.path(), &[]);
    let frozen = Browser::start();
    frozen.goto(&listen.url);
    frozen.wait_for("return window.cmsView().updates >= 5", Duration::from_secs(60), "updates");
    frozen.signal_all(nix::sys::signal::Signal::SIGSTOP);
    let live = Browser::start();
    let mut loads = Vec::new();
    for i in 0..4 {
        if i > 0 {
            live.new_window();
        }
        live.goto(&listen.url);
        loads.push(
            live.eval("const n = performance.getEntriesByType('navigation')[0]; return n.loadEventEnd - n.startTime;"),
        );
    }
    let windows = live.windows();
    let count = |b: &Browser| -> Vec<(f64, Instant)> {
        windows
            .iter()
            .map(|w| {
                b.switch(w);
                (b.eval("return window.cmsView().updates;").as_f64().unwrap(), Instant::now())
            })
            .collect()
    };
    let start = count(&live);
    let cpu0 = cpu_s(listen.child.id());
    thread::sleep(Duration::from_secs(secs));
    let cpu = format!("{:.1} % of a core", 100.0 * (cpu_s(listen.child.id()) - cpu0) / secs as f64);
    let end = count(&live);
    let rates: Vec<String> = start
        .iter()
        .zip(&end)
        .map(|(a, b)| format!("{:.1}", (b.0 - a.0) / b.1.duration_since(a.1).as_secs_f64()))
        .collect();
    drop(live);
    frozen.signal_all(nix::sys::signal::Signal::SIGCONT);
    drop(frozen);
    let rec_path = listen.rec.clone();
    let (status, stderr) = listen.interrupt();
    let (frames, order) = recorded(&rec_path);
    eprintln!(
        "{secs} s, 4 live pages + 1 frozen: page loads {loads:?} ms; updates/s per live page {rates:?}; recording: {} frames, {} missing (the head dropped {} on a full pty), first {:?} last {:?}; listener CPU {cpu}; load {}\n{stderr}",
        frames.len(),
        gaps(&order),
        sim_link_drops(&stderr),
        order.first(),
        order.last(),
        std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim()
    );
    assert!(status.success());
}
