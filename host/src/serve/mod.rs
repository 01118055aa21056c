//! `cms-host listen PORT --serve [ADDR]`: the live view, one page in a
//! browser that shows what the head sends while it is recorded, and marks
//! events (a weld, a joint, a kilometre post, a defect, a note) into the
//! recording at the head's position.
//!
//! # The path of a frame
//!
//! ```text
//!  listen's loop ──(every kept message, try_send)──► bounded queue ──► hub thread
//!   (reads the port,        never waits: a full queue              assembles frames,
//!    records every frame)   drops the view's copy, counted         rates, the estimate
//!                                                                       │ at most DISPLAY_HZ
//!                                                                       ▼
//!                                               watch (the latest update only) ──► one task per page
//!                                                                                   (WebSocket)
//! ```
//!
//! The listener's loop hands every message it kept (recorded) to
//! [`Feed::message`] and its link's state to [`Feed::link`]: a copy into a
//! bounded queue of [`QUEUE_MESSAGES`] with `try_send`, which never
//! blocks; when the queue is full the view's copy is dropped and counted
//! (`view_dropped`), the recording is not touched. The hub (a thread of its
//! own) assembles frames, the frame rate, speed, lost and damaged frames,
//! the running corrugation estimate ([`crate::analyze::live`], twice a
//! second), the run's EN 13231-3 band figures
//! ([`crate::analyze::live::bands`]) and the latest stretch's ISO 3095
//! verdicts ([`crate::analyze::live::iso3095`]: `analyze` itself on the
//! stretch, on a worker thread of the hub's, taken when ready), and publishes an update — the newest frame's points and every
//! figure, as one JSON text — at most [`DISPLAY_HZ`] times a second into a
//! `watch` channel, which holds the newest update only. Each page's task
//! sends the newest when it can: a slow page skips updates (counted,
//! `page_skipped`), a frozen one holds only its own task (and is dropped
//! after [`SEND_TIMEOUT`] without progress), and nothing a page does
//! reaches the queue, the hub or the listener.
//!
//! # The server
//!
//! axum on a tokio runtime of one thread (its own, beside the listener's
//! loop). It serves `GET /` (the page), `/app.js`, `/app.css` (embedded in
//! the binary: no CDN, no font, nothing fetched from elsewhere; plots on
//! plain canvas), `GET /ws` (the updates) and `POST /marks` (an event
//! mark, below). Everything else is a 4xx:
//! another path 404, another method 405, a malformed request 400 (hyper),
//! a `Host` that is not the loopback address when bound to loopback 421 (a
//! DNS-rebinding page elsewhere cannot read the view), a WebSocket from
//! another `Origin` 403, more than [`MAX_PAGES`] pages 429. The socket's
//! incoming messages are read and ignored. Every
//! response forbids other origins (`Content-Security-Policy: default-src
//! 'none'`, scripts, styles and connections to the server itself only).
//!
//! With [`ServeOptions::tls`] (`--serve-tls CERT KEY`) it speaks HTTPS
//! only ([`tls`]): the page, `wss://` and the marks over TLS, a plain HTTP
//! request answered 400 naming the `https://` address.
//!
//! It binds to loopback ([`DEFAULT_ADDR`]) unless an address is given.
//! Off loopback every request must carry the run's secret token
//! ([`access`]): without it the page, the socket and `POST /marks` are
//! answered 401 (403 with a wrong one) before any of the above, and
//! nothing reaches the recording. The address printed carries the token.
//!
//! # Marks
//!
//! `POST /marks` with `Content-Type: application/json` and a body of at
//! most 2048 bytes, `{"kind": "weld", "text": "…"}` — kind one of `weld`,
//! `joint`, `kilometre_post`, `defect`, `note`; text optional (a post's
//! label and a note's words required), checked as the terminal's
//! ([`crate::recording::mark`]); no other field. The `Host` check above
//! applies, and an `Origin` other than this server's is refused (403), as
//! for the socket; a cross-site form cannot send JSON without a preflight
//! this server never answers. The mark goes through the listener's bounded
//! queue ([`crate::device::listen::mark_channel`]) and is answered once
//! recorded: 201 with the mark as recorded (`kind`, `text`,
//! `odometer_mm`, `seq`, `host_us`, `chainage` from `--survey`), or one
//! line of why not: 400 (not JSON of that shape), 413 (too long), 415 (not
//! JSON), 422 (a kind or text refused), 409 (not recording, a recording of
//! a format without marks, no frame yet), 503 (the listener's queue full
//! or no answer within 3 s). The page's buttons and keys (W, J, K, D, N)
//! send it.
//!
//! # Priority
//!
//! The hub's and the server's threads run at nice [`VIEW_NICE`] (Linux
//! sets it per thread): on a loaded machine the listener's loop, which
//! reads the port and records, is scheduled before the view's work.

