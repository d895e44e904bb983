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
//!    cells; less where that would take more than an eighth of the budget), the triangles that
//!    overlap it widened by the cell margin (the exact triangle–box test of spec §6 where a
//!    triangle's box spans several cells). Summed upwards, these counts
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
//!    ([`super::blocks::partition`]) and the blocks are appended to the output; only
//!    the chunk's few top-tree nodes are kept.
//! 6. *Top*: the top tree above the chunks (empty leaves merged among their siblings as in the
//!    in-memory builder), the chunks' top nodes and the links are laid out together
//!    ([`super::blocks::assemble_top`]), then the directory and the header.
//!
//! **Memory.** Positions (12 bytes a vertex), the histogram (4 bytes a cell), three windows of
//! the mapped PLY (a 32nd of the budget each, 1 to 16 MiB), the spill buffers (an eighth of the
//! budget, 1 to 256 MiB), and one chunk's build: the chunk size is what is left of the budget
//! divided by [`BYTES_PER_CHUNK_TRIANGLE`], a measured upper bound of the in-memory builder's
//! peak per triangle. The trees of two chunks never coexist. Beyond the budget the process
//! itself takes about 20 MB (its code, thread stacks); measured (`oavm-pack --json`'s
//! `peak_rss_bytes`, commit 3126c7f, format 3): the dragon (871,414 triangles, as a binary PLY)
//! at a 16 MiB budget peaks at 33.2 MiB, at 64 MiB at 38.5 MiB; the file is 0.6 % larger at
//! 16 MiB than packed in memory (460 chunks, each in its own blocks), 192 bytes larger at
//! 64 MiB (39 chunks).
//!
//! **Differences from the in-memory build.** The top levels are split by the histogram rather
//! than by the leaf size (they hold far more than `K` triangles either way), and a chunk's root
//! does not know its ancestors' counts (the rule that stops where subdivision separates nothing
//! starts afresh at each chunk). Empty leaves above the chunks merge with their siblings; the
//! volumes of a chunk whose root turns out empty are its own cell. The file follows the same
//! specification and answers every ray the same way.

mod chunks;
mod plan;

use std::path::Path;
use std::time::Instant;

use super::run::{PackOptions, PackReport, StreamingReport};
use super::stats::{PhaseSeconds, TreeCounts};
use super::subdivide::Lattice;
use super::{BuildStats, Progress};
use crate::error::Error;
use crate::geom::triangle::is_degenerate;
use crate::mesh::stream::{PlyStream, StreamTriangle};
use crate::output::Output;
use crate::physical::format::PrimRecord;

pub use plan::HISTOGRAM_LEVEL;

/// Peak bytes of the in-memory builder per triangle of a chunk: triangle records (40), lattice
/// triangles (120), reference lists while subdividing and laying out, the laid-out parts, the
/// block copies and their encoded bytes. Measured: packing the dragon (871,414 triangles) in
/// memory peaks at 253 MB including the parsed mesh, about 290 bytes a triangle; this leaves room.
pub const BYTES_PER_CHUNK_TRIANGLE: u64 = 600;
/// Triangles per pass batch.
const BATCH: usize = 1 << 16;

/// The window of the passes over the map (a pass holds three of them): a 32nd of the budget,
/// between [`crate::mesh::stream::MIN_WINDOW`] and [`crate::mesh::stream::RELEASE_EVERY`].
fn window(mem_budget: u64) -> usize {
    ((mem_budget / 32) as usize).clamp(
        crate::mesh::stream::MIN_WINDOW,
        crate::mesh::stream::RELEASE_EVERY,
    )
}

/// What the bounds pass found.
struct Bounds {
    lo: [f32; 3],
    hi: [f32; 3],
    /// Triangles in the mesh, and those kept (not degenerate).
    input: u64,
    stored: u64,
}

