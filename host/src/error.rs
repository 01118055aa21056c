//! The host library's error, and what kind of failure each one is.
//!
//! Each domain module has its own typed error ([`crate::input::InputError`],
//! [`crate::link::LinkError`], [`crate::link::ClientError`],
//! [`crate::device::listen::ListenError`], [`crate::recording::RecordError`],
//! [`crate::device::qemu::QemuError`], [`crate::sim::head::SimulateError`], …) and
//! says what [`Class`] of failure each of its variants is ([`Classify`]).
//! [`Error`] holds any of them ([`Error::Module`]) or one of the plain
//! messages the command-level functions produce (a bad input, a device that
//! misbehaves). The library never decides an exit status: the command line
//! maps classes to statuses in one place (`cli::exit`).
//!
//! This module imports no other host module (they all import it): the
//! classes live with the errors, so the layers have no cycle.
//!
//! There is no blanket conversion from `io::Error`: whether a failed read
//! or write is the user's input (exit 2), an output (exit 1) or the device
//! (exit 3) depends on the file, so every call site says which.
//!
//! Messages are one line, name what was wrong, and do not repeat their
//! source's text when the source is attached (the command line prints the
//! chain).

use std::io;

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
    /// Writing an output failed (a closed pipe included).
    Output,
    /// Anything else (a failed build of the emulated head, a system call).
    Other,
}

/// A module's error that knows its class.
pub trait Classify: std::error::Error + Send + Sync + 'static {
    /// What kind of failure this is.
    fn class(&self) -> Class;
}

/// A module's error inside [`Error`]: shown as itself, its class kept.
#[derive(Debug)]
pub struct ModuleError {
    class: Class,
    inner: Box<dyn std::error::Error + Send + Sync>,
}

impl ModuleError {
    /// The module's error itself (to downcast to its type).
    pub fn inner(&self) -> &(dyn std::error::Error + Send + Sync + 'static) {
        &*self.inner
    }
}

impl std::fmt::Display for ModuleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.inner.fmt(f)
    }
}

impl std::error::Error for ModuleError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        // Transparent: the module's error is this one, its source is ours.
        self.inner.source()
    }
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
    /// A module's own error ([`Classify`]).
    #[error(transparent)]
    Module(ModuleError),
}

impl<E: Classify> From<E> for Error {
    fn from(e: E) -> Self {
        Error::Module(ModuleError { class: e.class(), inner: Box::new(e) })
    }
}

impl Error {
    /// What kind of failure this is.
    pub fn class(&self) -> Class {
        match self {
            Error::Input(_) => Class::Input,
            Error::Device(_) => Class::Device,
            Error::Output(_) => Class::Output,
            Error::Module(m) => m.class,
        }
    }

    /// The module's error of [`Error::Module`], as its type `E`.
    pub fn downcast_ref<E: std::error::Error + 'static>(&self) -> Option<&E> {
        match self {
            Error::Module(m) => m.inner().downcast_ref(),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("the head went away")]
    struct Gone;

    impl Classify for Gone {
        fn class(&self) -> Class {
            Class::Device
        }
    }

    #[test]
    fn classes_and_the_module_error_inside() {
        assert_eq!(Error::Input("x".into()).class(), Class::Input);
        assert_eq!(Error::Device("x".into()).class(), Class::Device);
        assert_eq!(Error::Output(io::Error::from(io::ErrorKind::BrokenPipe)).class(), Class::Output);
        let e = Error::from(Gone);
        assert_eq!(e.class(), Class::Device);
        assert_eq!(e.to_string(), "the head went away");
        assert!(e.downcast_ref::<Gone>().is_some());
        assert!(std::error::Error::source(&e).is_none(), "transparent: Gone itself has no source");
    }
}
