//! The physical layer: the bytes of an `.oavm` file (format-spec.md), mapping the file,
//! validating it at open, verifying it in full, and writing it.

pub mod blocks;
pub mod bounds;
pub mod file;
pub mod format;
pub mod mmap;
pub mod pager;
pub mod verify;
pub mod writer;

pub use file::{AlignedBytes, OavmFile};
pub use mmap::MappedFile;
