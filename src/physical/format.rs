//! The records of an `.oavm` file. `format-spec.md` is the single description of the bytes; each
//! type here cites the section of the spec it implements and asserts its size at compile time.
//! All multi-byte values are little-endian (spec §1); records are read by casting, so the crate
//! refuses to build file readers on big-endian hosts (see [`super::file`]).

use bytemuck::{Pod, Zeroable};

/// Spec §2: the 8 magic bytes. The high first byte catches 7-bit transfers, `\r\n` and `\x1a`
/// catch text-mode line-ending conversions, as in PNG.
pub const MAGIC: [u8; 8] = *b"\x89OAVM\r\n\x1a";

/// Spec §12: the format version this code reads and writes.
pub const VERSION: u32 = 7;

/// Spec §2: sections start at multiples of this, so records can be cast in place from a map.
pub const SECTION_ALIGN: u64 = 64;

/// Spec §2 (`lattice_bits`), §4: bits per axis of the integer lattice over the root cube that
/// node codes, volumes and traversal use. Codes of the deepest level use `3 * 21 = 63` bits.
pub const LATTICE_BITS: u32 = 21;
/// Number of lattice cells along each axis of the root cube.
pub const LATTICE_SIZE: u32 = 1 << LATTICE_BITS;
/// Deepest level a tree may have (level 0 is the root): one level per lattice bit.
pub const MAX_LEVEL: u32 = LATTICE_BITS;

/// Spec §6: every cell is enlarged by this many lattice units (of the `2^21` lattice; `2^-20` of
/// the root's edge) on each side when triangles are assigned to it, and solid leaves' tight
/// bounds are widened by as much. A triangle lying on, or within floating-point error of, a face
/// between two cells is thereby referenced by both, so a ray whose traversal rounds onto the
/// other side of that face still meets it: no ray slips through the crack between cells. It is
/// far above the f64 error of traversal (about `2^-31` units).
pub const CELL_MARGIN: f64 = 2.0;

/// Spec §2, `flags` bit 0: empty leaves refer to merged volumes (else one volume per empty leaf).
pub const FLAG_MERGED: u32 = 1;
/// Spec §2, `flags` bit 1: at least one block is stored compressed.
pub const FLAG_COMPRESSED: u32 = 2;
/// Spec §2, `flags` bit 2: solid leaves are clusters (spec §7.1, a wide BVH over triangle
/// groups); clear: solid leaves list references to triangle records (spec §6, §7), the paper's
/// structure (`oavm-pack --leaf list`).
pub const FLAG_CLUSTERS: u32 = 4;
/// Spec §2, `flags` bit 3: the file holds ropes (spec §8.4): for every leaf and link, the node
/// across each face of the box a walk crosses there, in an eighth section (the top tree) and
/// a ninth part of every block (`oavm-pack --ropes`).
pub const FLAG_ROPES: u32 = 8;
/// Spec §2, `flags` bit 4: the file holds occluders (spec §8.5): large triangles also stored at
/// internal nodes of the blocks, where shadow rays test them before descending (the primitive
/// index of Liang and Huang's multi-index tree; `oavm-pack --occluders`).
pub const FLAG_OCCLUDERS: u32 = 16;
/// Spec §2, `flags` bit 5: the file holds its primitive table (spec §8.6): every input
/// triangle's corners by primitive id, in chunks, so that an update (`oavm-update`) finds what
/// changed and where it was (`oavm-pack --updatable`).
pub const FLAG_PRIMS: u32 = 32;
/// Spec §2, `flags` bit 6: blocks may be lean ([`CODEC_LEAN`]: groups stored in the lean
/// encoding of spec §7.3; `oavm-pack --lean`). Such a file also has [`FLAG_COMPRESSED`].
pub const FLAG_LEAN: u32 = 64;
/// Spec §2, `flags` bit 7: the file holds a geometry table (spec §8.8): the meshes the input
/// was made of, each a run of primitive ids, with its name and the transform that placed it
/// (`oavm.pack([...])`, a glTF scene, several meshes given to `oavm-pack`).
pub const FLAG_GEOMETRIES: u32 = 128;
/// Every flag this version knows; any other bit set is an error at open.
pub const KNOWN_FLAGS: u32 = FLAG_MERGED
    | FLAG_COMPRESSED
    | FLAG_CLUSTERS
    | FLAG_ROPES
    | FLAG_OCCLUDERS
    | FLAG_PRIMS
    | FLAG_LEAN
    | FLAG_GEOMETRIES;

/// Spec §2: the offsets of the two header slots. A slot is a header followed by its section
/// table; a reader takes the valid slot of the highest generation (spec §2.1).
pub const HEADER_SLOTS: [u64; 2] = [0, 2048];
/// Spec §2.1: where the data region (the blocks section: blocks and primitive chunks) starts,
/// after both header slots.
pub const DATA_START: u64 = 4096;
/// Spec §2.1: the generation a freshly packed file has (in slot 0; slot 1 is zero).
pub const FIRST_GENERATION: u64 = 1;

