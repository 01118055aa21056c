//! Output sets: a folder of files (`analyze --report DIR`, `--parquet DIR`)
//! put in place as a whole, so that the folder holds the old set or the new
//! one, never a mix of both.
//!
//! [`write_set`] (or [`OutputSet`] by hand):
//!
//! 1. the target is checked ([`check_set`]): it does not exist, or it is a
//!    folder (through a symbolic link) that holds only regular files of
//!    names this kind of set writes — a folder with anything else (a
//!    recording, a sub-folder, someone's notes) is refused, since replacing
//!    it whole would delete what the user put there;
//! 2. the files go into a new hidden folder beside the target, on the same
//!    file system (`.NAME.PID-N.tmp`, created exclusively), each written by
//!    [`super::write_atomically`] (regular files only, `fsync`ed);
//! 3. the target is checked again, then the new folder takes its place:
//!    renamed onto a missing target; exchanged with an existing one in one
//!    `renameat2(RENAME_EXCHANGE)`; where the file system cannot exchange,
//!    the old folder is renamed away (`.NAME.PID-N.old`) and the new one
//!    renamed in. The parent folder is `fsync`ed, then the old set (now at
//!    the hidden name) is removed.
//!
//! **What a crash leaves**, at each step: during 1–2, the target as it was
//! (the old set whole, or nothing) and a hidden `.NAME.…tmp` folder beside
//! it with part of the new set; at the exchange, nothing in between (it is
//! one system call); after it, the new set whole and the old set whole or
//! in part in the hidden `.tmp` folder. Without the exchange, a crash
//! between the two renames leaves no target, the old set whole in
//! `.NAME.…old` and the new set whole in `.NAME.…tmp` (rename either back).
//! The hidden folders are never read; remove them by hand. An error (not a
//! crash) removes the hidden folder and leaves the target as it was.
//!
//! **Cost.** Besides each file's two `fsync`s, one `fsync` of the parent
//! folder and the removal of the old set: milliseconds.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::{OutputError, is_stdout, kind_of, sync_dir};

/// Checks that `path` can take an output set whose files are the names
/// `owns` accepts: it does not exist (its parent may not either), or it is
/// a folder (through symbolic links) holding only regular files of such
/// names (and the hidden temporaries of an interrupted file write). Returns
/// the folder to replace (the link's target for a symbolic link).
pub fn check_set(path: &Path, owns: fn(&str) -> bool) -> Result<PathBuf, OutputError> {
    if is_stdout(path) {
        return Err(OutputError::Stdout);
    }
    let meta = match fs::metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            if fs::symlink_metadata(path).is_ok() {
                return Err(OutputError::NotADirectory {
                    path: path.to_path_buf(),
                    what: "a symbolic link to nothing",
                });
            }
            if path.file_name().is_none() {
                return Err(OutputError::NotADirectory { path: path.to_path_buf(), what: "not a folder name" });
            }
            return Ok(path.to_path_buf());
        }
        Err(source) => return Err(OutputError::NoDirectory { path: path.to_path_buf(), source }),
        Ok(m) => m,
    };
    if !meta.is_dir() {
        let what = if meta.is_file() { "a regular file" } else { kind_of(&meta) };
        return Err(OutputError::NotADirectory { path: path.to_path_buf(), what });
    }
    let resolved = fs::canonicalize(path).map_err(|source| OutputError::Write { path: path.to_path_buf(), source })?;
    if resolved.parent().is_none() {
        return Err(OutputError::NotADirectory { path: path.to_path_buf(), what: "the root folder" });
    }
    let entries = fs::read_dir(&resolved).map_err(|source| OutputError::Write { path: path.to_path_buf(), source })?;
    for entry in entries {
        let entry = entry.map_err(|source| OutputError::Write { path: path.to_path_buf(), source })?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let regular = entry.file_type().is_ok_and(|t| t.is_file());
        if !(regular && (owns(&name) || is_file_temporary(&name, owns))) {
            return Err(OutputError::NotASet { path: path.to_path_buf(), entry: name });
        }
    }
    Ok(resolved)
}

/// `.NAME.PID-N.tmp` of an owned `NAME`: what an interrupted
/// [`super::write_atomically`] leaves.
fn is_file_temporary(name: &str, owns: fn(&str) -> bool) -> bool {
    let Some(inner) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else { return false };
    inner.rsplit_once('.').is_some_and(|(file, id)| owns(file) && id.chars().all(|c| c.is_ascii_digit() || c == '-'))
}

