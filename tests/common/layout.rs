//! The byte layout of an `.oavm` file as format-spec.md states it (section by section), written
//! out by hand for the tests and the fuzz targets that build or damage files byte by byte: they
//! must not take offsets from the code they check. Shared by the `tests/corrupt_*.rs` files
//! (`tests/common/corrupt`) and `fuzz/targets.rs` (through `#[path]`); a change of the format
//! changes this file with the spec. As of format version 7 (generations in two header slots, the
//! primitive table; the wide nodes of §8.7: the top tree's wide nodes and wide links, two
//! sections of a file of clusters; a block's groups at its end, in chunks checked and stored
//! on their own, §8.2–§8.3).
#![allow(dead_code)]

/// §12: the version this layout describes.
pub const VERSION: u32 = 7;
/// §2: the magic bytes a header starts with.
pub const MAGIC: &[u8; 8] = b"\x89OAVM\r\n\x1a";
/// §2: the header is 256 bytes; its last 8 are the checksum of the bytes before them and of the
/// section table.
pub const HEADER_LEN: usize = 256;
pub const HEADER_CHECKSUM: usize = 248;
/// §2: header fields these tests rewrite (offsets in the header, whichever slot it is in).
pub const VERSION_AT: usize = 8;
pub const FLAGS_AT: usize = 12;
pub const SECTION_COUNT_AT: usize = 20;
pub const TABLE_OFFSET_AT: usize = 24;
pub const FILE_SIZE_AT: usize = 32;
pub const ROOT_MIN_AT: usize = 40;
pub const ROOT_SIZE_AT: usize = 64;
pub const INPUT_TRIANGLES_AT: usize = 96;
pub const MAX_BLOCK_RAW_LEN_AT: usize = 144;
pub const GENERATION_AT: usize = 168;
/// §2, §8.3: `chunk_groups` (u32): triangle groups per chunk, `1..=MAX_CHUNK_GROUPS` in a file
/// of clusters that has groups, 0 in a file of lists.
pub const CHUNK_GROUPS_AT: usize = 176;
pub const MAX_CHUNK_GROUPS: u32 = 1 << 16;
/// §2: `reserved_u32` (u32) and `reserved` (u64[8]), zero, up to the checksum.
pub const RESERVED_U32_AT: usize = 180;
pub const RESERVED_AT: usize = 184;
/// §2, §2.1: the two header slots, each a header and its section table, zero after the table
/// to the slot's end. Generation `g` is in slot `(g - 1) mod 2`; a file as packed is
/// generation 1, in slot 0, and its slot 1 is all zero.
pub const HEADER_SLOTS: [usize; 2] = [0, 2048];
pub const SLOT_LEN: usize = 2048;
/// §3: the section table follows its slot's header: 48-byte entries, seven in every file.
pub const ENTRY_LEN: usize = 48;
pub const SECTION_COUNT: usize = 7;
/// Where slot 0's table ends in a file with no optional section (leaf lists: no wide nodes; no
/// ropes, no primitive table).
pub const TABLE_END: usize = HEADER_LEN + SECTION_COUNT * ENTRY_LEN;
/// §3: fields of a section table entry.
pub const ENTRY_KIND: usize = 0;
pub const ENTRY_OFFSET: usize = 8;
pub const ENTRY_LENGTH: usize = 16;
pub const ENTRY_COUNT: usize = 24;
pub const ENTRY_CHECKSUM: usize = 40;
/// §3: positions in the section table of the seven sections every file has (kind - 1).
pub const BLOCKS: usize = 0;
pub const DIRECTORY: usize = 1;
pub const LEVELS: usize = 2;
pub const NODES: usize = 3;
pub const RANKS: usize = 4;
pub const VOLUMES: usize = 5;
pub const LINK_BOUNDS: usize = 6;
/// §3: the kinds of the sections after them, each present by a flag: the top tree's wide nodes
/// and wide links (§8.7, `CLUSTERS`), the ropes (`ROPES`), the primitive table (`PRIMS`), in
/// this order in the table (not the order of their kinds).
pub const KIND_ROPES: u32 = 8;
pub const KIND_PRIMS: u32 = 9;
pub const KIND_WIDE_NODES: u32 = 10;
pub const KIND_WIDE_LINKS: u32 = 11;
/// §8.8: the geometry table (`GEOMETRIES`), after all of them; a record (`GeometryRecord`, 160
/// bytes): `first_primitive` u64, `primitive_count` u64, `transform` f64[3][4], `name` u8[48].
pub const KIND_GEOMETRIES: u32 = 12;
pub const GEOMETRY_LEN: usize = 160;
pub const GEO_FIRST: usize = 0;
pub const GEO_COUNT: usize = 8;
pub const GEO_TRANSFORM: usize = 16;
pub const GEO_NAME: usize = 112;
/// §8.7: a wide link (`WideLink`, 32 bytes): `block` u32, `root` u32, `lo` f32[3], `hi` f32[3].
pub const WIDE_LINK_LEN: usize = 32;
pub const WL_BLOCK: usize = 0;
pub const WL_ROOT: usize = 4;
pub const WL_LO: usize = 8;
pub const WL_HI: usize = 20;
/// §2, §3: the blocks section (the data region) starts at offset 4096, after both slots.
pub const BLOCKS_START: usize = 4096;
/// §8.2: a directory entry and its fields. `checksum` covers the head's stored bytes only (the
/// first `head_stored_len` of the block's); each chunk's checksum is in the head's chunk table.
pub const DIR_LEN: usize = 64;
pub const DIR_OFFSET: usize = 0;
pub const DIR_STORED_LEN: usize = 8;
pub const DIR_RAW_LEN: usize = 16;
pub const DIR_CODEC: usize = 24;
pub const DIR_ROOT_LEVEL: usize = 28;
pub const DIR_ROOT_COUNT: usize = 32;
pub const DIR_TRIANGLES: usize = 36;
pub const DIR_CHECKSUM: usize = 40;
pub const DIR_HEAD_STORED_LEN: usize = 48;
pub const DIR_HEAD_RAW_LEN: usize = 56;
/// §8.2: codecs, and where blocks of each start.
pub const CODEC_RAW: u32 = 0;
pub const CODEC_ZSTD: u32 = 1;
pub const CODEC_LEAN: u32 = 2;
pub const RAW_ALIGN: usize = 4096;
pub const ALIGN: usize = 64;
/// §8.2: a zstd frame (a head, or a chunk) decodes to at most this many times its size (a
/// head: plus one page, `GROUPS_ALIGN`, the zero padding before its groups).
pub const MAX_ZSTD_RATIO: usize = 64;
/// §2: flag bits.
pub const FLAG_MERGED: u32 = 1;
pub const FLAG_COMPRESSED: u32 = 2;
pub const FLAG_CLUSTERS: u32 = 4;
pub const FLAG_ROPES: u32 = 8;
pub const FLAG_OCCLUDERS: u32 = 16;
pub const FLAG_PRIMS: u32 = 32;
pub const FLAG_LEAN: u32 = 64;
pub const FLAG_GEOMETRIES: u32 = 128;
/// §8.6: the primitive table's chunk directory entry (`PrimChunk`, 32 bytes) and its fields,
/// a chunk's records (`PrimRecord`, 36 bytes: three corners), primitives per chunk, and the
/// bits of every word of an absent primitive's record.
pub const PRIM_CHUNK_LEN: usize = 32;
pub const PC_OFFSET: usize = 0;
pub const PC_COUNT: usize = 8;
pub const PC_CHECKSUM: usize = 16;
pub const PC_RESERVED: usize = 24;
pub const PRIM_RECORD_LEN: usize = 36;
pub const PRIMS_PER_CHUNK: usize = 4096;
pub const PRIM_ABSENT: u32 = 0xffff_ffff;
/// §8.3: a block's header (112 bytes), and where its counts are: `level_count` (u32), then from
/// `node_count` on seven u64 counts (nodes, ranks, volumes, refs, triangles, wide nodes,
/// groups), then `block_id`, then `rope_count`, `occluder_node_count`, `occluder_count` and
/// `chunk_count`. The level table still starts at 128.
pub const BLOCK_HEADER_LEN: usize = 112;
pub const BH_LEVEL_COUNT: usize = 4;
pub const BH_NODE_COUNT: usize = 16;
pub const BH_GROUP_COUNT: usize = 64;
pub const BH_BLOCK_ID: usize = 72;
pub const BH_ROPE_COUNT: usize = 80;
pub const BH_OCCLUDER_NODE_COUNT: usize = 88;
pub const BH_OCCLUDER_COUNT: usize = 96;
pub const BH_CHUNK_COUNT: usize = 104;
/// §8.3: a block's parts, in the order they are stored: the level table, nodes, ranks,
/// volumes, refs, triangles and wide nodes (these seven have their place even when empty, each
/// at the next multiple of 64), then the ropes, the occluder nodes, the occluders and the chunk
/// table (each only when not empty, at the next multiple of 64), then the groups (only when
/// there are some, at the next multiple of `GROUPS_ALIGN`). The *head* is everything before
/// the groups.
pub const BLOCK_PART_COUNT: usize = 12;
pub const FIXED_PARTS: usize = 7;
pub const PART_LEVELS: usize = 0;
pub const PART_NODES: usize = 1;
pub const PART_RANKS: usize = 2;
pub const PART_VOLUMES: usize = 3;
pub const PART_REFS: usize = 4;
pub const PART_TRIANGLES: usize = 5;
pub const PART_CLUSTER_NODES: usize = 6;
pub const PART_ROPES: usize = 7;
pub const PART_OCCLUDER_NODES: usize = 8;
pub const PART_OCCLUDERS: usize = 9;
pub const PART_CHUNKS: usize = 10;
pub const PART_GROUPS: usize = 11;
/// §8.3: the size of a record of each part, in part order.
pub const PART_RECORD_LEN: [usize; BLOCK_PART_COUNT] =
    [32, 8, 16, 24, 4, 40, 80, 24, 8, 40, 16, 160];
