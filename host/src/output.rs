//! Output files: written whole or not at all, and only as regular files.
//!
//! Every file the host writes (calibration files, images, plots, reports,
//! exports, the simulated head's stored calibration) goes through
//! [`write_atomically`]:
//!
//! 1. the target is checked: an existing directory, device, FIFO or socket
//!    is refused with a one-line error naming the path ([`check_target`]; a
//!    command calls it before its work too, so that a bad `--out` fails at
//!    once rather than after a long calibration);
//! 2. the content goes to a new temporary file in the target's own
//!    directory (`.NAME.PID-N.tmp`, created exclusively), which is flushed
//!    and `fsync`ed;
//! 3. the temporary file is renamed over the target, and the directory is
//!    `fsync`ed so that the rename itself survives a power loss.
//!
//! A reader therefore sees the old file or the new one, never half of one,
//! and a crash leaves at most a stray `.tmp` beside the target. A symbolic
//! link to a regular file is followed (the link stays, its target is
//! replaced); the replaced file's permission bits are kept.
//!
//! **Why refuse non-regular targets.** Renaming over a device node or a FIFO
//! would replace the node with a regular file (`--out /dev/full` did, and
//! reported success); writing into it instead would give up atomicity and
//! the check that the data arrived. `-` is the way to write to stdout, where
//! a command offers it (`export --out -`, by [`is_stdout`]); elsewhere `-`
//! is refused rather than taken as a file name.
//!
//! Folders of files written together (`analyze --report DIR`) are output
//! sets ([`set`]): written into a hidden folder beside the target and put in
//! place as a whole, never a mix of an old set and a new one.
//!
//! **Cost.** Two `fsync`s per file (the file and its directory): a few
//! milliseconds on a disk, nothing next to the work that produced the file.
//! The content is produced by the caller's closure straight into a buffered
//! writer, so large exports are not held in memory.

pub mod set;

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The target exists and is not a regular file.
    #[error("{}: {what}, not a regular file; refusing to write over it", path.display())]
    NotRegular {
        /// The target, as given.
        path: PathBuf,
        /// What it is ("a directory", "a character device", …).
        what: &'static str,
    },
    /// An output set's folder exists and is not a directory.
    #[error("{}: {what}, not a directory; refusing to write an output set over it", path.display())]
    NotADirectory {
        /// The target, as given.
        path: PathBuf,
        /// What it is ("a regular file", "a character device", …).
        what: &'static str,
    },
    /// An output set's folder holds something the set does not write:
    /// replacing the folder whole would delete it.
    #[error(
        "{}: the folder holds {entry}, which is no file of this output set; refusing to replace it \
         (give a new or empty folder, or one an earlier run of this command wrote)",
        path.display()
    )]
    NotASet {
        /// The folder, as given.
        path: PathBuf,
        /// The first entry that is not the set's.
        entry: String,
    },
    /// `-` (stdout) given for an output that cannot go there (a command whose
    /// stdout carries its report, a binary file).
    #[error("-: this output cannot go to stdout; give a file name")]
    Stdout,
    /// The target's directory does not exist (or is not a directory).
    #[error("cannot write {}: {source}", path.display())]
    NoDirectory {
        /// The target, as given.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// Writing, committing or renaming failed (a full disk, a closed pipe,
    /// no permission).
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The target, as given.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
}

impl crate::error::Classify for OutputError {
    fn class(&self) -> crate::Class {
        match self {
            // The user named something that cannot be an output.
            OutputError::NotRegular { .. }
            | OutputError::NotADirectory { .. }
            | OutputError::NotASet { .. }
            | OutputError::Stdout
            | OutputError::NoDirectory { .. } => crate::Class::Input,
            OutputError::Write { .. } => crate::Class::Output,
        }
    }
}

impl OutputError {
    /// The I/O error underneath, if any (a closed pipe is told by it).
    pub fn io(&self) -> Option<&io::Error> {
        match self {
            OutputError::NotRegular { .. }
            | OutputError::NotADirectory { .. }
            | OutputError::NotASet { .. }
            | OutputError::Stdout => None,
            OutputError::NoDirectory { source, .. } | OutputError::Write { source, .. } => Some(source),
        }
    }
}