/// An output set being written: files go into [`OutputSet::dir`], and
/// [`OutputSet::commit`] puts the folder in place. Dropped uncommitted, it
/// removes its folder and leaves the target as it was.
#[derive(Debug)]
pub struct OutputSet {
    /// As the user gave it (for messages).
    given: PathBuf,
    /// The folder to replace (a link's target resolved).
    target: PathBuf,
    /// The hidden folder beside it that receives the files.
    staging: PathBuf,
    owns: fn(&str) -> bool,
    committed: bool,
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// A hidden name beside `target`: `.NAME.PID-N.SUFFIX`.
fn hidden_beside(target: &Path, suffix: &str) -> PathBuf {
    let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    target.with_file_name(format!(".{name}.{}-{n}.{suffix}", std::process::id()))
}

impl OutputSet {
    /// Checks `path` ([`check_set`]) and creates the hidden folder beside
    /// it (and the target's missing parents).
    pub fn begin(path: &Path, owns: fn(&str) -> bool) -> Result<OutputSet, OutputError> {
        let target = check_set(path, owns)?;
        let target = if target.is_absolute() { target } else { std::path::absolute(&target).unwrap_or(target) };
        let no_dir = |source| OutputError::NoDirectory { path: path.to_path_buf(), source };
        let parent = target.parent().ok_or_else(|| no_dir(io::Error::other("no parent folder")))?;
        fs::create_dir_all(parent).map_err(no_dir)?;
        let staging = hidden_beside(&target, "tmp");
        fs::create_dir(&staging).map_err(|source| OutputError::Write { path: path.to_path_buf(), source })?;
        let set = OutputSet { given: path.to_path_buf(), target, staging, owns, committed: false };
        // A replaced folder keeps its permission bits.
        if let Ok(old) = fs::metadata(&set.target) {
            fs::set_permissions(&set.staging, old.permissions()).map_err(|e| set.err(e))?;
        }
        Ok(set)
    }

    /// Where the set's files go until the commit.
    pub fn dir(&self) -> &Path {
        &self.staging
    }

    fn err(&self, source: io::Error) -> OutputError {
        OutputError::Write { path: self.given.clone(), source }
    }

    /// Puts the set in place of the target (see the module docs): the
    /// target then holds exactly the files written into [`Self::dir`].
    pub fn commit(mut self) -> Result<(), OutputError> {
        // What the target holds may have changed during the work.
        check_set(&self.given, self.owns)?;
        sync_dir(&self.staging).map_err(|e| self.err(e))?;
        let parent = self.target.parent().unwrap_or(Path::new(".")).to_path_buf();
        let old = if fs::symlink_metadata(&self.target).is_ok() {
            match exchange(&self.staging, &self.target) {
                // The old set is at the hidden name now.
                Ok(()) => Some(self.staging.clone()),
                Err(e) if matches!(e.raw_os_error(), Some(22 | 38 | 95)) => {
                    // EINVAL, ENOSYS, EOPNOTSUPP: this file system cannot exchange.
                    let away = hidden_beside(&self.target, "old");
                    fs::rename(&self.target, &away).map_err(|e| self.err(e))?;
                    if let Err(e) = fs::rename(&self.staging, &self.target) {
                        // Put the old set back: the target stays as it was.
                        let _ = fs::rename(&away, &self.target);
                        return Err(self.err(e));
                    }
                    Some(away)
                }
                Err(e) => return Err(self.err(e)),
            }
        } else {
            fs::rename(&self.staging, &self.target).map_err(|e| self.err(e))?;
            None
        };
        self.committed = true;
        sync_dir(&parent).map_err(|e| self.err(e))?;
        if let Some(old) = old {
            fs::remove_dir_all(&old).map_err(|e| self.err(e))?;
        }
        Ok(())
    }
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}

/// Swaps two paths in one step (Linux `renameat2`; elsewhere "not supported").
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use nix::fcntl::{AT_FDCWD, RenameFlags, renameat2};
        renameat2(AT_FDCWD, a, AT_FDCWD, b, RenameFlags::RENAME_EXCHANGE).map_err(io::Error::from)
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        let _ = (a, b);
        Err(io::Error::from_raw_os_error(38))
    }
}

