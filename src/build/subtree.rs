//! One subtree built in memory from the triangles that overlap its root's widened cell:
//! subdivided, merged, laid out and split into blocks exactly as the in-memory builder does for
//! the whole tree. The streaming builder builds its chunks so; an update rebuilds so the
//! subtrees whose triangles changed.

use rayon::prelude::*;

use super::BuildOptions;
use super::blocks::{ClusterGeometry, Split, partition};
use super::layout::layout_from;
use super::merge;
use super::stats::TreeCounts;
use super::subdivide::{self, Lattice, LatticeTri, SubdivideParams};
use crate::error::Error;
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
    let params = SubdivideParams {
        max_depth: opts.max_depth,
        leaf_size: opts.leaf_size,
    };
    let tris: Vec<LatticeTri> = records.par_iter().map(|r| lattice.map(&r.v)).collect();
    let levels = subdivide::subdivide_from(&tris, level, code, params, &|_, _| {});
    let boxes = merge::merge_volumes_from(&levels, level, opts.merge);
    let laid = layout_from(&levels, level, &boxes, records, &tris)?;
    drop((levels, boxes, tris));
    let mut counts = TreeCounts::default();
    counts.add(laid.tree.as_ref(), level, laid.empty_leaves, laid.solid_leaves);
    let level_end = level + laid.tree.levels.len() as u32;
    let split = partition(
        laid.tree.as_ref(),
        level,
        &[code],
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
