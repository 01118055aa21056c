//! The view over HTTPS (`--serve-tls CERT KEY`): a certificate chain made
//! here (a CA of the test's own and a server certificate it signed, by
//! rcgen), a rustls client trusting that CA, and Chromium; off loopback,
//! so the token is asked for and now travels encrypted.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::time::Instant;

use rustls::pki_types::{CertificateDer, ServerName};
use tungstenite::Message;
use tungstenite::client::IntoClientRequest;

use super::browser::Browser;
use super::token::{exchange, marks_of};
use super::*;

/// A CA, and a server certificate for `localhost` and 127.0.0.1 it signed:
/// the CA's certificate (what a client trusts), and the server's chain
/// (server first) and key written as PEM files in `dir`.
fn certificates(dir: &Path) -> (CertificateDer<'static>, PathBuf, PathBuf) {
    use rcgen::{BasicConstraints, CertificateParams, DnType, IsCa, Issuer, KeyPair};
    let ca_key = KeyPair::generate().unwrap();
    let mut ca = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca.distinguished_name.push(DnType::CommonName, "cms-host test CA");
    let ca_cert = ca.self_signed(&ca_key).unwrap();
    let issuer = Issuer::new(ca, ca_key);
    let key = KeyPair::generate().unwrap();
    let server = CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()])
        .unwrap()
        .signed_by(&key, &issuer)
        .unwrap();
    let (cert_pem, key_pem) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&cert_pem, format!("{}{}", server.pem(), ca_cert.pem())).unwrap();
    std::fs::write(&key_pem, key.serialize_pem()).unwrap();
    (ca_cert.der().clone(), cert_pem, key_pem)
}

/// A TLS client that trusts `ca` only.
fn client(ca: CertificateDer<'static>) -> Arc<rustls::ClientConfig> {
    let mut roots = rustls::RootCertStore::empty();
    roots.add(ca).unwrap();
    #[allow(deprecated)] // ring, as the server (no post-quantum key exchange)
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    Arc::new(config)
}

type Tls = rustls::StreamOwned<rustls::ClientConnection, TcpStream>;

/// A TLS connection to `host` (127.0.0.1:PORT), the handshake done, the
/// server's certificate checked for 127.0.0.1 against the test's CA.
fn connect(config: &Arc<rustls::ClientConfig>, host: &str) -> Tls {
    let tcp = TcpStream::connect(host).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let name = ServerName::IpAddress(std::net::Ipv4Addr::LOCALHOST.into());
    let mut s = rustls::StreamOwned::new(rustls::ClientConnection::new(config.clone(), name).unwrap(), tcp);
    while s.conn.is_handshaking() {
        s.conn.complete_io(&mut s.sock).expect("the TLS handshake completes");
    }
    s
}

/// One request over its own TLS connection: status code, head and body.
fn exchange_tls(config: &Arc<rustls::ClientConfig>, host: &str, request: &str) -> (u16, String, String) {
    let mut s = connect(config, host);
    s.write_all(request.as_bytes()).unwrap();
    let mut got = Vec::new();
    // `Connection: close`: read until the server closes (a missing
    // close_notify is read as an end too).
    let _ = s.read_to_end(&mut got);
    let text = String::from_utf8_lossy(&got).to_string();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let code = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (code, head.to_string(), body.to_string())
}

