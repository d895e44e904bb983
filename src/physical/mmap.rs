//! The crate's only `unsafe` code: mapping a file into memory.
//!
//! Everything else reads the map through safe slices (`bytemuck` casts that fail on short or
//! misaligned data), and treats every byte as untrusted.

use std::fs::File;
use std::path::Path;

use memmap2::{Advice, Mmap};

/// A read-only memory map of a whole file. An empty file maps to an empty slice (mapping zero
/// bytes is an error on some platforms, so it is not mapped at all).
pub struct MappedFile {
    map: Option<Mmap>,
}

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
        if meta.len() == 0 {
            return Ok(MappedFile { map: None });
        }
        // SAFETY: the map is read-only and we only ever create `&[u8]` views of it. The one
        // hazard memmap2 documents is another process truncating or rewriting the file while it
        // is mapped (a SIGBUS, or bytes changing under a shared reference). oavm never modifies a
        // file in place: `oavm-pack` writes a new file and renames it over the old one, which
        // leaves existing maps of the old inode intact. Contents are never trusted, so bytes that
        // change are caught like any other corruption by the bounds checks of every reader.
        let map = unsafe { Mmap::map(&file)? };
        Ok(MappedFile { map: Some(map) })
    }

    /// Hints the kernel about the access pattern; failures are harmless and ignored.
    pub fn advise(&self, advice: Advice) {
        if let Some(map) = &self.map {
            let _ = map.advise(advice);
        }
    }
}

impl AsRef<[u8]> for MappedFile {
    fn as_ref(&self) -> &[u8] {
        self.map.as_deref().unwrap_or(&[])
    }
}
