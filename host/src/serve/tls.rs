//! HTTPS for the live view and the viewer (`--serve-tls CERT KEY`): the
//! page, its socket (`wss://`), `POST /marks` and the viewer's API over
//! TLS, so that the token and what the page shows cross a site's network
//! encrypted.
//!
//! rustls with the `ring` provider (no system library; classical key
//! exchange, X25519 first, no post-quantum hybrid), TLS 1.2 and 1.3,
//! HTTP/1.1 only (the socket's upgrade is HTTP/1.1's). The certificate
//! chain and its key are PEM files read once, when the view starts
//! ([`Tls::load`]): a file that cannot be read, holds no certificate or no
//! key, or a key that is not the certificate's is refused then, with one
//! line naming the file.
//!
//! Each connection is its own task on the view's runtime: the first byte
//! tells a TLS handshake (a handshake record, 0x16) from a plain HTTP
//! request (a method's capital letter), which is answered `400` in plain
//! text naming the `https://` address, and closed; nothing else is read
//! from it. A handshake not done within [`HANDSHAKE_TIMEOUT`] is dropped.
//! Through TLS the connection is served by hyper with the view's axum
//! router, as `axum::serve` serves a plain one.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use rustls::ServerConfig;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// How long a connection may take to send its first byte and finish its
/// handshake (or, in plain HTTP, its request's head).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// Most bytes of a plain HTTP request read to find its `Host` for the answer.
const PLAIN_HEAD_BYTES: usize = 8192;
/// The first byte of a TLS handshake record.
const TLS_HANDSHAKE: u8 = 0x16;

/// Why `--serve-tls CERT KEY` cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TlsError {
    /// A file that cannot be read.
    #[error("--serve-tls: cannot read {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A file that is not PEM, or holds none of what it should.
    #[error("--serve-tls: {} holds no PEM {what} ({why})", path.display())]
    Pem {
        /// The file.
        path: PathBuf,
        /// What it should hold: a certificate, a private key.
        what: &'static str,
        /// What the PEM reader found.
        why: String,
    },
    /// A key that is not the private key of the chain's first certificate.
    #[error("--serve-tls: {} is not the private key of the certificate in {}", key.display(), cert.display())]
    Mismatch {
        /// The certificate chain's file.
        cert: PathBuf,
        /// The key's file.
        key: PathBuf,
    },
    /// The certificate or the key refused by rustls (a malformed
    /// certificate, a key of a kind it does not sign with).
    #[error("--serve-tls {} {}: {source}", cert.display(), key.display())]
    Refused {
        /// The certificate chain's file.
        cert: PathBuf,
        /// The key's file.
        key: PathBuf,
        /// rustls's reason.
        #[source]
        source: rustls::Error,
    },
}

impl crate::error::Classify for TlsError {
    fn class(&self) -> crate::Class {
        // Each is a file the user gave: another file fixes it.
        crate::Class::Input
    }
}

/// A view's TLS: the certificate chain and key, checked, as rustls serves
/// them. Cheap to clone.
#[derive(Clone)]
pub struct Tls {
    config: Arc<ServerConfig>,
}

impl fmt::Debug for Tls {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Tls(…)")
    }
}

fn pem_error(path: &Path, what: &'static str, e: rustls::pki_types::pem::Error) -> TlsError {
    match e {
        rustls::pki_types::pem::Error::Io(source) => TlsError::Read { path: path.to_path_buf(), source },
        rustls::pki_types::pem::Error::NoItemsFound => {
            TlsError::Pem { path: path.to_path_buf(), what, why: "no such section".into() }
        }
        other => TlsError::Pem { path: path.to_path_buf(), what, why: other.to_string() },
    }
}

impl Tls {
    /// The PEM certificate chain in `cert` (the server's certificate
    /// first, then its intermediates) and its PEM private key in `key`
    /// (PKCS#8, PKCS#1 or SEC1), checked against each other.
    pub fn load(cert: &Path, key: &Path) -> Result<Tls, TlsError> {
        let chain = CertificateDer::pem_file_iter(cert)
            .map_err(|e| pem_error(cert, "certificate", e))?
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| pem_error(cert, "certificate", e))?;
        if chain.is_empty() {
            return Err(TlsError::Pem {
                path: cert.to_path_buf(),
                what: "certificate",
                why: "no CERTIFICATE section".into(),
            });
        }
        let private = PrivateKeyDer::from_pem_file(key).map_err(|e| pem_error(key, "private key", e))?;
        // ring: no system library and no cmake (aws-lc-rs needs both to
        // build). Its key exchanges are the classical ones (X25519, P-256,
        // P-384), no post-quantum hybrid, which rustls flags by deprecating it.
        #[allow(deprecated)]
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let refused = |source| match source {
            rustls::Error::InconsistentKeys(rustls::InconsistentKeys::KeyMismatch) => {
                TlsError::Mismatch { cert: cert.to_path_buf(), key: key.to_path_buf() }
            }
            source => TlsError::Refused { cert: cert.to_path_buf(), key: key.to_path_buf(), source },
        };
        let mut config = ServerConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .map_err(refused)?
            .with_no_client_auth()
            .with_single_cert(chain, private)
            .map_err(refused)?;
        config.alpn_protocols = vec![b"http/1.1".to_vec()];
        Ok(Tls { config: Arc::new(config) })
    }
}

