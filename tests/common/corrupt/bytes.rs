//! The byte layout these tests need beyond `common::layout` (format-spec.md §2–§8, version 5,
//! shared with the fuzz targets): records' fields by name, the sections, the directory, the
//! primitive chunks and a block's parts read from a file's bytes, and the checksums and the
//! layout a tool that rewrites a file would recompute.

use std::ops::Range;

use xxhash_rust::xxh3::xxh3_64;

use super::*;

/// §3: the section table of a file with ropes (and no primitive table): eight entries, the
/// eighth the ropes.
pub const SECTION_COUNT_ROPES: usize = 8;
/// §3: the ropes' position in the section table of a file with ropes (kind 8).
pub const ROPES: usize = 7;
/// Indices into [`SECTIONS`] (the sections after the blocks, by kind: `kind - 2`) of the ropes
/// and of the primitive table's chunk directory.
pub const SECTION_ROPES: usize = KIND_ROPES as usize - 2;
pub const SECTION_PRIMS: usize = KIND_PRIMS as usize - 2;
/// §8.5: an occluder node entry (`OccluderNode`: `node`, `first`) and an occluder (a
/// `TriRecord`, §7: three corners and the primitive id).
pub const OCCLUDER_NODE_LEN: usize = 8;
pub const TRI_LEN: usize = 40;
/// §8.4: a rope record (u32[6], one rope per face) and its special values.
pub const ROPE_LEN: usize = 24;
pub const ROPE_EXIT: u32 = 0xffff_ffff;
pub const ROPE_TOP: u32 = 0x8000_0000;

/// §2.1: the generation in the header slot at `slot`, if the slot holds a header (its magic).
pub fn slot_generation(b: &[u8], slot: usize) -> Option<u64> {
    (b.len() >= slot + HEADER_LEN && b[slot..slot + 8] == MAGIC[..])
        .then(|| read_u64(b, slot + GENERATION_AT))
}

/// §2.1: the offset of the header slot a reader takes in the file `b` (the one of the highest
/// generation), judged by the magic and the generation field alone: right for an intact file,
/// and for the changes these tests make (which pass the slot themselves where it matters).
pub fn slot_of(b: &[u8]) -> usize {
    match (slot_generation(b, 0), slot_generation(b, HEADER_SLOTS[1])) {
        (Some(g0), Some(g1)) if g1 > g0 => HEADER_SLOTS[1],
        (None, Some(_)) => HEADER_SLOTS[1],
        _ => 0,
    }
}

/// §2: the flags of the header in the slot at `slot` (0 past the end of `b`).
pub fn flags_at(b: &[u8], slot: usize) -> u32 {
    match b.len() >= slot + FLAGS_AT + 4 {
        true => read_u32(b, slot + FLAGS_AT),
        false => 0,
    }
}

/// §2–§3: how many sections the file `b` has, from the flags of its slot's header (7, plus 1
/// with `ROPES`, plus 1 with `PRIMS`).
pub fn section_count(b: &[u8]) -> usize {
    section_kinds(flags_at(b, slot_of(b))).len()
}

/// §2–§3: where the section table of the file `b` ends (the header checksum covers it).
pub fn table_end(b: &[u8]) -> usize {
    let slot = slot_of(b);
    table_range(slot, flags_at(b, slot)).end
}

/// Fields of a record: (offset in the record, name).
pub type Fields = &'static [(usize, &'static str)];

