//! The classic octree of the OAVM paper's comparison: exactly OAVM's subdivision, stored as a
//! pointer octree and traversed with the parametric algorithm of Revelles, Ureña and Lastra,
//! "An efficient parametric algorithm for octree traversal" (WSCG 2000).
//!
//! - [`build`]: OAVM's subdivision, stored as pointers;
//! - [`node`]: the node record;
//! - [`traverse`]: Revelles' parametric traversal.
//!
//! Triangles with a non-finite coordinate are left out (OAVM's builder refuses such meshes; no
//! ray hits them). Without triangles the structure misses everything. If the tree needs more
//! than 32-bit node or reference indices, it is not kept and every ray tests every triangle
//! (correct, slow; far beyond any mesh the comparison uses).
//!
//! **Counting conventions** (as `format-spec.md` §9 and [`oavm::pack::PointerCounts`]):
//!
//! - `nodes` = every octree node, internal or leaf, empty or solid: equal to OAVM's node count
//!   for the same options (OAVM keeps every node too, as a record);
//! - `pointers` = 8 child pointers per internal node + 1 triangle-list pointer per solid leaf:
//!   equal to OAVM's `pointer_octree_total`;
//! - `bytes` = the node array ([`Node`], 36 bytes, which holds the 8 child pointers or the
//!   leaf's list) + the reference array (4 bytes a reference) + the triangles
//!   (36 bytes each) and their primitive ids (4 bytes each);
//! - `nodes_visited` = nodes whose slab interval was computed (entered or rejected);
//!   `leaves_visited` = leaves entered (empty or solid); `triangles_tested` = ray–triangle
//!   tests (a four-lane test of three triangles counts three).

mod build;
mod node;
mod traverse;

#[cfg(test)]
mod tests;

pub use node::Node;

use super::StructureStats;
use super::leaf::Soup;

/// The classic pointer octree over OAVM's subdivision.
pub struct ClassicOctree {
    /// Level by level: the children of a level's internal nodes, 8 at a time, in order.
    nodes: Vec<Node>,
    /// Triangle lists of the solid leaves: indices into `soup`.
    refs: Vec<u32>,
    soup: Soup,
    root_min: [f64; 3],
    /// Lattice cells per world unit.
    scale: f64,
    /// No tree (indices beyond 32 bits): every ray tests every triangle.
    linear: bool,
    internal_nodes: u64,
    solid_leaves: u64,
    stats: StructureStats,
}

impl ClassicOctree {
    /// Internal nodes and solid leaves (for tests and reports).
    pub fn counts(&self) -> (u64, u64) {
        (self.internal_nodes, self.solid_leaves)
    }
}