/// Writes an output set into `path` (see the module docs): `write` puts
/// its files into the folder it is given; on its error, or any other,
/// the target is left as it was. Errors name the files by the target's
/// path, not the hidden folder's.
pub fn write_set(
    path: &Path,
    owns: fn(&str) -> bool,
    write: impl FnOnce(&Path) -> Result<(), crate::Error>,
) -> Result<(), crate::Error> {
    let set = OutputSet::begin(path, owns)?;
    if let Err(e) = write(set.dir()) {
        let (staging, given) = (set.dir().display().to_string(), path.display().to_string());
        let msg = e.to_string();
        return Err(if msg.contains(&staging) {
            // Writing into the hidden folder failed: an output failure.
            crate::Error::Output(io::Error::other(msg.replace(&staging, &given)))
        } else {
            e
        });
    }
    Ok(set.commit()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn owns(name: &str) -> bool {
        name.starts_with("part") && name.ends_with(".txt")
    }

    fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
        fs::read_dir(dir)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (e.file_name().to_string_lossy().into_owned(), fs::read(e.path()).unwrap())
            })
            .collect()
    }

    fn put(dir: &Path, name: &str, text: &str) -> Result<(), crate::Error> {
        Ok(super::super::write_atomically(&dir.join(name), |w| w.write_all(text.as_bytes()))?)
    }

    /// A set of `n` files `partK.txt` holding `tag`, failing after `fail_after` files.
    fn set_of(path: &Path, tag: &str, n: usize, fail_after: Option<usize>) -> Result<(), crate::Error> {
        write_set(path, owns, |d| {
            for k in 0..n {
                if fail_after == Some(k) {
                    let path = d.join(format!("part{k}.txt"));
                    return Err(OutputError::Write { path, source: io::Error::other("disk full") }.into());
                }
                put(d, &format!("part{k}.txt"), tag)?;
            }
            Ok(())
        })
    }

    #[test]
    fn a_set_is_replaced_whole_and_a_failed_one_leaves_the_old() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("deep/out");
        set_of(&out, "old", 4, None).unwrap();
        let old = files(&out);
        assert_eq!(old.len(), 4);
        // A failure after some files, at each point: the old set whole, nothing beside it.
        for k in 0..3 {
            let e = set_of(&out, "new", 3, Some(k)).unwrap_err();
            let named = format!("cannot write {}/part{k}.txt: disk full", out.display());
            assert!(e.to_string().ends_with(&named) && !e.to_string().contains(".out."), "{e}");
            assert_eq!(files(&out), old, "after {k} files");
            assert_eq!(fs::read_dir(root.path().join("deep")).unwrap().count(), 1, "no hidden folder left");
        }
        // A smaller new set leaves no file of the old one.
        set_of(&out, "new", 2, None).unwrap();
        let new = files(&out);
        assert_eq!(new.keys().collect::<Vec<_>>(), ["part0.txt", "part1.txt"]);
        assert!(new.values().all(|v| v == b"new"));
        assert_eq!(fs::read_dir(root.path().join("deep")).unwrap().count(), 1);
    }

    #[test]
    fn a_folder_with_anything_else_is_never_replaced() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("out");
        fs::create_dir(&out).unwrap();
        fs::write(out.join("part0.txt"), "old").unwrap();
        fs::write(out.join(".part0.txt.77-3.tmp"), "half").unwrap();
        fs::write(out.join("notes.md"), "mine").unwrap();
        let e = set_of(&out, "new", 1, None).unwrap_err();
        let inner = e.downcast_ref::<OutputError>();
        assert!(matches!(inner, Some(OutputError::NotASet { entry, .. }) if entry == "notes.md"), "{e}");
        assert_eq!(e.class(), crate::Class::Input);
        fs::remove_file(out.join("notes.md")).unwrap();
        fs::create_dir(out.join("part9.txt")).unwrap();
        let e = set_of(&out, "new", 1, None).unwrap_err();
        assert!(matches!(e.downcast_ref(), Some(OutputError::NotASet { .. })), "{e}");
        fs::remove_dir(out.join("part9.txt")).unwrap();
        // What is left is a set (with an interrupted file's temporary): replaced.
        set_of(&out, "new", 1, None).unwrap();
        assert_eq!(files(&out).keys().collect::<Vec<_>>(), ["part0.txt"]);

        let file = root.path().join("file");
        fs::write(&file, "x").unwrap();
        let e = check_set(&file, owns).unwrap_err();
        assert!(
            e.to_string().ends_with("a regular file, not a directory; refusing to write an output set over it"),
            "{e}"
        );
        assert!(matches!(check_set(Path::new("/dev/null"), owns), Err(OutputError::NotADirectory { .. })));
        assert!(matches!(check_set(Path::new("-"), owns), Err(OutputError::Stdout)));
        assert!(matches!(check_set(Path::new("/"), owns), Err(OutputError::NotADirectory { .. })));
    }

    #[test]
    fn a_link_to_a_set_keeps_the_link() {
        let root = tempfile::tempdir().unwrap();
        let real = root.path().join("real");
        set_of(&real, "old", 2, None).unwrap();
        let link = root.path().join("link");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        set_of(&link, "new", 1, None).unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(files(&real).into_iter().collect::<Vec<_>>(), [("part0.txt".to_string(), b"new".to_vec())]);
        // A set given by a dangling link is refused, not created elsewhere.
        let dangling = root.path().join("dangling");
        std::os::unix::fs::symlink(root.path().join("nothing"), &dangling).unwrap();
        assert!(matches!(check_set(&dangling, owns), Err(OutputError::NotADirectory { .. })));
    }
}
