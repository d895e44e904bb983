//! The streaming builder's plan: a histogram of where the triangles are (pass 3), the top of
//! the tree and its chunks decided from it, and the triangles distributed to their chunks'
//! spill buckets (pass 4). See the parent module for the passes.

use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::super::blocks::{TopKind, TopNode};
use super::super::merge::{self, Merged};
use super::super::spill::SpillBuckets;
use super::super::subdivide::{BuildLevel, BuildNode, LatticeTri, overlaps_cell};
use super::super::{BuildOptions, Progress};
use super::{BYTES_PER_CHUNK_TRIANGLE, Lattice, pass};
use crate::error::Error;
use crate::geom::triangle::is_degenerate;
use crate::mapping::morton::{self, MAX_LEVEL, cell_size};
use crate::mesh::stream::PlyStream;
use crate::physical::format::{CELL_MARGIN, TriRecord};

/// Deepest level of the histogram (8: 2^24 cells, 64 MiB of counts).
pub const HISTOGRAM_LEVEL: u32 = 8;

/// A chunk: a node of the top tree whose subtree is built in memory.
#[derive(Clone, Copy, Debug)]
pub(super) struct Chunk {
    pub(super) level: u32,
    pub(super) code: u64,
    /// Triangles the histogram counted (an upper bound).
    pub(super) estimate: u64,
}

/// The top of the tree and the chunks below it.
pub(super) struct Plan {
    /// Level of the histogram.
    pub(super) h: u32,
    /// The top tree's internal nodes and empty leaves.
    pub(super) top: Vec<TopNode>,
    /// In Morton order.
    pub(super) chunks: Vec<Chunk>,
    /// Triangles a chunk may hold, from the budget.
    pub(super) chunk_triangles: u64,
    /// The spill buffers' share of the budget.
    spill_bytes: u64,
}

/// Pass 3: counts, for every cell of level `H`, the triangles that overlap it (widened by the
/// cell margin), and decides the top of the tree and its chunks from the counts.
pub(super) fn plan(
    ply: &PlyStream,
    positions: &[[f32; 3]],
    lattice: &Lattice,
    mem_budget: u64,
    opts: &BuildOptions,
    progress: &dyn Progress,
) -> Result<Plan, Error> {
    // The histogram and its cell-to-chunk table take at most an eighth of the budget.
    let h = (1..=HISTOGRAM_LEVEL.min(opts.max_depth).max(1))
        .rev()
        .find(|&h| 8u64 << (3 * h) <= mem_budget / 8)
        .unwrap_or(1)
        .min(opts.max_depth);
    let cells = 1usize << (3 * h);
    let counts: Vec<AtomicU32> = (0..cells).map(|_| AtomicU32::new(0)).collect();
    pass(ply, positions, "counting", progress, &mut |batch| {
        batch.par_iter().for_each(|(_, v)| {
            if is_degenerate(v) {
                return;
            }
            let t = lattice.map(v);
            for_cells_overlapping(&t, h, |code| {
                let c = &counts[code as usize];
                // Saturating: a count only decides splits, never correctness.
                let _ = c.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |x| x.checked_add(1));
            });
        });
        Ok(())
    })?;
    // Positions, the histogram and the cell-to-chunk table (4 bytes a cell each), and the
    // passes' three windows of the map.
    let fixed =
        positions.len() as u64 * 12 + (8u64 << (3 * h)) + 3 * super::window(mem_budget) as u64;
    let spill_bytes = (mem_budget / 8).clamp(1 << 20, 256 << 20);
    let chunk_budget = mem_budget.saturating_sub(fixed + spill_bytes);
    let chunk_triangles = (chunk_budget / BYTES_PER_CHUNK_TRIANGLE).max(opts.leaf_size as u64 * 8);
    let (top, chunks) = top_tree(&counts, h, chunk_triangles, opts.merge);
    Ok(Plan {
        h,
        top,
        chunks,
        chunk_triangles,
        spill_bytes,
    })
}

/// Pass 4 (an external distribution sort by Morton code): appends every triangle to the spill
/// bucket of every chunk it overlaps, in an unnamed temporary file beside `out`.
pub(super) fn distribute(
    ply: &PlyStream,
    positions: &[[f32; 3]],
    lattice: &Lattice,
    plan: &Plan,
    out: &Path,
    progress: &dyn Progress,
) -> Result<SpillBuckets, Error> {
    let h = plan.h;
    // Which chunk each histogram cell lies in (u32::MAX: an empty top leaf).
    let mut chunk_of = vec![u32::MAX; 1usize << (3 * h)];
    for (i, c) in plan.chunks.iter().enumerate() {
        let shift = 3 * (h - c.level);
        let first = (c.code << shift) as usize;
        chunk_of[first..first + (1usize << shift)].fill(i as u32);
    }
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let chunks = &plan.chunks;
    let mut spill = SpillBuckets::new(dir, chunks.len().max(1), plan.spill_bytes as usize)?;
    pass(ply, positions, "distributing", progress, &mut |batch| {
        let routed: Vec<Vec<(u32, TriRecord)>> = batch
            .par_iter()
            .map(|&(prim, v)| {
                if is_degenerate(&v) {
                    return Vec::new();
                }
                let t = lattice.map(&v);
                let mut candidates: Vec<u32> = Vec::new();
                for_cells_of_box(&t, h, |code| {
                    let c = chunk_of[code as usize];
                    if c != u32::MAX && !candidates.contains(&c) {
                        candidates.push(c);
                    }
                });
                let rec = TriRecord { v, prim };
                candidates
                    .into_iter()
                    .filter(|&c| {
                        overlaps_cell(&t, chunks[c as usize].code, chunks[c as usize].level)
                    })
                    .map(|c| (c, rec))
                    .collect::<Vec<_>>()
            })
            .collect();
        for list in routed {
            for (c, rec) in list {
                spill.push(c, &rec)?;
            }
        }
        Ok(())
    })?;
    spill.finish()?;
    Ok(spill)
}

