//! Mapping a file into memory, telling the kernel to drop the pages of a range of it (the
//! pager's eviction, the streaming pack's release-behind), and finding out whether the file
//! changed while it was mapped.
//!
//! Everything else reads the map through safe slices (`bytemuck` casts that fail on short or
//! misaligned data), and treats every byte as untrusted.

use std::fs::File;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

use memmap2::{Advice, Mmap, UncheckedAdvice};

use super::guard::{self, Registration};

/// A read-only memory map of a whole file. An empty file maps to an empty slice (mapping zero
/// bytes is an error on some platforms, so it is not mapped at all).
///
/// The map is guarded against the file shrinking under it ([`super::guard`]): a read past the
/// new end gives zeros instead of a SIGBUS. The owner calls [`MappedFile::check_unchanged`]
/// after using the bytes (at the end of each batch) to turn such a change into an error.
pub struct MappedFile {
    // Declared before `map`, so it is dropped (unregistered) before the map is unmapped.
    guard: Option<Registration>,
    map: Option<Mmap>,
    /// Kept open for `posix_fadvise` (the map alone cannot drop page-cache pages) and `fstat`.
    file: File,
    /// The file's size and change time when it was mapped.
    stamp: Stamp,
}

/// What identifies a version of a file's contents: its size and its inode change time (which
/// every write, truncation and metadata change updates, and no user can set).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Stamp {
    len: u64,
    ctime: (i64, i64),
}

impl Stamp {
    fn of(meta: &std::fs::Metadata) -> Stamp {
        Stamp {
            len: meta.len(),
            ctime: (meta.ctime(), meta.ctime_nsec()),
        }
    }
}

/// The file behind a [`MappedFile`] changed after it was mapped: truncated, extended or
/// written in place. What was read from it since may be anything.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Changed;

impl std::fmt::Display for Changed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("changed while it was being read (truncated, rewritten or extended in place)")
    }
}

impl std::error::Error for Changed {}

impl MappedFile {
    /// Maps `path` read-only.
    pub fn open(path: &Path) -> std::io::Result<MappedFile> {
        let file = File::open(path)?;
        let meta = file.metadata()?;
        if meta.is_dir() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "is a directory, not an .oavm file",
            ));
        }
        if !meta.is_file() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "is not a regular file",
            ));
        }
        let stamp = Stamp::of(&meta);
        if meta.len() == 0 {
            return Ok(MappedFile {
                guard: None,
                map: None,
                file,
                stamp,
            });
        }
        // SAFETY: the map is read-only and we only ever create `&[u8]` views of it. The one
        // hazard memmap2 documents is another process truncating or rewriting the file while it
        // is mapped. oavm never modifies a file in place (it writes a new file and renames it
        // over the old one, which leaves maps of the old inode intact), but another program may:
        // a read past a truncated end is turned from a SIGBUS into zeros by the guard registered
        // below, bytes that change are read as untrusted bytes like any others (every reader
        // bounds-checks what it reads), and `check_unchanged` reports the change.
        let map = unsafe { Mmap::map(&file)? };
        let guard = Some(guard::register(map.as_ptr() as usize, map.len()));
        Ok(MappedFile {
            guard,
            map: Some(map),
            file,
            stamp,
        })
    }

    /// `Err(Changed)` if the file changed since it was mapped: a read of the map met a page
    /// past the file's end, or its size or change time differs now. One `fstat`; call it after
    /// using the bytes, before trusting what they gave.
    pub fn check_unchanged(&self) -> Result<(), Changed> {
        if self.guard.as_ref().is_some_and(Registration::faulted) {
            return Err(Changed);
        }
        match self.file.metadata() {
            Ok(meta) if Stamp::of(&meta) == self.stamp => Ok(()),
            _ => Err(Changed),
        }
    }

    /// Hints the kernel about the access pattern; failures are harmless and ignored.
    pub fn advise(&self, advice: Advice) {
        if let Some(map) = &self.map {
            let _ = map.advise(advice);
        }
    }

    /// Hints the kernel about bytes `offset .. offset + len` (e.g. [`Advice::WillNeed`] to read
    /// a block ahead in one request). The range is widened to whole pages and clipped to the
    /// file; failures are harmless and ignored.
    pub fn advise_range(&self, advice: Advice, offset: usize, len: usize) {
        if let Some((map, start, len)) = self.page_range(offset, len, false) {
            let _ = map.advise_range(advice, start, len);
        }
    }

    /// Gives the pages wholly inside `offset .. offset + len` back to the kernel: unmapped from
    /// this process (`MADV_DONTNEED`) and dropped from the page cache (`POSIX_FADV_DONTNEED`),
    /// so that they stop counting against the process's memory and its cgroup's. The bytes stay
    /// readable: the next access reads them from the file again. Pages shared with bytes
    /// outside the range are kept. Failures are harmless and ignored (the memory is then simply
    /// not released).
    pub fn release(&self, offset: usize, len: usize) {
        let Some((map, start, len)) = self.page_range(offset, len, true) else {
            return;
        };
        // SAFETY: `MADV_DONTNEED` on a read-only shared file mapping only drops this process's
        // page-table entries for the range; the next access faults the same file bytes back in
        // from the page cache or the disk. Any `&[u8]` into the range therefore stays valid
        // and keeps reading the file's bytes (see `open` for a file another program changes).
        // The range is inside the map (`page_range` clips it) and page-aligned.
        let _ = unsafe { map.unchecked_advise_range(UncheckedAdvice::DontNeed, start, len) };
        use std::os::fd::AsRawFd;
        // SAFETY: a plain system call on a file descriptor we own, with integer arguments; it
        // reads and writes no memory of ours. It only drops clean page-cache pages, which the
        // kernel reads again from the file if they are needed.
        let _ = unsafe {
            libc::posix_fadvise(
                self.file.as_raw_fd(),
                start as libc::off_t,
                len as libc::off_t,
                libc::POSIX_FADV_DONTNEED,
            )
        };
    }

    /// The map and the page-aligned range covering `offset .. offset + len` (`inner`: only the
    /// pages wholly inside it; the file's partial last page counts as inside), clipped to the
    /// map, as `(map, start, len)`; `None` if that is empty.
    fn page_range(&self, offset: usize, len: usize, inner: bool) -> Option<(&Mmap, usize, usize)> {
        let map = self.map.as_ref()?;
        let page = page_size();
        let end = offset.saturating_add(len).min(map.len());
        let (start, end) = if inner {
            let end = if end == map.len() {
                end
            } else {
                end / page * page
            };
            (offset.next_multiple_of(page), end)
        } else {
            (offset / page * page, end)
        };
        (start < end).then_some((map, start, end - start))
    }
}

/// The size of a memory page (4096 where the system does not say).
pub fn page_size() -> usize {
    // SAFETY: `sysconf` reads a system constant; no memory of ours is involved.
    let p = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    if p > 0 { p as usize } else { 4096 }
}

impl AsRef<[u8]> for MappedFile {
    fn as_ref(&self) -> &[u8] {
        self.map.as_deref().unwrap_or(&[])
    }
}
