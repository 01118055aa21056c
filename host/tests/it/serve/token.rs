//! The view off loopback: only the run's token lets a request in.
//! `listen sim --serve 0.0.0.0:0` (every address: off loopback), reached
//! through 127.0.0.1 with another machine's `Host` and `Origin`, as a
//! tablet on the site's network would.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Instant;

use super::browser::Browser;
use super::*;

/// The answer to one raw HTTP/1.1 request: status code and head.
pub(super) fn exchange(host: &str, request: &str) -> (u16, String) {
    let mut s = TcpStream::connect(host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while !got.windows(4).any(|w| w == b"\r\n\r\n") {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
    let text = String::from_utf8_lossy(&got).to_string();
    let head = text.split("\r\n\r\n").next().unwrap_or("").to_string();
    let code = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (code, head)
}

/// The recording's marks: kind and text.
pub(super) fn marks_of(rec: &Path) -> Vec<(&'static str, String)> {
    let mut marks = Vec::new();
    cms_host::recording::scan_records(rec, std::fs::File::open(rec).unwrap(), |item| {
        if let cms_host::recording::Item::Host(cms_host::recording::HostRecord::Mark(m)) = item {
            marks.push((m.kind.name(), m.text.clone()));
        }
        Ok(())
    })
    .unwrap();
    marks
}

/// Off loopback without the token the page, its script, the socket and
/// `POST /marks` are 401 (403 with a wrong token) and no mark is
/// recorded; the address printed carries a random token, whose first use
/// sets an `HttpOnly`, `SameSite=Strict` cookie, and with that cookie (or
/// the token as a bearer) the page, the socket and a mark go through.
#[test]
fn off_loopback_only_the_token_lets_a_request_in() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start_on(dir.path(), "0.0.0.0:0", &["--frames", "150", "--sim-speed-mm-s", "1000"]);
    let h = listen.host.clone();
    let token = listen.token.clone().expect("the address printed carries a token");
    assert!(token.len() == 32 && token.bytes().all(|c| c.is_ascii_hexdigit()), "{token}");
    let port = h.rsplit(':').next().unwrap();
    let (tablet, origin) = (format!("tablet.example:{port}"), format!("http://tablet.example:{port}"));
    let ws = "Connection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n";
    let mark = |auth: &str, text: &str| {
        let body = format!(r#"{{"kind":"defect","text":"{text}"}}"#);
        format!(
            "POST /marks HTTP/1.1\r\nHost: {tablet}\r\nOrigin: {origin}\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        )
    };
    let get =
        |path: &str, extra: &str| format!("GET {path} HTTP/1.1\r\nHost: {tablet}\r\n{extra}Connection: close\r\n\r\n");
    let cookie = format!("Cookie: cms_view_{port}={token}\r\n");
    let refused = [
        (get("/", ""), 401),
        (get("/app.js", ""), 401),
        (get("/ws", &format!("Origin: {origin}\r\n{ws}")), 401),
        (mark("", "no token"), 401),
        (get("/?token=0123456789abcdef0123456789abcdef", ""), 403),
        (get("/", &format!("Cookie: cms_view_{port}=0123456789abcdef0123456789abcdef\r\n")), 403),
        (mark("Authorization: Bearer 0123456789abcdef0123456789abcdef\r\n", "wrong token"), 403),
    ];
    for (request, want) in &refused {
        let (code, head) = exchange(&h, request);
        assert_eq!(code, *want, "{request:?}: {head}");
    }

    // The address printed: in, and the cookie set.
    let (code, head) = exchange(&h, &get(&format!("/?token={token}"), ""));
    assert_eq!(code, 200, "{head}");
    let set =
        head.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).unwrap_or_else(|| panic!("{head}"));
    assert!(set.contains(&format!("cms_view_{port}={token}")), "{set}");
    assert!(set.contains("HttpOnly") && set.contains("SameSite=Strict"), "{set}");
    assert_eq!(exchange(&h, &get("/app.js", &cookie)).0, 200);
    let (code, head) = exchange(&h, &get("/ws", &format!("Origin: {origin}\r\n{cookie}{ws}")));
    assert_eq!(code, 101, "{head}");
    // With the token, the origin check still holds.
    let (code, _) = exchange(&h, &get("/ws", &format!("Origin: http://evil.example\r\n{cookie}{ws}")));
    assert_eq!(code, 403);
    // A mark with the token, once the head has sent a frame (409 before).
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (code, head) = exchange(&h, &mark(&cookie, "with token"));
        if code == 201 {
            break;
        }
        assert!(code == 409 && Instant::now() < deadline, "{head}");
        thread::sleep(Duration::from_millis(100));
    }
    let rec = listen.rec.clone();
    let (status, stderr) = listen.wait();
    assert!(status.success(), "{stderr}");
    assert_eq!(marks_of(&rec), [("defect", "with token".to_string())], "{stderr}");
    assert!(stderr.contains("listen: marks: 1 recorded"), "{stderr}");
    assert!(view_figure(&stderr, "requests refused") >= refused.len() as u64, "{stderr}");
}

/// In Chromium, off loopback: the page without the token is a 401 that
/// says what to open; the address printed shows the live view and marks
/// a weld; once the cookie is set, the bare address shows it too.
#[test]
fn a_real_browser_gets_in_with_the_token_only() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start_on(
        dir.path(),
        "0.0.0.0:0",
        &["--serve-token", "field-tablet-secret-42", "--sim-speed-mm-s", "1000"],
    );
    assert_eq!(listen.token.as_deref(), Some("field-tablet-secret-42"));
    let bare = format!("http://{}/", listen.host);
    let b = Browser::start();
    b.goto(&bare);
    let text = b.eval("return document.body.innerText;");
    assert!(text.as_str().unwrap().contains("asks for its token"), "{text}");
    b.goto(&format!("{bare}?token=field-tablet-secret-42"));
    b.wait_for("return window.cmsView && window.cmsView().updates >= 3", Duration::from_secs(60), "live updates");
    b.eval("document.querySelector('#marks button[data-kind=weld]').click(); return null;");
    b.wait_for("return window.cmsView().marks === 1", Duration::from_secs(30), "a weld marked");
    b.goto(&bare);
    b.wait_for(
        "return window.cmsView && window.cmsView().updates >= 3",
        Duration::from_secs(60),
        "live updates by the cookie",
    );
    drop(b);
    let rec = listen.rec.clone();
    let (status, stderr) = listen.interrupt();
    assert!(status.success(), "{stderr}");
    assert_eq!(marks_of(&rec), [("weld", String::new())], "{stderr}");
}