pub mod access;
mod http;
mod hub;
pub mod tls;
pub mod viewer;

use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Duration;

use cms_core::protocol::DeviceMsg;

use crate::device::listen::LinkState;
use crate::recording::survey_info::Placement;

pub use hub::{MIN_OVERLAP_MM, speed_limit_mm_s};

/// The address served without one given: loopback, a fixed port.
pub const DEFAULT_ADDR: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 8130);
/// Most updates a page gets a second.
pub const DISPLAY_HZ: f64 = 24.0;
/// Messages the queue from the listener to the hub holds (8 s of 30
/// frames/s); the listener drops the view's copy beyond.
pub const QUEUE_MESSAGES: usize = 256;
/// Most pages open at once.
pub const MAX_PAGES: usize = 16;
/// How long a page may take to accept one update before it is dropped
/// (its page reconnects when it thaws).
pub const SEND_TIMEOUT: Duration = Duration::from_secs(10);

/// The nice value of the view's threads (the listener's stays where it
/// was started, 0 by default).
pub const VIEW_NICE: i32 = 10;

/// Lowers the calling thread's priority to [`VIEW_NICE`]; where it cannot
/// (another system, a limit), the view runs at the listener's.
fn lower_priority() {
    let tid = rustix::thread::gettid();
    let _ = rustix::process::setpriority_process(Some(tid), VIEW_NICE);
}

/// What to serve.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Where to listen.
    pub addr: SocketAddr,
    /// The port the head is on, as the page names it.
    pub port: String,
    /// Where the run lies on the line (from `--survey`): chainage from the
    /// odometer.
    pub placement: Option<Placement>,
    /// Whether the session records (the page says so).
    pub recording: bool,
    /// Where `POST /marks` sends event marks (`None`: refused).
    pub marks: Option<crate::device::listen::MarkSender>,
    /// The secret asked of every request (`--serve-token`); off loopback
    /// one is made when none is given ([`access`]).
    pub token: Option<access::Token>,
    /// What the live EN 13231-3 band figures evaluate.
    pub live_bands: crate::analyze::live::bands::LiveOptions,
    /// HTTPS (`--serve-tls`): the certificate and key, loaded; `None`: plain HTTP.
    pub tls: Option<tls::Tls>,
}

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServeError {
    /// The address cannot be listened on.
    #[error("cannot serve the live view on {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The server's or the hub's thread could not start.
    #[error("cannot start the live view: {0}")]
    Start(#[source] std::io::Error),
    /// The view's token: a given one refused, or none could be made.
    #[error(transparent)]
    Token(#[from] access::TokenError),
}

impl crate::error::Classify for ServeError {
    fn class(&self) -> crate::Class {
        match self {
            // An address in use, not this machine's, or a privileged port:
            // the user picks another.
            ServeError::Bind { .. } => crate::Class::Input,
            ServeError::Start(_) => crate::Class::Other,
            ServeError::Token(e) => crate::error::Classify::class(e),
        }
    }
}

/// What the hub receives.
enum Input {
    Message(Box<DeviceMsg>),
    Link(LinkState),
}

/// Counters shared by the feed, the hub and the pages' tasks.
#[derive(Debug, Default)]
struct Shared {
    /// Messages the listener offered the view.
    offered: AtomicU64,
    /// Messages dropped because the queue was full.
    view_dropped: AtomicU64,
    /// Updates published.
    updates: AtomicU64,
    /// Updates a page skipped because it had not taken the one before.
    page_skipped: AtomicU64,
    /// Pages open now.
    pages_open: AtomicU64,
    /// Pages ever connected.
    pages_served: AtomicU64,
    /// Requests refused with a 4xx.
    refused: AtomicU64,
    /// Frames missing from the sequence numbers the listener kept (counted
    /// before the queue, so the view's own drops are not among them).
    lost_frames: AtomicU64,
    /// The last frame's sequence number the listener kept, plus one (0: none yet).
    next_seq: AtomicU64,
    /// The view is stopping.
    stop: AtomicBool,
}

/// The listener's end of the view: cheap to clone, never blocks.
#[derive(Clone, Debug)]
pub struct Feed {
    tx: SyncSender<Input>,
    shared: Arc<Shared>,
}

impl Feed {
    fn offer(&self, input: Input) {
        self.shared.offered.fetch_add(1, Ordering::Relaxed);
        match self.tx.try_send(input) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.shared.view_dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// A message the listener kept (and recorded).
    pub fn message(&self, m: &DeviceMsg) {
        if let DeviceMsg::Profile(p) = m
            && p.part == 0
        {
            let seq = u64::from(p.seq);
            let next = self.shared.next_seq.swap(seq + 1, Ordering::Relaxed);
            // A head that restarts counts from 0 again: no gap there.
            if next > 0 && seq > next {
                self.shared.lost_frames.fetch_add(seq - next, Ordering::Relaxed);
            }
        }
        // Raw image rows are `capture`'s; the view has no use for them.
        if !matches!(m, DeviceMsg::RawRows(_) | DeviceMsg::Ack(_)) {
            self.offer(Input::Message(Box::new(m.clone())));
        }
    }

    /// The listener's link state.
    pub fn link(&self, s: &LinkState) {
        self.offer(Input::Link(*s));
    }
}

/// What the view did, for the listener's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ViewSummary {
    /// Updates published to the pages.
    pub updates: u64,
    /// Pages that connected.
    pub pages: u64,
    /// Messages the view did not get (its queue full); never recorded ones.
    pub view_dropped: u64,
    /// Updates pages skipped (slow or frozen pages).
    pub page_skipped: u64,
    /// Requests refused with a 4xx.
    pub refused: u64,
}

impl std::fmt::Display for ViewSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} updates to {} pages; {} messages not shown (view queue full), {} updates skipped by slow pages, {} requests refused; the recording is not affected",
            self.updates, self.pages, self.view_dropped, self.page_skipped, self.refused
        )
    }
}