/// Spec §2: the file header, at offset 0 (256 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, serde::Serialize)]
pub struct Header {
    pub magic: [u8; 8],
    pub version: u32,
    pub flags: u32,
    /// `size_of::<Header>()`; lets a reader check it is reading the header it expects.
    pub header_size: u32,
    pub section_count: u32,
    pub section_table_offset: u64,
    /// End of this generation's last section: the file is at least this long (spec §2.1).
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
    /// Blocks in the block directory (spec §8).
    pub block_count: u64,
    /// The largest `raw_len` of any block: what one decoded block can need.
    pub max_block_raw_len: u64,
    /// Triangle records over all blocks (a triangle referenced from two blocks is in both).
    pub block_triangles: u64,
    /// Distinct triangles stored (the input minus degenerate ones).
    pub stored_triangles: u64,
    /// Spec §2.1: 1 for a file as packed; each update writes the next in the other slot.
    pub generation: u64,
    /// Spec §8.3: triangle groups per chunk, the unit a block's groups are checked, compressed
    /// and read in: `1..=`[`MAX_CHUNK_GROUPS`] in a file of clusters, 0 in a file of lists.
    pub chunk_groups: u32,
    /// Zero.
    pub reserved_u32: u32,
    /// Zero in this version.
    pub reserved: [u64; 8],
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
    /// The blocks, one after another (spec §8); one "record" per block.
    Blocks = 1,
    /// The block directory (spec §8).
    Directory = 2,
    /// The top tree (spec §4, §8.1): level table, node records, rank words, volumes.
    Levels = 3,
    Nodes = 4,
    Ranks = 5,
    Volumes = 6,
    /// The top tree's link bounds (spec §8.1), one record per top-tree node.
    LinkBounds = 7,
    /// The top tree's ropes (spec §8.4), one record per top-tree node; only in a file with
    /// [`FLAG_ROPES`].
    Ropes = 8,
    /// The primitive table's chunk directory (spec §8.6), one [`PrimChunk`] per
    /// [`PRIM_CHUNK`] primitives; only in a file with [`FLAG_PRIMS`].
    Prims = 9,
    /// The top tree's wide nodes (spec §8.7), one [`ClusterNode`] per internal node of the
    /// top tree that has a child; only in a file with [`FLAG_CLUSTERS`].
    WideNodes = 10,
    /// The links of the top tree's wide nodes (spec §8.7), one [`WideLink`] per link; only in
    /// a file with [`FLAG_CLUSTERS`].
    WideLinks = 11,
    /// The geometry table (spec §8.8), one [`GeometryRecord`] per geometry; only in a file
    /// with [`FLAG_GEOMETRIES`].
    Geometries = 12,
}

impl SectionKind {
    /// Every kind, in file order. A file has the first [`Self::BASE`], then the wide nodes
    /// and links with [`FLAG_CLUSTERS`], [`Self::Ropes`] with [`FLAG_ROPES`] and
    /// [`Self::Prims`] with [`FLAG_PRIMS`] and [`Self::Geometries`] with [`FLAG_GEOMETRIES`],
    /// in this order. (A kind's index in a table of
    /// sections is `kind - 1`, not its place in this order.)
    pub const ALL: [SectionKind; 12] = [
        SectionKind::Blocks,
        SectionKind::Directory,
        SectionKind::Levels,
        SectionKind::Nodes,
        SectionKind::Ranks,
        SectionKind::Volumes,
        SectionKind::LinkBounds,
        SectionKind::WideNodes,
        SectionKind::WideLinks,
        SectionKind::Ropes,
        SectionKind::Prims,
        SectionKind::Geometries,
    ];
    /// Sections every file has.
    pub const BASE: usize = 7;

    /// Whether a file with these header flags has this section.
    pub fn present(self, flags: u32) -> bool {
        match self {
            SectionKind::Ropes => flags & FLAG_ROPES != 0,
            SectionKind::Prims => flags & FLAG_PRIMS != 0,
            SectionKind::Geometries => flags & FLAG_GEOMETRIES != 0,
            SectionKind::WideNodes | SectionKind::WideLinks => flags & FLAG_CLUSTERS != 0,
            _ => true,
        }
    }

    /// The sections a file with these header flags has, in file order.
    pub fn for_flags(flags: u32) -> impl Iterator<Item = SectionKind> {
        SectionKind::ALL
            .into_iter()
            .filter(move |k| k.present(flags))
    }

    /// How many sections a file with these header flags has.
    pub fn count_for(flags: u32) -> usize {
        Self::for_flags(flags).count()
    }

    pub fn from_u32(v: u32) -> Option<SectionKind> {
        SectionKind::ALL.into_iter().find(|k| *k as u32 == v)
    }

    pub fn name(self) -> &'static str {
        match self {
            SectionKind::Blocks => "blocks",
            SectionKind::Directory => "block directory",
            SectionKind::Levels => "levels",
            SectionKind::Nodes => "nodes",
            SectionKind::Ranks => "ranks",
            SectionKind::Volumes => "volumes",
            SectionKind::LinkBounds => "link bounds",
            SectionKind::Ropes => "ropes",
            SectionKind::Prims => "primitive table",
            SectionKind::WideNodes => "wide nodes",
            SectionKind::WideLinks => "wide links",
            SectionKind::Geometries => "geometry table",
        }
    }

    /// Size of one record of this section; `None` for the blocks section, whose blocks have
    /// their own lengths (its `count` is the number of blocks).
    pub fn record_size(self) -> Option<u64> {
        let size = match self {
            SectionKind::Blocks => return None,
            SectionKind::Directory => std::mem::size_of::<BlockEntry>(),
            SectionKind::Levels => std::mem::size_of::<LevelEntry>(),
            SectionKind::Nodes => std::mem::size_of::<NodeRecord>(),
            SectionKind::Ranks => std::mem::size_of::<RankWord>(),
            SectionKind::Volumes => std::mem::size_of::<VolumeRecord>(),
            SectionKind::LinkBounds => std::mem::size_of::<LinkBounds>(),
            SectionKind::Ropes => std::mem::size_of::<RopeRecord>(),
            SectionKind::Prims => std::mem::size_of::<PrimChunk>(),
            SectionKind::WideNodes => std::mem::size_of::<ClusterNode>(),
            SectionKind::WideLinks => std::mem::size_of::<WideLink>(),
            SectionKind::Geometries => std::mem::size_of::<GeometryRecord>(),
        };
        Some(size as u64)
    }
}

/// Spec §8.8: one geometry of the geometry table (160 bytes): the run of primitive ids
/// `first_primitive .. first_primitive + primitive_count` that one input mesh became, the
/// transform its vertices were placed by before they were stored (row-major 3x4, world =
/// `transform * (x, y, z, 1)`; the identity when none), and its name (UTF-8, zero-padded).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GeometryRecord {
    pub first_primitive: u64,
    pub primitive_count: u64,
    pub transform: [[f64; 4]; 3],
    pub name: [u8; GEOMETRY_NAME_LEN],
}
const _: () = assert!(std::mem::size_of::<GeometryRecord>() == 160);

/// Spec §8.8: bytes of a geometry's name; a longer name is cut at a character boundary.
pub const GEOMETRY_NAME_LEN: usize = 48;

/// Spec §8.6: primitives per chunk of the primitive table (the last chunk may hold fewer).
pub const PRIM_CHUNK: u64 = 4096;

