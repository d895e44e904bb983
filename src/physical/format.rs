//! The records of an `.oavm` file. `format-spec.md` is the single description of the bytes; each
//! type here cites the section of the spec it implements and asserts its size at compile time.
//! All multi-byte values are little-endian (spec §1); records are read by casting, so the crate
//! refuses to build file readers on big-endian hosts (see [`super::file`]).

use bytemuck::{Pod, Zeroable};

/// Spec §2: the 8 magic bytes. The high first byte catches 7-bit transfers, `\r\n` and `\x1a`
/// catch text-mode line-ending conversions, as in PNG.
pub const MAGIC: [u8; 8] = *b"\x89OAVM\r\n\x1a";

/// Spec §8: the format version this code reads and writes.
pub const VERSION: u32 = 1;

/// Spec §2: sections start at multiples of this, so records can be cast in place from a map.
pub const SECTION_ALIGN: u64 = 64;

/// Spec §2, `flags` bit 0: empty leaves refer to merged volumes (else one volume per empty leaf).
pub const FLAG_MERGED: u32 = 1;
/// Every flag this version knows; any other bit set is an error at open.
pub const KNOWN_FLAGS: u32 = FLAG_MERGED;

/// Spec §2: the file header, at offset 0 (256 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Header {
    pub magic: [u8; 8],
    pub version: u32,
    pub flags: u32,
    /// `size_of::<Header>()`; lets a reader check it is reading the header it expects.
    pub header_size: u32,
    pub section_count: u32,
    pub section_table_offset: u64,
    /// Exact length of the file in bytes.
    pub file_size: u64,
    /// Lowest corner of the root cube, world units.
    pub root_min: [f64; 3],
    /// Edge length of the root cube, world units.
    pub root_size: f64,
    /// Bounding box of the mesh's triangles, world units.
    pub mesh_min: [f32; 3],
    pub mesh_max: [f32; 3],
    /// Triangles in the input mesh: every primitive id stored is below this.
    pub input_triangles: u64,
    pub empty_leaves: u64,
    /// Leaves holding at least one triangle reference.
    pub solid_leaves: u64,
    /// Number of levels (the root is level 0), at most `LATTICE_BITS + 1`.
    pub level_count: u32,
    /// Bits per axis of the lattice that volumes and traversal use; 21 in this version.
    pub lattice_bits: u32,
    /// Build options (spec §2): maximum depth `D` and leaf size `K`.
    pub max_depth: u32,
    pub leaf_size: u32,
    /// Zero in this version.
    pub reserved: [u64; 14],
    /// xxh3-64 of the header's first 248 bytes followed by the whole section table.
    pub checksum: u64,
}
const _: () = assert!(std::mem::size_of::<Header>() == 256);

/// Offset of [`Header::checksum`]: everything before it is covered by it.
pub const HEADER_CHECKED_LEN: usize = std::mem::offset_of!(Header, checksum);

/// Spec §3: the kinds of section, in the order they appear in the file.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SectionKind {
    Levels = 1,
    Nodes = 2,
    Ranks = 3,
    Volumes = 4,
    Refs = 5,
    Triangles = 6,
}

impl SectionKind {
    pub const ALL: [SectionKind; 6] = [
        SectionKind::Levels,
        SectionKind::Nodes,
        SectionKind::Ranks,
        SectionKind::Volumes,
        SectionKind::Refs,
        SectionKind::Triangles,
    ];

    pub fn from_u32(v: u32) -> Option<SectionKind> {
        SectionKind::ALL.into_iter().find(|k| *k as u32 == v)
    }

    pub fn name(self) -> &'static str {
        match self {
            SectionKind::Levels => "levels",
            SectionKind::Nodes => "nodes",
            SectionKind::Ranks => "ranks",
            SectionKind::Volumes => "volumes",
            SectionKind::Refs => "refs",
            SectionKind::Triangles => "triangles",
        }
    }

    /// Size of one record of this section.
    pub fn record_size(self) -> u64 {
        (match self {
            SectionKind::Levels => std::mem::size_of::<LevelEntry>(),
            SectionKind::Nodes => std::mem::size_of::<NodeRecord>(),
            SectionKind::Ranks => std::mem::size_of::<RankWord>(),
            SectionKind::Volumes => std::mem::size_of::<VolumeRecord>(),
            SectionKind::Refs => std::mem::size_of::<u32>(),
            SectionKind::Triangles => std::mem::size_of::<TriRecord>(),
        }) as u64
    }
}

/// Spec §3: one entry of the section table (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct SectionEntry {
    /// A [`SectionKind`].
    pub kind: u32,
    /// 0: stored raw. Other values are reserved for block compression.
    pub codec: u32,
    pub offset: u64,
    pub length: u64,
    /// Number of records; `length == count * record_size`.
    pub count: u64,
    /// 0 in this version. Reserved for the offset of the section's block directory, when
    /// sections are split into independently compressed blocks.
    pub block_directory: u64,
    /// xxh3-64 of the section's `length` bytes.
    pub checksum: u64,
}
const _: () = assert!(std::mem::size_of::<SectionEntry>() == 48);

