//! The builder: a mesh in, an `.oavm` file out.
//!
//! Phases: [`prepare`] the triangles (drop degenerate ones, fit the root cube, map to the
//! lattice), [`subdivide`] into the octree, [`merge`] empty leaves into volumes (OAVM paper
//! §2.3), [`layout`] the tree in the order of `format-spec.md` (levels in Morton order;
//! references and triangles in leaf order), split it into [`blocks`] and [`write`] them. Build-
//! time nodes ([`subdivide::BuildNode`]) and file records
//! ([`crate::physical::format::NodeRecord`]) are different types: a convenient tree while
//! building, flat records for traversal. [`streaming`] does the same within a memory budget,
//! chunk by chunk, for meshes larger than memory; [`pack`] is what `oavm-pack` runs.
//!
//! Format 4: [`build_cluster`] builds the compact wide BVH of one solid leaf (a cluster) and
//! [`crate::physical::check_cluster`] re-derives from its records that it is well-formed and
//! complete.

pub(crate) mod blocks;
mod cluster;
mod layout;
mod merge;
pub mod occluders;
mod prepare;
pub mod prims;
pub mod ropes;
mod run;
mod spill;
mod stats;
mod streaming;
pub mod subdivide;
mod subtree;
pub mod update;
mod write;

use std::time::Instant;

use bytemuck::Zeroable;
use serde::Serialize;

use crate::error::Error;
use crate::mesh::Mesh;
use crate::physical::format::MAX_LEVEL;
use crate::physical::format::{FLAG_CLUSTERS, FLAG_MERGED, Header};
pub use crate::progress::{Progress, Quiet};
pub use cluster::{
    ClusterBuild, ClusterBuilder, ClusterError, ClusterTri, build_cluster, triangle_box,
};
pub use prepare::check_scale;
pub use run::{
    PackOptions, PackReport, StreamingReport, pack, pack_files, pack_mesh, streaming_budget,
};
pub use stats::{BuildStats, PointerCounts};
use stats::{PhaseSeconds, TreeCounts};
pub use streaming::{BYTES_PER_CHUNK_TRIANGLE, HISTOGRAM_LEVEL};
use subdivide::SubdivideParams;
pub use write::{TreeParts, encode, encode_with};

/// Build options. The defaults were chosen by measurement (see `tools/tune.sh` and the constants below).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct BuildOptions {
    /// Deepest level a leaf may have (`D`; the root is level 0). At most 21.
    pub max_depth: u32,
    /// A leaf is subdivided while it holds more than this many triangles (`K`).
    pub leaf_size: u32,
    /// Merge empty leaves into larger empty volumes (paper §2.3); off: every empty leaf is its
    /// own volume.
    pub merge: bool,
    /// What a solid leaf holds (spec §2 flag `CLUSTERS`).
    pub leaf: LeafKind,
}

/// What a solid leaf holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LeafKind {
    /// A cluster: a wide BVH over groups of triangles laid out for SIMD (spec §7.1, §7.2);
    /// the default, and the fastest to trace.
    Cluster,
    /// A list of references to triangle records (spec §6, §7): the OAVM paper's leaves, kept
    /// so that the paper's structure can still be measured.
    List,
}

/// Default `D`: a cap for pathologically dense meshes. Real meshes stop earlier, by `K` (the
/// dragon's tree is 11 levels deep at `K = 32`), so it does not change their trees.
pub const DEFAULT_MAX_DEPTH: u32 = 16;
/// Default `K` of leaf lists, chosen with `tools/tune.sh` (throughput relative to obvhs on the
/// bunny and the dragon, primary, random and shadow rays): 8 gave 0.46-0.55x, 16 gave
/// 0.53-0.59x, 24 to 48 a plateau at 0.51-0.63x; 32 is in the middle of the plateau and keeps
/// files small.
pub const DEFAULT_LEAF_SIZE: u32 = 32;
/// Default `K` of clusters: the triangles a cluster may hold before its cell is subdivided.
pub const DEFAULT_CLUSTER_SIZE: u32 = 512;

impl LeafKind {
    /// The default `K` for leaves of this kind.
    pub fn default_leaf_size(self) -> u32 {
        match self {
            LeafKind::Cluster => DEFAULT_CLUSTER_SIZE,
            LeafKind::List => DEFAULT_LEAF_SIZE,
        }
    }
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions::with_leaf(LeafKind::Cluster)
    }
}

