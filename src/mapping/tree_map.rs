//! [`TreeMap`]: the node records and rank directory of a unit (the top tree, or a block's
//! subtrees), addressed by `(level, index in level)`, with the child, parent, descent and
//! neighbour queries.

use super::morton::{self, MAX_LEVEL};
use super::rank::child_index;
use crate::physical::format::{LevelEntry, NodeKind, NodeRecord, RankWord};

/// What went wrong where, when a walk meets bytes that break the format's invariants. Small and
/// `Copy` so the tracer's hot path can return it cheaply; turned into a
/// [`crate::error::FormatError`] at the edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Corruption {
    pub what: &'static str,
    /// The block the node is in (`None`: the top tree, or a file without blocks).
    pub block: Option<u32>,
    pub level: u32,
    pub index: u64,
}

impl std::fmt::Display for Corruption {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.block {
            Some(b) => write!(
                f,
                "{} (block {b}, level {}, node {})",
                self.what, self.level, self.index
            ),
            None => write!(
                f,
                "{} (level {}, node {})",
                self.what, self.level, self.index
            ),
        }
    }
}

impl From<Corruption> for crate::error::FormatError {
    fn from(c: Corruption) -> Self {
        crate::error::FormatError::Corrupt(c.to_string())
    }
}

/// Per-level constants of a [`TreeMap`], copied out of the level table so the hot path reads
/// them from one small array.
#[derive(Clone, Copy, Debug, Default)]
struct LevelInfo {
    node_start: u64,
    rank_start: u64,
    /// Nodes of the next level (0 on the deepest level).
    next_count: u64,
}

/// The per-level constants of a unit (the top tree, or a block's subtrees), by absolute level:
/// what a [`TreeMap`] reads on every step of a descent. Made once per unit (when a file is
/// opened, when a block is admitted) and borrowed by every map of it, so that entering a block
/// rebuilds nothing.
#[derive(Clone, Copy, Debug)]
pub struct LevelInfos {
    /// Indexed by absolute level; 32 entries (levels outside `base .. base + level_count` are
    /// zero) so that `level & 31` indexes it without a bounds check.
    info: [LevelInfo; 32],
    base: u32,
    level_count: u32,
}

impl LevelInfos {
    /// The constants of a level table whose local level 0 is absolute level `base` (a block's
    /// roots; 0 for the top tree). Levels past the lattice's deepest are ignored.
    pub fn new(levels: &[LevelEntry], base: u32) -> LevelInfos {
        let base = base.min(MAX_LEVEL);
        let levels = &levels[..levels.len().min((MAX_LEVEL + 1 - base) as usize)];
        let mut info = [LevelInfo::default(); 32];
        for (l, e) in levels.iter().enumerate() {
            info[base as usize + l] = LevelInfo {
                node_start: e.node_start,
                rank_start: e.rank_start,
                next_count: levels.get(l + 1).map_or(0, |n| n.node_count),
            };
        }
        LevelInfos {
            info,
            base,
            level_count: levels.len() as u32,
        }
    }
}

/// The node records and rank directory of a tree, or of a block's subtrees, addressed by
/// `(absolute level, index in level)`. A block's map has a *base*: the absolute level of its
/// roots, which are its local level 0 (format-spec §8).
#[derive(Clone, Copy)]
pub struct TreeMap<'a> {
    infos: &'a LevelInfos,
    levels: &'a [LevelEntry],
    nodes: &'a [NodeRecord],
    ranks: &'a [RankWord],
}

impl<'a> TreeMap<'a> {
    /// A map over validated level, node and rank tables, with their constants `infos` (made by
    /// [`LevelInfos::new`] from the same level table; every access is still bounds-checked
    /// against the slices, so any other `infos` gives errors, never a panic).
    pub fn new(
        infos: &'a LevelInfos,
        levels: &'a [LevelEntry],
        nodes: &'a [NodeRecord],
        ranks: &'a [RankWord],
    ) -> Self {
        let levels = &levels[..levels.len().min(infos.level_count as usize)];
        TreeMap {
            infos,
            levels,
            nodes,
            ranks,
        }
    }

