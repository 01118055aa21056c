//! [`Client`]: the one conversation with a sensor head, shared by `listen`,
//! `capture` and `calibrate upload`.
//!
//! A client owns the port ([`Link`]), the [`Deframer`] behind it and the
//! commands waiting to go out ([`Outbox`]), and gives every command its
//! sequence number. On top of that it has:
//!
//! * **the handshake**: `GetInfo` until a `Hello`, a number of tries apart
//!   ([`Handshake`]), and the version check of the `Hello`;
//! * **heartbeats**, if asked for ([`Client::with_heartbeat`]): sent from
//!   [`Client::transmit`] whenever one is due (the head turns its lasers off
//!   1 s after the last one);
//! * **request/response**: a command and the wait for its `Ack` or `Error`,
//!   or for any message a closure picks, with a timeout ([`Wait`]).
//!
//! # Two ways to drive it
//! `capture` and `calibrate upload` talk in turns and use the blocking calls
//! ([`Client::handshake`], [`Client::request`], [`Client::until`]). `listen`
//! runs its own loop — it records every frame, reconnects, shows a status
//! line and must see Ctrl-C within a read — so it calls
//! [`Client::receive`] and [`Client::transmit`] itself and keeps its
//! handshake as a [`Greeting`], the same state machine the blocking
//! handshake runs. The frames reach the caller through a closure that also
//! gets the [`Outbox`]: a command decided on a frame (`Start` after a
//! `Hello`) gets its sequence number at once and goes out on the next
//! [`Client::transmit`], which is what lets the frames stay borrowed from
//! the deframer (no copy of a 40 kB profile per frame).
//!
//! # Failures
//! A port that fails ([`LinkError::Gone`]) is closed by the client itself
//! (the unfinished frame and the queued commands dropped, the counters
//! kept); [`Client::reopen`] opens the same path again, as after a USB
//! replug. A command the head does not take within
//! [`WRITE_TIMEOUT`](super::WRITE_TIMEOUT) is lost: the listener's
//! heartbeats and retries cover that and ignore it, a blocking call reports
//! [`ClientError::NotTaken`].
//!
//! Cost: one read of at most [`READ_TIMEOUT`](super::READ_TIMEOUT) per
//! [`Client::receive`], a 64 kB read buffer, and the outbox (a few commands).

use std::time::{Duration, Instant};

use cms_core::protocol::{DeviceInfo, DeviceMsg, ErrorCode, HostMsg, PROTOCOL_VERSION, WireError};

use super::{Counters, Deframer, Link, LinkError};

/// Bytes asked for per read: more than a frame's worth at USB speed in one
/// [`READ_TIMEOUT`](super::READ_TIMEOUT).
const READ_BUFFER: usize = 64 << 10;

/// Why a conversation with the head failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The port could not be opened, or failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// A command was not taken by the head within the write timeout.
    #[error("{port}: the head does not read its commands")]
    NotTaken {
        /// The port.
        port: String,
    },
    /// No answer to a request in time.
    #[error("{port}: no answer to {what} within {} s", after.as_secs())]
    NoAnswer {
        /// The port.
        port: String,
        /// What was asked.
        what: String,
        /// How long the client waited (see [`Wait`]).
        after: Duration,
    },
    /// No `Hello` after every try of a handshake of more than one try (a
    /// handshake of one try is one request: [`ClientError::NoAnswer`]).
    #[error(
        "no answer from {port}: no Hello after {tries} GetInfo requests {} s apart (is it a CMS sensor head, and is the baud rate right?)",
        apart.as_secs()
    )]
    NoHello {
        /// The port.
        port: String,
        /// `GetInfo` requests sent.
        tries: u32,
        /// Time between them.
        apart: Duration,
    },
    /// The head speaks another protocol version (its `Hello` said so, or
    /// its frames carried another version byte).
    #[error("the head on {port} speaks protocol version {theirs}; this cms-host speaks {PROTOCOL_VERSION}")]
    Version {
        /// The port.
        port: String,
        /// The head's version.
        theirs: u8,
    },
    /// The head answered a request with an `Error`.
    #[error("{port}: the head refused {what}: {code}")]
    Refused {
        /// The port.
        port: String,
        /// What was asked.
        what: String,
        /// The head's reason.
        code: ErrorCode,
    },
}

