//! A GNSS receiver on its own serial port, read by a thread of its own.
//!
//! The thread cuts the port's bytes into sentences and binary frames
//! ([`Framer`]), gathers the sentences into fixes ([`Assembler`]) and
//! hands each fix, stamped with the host time its epoch's first sentence
//! arrived, to the listener through a bounded channel. A listener that
//! falls behind never stalls the port: a fix that finds the channel full
//! is counted as dropped. A port that fails (the receiver unplugged) is
//! reopened every second; the fixes in between are missing, and counted
//! as the port's outages.

use std::io::{self, Read};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver as Rx, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::framing::{Framer, Piece};
use super::{Assembler, Fix};

/// Fixes that may wait for the listener (at 20 Hz, 12 s).
const CHANNEL_FIXES: usize = 256;
/// How long the port's read waits; an epoch still open after a silence
/// this long is complete (every sentence of an epoch comes in one burst).
const READ_TIMEOUT: Duration = Duration::from_millis(40);
/// Interval of attempts to reopen a lost port.
const REOPEN_INTERVAL: Duration = Duration::from_secs(1);

/// Why the receiver could not be started.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReceiverError {
    /// The port could not be opened.
    #[error("cannot open the GNSS receiver's port {port}: {source}")]
    Open {
        /// The port.
        port: String,
        /// Why.
        #[source]
        source: serialport::Error,
    },
    /// The thread could not be started.
    #[error("starting the GNSS reader: {0}")]
    Thread(#[source] io::Error),
}

impl crate::error::Classify for ReceiverError {
    fn class(&self) -> crate::Class {
        crate::Class::Device
    }
}

/// What the reader has seen so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReceiverStats {
    /// Fixes handed to the listener.
    pub fixes: u64,
    /// Fixes lost because the listener's channel was full.
    pub dropped: u64,
    /// NMEA sentences damaged: a checksum or syntax that fails, or cut short.
    pub damaged: u64,
    /// Sentences and frames skipped whole: proprietary and other kinds of
    /// sentence, sentences of an epoch already given out, binary frames.
    pub other: u64,
    /// Bytes in no sentence and no frame.
    pub stray_bytes: u64,
    /// Epochs without a position.
    pub no_position: u64,
    /// Times the port failed and was reopened.
    pub outages: u64,
}

#[derive(Default)]
struct Shared {
    fixes: AtomicU64,
    dropped: AtomicU64,
    damaged: AtomicU64,
    other: AtomicU64,
    stray_bytes: AtomicU64,
    no_position: AtomicU64,
    outages: AtomicU64,
}

/// A receiver being read; dropping it stops the thread.
pub struct Receiver {
    port: String,
    rx: Rx<(Instant, Fix)>,
    stop: Arc<AtomicBool>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Receiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Receiver").field("port", &self.port).field("stats", &self.stats()).finish()
    }
}

fn open(path: &str, baud: u32) -> Result<Box<dyn serialport::SerialPort>, serialport::Error> {
    crate::link::open_serial(path, baud, READ_TIMEOUT)
}

impl Receiver {
    /// Opens `port` at `baud` and starts reading it.
    pub fn start(port: &str, baud: u32) -> Result<Receiver, ReceiverError> {
        let serial = open(port, baud).map_err(|source| ReceiverError::Open { port: port.to_string(), source })?;
        let (tx, rx) = sync_channel(CHANNEL_FIXES);
        let stop = Arc::new(AtomicBool::new(false));
        let shared = Arc::new(Shared::default());
        let (flag, counts, path) = (stop.clone(), shared.clone(), port.to_string());
        let thread = std::thread::Builder::new()
            .name("cms-gnss".into())
            .spawn(move || read_loop(serial, &path, baud, &tx, &flag, &counts))
            .map_err(ReceiverError::Thread)?;
        Ok(Receiver { port: port.to_string(), rx, stop, shared, thread: Some(thread) })
    }

    /// The port.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// The fixes that arrived since the last call, each with the host time
    /// its epoch's first sentence arrived.
    pub fn drain(&self) -> impl Iterator<Item = (Instant, Fix)> + '_ {
        self.rx.try_iter()
    }

    /// What the reader has seen so far.
    pub fn stats(&self) -> ReceiverStats {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let s = &self.shared;
        ReceiverStats {
            fixes: g(&s.fixes),
            dropped: g(&s.dropped),
            damaged: g(&s.damaged),
            other: g(&s.other),
            stray_bytes: g(&s.stray_bytes),
            no_position: g(&s.no_position),
            outages: g(&s.outages),
        }
    }
}