/// Serves `app` on `listener` until the task is dropped: over TLS where
/// `tls` is given (a plain request answered 400 and `on_plain` called), as
/// `axum::serve` does otherwise.
pub(super) async fn serve(listener: TcpListener, app: Router, tls: Option<Tls>, on_plain: Arc<dyn Fn() + Send + Sync>) {
    let Some(tls) = tls else {
        let _ = axum::serve(listener, app).await;
        return;
    };
    let acceptor = tokio_rustls::TlsAcceptor::from(tls.config);
    loop {
        let tcp = match listener.accept().await {
            Ok((tcp, _)) => tcp,
            // Out of descriptors, or the like: wait as axum::serve does
            // rather than spin.
            Err(_) => {
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let (acceptor, app, on_plain) = (acceptor.clone(), app.clone(), on_plain.clone());
        tokio::spawn(async move { connection(tcp, acceptor, app, on_plain).await });
    }
}

/// One connection: the handshake, then HTTP/1.1 with upgrades (the
/// socket); or a plain request's refusal.
async fn connection(
    tcp: TcpStream,
    acceptor: tokio_rustls::TlsAcceptor,
    app: Router,
    on_plain: Arc<dyn Fn() + Send + Sync>,
) {
    let _ = tcp.set_nodelay(true);
    let mut first = [0u8; 1];
    match tokio::time::timeout(HANDSHAKE_TIMEOUT, tcp.peek(&mut first)).await {
        Ok(Ok(1)) => {}
        _ => return,
    }
    if first[0] != TLS_HANDSHAKE {
        if first[0].is_ascii_uppercase() {
            on_plain();
            refuse_plain(tcp).await;
        }
        return;
    }
    let Ok(Ok(stream)) = tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(tcp)).await else {
        return;
    };
    let service = hyper_util::service::TowerToHyperService::new(app);
    let _ = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        .serve_connection(hyper_util::rt::TokioIo::new(stream), service)
        .with_upgrades()
        .await;
}

/// A plain HTTP request on the TLS port: `400` naming the `https://`
/// address (the request's `Host`, else the port's own address), then
/// closed.
async fn refuse_plain(mut tcp: TcpStream) {
    let mut head = Vec::with_capacity(1024);
    let mut buf = [0u8; 1024];
    let read_head = async {
        while head.len() < PLAIN_HEAD_BYTES && !head.windows(4).any(|w| w == b"\r\n\r\n") {
            match tcp.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => head.extend_from_slice(&buf[..n]),
            }
        }
    };
    let _ = tokio::time::timeout(HANDSHAKE_TIMEOUT, read_head).await;
    let host = request_host(&head).or_else(|| tcp.local_addr().ok().map(|a| a.to_string())).unwrap_or_default();
    let body = format!("this port speaks HTTPS: https://{host}/\n");
    let answer = format!(
        "HTTP/1.1 400 Bad Request\r\ncontent-type: text/plain; charset=utf-8\r\nx-content-type-options: nosniff\r\ncache-control: no-store\r\nconnection: close\r\ncontent-length: {}\r\n\r\n{body}",
        body.len()
    );
    if tcp.write_all(answer.as_bytes()).await.is_err() {
        return;
    }
    let _ = tcp.shutdown().await;
    // What the client still sends is read and dropped until it closes, so
    // that closing with unread bytes does not reset the answer away.
    let drain = async { while matches!(tcp.read(&mut buf).await, Ok(n) if n > 0) {} };
    let _ = tokio::time::timeout(Duration::from_secs(1), drain).await;
}

/// The `Host` of a plain request's head, when it is a host name or
/// address with a port (nothing else is echoed back).
fn request_host(head: &[u8]) -> Option<String> {
    let text = std::str::from_utf8(head).ok()?;
    let value = text.split("\r\n").skip(1).take_while(|l| !l.is_empty()).find_map(|l| {
        l.split_once(':').filter(|(k, _)| k.trim().eq_ignore_ascii_case("host")).map(|(_, v)| v.trim())
    })?;
    let fine = !value.is_empty()
        && value.len() <= 255
        && value.bytes().all(|c| c.is_ascii_alphanumeric() || b".-:[]".contains(&c));
    fine.then(|| value.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plain_requests_host_is_echoed_only_when_it_is_a_host() {
        let head = b"GET / HTTP/1.1\r\nHost: 192.168.1.20:8130\r\nAccept: */*\r\n\r\n";
        assert_eq!(request_host(head).as_deref(), Some("192.168.1.20:8130"));
        assert_eq!(request_host(b"GET / HTTP/1.1\r\nhost: [::1]:8130\r\n\r\n").as_deref(), Some("[::1]:8130"));
        for bad in [&b"GET / HTTP/1.1\r\nHost: <script>\r\n\r\n"[..], b"GET / HTTP/1.1\r\n\r\nHost: a\r\n", b"GET /"] {
            assert_eq!(request_host(bad), None, "{}", String::from_utf8_lossy(bad));
        }
    }
}