/// §8.3: where in a block's header the count of each part is (`level_count` is a u32, the
/// others u64), in part order.
pub const PART_COUNT_AT: [usize; BLOCK_PART_COUNT] = [
    BH_LEVEL_COUNT,
    BH_NODE_COUNT,
    BH_NODE_COUNT + 8,
    BH_NODE_COUNT + 16,
    BH_NODE_COUNT + 24,
    BH_NODE_COUNT + 32,
    BH_NODE_COUNT + 40,
    BH_ROPE_COUNT,
    BH_OCCLUDER_NODE_COUNT,
    BH_OCCLUDER_COUNT,
    BH_CHUNK_COUNT,
    BH_GROUP_COUNT,
];
/// §8.3: the groups start at a multiple of this from the block's start.
pub const GROUPS_ALIGN: usize = 4096;
/// §8.3: an entry of the chunk table (`ChunkEntry`, 16 bytes): `offset` (u32, from the end of
/// the head's stored bytes), `stored_len` (u32: the chunk's raw length, a raw chunk; shorter,
/// one zstd frame), `checksum` (u64, xxh3-64 of the chunk's stored bytes).
pub const CHUNK_ENTRY_LEN: usize = 16;
pub const CE_OFFSET: usize = 0;
pub const CE_STORED_LEN: usize = 4;
pub const CE_CHECKSUM: usize = 8;

