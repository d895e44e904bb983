//! The operating system and the processor: the crate's only `unsafe` code (mapping files,
//! page-aligned buffers for direct reads and many of them at once (io_uring), dropping their pages, the SIGBUS guard, naming an unnamed file, the SIMD instructions of the
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
mod uring;

pub use buf::PageBuf;
pub use link::link_unnamed;
pub use map::{Changed, MappedFile, page_size};
pub use proc::{available_memory, peak_rss_bytes, read_bytes};
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
pub use simd::Sse41;
pub use simd::{Avx2, FmaNodeFields, FmaNodeRay, Portable, Simd8, WithAvx2};

/// Asks the CPU to bring the `LINES` cache lines from the start of `x` into its caches, so that
/// a load a little later does not wait on memory: the walks prefetch the children and groups
/// they will visit, whose loads then overlap. A hint only: no fault, no effect on any value;
/// nothing where the architecture has no such instruction.
#[inline(always)]
pub fn prefetch<T, const LINES: usize>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = (x as *const T).cast::<i8>();
        for l in 0..LINES {
            // SAFETY: a prefetch never faults nor reads into any value, whatever the address
            // (`wrapping_add` keeps the pointer arithmetic defined).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * l)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}
