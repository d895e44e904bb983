//! Page-aligned buffers of our own: where the pager reads blocks past the page cache.
//!
//! A direct read (`O_DIRECT`) moves a file's bytes from the disk into the caller's memory with
//! no copy in the page cache, but it asks for buffers aligned to the device's blocks; a page
//! is aligned for every device. [`PageBuf`] is such a buffer, mapped anonymously (so it starts
//! zeroed at no cost, its untouched pages take no memory, and freeing it gives its memory back
//! to the kernel at once).

use std::ptr::NonNull;

use super::map::page_size;

/// A zeroed, page-aligned buffer of whole pages, owned like a `Vec<u8>`.
pub struct PageBuf {
    /// The mapping's start (dangling and never dereferenced when `len` is 0).
    ptr: NonNull<u8>,
    /// Bytes mapped: a multiple of the page size.
    len: usize,
}

// SAFETY: a `PageBuf` owns its mapping exclusively (like a `Vec<u8>` its heap buffer): no other
// value points into it, `&PageBuf` only gives shared slices and `&mut PageBuf` exclusive ones.
unsafe impl Send for PageBuf {}
// SAFETY: as above; shared access is read-only.
unsafe impl Sync for PageBuf {}

impl PageBuf {
    /// A buffer of at least `len` bytes (rounded up to whole pages), zeroed. `None` if the
    /// kernel refuses the memory.
    pub fn new(len: usize) -> Option<PageBuf> {
        let len = len.checked_next_multiple_of(page_size())?;
        if len == 0 {
            return Some(PageBuf::default());
        }
        // SAFETY: an anonymous private mapping at an address of the kernel's choosing: it
        // aliases no memory of ours. The result is checked before use.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return None;
        }
        Some(PageBuf {
            ptr: NonNull::new(p.cast())?,
            len,
        })
    }

    /// Its bytes: a multiple of the page size.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl Default for PageBuf {
    /// An empty buffer (no mapping).
    fn default() -> Self {
        PageBuf {
            ptr: NonNull::dangling(),
            len: 0,
        }
    }
}

impl std::ops::Deref for PageBuf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        if self.len == 0 {
            return &[];
        }
        // SAFETY: `ptr .. ptr + len` is our mapping, readable and initialised (anonymous pages
        // read as zeros), alive as long as `self`; only `&mut self` gives a mutable view.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

impl std::ops::DerefMut for PageBuf {
    fn deref_mut(&mut self) -> &mut [u8] {
        if self.len == 0 {
            return &mut [];
        }
        // SAFETY: as in `deref`, and `&mut self` makes this view the only one.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.as_ptr(), self.len) }
    }
}

impl Drop for PageBuf {
    fn drop(&mut self) {
        if self.len > 0 {
            // SAFETY: the mapping `new` made, unmapped once; no slice of it outlives `self`.
            unsafe {
                libc::munmap(self.ptr.as_ptr().cast(), self.len);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_are_zeroed_page_aligned_and_writable() {
        let page = page_size();
        for len in [0, 1, page - 1, page, page + 1, 5 * page + 7] {
            let mut b = PageBuf::new(len).unwrap();
            assert_eq!(b.len(), len.next_multiple_of(page));
            assert!(b.len() >= len);
            if len > 0 {
                assert_eq!(b.as_ptr() as usize % page, 0);
            }
            assert!(b.iter().all(|&x| x == 0));
            b.iter_mut().enumerate().for_each(|(i, x)| *x = i as u8);
            assert!(b.iter().enumerate().all(|(i, &x)| x == i as u8));
        }
    }
}