/// Spec §8.6: one primitive of the primitive table (36 bytes): its three corners as the input
/// mesh gave them (degenerate triangles too), or all nine words [`PRIM_ABSENT`] for a primitive
/// id that holds no triangle (removed by an update).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PrimRecord {
    pub v: [[f32; 3]; 3],
}
const _: () = assert!(std::mem::size_of::<PrimRecord>() == 36);

/// Spec §8.6: the bits of every word of an absent primitive's record (a NaN, which no input
/// triangle has: meshes with non-finite corners are refused).
pub const PRIM_ABSENT: u32 = u32::MAX;

impl PrimRecord {
    /// The record of an absent primitive.
    pub const ABSENT: PrimRecord = PrimRecord {
        v: [[f32::from_bits(PRIM_ABSENT); 3]; 3],
    };

    /// Whether this record holds no triangle.
    pub fn is_absent(&self) -> bool {
        self.v.iter().flatten().all(|c| c.to_bits() == PRIM_ABSENT)
    }

    /// Whether the two records hold the same bits (corners compared as bits, so that `-0.0`
    /// and `0.0` differ as the stored triangles do).
    pub fn same_bits(&self, other: &PrimRecord) -> bool {
        bytemuck::bytes_of(self) == bytemuck::bytes_of(other)
    }
}

/// Spec §8.6: one entry of the primitive table's chunk directory (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable, serde::Serialize)]
pub struct PrimChunk {
    /// Offset in the file of the chunk's records, a multiple of [`SECTION_ALIGN`] in the data
    /// region (spec §2.1).
    pub offset: u64,
    /// Primitives in the chunk: [`PRIM_CHUNK`], but for the last chunk.
    pub count: u64,
    /// xxh3-64 of the chunk's `count * 36` bytes.
    pub checksum: u64,
    pub reserved: u64,
}
const _: () = assert!(std::mem::size_of::<PrimChunk>() == 32);

/// Spec §3: one entry of the section table (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, serde::Serialize)]
pub struct SectionEntry {
    /// A [`SectionKind`].
    pub kind: u32,
    /// 0. (Blocks carry their own codecs, spec §8.)
    pub codec: u32,
    pub offset: u64,
    pub length: u64,
    /// Number of records; `length == count * record_size`.
    pub count: u64,
    /// 0 in this version (reserved).
    pub block_directory: u64,
    /// xxh3-64 of the section's `length` bytes; 0 for the blocks section, whose blocks are
    /// checksummed one by one in the directory.
    pub checksum: u64,
}
const _: () = assert!(std::mem::size_of::<SectionEntry>() == 48);

/// Spec §8.7: a link of the top tree's wide nodes (32 bytes): root `root` of block `block`,
/// which is node `root` of the block's wide nodes, and that node's box in world units (the
/// union of its children's boxes, exact f32 faces), from which the parent's quantised box is
/// made and an update remakes the top tree without reading the block.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct WideLink {
    pub block: u32,
    pub root: u32,
    pub lo: [f32; 3],
    pub hi: [f32; 3],
}
const _: () = assert!(std::mem::size_of::<WideLink>() == 32);

/// Spec §8.1: the bounds of a link's subtree, in 256ths of the link's cell per axis: the box
/// `[lo, hi + 1) / 256` of the cell contains the tight bounds of every solid leaf below the
/// block root it links to. One record per top-tree node, parallel to the node records; all
/// zero for a node that is not a link.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Pod, Zeroable)]
pub struct LinkBounds {
    pub lo: [u8; 3],
    pub hi: [u8; 3],
    /// Zero.
    pub reserved: [u8; 2],
}
const _: () = assert!(std::mem::size_of::<LinkBounds>() == 8);

impl LinkBounds {
    /// The whole cell.
    pub const FULL: LinkBounds = LinkBounds {
        lo: [0; 3],
        hi: [255; 3],
        reserved: [0; 2],
    };

    /// The smallest bounds containing `[lo, hi]`, given as fractions of the cell (`0..=1`):
    /// rounded outward to 256ths (exact for the dyadic fractions leaf bounds give).
    pub fn enclosing(lo: [f64; 3], hi: [f64; 3]) -> LinkBounds {
        let l: [u8; 3] = std::array::from_fn(|a| (lo[a] * 256.0).floor().clamp(0.0, 255.0) as u8);
        let h: [u8; 3] =
            std::array::from_fn(|a| ((hi[a] * 256.0).ceil() - 1.0).clamp(l[a] as f64, 255.0) as u8);
        LinkBounds {
            lo: l,
            hi: h,
            reserved: [0; 2],
        }
    }

    /// Well-formed as a link's bounds: `lo <= hi` per axis and the reserved bytes zero.
    pub fn is_valid(&self) -> bool {
        (0..3).all(|a| self.lo[a] <= self.hi[a]) && self.reserved == [0; 2]
    }
}

/// Spec §4.1: where each level's records start (32 bytes per level).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, serde::Serialize)]
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
    /// Empty leaf: index of its merged volume. Solid leaf: index of its first triangle reference
    /// (or of its count word, spec §4.2). Internal node: 0 (reserved).
    pub payload: u32,
    /// Bits 30..31: the kind. Solid leaf: bits 24..29 the reference count (0: escape), bits 0..23
    /// the quantised bounds ([`LeafBounds`]). Empty leaf: bits 0..7 the shape of its volume
    /// ([`VolumeShape`]). Internal node: 0.
    pub meta: u32,
}
const _: () = assert!(std::mem::size_of::<NodeRecord>() == 8);

/// Spec §4.2: a solid leaf's tight bounds, in sixteenths of its cell per axis: the box
/// `[lo, hi + 1) / 16` of the cell contains every part of its triangles inside the cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeafBounds {
    pub lo: [u8; 3],
    pub hi: [u8; 3],
}

impl LeafBounds {
    /// The whole cell.
    pub const FULL: LeafBounds = LeafBounds {
        lo: [0; 3],
        hi: [15; 3],
    };

    fn pack(self) -> u32 {
        let q = |v: u8, shift: u32| ((v & 15) as u32) << shift;
        q(self.lo[0], 0)
            | q(self.lo[1], 4)
            | q(self.lo[2], 8)
            | q(self.hi[0], 12)
            | q(self.hi[1], 16)
            | q(self.hi[2], 20)
    }