/// What a non-regular file is, in words.
fn kind_of(meta: &fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt as _;
    let t = meta.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

/// Checks that `path` can be an output: it does not exist, or it is a
/// regular file (through symbolic links). Returns the path to replace (the
/// link's target for a symbolic link).
pub fn check_target(path: &Path) -> Result<PathBuf, OutputError> {
    if is_stdout(path) {
        // Not a file named `-`: a command that offers stdout (`export --out -`)
        // tests [`is_stdout`] first.
        return Err(OutputError::Stdout);
    }
    let not_regular = |what| OutputError::NotRegular { path: path.to_path_buf(), what };
    match fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(source) => return Err(OutputError::NoDirectory { path: path.to_path_buf(), source }),
        Ok(m) if m.file_type().is_symlink() => {
            return match fs::metadata(path) {
                Ok(t) if t.is_file() => {
                    fs::canonicalize(path).map_err(|source| OutputError::Write { path: path.to_path_buf(), source })
                }
                Ok(t) => Err(not_regular(kind_of(&t))),
                Err(_) => Err(not_regular("a symbolic link to nothing")),
            };
        }
        Ok(m) if !m.is_file() => return Err(not_regular(kind_of(&m))),
        Ok(_) => {}
    }
    if path.file_name().is_none() {
        // `..`, `/`: a directory by its name.
        return Err(not_regular("a directory"));
    }
    Ok(path.to_path_buf())
}

/// Writes `path` atomically (see the module docs): `write` produces the
/// content into a buffered writer (`Send`, as the Parquet writer needs);
/// on any error the target is untouched.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), OutputError>
where
    F: FnOnce(&mut (dyn Write + Send)) -> io::Result<()>,
{
    let mut f = AtomicFile::create(path)?;
    match write(&mut f) {
        Ok(()) => f.commit(),
        Err(e) => Err(f.failed(e)),
    }
}

/// A file written atomically, as [`write_atomically`] writes one, for
/// several files filled at once (one walk along a line feeding each): a
/// temporary file beside the target, renamed over it by
/// [`AtomicFile::commit`]; dropped before that, it is removed and the
/// target is untouched.
pub struct AtomicFile {
    /// The target, as given.
    path: PathBuf,
    target: PathBuf,
    dir: PathBuf,
    tmp: PathBuf,
    out: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates the temporary file for `path` (checked as a target first:
    /// never a device, a FIFO or a directory).
    pub fn create(path: &Path) -> Result<AtomicFile, OutputError> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let target = check_target(path)?;
        let dir = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{}-{n}.tmp", std::process::id()));
        let file = OpenOptions::new().write(true).create_new(true).open(&tmp).map_err(|source| {
            if matches!(source.kind(), io::ErrorKind::NotFound | io::ErrorKind::NotADirectory) {
                OutputError::NoDirectory { path: path.to_path_buf(), source }
            } else {
                OutputError::Write { path: path.to_path_buf(), source }
            }
        })?;
        let mut f = AtomicFile { path: path.to_path_buf(), target, dir, tmp, out: None };
        // Keep the mode of the file being replaced (an existing 0600 stays 0600).
        if let Ok(old) = fs::metadata(&f.target) {
            file.set_permissions(old.permissions()).map_err(|e| f.failed(e))?;
        }
        f.out = Some(BufWriter::with_capacity(256 << 10, file));
        Ok(f)
    }

    /// `e`, a failure while writing, as this file's error.
    pub fn failed(&self, source: io::Error) -> OutputError {
        OutputError::Write { path: self.path.clone(), source }
    }

