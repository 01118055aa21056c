//! The serial link to the sensor head: opening a port by path, reading with a
//! short timeout, sending commands, and splitting the byte stream into frames
//! while keeping each frame's wire bytes (for recordings).
//!
//! [`Link`] wraps a `serialport` port opened *by path* (no device
//! enumeration, so no libudev): `/dev/ttyACM0`, a pseudo-terminal such as
//! `/dev/pts/7`, or a symlink to either. Whatever goes wrong below the
//! framing — the path vanished, the read failed, end of file (a pseudo-terminal
//! whose other side closed) — is reported as [`LinkError::Gone`], and the
//! listener's answer is to close the port and open the same path again.
//!
//! [`Deframer`] feeds the bytes to `cms_core`'s [`FrameReader`] (the single
//! source of the link counters: frames, CRC errors, decode errors, overflows)
//! and hands every frame's result together with the exact bytes it came from,
//! delimiter included.
//!
//! [`Client`] (in `link/client.rs`) is the conversation built on both that
//! `listen`, `capture` and `calibrate upload` share: sequence numbers, the
//! handshake and its version check, heartbeats, request/response with
//! timeouts.

use std::fmt;
use std::io::{self, Read, Write};
use std::time::Duration;

mod client;
pub use client::{Client, ClientError, Greeting, Handshake, Outbox, Wait, check_version};

use cms_core::protocol::{
    Command, DeviceMsg, FrameReader, FromFrame, HostMsg, LinkStats, MAX_COMMAND_FRAME, MAX_READ_FRAME, WireError,
    encode,
};

/// How long one [`Link::read`] waits for bytes.
pub const READ_TIMEOUT: Duration = Duration::from_millis(20);

/// How long one command write may block (the head reads commands between
/// rows; a head that does not read for this long is treated as not answering).
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(200);

/// Why the port failed. The operating system's error is the [`source`]
/// (`std::error::Error::source`); the message repeats it, as `cms-host`
/// has always printed it, so a caller printing the whole chain should
/// print only this one.
///
/// [`source`]: std::error::Error::source
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// The port could not be opened.
    #[error("cannot open {port}: {source}")]
    Open {
        /// The path.
        port: String,
        /// Why.
        #[source]
        source: serialport::Error,
    },
    /// The port failed or closed after opening (unplugged, end of file).
    #[error("{port} failed: {source}")]
    Gone {
        /// The path.
        port: String,
        /// What the operating system said.
        #[source]
        source: io::Error,
    },
}

impl crate::error::Classify for LinkError {
    fn class(&self) -> crate::Class {
        crate::Class::Device
    }
}

/// Opens a serial port (or pty) at `baud` in raw mode, 8N1, no flow
/// control, its reads waiting at most `timeout`: the head's link and a
/// GNSS receiver's port alike.
pub fn open_serial(
    path: &str,
    baud: u32,
    timeout: Duration,
) -> Result<Box<dyn serialport::SerialPort>, serialport::Error> {
    serialport::new(path, baud)
        .timeout(timeout)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .open()
}

/// An open serial port to the head.
pub struct Link {
    port: Box<dyn serialport::SerialPort>,
    path: String,
    frame: Vec<u8>,
}

impl fmt::Debug for Link {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Link").field("path", &self.path).finish_non_exhaustive()
    }
}

impl Link {
    /// Opens `path` at `baud` (raw mode, 8N1, no flow control). A USB CDC
    /// device ignores the baud rate; a real UART needs the head's.
    pub fn open(path: &str, baud: u32) -> Result<Link, LinkError> {
        let port = open_serial(path, baud, READ_TIMEOUT)
            .map_err(|source| LinkError::Open { port: path.to_string(), source })?;
        Ok(Link { port, path: path.to_string(), frame: vec![0; MAX_COMMAND_FRAME] })
    }

    /// The path this link was opened with.
    pub fn path(&self) -> &str {
        &self.path
    }