    /// The bounds packed in `bits` (the low bits of [`NodeRecord::solid_bits`]), unvalidated:
    /// any bits give sixteenths from 0 to 15, so a box inside the cell and its margin. The one
    /// decoder of these bits, for the tracer's walks and for `verify`.
    #[inline(always)]
    pub fn unpack(bits: u32) -> LeafBounds {
        let q = |shift: u32| ((bits >> shift) & 15) as u8;
        LeafBounds {
            lo: [q(0), q(4), q(8)],
            hi: [q(12), q(16), q(20)],
        }
    }

    /// The box in lattice units of these bounds in the cell `[cell_lo, cell_lo + size)`,
    /// widened by `margin` on every side: per axis `cell_lo + lo * size / 16 - margin` to
    /// `cell_lo + (hi + 1) * size / 16 + margin`, in f64 (exact for lattice cells and the
    /// format's margin).
    #[inline(always)]
    pub fn lattice_box(self, cell_lo: [u32; 3], size: u32, margin: f64) -> ([f64; 3], [f64; 3]) {
        let s16 = size as f64 / 16.0;
        (
            std::array::from_fn(|a| cell_lo[a] as f64 + self.lo[a] as f64 * s16 - margin),
            std::array::from_fn(|a| cell_lo[a] as f64 + (self.hi[a] as f64 + 1.0) * s16 + margin),
        )
    }

    /// The edges of the box in lattice units (unwidened) in a cell of edge `size`.
    #[inline(always)]
    pub fn extent(self, size: u32) -> [f64; 3] {
        let s16 = size as f64 / 16.0;
        std::array::from_fn(|a| (self.hi[a] as f64 + 1.0 - self.lo[a] as f64) * s16)
    }

    pub fn is_valid(self) -> bool {
        (0..3).all(|k| self.lo[k] <= self.hi[k] && self.hi[k] < 16)
    }
}

/// Spec §4.2: the shape of an empty leaf's merged volume, as its record also stores it: the
/// volume is the node of level `level` containing the leaf, doubled along each axis in `axes`
/// to the extent of that node's parent. The volume table holds the same box; the tracer rebuilds
/// it from the shape and its position, without reading the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VolumeShape {
    /// Level of the merged nodes (the children of the type-2 node that stopped merging).
    pub level: u8,
    /// Bit `k`: merged with the sibling along axis `k`.
    pub axes: u8,
}

impl VolumeShape {
    fn pack(self) -> u32 {
        (self.axes & 7) as u32 | ((self.level & 31) as u32) << 3
    }

    fn unpack(bits: u32) -> Option<VolumeShape> {
        let s = VolumeShape {
            axes: (bits & 7) as u8,
            level: ((bits >> 3) & 31) as u8,
        };
        let ok = bits >> 8 == 0 && s.level as u32 <= MAX_LEVEL && (s.level > 0 || s.axes == 0);
        ok.then_some(s)
    }

    /// The box, in lattice cells, of this shape around lattice point `q`. Defined for any bits:
    /// a level above 21 counts as 21, and a merge beyond the root gives a box past the lattice,
    /// which ends a walk.
    #[inline(always)]
    pub fn box_around(self, q: [u32; 3]) -> ([u32; 3], [u32; 3]) {
        let size = 1u32 << (MAX_LEVEL - (self.level as u32).min(MAX_LEVEL));
        let mut lo = [0; 3];
        let mut hi = [0; 3];
        for k in 0..3 {
            // Merged along k: the parent's extent (twice the size); else the node's own.
            let span = if self.axes >> k & 1 == 1 {
                size << 1
            } else {
                size
            };
            lo[k] = q[k] & !(span - 1);
            hi[k] = lo[k] + span;
        }
        (lo, hi)
    }
}

/// Spec §4.2: the kinds of node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeKind {
    /// A leaf with no triangle; the ray skips its whole merged volume, entry `volume` of the
    /// volume table, whose box `shape` also gives.
    Empty { volume: u32, shape: VolumeShape },
    /// A leaf with triangles. Its references are the `inline_count` words from `first`, or, when
    /// `inline_count` is 0 (more than [`MAX_INLINE_REFS`] references), the number of words the
    /// word at `first` says, after it. See [`leaf_refs`].
    Solid {
        first: u32,
        inline_count: u32,
        bounds: LeafBounds,
    },
    /// A node with 8 children at the next level.
    Internal,
    /// Top tree only (spec §8.1): the node is root `root` of block `block`, where its subtree is.
    Link { block: u32, root: u32 },
}

/// Largest reference count stored in a solid leaf's record; larger counts are stored in the
/// refs section, in the word before the references.
pub const MAX_INLINE_REFS: u32 = 63;
const KIND_SHIFT: u32 = 30;
const COUNT_SHIFT: u32 = 24;
const BOUNDS_MASK: u32 = (1 << COUNT_SHIFT) - 1;
/// Spec §4.2: the kind bits ([`NodeRecord::kind_bits`]) of an empty leaf.
pub const KIND_EMPTY: u32 = 0;
/// The kind bits of a solid leaf.
pub const KIND_SOLID: u32 = 1;
/// The kind bits of an internal node.
pub const KIND_INTERNAL: u32 = 2;
/// The kind bits of a link (top tree only, spec §8.1).
pub const KIND_LINK: u32 = 3;
/// Largest root index a link can hold (bits 0..29 of `meta`).
pub const MAX_LINK_ROOT: u32 = (1 << KIND_SHIFT) - 1;

impl NodeRecord {
    pub fn empty(volume: u32, shape: VolumeShape) -> NodeRecord {
        NodeRecord {
            payload: volume,
            meta: KIND_EMPTY << KIND_SHIFT | shape.pack(),
        }
    }

    /// A solid leaf whose references start at `first` (its count word, if `count` is above
    /// [`MAX_INLINE_REFS`]).
    pub fn solid(first: u32, count: u32, bounds: LeafBounds) -> NodeRecord {
        debug_assert!(count > 0 && bounds.is_valid());
        let inline = if count <= MAX_INLINE_REFS { count } else { 0 };
        NodeRecord {
            payload: first,
            meta: KIND_SOLID << KIND_SHIFT | inline << COUNT_SHIFT | bounds.pack(),
        }
    }

