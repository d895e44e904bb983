//! `oavm-pack MESH... OUT.oavm`: builds the OAVM tree of a mesh (or of several, each a
//! geometry of the file) and writes it as one file.

mod cli;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use cli::LeafArg;
use oavm::pack::{self, BuildOptions, PackOptions, PackReport};
use oavm::physical::BlockOptions;

/// Packs a triangle mesh (PLY, OBJ, STL, OFF, glTF/GLB with its node transforms baked in, or a BART AFF scene posed at one time) into an .oavm file: a
/// Morton-ordered octree with merged empty volumes, ready to be memory-mapped and traced by
/// oavm-trace.
#[derive(Parser, Debug)]
#[command(name = "oavm-pack", version)]
struct Args {
    /// Input mesh: .ply (ascii or binary), .obj, .stl, .off, .gltf/.glb, or .aff (a BART
    /// scene with its includes). Several: each is a geometry of the file's geometry table
    /// (format-spec §8.8), named by its file name, its primitives numbered after the previous
    /// ones' (as is each node of a glTF scene).
    #[arg(required = true, num_args = 1..)]
    mesh: Vec<PathBuf>,
    /// Output .oavm file: written atomically (it appears only when complete); through a
    /// symlink to its target; never a directory, device or FIFO, nor the input.
    out: PathBuf,
    /// Deepest level of the octree (the root is level 0); at most 21.
    #[arg(long, default_value_t = pack::DEFAULT_MAX_DEPTH)]
    max_depth: u32,
    /// What a solid leaf holds: `cluster`, a wide BVH over SIMD groups of triangles (the
    /// fastest), or `list`, a list of triangle references (the OAVM paper's structure).
    #[arg(long, value_enum, default_value_t = LeafArg::Cluster)]
    leaf: LeafArg,
    /// Subdivide leaves holding more than this many triangles [default: 512 for clusters, 32
    /// for lists].
    #[arg(long)]
    leaf_size: Option<u32>,
    /// Do not merge empty leaves into larger volumes.
    #[arg(long)]
    no_merge: bool,
    /// Pose an animated .aff scene at this time (default: its animation start, or 0). An error
    /// for other formats.
    #[arg(
        long,
        value_name = "T",
        allow_negative_numbers = true,
        conflicts_with = "mem_budget"
    )]
    time: Option<f64>,
    /// Target size of a block (the unit of paging), e.g. 256K or 1M.
    #[arg(long, value_name = "SIZE", value_parser = cli::parse_bytes, default_value = "256K")]
    block_size: u64,
    /// Store blocks zstd-compressed, at LEVEL (default 3; 1-22, higher is smaller and slower
    /// to pack; tracing speed hardly depends on it). A block that does not shrink stays raw.
    #[arg(long, value_name = "LEVEL", num_args = 0..=1, require_equals = true,
          default_missing_value = "3", allow_negative_numbers = true)]
    compress: Option<i32>,
    /// Triangle groups per chunk (160 bytes each): the unit in which a block's groups are
    /// checked, compressed and read out of core. 128 (20 KiB) keeps raw chunks in whole pages.
    #[arg(long, value_name = "N", default_value_t = oavm::physical::DEFAULT_CHUNK_GROUPS)]
    chunk_groups: u32,
    /// Store triangle groups in the lean encoding (format-spec §7.3): lossless, about two
    /// thirds of their bytes, decoded far faster than zstd. For files traced out of core chunk
    /// by chunk (`oavm-trace --chunks`), where the disk's bytes count; in memory a lean file's
    /// blocks are decoded, not mapped. Not with --compress.
    #[arg(long, conflicts_with = "compress")]
    lean: bool,
    /// Pack within about this much memory (e.g. 4G), streaming the mesh: for meshes whose
    /// triangles do not fit in memory. Reads binary PLY only. Without it the whole mesh is read
    /// and built in memory, unless it is a binary PLY whose triangles would take more than the
    /// memory available to build (the build peaks at about 240 bytes a triangle; the rule
    /// counts 256): then it is streamed within half of that memory. The process itself takes about 20 MB beyond the budget; small
    /// budgets cut the tree into many chunks, each in its own blocks, and the file grows a
    /// little (the dragon at 16M: 0.6 % larger than packed in memory).
    #[arg(long, value_name = "SIZE", value_parser = cli::parse_bytes)]
    mem_budget: Option<u64>,
    /// Add ropes (format-spec §8.4): for every leaf, the node across each face of the box a
    /// walk crosses there, so that `oavm-trace --walk ropes` steps from leaf to leaf without
    /// finding the neighbour from Morton codes. 24 bytes per node; answers are unchanged.
    #[arg(long)]
    ropes: bool,
    /// Add occluders (format-spec §8.5): large triangles also stored at internal nodes of their
    /// block, where a shadow ray's top-down walk tests them before descending (the primitive
    /// index of Liang and Huang's multi-index tree). Answers are unchanged.
    #[arg(long)]
    occluders: bool,
    /// Store the primitive table (format-spec §8.6: every input triangle's corners by
    /// primitive id, 36 bytes a triangle), so that `oavm-update` can bring the file to new
    /// geometry in place. Not with --ropes or --occluders.
    #[arg(long)]
    updatable: bool,
    /// Fit the root cube to hold the box LO..HI as well as the mesh (X,Y,Z..X,Y,Z, world
    /// units): room for later updates to move triangles into (oavm-update refuses triangles
    /// outside the root cube).
    #[arg(long, value_name = "X,Y,Z..X,Y,Z", value_parser = parse_box, allow_hyphen_values = true)]
    bounds: Option<([f32; 3], [f32; 3])>,
    /// Print the report as one JSON object.
    #[arg(long)]
    json: bool,
    /// Worker threads (0: one per core). The output is identical for any count.
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("oavm-pack", || {
        let opts = PackOptions {
            build: BuildOptions {
                max_depth: args.max_depth,
                leaf_size: args
                    .leaf_size
                    .unwrap_or(args.leaf.kind().default_leaf_size()),
                leaf: args.leaf.kind(),
                merge: !args.no_merge,
            },
            blocks: BlockOptions {
                block_size: args.block_size,
                compress: args.compress,
                chunk_groups: args.chunk_groups,
                lean: args.lean,
            },
            time: args.time,
            mem_budget: args.mem_budget,
            ropes: args.ropes,
            occluders: args.occluders,
            updatable: args.updatable,
            bounds: args.bounds,
        };
        let progress = cli::progress_bar();
        let report = cli::with_threads(args.threads, || {
            let meshes: Vec<&std::path::Path> = args.mesh.iter().map(PathBuf::as_path).collect();
            pack::pack_files(&meshes, &args.out, &opts, &progress)
        })?;
        progress.finish();
        if args.json {
            cli::print_json(&report)
        } else {
            cli::print_text(&human(&report))
        }
    })
}