impl Drop for Receiver {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Cuts bytes into pieces and sentences into fixes.
#[derive(Default)]
pub(super) struct Lines {
    pub(super) framer: Framer,
    pub(super) asm: Assembler,
    /// Binary frames skipped.
    pub(super) frames: u64,
    /// Sentences cut short or too long.
    pub(super) broken: u64,
    /// When the open epoch's first timed sentence arrived.
    opened: Option<Instant>,
}

impl Lines {
    pub(super) fn feed(&mut self, bytes: &[u8], now: Instant, out: &mut impl FnMut(Instant, Fix)) {
        let Lines { framer, asm, frames, broken, opened } = self;
        framer.feed(bytes, &mut |piece| match piece {
            Piece::Line(line) => {
                let (before, was_open) = (asm.epochs_opened(), *opened);
                if let Ok(closed) = asm.line(line) {
                    if asm.epochs_opened() != before {
                        *opened = Some(now);
                    }
                    if let Some(f) = closed {
                        out(was_open.unwrap_or(now), f);
                    }
                }
            }
            Piece::Broken => *broken += 1,
            Piece::Frame(_) => *frames += 1,
        });
    }

    pub(super) fn idle(&mut self, out: &mut impl FnMut(Instant, Fix)) {
        if let Some(f) = self.asm.flush() {
            out(self.opened.unwrap_or_else(Instant::now), f);
        }
        self.opened = None;
    }

    fn publish(&self, shared: &Shared) {
        shared.damaged.store(self.asm.invalid + self.broken, Ordering::Relaxed);
        shared.other.store(self.asm.ignored + self.asm.late + self.frames, Ordering::Relaxed);
        shared.stray_bytes.store(self.framer.stray_bytes, Ordering::Relaxed);
        shared.no_position.store(self.asm.no_position, Ordering::Relaxed);
    }
}

fn read_loop(
    mut serial: Box<dyn serialport::SerialPort>,
    path: &str,
    baud: u32,
    tx: &SyncSender<(Instant, Fix)>,
    stop: &AtomicBool,
    shared: &Shared,
) {
    let mut lines = Lines::default();
    let mut buf = [0u8; 1024];
    let mut send = |t: Instant, f: Fix| match tx.try_send((t, f)) {
        Ok(()) => {
            shared.fixes.fetch_add(1, Ordering::Relaxed);
        }
        Err(TrySendError::Full(_)) => {
            shared.dropped.fetch_add(1, Ordering::Relaxed);
        }
        Err(TrySendError::Disconnected(_)) => {}
    };
    while !stop.load(Ordering::Relaxed) {
        match serial.read(&mut buf) {
            Ok(n) if n > 0 => lines.feed(&buf[..n], Instant::now(), &mut send),
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::Interrupted) => lines.idle(&mut send),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => lines.idle(&mut send),
            _ => {
                // End of file or an error: the port is gone. Reopen it.
                lines.idle(&mut send);
                shared.outages.fetch_add(1, Ordering::Relaxed);
                loop {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    std::thread::sleep(REOPEN_INTERVAL);
                    if let Ok(s) = open(path, baud) {
                        serial = s;
                        break;
                    }
                }
            }
        }
        lines.publish(shared);
    }
    lines.idle(&mut send);
    lines.publish(shared);
}

#[cfg(test)]
mod tests {
    use super::super::sentence::sentence;
    use super::*;

    #[test]
    fn an_epoch_is_stamped_when_its_first_sentence_arrived() {
        let mut l = Lines::default();
        let t0 = Instant::now();
        let t1 = t0 + Duration::from_millis(100);
        let gga = |t: &str| sentence(&format!("GPGGA,{t},4807.038,N,01131.000,E,4,08,0.9,545.4,M,46.9,M,,"));
        let mut got = Vec::new();
        // One epoch arriving in two pieces, then the next one's GGA.
        let first = gga("101530.20");
        let (a, b) = first.as_bytes().split_at(10);
        l.feed(a, t0, &mut |t, f| got.push((t, f)));
        l.feed(b, t0, &mut |t, f| got.push((t, f)));
        l.feed(sentence("GPVTG,87.5,T,,M,1.944,N,3.600,K,R").as_bytes(), t0, &mut |t, f| got.push((t, f)));
        assert!(got.is_empty());
        l.feed(gga("101530.30").as_bytes(), t1, &mut |t, f| got.push((t, f)));
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].0, t0);
        assert!(got[0].1.speed_mm_s.is_some());
        l.idle(&mut |t, f| got.push((t, f)));
        assert_eq!((got.len(), got[1].0), (2, t1));
        // A line without end is dropped, counted once.
        l.feed(b"$", t1, &mut |t, f| got.push((t, f)));
        l.feed(&[b'A'; 2000], t1, &mut |t, f| got.push((t, f)));
        l.feed(b"\n", t1, &mut |t, f| got.push((t, f)));
        assert_eq!((got.len(), l.broken, l.asm.invalid), (2, 1, 0));
    }
}
