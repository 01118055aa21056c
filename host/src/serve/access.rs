//! Who may use a view: on loopback, this machine (the `Host` check of
//! the HTTP side keeps other sites' pages out); anywhere else, only who
//! holds the run's secret token.
//!
//! Off loopback a view gets a token whatever the user asked: one given
//! with `--serve-token`, or [`TOKEN_BYTES`] random bytes from the
//! operating system, in hex. The address printed carries it
//! (`http://HOST:PORT/?token=…`); the first request with it gets a cookie
//! (`HttpOnly`, `SameSite=Strict`, named after the port so that two views
//! on one host keep theirs apart), which the page's own requests, its
//! socket and its marks then carry. A script may send
//! `Authorization: Bearer TOKEN` instead. A request with none of them is
//! answered 401, one with a wrong token 403, before anything else is
//! read: the page, the socket, `POST /marks` and the viewer's API alike.

use std::fmt;
use std::net::SocketAddr;
use std::sync::Arc;

use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};

/// Random bytes of a generated token (128 bits).
pub const TOKEN_BYTES: usize = 16;
/// Shortest token `--serve-token` takes, characters.
pub const MIN_TOKEN_CHARS: usize = 16;
/// Longest token `--serve-token` takes, characters.
pub const MAX_TOKEN_CHARS: usize = 128;
/// The query parameter that carries the token.
pub const TOKEN_PARAM: &str = "token";

/// Why a token cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TokenError {
    /// A given token of the wrong length.
    #[error("a --serve-token has {MIN_TOKEN_CHARS} to {MAX_TOKEN_CHARS} characters, not {0}")]
    Length(usize),
    /// A given token with a character an address cannot carry as is.
    #[error("a --serve-token is letters, digits, `-`, `_`, `.` and `~` only (it is part of the address)")]
    Character,
    /// The operating system gave no random bytes.
    #[error("cannot make the view's token: no random bytes from the system ({0})")]
    Random(#[source] getrandom::Error),
}

impl crate::error::Classify for TokenError {
    fn class(&self) -> crate::Class {
        match self {
            TokenError::Random(_) => crate::Class::Other,
            _ => crate::Class::Input,
        }
    }
}

/// A view's secret. Its `Debug` does not show it.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(Arc<str>);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(…)")
    }
}

impl Token {
    /// [`TOKEN_BYTES`] random bytes from the operating system, in hex.
    pub fn random() -> Result<Token, TokenError> {
        let mut b = [0u8; TOKEN_BYTES];
        getrandom::fill(&mut b).map_err(TokenError::Random)?;
        Ok(Token(b.iter().map(|x| format!("{x:02x}")).collect::<String>().into()))
    }

    /// A token the user chose (`--serve-token`): [`MIN_TOKEN_CHARS`] to
    /// [`MAX_TOKEN_CHARS`] characters an address carries unescaped.
    pub fn given(s: &str) -> Result<Token, TokenError> {
        let n = s.chars().count();
        if !(MIN_TOKEN_CHARS..=MAX_TOKEN_CHARS).contains(&n) {
            return Err(TokenError::Length(n));
        }
        if !s.bytes().all(|c| c.is_ascii_alphanumeric() || b"-_.~".contains(&c)) {
            return Err(TokenError::Character);
        }
        Ok(Token(s.into()))
    }

    /// The secret itself.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Whether `s` is this token, in a time that does not tell how much of
    /// it matched.
    fn is(&self, s: &str) -> bool {
        let (a, b) = (self.0.as_bytes(), s.as_bytes());
        a.len() == b.len() && a.iter().zip(b).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
    }
}

/// The token a view served on `addr` asks for: the one `given`, else a
/// random one off loopback, else none (loopback is this machine's own).
pub fn token_for(addr: SocketAddr, given: Option<Token>) -> Result<Option<Token>, TokenError> {
    match given {
        Some(t) => Ok(Some(t)),
        None if addr.ip().is_loopback() => Ok(None),
        None => Token::random().map(Some),
    }
}

/// The address of a view's page (`https://` where it is served over
/// TLS): with its token, where it has one.
pub fn page_url(addr: SocketAddr, token: Option<&Token>, https: bool) -> String {
    let scheme = if https { "https" } else { "http" };
    match token {
        Some(t) => format!("{scheme}://{addr}/?{TOKEN_PARAM}={}", t.as_str()),
        None => format!("{scheme}://{addr}/"),
    }
}

/// The cookie that carries the token of the view on `port`.
fn cookie_name(port: u16) -> String {
    format!("cms_view_{port}")
}

