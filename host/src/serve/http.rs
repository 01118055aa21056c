//! The HTTP side: the embedded page, the WebSocket of updates, and the
//! refusals (the module docs list them).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::Router;
use axum::extract::ws::{Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};

use super::access::{Admission, Token, admit};
use super::{MAX_PAGES, SEND_TIMEOUT, Shared};
use crate::device::listen::{MarkRefused, MarkSender};
use crate::recording::mark::{MarkEntry, MarkKind};
use crate::recording::survey_info::{Chainage, Heading, Placement};

/// Largest body of `POST /marks`, bytes (a kind and 200 characters of
/// text, escaped, fit).
pub(super) const MAX_MARK_BODY: usize = 2048;
/// How long `POST /marks` waits for the listener to record the mark.
const MARK_ANSWER: Duration = Duration::from_secs(3);

/// The page and its assets, embedded (served offline, nothing fetched
/// from elsewhere).
const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const APP_CSS: &str = include_str!("page/app.css");

/// Every response's policy: this server's own scripts, styles and socket
/// only; no frames, forms, plugins or other origins.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// One published update: its number and its JSON text.
#[derive(Clone, Debug, Default)]
pub(super) struct Update {
    pub seq: u64,
    pub json: Utf8Bytes,
}

/// What the handlers share.
#[derive(Clone)]
pub(super) struct Context {
    pub shared: Arc<Shared>,
    pub updates: tokio::sync::watch::Receiver<Update>,
    /// The address bound.
    pub local: SocketAddr,
    /// Where marks go (`None`: the listener takes none).
    pub marks: Option<MarkSender>,
    /// Where the run lies, to give a mark's chainage.
    pub placement: Option<Placement>,
    /// The secret every request carries (`None`: on loopback, none asked).
    pub token: Option<Token>,
    /// Served over TLS (`--serve-tls`): the page's origin is `https://`.
    pub https: bool,
}

/// Serves on `listener` until `shutdown`; the runtime (and with it every
/// page's task) is dropped then.
pub(super) fn serve(
    listener: std::net::TcpListener,
    ctx: Context,
    tls: Option<super::tls::Tls>,
    shutdown: tokio::sync::oneshot::Receiver<()>,
) {
    let rt = match tokio::runtime::Builder::new_current_thread().enable_io().enable_time().build() {
        Ok(rt) => rt,
        Err(_) => return,
    };
    rt.block_on(async move {
        let Ok(listener) = tokio::net::TcpListener::from_std(listener) else { return };
        let shared = ctx.shared.clone();
        let on_plain = Arc::new(move || {
            shared.refused.fetch_add(1, Ordering::Relaxed);
        });
        let app = router(ctx);
        tokio::select! {
            _ = super::tls::serve(listener, app, tls, on_plain) => {}
            _ = shutdown => {}
        }
    });
    // Pages still connected (a frozen one mid-send) are cut off here.
    rt.shutdown_timeout(Duration::from_millis(100));
}

fn router(ctx: Context) -> Router {
    Router::new()
        .route("/", get(|| async { asset(INDEX_HTML, "text/html; charset=utf-8") }))
        .route("/app.js", get(|| async { asset(APP_JS, "text/javascript; charset=utf-8") }))
        .route("/app.css", get(|| async { asset(APP_CSS, "text/css; charset=utf-8") }))
        .route("/ws", get(socket))
        .route("/marks", post(mark))
        .fallback(|| async { (StatusCode::NOT_FOUND, "not found\n") })
        .layer(middleware::from_fn_with_state(ctx.clone(), guard))
        .with_state(ctx)
}

fn asset(body: &'static str, mime: &'static str) -> Response {
    ([(header::CONTENT_TYPE, mime)], body).into_response()
}

/// Whether `host` (a `Host` header) names the loopback server on `port`.
pub(super) fn loopback_host(host: &str, port: u16) -> bool {
    let name = match host.rsplit_once(':') {
        Some((name, p)) if p == port.to_string() => name,
        _ => return false,
    };
    matches!(name, "127.0.0.1" | "localhost" | "[::1]")
}