impl crate::error::Classify for ClientError {
    /// Every failure of a conversation with a head is the device's or the
    /// link's (exit status 3).
    fn class(&self) -> crate::Class {
        crate::Class::Device
    }
}

/// How long a blocking call waits for its answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wait {
    /// At most this long from the request on.
    Within(Duration),
    /// Until the head has been silent this long: for answers that come in
    /// many frames (a captured image over a slow UART) and may take longer
    /// in all than any fixed limit.
    Silence(Duration),
}

impl Wait {
    fn duration(self) -> Duration {
        match self {
            Wait::Within(d) | Wait::Silence(d) => d,
        }
    }

    /// Whether the wait that began at `since`, with bytes last heard at
    /// `heard`, is over at `now`.
    fn expired(self, since: Instant, heard: Instant, now: Instant) -> bool {
        match self {
            Wait::Within(d) => now.duration_since(since) >= d,
            Wait::Silence(d) => now.duration_since(since.max(heard)) > d,
        }
    }
}

/// How a conversation opens: `GetInfo`, and a `Hello` within `wait`, up to
/// `tries` times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Handshake {
    /// `GetInfo` requests before giving up (at least 1).
    pub tries: u32,
    /// How long each one waits.
    pub wait: Wait,
}

/// Commands waiting to go out, each with its sequence number.
#[derive(Debug, Default)]
pub struct Outbox {
    last_seq: u16,
    queue: Vec<(u16, HostMsg)>,
}

impl Outbox {
    /// The next sequence number. They start at 1 and skip 0 when they wrap,
    /// so that 0 never names a command.
    pub fn next_seq(&mut self) -> u16 {
        self.last_seq = self.last_seq.wrapping_add(1).max(1);
        self.last_seq
    }

    /// Queues `msg` for the next [`Client::transmit`]; returns its sequence
    /// number (what the head's `Ack` or `Error` will name).
    pub fn push(&mut self, msg: HostMsg) -> u16 {
        let seq = self.next_seq();
        self.queue.push((seq, msg));
        seq
    }

    /// Drops what is queued.
    pub fn clear(&mut self) {
        self.queue.clear();
    }

    /// Commands queued.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}

/// The version check every `Hello` passes.
pub fn check_version(port: &str, info: &DeviceInfo) -> Result<(), ClientError> {
    if info.protocol == PROTOCOL_VERSION {
        Ok(())
    } else {
        Err(ClientError::Version { port: port.to_string(), theirs: info.protocol })
    }
}

/// A handshake in progress, for a caller that runs its own loop (the
/// listener); [`Client::handshake`] runs the same one to the end.
#[derive(Clone, Debug)]
pub struct Greeting {
    policy: Handshake,
    /// `GetInfo` requests sent so far.
    tries: u32,
    /// When the last one was queued.
    sent: Instant,
    /// The version byte of frames that failed the version check: a head of
    /// another version cannot be decoded, so its `Hello` shows only so.
    foreign: Option<u8>,
}

impl Greeting {
    /// Queues the first `GetInfo` of `policy`.
    pub fn begin(policy: Handshake, out: &mut Outbox, now: Instant) -> Greeting {
        out.push(HostMsg::GetInfo);
        Greeting { policy, tries: 1, sent: now, foreign: None }
    }

    /// `GetInfo` requests sent so far.
    pub fn tries(&self) -> u32 {
        self.tries
    }

    /// Offers a frame: `Some` when it is a `Hello` — the head's description
    /// if it speaks this protocol, [`ClientError::Version`] if not.
    pub fn on_frame(
        &mut self,
        port: &str,
        frame: &Result<DeviceMsg, WireError>,
    ) -> Option<Result<DeviceInfo, ClientError>> {
        match frame {
            Ok(DeviceMsg::Hello(info)) => Some(check_version(port, info).map(|()| info.clone())),
            Err(WireError::Version(v)) => {
                self.foreign = Some(*v);
                None
            }
            _ => None,
        }
    }