    /// Descends from the node `path[level]` to the leaf containing lattice point `q`, writing the
    /// indices of the nodes passed into `path` and counting them in `visits`. Returns the leaf's
    /// level and record. Internal nodes are recognised by their bit in the rank directory and
    /// their own records are never read: rank words (2 bits per node) stay in cache where
    /// records (64 bits per node) do not.
    ///
    /// `path[level]` must be a node index obtained from this map (the root, 0, or a child found
    /// by a descent): then every index is in range by construction, since each child index is
    /// checked against the size of the next level (0 past the deepest, which also rejects an
    /// internal node there). The slices are still accessed with bounds checks, so bytes that
    /// break this only ever produce an error.
    #[inline(always)]
    pub fn descend(
        &self,
        mut level: u32,
        path: &mut [u64; 32],
        q: [u32; 3],
        visits: &mut u64,
    ) -> Result<(u32, NodeRecord), Corruption> {
        loop {
            let idx = path[(level & 31) as usize];
            let li = &self.infos.info[(level & 31) as usize];
            *visits += 1;
            let bad = |what| Corruption {
                block: None,
                what,
                level,
                index: idx,
            };
            let word = self
                .ranks
                .get((li.rank_start + idx / 64) as usize)
                .ok_or(bad("rank word out of range"))?;
            let bit = idx % 64;
            if (word.internal >> bit) & 1 == 0 {
                let rec = self
                    .nodes
                    .get((li.node_start + idx) as usize)
                    .ok_or(bad("node record out of range"))?;
                return Ok((level, *rec));
            }
            // Octant of q among the children (level + 1 <= 21 for any child that exists).
            let p = MAX_LEVEL.wrapping_sub(level + 1) & 31;
            let octant = ((q[0] >> p) & 1) | ((q[1] >> p) & 1) << 1 | ((q[2] >> p) & 1) << 2;
            let child = child_index(word, bit, octant)
                .filter(|&c| c < li.next_count)
                .ok_or(bad("rank directory points past the next level"))?;
            level += 1;
            path[(level & 31) as usize] = child;
        }
    }

    /// The eight children of internal node `idx` of absolute level `level`: the index (in the
    /// next level) of the first, which children are internal (bit `o` for octant `o`, from the
    /// next level's rank word), and their records. `None` if `idx` is not an internal node of
    /// this map or its children run past the next level (bytes that break the format).
    #[inline(always)]
    pub fn children(&self, level: u32, idx: u64) -> Option<(u64, u8, &'a [NodeRecord; 8])> {
        let li = &self.infos.info[(level & 31) as usize];
        let word = self.ranks.get((li.rank_start + idx / 64) as usize)?;
        let bit = idx % 64;
        if (word.internal >> bit) & 1 == 0 {
            return None;
        }
        let first = child_index(word, bit, 0)?;
        if first.checked_add(8)? > li.next_count {
            return None;
        }
        let next = &self.infos.info[((level + 1) & 31) as usize];
        // Children start at a multiple of 8: their eight bits are one byte of one word.
        let cw = self.ranks.get((next.rank_start + first / 64) as usize)?;
        let internal = (cw.internal >> (first % 64)) as u8;
        let at = (next.node_start + first) as usize;
        let recs = self.nodes.get(at..at + 8)?.try_into().ok()?;
        Some((first, internal, recs))
    }

    /// Index in the node records of the first node of absolute level `level` (0 for a level
    /// the map does not hold).
    #[inline(always)]
    pub fn node_start(&self, level: u32) -> u64 {
        self.infos.info[(level & 31) as usize].node_start
    }

    /// Levels held (local levels, from the base).
    pub fn level_count(&self) -> u32 {
        self.infos.level_count
    }

    /// Absolute level of local level 0.
    pub fn base(&self) -> u32 {
        self.infos.base
    }