pub const LEVEL_FIELDS: Fields = &[
    (0, "node_count"),
    (8, "internal_count"),
    (16, "node_start"),
    (24, "rank_start"),
];
pub const NODE_FIELDS: Fields = &[(0, "payload"), (4, "meta")];
pub const RANK_FIELDS: Fields = &[(0, "internal"), (8, "rank")];
pub const VOLUME_FIELDS: Fields = &[(0, "lo"), (12, "hi")];
/// §8.1: a link's bounds, in 256ths of its cell.
pub const LINK_BOUNDS_FIELDS: Fields = &[(0, "lo"), (3, "hi"), (6, "reserved")];
/// §8.4: a rope record: the rope of each face, `2 * axis + positive`.
pub const ROPE_FIELDS: Fields = &[
    (0, "-x"),
    (4, "+x"),
    (8, "-y"),
    (12, "+y"),
    (16, "-z"),
    (20, "+z"),
];
/// §7: a triangle record (a file of lists' triangles, and every file's occluders, §8.5).
pub const TRI_FIELDS: Fields = &[(0, "v"), (36, "prim")];
/// §8.5: an occluder node entry: an internal node of the block, its first occluder.
pub const OCCLUDER_NODE_FIELDS: Fields = &[(0, "node"), (4, "first")];
/// §7.1: a cluster node: its quantisation grid, its children, their boxes.
pub const CLUSTER_NODE_FIELDS: Fields = &[
    (CN_ORIGIN, "origin"),
    (CN_EXP, "exp"),
    (CN_CHILD_COUNT, "child_count"),
    (CN_NODE_BASE, "node_base"),
    (CN_GROUP_BASE, "group_base"),
    (CN_INNER_COUNT, "inner_count"),
    (25, "reserved"),
    (CN_LO, "lo"),
    (CN_HI, "hi"),
];
/// §7.2: a triangle group: distinct corners, each lane's corner slots, lanes in use, ids.
pub const GROUP_FIELDS: Fields = &[
    (TG_CORNER, "corner"),
    (TG_TRI, "tri"),
    (TG_COUNT, "count"),
    (124, "reserved"),
    (TG_PRIM, "prim"),
];

/// §8.2: the fields of a directory entry.
pub const DIR_FIELDS: Fields = &[
    (DIR_OFFSET, "offset"),
    (DIR_STORED_LEN, "stored_len"),
    (DIR_RAW_LEN, "raw_len"),
    (DIR_CODEC, "codec"),
    (DIR_ROOT_LEVEL, "root_level"),
    (DIR_ROOT_COUNT, "root_count"),
    (DIR_TRIANGLES, "triangles"),
    (DIR_CHECKSUM, "checksum"),
];

/// §8.6: an entry of the primitive table's chunk directory.
pub const PRIM_CHUNK_FIELDS: Fields = &[
    (PC_OFFSET, "offset"),
    (PC_COUNT, "count"),
    (PC_CHECKSUM, "checksum"),
    (PC_RESERVED, "reserved"),
];
/// §8.6: a primitive's record in a chunk: its three corners.
pub const PRIM_RECORD_FIELDS: Fields = &[(0, "v[0]"), (12, "v[1]"), (24, "v[2]")];

/// §3, §8.2, §4–§5, §8.1, §8.4, §8.6: the sections after the blocks, by kind (index `kind -
/// 2`), with their record sizes and fields (named as the code names them: "levels section"
/// and so on). The ropes only in a file with flag `ROPES`, the primitive table's chunk
/// directory only in one with `PRIMS`.
pub const SECTIONS: [(&str, usize, Fields); 8] = [
    ("block directory", DIR_LEN, DIR_FIELDS),
    ("levels", 32, LEVEL_FIELDS),
    ("nodes", 8, NODE_FIELDS),
    ("ranks", 16, RANK_FIELDS),
    ("volumes", 24, VOLUME_FIELDS),
    ("link bounds", 8, LINK_BOUNDS_FIELDS),
    ("ropes", ROPE_LEN, ROPE_FIELDS),
    ("primitive table", PRIM_CHUNK_LEN, PRIM_CHUNK_FIELDS),
];

/// §8.3: the parts of a block after its header, in order, with their record sizes and fields.
/// A file of lists has no cluster nodes or groups, a file of clusters no refs or triangles; a
/// file without ropes no ropes (§8.4); a file without occluders, or a block that holds none,
/// no occluder nodes or occluders (§8.5).
pub const BLOCK_PARTS: [(&str, usize, Fields); BLOCK_PART_COUNT] = [
    ("levels", 32, LEVEL_FIELDS),
    ("nodes", 8, NODE_FIELDS),
    ("ranks", 16, RANK_FIELDS),
    ("volumes", 24, VOLUME_FIELDS),
    ("refs", 4, &[(0, "reference")]),
    ("triangles", TRI_LEN, TRI_FIELDS),
    ("cluster nodes", CLUSTER_NODE_LEN, CLUSTER_NODE_FIELDS),
    ("groups", TRI_GROUP_LEN, GROUP_FIELDS),
    ("ropes", ROPE_LEN, ROPE_FIELDS),
    ("occluder nodes", OCCLUDER_NODE_LEN, OCCLUDER_NODE_FIELDS),
    ("occluders", TRI_LEN, TRI_FIELDS),
];
/// Indices into [`BLOCK_PARTS`].
pub const PART_NODES: usize = 1;
pub const PART_REFS: usize = 4;
pub const PART_TRIANGLES: usize = 5;
pub const PART_CLUSTER_NODES: usize = 6;
pub const PART_GROUPS: usize = 7;
pub const PART_ROPES: usize = 8;
pub const PART_OCCLUDER_NODES: usize = 9;
pub const PART_OCCLUDERS: usize = 10;