    /// A solid leaf of a file of clusters (spec §4.2, §7.1): its cluster's root is node `root`
    /// of the block's cluster nodes.
    pub fn cluster(root: u32, bounds: LeafBounds) -> NodeRecord {
        debug_assert!(bounds.is_valid());
        NodeRecord {
            payload: root,
            meta: KIND_SOLID << KIND_SHIFT | bounds.pack(),
        }
    }

    pub fn internal() -> NodeRecord {
        NodeRecord {
            payload: 0,
            meta: KIND_INTERNAL << KIND_SHIFT,
        }
    }

    /// A top-tree node whose subtree is root `root` of block `block` (spec §8.1).
    pub fn link(block: u32, root: u32) -> NodeRecord {
        debug_assert!(root <= MAX_LINK_ROOT);
        NodeRecord {
            payload: block,
            meta: KIND_LINK << KIND_SHIFT | (root & MAX_LINK_ROOT),
        }
    }

    /// Whether the record is an internal node (its kind bits; what the rank directory marks).
    #[inline(always)]
    pub fn is_internal(self) -> bool {
        self.kind_bits() == KIND_INTERNAL
    }

    /// A link's block and root, unvalidated (see [`Self::kind_bits`]).
    #[inline(always)]
    pub fn link_bits(self) -> (u32, u32) {
        (self.payload, self.meta & MAX_LINK_ROOT)
    }

    /// The kind bits ([`KIND_EMPTY`], [`KIND_SOLID`], [`KIND_INTERNAL`], [`KIND_LINK`]), for the tracer's
    /// fast path, which then reads the fields below without the validation of [`Self::kind`]:
    /// any bits give a box or a range it bounds-checks, and `verify` reports them.
    #[inline(always)]
    pub fn kind_bits(self) -> u32 {
        self.meta >> KIND_SHIFT
    }

    /// An empty leaf's volume shape, unvalidated (see [`Self::kind_bits`]).
    #[inline(always)]
    pub fn shape_bits(self) -> VolumeShape {
        VolumeShape {
            axes: (self.meta & 7) as u8,
            level: ((self.meta >> 3) & 31) as u8,
        }
    }

    /// A solid leaf's inline count and packed bounds, unvalidated (see [`Self::kind_bits`]).
    #[inline(always)]
    pub fn solid_bits(self) -> (u32, u32) {
        (
            (self.meta >> COUNT_SHIFT) & MAX_INLINE_REFS,
            self.meta & BOUNDS_MASK,
        )
    }

    /// Decodes the record; `None` for bit patterns no writer produces (corruption).
    #[inline]
    pub fn kind(self) -> Option<NodeKind> {
        let low = self.meta & ((1 << KIND_SHIFT) - 1);
        match self.meta >> KIND_SHIFT {
            KIND_EMPTY => VolumeShape::unpack(low).map(|shape| NodeKind::Empty {
                volume: self.payload,
                shape,
            }),
            KIND_SOLID => {
                let bounds = LeafBounds::unpack(low & BOUNDS_MASK);
                bounds.is_valid().then_some(NodeKind::Solid {
                    first: self.payload,
                    inline_count: low >> COUNT_SHIFT,
                    bounds,
                })
            }
            KIND_INTERNAL if low == 0 && self.payload == 0 => Some(NodeKind::Internal),
            KIND_INTERNAL => None,
            _ => Some(NodeKind::Link {
                block: self.payload,
                root: low,
            }),
        }
    }
}

/// The references of a solid leaf (spec §4.2), and the range of the refs section they and their
/// count word (if any) occupy; `None` if they run past the section or an escaped count is not
/// above [`MAX_INLINE_REFS`].
#[inline]
pub fn leaf_refs(
    refs: &[u32],
    first: u32,
    inline_count: u32,
) -> Option<(&[u32], std::ops::Range<usize>)> {
    let first = first as usize;
    let (start, count) = if inline_count != 0 {
        (first, inline_count as usize)
    } else {
        let n = *refs.get(first)?;
        if n <= MAX_INLINE_REFS {
            return None;
        }
        (first + 1, n as usize)
    };
    let end = start.checked_add(count)?;
    Some((refs.get(start..end)?, first..end))
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

/// Spec §7.2: lanes of a triangle group.
pub const GROUP_LANES: usize = 8;
/// Spec §7.2: distinct corners a group may have (its corner table's slots).
pub const GROUP_CORNERS: usize = 8;
/// Spec §7.1: children of a cluster node.
pub const CLUSTER_WIDTH: usize = 8;
/// Spec §7.1: the deepest a cluster's tree may go (its root at depth 0). The builder's trees
/// are far shallower (a cluster holds a few hundred triangles); the cap bounds the tracer's
/// stack whatever the bytes.
pub const MAX_CLUSTER_DEPTH: usize = 16;
/// Spec §7.1: the range of a cluster node's grid exponents. `2^exp` and every box face
/// `origin + q * 2^exp` (`q <= 255`) are then normal, finite f32 values for any origin the
/// builder writes.
pub const CLUSTER_EXP_RANGE: std::ops::RangeInclusive<i8> = -64..=63;

/// Spec §7.1: one node of a cluster's wide BVH (80 bytes): up to eight children, each an inner
/// node or a leaf (one triangle group), with boxes quantised to 8 bits per face on a per-axis
/// grid `origin + q * 2^exp`, rounded outward.
///
/// Slots `0..inner_count` are inner children, nodes `node_base + i`; slots
/// `inner_count..child_count` are leaves, groups `group_base + (i - inner_count)`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ClusterNode {
    /// The grid's origin per axis: a multiple of `2^exp` with `|origin / 2^exp| + 255 < 2^24`,
    /// so that every face `origin + q * 2^exp` is exact in f32.
    pub origin: [f32; 3],
    /// The grid step per axis is `2^exp`; within [`CLUSTER_EXP_RANGE`].
    pub exp: [i8; 3],
    /// Children in use, `1..=8`.
    pub child_count: u8,
    /// Index (in the block's cluster nodes) of the first inner child; the others follow.
    pub node_base: u32,
    /// Index (in the block's groups) of the first leaf child's group; the others follow.
    pub group_base: u32,
    /// Inner children (slots `0..inner_count`), `<= child_count`.
    pub inner_count: u8,
    pub reserved: [u8; 7],
    /// Lowest face of child `i` along axis `k`: `origin[k] + lo[k][i] * 2^exp[k]`.
    pub lo: [[u8; CLUSTER_WIDTH]; 3],
    /// Highest face: `origin[k] + hi[k][i] * 2^exp[k]`; `lo <= hi` for children in use, 0 for
    /// unused slots.
    pub hi: [[u8; CLUSTER_WIDTH]; 3],
}
const _: () = assert!(std::mem::size_of::<ClusterNode>() == 80);