/// Spec §4.1: where each level's records start (32 bytes per level).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct LevelEntry {
    pub node_count: u64,
    /// Internal nodes of this level; the next level has exactly 8 times as many nodes.
    pub internal_count: u64,
    /// Index in the nodes section of this level's first record.
    pub node_start: u64,
    /// Index in the ranks section of this level's first rank word.
    pub rank_start: u64,
}
const _: () = assert!(std::mem::size_of::<LevelEntry>() == 32);

/// Spec §4.3: rank directory word for 64 consecutive nodes of a level (16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RankWord {
    /// Bit `i` set: node `64 w + i` of the level is internal.
    pub internal: u64,
    /// Internal nodes of the level before node `64 w`.
    pub rank: u64,
}
const _: () = assert!(std::mem::size_of::<RankWord>() == 16);

/// Spec §4.2: one node (8 bytes). What `payload` means depends on the kind in `meta`'s top bits.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct NodeRecord {
    /// Empty leaf: index of its merged volume. Solid leaf: index of its first triangle reference.
    /// Internal node: 0 (reserved).
    pub payload: u32,
    /// Bits 30..31: the [`NodeKind`]. Bits 0..29: solid leaf: number of references; else 0.
    pub meta: u32,
}
const _: () = assert!(std::mem::size_of::<NodeRecord>() == 8);

/// Spec §4.2: the kinds of node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeKind {
    /// A leaf with no triangle; the ray skips its whole merged volume.
    Empty { volume: u32 },
    /// A leaf with `count` triangle references starting at reference `first`.
    Solid { first: u32, count: u32 },
    /// A node with 8 children at the next level.
    Internal,
}

/// Largest reference count a solid leaf can record (30 bits).
pub const MAX_LEAF_REFS: u32 = (1 << 30) - 1;
const KIND_SHIFT: u32 = 30;
const KIND_EMPTY: u32 = 0;
const KIND_SOLID: u32 = 1;
const KIND_INTERNAL: u32 = 2;

impl NodeRecord {
    pub fn empty(volume: u32) -> NodeRecord {
        NodeRecord {
            payload: volume,
            meta: KIND_EMPTY << KIND_SHIFT,
        }
    }

    pub fn solid(first: u32, count: u32) -> NodeRecord {
        debug_assert!(count > 0 && count <= MAX_LEAF_REFS);
        NodeRecord {
            payload: first,
            meta: KIND_SOLID << KIND_SHIFT | count,
        }
    }

    pub fn internal() -> NodeRecord {
        NodeRecord {
            payload: 0,
            meta: KIND_INTERNAL << KIND_SHIFT,
        }
    }

    /// Decodes the record; `None` for bit patterns no writer produces (corruption).
    #[inline]
    pub fn kind(self) -> Option<NodeKind> {
        let low = self.meta & MAX_LEAF_REFS;
        match self.meta >> KIND_SHIFT {
            KIND_EMPTY if low == 0 => Some(NodeKind::Empty {
                volume: self.payload,
            }),
            KIND_SOLID if low != 0 => Some(NodeKind::Solid {
                first: self.payload,
                count: low,
            }),
            KIND_INTERNAL if low == 0 && self.payload == 0 => Some(NodeKind::Internal),
            _ => None,
        }
    }
}

/// Spec §5: a merged empty volume, an axis-aligned box of lattice cells (24 bytes).
/// `lo` is inclusive, `hi` exclusive: the box covers lattice cells `lo[k] <= c < hi[k]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Pod, Zeroable)]
pub struct VolumeRecord {
    pub lo: [u32; 3],
    pub hi: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<VolumeRecord>() == 24);

/// Spec §7: a triangle as the watertight test wants it: its three corners and its primitive id
/// (40 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TriRecord {
    pub v: [[f32; 3]; 3],
    pub prim: u32,
}
const _: () = assert!(std::mem::size_of::<TriRecord>() == 40);

/// Rounds `x` up to the next multiple of [`SECTION_ALIGN`].
pub fn align_up(x: u64) -> u64 {
    x.div_ceil(SECTION_ALIGN) * SECTION_ALIGN
}

/// xxh3-64, the checksum of every section and of the header (spec §1).
pub fn checksum(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_kinds_round_trip_and_reject_garbage() {
        assert_eq!(
            NodeRecord::empty(7).kind(),
            Some(NodeKind::Empty { volume: 7 })
        );
        assert_eq!(
            NodeRecord::solid(9, 3).kind(),
            Some(NodeKind::Solid { first: 9, count: 3 })
        );
        assert_eq!(NodeRecord::internal().kind(), Some(NodeKind::Internal));
        assert_eq!(
            NodeRecord {
                payload: 0,
                meta: 3 << 30
            }
            .kind(),
            None
        );
        assert_eq!(
            NodeRecord {
                payload: 0,
                meta: 1 << 30
            }
            .kind(),
            None
        ); // solid, 0 refs
        assert_eq!(
            NodeRecord {
                payload: 1,
                meta: 2 << 30
            }
            .kind(),
            None
        ); // internal, payload
        assert_eq!(
            NodeRecord {
                payload: 1,
                meta: 5
            }
            .kind(),
            None
        ); // empty, count bits
    }
}
