//! A block ready to be walked: what its bytes hold, found once when the pager first admits it
//! ([`ReadyMap`]), and the view a walk takes of it each time it enters ([`Held`]), which only
//! casts slices at known offsets.
//!
//! Format-spec §11 asks that a block's header, layout and level table be checked before it is
//! read. Those checks and the per-level constants of its map are `O(levels)` but not free (a
//! few hundred cycles with the 768-byte table of constants), and a ray enters a block or two:
//! done on every entry they cost as much as the rest of a short ray. So they are done once, when
//! the block is first admitted, and kept for the life of the file (the bytes of a block are the
//! same each time it is paged in: its checksum says so).

use crate::mapping::{LevelInfos, TreeMap};
use crate::physical::BlockView;
use crate::physical::format::{
    BLOCK_PARTS, BlockEntry, ClusterNode, LevelEntry, NodeRecord, OccluderNode, PART_GROUPS,
    PART_LEVELS, PART_NODES, PART_OCCLUDER_NODES, PART_OCCLUDERS, PART_RANKS, PART_REFS,
    PART_ROPES, PART_TRIANGLES, PART_WIDE, RankWord, RopeRecord, TriGroup, TriRecord, block_layout,
};

/// What a block's bytes hold, checked once ([`BlockView::parse`]): where its parts are and the
/// constants of its map.
#[derive(Debug)]
pub struct ReadyMap {
    parts: [(u32, u32); BLOCK_PARTS],
    infos: LevelInfos,
    pub(crate) root_level: u32,
    pub(crate) root_count: u32,
}

impl ReadyMap {
    /// Checks the raw bytes of block `id` as [`BlockView::parse`] does and keeps what it found
    /// (with `head`, the bytes of its head, [`BlockView::parse_head`]).
    pub fn new(
        raw: &[u8],
        id: u32,
        entry: &BlockEntry,
        head: bool,
    ) -> Result<ReadyMap, &'static str> {
        let v = match head {
            true => BlockView::parse_head(raw, id, entry)?,
            false => BlockView::parse(raw, id, entry)?,
        };
        let (ranges, _) = block_layout(&v.header).ok_or("block counts overflow")?;
        // Parse checked the block's length against its layout; raw_len <= 2^30.
        let parts = ranges.map(|r| (r.start as u32, r.end as u32));
        Ok(ReadyMap {
            parts,
            infos: LevelInfos::new(v.levels, v.header.root_level),
            root_level: v.header.root_level,
            root_count: v.header.root_count,
        })
    }

    /// Part `i` of `raw` (the block's bytes), cast; empty if `raw` is not the block's.
    #[inline(always)]
    fn part<'v, T: bytemuck::Pod>(&self, raw: &'v [u8], i: usize) -> &'v [T] {
        let (a, b) = self.parts[i];
        raw.get(a as usize..b as usize)
            .and_then(|p| bytemuck::try_cast_slice(p).ok())
            .unwrap_or(&[])
    }
}

/// A block as the wide walk sees it (spec §8.7): its wide nodes and its triangle groups, the
/// only parts that walk reads, cast when the walk enters it.
pub(crate) struct WideHeld<'v> {
    pub id: u32,
    pub root_count: u32,
    pub nodes: &'v [ClusterNode],
    pub groups: &'v [TriGroup],
    /// The block's bytes: its head's only, when `groups` holds none (spec §8.3), whose
    /// chunks the walk reads one by one ([`super::trace`]'s `Chunked`).
    pub raw: &'v [u8],
}

impl ReadyMap {
    /// The wide walk's view of block `id`, whose bytes are `raw` (casting only, as
    /// [`Held::new`]).
    #[inline(always)]
    pub fn wide<'v>(&self, id: u32, raw: &'v [u8]) -> WideHeld<'v> {
        WideHeld {
            id,
            root_count: self.root_count,
            nodes: self.part(raw, PART_WIDE),
            groups: self.part(raw, PART_GROUPS),
            raw,
        }
    }
}

/// A block being walked: its id and its records.
pub(crate) struct Held<'v> {
    pub id: u32,
    pub root_level: u32,
    pub root_count: u32,
    pub map: TreeMap<'v>,
    pub refs: &'v [u32],
    pub tris: &'v [TriRecord],
    pub cluster_nodes: &'v [ClusterNode],
    pub groups: &'v [TriGroup],
    /// Ropes (spec §8.4), by node record; empty in a block without them.
    pub ropes: &'v [RopeRecord],
    /// Occluders (spec §8.5): the internal nodes holding some, by node record, and their
    /// triangles; empty in a block without them.
    pub occluder_nodes: &'v [OccluderNode],
    pub occluders: &'v [TriRecord],
    /// The block's bytes ([`WideHeld::raw`]).
    pub raw: &'v [u8],
}

impl Held<'_> {
    /// The occluders of node record `at` (spec §8.5; none if it holds none, or if the records
    /// say nonsense: a walk reads them only to stop early, so wrong records cost answers that
    /// verify reports, never a panic).
    #[inline]
    pub fn occluders_of(&self, at: u64) -> &[TriRecord] {
        let Ok(at) = u32::try_from(at) else {
            return &[];
        };
        let Ok(i) = self.occluder_nodes.binary_search_by_key(&at, |n| n.node) else {
            return &[];
        };
        let first = self.occluder_nodes[i].first as usize;
        let end = self
            .occluder_nodes
            .get(i + 1)
            .map_or(self.occluders.len(), |n| n.first as usize);
        self.occluders.get(first..end).unwrap_or(&[])
    }
}

impl<'v> Held<'v> {
    /// The view of block `id`, whose bytes are `raw` and whose map is `ready`. Casting only: a
    /// `ready` of another block gives empty or wrong slices, which every access bounds-checks.
    #[inline(always)]
    pub fn new(id: u32, ready: &'v ReadyMap, raw: &'v [u8]) -> Held<'v> {
        let levels: &[LevelEntry] = ready.part(raw, PART_LEVELS);
        let nodes: &[NodeRecord] = ready.part(raw, PART_NODES);
        let ranks: &[RankWord] = ready.part(raw, PART_RANKS);
        Held {
            id,
            root_level: ready.root_level,
            root_count: ready.root_count,
            map: TreeMap::new(&ready.infos, levels, nodes, ranks),
            refs: ready.part(raw, PART_REFS),
            tris: ready.part(raw, PART_TRIANGLES),
            cluster_nodes: ready.part(raw, PART_WIDE),
            groups: ready.part(raw, PART_GROUPS),
            ropes: ready.part(raw, PART_ROPES),
            occluder_nodes: ready.part(raw, PART_OCCLUDER_NODES),
            occluders: ready.part(raw, PART_OCCLUDERS),
            raw,
        }
    }
}