impl ClusterNode {
    /// The node as the box test reads it.
    #[inline(always)]
    pub fn view(&self) -> crate::geom::ClusterNodeView<'_> {
        crate::geom::ClusterNodeView {
            origin: &self.origin,
            exp: &self.exp,
            lo: &self.lo,
            hi: &self.hi,
            child_count: self.child_count,
        }
    }

    /// The box of child slot `i` (`< 8`) in world units: exact f32 faces for a node whose
    /// grid follows spec §7.1 (for any other bytes, some box; never a panic).
    pub fn child_box(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let i = i & (CLUSTER_WIDTH - 1);
        let face = |k: usize, q: u8| {
            let step = 2f32.powi(self.exp[k] as i32);
            self.origin[k] + q as f32 * step
        };
        (
            std::array::from_fn(|k| face(k, self.lo[k][i])),
            std::array::from_fn(|k| face(k, self.hi[k][i])),
        )
    }
}

/// Spec §7.2: up to eight triangles that share at most eight distinct corners, laid out for
/// SIMD (160 bytes): the corners' coordinates as three rows of eight, each lane's three corners
/// as indices into them, and the lanes' primitive ids. Lanes `count..8` never hit (their
/// indices and ids are 0).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TriGroup {
    /// `corner[k][j]`: coordinate `k` of distinct corner `j` (world units). Unused slots 0.
    pub corner: [[f32; GROUP_CORNERS]; 3],
    /// `tri[c][l]`: the slot (`< 8`) of corner `c` of lane `l`'s triangle, in the input
    /// triangle's corner order.
    pub tri: [[u8; GROUP_LANES]; 3],
    /// Lanes in use, `1..=8`.
    pub count: u32,
    pub reserved: u32,
    /// Primitive id of each lane's triangle (spec §7).
    pub prim: [u32; GROUP_LANES],
}
const _: () = assert!(std::mem::size_of::<TriGroup>() == 160);

impl TriGroup {
    /// The group as the triangle test reads it.
    #[inline(always)]
    pub fn view(&self) -> crate::geom::TriGroupView<'_> {
        crate::geom::TriGroupView {
            corner: &self.corner,
            tri: &self.tri,
            count: self.count,
        }
    }

    /// The corners of lane `l`'s triangle (`l < 8`; slots are masked to `< 8`, so any bytes
    /// give coordinates of the group).
    #[inline(always)]
    pub fn triangle(&self, l: usize) -> [[f32; 3]; 3] {
        std::array::from_fn(|c| {
            let j = (self.tri[c][l & 7] & 7) as usize;
            [self.corner[0][j], self.corner[1][j], self.corner[2][j]]
        })
    }
}

/// Spec §8.2: how a block's bytes are stored.
pub const CODEC_RAW: u32 = 0;
/// Spec §8.2: one zstd frame whose content is the block's raw bytes.
pub const CODEC_ZSTD: u32 = 1;
/// Spec §8.2: the head stored raw, every chunk of groups in the lean encoding (spec §7.3).
pub const CODEC_LEAN: u32 = 2;
/// Spec §8.2: raw blocks start at multiples of this (a page), so that paging one block in or out
/// never touches another's pages.
pub const RAW_BLOCK_ALIGN: u64 = 4096;

/// Spec §8.2: one entry of the block directory (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable, serde::Serialize)]
pub struct BlockEntry {
    /// Offset of the block's stored bytes in the file.
    pub offset: u64,
    /// Bytes stored in the file: the head's, then the chunks' (spec §8.3).
    pub stored_len: u64,
    /// Bytes of the block once decoded (`== stored_len` for a raw block).
    pub raw_len: u64,
    /// The block's codec: [`CODEC_RAW`] (chunks raw too), [`CODEC_ZSTD`] (the head a zstd
    /// frame, each chunk raw or one) or [`CODEC_LEAN`] (the head raw, each chunk lean).
    pub codec: u32,
    /// Absolute level of the block's roots.
    pub root_level: u32,
    pub root_count: u32,
    /// Triangles stored in the block: its triangle records (lists) or its groups' lanes in use
    /// (clusters).
    pub triangles: u32,
    /// xxh3-64 of the head's `head_stored_len` stored bytes (each chunk has its own, in the
    /// head's chunk table).
    pub checksum: u64,
    /// Bytes of the head as stored: the first of the block's stored bytes.
    pub head_stored_len: u64,
    /// Bytes of the head once decoded: where the groups start in the decoded block (a multiple
    /// of [`GROUPS_ALIGN`] when it has groups), or `raw_len` when it has none.
    pub head_raw_len: u64,
}
const _: () = assert!(std::mem::size_of::<BlockEntry>() == 64);

/// Spec §8.3: one chunk of a block's triangle groups (16 bytes), in the chunk table of the
/// block's head. Chunk `c` holds groups `c * chunk_groups ..` (the last chunk fewer).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct ChunkEntry {
    /// Offset of the chunk's stored bytes from the end of the head's stored bytes.
    pub offset: u32,
    /// Bytes stored: the chunk's raw length (a raw chunk), fewer (one zstd frame), or its
    /// lean encoding's (a lean block's chunks).
    pub stored_len: u32,
    /// xxh3-64 of the stored bytes.
    pub checksum: u64,
}

/// Spec §2: the most groups a chunk may hold (a chunk of them is 10 MiB).
pub const MAX_CHUNK_GROUPS: u32 = 1 << 16;

