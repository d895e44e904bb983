//! Output files, written safely: every file oavm writes (a packed `.oavm`, a HITS or OCCL
//! file, an image) goes through [`Output`].
//!
//! - **Checked before any work.** [`Output::create`] resolves the path through symlinks (a
//!   symlink is written through: its target is replaced, the link stays), refuses a target that
//!   is a directory, a FIFO, a device or a socket (never replaced, never written into), refuses
//!   a target that is one of the command's inputs (same device and inode), and opens the new
//!   file in the target's directory, so an unwritable place fails at once, not after the work.
//! - **Atomic.** The new file is unnamed (`O_TMPFILE`) until [`Output::commit`]: flushed to
//!   disk, then given its name, replacing the old file in one `rename`; then the directory is
//!   synced, so the new name survives a crash. Until then the old file is untouched, and an
//!   error, a panic or a kill leaves nothing behind: an unnamed file vanishes with its
//!   descriptor.
//! - **No debris.** Replacing an existing file needs a name for the new one just before the
//!   `rename` (`linkat` cannot replace): `.NAME.oavm-tmp-PID-N` in the same directory, which
//!   lives for two system calls. Where `O_TMPFILE` is not supported (some file systems), the
//!   new file has that name from the start. Either way, every `create` removes such files
//!   left in its directory by processes that no longer exist.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::{FileTypeExt, MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::Error;

/// Symlinks followed before giving up (the kernel's own limit is 40).
const MAX_SYMLINKS: usize = 40;

/// A file being written: unnamed until [`Output::commit`]. See the module documentation.
pub struct Output {
    /// The path as the user gave it (errors name it).
    path: PathBuf,
    /// Where the file goes: `path` with symlinks resolved.
    target: PathBuf,
    file: File,
    /// The name the new file has had from the start, where `O_TMPFILE` is not supported;
    /// removed on drop unless committed.
    named: Option<PathBuf>,
}

impl Output {
    /// Checks that `path` can be written without harm and opens the new file beside its
    /// target. `inputs` are the files the command reads: the output may not be any of them.
    pub fn create(path: &Path, inputs: &[&Path]) -> Result<Output, Error> {
        let err = |what: String| Error::Output {
            path: path.to_owned(),
            what,
        };
        let target = resolve(path).map_err(|e| err(e.to_string()))?;
        match std::fs::metadata(&target) {
            Ok(meta) => {
                let kind = meta.file_type();
                let refuse = if kind.is_dir() {
                    Some("a directory")
                } else if kind.is_fifo() {
                    Some("a FIFO")
                } else if kind.is_char_device() || kind.is_block_device() {
                    Some("a device")
                } else if kind.is_socket() {
                    Some("a socket")
                } else {
                    None
                };
                if let Some(kind) = refuse {
                    return Err(err(format!(
                        "is {kind}, not a regular file: oavm writes regular files only, and \
                         never replaces anything else"
                    )));
                }
                for input in inputs {
                    if let Ok(m) = std::fs::metadata(input)
                        && (m.dev(), m.ino()) == (meta.dev(), meta.ino())
                    {
                        return Err(err(format!(
                            "is the input {}; writing it would destroy the input: choose \
                             another output path",
                            input.display()
                        )));
                    }
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(err(format!("cannot inspect it: {e}"))),
        }
        let dir = parent(&target);
        remove_stale(&dir);
        let (file, named) = match open_unnamed(&dir) {
            Ok(file) => (file, None),
            Err(_) => {
                let name = temp_name(&target);
                let file = OpenOptions::new()
                    .read(true)
                    .write(true)
                    .create_new(true)
                    .mode(0o666)
                    .open(&name)
                    .map_err(|e| err(format!("cannot create a file in {}: {e}", dir.display())))?;
                (file, Some(name))
            }
        };
        Ok(Output {
            path: path.to_owned(),
            target,
            file,
            named,
        })
    }

    /// The path as given.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The new file, to write into (from its start).
    pub fn file(&mut self) -> &mut File {
        &mut self.file
    }

    /// Flushes the new file to disk, gives it its name (replacing the old file, if any, in one
    /// `rename`) and syncs the directory.
    pub fn commit(mut self) -> Result<(), Error> {
        let err = |what: String| Error::Output {
            path: self.path.clone(),
            what,
        };
        self.file
            .sync_all()
            .map_err(|e| err(format!("cannot write it: {e}")))?;
        match self.named.take() {
            Some(name) => {
                if let Err(e) = std::fs::rename(&name, &self.target) {
                    let _ = std::fs::remove_file(&name);
                    return Err(err(format!("cannot rename the new file into place: {e}")));
                }
            }
            None => match crate::os::link_unnamed(&self.file, &self.target) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let name = temp_name(&self.target);
                    crate::os::link_unnamed(&self.file, &name)
                        .map_err(|e| err(format!("cannot name the new file: {e}")))?;
                    if let Err(e) = std::fs::rename(&name, &self.target) {
                        let _ = std::fs::remove_file(&name);
                        return Err(err(format!("cannot rename the new file into place: {e}")));
                    }
                }
                Err(e) => return Err(err(format!("cannot name the new file: {e}"))),
            },
        }
        let dir = parent(&self.target);
        File::open(&dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| err(format!("cannot sync its directory {}: {e}", dir.display())))
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        if let Some(name) = &self.named {
            let _ = std::fs::remove_file(name);
        }
    }
}

