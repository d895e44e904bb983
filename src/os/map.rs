//! Mapping a file into memory, telling the kernel to drop the pages of a range of it (the
//! pager's eviction, the streaming pack's release-behind), and finding out whether the file
//! changed while it was mapped.
//!
//! Everything else reads the map through safe slices (`bytemuck` casts that fail on short or
//! misaligned data), and treats every byte as untrusted.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::os::unix::fs::{FileExt, MetadataExt, OpenOptionsExt};
use std::path::Path;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

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
    /// Kept open for `posix_fadvise` (the map alone cannot drop page-cache pages), `fstat`
    /// and reads through the page cache.
    file: File,
    /// The same file opened for direct reads (`O_DIRECT`), on the first [`Self::read_at`]
    /// that can use it, with the alignment they need; `None` where it cannot be opened so.
    direct: OnceLock<Option<Direct>>,
    /// The file system refused a direct read: read through the page cache from then on.
    buffered_only: AtomicBool,
    /// The file's size and change time when it was mapped.
    stamp: Stamp,
}

/// A file opened for direct reads, and the alignment the file system asks of them.
struct Direct {
    file: File,
    /// What a direct read's offset and length must be multiples of (the device's logical
    /// block, often 512 bytes, where the kernel says; else the page size).
    offset_align: usize,
    /// What a direct read's buffer address must be a multiple of.
    mem_align: usize,
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
                direct: OnceLock::new(),
                buffered_only: AtomicBool::new(false),
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
            direct: OnceLock::new(),
            buffered_only: AtomicBool::new(false),
            stamp,
        })
    }

    /// `Err(Changed)` if the file changed since it was mapped: a read of the map met a page
    /// past the file's end, or its size or change time differs now. One `fstat`; call it after
    /// using the bytes, before trusting what they gave.
    pub fn check_unchanged(&self) -> Result<(), Changed> {
        self.check_unchanged_unless(|_| false)
    }

    /// [`Self::check_unchanged`], except that a file that grew (or kept its size) is
    /// unchanged if `appended(file)` says the change was one that leaves the mapped bytes a
    /// reader uses as they were (an `.oavm` update, which appends a generation).
    pub fn check_unchanged_unless(&self, appended: impl Fn(&File) -> bool) -> Result<(), Changed> {
        if self.guard.as_ref().is_some_and(Registration::faulted) {
            return Err(Changed);
        }
        match self.file.metadata() {
            Ok(meta) if Stamp::of(&meta) == self.stamp => Ok(()),
            Ok(meta) if meta.len() >= self.stamp.len && appended(&self.file) => Ok(()),
            _ => Err(Changed),
        }
    }

    /// Reads the file's bytes `offset .. offset + buf.len()` into `buf` (bytes past the file's
    /// end read as zeros), with no copy in the page cache when it can: a direct read
    /// (`O_DIRECT`) if `offset` and `buf`'s length are multiples of [`Self::direct_align`],
    /// `buf`'s address is page-aligned ([`super::PageBuf`]) and the file system allows it, else
    /// an ordinary one. A direct read costs the kernel far less than faulting the map's pages in
    /// and dropping them again, and many at once keep the disk busy at its bandwidth.
    pub fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        if !self.buffered_only.load(Ordering::Relaxed)
            && let Some(direct) = self.direct.get_or_init(|| open_direct(&self.file))
            && offset.is_multiple_of(direct.offset_align as u64)
            && buf.len().is_multiple_of(direct.offset_align)
            && (buf.as_ptr() as usize).is_multiple_of(direct.mem_align)
        {
            match read_full(&direct.file, offset, buf, Some(direct.offset_align)) {
                Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                    self.buffered_only.store(true, Ordering::Relaxed);
                }
                done => return done,
            }
        }
        read_full(&self.file, offset, buf, None)
    }

    /// Reads each `(offset, buf)` of `reads` as [`Self::read_at`] would, but all at once when
    /// each can be read directly: submitted together to an io_uring from this thread, at most
    /// `depth` in flight (`super::uring`); else, or where the kernel has no io_uring, one by
    /// one. Each read's result, in order.
    pub fn read_many(
        &self,
        reads: &mut [(u64, &mut [u8])],
        depth: usize,
    ) -> Vec<std::io::Result<()>> {
        let direct = match self.direct.get_or_init(|| open_direct(&self.file)) {
            Some(d) if !self.buffered_only.load(Ordering::Relaxed) => Some(d),
            _ => None,
        };
        let batched = direct.filter(|d| {
            reads.iter().all(|(offset, buf)| {
                offset.is_multiple_of(d.offset_align as u64)
                    && buf.len().is_multiple_of(d.offset_align)
            })
        });
        let done = batched.and_then(|d| super::uring::read_many(&d.file, reads, depth));
        let Some(done) = done else {
            return reads
                .iter_mut()
                .map(|(offset, buf)| self.read_at(*offset, buf))
                .collect();
        };
        reads
            .iter_mut()
            .zip(done)
            .map(|((offset, buf), got)| match got {
                Ok(n) if n == buf.len() => Ok(()),
                // Short (at the file's end, or cut off) or refused: read again as `read_at`
                // reads, which zero-fills past the end and falls back to the page cache.
                Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                    self.buffered_only.store(true, Ordering::Relaxed);
                    self.read_at(*offset, buf)
                }
                Ok(_) => self.read_at(*offset, buf),
                Err(e) => Err(e),
            })
            .collect()
    }

    /// What a read's offset and length must be multiples of for [`Self::read_at`] to read
    /// directly: the device's logical block where the kernel says (`statx` `STATX_DIOALIGN`),
    /// else the page size. A reader that rounds its reads to this reads no more of the disk
    /// than it needs, to within one block at each end.
    pub fn direct_align(&self) -> usize {
        match self.direct.get_or_init(|| open_direct(&self.file)) {
            Some(d) if !self.buffered_only.load(Ordering::Relaxed) => d.offset_align,
            _ => page_size(),
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

/// `file` opened again for direct reads, through `/proc/self/fd` (which reaches the same file
/// even if it was renamed or unlinked since), with the alignment its file system asks of them;
/// `None` if that fails.
fn open_direct(file: &File) -> Option<Direct> {
    let direct = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECT)
        .open(format!("/proc/self/fd/{}", file.as_raw_fd()))
        .ok()?;
    let page = page_size();
    let (offset_align, mem_align) = dio_align(&direct).unwrap_or((page, page));
    Some(Direct {
        file: direct,
        offset_align,
        mem_align,
    })
}

/// The alignment direct reads of `file` need, `(offset and length, buffer address)`, as the
/// kernel gives it (`statx` with `STATX_DIOALIGN`, Linux 6.1 and later); `None` where it does
/// not say, or says something unusable (zero, not a power of two, or more than a page: the
/// page size is used then).
fn dio_align(file: &File) -> Option<(usize, usize)> {
    // SAFETY: `statx` on a file descriptor we own with an empty path and `AT_EMPTY_PATH` reads
    // the descriptor's file; it writes only the `statx` buffer we pass, which is a plain C
    // struct (all integers) and may start zeroed.
    let mut stx: libc::statx = unsafe { std::mem::zeroed() };
    // SAFETY: see above; the path is a valid C string and `stx` outlives the call.
    let rc = unsafe {
        libc::statx(
            file.as_raw_fd(),
            c"".as_ptr(),
            libc::AT_EMPTY_PATH,
            libc::STATX_DIOALIGN,
            &mut stx,
        )
    };
    let page = page_size();
    let usable = |a: u32| a.is_power_of_two() && a as usize <= page;
    (rc == 0
        && stx.stx_mask & libc::STATX_DIOALIGN != 0
        && usable(stx.stx_dio_offset_align)
        && usable(stx.stx_dio_mem_align))
    .then_some((
        stx.stx_dio_offset_align as usize,
        stx.stx_dio_mem_align as usize,
    ))
}

/// Fills `buf` from `file` at `offset`; what lies past the end of the file reads as zeros. A
/// direct read (`direct`: its alignment) that stops short of an aligned length has reached the
/// end.
fn read_full(
    file: &File,
    mut offset: u64,
    mut buf: &mut [u8],
    direct: Option<usize>,
) -> std::io::Result<()> {
    while !buf.is_empty() {
        match file.read_at(buf, offset) {
            Ok(0) => break,
            Ok(n) if direct.is_some_and(|a| !n.is_multiple_of(a)) => {
                buf = &mut buf[n..];
                break;
            }
            Ok(n) => {
                offset += n as u64;
                buf = &mut buf[n..];
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    buf.fill(0);
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::os::PageBuf;

    /// Reads give the file's bytes, aligned (direct where the file system allows) or not, and
    /// zeros past the end; a read wholly past the end is all zeros.
    #[test]
    fn read_at_gives_the_files_bytes_and_zeros_past_the_end() {
        let page = page_size();
        let len = 3 * page + 100;
        let data: Vec<u8> = (0..len).map(|i| (i * 7 + i / 4096) as u8).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        std::fs::write(&path, &data).unwrap();
        let map = MappedFile::open(&path).unwrap();
        let expect = |off: usize, n: usize| -> Vec<u8> {
            (off..off + n)
                .map(|i| data.get(i).copied().unwrap_or(0))
                .collect()
        };
        // Aligned: whole pages into a page buffer, the last one past the end.
        for (off, n) in [
            (0, 4 * page),
            (page, 2 * page),
            (3 * page, page),
            (5 * page, page),
        ] {
            let mut buf = PageBuf::new(n).unwrap();
            buf.fill(0xAA);
            map.read_at(off as u64, &mut buf).unwrap();
            assert!(buf[..] == expect(off, n)[..], "aligned read at {off}+{n}");
        }
        // Unaligned offset, address or length: read through the page cache.
        for (off, n) in [(7, 100), (page - 3, page + 9), (3 * page + 50, 200)] {
            let mut buf = vec![0xAA; n];
            map.read_at(off as u64, &mut buf).unwrap();
            assert!(buf == expect(off, n), "unaligned read at {off}+{n}");
        }
        // Reads aligned to the file system's direct alignment (a device block, often smaller
        // than a page), into a page buffer, ending short of and past the end.
        let align = map.direct_align();
        assert!(
            align.is_power_of_two() && align <= page,
            "direct alignment {align}"
        );
        for (off, n) in [
            (align, 2 * align),
            (3 * page, align),
            (len / align * align, 2 * align),
        ] {
            let mut buf = PageBuf::new(n.next_multiple_of(page)).unwrap();
            buf.fill(0xAA);
            map.read_at(off as u64, &mut buf[..n]).unwrap();
            assert!(
                buf[..n] == expect(off, n)[..],
                "read at {off}+{n} (alignment {align})"
            );
        }
        // Many at once (an io_uring where the kernel has one): the same bytes as one by one,
        // in any buffers, with reads ending past the end and wholly past it, and more reads
        // than the depth; and with one unaligned read among them (then one by one).
        let mut offs: Vec<(usize, usize)> = (0..40)
            .map(|i| ((i * 3 % (len / align + 2)) * align, align * (1 + i % 3)))
            .collect();
        offs.push((len / align * align, 2 * align));
        for unaligned in [false, true] {
            if unaligned {
                offs.push((7, 100));
            }
            let mut bufs: Vec<Vec<u8>> = offs.iter().map(|&(_, n)| vec![0xAA; n]).collect();
            let mut reads: Vec<(u64, &mut [u8])> = offs
                .iter()
                .zip(bufs.iter_mut())
                .map(|(&(off, _), b)| (off as u64, &mut b[..]))
                .collect();
            let results = map.read_many(&mut reads, 8);
            assert_eq!(results.len(), offs.len());
            for ((&(off, n), b), r) in offs.iter().zip(&bufs).zip(results) {
                r.unwrap();
                assert!(b[..] == expect(off, n)[..], "read_many at {off}+{n}");
            }
        }
        // A direct read on a file system that allows it (the test's temporary directory).
        eprintln!(
            "direct reads: {}",
            map.direct.get().is_some_and(Option::is_some)
                && !map.buffered_only.load(Ordering::Relaxed)
        );
    }
}