/// Spec §8.2: whether a zstd head of `stored` bytes may decode to `raw`: at most
/// [`MAX_ZSTD_RATIO`] times its size, plus one page (the zero padding before the groups, which
/// compresses to nothing).
pub fn zstd_head_fits(raw: u64, stored: u64) -> bool {
    raw <= stored
        .saturating_mul(MAX_ZSTD_RATIO)
        .saturating_add(GROUPS_ALIGN)
}

/// Spec §8.3: a block's groups start at a multiple of this from the block's start, so that a
/// raw block's chunks can be read past the page cache, page by page.
pub const GROUPS_ALIGN: u64 = 4096;

impl BlockEntry {
    /// Spec §8.2: a free entry (all zero) stands where an update removed a block; no link
    /// refers to it. Only files of generation 2 and later have them.
    pub fn is_free(&self) -> bool {
        *self == BlockEntry::zeroed()
    }
}

/// Spec §2: the largest `max_block_raw_len` a reader accepts (1 GiB): what one decoded block
/// may make a reader allocate, whatever the file says. A writer refuses to write a larger block.
pub const MAX_BLOCK_RAW_LEN: u64 = 1 << 30;

/// Spec §8.2: a zstd block decodes to at most this many times its stored size. A writer stores
/// a block that would compress better than this raw; a reader refuses a zstd block whose entry
/// claims more, so a small frame cannot make it decode (and hold) a great deal.
pub const MAX_ZSTD_RATIO: u64 = 64;

/// Spec §8.3: the tag that starts every block's raw bytes ("OBLK", little-endian).
pub const BLOCK_TAG: u32 = u32::from_le_bytes(*b"OBLK");

/// Spec §8.3: the header of a block's raw bytes (104 bytes), followed by the block's records as
/// [`block_layout`] places them.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct BlockHeader {
    /// [`BLOCK_TAG`].
    pub tag: u32,
    /// Levels of the block's subtrees (local level 0 holds the roots).
    pub level_count: u32,
    /// Absolute level of the roots.
    pub root_level: u32,
    pub root_count: u32,
    pub node_count: u64,
    pub rank_count: u64,
    pub volume_count: u64,
    /// Reference words (leaf lists; 0 in a file of clusters).
    pub ref_count: u64,
    /// Triangle records (leaf lists; 0 in a file of clusters).
    pub triangle_count: u64,
    /// Cluster nodes (clusters; 0 in a file of leaf lists).
    pub cluster_node_count: u64,
    /// Triangle groups (clusters; 0 in a file of leaf lists).
    pub group_count: u64,
    /// The block's own index in the directory (catches a block stored in another's place).
    pub block_id: u64,
    /// Rope records (spec §8.4): `node_count` in a file with [`FLAG_ROPES`], else 0 (bytes
    /// 80..88 were padding before ropes, so blocks written before read 0 here).
    pub rope_count: u64,
    /// Internal nodes holding occluders (spec §8.5; 0 in a file without [`FLAG_OCCLUDERS`]).
    /// Bytes 88..104 were padding before occluders, so blocks written before read 0 here.
    pub occluder_node_count: u64,
    /// Occluder triangle records (spec §8.5).
    pub occluder_count: u64,
    /// Entries of the chunk table: `ceil(group_count / chunk_groups)`.
    pub chunk_count: u64,
}
const _: () = assert!(std::mem::size_of::<BlockHeader>() == 112);

/// Spec §8.3: the parts of a block, in the order they are stored.
pub const BLOCK_PARTS: usize = 12;
/// Indices of a block's parts in [`block_layout`]'s ranges.
pub const PART_LEVELS: usize = 0;
pub const PART_NODES: usize = 1;
pub const PART_RANKS: usize = 2;
pub const PART_VOLUMES: usize = 3;
pub const PART_REFS: usize = 4;
pub const PART_TRIANGLES: usize = 5;
pub const PART_WIDE: usize = 6;
pub const PART_ROPES: usize = 7;
pub const PART_OCCLUDER_NODES: usize = 8;
pub const PART_OCCLUDERS: usize = 9;
pub const PART_CHUNKS: usize = 10;
pub const PART_GROUPS: usize = 11;

/// The parts that take their place in a block even when empty (the first seven); the others
/// take none when empty.
const FIXED_PARTS: usize = 7;

/// Spec §8.5: an internal node of a block that holds occluders (8 bytes): its index in the
/// block's node records, and the index of its first occluder in the block's occluder records
/// (its occluders run to the next entry's `first`, or to the end).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct OccluderNode {
    pub node: u32,
    pub first: u32,
}

/// Spec §8.4: a rope that leads out of the root cube (the face is on its boundary).
pub const ROPE_EXIT: u32 = u32::MAX;
/// Spec §8.4: a rope with this bit set leads to the top tree's node record `rope & !ROPE_TOP`;
/// without it, to the node record of that index in the rope's own block.
pub const ROPE_TOP: u32 = 1 << 31;
/// Spec §8.4: the largest node index a rope can hold.
pub const ROPE_MAX_INDEX: u32 = ROPE_TOP - 2;

/// Spec §8.4: the ropes of one node record (24 bytes): for each face of the box a walk crosses
/// at that node (its cell, or an empty leaf's merged volume), the smallest node containing
/// everything just across the face. Faces in the order -x, +x, -y, +y, -z, +z
/// (`2 * axis + positive`). Internal nodes' records are 0.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct RopeRecord {
    pub across: [u32; 6],
}

