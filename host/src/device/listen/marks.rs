//! Event marks asked for while listening (the terminal, the live page)
//! and how they reach the recording.
//!
//! Whoever asks (a thread reading the terminal, the live view's server)
//! holds a [`MarkSender`]; the session holds the [`MarkInbox`] and, once
//! per turn of its loop, takes what is waiting without ever waiting itself:
//! each mark gets the odometer of the latest profile received, is written
//! to the recording as a host record ([`crate::recording::HostRecord::Mark`])
//! and answered. The queue holds [`MARK_QUEUE`] marks; a full one refuses
//! the next ([`MarkRefused::Busy`]) rather than hold the asker or the loop.

use std::fmt;
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};

use crate::recording::mark::{Mark, MarkEntry};

/// Marks waiting for the session at most (a person marks a few a second
/// at most; more waiting means the session is not turning).
pub const MARK_QUEUE: usize = 32;

/// Why a mark was not recorded.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum MarkRefused {
    /// The session does not record.
    #[error("not recording (--record FILE): a mark is kept in the recording only")]
    NotRecording,
    /// The recording appended to is of a format without marks.
    #[error("the recording is of format {0}, which holds no marks (format {m}); record to a new file", m = crate::recording::MARKS_FORMAT)]
    Format(u16),
    /// No profile has arrived yet: nothing to place the mark at.
    #[error("no frame received yet: nothing to place the mark at")]
    NoFrame,
    /// The queue to the session is full, or the session has ended.
    #[error("the listener is not taking marks now (its queue of {MARK_QUEUE} is full, or it has stopped)")]
    Busy,
    /// Writing it failed (the session ends with that error).
    #[error("writing the mark failed: {0}")]
    Write(String),
}

/// Where the answer to a mark goes: called once, on the session's thread,
/// so it must not block (send it on).
pub type MarkReply = Box<dyn FnOnce(Result<Mark, MarkRefused>) + Send>;

/// A mark asked for.
pub struct MarkRequest {
    /// What to mark.
    pub entry: MarkEntry,
    /// Where the answer goes.
    pub reply: MarkReply,
}

/// The askers' end: cheap to clone, never blocks.
#[derive(Clone)]
pub struct MarkSender(SyncSender<MarkRequest>);

impl fmt::Debug for MarkSender {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("MarkSender")
    }
}

impl MarkSender {
    /// Hands `entry` to the session; `reply` is told the outcome (at once,
    /// with [`MarkRefused::Busy`], when the queue is full or the session gone).
    pub fn send(&self, entry: MarkEntry, reply: MarkReply) {
        match self.0.try_send(MarkRequest { entry, reply }) {
            Ok(()) => {}
            Err(TrySendError::Full(r)) | Err(TrySendError::Disconnected(r)) => (r.reply)(Err(MarkRefused::Busy)),
        }
    }
}

/// The session's end.
#[derive(Debug)]
pub struct MarkInbox(pub(super) Receiver<MarkRequest>);

impl fmt::Debug for MarkRequest {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("MarkRequest").field("entry", &self.entry).finish_non_exhaustive()
    }
}

/// A queue of [`MARK_QUEUE`] marks from askers to a session.
pub fn mark_channel() -> (MarkSender, MarkInbox) {
    let (tx, rx) = mpsc::sync_channel(MARK_QUEUE);
    (MarkSender(tx), MarkInbox(rx))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::mark::MarkKind;
    use std::sync::{Arc, Mutex};

    /// A full queue refuses at once: the asker is never held.
    #[test]
    fn a_full_queue_refuses() {
        let (tx, rx) = mark_channel();
        let refused = Arc::new(Mutex::new(0));
        for _ in 0..MARK_QUEUE + 3 {
            let r = refused.clone();
            let e = MarkEntry::new(MarkKind::Weld, "").unwrap();
            tx.send(e, Box::new(move |res| *r.lock().unwrap() += usize::from(res == Err(MarkRefused::Busy))));
        }
        assert_eq!(*refused.lock().unwrap(), 3);
        assert_eq!(rx.0.try_iter().count(), MARK_QUEUE);
        drop(rx);
        let r = refused.clone();
        tx.send(
            MarkEntry::new(MarkKind::Joint, "").unwrap(),
            Box::new(move |res| *r.lock().unwrap() += usize::from(res == Err(MarkRefused::Busy))),
        );
        assert_eq!(*refused.lock().unwrap(), 4);
    }
}
