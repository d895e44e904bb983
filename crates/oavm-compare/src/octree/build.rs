//! Building the classic octree.
//!
//! **Build.** The same tree as OAVM's, so that the comparison isolates what OAVM adds (merged
//! empty volumes, pointer-free Morton layout, neighbour stepping): the same root cube
//! ([`oavm::physical::format::root_cube`] of the triangles' bounds), the same mapping of the triangles
//! into the `2^21` lattice (in f64, as `prepare` in [`oavm::pack`] does), and the same
//! subdivision ([`oavm::pack::subdivide::subdivide`], with OAVM's `K` and `D` from
//! [`BuildOptions`]): a node is split while it holds more than `K` triangles, a triangle goes to
//! every child it overlaps by the exact triangle–box test, with the cell grown by
//! [`CELL_MARGIN`]. No merging. The levels are then stored as a pointer octree: every internal
//! node holds the indices of its 8 children, every solid leaf the offset and length of its
//! triangle list (a run of the reference array), every empty leaf nothing.
//!
//! [`CELL_MARGIN`]: oavm::physical::format::CELL_MARGIN

use rayon::prelude::*;

use super::ClassicOctree;
use super::node::Node;
use crate::aabb::Aabb;
use crate::leaf::Soup;
use crate::{StructureStats, Triangles};
use oavm::mapping::morton::LATTICE_SIZE;
use oavm::pack::BuildOptions;
use oavm::pack::subdivide::{self, BuildNode, LatticeTri, SubdivideParams};

impl ClassicOctree {
    /// Builds the octree over `tris` with OAVM's subdivision parameters from `opts` (see the
    /// module documentation). Never panics.
    pub fn build(tris: &Triangles, opts: &BuildOptions) -> ClassicOctree {
        let t0 = std::time::Instant::now();
        let mut tree = Self::build_tree(tris, opts);
        let node_bytes = tree.nodes.len() * std::mem::size_of::<Node>();
        tree.stats = StructureStats {
            name: "octree",
            build_seconds: t0.elapsed().as_secs_f64(),
            nodes: tree.nodes.len() as u64,
            pointers: 8 * tree.internal_nodes + tree.solid_leaves,
            bytes: (node_bytes + tree.refs.len() * 4 + tree.soup.bytes()) as u64,
        };
        tree
    }

    fn build_tree(tris: &Triangles, opts: &BuildOptions) -> ClassicOctree {
        let mut tree = ClassicOctree {
            nodes: Vec::new(),
            refs: Vec::new(),
            soup: Soup::finite(tris),
            root_min: [0.0; 3],
            scale: 1.0,
            linear: false,
            internal_nodes: 0,
            solid_leaves: 0,
            stats: StructureStats::default(),
        };
        if tree.soup.is_empty() {
            return tree;
        }
        if tree.soup.len() > u32::MAX as usize {
            tree.linear = true;
            return tree;
        }
        // Bounds of the (finite) triangles: `tris.min`/`tris.max` whenever all are finite.
        let mut b = Aabb::EMPTY;
        for p in tree.soup.v.iter().flatten() {
            b.grow_point(p);
        }
        let (lo, hi) = (b.lo, b.hi);
        // The root cube and lattice mapping of `pack::prepare`, expression for expression.
        let (root_min, root_size) = oavm::physical::format::root_cube(lo, hi);
        let scale = LATTICE_SIZE as f64 / root_size;
        tree.root_min = root_min;
        tree.scale = scale;
        let lattice: Vec<LatticeTri> = tree
            .soup
            .v
            .par_iter()
            .map(|v| {
                LatticeTri::new(std::array::from_fn(|i| {
                    std::array::from_fn(|k| (v[i][k] as f64 - root_min[k]) * scale)
                }))
            })
            .collect();
        let params = SubdivideParams {
            max_depth: opts.max_depth,
            // OAVM refuses K = 0 (`BuildOptions::validate`); here it means K = 1.
            leaf_size: opts.leaf_size.max(1),
        };
        let levels = subdivide::subdivide(&lattice, params, &|_, _| {});
        drop(lattice);

        // Pointer octree, level by level: the children of a level's internal nodes, 8 at a time
        // in order, are the next level's nodes (see `subdivide`).
        let total: usize = levels.iter().map(|l| l.nodes.len()).sum();
        let total_refs: usize = levels
            .iter()
            .flat_map(|l| &l.nodes)
            .map(|n| match n {
                BuildNode::Leaf(t) => t.len(),
                BuildNode::Internal => 0,
            })
            .sum();
        if u32::try_from(total).is_err() || u32::try_from(total_refs).is_err() {
            tree.linear = true;
            return tree;
        }
        let mut nodes = Vec::with_capacity(total);
        let mut refs = Vec::with_capacity(total_refs);
        let mut next_level_start = 0usize;
        for level in &levels {
            next_level_start += level.nodes.len();
            let mut internal = 0usize;
            for n in &level.nodes {
                match n {
                    BuildNode::Internal => {
                        let first = next_level_start + 8 * internal;
                        internal += 1;
                        tree.internal_nodes += 1;
                        // first + 7 < total <= u32::MAX (checked above)
                        nodes.push(Node::internal(std::array::from_fn(|o| {
                            u32::try_from(first + o).unwrap_or(u32::MAX)
                        })));
                    }
                    BuildNode::Leaf(t) => {
                        if !t.is_empty() {
                            tree.solid_leaves += 1;
                        }
                        nodes.push(Node::leaf(
                            u32::try_from(refs.len()).unwrap_or(u32::MAX),
                            u32::try_from(t.len()).unwrap_or(u32::MAX),
                        ));
                        refs.extend_from_slice(t);
                    }
                }
            }
        }
        tree.nodes = nodes;
        tree.refs = refs;
        tree
    }
}
