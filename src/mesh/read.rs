//! Reading an untrusted file whole into memory: bounded in size before a byte is read, and
//! checked not to have changed while it was read.
//!
//! - The open file's size (its metadata) is checked against the limit first, so an oversized
//!   file is refused without reading it; the read then goes through `take(limit + 1)`, so a file
//!   that grows meanwhile cannot take more than the limit either.
//! - The open file's [`Stamp`] (length, status-change time, inode) is taken before and after
//!   the read: a file rewritten, appended to or truncated while we read it would give bytes
//!   from two versions, which no parser can tell from a valid file.

use std::fs::{File, Metadata};
use std::io::{self, Read};
use std::path::Path;

/// What changes when a file is written: its length, its status-change time (`ctime`, which a
/// write or a truncation sets, and which no one can set back), and its inode. Elsewhere than on
/// Unix, the modification time stands in for `ctime` and there is no inode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Stamp {
    len: u64,
    changed: (i64, i64),
    inode: u64,
}

impl Stamp {
    pub(crate) fn of(meta: &Metadata) -> Stamp {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            Stamp {
                len: meta.len(),
                changed: (meta.ctime(), meta.ctime_nsec()),
                inode: meta.ino(),
            }
        }
        #[cfg(not(unix))]
        {
            let since = meta
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .unwrap_or_default();
            Stamp {
                len: meta.len(),
                changed: (since.as_secs() as i64, i64::from(since.subsec_nanos())),
                inode: 0,
            }
        }
    }
}

/// Why a bounded read failed.
#[derive(Debug)]
pub(crate) enum ReadError {
    Io(io::Error),
    /// The file holds more than the limit: `bytes` by its metadata, or more than the limit
    /// read (a file whose metadata does not give its size).
    TooLarge {
        bytes: u64,
    },
    /// The file's [`Stamp`] differs after the read.
    Changed,
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "{e}"),
            ReadError::TooLarge { bytes } => write!(f, "{bytes} bytes, more than this run reads"),
            ReadError::Changed => f.write_str("it changed while it was read"),
        }
    }
}

impl From<io::Error> for ReadError {
    fn from(e: io::Error) -> ReadError {
        ReadError::Io(e)
    }
}

/// Reads the whole of `path`, at most `limit` bytes (see the module documentation).
pub(crate) fn read_file(path: &Path, limit: u64) -> Result<Vec<u8>, ReadError> {
    let mut file = File::open(path)?;
    if file.metadata()?.is_dir() {
        return Err(io::Error::new(io::ErrorKind::IsADirectory, "is a directory").into());
    }
    read_unchanged(&mut file, limit, |f: &File| Ok(Stamp::of(&f.metadata()?)))
}

/// Reads `file` to its end, at most `limit` bytes, between two stamps that must agree.
fn read_unchanged<F: Read>(
    file: &mut F,
    limit: u64,
    stamp: impl Fn(&F) -> io::Result<Stamp>,
) -> Result<Vec<u8>, ReadError> {
    let before = stamp(file)?;
    if before.len > limit {
        return Err(ReadError::TooLarge { bytes: before.len });
    }
    let mut bytes = Vec::new();
    // Within the limit; an allocation that fails is an error, not an abort.
    bytes
        .try_reserve_exact(usize::try_from(before.len).unwrap_or(usize::MAX))
        .map_err(|e| io::Error::new(io::ErrorKind::OutOfMemory, e))?;
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if stamp(file)? != before {
        return Err(ReadError::Changed);
    }
    if bytes.len() as u64 > limit {
        return Err(ReadError::TooLarge {
            bytes: bytes.len() as u64,
        });
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use std::cell::Cell;
    use std::io::{Cursor, Write};

    use super::*;

    fn stamp(len: u64, changed: i64) -> Stamp {
        Stamp {
            len,
            changed: (changed, 0),
            inode: 7,
        }
    }

    #[test]
    fn a_file_within_the_limit_is_read_whole() {
        let mut c = Cursor::new(b"hello".to_vec());
        let got = read_unchanged(&mut c, 5, |_| Ok(stamp(5, 1))).unwrap();
        assert_eq!(got, b"hello");
    }

    #[test]
    fn a_file_over_the_limit_is_refused_before_reading() {
        let mut c = Cursor::new(b"hello".to_vec());
        let e = read_unchanged(&mut c, 4, |_| Ok(stamp(5, 1))).unwrap_err();
        assert!(matches!(e, ReadError::TooLarge { bytes: 5 }), "{e:?}");
        assert_eq!(c.position(), 0, "not a byte read");
    }

    #[test]
    fn a_file_longer_than_its_metadata_stops_past_the_limit() {
        // A file that says 3 bytes (or grew unseen): at most limit + 1 bytes are read.
        let mut c = Cursor::new(vec![b'x'; 1000]);
        let e = read_unchanged(&mut c, 10, |_| Ok(stamp(3, 1))).unwrap_err();
        assert!(matches!(e, ReadError::TooLarge { bytes: 11 }), "{e:?}");
        assert_eq!(c.position(), 11);
    }

    #[test]
    fn a_file_changed_during_the_read_is_an_error() {
        // The second stamp (after the read) differs: the file was written meanwhile.
        let calls = Cell::new(0);
        let mut c = Cursor::new(b"hello".to_vec());
        let e = read_unchanged(&mut c, 100, |_| {
            calls.set(calls.get() + 1);
            Ok(stamp(5, calls.get()))
        })
        .unwrap_err();
        assert!(matches!(e, ReadError::Changed), "{e:?}");
        assert_eq!(calls.get(), 2);
    }

    #[test]
    fn stamps_see_appends_and_rewrites_of_an_open_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.ply");
        std::fs::write(&path, b"one").unwrap();
        let file = File::open(&path).unwrap();
        let first = Stamp::of(&file.metadata().unwrap());
        assert_eq!(first, Stamp::of(&file.metadata().unwrap()));
        assert_eq!(first.len, 3);
        // Appended through another handle: the open file's stamp changes.
        std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap()
            .write_all(b" two")
            .unwrap();
        let second = Stamp::of(&file.metadata().unwrap());
        assert_ne!(first, second);
        // Truncated back to its first length: the length agrees with the first stamp, the
        // change time does not (after a pause longer than the coarsest time stamps of file
        // systems, a few milliseconds).
        std::thread::sleep(std::time::Duration::from_millis(20));
        let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        f.set_len(3).unwrap();
        let third = Stamp::of(&file.metadata().unwrap());
        assert_eq!(third.len, first.len);
        assert_ne!(third, first);
    }

    #[test]
    fn read_file_reads_files_and_refuses_directories_and_big_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.obj");
        std::fs::write(&path, b"v 0 0 0\n").unwrap();
        assert_eq!(read_file(&path, 8).unwrap(), b"v 0 0 0\n");
        assert!(matches!(
            read_file(&path, 7),
            Err(ReadError::TooLarge { bytes: 8 })
        ));
        assert!(matches!(read_file(dir.path(), 100), Err(ReadError::Io(_))));
        assert!(matches!(
            read_file(&dir.path().join("missing"), 100),
            Err(ReadError::Io(_))
        ));
    }
}
