//! The builder: a mesh in, the parts of an `.oavm` file out.
//!
//! Phases: prepare the triangles (drop degenerate ones, fit the root cube, map to the lattice),
//! [`subdivide`] into the octree, [`merge`] empty leaves into volumes, then lay the tree out in
//! the order of `format-spec.md` (levels in Morton order; references and triangles in leaf order).
//! Build-time nodes ([`subdivide::BuildNode`]) and file records
//! ([`crate::physical::format::NodeRecord`]) are different types: a convenient tree while
//! building, flat records for traversal.

pub mod merge;
pub mod spill;
pub mod streaming;
pub mod subdivide;

use std::collections::HashMap;
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::error::Error;
use crate::mapping::morton::{LATTICE_SIZE, MAX_LEVEL};
use crate::mesh::Mesh;
use crate::physical::format::{
    LeafBounds, LevelEntry, MAX_INLINE_REFS, NodeRecord, RankWord, TriRecord, VolumeRecord,
    VolumeShape,
};
use crate::physical::writer::{BlockOptions, TreeParts};
use subdivide::{BuildLevel, BuildNode, LatticeTri, SubdivideParams};

/// Build options. The defaults were chosen by measurement (see `tools/tune.rs` and the README).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct BuildOptions {
    /// Deepest level a leaf may have (`D`; the root is level 0). At most 21.
    pub max_depth: u32,
    /// A leaf is subdivided while it holds more than this many triangles (`K`).
    pub leaf_size: u32,
    /// Merge empty leaves into larger empty volumes (paper §2.3); off: every empty leaf is its
    /// own volume.
    pub merge: bool,
}

/// Default `D`: a cap for pathologically dense meshes. Real meshes stop earlier, by `K` (the
/// dragon's tree is 11 levels deep at `K = 32`), so it does not change their trees.
pub const DEFAULT_MAX_DEPTH: u32 = 16;
/// Default `K`, chosen with `tools/tune.sh` (throughput relative to obvhs on the bunny and the
/// dragon, primary, random and shadow rays): 8 gave 0.46-0.55x, 16 gave 0.53-0.59x, 24 to 48 a
/// plateau at 0.51-0.63x; 32 is in the middle of the plateau and keeps files small.
pub const DEFAULT_LEAF_SIZE: u32 = 32;

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            max_depth: DEFAULT_MAX_DEPTH,
            leaf_size: DEFAULT_LEAF_SIZE,
            merge: true,
        }
    }
}

impl BuildOptions {
    pub fn validate(&self) -> Result<(), Error> {
        if self.max_depth > MAX_LEVEL {
            return Err(Error::Invalid(format!(
                "--max-depth {} is too deep: the lattice allows at most {MAX_LEVEL}",
                self.max_depth
            )));
        }
        if self.leaf_size == 0 {
            return Err(Error::Invalid("--leaf-size must be at least 1".into()));
        }
        Ok(())
    }
}

/// Stored pointers and offsets, against what a classic pointer octree over the same subdivision
/// stores (counting conventions in `format-spec.md` §9).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PointerCounts {
    /// Child pointers stored: none, children are found by rank.
    pub child_pointers: u64,
    /// Rank directory entries (one per 64 nodes of a level).
    pub rank_entries: u64,
    /// Offsets from leaves into other sections: first reference of each solid leaf, volume index
    /// of each empty leaf.
    pub leaf_offsets: u64,
    pub total: u64,
    /// A pointer octree: 8 child pointers per internal node.
    pub pointer_octree_child_pointers: u64,
    /// A pointer octree: one triangle-list pointer per solid leaf.
    pub pointer_octree_leaf_offsets: u64,
    pub pointer_octree_total: u64,
}