/// Parses `X,Y,Z..X,Y,Z`: a box's lowest and highest corners.
fn parse_box(s: &str) -> Result<([f32; 3], [f32; 3]), String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("expected X,Y,Z..X,Y,Z, got {s:?}"))?;
    let (lo, hi) = (cli::parse_vec3(a)?, cli::parse_vec3(b)?);
    let f = |v: [f64; 3]| v.map(|c| c as f32);
    if (0..3).any(|k| lo[k] > hi[k] || !(f(lo)[k].is_finite() && f(hi)[k].is_finite())) {
        return Err(format!(
            "{s:?}: the first corner must be below the second, per axis"
        ));
    }
    Ok((f(lo), f(hi)))
}

/// The text report of a pack, a line a figure: the mesh, the tree, the file, the optional
/// passes and the times.
fn human(r: &PackReport) -> String {
    let mut t = Lines::default();
    t.line(
        "mesh",
        format!("{} ({:.1} MB)", r.mesh, r.mesh_bytes as f64 / 1e6),
    );
    if let Some(time) = r.time {
        t.line("scene time", time);
    }
    tree(&mut t, r);
    file(&mut t, r);
    passes(&mut t, r);
    let s = &r.stats;
    t.line(
        "time",
        format!(
            "parse {:.3} s ({:.0} MB/s), build {:.3} s, merge {:.3} s, layout {:.3} s, write {:.3} s; total {:.3} s",
            r.parse_seconds,
            r.parse_mb_per_s,
            s.build_seconds,
            s.merge_seconds,
            s.layout_seconds,
            r.write_seconds,
            r.total_seconds
        ),
    );
    t.0
}

/// A text report: a line a figure, `key value`, the values aligned.
#[derive(Default)]
struct Lines(String);

