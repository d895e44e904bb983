//! The physical layer (OAVM paper §2.1): the bytes of an `.oavm` file, as `format-spec.md`
//! specifies them. It owns the records and constants of the format ([`format`]), opening a
//! file with `O(1)` checks and casting its sections in place ([`OavmFile`]), reading a block
//! the one way the pager and `verify` both use ([`BlockReader`], [`BlockView`]), the link
//! bounds beside the top tree's links ([`bounds`]), the byte-level part of verification
//! ([`verify`]; [`check_cluster`], which re-derives from a cluster's records alone that it is
//! well-formed and holds what it must) and writing a file ([`writer`]).
//!
//! It imports nothing above it: no Morton codes, no tree walks (those are the mapping and
//! logical layers', which read the records this layer casts).

mod block;
pub(crate) mod bounds;
mod cluster_check;
mod file;
pub mod format;
mod geometry;
mod inspect;
pub mod lean;
pub(crate) mod verify;
pub mod wide;
pub(crate) mod writer;

pub(crate) use block::decode_frame;
pub use block::{BlockError, BlockReader, BlockView, ReadBlock};
pub(crate) use cluster_check::check_node;
#[cfg(test)]
pub(crate) use cluster_check::check_with_depth;
pub use cluster_check::{ClusterShape, check_cluster, wide_region};
pub use file::{AlignedBytes, OavmFile, SlotState, generation_intact};
pub use geometry::{geometry_records, read_geometries};
pub use inspect::{
    BlockWideCounts, DirectorySummary, InspectOptions, Inspection, Section, TopLevel, TreeLevel,
    WideSummary, inspect,
};
pub use writer::{BlockOptions, DEFAULT_BLOCK_SIZE, DEFAULT_CHUNK_GROUPS, DEFAULT_ZSTD_LEVEL};