/// The refusals every request passes, and the headers every response gets.
async fn guard(State(ctx): State<Context>, req: Request, next: Next) -> Response {
    let refuse = |r: Response| {
        ctx.shared.refused.fetch_add(1, Ordering::Relaxed);
        r
    };
    let mut resp = match checked(&ctx.local, ctx.token.as_ref(), ctx.https, &req) {
        Err(r) => refuse(*r),
        Ok(_)
            if req.method() != axum::http::Method::GET
                && req.method() != axum::http::Method::HEAD
                && !(req.method() == axum::http::Method::POST && req.uri().path() == "/marks") =>
        {
            refuse((StatusCode::METHOD_NOT_ALLOWED, "the live view is read-only but for POST /marks\n").into_response())
        }
        Ok(cookie) => {
            let mut r = next.run(req).await;
            if r.status().is_client_error() {
                ctx.shared.refused.fetch_add(1, Ordering::Relaxed);
            }
            if let Some(c) = cookie {
                r.headers_mut().insert(header::SET_COOKIE, c);
            }
            r
        }
    };
    harden(resp.headers_mut());
    resp
}

/// The checks of who asks, before what is asked: on loopback the `Host`,
/// then the token where the view has one ([`super::access`]). The cookie
/// to set where the request came in by the token in its address, or the
/// refusal.
pub(super) fn checked(
    local: &SocketAddr,
    token: Option<&Token>,
    https: bool,
    req: &Request,
) -> Result<Option<HeaderValue>, Box<Response>> {
    let host = req.headers().get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("");
    if local.ip().is_loopback() && !loopback_host(host, local.port()) {
        // A page of another site whose name was made to resolve here
        // (DNS rebinding) sends its own name.
        return Err(Box::new(
            (StatusCode::MISDIRECTED_REQUEST, "this server answers to its loopback address only\n").into_response(),
        ));
    }
    match admit(token, local.port(), https, req.uri(), req.headers()) {
        Admission::In => Ok(None),
        Admission::InSetCookie(c) => Ok(Some(c)),
        Admission::Out(code, why) => {
            let mut r = (code, why).into_response();
            if code == StatusCode::UNAUTHORIZED {
                r.headers_mut()
                    .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer realm=\"cms-host view\""));
            }
            Err(Box::new(r))
        }
    }
}

/// The headers every response of the live view and the viewer gets.
pub(super) fn harden(h: &mut HeaderMap) {
    h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CSP));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
}

/// `GET /ws`: the page's updates, from another origin refused.
async fn socket(State(ctx): State<Context>, headers: HeaderMap, ws: WebSocketUpgrade) -> Response {
    if !same_origin(&headers, ctx.https) {
        return (StatusCode::FORBIDDEN, "updates go to this server's own page only\n").into_response();
    }
    if ctx.shared.pages_open.load(Ordering::SeqCst) >= MAX_PAGES as u64 {
        return (StatusCode::TOO_MANY_REQUESTS, "too many pages open\n").into_response();
    }
    ws.on_upgrade(move |s| page(s, ctx))
}

/// Whether a request's `Origin`, if it has one, is this server's own page
/// (`https://` when served over TLS, `http://` otherwise).
fn same_origin(headers: &HeaderMap, https: bool) -> bool {
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("");
    let scheme = if https { "https://" } else { "http://" };
    match headers.get(header::ORIGIN) {
        Some(origin) => origin.to_str().ok().and_then(|o| o.strip_prefix(scheme)).is_some_and(|o| o == host),
        None => true,
    }
}

/// The body of `POST /marks`: `{"kind": "weld", "text": "…"}`, nothing else.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct MarkBody {
    kind: String,
    #[serde(default)]
    text: String,
}

/// A refusal of `POST /marks`: its status and one line of why.
fn mark_refusal(code: StatusCode, why: impl std::fmt::Display) -> Response {
    (code, format!("{why}\n")).into_response()
}

/// A refusal before the mark is sent on: its status and why.
type Refusal = (StatusCode, String);