    fn gone(&self, source: io::Error) -> LinkError {
        LinkError::Gone { port: self.path.clone(), source }
    }

    /// Reads what is there, waiting at most [`READ_TIMEOUT`]. `Ok(0)` means
    /// nothing arrived; end of file and every error other than a timeout or
    /// an interrupted call mean the port is gone.
    pub fn read(&mut self, buf: &mut [u8]) -> Result<usize, LinkError> {
        match self.port.read(buf) {
            Ok(0) => Err(self.gone(io::Error::new(io::ErrorKind::UnexpectedEof, "end of file (device closed)"))),
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::Interrupted) => Ok(0),
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(0),
            Err(e) => Err(self.gone(e)),
        }
    }

    /// Sends one command. `Ok(false)` when the head did not take it within
    /// [`WRITE_TIMEOUT`] (the command is lost; the handshake's retries and the
    /// heartbeat cover that); an error means the port is gone.
    pub fn send(&mut self, seq: u16, msg: HostMsg) -> Result<bool, LinkError> {
        let cmd = Command { seq, msg };
        let frame = match encode(&cmd, &mut self.frame) {
            Ok(f) => f,
            // Every command fits MAX_COMMAND_FRAME (checked by cms-core's tests).
            Err(e) => return Err(self.gone(io::Error::other(format!("encoding a command: {e}")))),
        };
        let mut rest: &[u8] = frame;
        let deadline = std::time::Instant::now() + WRITE_TIMEOUT;
        while !rest.is_empty() {
            match self.port.write(rest) {
                Ok(0) => return Err(self.gone(io::Error::new(io::ErrorKind::WriteZero, "wrote nothing"))),
                Ok(n) => rest = &rest[n..],
                Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock) => {
                    if std::time::Instant::now() >= deadline {
                        // A partial frame ends at the head's next delimiter
                        // (it counts one bad frame); the next command's
                        // leading bytes are not lost because we finish with 0.
                        if rest.len() < frame.len() {
                            let _ = self.port.write(&[0]);
                        }
                        return Ok(false);
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    let e = self.gone(e);
                    return Err(e);
                }
            }
        }
        Ok(true)
    }
}

/// Counters of the link, summed over every connection (a reconnect starts a
/// new [`FrameReader`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Frames decoded.
    pub frames: u64,
    /// Frames with a CRC mismatch.
    pub crc_errors: u64,
    /// Frames that failed COBS, length, version or payload decoding.
    pub decode_errors: u64,
    /// Frames longer than [`MAX_READ_FRAME`] (discarded).
    pub overflows: u64,
    /// Bytes discarded while resynchronising.
    pub discarded_bytes: u64,
}

impl Counters {
    /// Resynchronisations: frames dropped for anything but their CRC
    /// (decode errors and overflows).
    pub fn resyncs(&self) -> u64 {
        self.decode_errors + self.overflows
    }

    /// Damaged frames of any kind.
    pub fn damaged(&self) -> u64 {
        self.crc_errors + self.decode_errors + self.overflows
    }

    fn add(&mut self, s: LinkStats) {
        self.frames += u64::from(s.frames);
        self.crc_errors += u64::from(s.crc_errors);
        self.decode_errors += u64::from(s.decode_errors);
        self.overflows += u64::from(s.overflows);
        self.discarded_bytes += u64::from(s.discarded_bytes);
    }
}

/// Splits a device → host byte stream into frames with [`FrameReader`], and
/// keeps each frame's wire bytes.
pub struct Deframer {
    reader: Box<FrameReader<MAX_READ_FRAME>>,
    /// Wire bytes of the frame in progress (delimiter appended when complete).
    raw: Vec<u8>,
    /// Bytes of the frame in progress, including those beyond `raw`'s cap.
    pending: u64,
    /// Counters of readers replaced by [`Deframer::restart`].
    before: Counters,
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

impl fmt::Debug for Deframer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Deframer").field("pending", &self.pending).field("counters", &self.counters()).finish()
    }
}

