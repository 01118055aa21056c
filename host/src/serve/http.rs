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
use axum::routing::get;

use super::{MAX_PAGES, SEND_TIMEOUT, Shared};

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
}

/// Serves on `listener` until `shutdown`; the runtime (and with it every
/// page's task) is dropped then.
pub(super) fn serve(listener: std::net::TcpListener, ctx: Context, shutdown: tokio::sync::oneshot::Receiver<()>) {
    let rt = match tokio::runtime::Builder::new_current_thread().enable_io().enable_time().build() {
        Ok(rt) => rt,
        Err(_) => return,
    };
    rt.block_on(async move {
        let Ok(listener) = tokio::net::TcpListener::from_std(listener) else { return };
        let app = router(ctx);
        tokio::select! {
            _ = axum::serve(listener, app) => {}
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
    let refuse = |code: StatusCode, why: &'static str| {
        ctx.shared.refused.fetch_add(1, Ordering::Relaxed);
        (code, why).into_response()
    };
    let host = req.headers().get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("");
    let mut resp = if ctx.local.ip().is_loopback() && !loopback_host(host, ctx.local.port()) {
        // A page of another site whose name was made to resolve here
        // (DNS rebinding) sends its own name.
        refuse(StatusCode::MISDIRECTED_REQUEST, "this server answers to its loopback address only\n")
    } else if req.method() != axum::http::Method::GET && req.method() != axum::http::Method::HEAD {
        refuse(StatusCode::METHOD_NOT_ALLOWED, "the live view is read-only\n")
    } else {
        let r = next.run(req).await;
        if r.status().is_client_error() {
            ctx.shared.refused.fetch_add(1, Ordering::Relaxed);
        }
        r
    };
    harden(resp.headers_mut());
    resp
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
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok()).unwrap_or("");
    if let Some(origin) = headers.get(header::ORIGIN) {
        let same = origin.to_str().ok().and_then(|o| o.strip_prefix("http://")).is_some_and(|o| o == host);
        if !same {
            return (StatusCode::FORBIDDEN, "updates go to this server's own page only\n").into_response();
        }
    }
    if ctx.shared.pages_open.load(Ordering::SeqCst) >= MAX_PAGES as u64 {
        return (StatusCode::TOO_MANY_REQUESTS, "too many pages open\n").into_response();
    }
    ws.on_upgrade(move |s| page(s, ctx))
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