/// What a request asks to mark, or why it is refused.
fn mark_entry(headers: &HeaderMap, body: &[u8]) -> Result<MarkEntry, Refusal> {
    let json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|c| c.to_str().ok())
        .is_some_and(|c| c.split(';').next().is_some_and(|t| t.trim().eq_ignore_ascii_case("application/json")));
    if !json {
        return Err((StatusCode::UNSUPPORTED_MEDIA_TYPE, "a mark is sent as application/json".to_string()));
    }
    let b: MarkBody = serde_json::from_slice(body).map_err(|e| {
        let why: String = e.to_string().chars().take(160).collect();
        (StatusCode::BAD_REQUEST, format!("not a mark ({{\"kind\": \"weld\", \"text\": \"…\"}}): {why}"))
    })?;
    let kind = MarkKind::ALL.into_iter().find(|k| k.name() == b.kind).ok_or_else(|| {
        let names: Vec<&str> = MarkKind::ALL.iter().map(|k| k.name()).collect();
        (
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "no mark kind `{}`: one of {}",
                crate::output::printable(&b.kind.chars().take(24).collect::<String>()),
                names.join(", ")
            ),
        )
    })?;
    MarkEntry::new(kind, &b.text).map_err(|e| (StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))
}

/// `POST /marks`: an event mark at the head's position, recorded; answered
/// with the mark as recorded (201) or why not (4xx, 503).
async fn mark(State(ctx): State<Context>, headers: HeaderMap, body: axum::body::Body) -> Response {
    if !same_origin(&headers, ctx.https) {
        return mark_refusal(StatusCode::FORBIDDEN, "marks come from this server's own page only");
    }
    let Ok(bytes) = axum::body::to_bytes(body, MAX_MARK_BODY).await else {
        return mark_refusal(StatusCode::PAYLOAD_TOO_LARGE, format!("a mark's body is at most {MAX_MARK_BODY} bytes"));
    };
    let entry = match mark_entry(&headers, &bytes) {
        Ok(e) => e,
        Err((code, why)) => return mark_refusal(code, why),
    };
    let Some(marks) = &ctx.marks else {
        return mark_refusal(StatusCode::CONFLICT, MarkRefused::NotRecording);
    };
    let (tx, rx) = tokio::sync::oneshot::channel();
    marks.send(
        entry,
        Box::new(move |r| {
            let _ = tx.send(r);
        }),
    );
    match tokio::time::timeout(MARK_ANSWER, rx).await {
        Ok(Ok(Ok(m))) => {
            let chainage = ctx.placement.and_then(|p| {
                let o = m.odometer_mm() / 1000.0;
                p.start_m.map(|s| Chainage(if p.heading == Some(Heading::Down) { s - o } else { s + o }).to_string())
            });
            let body = serde_json::json!({
                "kind": m.kind.name(),
                "text": m.text,
                "odometer_mm": m.odometer_mm(),
                "seq": m.seq,
                "host_us": m.host_us,
                "chainage": chainage,
            });
            (StatusCode::CREATED, [(header::CONTENT_TYPE, "application/json")], body.to_string()).into_response()
        }
        Ok(Ok(Err(why))) => {
            let code = match why {
                MarkRefused::Busy => StatusCode::SERVICE_UNAVAILABLE,
                MarkRefused::Write(_) => StatusCode::INTERNAL_SERVER_ERROR,
                _ => StatusCode::CONFLICT,
            };
            mark_refusal(code, why)
        }
        _ => mark_refusal(StatusCode::SERVICE_UNAVAILABLE, "the listener did not take the mark in time"),
    }
}