impl Deframer {
    /// An empty deframer.
    pub fn new() -> Self {
        Deframer {
            reader: Box::new(FrameReader::new()),
            raw: Vec::with_capacity(4096),
            pending: 0,
            before: Counters::default(),
        }
    }

    /// Feeds bytes; calls `on_frame` for every complete frame with its result
    /// and its wire bytes (COBS bytes and the 0x00 delimiter; empty for a
    /// frame longer than [`MAX_READ_FRAME`]).
    pub fn feed(&mut self, data: &[u8], on_frame: impl FnMut(Result<DeviceMsg, WireError>, &[u8])) {
        self.feed_as(data, on_frame)
    }

    /// [`Deframer::feed`], decoding frames as `T` (a recording's frames
    /// hold host records too).
    pub fn feed_as<T: FromFrame>(&mut self, data: &[u8], mut on_frame: impl FnMut(Result<T, WireError>, &[u8])) {
        for seg in data.split_inclusive(|&b| b == 0) {
            self.pending += seg.len() as u64;
            if self.raw.len() + seg.len() <= MAX_READ_FRAME {
                self.raw.extend_from_slice(seg);
            } else {
                self.raw.clear();
            }
            let mut got = None;
            self.reader.feed(seg, |r: Result<T, WireError>| got = Some(r));
            if seg.last() == Some(&0) {
                if let Some(r) = got {
                    on_frame(r, &self.raw);
                }
                self.raw.clear();
                self.pending = 0;
            }
        }
    }

    /// Bytes of an unfinished frame (no delimiter yet).
    pub fn pending(&self) -> u64 {
        self.pending
    }

    /// Forgets an unfinished frame (the port was closed under it) and starts
    /// a new reader; the counters carry over.
    pub fn restart(&mut self) {
        self.before.add(self.reader.stats());
        *self.reader = FrameReader::new();
        self.raw.clear();
        self.pending = 0;
    }

    /// Counters over every reader so far.
    pub fn counters(&self) -> Counters {
        let mut c = self.before;
        c.add(self.reader.stats());
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cms_core::protocol::{HeadState, MAX_FRAME, Status};

    fn frame(msg: &DeviceMsg) -> Vec<u8> {
        let mut out = vec![0u8; MAX_FRAME];
        encode(msg, &mut out).unwrap().to_vec()
    }

    fn status(frames: u32) -> DeviceMsg {
        DeviceMsg::Status(Status {
            state: HeadState::Streaming,
            lasers_on: 7,
            frames,
            frame_rate_millihz: 0,
            rows_per_s: 0,
            dropped_frames: 0,
            ns_per_row: 0,
            cycles_per_row: 0,
            dropped_rows: 0,
            link_backlog_bytes: 0,
            laser_duty_permille: 0,
            heartbeat_age_ms: 0,
            fault: None,
        })
    }

    #[test]
    fn wire_bytes_come_with_each_frame_in_any_chunking() {
        let mut stream = Vec::new();
        let frames: Vec<Vec<u8>> = (0..5).map(|i| frame(&status(i))).collect();
        stream.extend_from_slice(b"\x01\x02garbage\0");
        for f in &frames {
            stream.extend_from_slice(f);
        }
        stream.extend_from_slice(&frames[0][..3]);
        for chunk in [1, 2, 7, 1000] {
            let mut d = Deframer::new();
            let mut got = Vec::new();
            for c in stream.chunks(chunk) {
                d.feed(c, |r, raw| got.push((r.is_ok(), raw.to_vec())));
            }
            assert_eq!(got.len(), 6);
            assert!(!got[0].0);
            for (g, f) in got[1..].iter().zip(&frames) {
                assert!(g.0);
                assert_eq!(&g.1, f);
            }
            assert_eq!(d.pending(), 3);
            assert_eq!(d.counters().frames, 5);
            assert_eq!(d.counters().damaged(), 1);
            d.restart();
            assert_eq!(d.pending(), 0);
            assert_eq!(d.counters().frames, 5);
        }
    }
}
