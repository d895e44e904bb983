//! The byte layout of an `.oavm` file as format-spec.md states it (section by section), written
//! out by hand for the tests and the fuzz targets that build or damage files byte by byte: they
//! must not take offsets from the code they check. Shared by `tests/corruption.rs` and
//! `fuzz/targets.rs` (through `#[path]`); a change of the format changes this file with the spec.
#![allow(dead_code)]

/// §2: the header is 256 bytes; its last 8 are the checksum of the bytes before them and of the
/// section table.
pub const HEADER_LEN: usize = 256;
pub const HEADER_CHECKSUM: usize = 248;
/// §2: header fields these tests rewrite.
pub const VERSION_AT: usize = 8;
pub const FLAGS_AT: usize = 12;
pub const FILE_SIZE_AT: usize = 32;
pub const ROOT_MIN_AT: usize = 40;
pub const ROOT_SIZE_AT: usize = 64;
pub const MAX_BLOCK_RAW_LEN_AT: usize = 144;
/// §3: the section table follows the header: seven 48-byte entries.
pub const ENTRY_LEN: usize = 48;
pub const SECTION_COUNT: usize = 7;
pub const TABLE_END: usize = HEADER_LEN + SECTION_COUNT * ENTRY_LEN;
/// §3: fields of a section table entry.
pub const ENTRY_OFFSET: usize = 8;
pub const ENTRY_LENGTH: usize = 16;
pub const ENTRY_CHECKSUM: usize = 40;
/// §3: positions in the section table.
pub const BLOCKS: usize = 0;
pub const DIRECTORY: usize = 1;
pub const LEVELS: usize = 2;
pub const NODES: usize = 3;
pub const LINK_BOUNDS: usize = 6;
/// §2: the blocks section starts at offset 4096.
pub const BLOCKS_START: usize = 4096;
/// §8.2: a directory entry and its fields.
pub const DIR_LEN: usize = 48;
pub const DIR_OFFSET: usize = 0;
pub const DIR_STORED_LEN: usize = 8;
pub const DIR_RAW_LEN: usize = 16;
pub const DIR_CODEC: usize = 24;
pub const DIR_ROOT_LEVEL: usize = 28;
pub const DIR_ROOT_COUNT: usize = 32;
pub const DIR_TRIANGLES: usize = 36;
pub const DIR_CHECKSUM: usize = 40;
/// §8.2: codecs, and where blocks of each start.
pub const CODEC_RAW: u32 = 0;
pub const CODEC_ZSTD: u32 = 1;
pub const RAW_ALIGN: usize = 4096;
pub const ALIGN: usize = 64;
/// §2: flag bits.
pub const FLAG_COMPRESSED: u32 = 2;
pub const FLAG_CLUSTERS: u32 = 4;
/// §8.3: a block's header, and where its counts are: `level_count` (u32), then from
/// `node_count` on seven u64 counts, one per part after the level table, in part order (nodes,
/// ranks, volumes, refs, triangles, cluster nodes, groups), then `block_id`.
pub const BLOCK_HEADER_LEN: usize = 80;
pub const BH_LEVEL_COUNT: usize = 4;
pub const BH_NODE_COUNT: usize = 16;
pub const BH_BLOCK_ID: usize = 72;
/// §8.3: a block's parts, the level table first.
pub const BLOCK_PART_COUNT: usize = 8;
/// §7.1: a cluster node (80 bytes) and the fields these tests rewrite.
pub const CLUSTER_NODE_LEN: usize = 80;
pub const CN_ORIGIN: usize = 0;
pub const CN_EXP: usize = 12;
pub const CN_CHILD_COUNT: usize = 15;
pub const CN_NODE_BASE: usize = 16;
pub const CN_GROUP_BASE: usize = 20;
pub const CN_INNER_COUNT: usize = 24;
pub const CN_LO: usize = 32;
pub const CN_HI: usize = 56;
/// §7.2: a triangle group (160 bytes) and its fields.
pub const TRI_GROUP_LEN: usize = 160;
pub const TG_CORNER: usize = 0;
pub const TG_TRI: usize = 96;
pub const TG_COUNT: usize = 120;
pub const TG_PRIM: usize = 128;
/// §4.2: the kinds of node record (bits 30–31 of `meta`).
pub const KIND_SOLID: u32 = 1;
pub const KIND_INTERNAL: u32 = 2;
pub const KIND_LINK: u32 = 3;
pub const LINK_ROOT_MASK: u32 = (1 << 30) - 1;
/// §8.3: a decoded block starts with this tag.
pub const BLOCK_TAG: &[u8; 4] = b"OBLK";
