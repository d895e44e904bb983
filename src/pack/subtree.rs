//! One subtree built in memory from the triangles that overlap its root's widened cell:
//! subdivided, merged, laid out and split into blocks exactly as the in-memory builder does for
//! the whole tree. The streaming builder builds its chunks so; an update rebuilds so the
//! subtrees whose triangles changed.

use rayon::prelude::*;

use super::BuildOptions;
use super::blocks::{Split, partition};
use super::layout::layout_from;
use super::merge;
use super::stats::TreeCounts;
use super::subdivide::{
    self, BuildLevel, BuildNode, Lattice, LatticeTri, SubdivideParams, box_misses, overlaps_cell,
    widened_cell,
};
use crate::error::Error;
use crate::mapping::ClusterGeometry;
use crate::physical::format::TriRecord;

/// A subtree built and split into blocks.
pub(crate) struct Subtree {
    /// Its blocks (numbered from the `first_block` asked for) and top-tree nodes, the root's
    /// among them.
    pub split: Split,
    /// Its nodes, leaves, volumes and rank words.
    pub counts: TreeCounts,
    /// One past its deepest absolute level.
    pub level_end: u32,
}

/// Builds the subtree of node `code` at absolute level `level` over `records` (the triangles
/// overlapping its widened cell, sorted by primitive id), and splits it into blocks of about
/// `block_size` bytes numbered from `first_block`. With no triangles the root is an empty leaf
/// (a top-tree node whose volume is its own cell; the caller merges it with its siblings).
#[allow(clippy::too_many_arguments)]
pub(crate) fn build_subtree(
    records: &[TriRecord],
    level: u32,
    code: u64,
    lattice: &Lattice,
    opts: &BuildOptions,
    block_size: u64,
    first_block: u32,
    clusters: Option<&ClusterGeometry>,
) -> Result<Subtree, Error> {
    build_subtrees(
        records,
        level,
        &[code],
        lattice,
        opts,
        block_size,
        first_block,
        clusters,
    )
}

/// [`build_subtree`] for several nodes of one level (`codes`, in Morton order) built together
/// over the union of their triangles (`records`, sorted by primitive id; each root takes those
/// that overlap its widened cell), so that consecutive roots are grouped into blocks as a pack
/// groups them: what an update does with the roots of a block it rebuilds.
#[allow(clippy::too_many_arguments)]
pub(crate) fn build_subtrees(
    records: &[TriRecord],
    level: u32,
    codes: &[u64],
    lattice: &Lattice,
    opts: &BuildOptions,
    block_size: u64,
    first_block: u32,
    clusters: Option<&ClusterGeometry>,
) -> Result<Subtree, Error> {
    let params = SubdivideParams {
        max_depth: opts.max_depth,
        leaf_size: opts.leaf_size,
    };
    let tris: Vec<LatticeTri> = records.par_iter().map(|r| lattice.map(&r.v)).collect();
    let levels = if let [code] = codes {
        subdivide::subdivide_from(&tris, level, *code, params, &|_, _| {})
    } else {
        // Each root over its own triangles, its leaves' indices mapped back into `tris`, the
        // roots' levels laid side by side (the mapping rule holds across them: a level's
        // internal nodes, root after root, have their children in the same order below).
        let mut levels: Vec<BuildLevel> = Vec::new();
        for &code in codes {
            let cell = widened_cell(code, level);
            let mine: Vec<u32> = (0..tris.len() as u32)
                .filter(|&i| {
                    let t = &tris[i as usize];
                    !box_misses(t, &cell) && overlaps_cell(t, code, level)
                })
                .collect();
            let sub: Vec<LatticeTri> = mine.iter().map(|&i| tris[i as usize]).collect();
            let built = subdivide::subdivide_from(&sub, level, code, params, &|_, _| {});
            for (l, lv) in built.into_iter().enumerate() {
                if levels.len() <= l {
                    levels.push(BuildLevel {
                        codes: Vec::new(),
                        nodes: Vec::new(),
                    });
                }
                levels[l].codes.extend(lv.codes);
                levels[l]
                    .nodes
                    .extend(lv.nodes.into_iter().map(|n| match n {
                        BuildNode::Leaf(ids) => {
                            BuildNode::Leaf(ids.into_iter().map(|i| mine[i as usize]).collect())
                        }
                        other => other,
                    }));
            }
        }
        levels
    };
    let boxes = merge::merge_volumes_from(&levels, level, opts.merge);
    let laid = layout_from(&levels, level, &boxes, records, &tris)?;
    drop((levels, boxes, tris));
    let mut counts = TreeCounts::default();
    counts.add(
        laid.tree.as_ref(),
        level,
        laid.empty_leaves,
        laid.solid_leaves,
    );
    let level_end = level + laid.tree.levels.len() as u32;
    let split = partition(
        laid.tree.as_ref(),
        level,
        codes,
        block_size,
        first_block,
        clusters,
    )?;
    Ok(Subtree {
        split,
        counts,
        level_end,
    })
}