impl BuildOptions {
    /// The default options for leaves of kind `leaf`.
    pub fn with_leaf(leaf: LeafKind) -> BuildOptions {
        BuildOptions {
            max_depth: DEFAULT_MAX_DEPTH,
            leaf_size: leaf.default_leaf_size(),
            merge: true,
            leaf,
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

/// The header fields the builder knows (spec §2); the writer sets the rest
/// ([`crate::physical::writer::FileWriter::finish`]).
pub(crate) struct HeaderFields {
    pub root: ([f64; 3], f64),
    pub mesh: ([f32; 3], [f32; 3]),
    pub input_triangles: u64,
    pub stored_triangles: u64,
    pub empty_leaves: u64,
    pub solid_leaves: u64,
    pub level_count: u32,
}

impl HeaderFields {
    pub(crate) fn header(&self, opts: &BuildOptions) -> Header {
        Header {
            flags: if opts.merge { FLAG_MERGED } else { 0 }
                | if opts.leaf == LeafKind::Cluster {
                    FLAG_CLUSTERS
                } else {
                    0
                },
            root_min: self.root.0,
            root_size: self.root.1,
            mesh_min: self.mesh.0,
            mesh_max: self.mesh.1,
            input_triangles: self.input_triangles,
            stored_triangles: self.stored_triangles,
            empty_leaves: self.empty_leaves,
            solid_leaves: self.solid_leaves,
            level_count: self.level_count,
            max_depth: opts.max_depth,
            leaf_size: opts.leaf_size,
            ..Header::zeroed()
        }
    }
}

/// Builds the tree of `mesh` in memory. `progress` is told what phase is running.
pub fn build(
    mesh: &Mesh,
    opts: &BuildOptions,
    progress: &dyn Progress,
) -> Result<(TreeParts, BuildStats), Error> {
    build_within(mesh, opts, None, progress)
}

/// [`build`] with the root cube fitted to hold `room` too (`lo`, `hi`: where the triangles
/// may move later, [`PackOptions::bounds`]).
pub fn build_within(
    mesh: &Mesh,
    opts: &BuildOptions,
    room: Option<([f32; 3], [f32; 3])>,
    progress: &dyn Progress,
) -> Result<(TreeParts, BuildStats), Error> {
    opts.validate()?;
    let t0 = Instant::now();
    progress.phase("preparing triangles", None, false);
    let p = prepare::prepare_within(mesh, room)?;

    progress.phase("subdividing", None, false);
    let params = SubdivideParams {
        max_depth: opts.max_depth,
        leaf_size: opts.leaf_size,
    };
    let levels = subdivide::subdivide(&p.lattice, params, &|level, _| progress.at(level as u64));
    let build_seconds = t0.elapsed().as_secs_f64();

    progress.phase("merging empty volumes", None, false);
    let t1 = Instant::now();
    let boxes = merge::merge_volumes(&levels, opts.merge);
    let merge_seconds = t1.elapsed().as_secs_f64();

    progress.phase("laying out", None, false);
    let t2 = Instant::now();
    let laid = layout::layout(&levels, &boxes, &p.records, &p.lattice)?;
    let layout_seconds = t2.elapsed().as_secs_f64();

    let input = mesh.triangles.len() as u64;
    let stored = p.records.len() as u64;
    let mut counts = TreeCounts::default();
    counts.add(laid.tree.as_ref(), 0, laid.empty_leaves, laid.solid_leaves);
    let header = HeaderFields {
        root: (p.root_min, p.root_size),
        mesh: (p.mesh_min, p.mesh_max),
        input_triangles: input,
        stored_triangles: laid.tree.triangles.len() as u64,
        empty_leaves: laid.empty_leaves,
        solid_leaves: laid.solid_leaves,
        level_count: laid.tree.levels.len() as u32,
    }
    .header(opts);
    let stats = BuildStats::new(
        &counts,
        input,
        stored,
        PhaseSeconds {
            build: build_seconds,
            merge: merge_seconds,
            layout: layout_seconds,
        },
    );
    Ok((
        TreeParts {
            header,
            tree: laid.tree,
        },
        stats,
    ))
}