/// A pass over the triangles of `ply` in batches, then a check that the file did not change
/// under its map meanwhile.
fn pass(
    ply: &PlyStream,
    positions: &[[f32; 3]],
    name: &str,
    progress: &dyn Progress,
    f: &mut dyn FnMut(&[StreamTriangle]) -> Result<(), Error>,
) -> Result<u64, Error> {
    progress.phase(name, Some(ply.file_len()), true);
    // A file changed under the pass explains any error the pass met: that is the one reported.
    let n = ply
        .for_each_triangle_batch(positions, BATCH, &|b| progress.at(b), f)
        .map_err(|e| ply.check_unchanged().err().unwrap_or(e))?;
    ply.check_unchanged()?;
    Ok(n)
}

/// Packs the binary PLY at `mesh_path` into `out` within about `mem_budget` bytes of memory.
pub(super) fn pack_streaming(
    mesh_path: &Path,
    out: Output,
    opts: &PackOptions,
    mem_budget: u64,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    let t0 = Instant::now();
    let ply = PlyStream::open(mesh_path)?.with_window(window(mem_budget));
    let file_len = ply.file_len();

    // 1. Vertices.
    progress.phase("reading vertices", Some(file_len), true);
    let positions = ply
        .read_positions(&|b| progress.at(b))
        .map_err(|e| ply.check_unchanged().err().unwrap_or(e.into()))?;
    ply.check_unchanged()?;

    // 2. Bounds of the non-degenerate triangles, hence the root cube; with --updatable, every
    // triangle's record of the primitive table (format-spec §8.6) into an unnamed temporary
    // file beside the output, by primitive id, copied after the blocks.
    let prims = match opts.updatable {
        true => Some(PrimSpill::new(out.path())?),
        false => None,
    };
    let b = bounds(&ply, &positions, prims.as_ref(), progress)?;
    let parse_seconds = t0.elapsed().as_secs_f64();
    if b.input > u32::MAX as u64 {
        return Err(Error::Invalid(format!(
            "{} triangles: primitive ids are 32-bit",
            b.input
        )));
    }
    if b.stored == 0 {
        return Err(Error::Invalid(format!(
            "{}: every triangle is degenerate; pack it without --mem-budget",
            mesh_path.display()
        )));
    }
    let lattice = match opts.bounds {
        Some((lo, hi)) => Lattice::fit(
            std::array::from_fn(|k| b.lo[k].min(lo[k])),
            std::array::from_fn(|k| b.hi[k].max(hi[k])),
        )?,
        None => Lattice::fit(b.lo, b.hi)?,
    };

    // 3. Histogram, top of the tree and chunks; 4. distribution into spill buckets.
    let plan = plan::plan(
        &ply,
        &positions,
        &lattice,
        mem_budget,
        &opts.build,
        progress,
    )?;
    let spill = plan::distribute(&ply, &positions, &lattice, &plan, out.path(), progress)?;
    drop(positions);
    let build_seconds_pre = t0.elapsed().as_secs_f64() - parse_seconds;

    // 5. Chunks, in Morton order, each built in memory and written as blocks; 6. the top.
    let t_chunks = Instant::now();
    let done = chunks::build_and_write(
        out,
        &plan,
        &spill,
        &lattice,
        &b,
        prims.as_ref(),
        opts,
        progress,
    )?;
    let chunk_seconds = t_chunks.elapsed().as_secs_f64();

    let stats = BuildStats::new(
        &done.counts,
        b.input,
        b.stored,
        PhaseSeconds {
            build: build_seconds_pre + chunk_seconds,
            ..PhaseSeconds::default()
        },
    );
    Ok(PackReport {
        mesh: mesh_path.display().to_string(),
        time: None,
        output: done.output,
        options: opts.build,
        mesh_bytes: file_len,
        parse_seconds,
        parse_mb_per_s: file_len as f64 / 1e6 / parse_seconds.max(1e-9),
        bytes_per_triangle: done.file_bytes as f64 / b.input.max(1) as f64,
        stats,
        write_seconds: 0.0,
        file_bytes: done.file_bytes,
        blocks: opts.blocks,
        block_count: done.block_count,
        streaming: Some(StreamingReport {
            mem_budget,
            chunks: plan.chunks.len() as u64,
            chunk_triangles_target: plan.chunk_triangles,
            largest_chunk_estimate: plan.chunks.iter().map(|c| c.estimate).max().unwrap_or(0),
            spill_bytes: spill.disk_bytes(),
            histogram_level: plan.h,
        }),
        ropes: None,
        occluders: None,
        total_seconds: t0.elapsed().as_secs_f64(),
        peak_rss_bytes: crate::os::peak_rss_bytes(),
    })
}