/// What the builder made, for `oavm-pack`'s report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BuildStats {
    pub input_triangles: u64,
    /// Triangles stored (the input minus degenerate ones, which no ray can hit).
    pub triangles: u64,
    pub degenerate_triangles: u64,
    pub depth: u32,
    pub nodes_per_level: Vec<u64>,
    pub nodes: u64,
    pub internal_nodes: u64,
    pub empty_leaves: u64,
    pub solid_leaves: u64,
    pub volumes: u64,
    /// Empty leaves per volume (1 without merging).
    pub empty_leaves_per_volume: f64,
    pub refs: u64,
    pub refs_per_triangle: f64,
    pub pointers: PointerCounts,
    pub build_seconds: f64,
    pub merge_seconds: f64,
    pub layout_seconds: f64,
}

/// Builds the file parts for `mesh`. `progress` is told what phase is running.
pub fn build(
    mesh: &Mesh,
    opts: &BuildOptions,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(TreeParts, BuildStats), Error> {
    opts.validate()?;
    let t0 = Instant::now();
    progress("preparing triangles");
    let prepared = prepare(mesh)?;
    let Prepared {
        records,
        lattice,
        root_min,
        root_size,
        mesh_min,
        mesh_max,
    } = prepared;

    progress("subdividing");
    let params = SubdivideParams {
        max_depth: opts.max_depth,
        leaf_size: opts.leaf_size,
    };
    let levels = subdivide::subdivide(&lattice, params, &|level, n| {
        progress(&format!("subdividing: level {level}, {n} nodes"))
    });
    let build_seconds = t0.elapsed().as_secs_f64();

    progress("merging empty volumes");
    let t1 = Instant::now();
    let boxes = merge::merge_volumes(&levels, opts.merge);
    let merge_seconds = t1.elapsed().as_secs_f64();

    progress("laying out");
    let t2 = Instant::now();
    let mut parts = layout(&levels, &boxes, &records, &lattice)?;
    parts.root_min = root_min;
    parts.root_size = root_size;
    parts.mesh_min = mesh_min;
    parts.mesh_max = mesh_max;
    parts.input_triangles = mesh.triangles.len() as u64;
    parts.max_depth = opts.max_depth;
    parts.leaf_size = opts.leaf_size;
    parts.merged = opts.merge;
    let layout_seconds = t2.elapsed().as_secs_f64();

    let stats = stats_of(
        &parts,
        mesh,
        records.len() as u64,
        build_seconds,
        merge_seconds,
        layout_seconds,
    );
    Ok((parts, stats))
}

struct Prepared {
    records: Vec<TriRecord>,
    lattice: Vec<LatticeTri>,
    root_min: [f64; 3],
    root_size: f64,
    mesh_min: [f32; 3],
    mesh_max: [f32; 3],
}

/// Validates the mesh, drops degenerate triangles, fits the root cube and maps the triangles
/// into the lattice.
fn prepare(mesh: &Mesh) -> Result<Prepared, Error> {
    if mesh.triangles.is_empty() {
        return Err(Error::Invalid("the mesh has no triangles".into()));
    }
    if mesh.triangles.len() > u32::MAX as usize {
        return Err(Error::Invalid(format!(
            "{} triangles: primitive ids are 32-bit",
            mesh.triangles.len()
        )));
    }
    let n = mesh.positions.len();
    let mut records = Vec::with_capacity(mesh.triangles.len());
    for (i, tri) in mesh.triangles.iter().enumerate() {
        let mut v = [[0f32; 3]; 3];
        for (k, &ix) in tri.iter().enumerate() {
            let p = mesh.positions.get(ix as usize).ok_or_else(|| {
                Error::Invalid(format!(
                    "triangle {i} refers to vertex {ix}, the mesh has {n}"
                ))
            })?;
            if !p.iter().all(|c| c.is_finite()) {
                return Err(Error::Invalid(format!(
                    "vertex {ix} has non-finite coordinates {p:?}"
                )));
            }
            v[k] = *p;
        }
        if !is_degenerate(&v) {
            records.push(TriRecord { v, prim: i as u32 });
        }
    }

    // Bounds of the stored triangles (or of every vertex used, if all are degenerate).
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut grow = |p: &[f32; 3]| {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    };
    if records.is_empty() {
        for tri in &mesh.triangles {
            tri.iter()
                .for_each(|&ix| grow(&mesh.positions[ix as usize]));
        }
    } else {
        records.iter().flat_map(|r| r.v.iter()).for_each(&mut grow);
    }

    let (root_min, root_size) = root_cube(lo, hi);
    let scale = LATTICE_SIZE as f64 / root_size;

    let lattice = records
        .par_iter()
        .map(|r| {
            LatticeTri::new(std::array::from_fn(|i| {
                std::array::from_fn(|k| (r.v[i][k] as f64 - root_min[k]) * scale)
            }))
        })
        .collect();
    Ok(Prepared {
        records,
        lattice,
        root_min,
        root_size,
        mesh_min: lo,
        mesh_max: hi,
    })
}

/// The root cube for mesh bounds `lo..hi` (format-spec §2): centred on the mesh, edge = the
/// largest extent plus 1/1024, so the mesh sits strictly inside; a mesh with no extent (one
/// point) gets an edge of `1e-6` of its largest coordinate magnitude, or 1. Returns the lowest
/// corner and the edge. `verify` recomputes it to check a file's header.
pub fn root_cube(lo: [f32; 3], hi: [f32; 3]) -> ([f64; 3], f64) {
    let centre: [f64; 3] = std::array::from_fn(|k| (lo[k] as f64 + hi[k] as f64) * 0.5);
    let extent = (0..3)
        .map(|k| hi[k] as f64 - lo[k] as f64)
        .fold(0.0, f64::max);
    let mut root_size = extent * (1.0 + 1.0 / 1024.0);
    if !(root_size > 0.0 && root_size.is_normal()) {
        let mag = centre.iter().map(|c| c.abs()).fold(0.0, f64::max);
        root_size = if mag > 0.0 { mag * 1e-6 } else { 1.0 };
    }
    (
        std::array::from_fn(|k| centre[k] - root_size * 0.5),
        root_size,
    )
}

/// A triangle whose edges' cross product is exactly zero in f64 (coincident or collinear
/// corners): it has no area and no ray can hit it (`RAYS.md`: degenerate triangles keep their
/// ids but are never hit), so it is not stored.
pub(crate) fn is_degenerate(v: &[[f32; 3]; 3]) -> bool {
    let e1: [f64; 3] = std::array::from_fn(|k| v[1][k] as f64 - v[0][k] as f64);
    let e2: [f64; 3] = std::array::from_fn(|k| v[2][k] as f64 - v[0][k] as f64);
    let c = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    c == [0.0; 3]
}

/// Lays the tree out as file records: node records per level, the rank directory, the volume
/// table, references and triangles in leaf (depth-first, i.e. global Morton) order.
fn layout(
    levels: &[BuildLevel],
    boxes: &merge::LeafBoxes,
    records: &[TriRecord],
    lattice: &[LatticeTri],
) -> Result<TreeParts, Error> {
    layout_from(levels, 0, boxes, records, lattice)
}

/// [`layout`] for a subtree whose `levels[0]` is absolute level `base`.
fn layout_from(
    levels: &[BuildLevel],
    base: u32,
    boxes: &merge::LeafBoxes,
    records: &[TriRecord],
    lattice: &[LatticeTri],
) -> Result<TreeParts, Error> {
    // All leaves, ordered by the Morton code of their lowest lattice corner: depth-first order,
    // so the leaves (and with them references and triangles) of a subtree are contiguous.
    let mut leaves: Vec<(u64, u32, u32)> = levels
        .iter()
        .enumerate()
        .flat_map(|(l, lv)| {
            lv.nodes
                .iter()
                .zip(&lv.codes)
                .enumerate()
                .filter(|(_, (n, _))| matches!(n, BuildNode::Leaf(_)))
                .map(move |(i, (_, &code))| {
                    (
                        code << (3 * (MAX_LEVEL - base - l as u32)),
                        l as u32,
                        i as u32,
                    )
                })
        })
        .collect();
    leaves.par_sort_unstable();

    // Tight bounds of every solid leaf (spec §4.2), in parallel.
    let bounds: Vec<Vec<LeafBounds>> = levels
        .par_iter()
        .enumerate()
        .map(|(l, lv)| {
            lv.nodes
                .par_iter()
                .zip(&lv.codes)
                .map(|(n, &code)| match n {
                    BuildNode::Leaf(t) if !t.is_empty() => {
                        leaf_bounds(lattice, t, code, base + l as u32)
                    }
                    _ => LeafBounds::FULL,
                })
                .collect()
        })
        .collect();

    let too_many = |what: &str, n: usize| {
        Error::Build(format!(
            "{n} {what}: more than this version's 32-bit indices can address; raise --leaf-size \
             or lower --max-depth"
        ))
    };
    let mut payload: Vec<Vec<u32>> = levels.iter().map(|lv| vec![0; lv.nodes.len()]).collect();
    let mut shapes: Vec<Vec<VolumeShape>> = levels
        .iter()
        .map(|lv| vec![VolumeShape { level: 0, axes: 0 }; lv.nodes.len()])
        .collect();
    let mut refs: Vec<u32> = Vec::new();
    let mut new_index = vec![u32::MAX; records.len()];
    let mut triangles: Vec<TriRecord> = Vec::with_capacity(records.len());
    let mut volumes: Vec<VolumeRecord> = Vec::new();
    let mut volume_index: HashMap<VolumeRecord, u32> = HashMap::new();
    for &(_, l, i) in &leaves {
        let (l, i) = (l as usize, i as usize);
        let BuildNode::Leaf(tris) = &levels[l].nodes[i] else {
            continue;
        };
        if tris.is_empty() {
            let merged =
                boxes[l][i].ok_or_else(|| Error::Build("empty leaf without a volume".into()))?;
            let b = merged.volume;
            let next = volumes.len();
            let v = *volume_index.entry(b).or_insert_with(|| {
                volumes.push(b);
                next as u32
            });
            if volumes.len() > u32::MAX as usize {
                return Err(too_many("volumes", volumes.len()));
            }
            payload[l][i] = v;
            shapes[l][i] = merged.shape;
        } else {
            if refs.len() + tris.len() + 1 > u32::MAX as usize {
                return Err(too_many("triangle references", refs.len() + tris.len()));
            }
            payload[l][i] = refs.len() as u32;
            if tris.len() > MAX_INLINE_REFS as usize {
                refs.push(tris.len() as u32); // escaped count (spec §4.2)
            }
            let start = refs.len();
            for &t in tris {
                let slot = &mut new_index[t as usize];
                if *slot == u32::MAX {
                    *slot = triangles.len() as u32;
                    triangles.push(records[t as usize]);
                }
                refs.push(*slot);
            }
            refs[start..].sort_unstable();
        }
    }

    let mut level_entries = Vec::with_capacity(levels.len());
    let mut nodes = Vec::new();
    let mut ranks = Vec::new();
    let (mut empty_leaves, mut solid_leaves) = (0u64, 0u64);
    for (l, lv) in levels.iter().enumerate() {
        let entry = LevelEntry {
            node_count: lv.nodes.len() as u64,
            internal_count: lv
                .nodes
                .iter()
                .filter(|n| matches!(n, BuildNode::Internal))
                .count() as u64,
            node_start: nodes.len() as u64,
            rank_start: ranks.len() as u64,
        };
        level_entries.push(entry);
        let mut rank = 0u64;
        for (chunk_i, chunk) in lv.nodes.chunks(64).enumerate() {
            let mut bits = 0u64;
            for (j, n) in chunk.iter().enumerate() {
                let i = chunk_i * 64 + j;
                nodes.push(match n {
                    BuildNode::Internal => {
                        bits |= 1 << j;
                        NodeRecord::internal()
                    }
                    BuildNode::Leaf(t) if t.is_empty() => {
                        empty_leaves += 1;
                        NodeRecord::empty(payload[l][i], shapes[l][i])
                    }
                    BuildNode::Leaf(t) => {
                        solid_leaves += 1;
                        NodeRecord::solid(payload[l][i], t.len() as u32, bounds[l][i])
                    }
                });
            }
            ranks.push(RankWord {
                internal: bits,
                rank,
            });
            rank += bits.count_ones() as u64;
        }
    }

    Ok(TreeParts {
        empty_leaves,
        solid_leaves,
        levels: level_entries,
        nodes,
        ranks,
        volumes,
        refs,
        triangles,
        ..TreeParts::default()
    })
}

/// The tight bounds of a solid leaf: the box of the parts of its triangles inside its cell
/// (enlarged by the cell margin, like the cell the triangles were assigned to), in sixteenths of
/// the cell, rounded outward.
fn leaf_bounds(lattice: &[LatticeTri], tris: &[u32], code: u64, level: u32) -> LeafBounds {
    use crate::mapping::morton::{cell_origin, cell_size};
    let size = cell_size(level) as f64;
    let origin = cell_origin(code, level).map(|c| c as f64);
    let m = crate::physical::format::CELL_MARGIN;
    let lo: [f64; 3] = std::array::from_fn(|k| origin[k] - m);
    let hi: [f64; 3] = std::array::from_fn(|k| origin[k] + size + m);
    let mut blo = [f64::INFINITY; 3];
    let mut bhi = [f64::NEG_INFINITY; 3];
    for &t in tris {
        let tri = &lattice[t as usize];
        // The exact clip; if rounding leaves nothing of a triangle the exact test kept, fall back
        // to its bounding box (still conservative).
        let (a, b) = crate::geom::tribox::clipped_bounds(&tri.v, lo, hi).unwrap_or((
            std::array::from_fn(|k| tri.lo[k].max(lo[k])),
            std::array::from_fn(|k| tri.hi[k].min(hi[k])),
        ));
        for k in 0..3 {
            blo[k] = blo[k].min(a[k]);
            bhi[k] = bhi[k].max(b[k]);
        }
    }
    let q = 16.0 / size;
    let mut b = LeafBounds::FULL;
    for k in 0..3 {
        let l = ((blo[k] - origin[k]) * q).floor().clamp(0.0, 15.0);
        let h = ((bhi[k] - origin[k]) * q).ceil().clamp(1.0, 16.0) - 1.0;
        if l <= h {
            b.lo[k] = l as u8;
            b.hi[k] = h as u8;
        }
    }
    b
}

fn stats_of(
    parts: &TreeParts,
    mesh: &Mesh,
    stored: u64,
    build_seconds: f64,
    merge_seconds: f64,
    layout_seconds: f64,
) -> BuildStats {
    let internal: u64 = parts.levels.iter().map(|l| l.internal_count).sum();
    let rank_entries = parts.ranks.len() as u64;
    let leaf_offsets = parts.empty_leaves + parts.solid_leaves;
    let pointers = PointerCounts {
        child_pointers: 0,
        rank_entries,
        leaf_offsets,
        total: rank_entries + leaf_offsets,
        pointer_octree_child_pointers: 8 * internal,
        pointer_octree_leaf_offsets: parts.solid_leaves,
        pointer_octree_total: 8 * internal + parts.solid_leaves,
    };
    BuildStats {
        input_triangles: mesh.triangles.len() as u64,
        triangles: stored,
        degenerate_triangles: mesh.triangles.len() as u64 - stored,
        depth: parts.levels.len() as u32 - 1,
        nodes_per_level: parts.levels.iter().map(|l| l.node_count).collect(),
        nodes: parts.nodes.len() as u64,
        internal_nodes: internal,
        empty_leaves: parts.empty_leaves,
        solid_leaves: parts.solid_leaves,
        volumes: parts.volumes.len() as u64,
        empty_leaves_per_volume: if parts.volumes.is_empty() {
            0.0
        } else {
            parts.empty_leaves as f64 / parts.volumes.len() as f64
        },
        refs: parts.refs.len() as u64,
        refs_per_triangle: if stored == 0 {
            0.0
        } else {
            parts.refs.len() as f64 / stored as f64
        },
        pointers,
        build_seconds,
        merge_seconds,
        layout_seconds,
    }
}

/// What [`pack`] did, for `oavm-pack`'s report.
#[derive(Clone, Debug, Serialize)]
pub struct PackReport {
    pub mesh: String,
    /// The scene time an animated (AFF) scene was posed at, when one was asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time: Option<f64>,
    pub output: String,
    pub options: BuildOptions,
    pub mesh_bytes: u64,
    pub parse_seconds: f64,
    pub parse_mb_per_s: f64,
    #[serde(flatten)]
    pub stats: BuildStats,
    pub write_seconds: f64,
    pub file_bytes: u64,
    pub bytes_per_triangle: f64,
    /// How blocks were made, and how many.
    #[serde(rename = "block_options")]
    pub blocks: BlockOptions,
    pub block_count: u32,
    /// How the streaming builder (`--mem-budget`) split the work; absent for the in-memory one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub streaming: Option<StreamingReport>,
    pub total_seconds: f64,
}

/// What the streaming builder did ([`streaming::pack_streaming`]).
#[derive(Clone, Debug, Serialize)]
pub struct StreamingReport {
    pub mem_budget: u64,
    /// Subtrees built in memory one at a time.
    pub chunks: u64,
    /// Triangles a chunk may hold, from the budget.
    pub chunk_triangles_target: u64,
    /// The largest chunk's triangle count as the histogram estimated it.
    pub largest_chunk_estimate: u64,
    /// Bytes spilled to the temporary file (triangles, once per chunk they overlap).
    pub spill_bytes: u64,
    pub histogram_level: u32,
}

/// Reads the mesh at `mesh_path`, builds its tree and writes it to `out` atomically: on any
/// error nothing is left at `out`.
pub fn pack(
    mesh_path: &std::path::Path,
    out: &std::path::Path,
    opts: &BuildOptions,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<PackReport, Error> {
    pack_at(mesh_path, None, out, opts, progress)
}

/// [`pack`] with an animated (BART AFF) scene posed at `time` ([`crate::mesh::load_at`]); a
/// time for any other format is an error.
pub fn pack_at(
    mesh_path: &std::path::Path,
    time: Option<f64>,
    out: &std::path::Path,
    opts: &BuildOptions,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<PackReport, Error> {
    pack_with(
        mesh_path,
        time,
        out,
        opts,
        &BlockOptions::default(),
        progress,
    )
}

/// [`pack_at`] with the file's blocks made and stored as `blocks` says.
pub fn pack_with(
    mesh_path: &std::path::Path,
    time: Option<f64>,
    out: &std::path::Path,
    opts: &BuildOptions,
    blocks: &BlockOptions,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<PackReport, Error> {
    opts.validate()?;
    blocks.validate()?;
    let t0 = Instant::now();
    progress("parsing the mesh");
    let mesh_bytes = std::fs::metadata(mesh_path).map(|m| m.len()).unwrap_or(0);
    let mesh = crate::mesh::load_at(mesh_path, time)?;
    let parse_seconds = t0.elapsed().as_secs_f64();

    let (parts, stats) = build(&mesh, opts, progress)?;
    drop(mesh);

    progress("writing");
    let t1 = Instant::now();
    let (file_bytes, block_count) = crate::physical::writer::write_file(out, &parts, blocks)?;
    drop(parts);
    let write_seconds = t1.elapsed().as_secs_f64();
    Ok(PackReport {
        mesh: mesh_path.display().to_string(),
        time,
        output: out.display().to_string(),
        options: *opts,
        mesh_bytes,
        parse_seconds,
        parse_mb_per_s: mesh_bytes as f64 / 1e6 / parse_seconds.max(1e-9),
        bytes_per_triangle: file_bytes as f64 / stats.input_triangles.max(1) as f64,
        stats,
        write_seconds,
        file_bytes,
        blocks: *blocks,
        block_count,
        streaming: None,
        total_seconds: t0.elapsed().as_secs_f64(),
    })
}