    /// The timer: once the wait for a `Hello` is over, queues the next
    /// `GetInfo`, or, after the last try, says why the head is not
    /// answering. `heard` is when bytes last arrived (for [`Wait::Silence`]).
    pub fn poll(&mut self, port: &str, now: Instant, heard: Instant, out: &mut Outbox) -> Result<(), ClientError> {
        if !self.policy.wait.expired(self.sent, heard, now) {
            return Ok(());
        }
        if self.tries < self.policy.tries {
            self.tries += 1;
            self.sent = now;
            out.push(HostMsg::GetInfo);
            return Ok(());
        }
        let port = port.to_string();
        Err(match self.foreign {
            Some(theirs) => ClientError::Version { port, theirs },
            None if self.policy.tries <= 1 => {
                ClientError::NoAnswer { port, what: "GetInfo".to_string(), after: self.policy.wait.duration() }
            }
            None => ClientError::NoHello { port, tries: self.tries, apart: self.policy.wait.duration() },
        })
    }
}

/// A conversation with one head on one port path (see the module docs).
pub struct Client {
    path: String,
    baud: u32,
    link: Option<Link>,
    deframer: Deframer,
    buf: Vec<u8>,
    out: Outbox,
    heartbeat: Option<Duration>,
    last_heartbeat: Option<Instant>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client")
            .field("path", &self.path)
            .field("open", &self.is_open())
            .field("queued", &self.out.len())
            .field("counters", &self.counters())
            .finish_non_exhaustive()
    }
}

impl Client {
    /// Opens `path` at `baud` (see [`Link::open`]). No heartbeats until
    /// [`Client::with_heartbeat`].
    pub fn open(path: &str, baud: u32) -> Result<Client, LinkError> {
        let link = Link::open(path, baud)?;
        Ok(Client {
            path: path.to_string(),
            baud,
            link: Some(link),
            deframer: Deframer::new(),
            buf: vec![0; READ_BUFFER],
            out: Outbox::default(),
            heartbeat: None,
            last_heartbeat: None,
        })
    }

    /// Sends a `Heartbeat` from [`Client::transmit`] every `every` while the
    /// port is open, the first `every` after opening (the handshake's
    /// `GetInfo` already tells the head the host is there).
    pub fn with_heartbeat(mut self, every: Duration) -> Client {
        self.heartbeat = Some(every);
        self.last_heartbeat = Some(Instant::now());
        self
    }

    /// The port's path.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Whether the port is open (it closes when it fails).
    pub fn is_open(&self) -> bool {
        self.link.is_some()
    }

    /// Closes the port: the unfinished frame and the queued commands are
    /// dropped, the counters kept.
    pub fn close(&mut self) {
        self.link = None;
        self.deframer.restart();
        self.out.queue.clear();
    }

    /// Opens the same path again (a no-op while open).
    pub fn reopen(&mut self) -> Result<(), LinkError> {
        if self.link.is_none() {
            self.link = Some(Link::open(&self.path, self.baud)?);
        }
        Ok(())
    }

    /// The link's counters over every connection.
    pub fn counters(&self) -> Counters {
        self.deframer.counters()
    }

    /// The commands waiting for the next [`Client::transmit`].
    pub fn outbox(&mut self) -> &mut Outbox {
        &mut self.out
    }

    /// Reads once (waiting at most [`READ_TIMEOUT`](super::READ_TIMEOUT))
    /// and hands every complete frame to `on_frame` with its wire bytes and
    /// the outbox. Returns the bytes read (0 when closed or nothing came).
    /// A failed port is closed and its error returned.
    pub fn receive(
        &mut self,
        mut on_frame: impl FnMut(Result<DeviceMsg, WireError>, &[u8], &mut Outbox),
    ) -> Result<usize, LinkError> {
        let Some(link) = &mut self.link else { return Ok(0) };
        match link.read(&mut self.buf) {
            Ok(n) => {
                let out = &mut self.out;
                self.deframer.feed(&self.buf[..n], |r, raw| on_frame(r, raw, out));
                Ok(n)
            }
            Err(e) => {
                self.close();
                Err(e)
            }
        }
    }