/// How a request stands with the view's token.
#[derive(Debug, PartialEq)]
pub(super) enum Admission {
    /// In, as it is (no token asked, or it carried the cookie or header).
    In,
    /// In by the token in its address: the cookie to set on the answer.
    InSetCookie(HeaderValue),
    /// Refused: 401 (no token) or 403 (a wrong one), and why.
    Out(StatusCode, &'static str),
}

/// Whether a request to the view on `port` with `uri` and `headers` may
/// in. Over HTTPS (`secure`) the cookie is one the browser sends over
/// HTTPS only.
pub(super) fn admit(token: Option<&Token>, port: u16, secure: bool, uri: &Uri, headers: &HeaderMap) -> Admission {
    let Some(token) = token else { return Admission::In };
    let wrong = Admission::Out(StatusCode::FORBIDDEN, "wrong token for this view\n");
    let in_query = uri
        .query()
        .into_iter()
        .flat_map(|q| q.split('&'))
        .find_map(|kv| kv.split_once('=').filter(|(k, _)| *k == TOKEN_PARAM).map(|(_, v)| v));
    if let Some(v) = in_query {
        if !token.is(v) {
            return wrong;
        }
        let secure = if secure { "; Secure" } else { "" };
        let cookie = format!("{}={}; Path=/; HttpOnly; SameSite=Strict{secure}", cookie_name(port), token.as_str());
        return match HeaderValue::from_str(&cookie) {
            Ok(c) => Admission::InSetCookie(c),
            Err(_) => wrong,
        };
    }
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|h| h.to_str().ok())
        .and_then(|h| h.strip_prefix("Bearer "))
        .map(str::trim);
    let name = cookie_name(port);
    let cookie = headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|h| h.to_str().ok())
        .flat_map(|h| h.split(';'))
        .find_map(|c| c.trim().split_once('=').filter(|(k, _)| *k == name).map(|(_, v)| v));
    match bearer.or(cookie) {
        Some(v) if token.is(v) => Admission::In,
        Some(_) => wrong,
        None => Admission::Out(
            StatusCode::UNAUTHORIZED,
            "this view asks for its token: open the address the command printed (…/?token=…)\n",
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(token: &Token, uri: &str, headers: &[(&'static str, &str)]) -> Admission {
        let mut h = HeaderMap::new();
        for (k, v) in headers {
            h.append(*k, HeaderValue::from_str(v).unwrap());
        }
        admit(Some(token), 8130, false, &uri.parse().unwrap(), &h)
    }

    #[test]
    fn random_tokens_differ_and_given_ones_are_checked() {
        let (a, b) = (Token::random().unwrap(), Token::random().unwrap());
        assert_ne!(a, b);
        assert_eq!(a.as_str().len(), 2 * TOKEN_BYTES);
        assert_eq!(format!("{a:?}"), "Token(…)");
        assert!(Token::given("abcdefgh-ijkl_mn.o~").is_ok());
        assert!(matches!(Token::given("short"), Err(TokenError::Length(5))));
        assert!(matches!(Token::given("abcdefgh ijklmnop"), Err(TokenError::Character)));
        assert!(matches!(Token::given("abcdefgh&ijklmnop"), Err(TokenError::Character)));
    }

    #[test]
    fn off_loopback_a_view_always_has_a_token() {
        let lo: SocketAddr = "127.0.0.1:8130".parse().unwrap();
        let any: SocketAddr = "0.0.0.0:8130".parse().unwrap();
        assert_eq!(token_for(lo, None).unwrap(), None);
        assert!(token_for(any, None).unwrap().is_some());
        let t = Token::given("0123456789abcdef").unwrap();
        assert_eq!(token_for(lo, Some(t.clone())).unwrap(), Some(t.clone()));
        assert_eq!(page_url(any, Some(&t), false), "http://0.0.0.0:8130/?token=0123456789abcdef");
        assert_eq!(page_url(any, Some(&t), true), "https://0.0.0.0:8130/?token=0123456789abcdef");
        assert_eq!(page_url(lo, None, false), "http://127.0.0.1:8130/");
    }

    #[test]
    fn only_the_token_lets_a_request_in() {
        let t = Token::given("0123456789abcdef").unwrap();
        assert_eq!(admit(None, 8130, false, &"/".parse().unwrap(), &HeaderMap::new()), Admission::In);
        let Admission::InSetCookie(c) = at(&t, "/?token=0123456789abcdef", &[]) else { panic!() };
        assert_eq!(c, "cms_view_8130=0123456789abcdef; Path=/; HttpOnly; SameSite=Strict");
        let secure = admit(Some(&t), 8130, true, &"/?token=0123456789abcdef".parse().unwrap(), &HeaderMap::new());
        let Admission::InSetCookie(c) = secure else { panic!() };
        assert_eq!(c, "cms_view_8130=0123456789abcdef; Path=/; HttpOnly; SameSite=Strict; Secure");
        assert_eq!(at(&t, "/ws", &[("cookie", "a=b; cms_view_8130=0123456789abcdef")]), Admission::In);
        assert_eq!(at(&t, "/marks", &[("authorization", "Bearer 0123456789abcdef")]), Admission::In);
        let code = |a: Admission| match a {
            Admission::Out(c, _) => c.as_u16(),
            other => panic!("{other:?}"),
        };
        assert_eq!(code(at(&t, "/", &[])), 401);
        assert_eq!(code(at(&t, "/", &[("cookie", "cms_view_8131=0123456789abcdef")])), 401);
        assert_eq!(code(at(&t, "/?token=0123456789abcdeX", &[])), 403);
        assert_eq!(code(at(&t, "/?token=", &[])), 403);
        assert_eq!(code(at(&t, "/", &[("cookie", "cms_view_8130=0123456789abcde")])), 403);
        assert_eq!(code(at(&t, "/", &[("authorization", "Bearer nope")])), 403);
    }
}