/// §8.3: the byte ranges of a decoded block's parts (indexed by `PART_*`) from the counts in
/// its header (the first `BLOCK_HEADER_LEN` bytes of `raw`), and the block's length (the end of
/// its last part); `None` if `raw` is shorter than a header or the counts overflow. Checked
/// arithmetic throughout: the fuzz targets call it on any bytes.
pub fn block_layout(raw: &[u8]) -> Option<([std::ops::Range<usize>; BLOCK_PART_COUNT], usize)> {
    let header = raw.get(..BLOCK_HEADER_LEN)?;
    let mut out: [std::ops::Range<usize>; BLOCK_PART_COUNT] = Default::default();
    let mut at = BLOCK_HEADER_LEN;
    for (i, range) in out.iter_mut().enumerate() {
        let c = PART_COUNT_AT[i];
        let count = match i {
            PART_LEVELS => u64::from(u32::from_le_bytes(header[c..c + 4].try_into().ok()?)),
            _ => u64::from_le_bytes(header[c..c + 8].try_into().ok()?),
        };
        let count = usize::try_from(count).ok()?;
        if i == PART_GROUPS && count > 0 {
            at = at.checked_next_multiple_of(GROUPS_ALIGN)?;
        } else if i < FIXED_PARTS || count > 0 {
            at = at.checked_next_multiple_of(ALIGN)?;
        }
        let end = at.checked_add(count.checked_mul(PART_RECORD_LEN[i])?)?;
        *range = at..end;
        at = end;
    }
    Some((out, at))
}

/// §8.3: the length of a decoded block's head: where its groups start, or its whole length
/// when it has none.
pub fn head_len(raw: &[u8]) -> Option<usize> {
    let (parts, len) = block_layout(raw)?;
    Some(match parts[PART_GROUPS].is_empty() {
        true => len,
        false => parts[PART_GROUPS].start,
    })
}
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

/// §3: the kinds of the sections a file with these header flags has, in table order: the
/// seven every file has, then the wide nodes and wide links with `CLUSTERS`, then ropes with
/// `ROPES`, then the primitive table with `PRIMS`.
pub fn section_kinds(flags: u32) -> Vec<u32> {
    let mut kinds: Vec<u32> = (1..=SECTION_COUNT as u32).collect();
    if flags & FLAG_CLUSTERS != 0 {
        kinds.extend([KIND_WIDE_NODES, KIND_WIDE_LINKS]);
    }
    if flags & FLAG_ROPES != 0 {
        kinds.push(KIND_ROPES);
    }
    if flags & FLAG_PRIMS != 0 {
        kinds.push(KIND_PRIMS);
    }
    if flags & FLAG_GEOMETRIES != 0 {
        kinds.push(KIND_GEOMETRIES);
    }
    kinds
}

/// §3: the position in the section table of the section of `kind`, if a file with these flags
/// has it.
pub fn section_position(flags: u32, kind: u32) -> Option<usize> {
    section_kinds(flags).iter().position(|&k| k == kind)
}

/// §2.1: where the section table of the slot at `slot_at` starts, and where it ends for a file
/// with these flags (the header checksum covers it; zero bytes follow it to the slot's end).
pub fn table_range(slot_at: usize, flags: u32) -> std::ops::Range<usize> {
    let start = slot_at + HEADER_LEN;
    start..start + section_kinds(flags).len() * ENTRY_LEN
}
