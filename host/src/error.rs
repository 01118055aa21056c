//! The host library's error, and what kind of failure each one is.
//!
//! Each domain module has its own typed error ([`crate::input::InputError`],
//! [`crate::link::LinkError`], [`crate::link::ClientError`], [`crate::listen::ListenError`],
//! [`crate::record::RecordError`], [`crate::qemu::QemuError`],
//! [`crate::simulate::SimulateError`], …); [`Error`] is their union plus the
//! two kinds of plain message that the command-level functions produce (a bad
//! input, a device that misbehaves). The library never decides an exit
//! status: it says what *kind* of failure an error is ([`Error::class`]) and
//! the command line maps classes to statuses in one place (`cli::exit`).
//!
//! Messages are one line, name what was wrong, and do not repeat their
//! source's text when the source is attached (the command line prints the
//! chain).

use std::io;

use crate::input::InputError;
use crate::link::{ClientError, LinkError};
use crate::listen::ListenError;
use crate::qemu::QemuError;
use crate::record::RecordError;
use crate::simulate::SimulateError;

/// What kind of failure an error is: the user's to fix, the device's, or
/// anything else.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Class {
    /// A bad option value or a bad input file.
    Input,
    /// The device or the link failed: a port that cannot be opened, a head
    /// that does not answer, refuses or speaks another protocol, the
    /// emulated head that cannot start.
    Device,
    /// Writing an output failed (a closed pipe included: see
    /// [`Error::is_broken_pipe`]).
    Output,
    /// Anything else (a failed build of the emulated head, a system call).
    Other,
}

/// Why a host operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A bad option value or a bad input file, in words.
    #[error("{0}")]
    Input(String),
    /// A device or link failure, in words.
    #[error("{0}")]
    Device(String),
    /// Writing an output failed.
    #[error("writing output: {0}")]
    Output(#[source] io::Error),
    /// Reading an image or rows.
    #[error(transparent)]
    Read(#[from] InputError),
    /// The serial link.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// A conversation with a head (`capture`, `calibrate upload`).
    #[error(transparent)]
    Client(#[from] ClientError),
    /// A listening session.
    #[error(transparent)]
    Listen(#[from] ListenError),
    /// A recording.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The emulated head.
    #[error(transparent)]
    Qemu(#[from] QemuError),
    /// The simulated head.
    #[error(transparent)]
    Simulate(#[from] SimulateError),
}

impl From<io::Error> for Error {
    fn from(e: io::Error) -> Self {
        Error::Output(e)
    }
}

impl Error {
    /// What kind of failure this is.
    pub fn class(&self) -> Class {
        match self {
            Error::Input(_) | Error::Read(_) => Class::Input,
            Error::Device(_) | Error::Link(_) => Class::Device,
            // As `capture` and `calibrate upload` have always exited (2),
            // their port and head failures included; making them device
            // failures (3), as listen's are, is this match's one line.
            Error::Client(_) => Class::Input,
            Error::Output(_) => Class::Output,
            Error::Listen(e) => match e {
                ListenError::Output(_) => Class::Output,
                ListenError::Record(r) => record_class(r),
                _ => Class::Device,
            },
            Error::Record(e) => record_class(e),
            Error::Qemu(e) => qemu_class(e),
            Error::Simulate(e) => simulate_class(e),
        }
    }

    /// The class of any error of this library, found by its type: an
    /// [`Error`] or one of the module errors it unites (the command line
    /// passes them on as they come). `None` for another crate's error.
    pub fn class_of(e: &(dyn std::error::Error + 'static)) -> Option<Class> {
        if let Some(e) = e.downcast_ref::<Error>() {
            return Some(e.class());
        }
        if e.is::<InputError>() {
            return Some(Class::Input);
        }
        if e.is::<LinkError>() {
            return Some(Class::Device);
        }
        if let Some(l) = e.downcast_ref::<ListenError>() {
            return Some(match l {
                ListenError::Output(_) => Class::Output,
                ListenError::Record(r) => record_class(r),
                _ => Class::Device,
            });
        }
        if let Some(r) = e.downcast_ref::<RecordError>() {
            return Some(record_class(r));
        }
        if let Some(q) = e.downcast_ref::<QemuError>() {
            return Some(qemu_class(q));
        }
        if let Some(s) = e.downcast_ref::<SimulateError>() {
            return Some(simulate_class(s));
        }
        None
    }

    /// Whether this is a write to a closed pipe (`cms-host export … | head`),
    /// which ends a command quietly and successfully.
    pub fn is_broken_pipe(&self) -> bool {
        let io = match self {
            Error::Output(e) | Error::Listen(ListenError::Output(e)) | Error::Record(RecordError::Output(e)) => e,
            _ => return false,
        };
        io.kind() == io::ErrorKind::BrokenPipe
    }
}

fn qemu_class(e: &QemuError) -> Class {
    match e {
        QemuError::Usage(_) => Class::Input,
        QemuError::Build { .. } | QemuError::Io(..) | QemuError::Bench(_) => Class::Other,
        _ => Class::Device,
    }
}

fn simulate_class(e: &SimulateError) -> Class {
    match e {
        SimulateError::Usage(_) => Class::Input,
        _ => Class::Other,
    }
}

fn record_class(e: &RecordError) -> Class {
    match e {
        RecordError::Output(_) => Class::Output,
        // A recording that cannot be opened or read is a bad input file.
        RecordError::Io { .. } | RecordError::Format { .. } => Class::Input,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classes() {
        assert_eq!(Error::Input("x".into()).class(), Class::Input);
        assert_eq!(Error::Device("x".into()).class(), Class::Device);
        let gone = LinkError::Gone { port: "/dev/ttyACM0".into(), source: io::Error::other("unplugged") };
        assert_eq!(Error::from(gone).class(), Class::Device);
        assert_eq!(Error::from(QemuError::NotInstalled).class(), Class::Device);
        assert_eq!(Error::from(QemuError::Usage("x".into())).class(), Class::Input);
        let pipe = Error::from(io::Error::from(io::ErrorKind::BrokenPipe));
        assert!(pipe.is_broken_pipe());
        assert_eq!(pipe.class(), Class::Output);
        assert!(!Error::Input("x".into()).is_broken_pipe());
        let bare = RecordError::Format { path: "a.cmsrec".into(), why: "not a CMS recording".into() };
        assert_eq!(Error::class_of(&bare), Some(Class::Input));
        assert_eq!(Error::class_of(&SimulateError::Usage("x".into())), Some(Class::Input));
        assert_eq!(Error::class_of(&io::Error::other("x")), None);
    }
}
