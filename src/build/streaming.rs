//! The streaming builder (`oavm-pack --mem-budget`): packs a binary PLY whose triangles do not
//! fit in memory, holding at most a budget's worth at a time, and writes the file in one pass.
//!
//! **Passes.**
//!
//! 1. *Vertices*: the PLY is read through a map ([`PlyStream`]); only the vertex positions are
//!    kept (12 bytes a vertex), the map is released behind the reader.
//! 2. *Bounds*: a pass over the triangles finds the bounds of the non-degenerate ones, hence the
//!    root cube (the same one the in-memory builder fits, format-spec §2).
//! 3. *Histogram*: a second pass counts, for every cell of level `H` (at most 8: 16.7 million
//!    cells; less where that would take more than an eighth of the budget), the triangles that overlap it widened by the cell margin (the exact triangle–box
//!    test of spec §6 where a triangle's box spans several cells). Summed upwards, these counts
//!    decide the **top of the tree** without holding any triangle: a node holding more than a
//!    chunk's worth of triangles is split, a node holding none is an empty leaf, any other node
//!    is a **chunk**, a subtree that will be built in memory. (Sums over-count triangles that
//!    straddle cells; that only makes a split more likely. Emptiness is exact: a cell counted 0
//!    has no triangle within its margin.)
//! 4. *Distribution* (an external distribution sort by Morton code): a third pass appends every
//!    triangle to the spill bucket of every chunk it overlaps ([`SpillBuckets`]: one unnamed
//!    temporary file, which the kernel removes whatever happens to the process).
//! 5. *Chunks*, in Morton order: each chunk's triangles are read back, its subtree is built,
//!    merged and laid out exactly as the in-memory builder does for a node
//!    ([`subdivide::subdivide_from`] and friends), split into blocks
//!    ([`crate::physical::blocks::partition`]) and the blocks are appended to the output; only
//!    the chunk's few top-tree nodes are kept.
//! 6. *Top*: the top tree above the chunks (empty leaves merged among their siblings as in the
//!    in-memory builder), the chunks' top nodes and the links are laid out together
//!    ([`crate::physical::blocks::assemble_top`]), then the directory and the header.
//!
//! **Memory.** Positions (12 bytes a vertex), the histogram (4 bytes a cell), the spill buffers
//! (an eighth of the budget, at most 256 MiB), and one chunk's build: the chunk size is what is
//! left of the budget divided by [`BYTES_PER_CHUNK_TRIANGLE`], a measured upper bound of the
//! in-memory builder's peak per triangle. The trees of two chunks never coexist.
//!
//! **Differences from the in-memory build.** The top levels are split by the histogram rather
//! than by the leaf size (they hold far more than `K` triangles either way), and a chunk's root
//! does not know its ancestors' counts (the rule that stops where subdivision separates nothing
//! starts afresh at each chunk). Empty leaves above the chunks merge with their siblings; the
//! volumes of a chunk whose root turns out empty are its own cell. The file follows the same
//! specification and answers every ray the same way.

use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use super::merge::{self, Merged};
use super::spill::SpillBuckets;
use super::subdivide::{self, BuildLevel, BuildNode, LatticeTri, SubdivideParams};
use super::{
    BuildOptions, BuildStats, PackReport, PointerCounts, is_degenerate, layout_from, root_cube,
};
use crate::error::Error;
use crate::geom::tribox::triangle_overlaps_box;
use crate::mapping::morton::{self, LATTICE_SIZE, MAX_LEVEL, cell_origin, cell_size};
use crate::mesh::stream::PlyStream;
use crate::physical::blocks::{TopKind, TopNode, assemble_top, partition};
use crate::physical::format::{CELL_MARGIN, TriRecord};
use crate::physical::writer::{
    BlockOptions, FileMeta, FileSink, FileWriter, StoredBlock, store_block, write_atomic_with,
};

/// Deepest level of the histogram (8: 2^24 cells, 64 MiB of counts).
pub const HISTOGRAM_LEVEL: u32 = 8;
/// Peak bytes of the in-memory builder per triangle of a chunk: triangle records (40), lattice
/// triangles (120), reference lists while subdividing and laying out, the laid-out parts, the
/// block copies and their encoded bytes. Measured: packing the dragon (871,414 triangles) in
/// memory peaks at 253 MB including the parsed mesh, about 290 bytes a triangle; this leaves room.
pub const BYTES_PER_CHUNK_TRIANGLE: u64 = 600;
/// Triangles per pass batch.
const BATCH: usize = 1 << 16;

