//! Packing: a mesh file in, an `.oavm` file out, built in memory or, within a memory budget,
//! streamed ([`super::streaming`]). What `oavm-pack` runs.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::{BuildOptions, BuildStats, Progress, streaming, write};
use crate::error::Error;
use crate::mesh::Mesh;
use crate::output::Output;
use crate::physical::writer::BlockOptions;

/// How to pack.
#[derive(Clone, Copy, Debug, Default)]
pub struct PackOptions {
    pub build: BuildOptions,
    pub blocks: BlockOptions,
    /// Pose an animated (BART AFF) scene at this time; an error for other formats.
    pub time: Option<f64>,
    /// Pack within about this many bytes of memory, streaming the mesh (binary PLY only):
    /// for meshes larger than memory. `None`: read and build the whole mesh in memory, unless
    /// it is a binary PLY whose triangles would take more than the memory available to build
    /// ([`IN_MEMORY_BYTES_PER_TRIANGLE`] each): then streaming within half of it
    /// ([`streaming_budget`]).
    pub mem_budget: Option<u64>,
    /// Add ropes (format-spec §8.4) once the file is written ([`super::ropes::add_ropes`]).
    pub ropes: bool,
    /// Add occluders (format-spec §8.5) once the file is written, chosen with the default
    /// [`super::occluders::ShadowParams`] ([`super::occluders::add_occluders`]).
    pub occluders: bool,
    /// Store the primitive table (format-spec §8.6: every input triangle's corners by
    /// primitive id, 36 bytes each), which `oavm-update` needs to find what changed.
    pub updatable: bool,
    /// Fit the root cube to hold this box (`lo`, `hi`, world units) as well as the mesh: room
    /// for later updates to move triangles into (an update refuses geometry outside the root
    /// cube).
    pub bounds: Option<([f32; 3], [f32; 3])>,
}

