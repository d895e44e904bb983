//! The paper's "improved KD-tree": surface-area-heuristic splits with an empty-space bonus,
//! perfect splits, an O(N log N) build, and stack traversal.
//!
//! - [`build`]: the SAH split choice (pbrt-v3) and the O(N log N) event-sweep build (Wald and
//!   Havran 2006) with perfect splits;
//! - [`node`]: pbrt's 8-byte node record;
//! - [`traverse`]: pbrt's front-to-back stack traversal, with a tolerance, and the stackless
//!   variants;
//! - [`ropes`]: the threaded KD-tree's ropes and their walks (the source's, with stored cells or
//!   its `SplitStack` register, and Popov's).
//!
//! **Counting** (the paper's Table 2 sense): `nodes` = all nodes, interior and leaves;
//! `pointers` = one above-child index per interior node plus one primitive-list offset per leaf
//! with more than one triangle (a one-triangle leaf holds the triangle's index in place of the
//! pointer, an empty leaf holds nothing); `bytes` = nodes (8 bytes each), the leaf primitive list
//! (4 bytes per entry), the triangles (36 bytes) and their primitive ids (4 bytes). While
//! tracing, `nodes_visited` counts every node visited (interior and leaf) and `leaves_visited`
//! the leaves among them.

mod build;
mod node;
mod ropes;
mod shadow;
mod traverse;

#[cfg(test)]
mod tests;

pub use build::{EMPTY_BONUS, ISECT_COST, MAX_BAD_REFINES, MAX_DEPTH_CAP, TRAVERSAL_COST};
pub use node::KdNode;
pub use ropes::SPLIT_STACK_FORKS;
pub use shadow::{Adjacency, Precompute, PrimitiveIndex, REMEMBER, SatoOrder, ShadowParams};
pub use traverse::{KdTraversal, MAX_SHORT_STACK, STACK};

use super::StructureStats;
use super::leaf::Soup;

/// An SAH KD-tree over triangles (module docs).
pub struct KdTree {
    /// Root box for clipping rays (the triangles' box, padded).
    lo: [f64; 3],
    hi: [f64; 3],
    /// Scale of the scene (diagonal) and its centre, for the traversal tolerance.
    diag: f64,
    centre: [f64; 3],
    /// Depth-first: an interior node's below child follows it.
    nodes: Vec<KdNode>,
    /// The triangle lists of the leaves holding more than one triangle.
    leaf_prims: Vec<u32>,
    soup: Soup,
    max_depth: u32,
    /// Too large to store with 30-bit indices: every ray tests every triangle.
    brute: bool,
    /// How rays walk it.
    traversal: KdTraversal,
    /// Its ropes, for the rope walks.
    ropes: Option<ropes::Ropes>,
    stats: StructureStats,
}

impl KdTree {
    /// The same tree, walked by `traversal` (and named after it in reports). The rope walks
    /// build their ropes here: their time and bytes are added to the tree's.
    pub fn with_traversal(mut self, traversal: KdTraversal) -> KdTree {
        self.traversal = traversal;
        self.stats.name = traversal.name();
        self.ropes = None;
        if traversal.has_ropes() && !self.brute {
            let start = std::time::Instant::now();
            let r = ropes::Ropes::build(&self, traversal);
            self.stats.build_seconds += start.elapsed().as_secs_f64();
            self.stats.bytes += r.bytes() as u64;
            // Six ropes a leaf, or a node for the SplitStack walk (an interior node's tell
            // where the interval of a node a rope leads to ends: `ropes`).
            let roped = if traversal == KdTraversal::SplitStack {
                self.nodes.len()
            } else {
                self.nodes.iter().filter(|n| n.is_leaf()).count()
            };
            self.stats.pointers += 6 * roped as u64;
            self.ropes = Some(r);
        }
        self
    }

    /// The depth limit the build used.
    pub fn max_depth(&self) -> u32 {
        self.max_depth
    }

    /// Depth of the deepest leaf (the root has depth 0) and the number of leaves.
    pub fn depth_and_leaves(&self) -> (u32, usize) {
        let (mut deepest, mut leaves) = (0, 0);
        let mut stack = vec![(0usize, 0u32)];
        while let Some((i, d)) = stack.pop() {
            let Some(n) = self.nodes.get(i) else { continue };
            if n.is_leaf() {
                deepest = deepest.max(d);
                leaves += 1;
            } else {
                stack.push((i + 1, d + 1));
                stack.push((n.upper() as usize, d + 1));
            }
        }
        (deepest, leaves)
    }

    /// The triangles of leaf `n` (a node of `self.nodes`): in place for one, else a run of
    /// `leaf_prims` (empty if it does not exist).
    #[inline]
    fn leaf_list<'a>(&'a self, n: &'a KdNode) -> &'a [u32] {
        let count = n.upper() as usize;
        if count == 1 {
            std::slice::from_ref(&n.a)
        } else {
            let at = n.a as usize;
            self.leaf_prims.get(at..at + count).unwrap_or(&[])
        }
    }
}