    /// Flushes, syncs and renames the file over its target.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let out = self.out.take();
        let result = (|| {
            let file = out.ok_or_else(|| io::Error::other("already committed"))?;
            let file = file.into_inner().map_err(io::IntoInnerError::into_error)?;
            file.sync_all()?;
            drop(file);
            fs::rename(&self.tmp, &self.target)?;
            sync_dir(&self.dir)
        })();
        result.map_err(|e| {
            let _ = fs::remove_file(&self.tmp);
            self.failed(e)
        })
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match &mut self.out {
            Some(o) => o.write(buf),
            None => Err(io::Error::other("already committed")),
        }
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        match &mut self.out {
            Some(o) => o.write_all(buf),
            None => Err(io::Error::other("already committed")),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        self.out.as_mut().map_or(Ok(()), Write::flush)
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.out.take().is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// Commits a directory's entries (the rename). File systems that cannot
/// sync a directory say so with `EINVAL`; that is not a failure.
fn sync_dir(dir: &Path) -> io::Result<()> {
    match File::open(dir).and_then(|d| d.sync_all()) {
        Err(e) if e.kind() == io::ErrorKind::InvalidInput => Ok(()),
        r => r,
    }
}

/// Whether `path` is `-`, stdout.
pub fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_whole_files_and_refuses_what_is_not_one() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a.txt");
        write_atomically(&f, |w| w.write_all(b"one")).unwrap();
        write_atomically(&f, |w| w.write_all(b"two")).unwrap();
        assert_eq!(fs::read(&f).unwrap(), b"two");

        // A failing producer leaves the old file and no temporary.
        let e = write_atomically(&f, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("disk full"))
        })
        .unwrap_err();
        assert_eq!(e.to_string(), format!("cannot write {}: disk full", f.display()));
        assert_eq!(fs::read(&f).unwrap(), b"two");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1, "no temporary left");

        // A link to a file: the target is replaced, the link stays.
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink(&f, &link).unwrap();
        write_atomically(&link, |w| w.write_all(b"three")).unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(fs::read(&f).unwrap(), b"three");

        // Not regular files.
        let e = write_atomically(dir.path(), |w| w.write_all(b"x")).unwrap_err();
        assert!(e.to_string().ends_with("a directory, not a regular file; refusing to write over it"), "{e}");
        let e = check_target(Path::new("/dev/null")).unwrap_err();
        assert_eq!(e.to_string(), "/dev/null: a character device, not a regular file; refusing to write over it");
        assert_eq!(crate::error::Classify::class(&e), crate::Class::Input);
        let dangling = dir.path().join("dangling");
        std::os::unix::fs::symlink(dir.path().join("nothing"), &dangling).unwrap();
        assert!(check_target(&dangling).unwrap_err().to_string().contains("a symbolic link to nothing"));
        assert!(matches!(check_target(Path::new("-")), Err(OutputError::Stdout)));
        let e = write_atomically(&dir.path().join("no/such/dir.txt"), |w| w.write_all(b"x")).unwrap_err();
        assert!(matches!(e, OutputError::NoDirectory { .. }), "{e}");
    }

    #[test]
    fn keeps_the_mode_of_the_replaced_file() {
        use std::os::unix::fs::PermissionsExt as _;
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("secret");
        fs::write(&f, b"x").unwrap();
        fs::set_permissions(&f, fs::Permissions::from_mode(0o600)).unwrap();
        write_atomically(&f, |w| w.write_all(b"y")).unwrap();
        assert_eq!(fs::metadata(&f).unwrap().permissions().mode() & 0o777, 0o600);
    }
}

/// Whether `file` lies directly in the folder `dir` (through links: by
/// device and inode, not by the names given). An output set written into a
/// folder that holds one of its inputs could replace that input (`analyze
/// clob/profile.csv --report clob` writes a `profile.csv`), so commands
/// that write a set refuse such a folder.
pub fn folder_holds(dir: &Path, file: &Path) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    let parent = fs::canonicalize(file).ok().and_then(|f| f.parent().map(Path::to_path_buf));
    match (parent.and_then(|p| fs::metadata(p).ok()), fs::metadata(dir)) {
        (Some(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// `s` with every character that would act rather than print — control
/// characters (C0 with ESC, DEL, C1) and the bidirectional overrides — as
/// its `\u{…}` escape: text a user or a file supplied (a survey's notes, a
/// line's name) then cannot move the terminal's cursor, change its colours
/// or reorder what a report shows around it.
pub fn printable(s: &str) -> std::borrow::Cow<'_, str> {
    let acts = |c: char| c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
    if !s.chars().any(acts) {
        return s.into();
    }
    s.chars().map(|c| if acts(c) { c.escape_unicode().to_string() } else { c.to_string() }).collect::<String>().into()
}

#[cfg(test)]
mod printable_tests {
    use super::printable;

    #[test]
    fn escapes_are_shown_not_acted_on() {
        assert_eq!(printable("after grinding, pass 2 – Nordstrecke"), "after grinding, pass 2 – Nordstrecke");
        assert_eq!(printable("a\u{1b}[2Jb\nc\u{7f}\u{9b}d\u{202e}e"), "a\\u{1b}[2Jb\\u{a}c\\u{7f}\\u{9b}d\\u{202e}e");
    }
}
