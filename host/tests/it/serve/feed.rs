//! The view against what a browser may do to it: a page that never reads,
//! hostile requests. Neither may cost the recording a frame.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::thread;
use std::time::Duration;

use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

use super::*;

fn ws(host: &str) -> WebSocket<TcpStream> {
    let stream = TcpStream::connect(host).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let req = format!("ws://{host}/ws").into_client_request().unwrap();
    tungstenite::client::client(req, stream).expect("the view accepts the socket").0
}

/// A page that reads every update until the view closes: how many it got,
/// and the last.
pub(super) fn reader(host: &str) -> JoinHandle<(u64, serde_json::Value)> {
    let mut s = ws(host);
    thread::spawn(move || {
        let (mut n, mut last) = (0, serde_json::Value::Null);
        while let Ok(m) = s.read() {
            if let Message::Text(t) = m {
                n += 1;
                last = serde_json::from_str(t.as_str()).expect("an update is JSON");
            }
        }
        (n, last)
    })
}

/// One page reads, one never does (its socket full, its task stuck in a
/// send): all 150 frames are recorded in sequence, the reading page gets
/// an update at least every third frame, and the frozen one costs nothing.
#[test]
fn a_frozen_page_costs_the_recording_no_frame() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start(dir.path(), &["--frames", "150", "--sim-speed-mm-s", "1000"]);
    let frozen = ws(&listen.host);
    let reading = reader(&listen.host);
    let (status, stderr) = listen.wait();
    assert!(status.success(), "{stderr}");
    let (updates, last) = reading.join().unwrap();
    drop(frozen);
    assert!(stderr.contains("listen: frames: 150 "), "{stderr}");
    // Every frame the head got onto the link is recorded: the only gaps
    // are frames it dropped itself when the pty was full (a loaded machine
    // that did not run the listener in time; none on an idle one).
    let (frames, order) = recorded(&dir.path().join("live.cmsrec"));
    assert_eq!(frames.len(), 150, "{stderr}");
    assert_eq!(gaps(&order), sim_link_drops(&stderr), "{order:?}");
    assert_eq!(view_figure(&stderr, "messages not shown"), 0, "{stderr}");
    assert!(stderr.contains(" to 2 pages;"), "{stderr}");
    eprintln!("reading page: {updates} updates over 150 frames, {} frames the head dropped; {stderr}", gaps(&order));
    assert!(updates >= 50, "{updates} updates for 150 frames");
    // The last update it got is of a recorded frame, with every figure.
    let seq = last["frame"]["seq"].as_u64().unwrap() as u32;
    assert!(frames.contains_key(&seq), "{last}");
    assert!(last["lost_frames"].as_u64().unwrap() <= gaps(&order), "{last}");
    assert_eq!(last["damaged_frames"], 0);
    assert_eq!(last["device"]["calibrated"], true);
    assert_eq!(last["recording"], true);
}

/// The status line of the answer to `request`.
fn answer(host: &str, request: &[u8]) -> String {
    let mut s = TcpStream::connect(host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    // A server that answers before the whole request is sent may close
    // while it is still written.
    let _ = s.write_all(request);
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while !got.windows(2).any(|w| w == b"\r\n") {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
    String::from_utf8_lossy(&got).lines().next().unwrap_or("").to_string()
}

/// Malformed and hostile requests get a 4xx, a half-sent request stays
/// open meanwhile, and the run records every frame it was asked for.
#[test]
fn hostile_requests_get_4xx_and_the_recording_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start(dir.path(), &["--frames", "120"]);
    let h = listen.host.clone();
    let mut slow = TcpStream::connect(&h).unwrap();
    slow.write_all(b"GET / HTTP/1.1\r\nHost: ").unwrap();
    let ws_headers = "Connection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n";
    let many: String = (0..300).map(|i| format!("X-{i}: v\r\n")).collect();
    let cases: Vec<(String, &str)> = vec![
        (format!("GET / HTTP/1.1\r\nHost: {h}\r\n\r\n"), "200"),
        (format!("GET /app.js HTTP/1.1\r\nHost: {h}\r\n\r\n"), "200"),
        (format!("POST / HTTP/1.1\r\nHost: {h}\r\nContent-Length: 3\r\n\r\nabc"), "405"),
        (format!("DELETE /ws HTTP/1.1\r\nHost: {h}\r\n\r\n"), "405"),
        (format!("GET /../../etc/passwd HTTP/1.1\r\nHost: {h}\r\n\r\n"), "404"),
        (format!("GET /index.html%00 HTTP/1.1\r\nHost: {h}\r\n\r\n"), "404"),
        ("GET / HTTP/1.1\r\nHost: evil.example\r\n\r\n".to_string(), "421"),
        ("GET / HTTP/1.1\r\n\r\n".to_string(), "421"),
        (format!("GET /ws HTTP/1.1\r\nHost: {h}\r\n\r\n"), "4"),
        (format!("GET /ws HTTP/1.1\r\nHost: {h}\r\nOrigin: http://evil.example\r\n{ws_headers}\r\n"), "403"),
        ("\u{0}\u{1}garbage\r\n\r\n".to_string(), "400"),
        (format!("GET / HTTP/1.1\r\nHost: {h}\r\nX-Big: {}\r\n\r\n", "a".repeat(600_000)), "431"),
        (format!("GET / HTTP/1.1\r\nHost: {h}\r\n{many}\r\n"), "431"),
    ];
    for (request, code) in &cases {
        let status = answer(&h, request.as_bytes());
        let shown: String = request.chars().take(60).collect();
        assert!(status.starts_with(&format!("HTTP/1.1 {code}")), "{shown:?}: {status:?}");
    }
    let (status, stderr) = listen.wait();
    drop(slow);
    assert!(status.success(), "{stderr}");
    assert!(stderr.contains("listen: frames: 120 "), "{stderr}");
    let (frames, order) = recorded(&dir.path().join("live.cmsrec"));
    assert_eq!(frames.len(), 120);
    assert_eq!(gaps(&order), sim_link_drops(&stderr), "{order:?}");
    // Those the router and the guard refused (hyper answers the malformed
    // and oversized ones before them).
    assert!(view_figure(&stderr, "requests refused") >= 7, "{stderr}");
}

/// A bad `--serve` address (clap's error and usage hint), and one in use
/// (one line): exit 2.
#[test]
fn serve_addresses_that_cannot_be_served_are_refused() {
    let out = crate::common::run(&["listen", "/dev/null", "--serve", "nowhere:80"]);
    assert_eq!(out.status.code(), Some(2));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.starts_with("error: ") && e.contains("`nowhere:80` is not an address to serve on"), "{e}");
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(bin())
        .args(["listen", "sim", "--frames", "2", "--serve", &addr])
        .env("CMS_SIM_STATE", dir.path().join("st"))
        .output()
        .unwrap();
    let e = crate::common::one_line_error(&out);
    assert!(e.contains(&format!("cannot serve the live view on {addr}")), "{e}");
}