/// Spec §8.3: the byte ranges, from a block's start, of its parts (indexed by `PART_*`): the
/// level table, nodes, ranks, volumes, refs, triangles and wide nodes, each at the next
/// multiple of [`SECTION_ALIGN`]; then the ropes, occluder nodes, occluders and chunk table,
/// likewise but only when not empty; then the groups, when there are some, at the next multiple
/// of [`GROUPS_ALIGN`]. Also the block's raw length; `None` if the counts overflow. The *head*
/// is everything before the groups.
pub fn block_layout(h: &BlockHeader) -> Option<([std::ops::Range<u64>; BLOCK_PARTS], u64)> {
    let sizes = [
        (h.level_count as u64, std::mem::size_of::<LevelEntry>()),
        (h.node_count, std::mem::size_of::<NodeRecord>()),
        (h.rank_count, std::mem::size_of::<RankWord>()),
        (h.volume_count, std::mem::size_of::<VolumeRecord>()),
        (h.ref_count, std::mem::size_of::<u32>()),
        (h.triangle_count, std::mem::size_of::<TriRecord>()),
        (h.cluster_node_count, std::mem::size_of::<ClusterNode>()),
        (h.rope_count, std::mem::size_of::<RopeRecord>()),
        (h.occluder_node_count, std::mem::size_of::<OccluderNode>()),
        (h.occluder_count, std::mem::size_of::<TriRecord>()),
        (h.chunk_count, std::mem::size_of::<ChunkEntry>()),
        (h.group_count, std::mem::size_of::<TriGroup>()),
    ];
    let mut at = std::mem::size_of::<BlockHeader>() as u64;
    let mut out: [std::ops::Range<u64>; BLOCK_PARTS] = Default::default();
    for (i, (count, size)) in sizes.into_iter().enumerate() {
        if i == PART_GROUPS && count > 0 {
            at = at.checked_next_multiple_of(GROUPS_ALIGN)?;
        } else if i < FIXED_PARTS || count > 0 {
            at = at.checked_next_multiple_of(SECTION_ALIGN)?;
        }
        let end = at.checked_add(count.checked_mul(size as u64)?)?;
        out[i] = at..end;
        at = end;
    }
    Some((out, at))
}

/// Spec §2: the root cube for mesh bounds `lo..hi`: centred on the mesh, edge = the largest
/// extent plus 1/1024, so the mesh sits strictly inside; a mesh with no extent (one point) gets
/// an edge of `1e-6` of its largest coordinate magnitude, or 1. Returns the lowest corner and
/// the edge. The builder fits it; `verify` recomputes it to check a file's header.
pub fn root_cube(lo: [f32; 3], hi: [f32; 3]) -> ([f64; 3], f64) {
    let centre: [f64; 3] = std::array::from_fn(|k| (lo[k] as f64 + hi[k] as f64) * 0.5);
    let extent = (0..3)
        .map(|k| hi[k] as f64 - lo[k] as f64)
        .fold(0.0, f64::max);
    let mut root_size = extent * (1.0 + 1.0 / 1024.0);
    if !(root_size > 0.0 && root_size.is_normal()) {
        let mag = centre.iter().map(|c| c.abs()).fold(0.0, f64::max);
        root_size = if mag > 0.0 { mag * 1e-6 } else { 1.0 };
    }
    (
        std::array::from_fn(|k| centre[k] - root_size * 0.5),
        root_size,
    )
}

/// Spec §2: the smallest root cube edge a file may have. The triangle test works in f32, and
/// the `t` of a hit is a product of three coordinate differences over a product of two: at the
/// bunny scaled so that its root cube's edge is 1.5e-13, that product underflows and 97 % of
/// the hits the f64 reference finds get a wrong `t` (at 1.5e-11, none). A writer refuses a
/// smaller mesh; a reader refuses a file that records one.
pub const MIN_ROOT_SIZE: f64 = 1e-10;
/// Spec §2: the largest root cube edge: at 1.5e15 the same product overflows and every hit is
/// lost (at 1.5e13, none); this leaves rays from a hundred times the mesh's size away room.
pub const MAX_ROOT_SIZE: f64 = 1e11;

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
        let shape = VolumeShape {
            level: 3,
            axes: 0b101,
        };
        assert_eq!(
            NodeRecord::empty(7, shape).kind(),
            Some(NodeKind::Empty { volume: 7, shape })
        );
        let b = LeafBounds {
            lo: [1, 2, 3],
            hi: [4, 15, 3],
        };
        assert_eq!(
            NodeRecord::solid(9, 3, b).kind(),
            Some(NodeKind::Solid {
                first: 9,
                inline_count: 3,
                bounds: b
            })
        );
        assert_eq!(
            NodeRecord::solid(9, 64, b).kind(),
            Some(NodeKind::Solid {
                first: 9,
                inline_count: 0,
                bounds: b
            })
        );
        assert_eq!(NodeRecord::internal().kind(), Some(NodeKind::Internal));
        let raw = |payload, meta| NodeRecord { payload, meta }.kind();
        assert_eq!(
            raw(4, 3 << 30 | 5),
            Some(NodeKind::Link { block: 4, root: 5 })
        );
        assert_eq!(
            NodeRecord::link(4, 5).kind(),
            Some(NodeKind::Link { block: 4, root: 5 })
        );
        assert_eq!(raw(1, 2 << 30), None); // internal with a payload
        assert_eq!(raw(1, 1 << 8), None); // empty with bits past the shape
        assert_eq!(raw(1, 1), None); // empty, merged along x at level 0 (beyond the root)
        assert_eq!(raw(1, 22 << 3), None); // empty, level 22
        assert_eq!(raw(0, 1 << 30 | 1 << 24 | 0x00_0001), None); // bounds lo.x 1 > hi.x 0
    }

    #[test]
    fn volume_shapes_give_boxes() {
        let q = [5 << 18, 3 << 18, 0];
        // Level 2 node (size 2^19) containing q, doubled along x to its level-1 parent.
        let s = VolumeShape {
            level: 2,
            axes: 0b001,
        };
        assert_eq!(
            s.box_around(q),
            ([1 << 20, 1 << 19, 0], [1 << 21, 2 << 19, 1 << 19])
        );
        let root = VolumeShape { level: 0, axes: 0 };
        assert_eq!(root.box_around(q), ([0; 3], [1 << 21; 3]));
    }

    #[test]
    fn escaped_counts() {
        let mut refs = vec![0u32; 70];
        refs[2] = 64;
        let (r, range) = leaf_refs(&refs, 2, 0).unwrap();
        assert_eq!((r.len(), range), (64, 2..67));
        refs[2] = 63; // must be above the inline maximum
        assert!(leaf_refs(&refs, 2, 0).is_none());
        refs[2] = 100; // runs past the end
        assert!(leaf_refs(&refs, 2, 0).is_none());
        assert_eq!(leaf_refs(&refs, 68, 2).unwrap().1, 68..70);
        assert!(leaf_refs(&refs, 69, 2).is_none());
    }
}