    /// Sends what is queued, a heartbeat first if one is due. Returns how
    /// many commands the head did not take (they are lost). With the port
    /// closed the queue is dropped; a port that fails is closed.
    pub fn transmit(&mut self, now: Instant) -> Result<usize, LinkError> {
        let Some(link) = &mut self.link else {
            self.out.queue.clear();
            return Ok(0);
        };
        if let Some(every) = self.heartbeat
            && self.last_heartbeat.is_none_or(|t| now.saturating_duration_since(t) >= every)
        {
            self.last_heartbeat = Some(now);
            let seq = self.out.next_seq();
            self.out.queue.insert(0, (seq, HostMsg::Heartbeat));
        }
        let mut lost = 0;
        for (seq, msg) in std::mem::take(&mut self.out.queue) {
            match link.send(seq, msg) {
                Ok(true) => {}
                Ok(false) => lost += 1,
                Err(e) => {
                    self.close();
                    return Err(e);
                }
            }
        }
        Ok(lost)
    }

    /// Sends `msg` now (with whatever was queued); an error if the head did
    /// not take it. Returns its sequence number.
    pub fn send(&mut self, msg: HostMsg) -> Result<u16, ClientError> {
        let seq = self.out.push(msg);
        self.transmit_all(Instant::now())?;
        Ok(seq)
    }

    /// [`Client::transmit`], with a command the head did not take as an error.
    fn transmit_all(&mut self, now: Instant) -> Result<(), ClientError> {
        match self.transmit(now)? {
            0 => Ok(()),
            _ => Err(ClientError::NotTaken { port: self.path.clone() }),
        }
    }

    /// Offers every intact message to `take` until it returns `Some` (or an
    /// error), or `wait` is over ([`ClientError::NoAnswer`] to `what`).
    /// Heartbeats go out meanwhile if enabled.
    pub fn until<T, E: From<ClientError>>(
        &mut self,
        what: &str,
        wait: Wait,
        mut take: impl FnMut(DeviceMsg) -> Result<Option<T>, E>,
    ) -> Result<T, E> {
        let since = Instant::now();
        let mut heard = since;
        loop {
            if !self.is_open() {
                return Err(ClientError::from(LinkError::Gone {
                    port: self.path.clone(),
                    source: std::io::Error::new(std::io::ErrorKind::NotConnected, "closed"),
                })
                .into());
            }
            self.transmit_all(Instant::now())?;
            let mut got = Ok(None);
            let n = self
                .receive(|r, _, _| {
                    if let (Ok(None), Ok(m)) = (&got, r) {
                        got = take(m);
                    }
                })
                .map_err(ClientError::from)?;
            if let Some(v) = got? {
                return Ok(v);
            }
            let now = Instant::now();
            if n > 0 {
                heard = now;
            }
            if wait.expired(since, heard, now) {
                let (port, what, after) = (self.path.clone(), what.to_string(), wait.duration());
                return Err(ClientError::NoAnswer { port, what, after }.into());
            }
        }
    }

    /// Sends `msg` and waits for its `Ack` ([`ClientError::Refused`] for
    /// its `Error`).
    pub fn request(&mut self, msg: HostMsg, what: &str, wait: Wait) -> Result<(), ClientError> {
        let seq = self.send(msg)?;
        let answer = self.until(what, wait, |m| {
            Ok::<_, ClientError>(match m {
                DeviceMsg::Ack(s) if s == seq => Some(Ok(())),
                DeviceMsg::Error { seq: Some(s), code } if s == seq => Some(Err(code)),
                _ => None,
            })
        })?;
        answer.map_err(|code| ClientError::Refused { port: self.path.clone(), what: what.to_string(), code })
    }

    /// `GetInfo`, and the `Hello` that answers it (any version).
    pub fn info(&mut self, wait: Wait) -> Result<DeviceInfo, ClientError> {
        self.send(HostMsg::GetInfo)?;
        self.until("GetInfo", wait, |m| {
            Ok::<_, ClientError>(match m {
                DeviceMsg::Hello(i) => Some(i),
                _ => None,
            })
        })
    }