/// Calls `f` with the level-`h` code of every cell whose margin-widened box overlaps `t`'s
/// bounding box.
fn for_cells_of_box(t: &LatticeTri, h: u32, mut f: impl FnMut(u64)) {
    let s = cell_size(h) as f64;
    let n = (1u32 << h) - 1;
    let range = |k: usize| {
        let a = ((t.lo[k] - CELL_MARGIN) / s).floor().clamp(0.0, n as f64) as u32;
        let b = ((t.hi[k] + CELL_MARGIN) / s).floor().clamp(0.0, n as f64) as u32;
        (a, b)
    };
    let (x, y, z) = (range(0), range(1), range(2));
    for cz in z.0..=z.1 {
        for cy in y.0..=y.1 {
            for cx in x.0..=x.1 {
                let shift = MAX_LEVEL - h;
                f(morton::encode([cx << shift, cy << shift, cz << shift]) >> (3 * shift));
            }
        }
    }
}

/// Calls `f` with the level-`h` code of every cell `t` overlaps (widened by the margin), by the
/// exact test where its box spans several cells (no allocation: this runs once per triangle).
fn for_cells_overlapping(t: &LatticeTri, h: u32, mut f: impl FnMut(u64)) {
    let mut first = None;
    let mut several = false;
    for_cells_of_box(t, h, |c| match first {
        None => first = Some(c),
        Some(_) => several = true,
    });
    match first {
        Some(c) if !several => f(c),
        _ => for_cells_of_box(t, h, |c| {
            if overlaps_cell(t, c, h) {
                f(c);
            }
        }),
    }
}

/// The top of the tree from the level-`h` histogram: the top tree's internal nodes and empty
/// leaves (merged among their siblings), and the chunks in Morton order.
fn top_tree(
    counts: &[AtomicU32],
    h: u32,
    chunk_tris: u64,
    merge: bool,
) -> (Vec<TopNode>, Vec<Chunk>) {
    // Counts per level, summed upwards (level h first).
    let mut per_level: Vec<Vec<u64>> = vec![Vec::new(); h as usize + 1];
    per_level[h as usize] = counts
        .iter()
        .map(|c| c.load(Ordering::Relaxed) as u64)
        .collect();
    for l in (0..h as usize).rev() {
        let below = &per_level[l + 1];
        per_level[l] = below.chunks(8).map(|c| c.iter().sum()).collect();
    }
    // Top-down: split, empty leaf, or chunk; as build levels, so that empty leaves merge as in
    // the in-memory builder (a chunk counts as a non-empty leaf).
    let mut levels: Vec<BuildLevel> = Vec::new();
    let mut chunks = Vec::new();
    let mut current = vec![0u64];
    let mut l = 0u32;
    while !current.is_empty() {
        let mut next = Vec::new();
        let mut nodes = Vec::with_capacity(current.len());
        for &code in &current {
            let count = per_level[l as usize][code as usize];
            if count == 0 {
                nodes.push(BuildNode::Leaf(Vec::new()));
            } else if l < h && count > chunk_tris {
                nodes.push(BuildNode::Internal);
                next.extend((0..8).map(|o| code << 3 | o));
            } else {
                nodes.push(BuildNode::Leaf(vec![0]));
                chunks.push(Chunk {
                    level: l,
                    code,
                    estimate: count,
                });
            }
        }
        levels.push(BuildLevel {
            codes: current,
            nodes,
        });
        current = next;
        l += 1;
    }
    let boxes = merge::merge_volumes(&levels, merge);
    let mut top = Vec::new();
    for (l, lv) in levels.iter().enumerate() {
        for (i, (n, &code)) in lv.nodes.iter().zip(&lv.codes).enumerate() {
            let kind = match n {
                BuildNode::Internal => TopKind::Internal,
                BuildNode::Leaf(t) if t.is_empty() => {
                    let Some(Merged { volume, shape }) = boxes[l][i] else {
                        continue;
                    };
                    TopKind::Empty { volume, shape }
                }
                BuildNode::Leaf(_) => continue, // a chunk: its own partition gives its nodes
            };
            top.push(TopNode {
                level: l as u32,
                code,
                kind,
            });
        }
    }
    chunks.sort_unstable_by_key(|c| c.code << (3 * (MAX_LEVEL - c.level)));
    (top, chunks)
}