/// §8.3: the fields of a block's header.
pub const BLOCK_HEADER_FIELDS: Fields = &[
    (0, "tag"),
    (4, "level_count"),
    (8, "root_level"),
    (12, "root_count"),
    (16, "node_count"),
    (24, "rank_count"),
    (32, "volume_count"),
    (40, "ref_count"),
    (48, "triangle_count"),
    (56, "cluster_node_count"),
    (64, "group_count"),
    (BH_BLOCK_ID, "block_id"),
    (BH_ROPE_COUNT, "rope_count"),
    (BH_OCCLUDER_NODE_COUNT, "occluder_node_count"),
    (BH_OCCLUDER_COUNT, "occluder_count"),
];

/// §2: the header's fields (offset, name).
pub const HEADER_FIELDS: Fields = &[
    (0, "magic"),
    (8, "version"),
    (12, "flags"),
    (16, "header_size"),
    (20, "section_count"),
    (24, "section_table_offset"),
    (32, "file_size"),
    (40, "root_min"),
    (64, "root_size"),
    (72, "mesh_min"),
    (84, "mesh_max"),
    (96, "input_triangles"),
    (104, "empty_leaves"),
    (112, "solid_leaves"),
    (120, "level_count"),
    (124, "lattice_bits"),
    (128, "max_depth"),
    (132, "leaf_size"),
    (136, "block_count"),
    (144, "max_block_raw_len"),
    (152, "block_triangles"),
    (160, "stored_triangles"),
    (GENERATION_AT, "generation"),
    (RESERVED_AT, "reserved"),
    (HEADER_CHECKSUM, "checksum"),
];

/// §3: the fields of a section table entry.
pub const ENTRY_FIELDS: Fields = &[
    (0, "kind"),
    (4, "codec"),
    (8, "offset"),
    (16, "length"),
    (24, "count"),
    (32, "block_directory"),
    (40, "checksum"),
];

pub fn read_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

pub fn read_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

pub fn write_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

pub fn write_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// §3: the offset and length of the section at position `i` of the table of the file `b`
/// (the table of its slot, [`slot_of`]).
pub fn section(b: &[u8], i: usize) -> (usize, usize) {
    section_in(b, slot_of(b), i)
}

/// §3: the same, in the table of the header slot at `slot`.
pub fn section_in(b: &[u8], slot: usize, i: usize) -> (usize, usize) {
    let e = slot + HEADER_LEN + i * ENTRY_LEN;
    (
        read_u64(b, e + ENTRY_OFFSET) as usize,
        read_u64(b, e + ENTRY_LENGTH) as usize,
    )
}

/// §3: the offset and length of the section of `kind` of the file `b`, if its flags give it
/// one (ropes with `ROPES`, the primitive table with `PRIMS`).
pub fn section_of(b: &[u8], kind: u32) -> Option<(usize, usize)> {
    let slot = slot_of(b);
    section_position(flags_at(b, slot), kind).map(|i| section_in(b, slot, i))
}

/// §8.2: a directory entry, read from the file.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    pub offset: usize,
    pub stored_len: usize,
    pub raw_len: usize,
    pub codec: u32,
    pub root_level: u32,
    pub root_count: u32,
    /// All 48 bytes zero: a free entry (§8.2; generations after the first only).
    pub free: bool,
}

impl Entry {
    pub fn stored(&self) -> Range<usize> {
        self.offset..self.offset + self.stored_len
    }
}