    /// The level table, by local level.
    pub fn levels(&self) -> &'a [LevelEntry] {
        self.levels
    }

    /// Rank word `w` of absolute level `level`, if it exists.
    pub fn rank_word(&self, level: u32, w: u64) -> Option<&'a RankWord> {
        let lv = self.level(level)?;
        if w >= lv.node_count.div_ceil(64) {
            return None;
        }
        self.ranks.get((lv.rank_start + w) as usize)
    }

    /// The level entry of absolute level `level`.
    fn level(&self, level: u32) -> Option<&'a LevelEntry> {
        self.levels
            .get(level.checked_sub(self.infos.base)? as usize)
    }

    /// The record of node `idx` of `level`.
    #[inline]
    pub fn node(&self, level: u32, idx: u64) -> Result<NodeRecord, Corruption> {
        let bad = Corruption {
            block: None,
            what: "node index out of range",
            level,
            index: idx,
        };
        let lv = self.level(level).ok_or(bad)?;
        if idx >= lv.node_count {
            return Err(bad);
        }
        self.nodes
            .get((lv.node_start + idx) as usize)
            .copied()
            .ok_or(bad)
    }

    /// Index at `level + 1` of child `octant` of the internal node `idx` of `level`.
    #[inline]
    pub fn child(&self, level: u32, idx: u64, octant: u32) -> Result<u64, Corruption> {
        let bad = |what| Corruption {
            block: None,
            what,
            level,
            index: idx,
        };
        let lv = self.level(level).ok_or(bad("level out of range"))?;
        let word = self
            .ranks
            .get((lv.rank_start + idx / 64) as usize)
            .ok_or(bad("rank word out of range"))?;
        let bit = idx % 64;
        if (word.internal >> bit) & 1 == 0 {
            return Err(bad("internal node not marked in the rank directory"));
        }
        let child = child_index(word, bit, octant)
            .ok_or(bad("rank directory points past the next level"))?;
        let next = self
            .level(level + 1)
            .ok_or(bad("internal node on the deepest level"))?;
        if child >= next.node_count {
            return Err(bad("rank directory points past the next level"));
        }
        Ok(child)
    }

    /// Index at `level - 1` of the parent of node `idx` of `level` (`level >= 1`): the internal
    /// node of rank `idx / 8`, found by binary search over the rank words (select).
    pub fn parent(&self, level: u32, idx: u64) -> Result<u64, Corruption> {
        let bad = |what| Corruption {
            block: None,
            what,
            level,
            index: idx,
        };
        if level == 0 {
            return Err(bad("the root has no parent"));
        }
        let pl = level - 1;
        let lv = self.level(pl).ok_or(bad("level out of range"))?;
        let words = self
            .ranks
            .get(lv.rank_start as usize..(lv.rank_start + lv.node_count.div_ceil(64)) as usize)
            .ok_or(bad("rank words out of range"))?;
        let rank = idx / 8;
        // The last word whose count of earlier internal nodes is <= rank holds the parent.
        let w = words.partition_point(|w| w.rank <= rank);
        let word = w
            .checked_sub(1)
            .and_then(|w| words.get(w))
            .ok_or(bad("no parent for rank"))?;
        let mut left = rank - word.rank; // internal nodes to skip inside the word
        let mut bits = word.internal;
        while bits != 0 {
            let b = bits.trailing_zeros() as u64;
            if left == 0 {
                return Ok((w as u64 - 1) * 64 + b);
            }
            left -= 1;
            bits &= bits - 1;
        }
        Err(bad("no parent for rank"))
    }

    /// Index of node `(level, code)`, or `None` if an ancestor of it is a leaf (the node does not
    /// exist). `L` child steps from the root.
    pub fn index_of(&self, level: u32, code: u64) -> Result<Option<u64>, Corruption> {
        let mut idx = 0;
        for l in 0..level {
            match self.node(l, idx)?.kind() {
                Some(NodeKind::Internal) => {
                    let octant = ((code >> (3 * (level - l - 1))) & 7) as u32;
                    idx = self.child(l, idx, octant)?;
                }
                Some(_) => return Ok(None),
                None => {
                    return Err(Corruption {
                        block: None,
                        what: "invalid node record",
                        level: l,
                        index: idx,
                    });
                }
            }
        }
        Ok(Some(idx))
    }

    /// The leaf containing lattice point `q`: its level, index and record.
    pub fn leaf_at(&self, q: [u32; 3]) -> Result<(u32, u64, NodeRecord), Corruption> {
        let (mut level, mut idx) = (0u32, 0u64);
        loop {
            let rec = self.node(level, idx)?;
            match rec.kind() {
                Some(NodeKind::Internal) => {
                    idx = self.child(level, idx, morton::octant_of_point(q, level + 1))?;
                    level += 1;
                }
                Some(_) => return Ok((level, idx, rec)),
                None => {
                    return Err(Corruption {
                        block: None,
                        what: "invalid node record",
                        level,
                        index: idx,
                    });
                }
            }
        }
    }

    /// The leaves adjacent to face `(axis, positive)` of node `(level, code)`: the neighbour at
    /// the same level if it exists, else the leaf that contains it (a coarser neighbour), else
    /// all the leaves of the neighbour's subtree that touch the shared face (finer neighbours).
    /// Empty for a face on the root's boundary.
    pub fn face_neighbours(
        &self,
        level: u32,
        code: u64,
        axis: u32,
        positive: bool,
    ) -> Result<Vec<(u32, u64)>, Corruption> {
        let Some(ncode) = morton::neighbour(code, level, axis, positive) else {
            return Ok(Vec::new());
        };
        // Walk down towards (level, ncode); stop early at a coarser leaf.
        let (mut l, mut idx) = (0u32, 0u64);
        while l < level {
            match self.node(l, idx)?.kind() {
                Some(NodeKind::Internal) => {
                    let octant = ((ncode >> (3 * (level - l - 1))) & 7) as u32;
                    idx = self.child(l, idx, octant)?;
                    l += 1;
                }
                Some(_) => return Ok(vec![(l, idx)]),
                None => {
                    return Err(Corruption {
                        block: None,
                        what: "invalid node record",
                        level: l,
                        index: idx,
                    });
                }
            }
        }
        // At the same level: collect the leaves of its subtree on the face towards us, i.e. the
        // children whose `axis` bit is 0 if we step in the positive direction, else 1.
        // Corrupt rank words could send several parents to the same children: bound the walk by
        // the number of nodes, which a well-formed tree never exceeds.
        let mut out = Vec::new();
        let mut stack = vec![(l, idx)];
        let mut budget = self.nodes.len();
        while let Some((l, idx)) = stack.pop() {
            budget = budget.checked_sub(1).ok_or(Corruption {
                block: None,
                what: "subtree walk visits more nodes than the tree has",
                level: l,
                index: idx,
            })?;
            match self.node(l, idx)?.kind() {
                Some(NodeKind::Internal) => {
                    for octant in 0..8u32 {
                        if ((octant >> axis) & 1 == 1) != positive {
                            stack.push((l + 1, self.child(l, idx, octant)?));
                        }
                    }
                }
                Some(_) => out.push((l, idx)),
                None => {
                    return Err(Corruption {
                        block: None,
                        what: "invalid node record",
                        level: l,
                        index: idx,
                    });
                }
            }
        }
        out.sort_unstable();
        Ok(out)
    }
}
