//! The streaming builder's passes 5 and 6: each chunk's triangles read back from its spill
//! bucket, its subtree built, merged and laid out exactly as the in-memory builder does for a
//! node, split into blocks and written; then the top tree above the chunks, the directory and
//! the header.

use rayon::prelude::*;

use super::super::blocks::{TopKind, assemble_top};
use super::super::run::PackOptions;
use super::super::spill::SpillBuckets;
use super::super::stats::TreeCounts;
use super::super::subdivide::Lattice;
use super::super::subtree::build_subtree;
use super::super::write::write_blocks;
use super::super::{HeaderFields, LeafKind, Progress};
use super::plan::Plan;
use super::{Bounds, PrimSpill, Written};
use crate::error::Error;
use crate::mapping::ClusterGeometry;
use crate::output::Output;
use crate::physical::format::{PRIM_CHUNK, PrimRecord};
use crate::physical::writer::{FileSink, FileWriter};

/// Builds every chunk of `plan` in Morton order and writes its blocks into `out`, then the top
/// tree and the header; commits `out`.
#[allow(clippy::too_many_arguments)]
pub(super) fn build_and_write(
    mut out: Output,
    plan: &Plan,
    spill: &SpillBuckets,
    lattice: &Lattice,
    bounds: &Bounds,
    prims: Option<&PrimSpill>,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<Written, Error> {
    let path = out.path().to_owned();
    let io = |e: std::io::Error| Error::io(&path, e);
    let mut w = FileWriter::new(FileSink::new(out.file().try_clone().map_err(io)?)).map_err(io)?;
    let mut top_nodes = plan.top.clone();
    let mut counts = TreeCounts::default();
    let mut level_count = top_nodes.iter().map(|n| n.level + 1).max().unwrap_or(1);
    let clusters = (opts.build.leaf == LeafKind::Cluster).then_some(ClusterGeometry {
        root_min: lattice.root_min,
        root_size: lattice.root_size,
    });
    progress.phase("building chunks", Some(plan.chunks.len() as u64), false);
    for (i, c) in plan.chunks.iter().enumerate() {
        let mut records = spill.read(i as u32)?;
        records.par_sort_unstable_by_key(|r| r.prim);
        let built = build_subtree(
            &records,
            c.level,
            c.code,
            lattice,
            &opts.build,
            opts.blocks.block_size,
            w.block_count(),
            clusters.as_ref(),
        )?;
        drop(records);
        counts.add_counts(&built.counts);
        level_count = level_count.max(built.level_end);
        write_blocks(&built.split.blocks, &opts.blocks, &mut w, &io)?;
        top_nodes.extend(built.split.top);
        progress.at(i as u64 + 1);
    }
    let top = assemble_top(top_nodes)?;
    if let Some(p) = prims {
        // The primitive table after the blocks, a chunk at a time.
        let mut buf = vec![PrimRecord::ABSENT; PRIM_CHUNK as usize];
        for c in 0..bounds.input.div_ceil(PRIM_CHUNK) {
            let start = c * PRIM_CHUNK;
            let n = (bounds.input - start).min(PRIM_CHUNK) as usize;
            p.read(start, &mut buf[..n])?;
            w.write_prim_chunk(c as usize, &buf[..n]).map_err(io)?;
        }
    }

    // The top tree above the chunks, in the counts.
    for n in &plan.top {
        let l = n.level as usize;
        if counts.nodes_per_level.len() <= l {
            counts.nodes_per_level.resize(l + 1, 0);
        }
        counts.nodes_per_level[l] += 1;
        match n.kind {
            TopKind::Internal => counts.internal += 1,
            TopKind::Empty { .. } => counts.empty += 1,
            TopKind::Link { .. } => {}
        }
    }
    counts.rank_entries += top.ranks.len() as u64;
    counts.volumes += top.volumes.len() as u64;

    let header = HeaderFields {
        root: (lattice.root_min, lattice.root_size),
        mesh: (bounds.lo, bounds.hi),
        input_triangles: bounds.input,
        stored_triangles: bounds.stored,
        empty_leaves: counts.empty,
        solid_leaves: counts.solid,
        level_count,
    }
    .header(&opts.build);
    let block_count = w.block_count();
    let (sink, file_bytes) = w.finish(&header, top.as_ref()).map_err(io)?;
    sink.into_file().map_err(io)?;
    let output = out.path().display().to_string();
    out.commit()?;
    Ok(Written {
        output,
        file_bytes,
        block_count,
        counts,
    })
}