pub fn directory(b: &[u8]) -> Vec<Entry> {
    let (offset, length) = section(b, DIRECTORY);
    (0..length / DIR_LEN)
        .map(|i| {
            let e = offset + i * DIR_LEN;
            Entry {
                offset: read_u64(b, e + DIR_OFFSET) as usize,
                stored_len: read_u64(b, e + DIR_STORED_LEN) as usize,
                raw_len: read_u64(b, e + DIR_RAW_LEN) as usize,
                codec: read_u32(b, e + DIR_CODEC),
                root_level: read_u32(b, e + DIR_ROOT_LEVEL),
                root_count: read_u32(b, e + DIR_ROOT_COUNT),
                free: b[e..e + DIR_LEN].iter().all(|&x| x == 0),
            }
        })
        .collect()
}

/// Where directory entry `i` starts in the file.
pub fn dir_entry_at(b: &[u8], i: usize) -> usize {
    section(b, DIRECTORY).0 + i * DIR_LEN
}

/// §8.6: a primitive chunk, as the chunk directory gives it.
#[derive(Clone, Copy, Debug)]
pub struct Chunk {
    pub offset: usize,
    pub count: usize,
}

impl Chunk {
    /// Where its records are.
    pub fn records(&self) -> Range<usize> {
        self.offset..self.offset + self.count * PRIM_RECORD_LEN
    }
}

/// §8.6: the primitive chunks of the file `b` (none without flag `PRIMS`).
pub fn prim_chunks(b: &[u8]) -> Vec<Chunk> {
    let Some((offset, length)) = section_of(b, KIND_PRIMS) else {
        return Vec::new();
    };
    (0..length / PRIM_CHUNK_LEN)
        .map(|c| {
            let e = offset + c * PRIM_CHUNK_LEN;
            Chunk {
                offset: read_u64(b, e + PC_OFFSET) as usize,
                count: read_u64(b, e + PC_COUNT) as usize,
            }
        })
        .collect()
}

/// Where primitive `prim`'s record (§8.6: 36 bytes, its three corners) is in the file `b`.
pub fn prim_record_at(b: &[u8], prim: usize) -> usize {
    let chunk = prim_chunks(b)[prim / PRIMS_PER_CHUNK];
    chunk.offset + (prim % PRIMS_PER_CHUNK) * PRIM_RECORD_LEN
}

/// §8.3: the byte ranges of a decoded block's eleven parts, from its header's counts:
/// `level_count` (u32), the seven u64 counts from `node_count` on (nodes, ranks, volumes, refs,
/// triangles, cluster nodes, groups), then, past `block_id`, `rope_count`,
/// `occluder_node_count` and `occluder_count`. Each part at the next multiple of 64, but the
/// late parts (ropes, occluder nodes, occluders) take no place when absent (count 0): a block
/// without them ends at the end of its groups.
pub fn block_parts(raw: &[u8]) -> [Range<usize>; BLOCK_PART_COUNT] {
    let counts: [usize; BLOCK_PART_COUNT] = std::array::from_fn(|i| match i {
        0 => read_u32(raw, BH_LEVEL_COUNT) as usize,
        PART_ROPES => read_u64(raw, BH_ROPE_COUNT) as usize,
        PART_OCCLUDER_NODES => read_u64(raw, BH_OCCLUDER_NODE_COUNT) as usize,
        PART_OCCLUDERS => read_u64(raw, BH_OCCLUDER_COUNT) as usize,
        _ => read_u64(raw, BH_NODE_COUNT + 8 * (i - 1)) as usize,
    });
    let mut at = BLOCK_HEADER_LEN;
    std::array::from_fn(|i| {
        if i < FIRST_LATE_PART || counts[i] > 0 {
            at = at.next_multiple_of(ALIGN);
        }
        let r = at..at + counts[i] * BLOCK_PARTS[i].1;
        at = r.end;
        r
    })
}