    /// Runs a [`Greeting`] to the end: the head's description, checked to
    /// speak this protocol.
    pub fn handshake(&mut self, policy: Handshake) -> Result<DeviceInfo, ClientError> {
        let port = self.path.clone();
        let mut g = Greeting::begin(policy, &mut self.out, Instant::now());
        let mut heard = Instant::now();
        loop {
            self.transmit_all(Instant::now())?;
            let mut got = None;
            let n = self.receive(|r, _, _| {
                if got.is_none() {
                    got = g.on_frame(&port, &r);
                }
            })?;
            if let Some(r) = got {
                return r;
            }
            let now = Instant::now();
            if n > 0 {
                heard = now;
            }
            g.poll(&port, now, heard, &mut self.out)?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_numbers_start_at_one_and_skip_zero() {
        let mut o = Outbox::default();
        assert_eq!(o.push(HostMsg::GetInfo), 1);
        assert_eq!(o.next_seq(), 2);
        o.last_seq = u16::MAX;
        assert_eq!(o.next_seq(), 1);
        assert_eq!(o.len(), 1);
    }

    #[test]
    fn waits_expire_from_the_request_or_the_last_byte() {
        let t0 = Instant::now();
        let s = Duration::from_secs(1);
        let within = Wait::Within(Duration::from_secs(2));
        assert!(!within.expired(t0, t0, t0 + s));
        assert!(within.expired(t0, t0 + 2 * s, t0 + 2 * s), "bytes do not extend a fixed wait");
        let silence = Wait::Silence(Duration::from_secs(2));
        assert!(!silence.expired(t0, t0 + 2 * s, t0 + 3 * s), "bytes extend a silence wait");
        assert!(silence.expired(t0, t0 + 2 * s, t0 + 5 * s));
    }

    #[test]
    fn a_greeting_retries_then_names_the_failure() {
        let t0 = Instant::now();
        let s = Duration::from_secs(1);
        let policy = Handshake { tries: 3, wait: Wait::Within(2 * s) };
        let mut out = Outbox::default();
        let mut g = Greeting::begin(policy, &mut out, t0);
        assert_eq!(out.len(), 1);
        g.poll("p", t0 + s, t0, &mut out).unwrap();
        assert_eq!((g.tries(), out.len()), (1, 1), "not yet due");
        g.poll("p", t0 + 2 * s, t0, &mut out).unwrap();
        g.poll("p", t0 + 4 * s, t0, &mut out).unwrap();
        assert_eq!((g.tries(), out.len()), (3, 3));
        let e = g.poll("p", t0 + 6 * s, t0, &mut out).unwrap_err();
        assert!(matches!(e, ClientError::NoHello { tries: 3, .. }), "{e}");
        assert!(e.to_string().starts_with("no answer from p: no Hello after 3 GetInfo requests 2 s apart"), "{e}");

        // One try is one request; frames of another version name it.
        let one = Handshake { tries: 1, wait: Wait::Silence(10 * s) };
        let mut g = Greeting::begin(one, &mut out, t0);
        assert_eq!(
            g.poll("p", t0 + 11 * s, t0, &mut out).unwrap_err().to_string(),
            "p: no answer to GetInfo within 10 s"
        );
        let mut g = Greeting::begin(one, &mut out, t0);
        assert!(g.on_frame("p", &Err(WireError::Version(9))).is_none());
        let e = g.poll("p", t0 + 11 * s, t0, &mut out).unwrap_err();
        assert!(matches!(e, ClientError::Version { theirs: 9, .. }), "{e}");
    }

    #[test]
    fn the_port_error_is_the_source() {
        use std::error::Error as _;
        let e = ClientError::from(LinkError::Gone { port: "p".into(), source: std::io::Error::other("unplugged") });
        assert_eq!(e.to_string(), "p failed: unplugged");
        let source = e.source().expect("the link error's source shows through");
        assert_eq!(source.to_string(), "unplugged");
    }
}
