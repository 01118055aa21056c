//! A pseudo-terminal pair: what a simulated device serves on, as a real
//! one serves on its serial line.

use std::fs::File;
use std::io;
use std::os::fd::{AsFd as _, OwnedFd};
use std::path::PathBuf;

use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use super::SimulateError;

/// A pseudo-terminal pair: the server's master side, and the slave that a
/// listener opens by its path.
pub struct Pty {
    pub(super) master: File,
    // Held open for the server's lifetime: with no slave descriptor open, the
    // pty hangs up (reads on the master fail with EIO) between two listener
    // connections, and the raw-mode settings would be lost.
    _slave: OwnedFd,
    path: PathBuf,
}

impl Pty {
    /// Opens a new pty, raw on the slave (no echo, no line editing, no CR/LF
    /// translation: the line discipline passes every byte through), the
    /// master non-blocking.
    pub fn open() -> Result<Pty, SimulateError> {
        let sys = |what: &'static str| move |e: nix::Error| SimulateError::Io(what, io::Error::from(e));
        let p = nix::pty::openpty(None, None).map_err(sys("openpty"))?;
        let mut t = tcgetattr(p.slave.as_fd()).map_err(sys("tcgetattr on the pty slave"))?;
        cfmakeraw(&mut t);
        tcsetattr(p.slave.as_fd(), SetArg::TCSANOW, &t).map_err(sys("tcsetattr on the pty slave"))?;
        let path = nix::unistd::ttyname(p.slave.as_fd()).map_err(sys("ttyname of the pty slave"))?;
        for fd in [p.master.as_fd(), p.slave.as_fd()] {
            nix::fcntl::fcntl(fd, nix::fcntl::FcntlArg::F_SETFD(nix::fcntl::FdFlag::FD_CLOEXEC))
                .map_err(sys("fcntl(FD_CLOEXEC)"))?;
        }
        let fl = nix::fcntl::fcntl(p.master.as_fd(), nix::fcntl::FcntlArg::F_GETFL).map_err(sys("fcntl(F_GETFL)"))?;
        let fl = nix::fcntl::OFlag::from_bits_retain(fl) | nix::fcntl::OFlag::O_NONBLOCK;
        nix::fcntl::fcntl(p.master.as_fd(), nix::fcntl::FcntlArg::F_SETFL(fl)).map_err(sys("fcntl(O_NONBLOCK)"))?;
        Ok(Pty { master: File::from(p.master), _slave: p.slave, path })
    }

    /// The slave's path (`/dev/pts/N`): what a listener opens.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Writes what the pty takes now (its master is non-blocking): a
    /// line nobody reads fills the buffer, and the rest is lost, as bytes
    /// a device sends into an unread serial line are.
    pub fn send(&mut self, bytes: &[u8]) -> io::Result<usize> {
        match io::Write::write(&mut self.master, bytes) {
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => Ok(0),
            r => r,
        }
    }
}
