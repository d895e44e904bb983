//! A binned-SAH bounding volume hierarchy, the modern reference of the comparison, built and
//! traversed as pbrt-v4 does (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 4th ed.,
//! §7.3 "Bounding Volume Hierarchies").
//!
//! - [`build`]: pbrt-v4's binned SAH (over all three axes), with a depth bound;
//! - [`node`]: pbrt-v4's 32-byte `LinearBVHNode`, depth-first;
//! - [`traverse`]: pbrt-v4's front-to-back stack traversal with the conservative slab test.
//!
//! Triangles with a non-finite coordinate are left out, as by the other structures (no ray
//! hits them).
//!
//! **Counting conventions** ([`StructureStats`], [`Counters`]):
//!
//! - `nodes` = all nodes of the flattened tree, interior and leaf;
//! - `pointers` = one `secondChildOffset` per interior node + one `primitivesOffset` per leaf
//!   (the first child of an interior node is implicit, next in the array);
//! - `bytes` = nodes × 32 + the reordered triangles (36 bytes each) + their primitive ids
//!   (4 bytes each);
//! - `nodes_visited` = nodes whose box was tested; `leaves_visited` = leaves whose box was hit,
//!   so their triangles were tested; `triangles_tested` = ray–triangle tests (a four-lane test of
//!   a leaf of three counts three).

mod build;
mod node;
mod traverse;

#[cfg(test)]
mod tests;

pub use build::{BINS, MAX_PRIMS_IN_NODE, PARALLEL_MIN, SAH_MAX_DEPTH};
pub use node::LinearNode;
pub use traverse::STACK_SIZE;

use super::StructureStats;
use super::leaf::Soup;

/// A binned-SAH BVH over a set of triangles.
pub struct Bvh {
    nodes: Vec<LinearNode>,
    /// Triangles in leaf order, with their primitive ids.
    soup: Soup,
    /// No tree: too many triangles for 32-bit offsets; every ray tests every triangle.
    linear: bool,
    stats: StructureStats,
}

impl Bvh {
    /// The flattened nodes (depth-first), for tests and reports.
    pub fn nodes(&self) -> &[LinearNode] {
        &self.nodes
    }

    /// Depth of the deepest leaf (the root is at depth 0); 0 for an empty tree.
    pub fn depth(&self) -> usize {
        let mut deepest = 0;
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, d)) = stack.pop() {
            let Some(node) = self.nodes.get(i) else {
                continue;
            };
            deepest = deepest.max(d);
            if node.n_prims == 0 {
                stack.push((i + 1, d + 1));
                stack.push((node.offset as usize, d + 1));
            }
        }
        deepest
    }
}