/// The primitive table's records (format-spec §8.6), held in an unnamed temporary file by
/// primitive id while the chunks are built.
pub(super) struct PrimSpill {
    file: std::fs::File,
    path: std::path::PathBuf,
}

impl PrimSpill {
    fn new(out: &Path) -> Result<PrimSpill, Error> {
        let dir = out
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let file = tempfile::tempfile_in(dir).map_err(|e| Error::io(dir, e))?;
        Ok(PrimSpill {
            file,
            path: dir.to_owned(),
        })
    }

    /// Writes the records of a batch (runs of consecutive primitive ids in one write each).
    fn write(&self, batch: &[StreamTriangle]) -> Result<(), Error> {
        use std::os::unix::fs::FileExt;
        let size = std::mem::size_of::<PrimRecord>() as u64;
        let mut run: Vec<u8> = Vec::new();
        let mut first = 0u32;
        let flush = |run: &mut Vec<u8>, first: u32| -> Result<(), Error> {
            if !run.is_empty() {
                self.file
                    .write_all_at(run, first as u64 * size)
                    .map_err(|e| Error::io(&self.path, e))?;
                run.clear();
            }
            Ok(())
        };
        for (i, (id, v)) in batch.iter().enumerate() {
            if i == 0 || *id != first + (run.len() as u64 / size) as u32 {
                flush(&mut run, first)?;
                first = *id;
            }
            run.extend_from_slice(bytemuck::bytes_of(&PrimRecord { v: *v }));
        }
        flush(&mut run, first)
    }

    /// The records of primitives `start .. start + buf.len()`.
    pub(super) fn read(&self, start: u64, buf: &mut [PrimRecord]) -> Result<(), Error> {
        use std::os::unix::fs::FileExt;
        let size = std::mem::size_of::<PrimRecord>() as u64;
        self.file
            .read_exact_at(bytemuck::cast_slice_mut(buf), start * size)
            .map_err(|e| Error::io(&self.path, e))
    }
}

/// Pass 2: the bounds of the non-degenerate triangles, and the triangle counts; every
/// triangle's record into `prims`, if given.
fn bounds(
    ply: &PlyStream,
    positions: &[[f32; 3]],
    prims: Option<&PrimSpill>,
    progress: &dyn Progress,
) -> Result<Bounds, Error> {
    let mut b = Bounds {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
        input: 0,
        stored: 0,
    };
    b.input = pass(ply, positions, "bounds", progress, &mut |batch| {
        if let Some(p) = prims {
            p.write(batch)?;
        }
        for (_, v) in batch {
            if is_degenerate(v) {
                continue;
            }
            b.stored += 1;
            for p in v {
                b.lo = std::array::from_fn(|k| b.lo[k].min(p[k]));
                b.hi = std::array::from_fn(|k| b.hi[k].max(p[k]));
            }
        }
        Ok(())
    })?;
    Ok(b)
}

/// What the chunks and the top made.
struct Written {
    output: String,
    file_bytes: u64,
    block_count: u32,
    /// Over the chunks' trees and the top tree above them.
    counts: TreeCounts,
}