/// One page: the newest update whenever there is a new one, never a queue.
async fn page(mut ws: WebSocket, mut ctx: Context) {
    let shared = ctx.shared.clone();
    shared.pages_open.fetch_add(1, Ordering::SeqCst);
    shared.pages_served.fetch_add(1, Ordering::Relaxed);
    let mut sent: Option<u64> = None;
    loop {
        tokio::select! {
            changed = ctx.updates.changed() => {
                if changed.is_err() {
                    break;
                }
                let u = ctx.updates.borrow_and_update().clone();
                if let Some(s) = sent {
                    shared.page_skipped.fetch_add(u.seq.saturating_sub(s + 1), Ordering::Relaxed);
                }
                sent = Some(u.seq);
                match tokio::time::timeout(SEND_TIMEOUT, ws.send(Message::Text(u.json))).await {
                    Ok(Ok(())) => {}
                    _ => break,
                }
            }
            incoming = ws.recv() => match incoming {
                // Read-only: whatever the page sends is read and ignored.
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
        }
    }
    shared.pages_open.fetch_sub(1, Ordering::SeqCst);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.insert(*k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    fn status(r: Result<MarkEntry, Refusal>) -> Result<MarkEntry, u16> {
        r.map_err(|r| r.0.as_u16())
    }

    #[test]
    fn mark_bodies_are_checked_strictly() {
        let json = headers(&[("content-type", "application/json; charset=utf-8")]);
        let ok = status(mark_entry(&json, br#"{"kind":"kilometre_post","text":" 12.300 "}"#)).unwrap();
        assert_eq!((ok.kind, ok.text.as_str()), (MarkKind::KilometrePost, "12.300"));
        assert_eq!(status(mark_entry(&json, br#"{"kind":"weld"}"#)).unwrap().kind, MarkKind::Weld);
        let cases: [(&[u8], u16); 9] = [
            (br#"{"kind":"weld","text":"x","extra":1}"#, 400),
            (br#"{"text":"x"}"#, 400),
            (br#"{"kind":7}"#, 400),
            (b"weld", 400),
            (br#"{"kind":"w"}"#, 422),
            (br#"{"kind":"Weld"}"#, 422),
            (br#"{"kind":"note"}"#, 422),
            (br#"{"kind":"defect","text":"a\u001bb"}"#, 422),
            (br#"{"kind":"note","text":"\u202eevil"}"#, 422),
        ];
        for (body, code) in cases {
            assert_eq!(status(mark_entry(&json, body)).map(|_| ()), Err(code), "{}", String::from_utf8_lossy(body));
        }
        let long = format!(r#"{{"kind":"note","text":"{}"}}"#, "x".repeat(crate::recording::mark::MAX_TEXT_CHARS + 1));
        assert_eq!(status(mark_entry(&json, long.as_bytes())).map(|_| ()), Err(422));
        for ct in [&[][..], &[("content-type", "text/plain")][..], &[("content-type", "application/jsonx")][..]] {
            assert_eq!(status(mark_entry(&headers(ct), br#"{"kind":"weld"}"#)).map(|_| ()), Err(415));
        }
    }

    #[test]
    fn marks_come_from_the_page_of_this_server() {
        assert!(same_origin(&headers(&[("host", "127.0.0.1:8130")]), false));
        assert!(same_origin(&headers(&[("host", "127.0.0.1:8130"), ("origin", "http://127.0.0.1:8130")]), false));
        assert!(!same_origin(&headers(&[("host", "127.0.0.1:8130"), ("origin", "http://evil.example")]), false));
        assert!(!same_origin(&headers(&[("host", "127.0.0.1:8130"), ("origin", "null")]), false));
        // Over TLS the page's origin is https://, and a plain page of the same host is another origin.
        assert!(same_origin(&headers(&[("host", "10.0.0.2:8130"), ("origin", "https://10.0.0.2:8130")]), true));
        assert!(!same_origin(&headers(&[("host", "10.0.0.2:8130"), ("origin", "http://10.0.0.2:8130")]), true));
    }

    #[test]
    fn only_loopback_names_with_the_port_are_this_server() {
        assert!(loopback_host("127.0.0.1:8130", 8130));
        assert!(loopback_host("localhost:8130", 8130));
        assert!(loopback_host("[::1]:8130", 8130));
        for bad in ["127.0.0.1:8131", "evil.example:8130", "127.0.0.1", "", "localhost.evil.example:8130"] {
            assert!(!loopback_host(bad, 8130), "{bad}");
        }
    }
}