/// `listen sim --serve 0.0.0.0:0 --serve-tls CERT KEY`: the address printed
/// is `https://…?token=…`; through TLS (a client trusting the test's CA)
/// the page with the token sets a `Secure` cookie, the script and the
/// socket (`wss`, an update read) go through with it and a mark is
/// recorded, while without the token it is 401 as over HTTP; plain HTTP
/// to the port is answered 400 naming the `https://` address.
#[test]
fn over_https_the_page_the_socket_and_a_mark_go_through_with_the_token() {
    let dir = tempfile::tempdir().unwrap();
    let (ca, cert, key) = certificates(dir.path());
    let (cert, key) = (cert.to_str().unwrap().to_string(), key.to_str().unwrap().to_string());
    let listen = Listen::start_on(
        dir.path(),
        "0.0.0.0:0",
        &["--serve-tls", &cert, &key, "--frames", "150", "--sim-speed-mm-s", "1000"],
    );
    assert!(listen.url.starts_with("https://0.0.0.0:"), "{}", listen.url);
    let (h, token) = (listen.host.clone(), listen.token.clone().expect("off loopback the address carries a token"));
    let port = h.rsplit(':').next().unwrap();
    let (tablet, origin) = (format!("tablet.example:{port}"), format!("https://tablet.example:{port}"));
    let config = client(ca);
    let get =
        |path: &str, extra: &str| format!("GET {path} HTTP/1.1\r\nHost: {tablet}\r\n{extra}Connection: close\r\n\r\n");

    let t0 = Instant::now();
    let (code, head, body) = exchange_tls(&config, &h, &get(&format!("/?token={token}"), ""));
    let page_ms = t0.elapsed().as_secs_f64() * 1e3;
    assert_eq!(code, 200, "{head}");
    assert!(body.contains("<html") || body.contains("<!doctype"), "{body}");
    let set =
        head.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).unwrap_or_else(|| panic!("{head}"));
    assert!(set.contains(&format!("cms_view_{port}={token}")) && set.contains("; Secure"), "{set}");
    let t0 = Instant::now();
    drop(connect(&config, &h));
    let handshake_ms = t0.elapsed().as_secs_f64() * 1e3;
    eprintln!("TLS handshake {handshake_ms:.1} ms; handshake and page {page_ms:.1} ms ({} bytes)", body.len());

    let cookie = format!("Cookie: cms_view_{port}={token}\r\n");
    assert_eq!(exchange_tls(&config, &h, &get("/", "")).0, 401, "without the token, as over HTTP");
    let (code, _, script) = exchange_tls(&config, &h, &get("/app.js", &cookie));
    assert!(code == 200 && script.contains("wss"), "{code}");

    // The socket: wss, with the cookie and the page's https origin; one update read.
    let mut req = format!("wss://{tablet}/ws").into_client_request().unwrap();
    req.headers_mut().insert("origin", origin.parse().unwrap());
    req.headers_mut().insert("cookie", format!("cms_view_{port}={token}").parse().unwrap());
    let (mut ws, resp) = tungstenite::client::client(req, connect(&config, &h)).expect("the socket opens over TLS");
    assert_eq!(resp.status(), 101);
    let update = loop {
        match ws.read().expect("updates come over wss") {
            Message::Text(t) => break t,
            _ => continue,
        }
    };
    let update: serde_json::Value = serde_json::from_str(update.as_str()).expect("an update is JSON");
    assert!(update.is_object(), "{update}");
    drop(ws);
    // A plain page of the same host is another origin.
    let mut req = format!("wss://{tablet}/ws").into_client_request().unwrap();
    req.headers_mut().insert("origin", format!("http://tablet.example:{port}").parse().unwrap());
    req.headers_mut().insert("cookie", format!("cms_view_{port}={token}").parse().unwrap());
    assert!(tungstenite::client::client(req, connect(&config, &h)).is_err(), "an http:// origin is refused");

    // A mark, once the head has sent a frame (409 before).
    let body = r#"{"kind":"defect","text":"over https"}"#;
    let mark = format!(
        "POST /marks HTTP/1.1\r\nHost: {tablet}\r\nOrigin: {origin}\r\n{cookie}Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (code, head, _) = exchange_tls(&config, &h, &mark);
        if code == 201 {
            break;
        }
        assert!(code == 409 && Instant::now() < deadline, "{head}");
        thread::sleep(Duration::from_millis(100));
    }

    // Plain HTTP to the port: a 400 naming the https:// address, no page.
    let mut s = TcpStream::connect(&h).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(get(&format!("/?token={token}"), "").as_bytes()).unwrap();
    let mut plain = String::new();
    let _ = s.read_to_string(&mut plain);
    assert!(plain.starts_with("HTTP/1.1 400 "), "{plain}");
    assert!(plain.ends_with(&format!("this port speaks HTTPS: https://{tablet}/\n")), "{plain}");
    assert_eq!(exchange(&h, &get("/app.js", &cookie)).0, 400);

    let rec = listen.rec.clone();
    let (status, stderr) = listen.wait();
    assert!(status.success(), "{stderr}");
    assert_eq!(marks_of(&rec), [("defect", "over https".to_string())], "{stderr}");
    assert!(view_figure(&stderr, "requests refused") >= 4, "{stderr}");
}