/// §7, §7.2: every triangle a decoded block stores, as the 40 bytes of a triangle record (§7:
/// corners, then primitive id): its triangle records (a file of lists), or each lane in use of
/// its groups (a file of clusters), the corners its slots name in their order. An occluder
/// (§8.5) is one of these, byte for byte.
pub fn block_triangles(raw: &[u8]) -> Vec<[u8; TRI_LEN]> {
    let parts = block_parts(raw);
    let mut out: Vec<[u8; TRI_LEN]> = parts[PART_TRIANGLES]
        .clone()
        .step_by(TRI_LEN)
        .map(|at| raw[at..at + TRI_LEN].try_into().expect("40 bytes"))
        .collect();
    for g in parts[PART_GROUPS].clone().step_by(TRI_GROUP_LEN) {
        for lane in 0..(read_u32(raw, g + TG_COUNT) as usize).min(8) {
            let mut t = [0u8; TRI_LEN];
            for c in 0..3 {
                let slot = raw[g + TG_TRI + 8 * c + lane] as usize;
                for k in 0..3 {
                    let at = g + TG_CORNER + 4 * (8 * k + slot);
                    t[12 * c + 4 * k..12 * c + 4 * k + 4].copy_from_slice(&raw[at..at + 4]);
                }
            }
            let prim = g + TG_PRIM + 4 * lane;
            t[36..].copy_from_slice(&raw[prim..prim + 4]);
            out.push(t);
        }
    }
    out
}

/// Recomputes the header checksum (§2: xxh3-64 of header bytes 0..248, then the section table:
/// 336 bytes, 48 more with ropes, 48 more with the primitive table, as the header's flags say)
/// of the slot a reader takes ([`slot_of`]).
pub fn fix_header_checksum(b: &mut [u8]) {
    fix_header_checksum_at(b, slot_of(b));
}

/// The same in the header slot at `slot`.
pub fn fix_header_checksum_at(b: &mut [u8], slot: usize) {
    let table = table_range(slot, flags_at(b, slot));
    if b.len() < table.end {
        return;
    }
    let mut covered = b[slot..slot + HEADER_CHECKSUM].to_vec();
    covered.extend_from_slice(&b[table]);
    write_u64(b, slot + HEADER_CHECKSUM, xxh3_64(&covered));
}

/// Recomputes every checksum as a tool that rewrites a file would, so that afterwards only the
/// checks on the contents can tell the file was changed: each block's in its directory entry
/// (§8.2: xxh3-64 of its stored bytes), each primitive chunk's in the chunk directory (§8.6),
/// each section's but the blocks' (§3), then the header's; those of the generation a reader
/// takes ([`slot_of`]). Ranges that are not inside the file are left as they are (open or the
/// pager rejects them).
pub fn fix_checksums(b: &mut [u8]) {
    fix_checksums_at(b, slot_of(b));
}

/// The same for the generation in the header slot at `slot`.
pub fn fix_checksums_at(b: &mut [u8], slot: usize) {
    let flags = flags_at(b, slot);
    if b.len() < table_range(slot, flags).end {
        return;
    }
    let inside = |offset: u64, len: u64, size: usize| {
        offset
            .checked_add(len)
            .filter(|&end| end <= size as u64)
            .map(|end| offset as usize..end as usize)
    };
    let (dir, dir_len) = section_in(b, slot, DIRECTORY);
    if dir.checked_add(dir_len).is_some_and(|end| end <= b.len()) {
        for i in 0..dir_len / DIR_LEN {
            let e = dir + i * DIR_LEN;
            let (offset, len) = (read_u64(b, e + DIR_OFFSET), read_u64(b, e + DIR_STORED_LEN));
            if b[e..e + DIR_LEN].iter().all(|&x| x == 0) {
                continue; // a free entry (§8.2) has no checksum
            }
            if let Some(r) = inside(offset, len, b.len()) {
                let sum = xxh3_64(&b[r]);
                write_u64(b, e + DIR_CHECKSUM, sum);
            }
        }
    }
    if let Some(i) = section_position(flags, KIND_PRIMS) {
        let (at, len) = section_in(b, slot, i);
        if at.checked_add(len).is_some_and(|end| end <= b.len()) {
            for c in 0..len / PRIM_CHUNK_LEN {
                let e = at + c * PRIM_CHUNK_LEN;
                let (offset, count) = (read_u64(b, e + PC_OFFSET), read_u64(b, e + PC_COUNT));
                let len = count.checked_mul(PRIM_RECORD_LEN as u64);
                if let Some(r) = len.and_then(|len| inside(offset, len, b.len())) {
                    let sum = xxh3_64(&b[r]);
                    write_u64(b, e + PC_CHECKSUM, sum);
                }
            }
        }
    }
    for i in DIRECTORY..section_kinds(flags).len() {
        let e = slot + HEADER_LEN + i * ENTRY_LEN;
        let (offset, length) = (read_u64(b, e + ENTRY_OFFSET), read_u64(b, e + ENTRY_LENGTH));
        if let Some(r) = inside(offset, length, b.len()) {
            let sum = xxh3_64(&b[r]);
            write_u64(b, e + ENTRY_CHECKSUM, sum);
        }
    }
    fix_header_checksum_at(b, slot);
}