impl PackOptions {
    /// Whether the build and block options are valid (the error says which is not).
    pub fn validate(&self) -> Result<(), Error> {
        self.build.validate()?;
        self.blocks.validate()?;
        if self.updatable && (self.ropes || self.occluders) {
            return Err(Error::Invalid(
                "--updatable with --ropes or --occluders: an update would have to rewrite every \
                 block's ropes and occluders (ropes name top-tree nodes by index); pack an \
                 updatable file without them"
                    .into(),
            ));
        }
        if let Some((lo, hi)) = self.bounds
            && !(0..3).all(|k| lo[k].is_finite() && hi[k].is_finite() && lo[k] <= hi[k])
        {
            return Err(Error::Invalid(format!(
                "--bounds {lo:?}..{hi:?}: corners must be finite, the first below the second"
            )));
        }
        Ok(())
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
    /// What adding ropes did (`--ropes`); `file_bytes` counts them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ropes: Option<super::ropes::RopeReport>,
    /// What adding occluders did (`--occluders`); `file_bytes` counts them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occluders: Option<super::occluders::OccluderReport>,
    pub total_seconds: f64,
    /// The process's peak resident set size when the file was written (`VmHWM`; what the
    /// memory budget of the streaming pack bounds), where the system says.
    pub peak_rss_bytes: Option<u64>,
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

/// Reads the mesh at `mesh_path`, builds its tree and writes it to `out` atomically (see
/// [`crate::output`]): the output path is checked before any work (it may not be the mesh), and
/// on any error nothing is left at `out`.
pub fn pack(
    mesh_path: &Path,
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    let t0 = Instant::now();
    let report = pack_without_ropes(mesh_path, out, opts, progress)?;
    with_ropes(report, out, opts, progress, t0)
}

/// Packs several mesh files into one `.oavm` file, each a geometry of its geometry table
/// (format-spec §8.8) named by its file name; one file is [`pack`]. Each is read whole into
/// memory (a memory budget, which streams one binary PLY, is refused).
pub fn pack_files(
    mesh_paths: &[&Path],
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    let [one] = mesh_paths else {
        return pack_joined(mesh_paths, out, opts, progress);
    };
    pack(one, out, opts, progress)
}

fn pack_joined(
    mesh_paths: &[&Path],
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    opts.validate()?;
    if mesh_paths.is_empty() {
        return Err(Error::Invalid("no mesh to pack".into()));
    }
    if opts.mem_budget.is_some() {
        return Err(Error::Invalid(
            "--mem-budget streams one binary PLY; several meshes are read and joined in memory"
                .into(),
        ));
    }
    let output = Output::create(out, mesh_paths)?;
    let t0 = Instant::now();
    progress.phase("parsing the meshes", None, false);
    let limits = crate::mesh::LoadLimits {
        max_file_bytes: crate::os::available_memory()
            .unwrap_or(crate::mesh::LoadLimits::DEFAULT_MAX_FILE_BYTES),
    };
    let mut parts = Vec::with_capacity(mesh_paths.len());
    let mut bytes = 0u64;
    for path in mesh_paths {
        bytes += std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        parts.push((name, crate::mesh::load_with(path, opts.time, &limits)?));
    }
    let mesh = Mesh::join(parts).map_err(Error::Invalid)?;
    let source = MeshSource {
        name: mesh_paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(" + "),
        bytes,
        parse_seconds: t0.elapsed().as_secs_f64(),
    };
    let report = pack_built(mesh, source, output, out, opts, progress, t0)?;
    with_ropes(report, out, opts, progress, t0)
}

/// Adds occluders, then ropes, to the file just packed at `out` if `opts` ask for them. The
/// file without them is complete and in place; each pass replaces it atomically (a crash in
/// between leaves a valid file, without what the pass adds).
fn with_ropes(
    mut report: PackReport,
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
    t0: Instant,
) -> Result<PackReport, Error> {
    if opts.occluders {
        progress.phase("adding occluders", None, false);
        let r = super::occluders::add_occluders_file(
            out,
            out,
            &super::occluders::ShadowParams::default(),
        )?;
        report.file_bytes = r.bytes_after;
        report.bytes_per_triangle =
            r.bytes_after as f64 / report.stats.input_triangles.max(1) as f64;
        report.occluders = Some(r);
        report.total_seconds = t0.elapsed().as_secs_f64();
        report.peak_rss_bytes = crate::os::peak_rss_bytes();
    }
    if opts.ropes {
        progress.phase("adding ropes", None, false);
        let r = super::ropes::add_ropes_file(out, out)?;
        report.file_bytes = r.bytes_after;
        report.bytes_per_triangle =
            r.bytes_after as f64 / report.stats.input_triangles.max(1) as f64;
        report.ropes = Some(r);
        report.total_seconds = t0.elapsed().as_secs_f64();
        report.peak_rss_bytes = crate::os::peak_rss_bytes();
    }
    Ok(report)
}

fn pack_without_ropes(
    mesh_path: &Path,
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    opts.validate()?;
    if opts.mem_budget.is_some() && opts.time.is_some() {
        return Err(Error::Invalid(
            "--time poses an .aff scene, which --mem-budget cannot stream (binary PLY only)".into(),
        ));
    }
    let output = Output::create(out, &[mesh_path])?;
    // Without a budget, a binary PLY too large to build in memory is packed streaming, within
    // half of the memory available, rather than run out of it.
    let budget = match (opts.mem_budget, opts.time) {
        (Some(b), _) => Some(b),
        (None, None) => crate::mesh::stream::PlyStream::open(mesh_path)
            .ok()
            .and_then(|ply| streaming_budget(ply.face_count(), crate::os::available_memory()?)),
        (None, Some(_)) => None,
    };
    if let Some(budget) = budget {
        return streaming::pack_streaming(mesh_path, output, opts, budget, progress);
    }
    let t0 = Instant::now();
    progress.phase("parsing the mesh", None, false);
    let mesh_bytes = std::fs::metadata(mesh_path).map(|m| m.len()).unwrap_or(0);
    // The in-memory build holds the file and many times its triangles: a file larger than the
    // memory available is for the streaming pack, which the error suggests.
    let limits = crate::mesh::LoadLimits {
        max_file_bytes: crate::os::available_memory()
            .unwrap_or(crate::mesh::LoadLimits::DEFAULT_MAX_FILE_BYTES),
    };
    let mesh = crate::mesh::load_with(mesh_path, opts.time, &limits)?;
    let parse_seconds = t0.elapsed().as_secs_f64();
    let source = MeshSource {
        name: mesh_path.display().to_string(),
        bytes: mesh_bytes,
        parse_seconds,
    };
    pack_built(mesh, source, output, out, opts, progress, t0)
}

/// Bytes a triangle takes in the in-memory build at its peak (measured with `oavm-pack`'s
/// peak RSS: 233 on 12 copies of the dragon, 10.5M triangles from a binary PLY; 239 on the
/// dragon), rounded up.
pub const IN_MEMORY_BYTES_PER_TRIANGLE: u64 = 256;

/// The budget to pack `faces` triangles streaming with when no budget is given: half of the
/// `available` memory, if building them in memory would take more than it; `None`: build in
/// memory.
pub fn streaming_budget(faces: u64, available: u64) -> Option<u64> {
    (faces.saturating_mul(IN_MEMORY_BYTES_PER_TRIANGLE) > available).then_some(available / 2)
}

/// Builds the tree of `mesh` (already in memory: arrays handed over by a program, such as the
/// Python bindings' `oavm.pack((vertices, faces), ...)`) and writes it to `out` atomically, as
/// [`pack`] does for a mesh file; `name` names the mesh in the report. The mesh is untrusted:
/// an index out of range or a non-finite corner is an error, as in a file. `opts.time` and
/// `opts.mem_budget` apply to mesh files only and are refused.
pub fn pack_mesh(
    mesh: Mesh,
    name: &str,
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
) -> Result<PackReport, Error> {
    opts.validate()?;
    if opts.time.is_some() {
        return Err(Error::Invalid(
            "a scene time poses an .aff scene file, not a mesh given as arrays".into(),
        ));
    }
    if opts.mem_budget.is_some() {
        return Err(Error::Invalid(
            "a memory budget streams a binary PLY file; a mesh given as arrays is already in \
             memory and is packed there"
                .into(),
        ));
    }
    let output = Output::create(out, &[])?;
    let source = MeshSource {
        name: name.to_string(),
        bytes: (mesh.positions.len() * 12 + mesh.triangles.len() * 12) as u64,
        parse_seconds: 0.0,
    };
    let t0 = Instant::now();
    let report = pack_built(mesh, source, output, out, opts, progress, t0)?;
    with_ropes(report, out, opts, progress, t0)
}

/// The mesh a pack read, for its report.
struct MeshSource {
    name: String,
    /// The file's bytes, or the arrays' (12 per vertex and per triangle).
    bytes: u64,
    parse_seconds: f64,
}

/// Builds `mesh` in memory and writes it to `output` (the in-memory half of [`pack`]).
fn pack_built(
    mut mesh: Mesh,
    source: MeshSource,
    output: Output,
    out: &Path,
    opts: &PackOptions,
    progress: &dyn Progress,
    t0: Instant,
) -> Result<PackReport, Error> {
    crate::mesh::check_geometries(&mesh.geometries, mesh.triangles.len() as u64)
        .map_err(|e| Error::Invalid(format!("{}: {e}", source.name)))?;
    let geometries = std::mem::take(&mut mesh.geometries);
    let (parts, stats) = super::build_within(&mesh, &opts.build, opts.bounds, progress)?;
    let prims = opts.updatable.then(|| super::prims::prim_records(&mesh));
    drop(mesh);

    progress.phase("writing", None, false);
    let t1 = Instant::now();
    let (file_bytes, block_count) =
        write::write_file(output, &parts, &opts.blocks, prims.as_deref(), geometries)?;
    drop(parts);
    let write_seconds = t1.elapsed().as_secs_f64();
    Ok(PackReport {
        mesh: source.name,
        time: opts.time,
        output: out.display().to_string(),
        options: opts.build,
        mesh_bytes: source.bytes,
        parse_seconds: source.parse_seconds,
        parse_mb_per_s: match source.parse_seconds {
            s if s > 0.0 => source.bytes as f64 / 1e6 / s,
            _ => 0.0,
        },
        bytes_per_triangle: file_bytes as f64 / stats.input_triangles.max(1) as f64,
        stats,
        write_seconds,
        file_bytes,
        blocks: opts.blocks,
        block_count,
        streaming: None,
        ropes: None,
        occluders: None,
        total_seconds: t0.elapsed().as_secs_f64(),
        peak_rss_bytes: crate::os::peak_rss_bytes(),
    })
}

#[cfg(test)]
mod budget_tests {
    use super::*;

    #[test]
    fn meshes_too_large_for_memory_stream_within_half_of_it() {
        let gib = 1u64 << 30;
        // 130M triangles (the out-of-core figures' mesh) with 23 GiB available: streamed.
        assert_eq!(streaming_budget(130_712_100, 23 * gib), Some(23 * gib / 2));
        // The dragon: in memory.
        assert_eq!(streaming_budget(871_414, 23 * gib), None);
        // At the edge: what fits is built in memory.
        let fits = 23 * gib / IN_MEMORY_BYTES_PER_TRIANGLE;
        assert_eq!(streaming_budget(fits, 23 * gib), None);
        assert!(streaming_budget(fits + 1, 23 * gib).is_some());
        // No overflow for absurd counts.
        assert_eq!(streaming_budget(u64::MAX, gib), Some(gib / 2));
    }
}
