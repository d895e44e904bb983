//! The mapping layer: `(level L, Morton code M) -> record index`, with no per-node pointers
//! (OAVM paper §2.2, "pointer reduction"; format-spec §4).
//!
//! **Method.** Each level stores its nodes in Morton order, and every internal node has exactly
//! 8 children. The children of a level's internal nodes are therefore the next level, in the same
//! order, 8 per internal node: the children of the internal node of *rank* `r` (the `r`-th
//! internal node of its level, counting from 0) are records `8 r .. 8 r + 8` of the next level,
//! in octant order. The rank is read from the rank directory (spec §4.3): one [`RankWord`] per 64
//! nodes holds a bitmap of which nodes are internal and the count of internal nodes before it, so
//!
//! ```text
//!   rank(idx)      = word.rank + popcount(word.internal & ((1 << (idx % 64)) - 1)),  word = ranks[idx / 64]
//!   child(idx, o)  = 8 * rank(idx) + o
//! ```
//!
//! **Cost.** A child step reads one 16-byte rank word and one popcount: O(1). Finding `(L, M)`
//! from the root takes `L` child steps; the tracer keeps the indices of the current leaf's
//! ancestors and descends from the lowest common ancestor of two consecutive leaves, which
//! [`morton::common_level`] finds from the coordinates alone, so a step to a neighbour costs one
//! child step per level between that ancestor and the new leaf. A parent query needs the inverse
//! (select): a binary search over the level's rank words, `O(log n)`, used by tools and tests,
//! never by the tracer. The directory costs 2 bits per node, against a pointer octree's 8 child
//! pointers per internal node.

pub mod morton;
mod rank;
mod tree_map;

pub use rank::{rank, rank_words};
pub use tree_map::{Corruption, LevelInfos, TreeMap};

use crate::physical::format::CELL_MARGIN;
use morton::LATTICE_SIZE;

/// Where the lattice lies in world units: what turning solid leaves into clusters needs (each
/// cluster's boxes are clipped to its leaf's widened cell, spec §7.1).
#[derive(Clone, Copy, Debug)]
pub struct ClusterGeometry {
    pub root_min: [f64; 3],
    pub root_size: f64,
}

impl ClusterGeometry {
    /// The cell of the node of absolute level `level` and Morton code `code`, widened by
    /// [`CELL_MARGIN`] lattice units, in world units.
    pub fn widened_cell(&self, level: u32, code: u64) -> ([f64; 3], [f64; 3]) {
        let size = morton::cell_size(level) as f64;
        let lo = morton::cell_origin(code, level);
        let unit = self.root_size / LATTICE_SIZE as f64;
        let world = |k: usize, lattice: f64| self.root_min[k] + lattice * unit;
        (
            std::array::from_fn(|k| world(k, lo[k] as f64 - CELL_MARGIN)),
            std::array::from_fn(|k| world(k, lo[k] as f64 + size + CELL_MARGIN)),
        )
    }
}