/// The file `b` (a file as packed: generation 1, in slot 0) with block `block`'s stored bytes
/// replaced by `stored` (and its `raw_len` by `raw_len`), laid out again as §2, §3, §8.2 and
/// §8.6 say: blocks from offset 4096 in directory order (raw ones at multiples of 4096,
/// compressed ones at multiples of 64), then the primitive chunks in order at multiples of 64;
/// the data region ending at the next multiple of 64, where the directory starts, then the top
/// tree's sections and the others, each at the next multiple of 64; offsets, lengths, the file
/// size and every checksum rewritten. `b` must be a sound file.
pub fn relayout(b: &[u8], block: usize, stored: &[u8], raw_len: usize) -> Vec<u8> {
    assert_eq!(
        slot_of(b),
        0,
        "relayout lays out a file as packed (generation 1)"
    );
    let dir = directory(b);
    let mut out = b[..BLOCKS_START].to_vec();
    let mut dir_bytes = {
        let (o, l) = section(b, DIRECTORY);
        b[o..o + l].to_vec()
    };
    for (i, e) in dir.iter().enumerate() {
        let align = if e.codec == CODEC_RAW {
            RAW_ALIGN
        } else {
            ALIGN
        };
        out.resize(out.len().next_multiple_of(align), 0);
        let bytes = if i == block { stored } else { &b[e.stored()] };
        write_u64(&mut dir_bytes, i * DIR_LEN + DIR_OFFSET, out.len() as u64);
        write_u64(
            &mut dir_bytes,
            i * DIR_LEN + DIR_STORED_LEN,
            bytes.len() as u64,
        );
        if i == block {
            write_u64(&mut dir_bytes, i * DIR_LEN + DIR_RAW_LEN, raw_len as u64);
        }
        out.extend_from_slice(bytes);
    }
    let mut prims_bytes = section_of(b, KIND_PRIMS)
        .map(|(o, l)| b[o..o + l].to_vec())
        .unwrap_or_default();
    for (c, chunk) in prim_chunks(b).iter().enumerate() {
        out.resize(out.len().next_multiple_of(ALIGN), 0);
        write_u64(
            &mut prims_bytes,
            c * PRIM_CHUNK_LEN + PC_OFFSET,
            out.len() as u64,
        );
        out.extend_from_slice(&b[chunk.records()]);
    }
    out.resize(out.len().next_multiple_of(ALIGN), 0);
    let kinds = section_kinds(flags_at(b, 0));
    let table = table_range(0, flags_at(b, 0));
    let mut t = b[table.clone()].to_vec();
    write_u64(
        &mut t,
        BLOCKS * ENTRY_LEN + ENTRY_LENGTH,
        (out.len() - BLOCKS_START) as u64,
    );
    for (i, &kind) in kinds.iter().enumerate().skip(DIRECTORY) {
        out.resize(out.len().next_multiple_of(ALIGN), 0);
        let bytes = match kind {
            _ if i == DIRECTORY => dir_bytes.clone(),
            KIND_PRIMS => prims_bytes.clone(),
            _ => {
                let (o, l) = section(b, i);
                b[o..o + l].to_vec()
            }
        };
        write_u64(&mut t, i * ENTRY_LEN + ENTRY_OFFSET, out.len() as u64);
        out.extend_from_slice(&bytes);
    }
    out[table].copy_from_slice(&t);
    let len = out.len() as u64;
    write_u64(&mut out, FILE_SIZE_AT, len);
    fix_checksums_at(&mut out, 0);
    out
}

pub fn zstd_frame(raw: &[u8]) -> Vec<u8> {
    zstd::bulk::compress(raw, 3).expect("compress")
}
