//! The operating system and the processor: the crate's only `unsafe` code (mapping files,
//! page-aligned buffers for direct reads, dropping their pages, the SIGBUS guard, naming an unnamed file, the SIMD instructions of the
//! tracer's kernels), and what `/proc` says about the process.
//!
//! Every `unsafe` block here carries a `// SAFETY:` comment; the rest of the crate is compiled
//! with `#![deny(unsafe_code)]` and reads the maps through safe slices.

mod buf;
mod guard;
mod link;
mod map;
mod proc;
mod simd;

pub use buf::PageBuf;
pub use link::link_unnamed;
pub use map::{Changed, MappedFile, page_size};
pub use proc::{available_memory, peak_rss_bytes, read_bytes};
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
pub use simd::Sse41;
pub use simd::{Avx2, Portable, Simd8, WithAvx2};