/// Writes `bytes` to `path` through an [`Output`] (see the module documentation).
pub fn write_file(path: &Path, bytes: &[u8], inputs: &[&Path]) -> Result<(), Error> {
    let mut out = Output::create(path, inputs)?;
    out.file().write_all(bytes).map_err(|e| Error::Output {
        path: path.to_owned(),
        what: format!("cannot write it: {e}"),
    })?;
    out.commit()
}

/// `path` with every symlink along the last component resolved (a dangling link resolves to
/// the file it names, which will be created).
fn resolve(path: &Path) -> std::io::Result<PathBuf> {
    let mut p = path.to_owned();
    for _ in 0..MAX_SYMLINKS {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = std::fs::read_link(&p)?;
                p = if to.is_absolute() {
                    to
                } else {
                    parent(&p).join(to)
                };
            }
            _ => return Ok(p),
        }
    }
    Err(std::io::Error::other(format!(
        "more than {MAX_SYMLINKS} symbolic links"
    )))
}

/// The directory of `path` (`.` for a bare name).
fn parent(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    }
}

/// An unnamed file in `dir` (`O_TMPFILE`, linkable: no `O_EXCL`), readable and writable,
/// with the permissions of a new file (0666 less the umask).
fn open_unnamed(dir: &Path) -> std::io::Result<File> {
    OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_TMPFILE)
        .mode(0o666)
        .open(dir)
}

/// The prefix of every name oavm gives a file it has not finished (after a leading `.` and
/// the target's name): `.NAME.oavm-tmp-PID-N`.
const TEMP_MARK: &str = ".oavm-tmp-";

/// A name for a new file beside `target`, unique in this process.
fn temp_name(target: &Path) -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    parent(target).join(format!(".{name}{TEMP_MARK}{}-{n}", std::process::id()))
}

/// Removes the unfinished files (`.NAME.oavm-tmp-PID-N`) that processes no longer running
/// left in `dir`. Best effort: errors are ignored.
fn remove_stale(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let Some((_, rest)) = name.rsplit_once(TEMP_MARK) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        let alive = Path::new("/proc").join(pid.to_string()).exists();
        if name.starts_with('.') && !alive && pid != std::process::id() {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().expect("temp dir")
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn writes_atomically_and_leaves_nothing_else() {
        let d = dir();
        let p = d.path().join("out.bin");
        write_file(&p, b"one", &[]).unwrap();
        write_file(&p, b"two", &[]).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(names(d.path()), vec!["out.bin"]);
        // Dropped before commit: nothing is written, the old file stays.
        let mut o = Output::create(&p, &[]).unwrap();
        o.file().write_all(b"three").unwrap();
        drop(o);
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(names(d.path()), vec!["out.bin"]);
    }

    #[test]
    fn writes_through_symlinks() {
        let d = dir();
        let real = d.path().join("real.bin");
        let link = d.path().join("link.bin");
        std::fs::write(&real, b"old").unwrap();
        std::os::unix::fs::symlink("real.bin", &link).unwrap();
        write_file(&link, b"new", &[]).unwrap();
        assert!(std::fs::symlink_metadata(&link).unwrap().is_symlink());
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
        // A dangling link creates its target.
        let dangling = d.path().join("dangling.bin");
        std::os::unix::fs::symlink("made.bin", &dangling).unwrap();
        write_file(&dangling, b"x", &[]).unwrap();
        assert_eq!(std::fs::read(d.path().join("made.bin")).unwrap(), b"x");
    }

    #[test]
    fn refuses_inputs_and_what_is_not_a_regular_file() {
        let d = dir();
        let input = d.path().join("in.ply");
        std::fs::write(&input, b"mesh").unwrap();
        let e = Output::create(&input, &[&input]).err().unwrap().to_string();
        assert!(e.contains("is the input"), "{e}");
        // The same file under another name (a hard link, a symlink) too.
        let hard = d.path().join("hard.ply");
        std::fs::hard_link(&input, &hard).unwrap();
        assert!(Output::create(&hard, &[&input]).is_err());
        let sym = d.path().join("sym.ply");
        std::os::unix::fs::symlink(&input, &sym).unwrap();
        assert!(Output::create(&sym, &[&input]).is_err());
        assert_eq!(std::fs::read(&input).unwrap(), b"mesh");

        let e = Output::create(d.path(), &[]).err().unwrap().to_string();
        assert!(e.contains("a directory"), "{e}");
        let fifo = d.path().join("fifo");
        let status = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo");
        assert!(status.success());
        let e = Output::create(&fifo, &[]).err().unwrap().to_string();
        assert!(e.contains("a FIFO"), "{e}");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        let e = Output::create(Path::new("/dev/null"), &[])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("a device"), "{e}");
        let e = Output::create(&d.path().join("no/such/dir/x"), &[])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("no/such/dir/x"), "{e}");
    }

    #[test]
    fn removes_what_dead_processes_left() {
        let d = dir();
        // No process has pid 4194304 + 1 (above Linux's largest pid).
        let stale = d.path().join(".out.bin.oavm-tmp-4194305-0");
        std::fs::write(&stale, b"debris").unwrap();
        let other = d.path().join("keep.oavm-tmp-4194305-0");
        std::fs::write(&other, b"not ours: no leading dot").unwrap();
        write_file(&d.path().join("out.bin"), b"x", &[]).unwrap();
        assert_eq!(names(d.path()), vec!["keep.oavm-tmp-4194305-0", "out.bin"]);
    }
}
