//! Exit statuses, in one place, and the one `error: ` line a failure prints.
//!
//! | status | meaning |
//! |---|---|
//! | 0 | success (and a write to a closed pipe: `… | head` ends quietly) |
//! | 2 | bad usage or a bad input file (clap's own errors exit 2 too) |
//! | 3 | the device or the link failed |
//! | 1 | anything else (writing an output, a system call, a build) |
//!
//! The status comes from the first error of the `cms_host` library (its
//! [`cms_host::Error`] or a module's error: `class_of`) or [`Usage`]
//! in the error's chain (the command line wraps library errors in context,
//! never the other way round); an error with neither is "anything else".

use std::io::Write as _;
use std::process::ExitCode;

use cms_host::{Class, Error};

/// A bad command line that clap's parsers cannot see (options that do not
/// go together, a value checked against a file): exit status 2.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Usage(pub String);

/// A bad input, as the command line's error (exit status 2).
pub fn input(msg: String) -> anyhow::Error {
    Error::Input(msg).into()
}

/// The exit status of a failure.
pub fn status(e: &anyhow::Error) -> u8 {
    for cause in e.chain() {
        if cause.is::<Usage>() {
            return 2;
        }
        if let Some(class) = class_of(cause) {
            return match class {
                Class::Input => 2,
                Class::Device => 3,
                _ => 1,
            };
        }
    }
    1
}

/// The class of an error of the `cms_host` library, found by its type: an
/// [`Error`], or a module's error passed on bare. `None` for another
/// crate's error.
fn class_of(e: &(dyn std::error::Error + 'static)) -> Option<Class> {
    use cms_host::error::Classify;
    if let Some(e) = e.downcast_ref::<Error>() {
        return Some(e.class());
    }
    macro_rules! classed {
        ($($t:ty),*) => {$(
            if let Some(x) = e.downcast_ref::<$t>() {
                return Some(x.class());
            }
        )*};
    }
    classed!(
        cms_host::input::InputError,
        cms_host::link::LinkError,
        cms_host::link::ClientError,
        cms_host::device::listen::ListenError,
        cms_host::recording::RecordError,
        cms_host::output::OutputError,
        cms_host::device::qemu::QemuError,
        cms_host::sim::head::SimulateError,
        cms_host::sim::scene::RoughnessSpectrumError,
        cms_host::gnss::ReceiverError,
        cms_host::gnss::register::RegisterError
    );
    None
}

/// The whole chain as one line: each cause's text, skipping a cause whose
/// text its outer message already carries (many library errors quote their
/// source), control characters escaped, at most 2000 characters.
pub fn message(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    cms_host::input::one_line(&line, 2000)
}

/// Prints the failure as one `error: ` line on stderr (nothing for a closed
/// output pipe) and returns its exit status.
pub fn report(e: &anyhow::Error) -> ExitCode {
    let broken_pipe = |c: &(dyn std::error::Error + 'static)| {
        c.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    };
    if e.chain().any(broken_pipe) {
        return ExitCode::SUCCESS;
    }
    // Not eprintln!: it panics if stderr is closed.
    let _ = writeln!(std::io::stderr(), "error: {}", message(e));
    ExitCode::from(status(e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statuses_follow_the_class() {
        assert_eq!(status(&anyhow::Error::new(Error::Input("bad".into()))), 2);
        assert_eq!(status(&anyhow::Error::new(Error::Device("gone".into())).context("listen")), 3);
        assert_eq!(status(&anyhow::Error::new(Usage("x".into()))), 2);
        assert_eq!(status(&anyhow::anyhow!("other")), 1);
        let out = Error::Output(std::io::Error::other("disk full"));
        assert_eq!(status(&anyhow::Error::new(out)), 1);
    }

    #[test]
    fn message_does_not_repeat_a_quoted_source() {
        let e = anyhow::Error::new(Error::Input("a.toml: bad key".into())).context("calibration");
        assert_eq!(message(&e), "calibration: a.toml: bad key");
        let out = anyhow::Error::new(Error::Output(std::io::Error::other("disk full")));
        assert_eq!(message(&out), "writing output: disk full");
    }
}
