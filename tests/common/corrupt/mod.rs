//! Corrupted `.oavm` files, version 5 (format-spec.md §11; hostile input): what the
//! `tests/corrupt_*.rs` files share. Each of them damages one part of the format:
//!
//! - `corrupt_header.rs`: the header and its two slots (§2, §2.1: generations), the section
//!   table (§3) and the version (§12): truncated, extended, wrong magic or version (version 1
//!   files included), header fields rewritten, generations; files held in misaligned buffers;
//!   and the layout these tests use, checked against the code;
//! - `corrupt_anywhere.rs`: every region of every file: a bit flipped anywhere, regions
//!   rewritten with their checksums recomputed (inside compressed blocks too: decoded, changed,
//!   recompressed), and the long run;
//! - `corrupt_blocks.rs`: the block directory (§8.2), a block's bytes (§8.3: frames that lie,
//!   damaged blocks traced under a memory budget of a few blocks) and the tree's records in
//!   them (§4.3 rank words, §7.1–§7.2 cluster nodes and triangle groups);
//! - `corrupt_top.rs`: the top tree's links (§8.1) and ropes (§8.4);
//! - `corrupt_occluders.rs`: occluders (§8.5);
//! - `corrupt_prims.rs`: primitive tables (§8.6).
//!
//! What must hold, for every corruption tried:
//!
//! - a damaged file (truncated, bit flipped) fails at open, or `verify` reports a defect that
//!   names the damaged place; a damaged block (its bytes are checksummed in the directory) is
//!   also refused by the pager when a walk needs it: tracing fails with an error naming the
//!   block, never a wrong answer;
//! - where the format deliberately covers no byte (§2.1), the damage changes nothing: the
//!   header slot that is not the generation's (all zero in a file as packed, an older header in
//!   an updated file), bytes past `file_size` (an extended file, what an interrupted update
//!   left) and, in a generation after the first, the bytes of the data region it no longer
//!   refers to. The file opens as the same generation, verifies clean and answers every ray bit
//!   for bit as before. And damage to the newest header slot makes the file open as the
//!   previous generation, which answers as that generation did (the format's rule: a reader
//!   takes the valid slot of the highest generation, so a torn or damaged header is an
//!   interrupted update);
//! - whatever the bytes, and whether or not the file was verified, opening, verifying and tracing
//!   (closest hit and any hit) return an answer or an error: never a panic, never an endless walk
//!   (spec §10, §11 "Trace"). A rewritten file (checksums recomputed, so that only the structure
//!   checks can tell) is either reported by verify or traced with the intact file's answers. Each
//!   corrupted file is opened, verified and traced on a thread of its own with a time limit, so
//!   that a panic is reported with the corruption that caused it and a hang fails the test
//!   instead of stalling it. Files whose blocks matter are also traced under a memory budget of a
//!   few blocks on 2 threads, and must give the same outcome.
//!
//! The files are built in memory from the dragon's smallest decimation: with the default build
//! options (solid leaves are clusters, §7.1–§7.2: wide BVHs over triangle groups), with the
//! default options of leaf lists (`--leaf list`, §6–§7: format 3's leaves), and from its first
//! triangles with leaf size 4 (a deep tree, of small clusters), each split into small blocks
//! (so that a small mesh makes many) and written both raw and zstd-compressed; and the default
//! file (raw) and the file of lists (zstd) again, with ropes (§8.4: an eighth section and a
//! ninth part in every block, added by `add_ropes` as `oavm-pack --ropes` adds them), traced by
//! the walk that follows them (`Walk::Ropes`; the other files by the default walk); and the deep
//! file, raw and zstd, with occluders (§8.5: a tenth and an eleventh part in the blocks that
//! hold some, added by `add_occluders` with the default parameters as `oavm-pack --occluders`
//! adds them), traced by the default top-down walk, whose any-hit queries test them. Two more
//! are written to disk: the default file packed `--updatable` (`pack_mesh`, §8.6: a primitive
//! table, its chunks after the blocks and its chunk directory a last section), and that file
//! updated in place (`Updater`: a block's primitives removed, some moved, some inserted), a
//! file of generation 2 in slot 1 whose data region holds the first generation's bytes too.
//! The byte layout used to corrupt them, to recompute checksums and to re-lay a file out after
//! a compressed block changed size, as a tool that rewrites a file would, is taken from
//! format-spec.md §2–§8 (`tests/common/layout.rs`), not from the code;
//! `layout_matches_the_spec` (`corrupt_header.rs`) checks that the two agree.
//!
//! The mutation runs print what they found (`--nocapture`). A corruption that aborts the process
//! (a failed allocation cannot be caught) is found by running with `OAVM_CORRUPTION_LOG=1`, which
//! prints each case before it runs. A longer run, with more mutations per
//! region and the whole dragon at leaf size 4, is ignored by default:
//! `cargo test --release --test corrupt_anywhere -- --ignored --nocapture`.
//!
//! Each file keeps a small reproduction of each library bug these runs found in the part it
//! damages, as a regression test (a bug found later gets an `#[ignore = "bug: ..."]` test in the
//! file of the part it damages until it is fixed).
//!
//! The modules: [`bytes`] (the layout beyond `common::layout`: fields, sections, checksums,
//! re-laying a file out), [`regions`] (the regions of a file, as errors name them), [`fixture`]
//! (a built file, decoded, its regions, its intact answers), [`files`] (the fixtures' files)
//! and [`harness`] (opening, verifying and tracing a damaged file under a time limit).

pub mod bytes;
pub mod files;
pub mod fixture;
pub mod harness;
pub mod regions;

pub use super::layout::*;
pub use bytes::*;
pub use files::*;
pub use fixture::*;
// Every test binary has `common`; those that damage no file use nothing of the harness.
#[allow(unused_imports)]
pub use harness::*;
pub use regions::*;