/// A running live view: the server and the hub.
pub struct LiveView {
    addr: SocketAddr,
    token: Option<access::Token>,
    https: bool,
    feed: Feed,
    shared: Arc<Shared>,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    server: Option<JoinHandle<()>>,
    hub: Option<JoinHandle<()>>,
}

impl LiveView {
    /// Binds `opts.addr` and starts serving (the address is bound before
    /// this returns: a port in use fails here, before any listening).
    pub fn start(opts: &ServeOptions) -> Result<LiveView, ServeError> {
        let token = access::token_for(opts.addr, opts.token.clone())?;
        let listener = TcpListener::bind(opts.addr).map_err(|source| ServeError::Bind { addr: opts.addr, source })?;
        let addr = listener.local_addr().map_err(ServeError::Start)?;
        listener.set_nonblocking(true).map_err(ServeError::Start)?;
        let shared = Arc::new(Shared::default());
        let (tx, rx) = mpsc::sync_channel(QUEUE_MESSAGES);
        let (updates_tx, updates_rx) = tokio::sync::watch::channel(http::Update::default());
        let hub = {
            let (shared, opts) = (shared.clone(), opts.clone());
            std::thread::Builder::new()
                .name("cms-view-hub".into())
                .spawn(move || {
                    lower_priority();
                    hub::run(rx, updates_tx, &shared, &opts)
                })
                .map_err(ServeError::Start)?
        };
        let (shutdown, shutdown_rx) = tokio::sync::oneshot::channel();
        let server = {
            let ctx = http::Context {
                shared: shared.clone(),
                updates: updates_rx,
                local: addr,
                marks: opts.marks.clone(),
                placement: opts.placement,
                token: token.clone(),
                https: opts.tls.is_some(),
            };
            let tls = opts.tls.clone();
            std::thread::Builder::new()
                .name("cms-view-http".into())
                .spawn(move || {
                    lower_priority();
                    http::serve(listener, ctx, tls, shutdown_rx)
                })
                .map_err(ServeError::Start)?
        };
        Ok(LiveView {
            addr,
            token,
            https: opts.tls.is_some(),
            feed: Feed { tx, shared: shared.clone() },
            shared,
            shutdown: Some(shutdown),
            server: Some(server),
            hub: Some(hub),
        })
    }

    /// The address served (the port chosen, if 0 was asked for).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's address, with the token where the view asks for one.
    pub fn url(&self) -> String {
        access::page_url(self.addr, self.token.as_ref(), self.https)
    }

    /// The listener's end.
    pub fn feed(&self) -> Feed {
        self.feed.clone()
    }

    /// Stops the server (pages are disconnected) and the hub.
    pub fn stop(mut self) -> ViewSummary {
        self.halt();
        let s = &self.shared;
        ViewSummary {
            updates: s.updates.load(Ordering::Relaxed),
            pages: s.pages_served.load(Ordering::Relaxed),
            view_dropped: s.view_dropped.load(Ordering::Relaxed),
            page_skipped: s.page_skipped.load(Ordering::Relaxed),
            refused: s.refused.load(Ordering::Relaxed),
        }
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        for t in [self.server.take(), self.hub.take()].into_iter().flatten() {
            let _ = t.join();
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        self.halt();
    }
}