/// What the streaming builder reports progress with: a phase, with its amount of work in
/// bytes of the input or in chunks, then how much is done.
pub trait PackProgress: Sync {
    fn phase(&self, name: &str, total: u64, bytes: bool);
    fn at(&self, done: u64);
}

/// No progress reporting.
pub struct Quiet;

impl PackProgress for Quiet {
    fn phase(&self, _: &str, _: u64, _: bool) {}
    fn at(&self, _: u64) {}
}

/// A chunk: a node of the top tree whose subtree is built in memory.
#[derive(Clone, Copy, Debug)]
struct Chunk {
    level: u32,
    code: u64,
    /// Triangles the histogram counted (an upper bound).
    estimate: u64,
}

/// Packs the binary PLY at `mesh_path` into `out` within about `mem_budget` bytes of memory.
pub fn pack_streaming(
    mesh_path: &Path,
    out: &Path,
    opts: &BuildOptions,
    blocks: &BlockOptions,
    mem_budget: u64,
    progress: &dyn PackProgress,
) -> Result<PackReport, Error> {
    opts.validate()?;
    blocks.validate()?;
    let t0 = Instant::now();
    let ply = PlyStream::open(mesh_path)?;
    let file_len = ply.file_len();

    // 1. Vertices.
    progress.phase("reading vertices", file_len, true);
    let positions = ply.read_positions(&|b| progress.at(b))?;
    // The histogram and its cell-to-chunk table take at most an eighth of the budget.
    let h = (1..=HISTOGRAM_LEVEL.min(opts.max_depth).max(1))
        .rev()
        .find(|&h| 8u64 << (3 * h) <= mem_budget / 8)
        .unwrap_or(1)
        .min(opts.max_depth);
    // Positions, and the histogram and the cell-to-chunk table (4 bytes a cell each).
    let fixed = positions.len() as u64 * 12 + (8u64 << (3 * h));

    // 2. Bounds of the non-degenerate triangles.
    progress.phase("bounds", file_len, true);
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut stored = 0u64;
    let input =
        ply.for_each_triangle_batch(&positions, BATCH, &|b| progress.at(b), &mut |batch| {
            for (_, v) in batch {
                if is_degenerate(v) {
                    continue;
                }
                stored += 1;
                for p in v {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
            }
            Ok(())
        })?;
    let parse_seconds = t0.elapsed().as_secs_f64();
    if input > u32::MAX as u64 {
        return Err(Error::Invalid(format!(
            "{input} triangles: primitive ids are 32-bit"
        )));
    }
    if stored == 0 {
        return Err(Error::Invalid(format!(
            "{}: every triangle is degenerate; pack it without --mem-budget",
            mesh_path.display()
        )));
    }
    let (root_min, root_size) = root_cube(lo, hi);
    let scale = LATTICE_SIZE as f64 / root_size;
    let to_lattice = |v: &[[f32; 3]; 3]| {
        LatticeTri::new(std::array::from_fn(|i| {
            std::array::from_fn(|k| (v[i][k] as f64 - root_min[k]) * scale)
        }))
    };

    // 3. Histogram at level H, and the top of the tree.
    let cells = 1usize << (3 * h);
    let counts: Vec<AtomicU32> = (0..cells).map(|_| AtomicU32::new(0)).collect();
    progress.phase("counting", file_len, true);
    ply.for_each_triangle_batch(&positions, BATCH, &|b| progress.at(b), &mut |batch| {
        batch.par_iter().for_each(|(_, v)| {
            if is_degenerate(v) {
                return;
            }
            let t = to_lattice(v);
            for_cells_overlapping(&t, h, |code| {
                let c = &counts[code as usize];
                // Saturating: a count only decides splits, never correctness.
                let _ = c.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |x| x.checked_add(1));
            });
        });
        Ok(())
    })?;
    let spill_bytes = (mem_budget / 8).clamp(16 << 20, 256 << 20);
    let chunk_budget = mem_budget.saturating_sub(fixed + spill_bytes);
    let chunk_tris = (chunk_budget / BYTES_PER_CHUNK_TRIANGLE).max(opts.leaf_size as u64 * 8);
    let (top_levels, chunks) = top_tree(&counts, h, chunk_tris, opts.merge);
    drop(counts);

    // Which chunk each histogram cell lies in (u32::MAX: an empty top leaf).
    let mut chunk_of = vec![u32::MAX; cells];
    for (i, c) in chunks.iter().enumerate() {
        let shift = 3 * (h - c.level);
        let first = (c.code << shift) as usize;
        chunk_of[first..first + (1usize << shift)].fill(i as u32);
    }

    // 4. Distribution into per-chunk spill buckets.
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut spill = SpillBuckets::new(dir, chunks.len().max(1), spill_bytes as usize)?;
    progress.phase("distributing", file_len, true);
    ply.for_each_triangle_batch(&positions, BATCH, &|b| progress.at(b), &mut |batch| {
        let routed: Vec<Vec<(u32, TriRecord)>> = batch
            .par_iter()
            .map(|&(prim, v)| {
                if is_degenerate(&v) {
                    return Vec::new();
                }
                let t = to_lattice(&v);
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
    drop(chunk_of);
    drop(positions);
    let build_seconds_pre = t0.elapsed().as_secs_f64() - parse_seconds;

    // 5. Chunks, in Morton order, each built in memory and written as blocks.
    let params = SubdivideParams {
        max_depth: opts.max_depth,
        leaf_size: opts.leaf_size,
    };
    let t_chunks = Instant::now();
    let top_only = top_levels.clone();
    let mut top_nodes = top_levels;
    let mut acc = Accumulated::default();
    let mut level_count = top_nodes.iter().map(|n| n.level + 1).max().unwrap_or(1);
    let mut failure: Option<Error> = None;
    let result = write_atomic_with(out, |file| {
        // Library errors inside are kept in `failure`; the closure reports them as I/O errors
        // only so that the temporary file is removed.
        let mut fail = |e: Error| {
            failure = Some(e);
            std::io::Error::other("streaming build failed")
        };
        let sink = FileSink::new(file.try_clone()?);
        let mut w = FileWriter::new(sink)?;
        progress.phase("building chunks", chunks.len() as u64, false);
        for (i, c) in chunks.iter().enumerate() {
            let mut records = spill.read(i as u32).map_err(&mut fail)?;
            records.par_sort_unstable_by_key(|r| r.prim);
            let lattice: Vec<LatticeTri> = records.par_iter().map(|r| to_lattice(&r.v)).collect();
            let levels = subdivide::subdivide_from(&lattice, c.level, c.code, params, &|_, _| {});
            let boxes = merge::merge_volumes_from(&levels, c.level, opts.merge);
            let parts =
                layout_from(&levels, c.level, &boxes, &records, &lattice).map_err(&mut fail)?;
            drop((levels, boxes, lattice, records));
            acc.add(&parts, c.level);
            level_count = level_count.max(c.level + parts.levels.len() as u32);
            let split = partition(
                parts.unit(),
                c.level,
                &[c.code],
                blocks.block_size,
                w.block_count(),
            )
            .map_err(&mut fail)?;
            drop(parts);
            for batch in split.blocks.chunks(64) {
                let encoded: Vec<StoredBlock> = batch
                    .par_iter()
                    .map(|b| store_block(b.unit.as_ref(), b.root_level, b.id, blocks))
                    .collect::<Result<_, _>>()
                    .map_err(&mut fail)?;
                for e in encoded {
                    w.push(e)?;
                }
            }
            top_nodes.extend(split.top);
            progress.at(i as u64 + 1);
        }
        let top = assemble_top(std::mem::take(&mut top_nodes)).map_err(&mut fail)?;
        let top_empty = top_only
            .iter()
            .filter(|n| matches!(n.kind, TopKind::Empty { .. }))
            .count() as u64;
        let meta = FileMeta {
            root_min,
            root_size,
            mesh_min: lo,
            mesh_max: hi,
            input_triangles: input,
            stored_triangles: stored,
            empty_leaves: acc.empty + top_empty,
            solid_leaves: acc.solid,
            level_count,
            max_depth: opts.max_depth,
            leaf_size: opts.leaf_size,
            merged: opts.merge,
        };
        let block_count = w.block_count();
        let (sink, size) = w.finish(&meta, top.as_ref())?;
        sink.into_file()?;
        Ok((size, block_count, top))
    });
    let (file_bytes, block_count, top) = match (failure, result) {
        (Some(e), _) => return Err(e),
        (None, r) => r?,
    };
    let chunk_seconds = t_chunks.elapsed().as_secs_f64();

    // What the tree holds, for the report: the chunks' trees and the top tree above them.
    let mut nodes_per_level = acc.nodes_per_level.clone();
    let (mut top_internal, mut top_empty) = (0u64, 0u64);
    for n in &top_only {
        let l = n.level as usize;
        if nodes_per_level.len() <= l {
            nodes_per_level.resize(l + 1, 0);
        }
        nodes_per_level[l] += 1;
        match n.kind {
            TopKind::Internal => top_internal += 1,
            TopKind::Empty { .. } => top_empty += 1,
            TopKind::Link { .. } => {}
        }
    }
    let nodes: u64 = nodes_per_level.iter().sum();
    let internal = acc.internal + top_internal;
    let empty = acc.empty + top_empty;
    let rank_entries: u64 = acc.rank_entries + top.ranks.len() as u64;
    let leaf_offsets = empty + acc.solid;
    let stats = BuildStats {
        input_triangles: input,
        triangles: stored,
        degenerate_triangles: input - stored,
        depth: level_count - 1,
        nodes_per_level,
        nodes,
        internal_nodes: internal,
        empty_leaves: empty,
        solid_leaves: acc.solid,
        volumes: acc.volumes + top.volumes.len() as u64,
        empty_leaves_per_volume: empty as f64
            / (acc.volumes + top.volumes.len() as u64).max(1) as f64,
        refs: acc.refs,
        refs_per_triangle: acc.refs as f64 / stored.max(1) as f64,
        pointers: PointerCounts {
            child_pointers: 0,
            rank_entries,
            leaf_offsets,
            total: rank_entries + leaf_offsets,
            pointer_octree_child_pointers: 8 * internal,
            pointer_octree_leaf_offsets: acc.solid,
            pointer_octree_total: 8 * internal + acc.solid,
        },
        build_seconds: build_seconds_pre + chunk_seconds,
        merge_seconds: 0.0,
        layout_seconds: 0.0,
    };
    Ok(PackReport {
        mesh: mesh_path.display().to_string(),
        time: None,
        output: out.display().to_string(),
        options: *opts,
        mesh_bytes: file_len,
        parse_seconds,
        parse_mb_per_s: file_len as f64 / 1e6 / parse_seconds.max(1e-9),
        bytes_per_triangle: file_bytes as f64 / input.max(1) as f64,
        stats,
        write_seconds: 0.0,
        file_bytes,
        blocks: *blocks,
        block_count,
        streaming: Some(super::StreamingReport {
            mem_budget,
            chunks: chunks.len() as u64,
            chunk_triangles_target: chunk_tris,
            largest_chunk_estimate: chunks.iter().map(|c| c.estimate).max().unwrap_or(0),
            spill_bytes: spill.disk_bytes(),
            histogram_level: h,
        }),
        total_seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Totals over the chunks' trees.
#[derive(Default)]
struct Accumulated {
    nodes_per_level: Vec<u64>,
    internal: u64,
    empty: u64,
    solid: u64,
    volumes: u64,
    refs: u64,
    rank_entries: u64,
}

impl Accumulated {
    fn add(&mut self, parts: &crate::physical::writer::TreeParts, base: u32) {
        for (i, lv) in parts.levels.iter().enumerate() {
            let l = base as usize + i;
            if self.nodes_per_level.len() <= l {
                self.nodes_per_level.resize(l + 1, 0);
            }
            self.nodes_per_level[l] += lv.node_count;
            self.internal += lv.internal_count;
        }
        self.empty += parts.empty_leaves;
        self.solid += parts.solid_leaves;
        self.volumes += parts.volumes.len() as u64;
        self.refs += parts.refs.len() as u64;
        self.rank_entries += parts.ranks.len() as u64;
    }
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

/// Whether `t` overlaps the cell of `code` at `level`, widened by the cell margin (spec §6).
fn overlaps_cell(t: &LatticeTri, code: u64, level: u32) -> bool {
    let s = cell_size(level) as f64;
    let o = cell_origin(code, level);
    let c: [f64; 3] = std::array::from_fn(|k| o[k] as f64 + s * 0.5);
    let half = [s * 0.5 + CELL_MARGIN; 3];
    // A triangle whose box lies inside the widened cell overlaps it.
    let inside = (0..3).all(|k| t.lo[k] >= c[k] - half[k] && t.hi[k] <= c[k] + half[k]);
    inside || triangle_overlaps_box(&t.v, c, half)
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