/// A certificate or key that cannot be used stops the run before it
/// starts: exit status 2 and one line naming the file.
#[test]
fn certificates_that_cannot_be_used_are_refused_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cert, key) = certificates(dir.path());
    let other = tempfile::tempdir().unwrap();
    let (_, _, other_key) = certificates(other.path());
    let junk = dir.path().join("junk.pem");
    std::fs::write(&junk, "not a certificate\n").unwrap();
    let missing = dir.path().join("missing.pem");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let cases = [
        (s(&missing), s(&key), format!("cannot read {}", s(&missing))),
        (s(&junk), s(&key), format!("{} holds no PEM certificate", s(&junk))),
        (s(&cert), s(&junk), format!("{} holds no PEM private key", s(&junk))),
        (
            s(&cert),
            s(&other_key),
            format!("{} is not the private key of the certificate in {}", s(&other_key), s(&cert)),
        ),
    ];
    for (c, k, why) in &cases {
        let out = Command::new(bin())
            .args(["listen", "sim", "--serve", "127.0.0.1:0", "--serve-tls", c, k, "--duration", "1"])
            .env("CMS_SIM_STATE", dir.path().join("sim-state"))
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{c} {k}: {err}");
        // Read before the simulated head starts: the error is all it says.
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.starts_with("error: --serve-tls: ") && err.contains(why.as_str()), "{err}");
    }
}

/// Chromium over HTTPS (the test's certificate taken with
/// `--ignore-certificate-errors`): the address printed shows live updates
/// over `wss` and marks a weld; every request the page made is to the
/// server's `https://` and `wss://` addresses.
#[test]
fn a_real_browser_shows_the_live_view_over_https() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cert, key) = certificates(dir.path());
    let (cert, key) = (cert.to_str().unwrap().to_string(), key.to_str().unwrap().to_string());
    let listen = Listen::start_on(
        dir.path(),
        "0.0.0.0:0",
        &["--serve-tls", &cert, &key, "--serve-token", "field-tablet-secret-42", "--sim-speed-mm-s", "1000"],
    );
    let page = format!("https://{}/", listen.host);
    let b = Browser::start_with(&["--ignore-certificate-errors"]);
    b.goto(&format!("{page}?token=field-tablet-secret-42"));
    b.wait_for("return window.cmsView && window.cmsView().updates >= 3", Duration::from_secs(60), "live updates");
    assert_eq!(b.eval("return location.protocol;"), "https:");
    b.eval("document.querySelector('#marks button[data-kind=weld]').click(); return null;");
    b.wait_for("return window.cmsView().marks === 1", Duration::from_secs(30), "a weld marked");
    let urls = b.requested();
    drop(b);
    let socket = format!("wss://{}/ws", listen.host);
    assert!(urls.contains(&socket), "no {socket} in {urls:?}");
    for u in &urls {
        let internal = ["chrome:", "chrome-untrusted:", "about:", "data:", "blob:"].iter().any(|s| u.starts_with(s));
        assert!(internal || u.starts_with(&page) || u == &socket, "the browser asked {u} (of {urls:?})");
    }
    let rec = listen.rec.clone();
    let (status, stderr) = listen.interrupt();
    assert!(status.success(), "{stderr}");
    assert_eq!(marks_of(&rec), [("weld", String::new())], "{stderr}");
}