impl Lines {
    fn line(&mut self, key: &str, value: impl std::fmt::Display) {
        self.0.push_str(&format!("{key:<22} {value}\n"));
    }
}

/// The tree built: its triangles, options, nodes, leaves, merged volumes, references and the
/// pointers it stores (against a pointer octree's).
fn tree(t: &mut Lines, r: &PackReport) {
    let s = &r.stats;
    let p = &s.pointers;
    t.line(
        "triangles",
        format!(
            "{} ({} stored, {} degenerate dropped)",
            s.input_triangles, s.triangles, s.degenerate_triangles
        ),
    );
    t.line(
        "options",
        format!(
            "max depth {}, leaf size {}, merging {}",
            r.options.max_depth,
            r.options.leaf_size,
            if r.options.merge { "on" } else { "off" }
        ),
    );
    t.line("depth", s.depth);
    let per_level: Vec<String> = s.nodes_per_level.iter().map(|n| n.to_string()).collect();
    t.line("nodes per level", per_level.join(" "));
    t.line(
        "nodes",
        format!("{} ({} internal)", s.nodes, s.internal_nodes),
    );
    t.line(
        "leaves",
        format!("{} solid, {} empty", s.solid_leaves, s.empty_leaves),
    );
    t.line(
        "merged volumes",
        format!(
            "{} ({:.2} empty leaves per volume)",
            s.volumes, s.empty_leaves_per_volume
        ),
    );
    t.line(
        "triangle references",
        format!("{} ({:.2} per triangle)", s.refs, s.refs_per_triangle),
    );
    t.line(
        "stored pointers",
        format!(
            "{} (0 child pointers, {} rank entries, {} leaf offsets); a pointer octree: {} ({} child, {} leaf)",
            p.total,
            p.rank_entries,
            p.leaf_offsets,
            p.pointer_octree_total,
            p.pointer_octree_child_pointers,
            p.pointer_octree_leaf_offsets
        ),
    );
}

/// The file written: its size, its blocks and, for a streaming pack, the chunks.
fn file(t: &mut Lines, r: &PackReport) {
    t.line(
        "file",
        format!(
            "{} ({} bytes, {:.1} bytes per triangle)",
            r.output, r.file_bytes, r.bytes_per_triangle
        ),
    );
    t.line(
        "blocks",
        format!(
            "{} of about {} KiB, {}",
            r.block_count,
            r.blocks.block_size >> 10,
            match r.blocks.compress {
                Some(level) => format!("zstd level {level}"),
                None if r.blocks.lean => "groups lean".to_string(),
                None => "raw".to_string(),
            }
        ),
    );
    if let Some(st) = &r.streaming {
        t.line(
            "streaming",
            format!(
                "budget {} MiB: {} chunks of at most ~{} triangles (largest ~{}), {:.1} MB spilled",
                st.mem_budget >> 20,
                st.chunks,
                st.chunk_triangles_target,
                st.largest_chunk_estimate,
                st.spill_bytes as f64 / 1e6
            ),
        );
    }
}

/// The optional passes: occluders and ropes.
fn passes(t: &mut Lines, r: &PackReport) {
    if let Some(o) = &r.occluders {
        t.line(
            "occluders",
            format!(
                "{} triangles at {} internal nodes, of {} candidates; {:.1} MB of records \
                 (+{:.1} %); {:.3} s choosing them, {:.3} s for the pass",
                o.occluders,
                o.occluder_nodes,
                o.candidates,
                o.occluder_bytes as f64 / 1e6,
                100.0 * (o.bytes_after as f64 / o.bytes_before.max(1) as f64 - 1.0),
                o.compute_seconds,
                o.seconds
            ),
        );
    }
    if let Some(rp) = &r.ropes {
        t.line(
            "ropes",
            format!(
                "{} on {} leaves and links ({} out of the root, {} from a block to the top tree), \
                 {:.1} MB of records (+{:.1} %); {:.3} s finding them, {:.3} s for the pass",
                rp.ropes,
                rp.roped_nodes,
                rp.exits,
                rp.to_top,
                rp.rope_bytes as f64 / 1e6,
                100.0 * (rp.bytes_after as f64 / rp.bytes_before.max(1) as f64 - 1.0),
                rp.compute_seconds,
                rp.seconds
            ),
        );
    }
}
