//! Local updates of a file in place (the OAVM paper's §3, written as a new generation,
//! format-spec §2.1): triangles inserted, removed or moved, by primitive id, and only the
//! subtrees they touch rebuilt.
//!
//! **What is rebuilt.** A changed triangle is looked up where it was (the primitive table,
//! spec §8.6, holds its old corners) and where it goes, by a descent of the top tree through
//! every node whose widened cell it overlaps (the builder's exact test). It meets links (their
//! blocks are rebuilt) and, where it goes, empty leaves of the top tree (they become subtrees).
//! Each root of an affected block is built again from the triangles its block stores (minus
//! the changed ones) that overlap its cell, plus the changed triangles that now do; an empty
//! top-tree leaf from the changed triangles that reach it. Each such subtree is subdivided,
//! merged and split into blocks exactly as a pack does ([`super::subtree`]), so inside it the
//! paper's steps hold as they do in a fresh build: a solid node that turned empty merges with
//! its empty siblings, and upward through type-1 nodes to the first type-2 node; an empty node
//! that turned solid leaves its volume, whose siblings' volumes are recomputed. Above the
//! blocks, the top tree is resident and small: its empty leaves' volumes are merged again as a
//! whole, which carries the same steps across the top (a block root that turned empty is an
//! empty leaf of the top tree, merged with its siblings and upward). Every other block is left
//! where it is, byte for byte.
//!
//! **What is written.** A new generation: the new blocks (into the directory entries the
//! removed blocks freed, or appended to it) and the changed primitive chunks, appended after
//! everything the file holds; then the directory, the top tree and the primitive chunk
//! directory; synced; then the header in the other slot; synced ([`FileWriter::resume`]). A
//! crash before the header is durable leaves the previous generation the file's; nothing the
//! previous generation refers to is written over, so readers that opened it keep reading it.
//!
//! **Where the answers come from.** A ray's answer depends only on the triangles: the tree
//! only decides which are tested. A fresh pack of the same triangles answers the same, bit for
//! bit (the tests hold this).

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use bytemuck::Zeroable;
use rayon::prelude::*;
use serde::Serialize;

use super::blocks::{BlockParts, TopKind, TopNode, assemble_top};
use super::merge::{self, Merged};
use super::subdivide::{
    BuildLevel, BuildNode, Lattice, LatticeTri, box_misses, overlaps_cell, widened_cell,
};
use super::subtree::{Subtree, build_subtrees};
use super::{BuildOptions, LeafKind};
use crate::error::Error;
use crate::geom::triangle::is_degenerate;
use crate::mapping::ClusterGeometry;
use crate::mapping::{LevelInfos, TreeMap};
use crate::mesh::Mesh;
use crate::os::MappedFile;
use crate::physical::format::*;
use crate::physical::writer::{
    BlockOptions, DEFAULT_ZSTD_LEVEL, FileSink, FileWriter, StoredBlock, UnitRef, store_block,
};
use crate::physical::{BlockReader, BlockView, OavmFile};

/// How an update stores the blocks it makes.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct UpdateOptions {
    /// Target raw size of a new block (as `oavm-pack --block-size`).
    pub block_size: u64,
    /// zstd level of new blocks; `None`: [`DEFAULT_ZSTD_LEVEL`] if the file has compressed
    /// blocks, else raw.
    pub compress: Option<Option<i32>>,
}

impl UpdateOptions {
    /// Whether the options are valid (the error says which is not).
    pub fn validate(&self) -> Result<(), Error> {
        BlockOptions {
            block_size: self.block_size,
            compress: self.compress.flatten(),
            ..BlockOptions::default()
        }
        .validate()
    }
}

impl Default for UpdateOptions {
    fn default() -> Self {
        UpdateOptions {
            block_size: crate::physical::DEFAULT_BLOCK_SIZE,
            compress: None,
        }
    }
}

/// What an update did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct UpdateReport {
    pub file: String,
    /// The generation written, and the one before it.
    pub generation: u64,
    pub previous_generation: u64,
    /// Primitives inserted, removed and moved (a primitive that stays degenerate is not
    /// counted).
    pub inserted: u64,
    pub removed: u64,
    pub moved: u64,
    /// Blocks the changes reached (rebuilt and freed), of the blocks the file had.
    pub blocks_rebuilt: u64,
    pub blocks_before: u64,
    /// Blocks written, and the file's blocks after.
    pub blocks_written: u64,
    pub blocks_after: u64,
    /// Subtrees rebuilt: roots of the rebuilt blocks, and empty top-tree leaves that became
    /// solid.
    pub subtrees_rebuilt: u64,
    pub empty_leaves_filled: u64,
    /// Leaves and volumes of the rebuilt subtrees, before and after.
    pub leaves_before: u64,
    pub leaves_after: u64,
    pub volumes_after: u64,
    /// Top-tree empty leaves, before and after (their volumes are all merged again).
    pub top_empty_before: u64,
    pub top_empty_after: u64,
    /// Primitive chunks written again.
    pub prim_chunks_written: u64,
    /// Bytes appended to the file (blocks, primitive chunks, the new directory and top tree)
    /// and the header slot; the file's length after.
    pub bytes_written: u64,
    pub file_bytes: u64,
    /// Seconds: finding the changes, rebuilding, writing (syncs included), in all.
    pub diff_seconds: f64,
    pub build_seconds: f64,
    pub write_seconds: f64,
    pub total_seconds: f64,
}

/// An update of one file: open it, say what changes (by primitive id, or a whole new mesh),
/// then [`Updater::commit`]. The file is locked against other updaters from open to commit;
/// readers are not locked out (they read the generation they opened).
///
/// ```
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// use oavm::pack::update::{UpdateOptions, Updater};
/// use oavm::pack::{PackOptions, Quiet, pack};
/// use oavm::{Hit, Ray, Scene};
/// # let dir = tempfile::tempdir()?;
/// # let path = dir.path().join("bunny.oavm");
/// // The bunny, packed updatable, with room in front of it (z up to 1) for what comes.
/// let room = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]);
/// let opts = PackOptions { updatable: true, bounds: Some(room), ..Default::default() };
/// pack("data/bunny.ply".as_ref(), &path, &opts, &Quiet)?;
/// let ray = Ray::new([-0.02, 0.1, 10.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
/// let trace = |ray: &Ray| -> Result<Hit, oavm::Error> {
///     let mut hit = [Hit::MISS];
///     Scene::open(&path)?.intersect_batch(std::slice::from_ref(ray), &mut hit)?;
///     Ok(hit[0])
/// };
/// let before = trace(&ray)?;
/// assert!(before.is_hit());
///
/// // Remove the triangle the ray hit, and put a new one across the ray in front of the bunny.
/// let mut update = Updater::open(&path)?;
/// update.remove(before.prim)?;
/// let wall = update.insert([[-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.0, 0.5, 0.5]])?;
/// let report = update.commit(&UpdateOptions::default())?;
/// assert_eq!((report.removed, report.inserted), (1, 1));
///
/// // A new generation of the file answers with the new triangle.
/// let after = trace(&ray)?;
/// assert_eq!((after.prim, after.t), (wall, 9.5));
/// # Ok(()) }
/// ```
pub struct Updater {
    path: PathBuf,
    /// The file, open for writing and locked.
    handle: std::fs::File,
    file: OavmFile<MappedFile>,
    /// Changed primitives: their new records ([`PrimRecord::ABSENT`]: removed).
    edits: BTreeMap<u32, PrimRecord>,
    /// Primitives after the update (`input_triangles`).
    count: u64,
    /// The geometry table after the update (format-spec §8.8; empty: none).
    geometries: Vec<crate::mesh::Geometry>,
    diff_seconds: f64,
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{}: {what}", path.display()))
}

impl Updater {
    /// Opens the file at `path` for an update: it must hold the primitive table (packed with
    /// `--updatable`) and no ropes or occluders.
    pub fn open(path: &Path) -> Result<Updater, Error> {
        let handle = lock(path)?;
        let map = MappedFile::open(path).map_err(|e| Error::io(path, e))?;
        let file = OavmFile::open(map).map_err(|e| Error::format(path, e))?;
        let h = file.header();
        if h.flags & FLAG_PRIMS == 0 {
            return Err(invalid(
                path,
                "the file has no primitive table (format-spec §8.6), which an update needs to \
                 find what changed: pack it with `oavm-pack --updatable`",
            ));
        }
        if h.flags & (FLAG_ROPES | FLAG_OCCLUDERS) != 0 {
            return Err(invalid(
                path,
                "the file has ropes or occluders, which an update does not rebuild: pack it \
                 without them",
            ));
        }
        let count = h.input_triangles;
        let geometries =
            crate::physical::read_geometries(&file).map_err(|e| Error::format(path, e))?;
        Ok(Updater {
            path: path.to_owned(),
            handle,
            file,
            edits: BTreeMap::new(),
            count,
            geometries,
            diff_seconds: 0.0,
        })
    }

    /// The generation open.
    pub fn generation(&self) -> u64 {
        self.file.header().generation
    }

    /// Primitives the file will have (`input_triangles` after the update).
    pub fn primitive_count(&self) -> u64 {
        self.count
    }

    /// The geometry table the file will have (format-spec §8.8; empty: none).
    pub fn geometries(&self) -> &[crate::mesh::Geometry] {
        &self.geometries
    }

    /// Replaces the geometry table (empty: the file will have none); [`Self::commit`] checks
    /// that it covers the primitives the file will have.
    pub fn set_geometries(&mut self, geometries: Vec<crate::mesh::Geometry>) {
        self.geometries = geometries;
    }

    /// The geometry table with its last geometry ending where `count` primitives do (after
    /// inserts, or a new mesh of another size given without geometries); an error if that
    /// geometry starts past them.
    fn stretched_geometries(&self, count: u64) -> Result<Vec<crate::mesh::Geometry>, Error> {
        let mut geometries = self.geometries.clone();
        if let Some(last) = geometries.last_mut() {
            if count < last.first_primitive {
                return Err(invalid(
                    &self.path,
                    format!(
                        "the file's geometry table places its last geometry ({:?}) at \
                         primitive {}, past the new mesh's {count} primitives: give the new \
                         mesh's geometries",
                        last.name, last.first_primitive
                    ),
                ));
            }
            last.primitive_count = count - last.first_primitive;
        }
        Ok(geometries)
    }

    /// The stored record of primitive `prim` in the open generation (`None` past the table,
    /// or where its chunk is damaged).
    fn stored(&self, prim: u64) -> Option<PrimRecord> {
        if prim >= self.file.header().input_triangles {
            return None;
        }
        let chunks: &[PrimChunk] = self.file.records(SectionKind::Prims);
        let ch = chunks.get((prim / PRIM_CHUNK) as usize)?;
        let at =
            ch.offset as usize + (prim % PRIM_CHUNK) as usize * std::mem::size_of::<PrimRecord>();
        let bytes = self
            .file
            .bytes()
            .get(at..at + std::mem::size_of::<PrimRecord>())?;
        Some(bytemuck::pod_read_unaligned(bytes))
    }

    /// Primitive `prim`'s corners as they will be (the edits over the open generation); `None`
    /// where it holds no triangle.
    pub fn triangle(&self, prim: u32) -> Option<[[f32; 3]; 3]> {
        if prim as u64 >= self.count {
            return None;
        }
        let r = match self.edits.get(&prim) {
            Some(r) => *r,
            None => self.stored(prim as u64)?,
        };
        (!r.is_absent()).then_some(r.v)
    }

    fn check_prim(&self, prim: u32) -> Result<(), Error> {
        if prim as u64 >= self.count {
            return Err(invalid(
                &self.path,
                format!("primitive {prim} is past the {} primitives", self.count),
            ));
        }
        Ok(())
    }

    fn check_corners(&self, prim: u32, v: &[[f32; 3]; 3]) -> Result<(), Error> {
        if v.iter().flatten().any(|c| !c.is_finite()) {
            return Err(invalid(
                &self.path,
                format!("primitive {prim}: a corner is not finite"),
            ));
        }
        Ok(())
    }

    /// Sets primitive `prim` to the triangle `v` (moved, or inserted where it held none).
    pub fn set(&mut self, prim: u32, v: [[f32; 3]; 3]) -> Result<(), Error> {
        self.check_prim(prim)?;
        self.check_corners(prim, &v)?;
        self.edits.insert(prim, PrimRecord { v });
        Ok(())
    }

    /// Removes primitive `prim`'s triangle (its id stays, holding none).
    pub fn remove(&mut self, prim: u32) -> Result<(), Error> {
        self.check_prim(prim)?;
        self.edits.insert(prim, PrimRecord::ABSENT);
        Ok(())
    }

    /// Appends a triangle with the next primitive id, which it returns; in a file with a
    /// geometry table, it joins the last geometry.
    pub fn insert(&mut self, v: [[f32; 3]; 3]) -> Result<u32, Error> {
        let prim = u32::try_from(self.count)
            .map_err(|_| invalid(&self.path, "primitive ids are 32-bit"))?;
        self.check_corners(prim, &v)?;
        self.geometries = self.stretched_geometries(self.count + 1)?;
        self.count += 1;
        self.set(prim, v)?;
        Ok(prim)
    }

    /// Applies `m` to the corners of every triangle of `prims` (an object that moved).
    pub fn transform(
        &mut self,
        prims: std::ops::Range<u32>,
        m: &glam::DAffine3,
    ) -> Result<(), Error> {
        for prim in prims {
            if let Some(v) = self.triangle(prim) {
                let t = v.map(|p| {
                    let q =
                        m.transform_point3(glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                    [q.x as f32, q.y as f32, q.z as f32]
                });
                self.set(prim, t)?;
            }
        }
        Ok(())
    }

    /// Makes the file's triangles those of `mesh` (same primitive-id space: triangle `i` of the
    /// mesh is primitive `i`; primitives past its end are removed, new ones inserted), and its
    /// geometry table the mesh's geometries; a mesh without any keeps the file's table, its
    /// last geometry stretched or shrunk to the new count. Returns how many primitives differ
    /// from the open generation.
    pub fn set_mesh(&mut self, mesh: &Mesh) -> Result<u64, Error> {
        let t0 = Instant::now();
        let n = mesh.triangles.len() as u64;
        if n > u32::MAX as u64 {
            return Err(invalid(&self.path, "primitive ids are 32-bit"));
        }
        // Untrusted: every index in range, every corner finite, before anything is read.
        let nv = mesh.positions.len() as u64;
        if let Some((i, t)) = mesh
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&v| v as u64 >= nv))
        {
            return Err(invalid(
                &self.path,
                format!(
                    "the new mesh's triangle {i} holds vertex index {t:?}, past its {nv} vertices"
                ),
            ));
        }
        if let Some(i) = mesh
            .positions
            .iter()
            .position(|p| p.iter().any(|c| !c.is_finite()))
        {
            return Err(invalid(
                &self.path,
                format!("the new mesh's vertex {i} is not finite"),
            ));
        }
        crate::mesh::check_geometries(&mesh.geometries, n)
            .map_err(|e| invalid(&self.path, format!("the new mesh: {e}")))?;
        self.geometries = match mesh.geometries.is_empty() {
            true => self.stretched_geometries(n)?,
            false => mesh.geometries.clone(),
        };
        self.edits.clear();
        let old = self.file.header().input_triangles;
        self.count = n;
        let changed: Vec<(u32, PrimRecord)> = (0..n.max(old))
            .into_par_iter()
            .filter_map(|p| {
                let new = if p < n {
                    PrimRecord {
                        v: mesh.triangle(p as usize),
                    }
                } else {
                    PrimRecord::ABSENT
                };
                let same = self.stored(p).is_some_and(|s| s.same_bits(&new));
                (!same && p < n).then_some((p as u32, new))
            })
            .collect();
        // Built from the sorted list in one go (full nodes): inserted one by one, in
        // ascending order, a B-tree's nodes stay half full, which doubles what a scene where
        // everything moves holds (80 million records on Rain at 10^7 balls).
        self.edits = changed.into_iter().collect();
        self.diff_seconds += t0.elapsed().as_secs_f64();
        Ok(self.edits.len() as u64 + old.saturating_sub(n))
    }

    /// Writes the new generation (see the module's documentation).
    pub fn commit(self, opts: &UpdateOptions) -> Result<UpdateReport, Error> {
        commit(self, opts)
    }
}

/// What a run of changes reaches: the links their old triangles overlap (each once), and each
/// new triangle, by its index in the change list, with every node it overlaps: (node, change)
/// pairs of 8 bytes, not the triangle itself, since on Rain at 10^7 balls every one of 80
/// million triangles moves.
type Reached = (Vec<u32>, Vec<(u32, u32)>);

/// A changed primitive: before and after ([`PrimRecord::ABSENT`]: none).
#[derive(Clone, Copy)]
struct Change {
    prim: u32,
    old: PrimRecord,
    new: PrimRecord,
}

fn holds_triangle(r: &PrimRecord) -> bool {
    !r.is_absent() && !is_degenerate(&r.v)
}

/// The top tree of the open generation, as nodes at their places.
struct Top {
    nodes: Vec<TopNode>,
    /// (level, code) -> index in `nodes`.
    at: HashMap<(u32, u64), usize>,
    /// An internal node's first child's index in `nodes` (its eight children follow it), as
    /// read: `descend`'s walk, which runs once or twice per changed triangle, needs no hash
    /// lookups (on Rain, every ball moving, they were most of the update's time).
    first_child: Vec<u32>,
    /// Each node's cell widened by the cell margin (spec §6), low and high corners in lattice
    /// units, as read: `descend` rejects a child whose cell the triangle's box misses with six
    /// comparisons, before the exact triangle-box test.
    cells: Vec<([f64; 3], [f64; 3])>,
    /// Each link's (level, code), by (block, root).
    roots: HashMap<(u32, u32), (u32, u64)>,
    /// Each link's bounds, by (block, root).
    bounds: HashMap<(u32, u32), LinkBounds>,
}

fn read_top(file: &OavmFile<MappedFile>, path: &Path) -> Result<Top, Error> {
    let levels = file.levels();
    let infos = LevelInfos::new(levels, 0);
    let records: &[NodeRecord] = file.records(SectionKind::Nodes);
    let map = TreeMap::new(&infos, levels, records, file.records(SectionKind::Ranks));
    let volumes: &[VolumeRecord] = file.records(SectionKind::Volumes);
    let link_bounds: &[LinkBounds] = file.records(SectionKind::LinkBounds);
    let mut top = Top {
        nodes: Vec::new(),
        at: HashMap::new(),
        first_child: Vec::new(),
        cells: Vec::new(),
        roots: HashMap::new(),
        bounds: HashMap::new(),
    };
    let mut codes = vec![0u64];
    for (l, e) in levels.iter().enumerate() {
        let mut next = Vec::with_capacity(e.internal_count as usize * 8);
        // Nodes go in level by level, each level in Morton order: the next level starts after
        // this one, and an internal node's children are the next eight codes of it.
        let next_start = top.nodes.len() + codes.len();
        for (i, &code) in codes.iter().enumerate() {
            let mut first_child = u32::MAX;
            let rec = map
                .node(l as u32, i as u64)
                .map_err(|e| invalid(path, format!("top tree: {e}")))?;
            let kind = match rec.kind() {
                Some(NodeKind::Internal) => {
                    first_child = u32::try_from(next_start + next.len())
                        .map_err(|_| invalid(path, "top tree: too many nodes"))?;
                    next.extend((0..8).map(|o| code << 3 | o));
                    TopKind::Internal
                }
                Some(NodeKind::Empty { volume, shape }) => TopKind::Empty {
                    volume: *volumes.get(volume as usize).ok_or_else(|| {
                        invalid(path, format!("top tree: volume {volume} is out of range"))
                    })?,
                    shape,
                },
                Some(NodeKind::Link { block, root }) => {
                    top.roots.insert((block, root), (l as u32, code));
                    let index = e.node_start as usize + i;
                    top.bounds.insert(
                        (block, root),
                        link_bounds.get(index).copied().unwrap_or_default(),
                    );
                    TopKind::Link { block, root }
                }
                _ => return Err(invalid(path, format!("top tree: bad node at level {l}"))),
            };
            top.at.insert((l as u32, code), top.nodes.len());
            top.first_child.push(first_child);
            top.cells.push(widened_cell(code, l as u32));
            top.nodes.push(TopNode {
                level: l as u32,
                code,
                kind,
            });
        }
        codes = next;
    }
    Ok(top)
}

/// Where a triangle reaches the top tree: the blocks it overlaps, and the links and empty
/// leaves (by node index) it overlaps.
fn descend(top: &Top, t: &LatticeTri, stack: &mut Vec<usize>, out: &mut Vec<usize>) {
    stack.clear();
    if !top.nodes.is_empty() {
        stack.push(0);
    }
    while let Some(i) = stack.pop() {
        let node = &top.nodes[i];
        if node.level > 0
            && (box_misses(t, &top.cells[i]) || !overlaps_cell(t, node.code, node.level))
        {
            continue;
        }
        match node.kind {
            TopKind::Internal => {
                let first = top.first_child[i] as usize;
                stack.extend(first..(first + 8).min(top.nodes.len()));
            }
            _ => out.push(i),
        }
    }
}

/// Subtrees to build together: the block they were in (whose triangles but the changed ones
/// they take), their roots (one level, Morton order), and the changed triangles that reach
/// them.
struct Job {
    block: Option<u32>,
    level: u32,
    codes: Vec<u64>,
    /// The top-tree nodes replaced (the roots, or the empty leaf), whose changed triangles
    /// the job takes.
    nodes: Vec<usize>,
}

/// Empty and solid leaves: of the blocks an update removes, or of those it writes.
#[derive(Clone, Copy, Default)]
struct Leaves {
    empty: u64,
    solid: u64,
}

impl Leaves {
    /// The leaves among `nodes`.
    fn of(nodes: &[NodeRecord]) -> Leaves {
        let mut n = Leaves::default();
        for r in nodes {
            match r.kind_bits() {
                KIND_EMPTY => n.empty += 1,
                KIND_SOLID => n.solid += 1,
                _ => {}
            }
        }
        n
    }

    fn add(&mut self, other: Leaves) {
        self.empty += other.empty;
        self.solid += other.solid;
    }
}

/// The distinct triangles a decoded block stores, and its leaf counts.
fn block_triangles(view: &BlockView<'_>) -> (Vec<TriRecord>, Leaves) {
    let mut seen = HashSet::new();
    let mut out = Vec::new();
    for t in view.triangles {
        if seen.insert(t.prim) {
            out.push(*t);
        }
    }
    for g in view.groups {
        for l in 0..(g.count as usize).min(GROUP_LANES) {
            if seen.insert(g.prim[l]) {
                out.push(TriRecord {
                    v: g.triangle(l),
                    prim: g.prim[l],
                });
            }
        }
    }
    (out, Leaves::of(view.nodes))
}

fn commit(mut u: Updater, opts: &UpdateOptions) -> Result<UpdateReport, Error> {
    let t0 = Instant::now();
    let path = u.path.clone();
    let header = *u.file.header();
    let mut report = UpdateReport {
        file: path.display().to_string(),
        previous_generation: header.generation,
        generation: header.generation + 1,
        blocks_before: header.block_count,
        diff_seconds: u.diff_seconds,
        ..UpdateReport::default()
    };

    // 1. The changes, old and new, and where they may be. The edits are consumed: from here
    // on the changes (in increasing primitive order) are what says what a primitive becomes.
    crate::mesh::check_geometries(&u.geometries, u.count)
        .map_err(|e| invalid(&path, format!("the geometry table: {e}")))?;
    let changes = take_changes(&mut u);
    let lattice = Lattice::of_root(header.root_min, header.root_size);
    check_changes(&changes, &lattice, &header, &path, &mut report)?;
    let file = &u.file;
    let top = read_top(file, &path)?;
    let changed = ChangedSet::new(&changes, header.input_triangles.max(u.count));

    // 2. Where the changes reach: blocks to rebuild, empty leaves to fill.
    let reach = reach_changes(&top, &lattice, &changes, &path)?;
    report.diff_seconds += t0.elapsed().as_secs_f64();

    // 3. The subtrees to build: the roots of every reached block together, every empty leaf
    // reached alone.
    let t1 = Instant::now();
    let directory = file.directory();
    let (jobs, replaced) = plan_jobs(&top, directory, &reach, &path, &mut report)?;
    let build = build_options(&header);
    let src = Sources {
        file,
        reader: BlockReader::new(file),
        path: &path,
        changes: &changes,
        changed: &changed,
        reach: &reach,
        lattice,
        build,
        clusters: (build.leaf == LeafKind::Cluster).then_some(ClusterGeometry {
            root_min: header.root_min,
            root_size: header.root_size,
        }),
        block_opts: block_options(&header, opts),
    };

    // 4. The writer of the new generation: the directory with the reached blocks' entries
    // freed, appending after everything the file holds.
    let (mut w, start) = open_generation(&u, &top, &reach.blocks, report.generation)?;

    // 5. Build and write, a batch of jobs at a time.
    let mut built = Rebuilt::new(
        &top,
        &replaced,
        &reach.blocks,
        directory,
        header.level_count,
    );
    built.run(jobs, &src, &mut w, &mut report)?;
    report.leaves_before = built.removed.empty + built.removed.solid;
    report.leaves_after = built.added.empty + built.added.solid;

    // 6. The top tree's empty leaves merged again, as a whole.
    let mut top_nodes = std::mem::take(&mut built.top_nodes);
    report.top_empty_before = count_empty(&top.nodes);
    remerge_top(&mut top_nodes, build.merge);
    report.top_empty_after = count_empty(&top_nodes);
    let top_unit = assemble_top(top_nodes)?;
    report.build_seconds = t1.elapsed().as_secs_f64() - built.write_seconds;
    let t2 = Instant::now();

    // 7. The primitive chunks that changed, and the header's triangle counts and mesh bounds.
    let io = |e: std::io::Error| Error::io(&path, e);
    report.prim_chunks_written =
        write_prim_chunks(&u, &changes, header.input_triangles, &mut w).map_err(io)?;
    w.trim_free();
    report.blocks_after = w.block_count() as u64;
    let meta = header_after(&u, &header, &changes, &built, &report);
    w.set_geometries(u.geometries.clone());
    let (_, end) = w.finish(&meta, top_unit.as_ref()).map_err(io)?;
    report.write_seconds = built.write_seconds + t2.elapsed().as_secs_f64();
    report.file_bytes = std::fs::metadata(&path).map_err(io)?.len();
    report.bytes_written = end - start + (std::mem::size_of::<Header>() as u64);
    report.blocks_rebuilt = reach.blocks.len() as u64;
    report.total_seconds = report.diff_seconds + t0.elapsed().as_secs_f64();
    Ok(report)
}

/// Takes the updater's edits as changes, in increasing primitive order, each with the record
/// the open generation stores: the edits that change a record, then every primitive past the
/// new count, removed.
fn take_changes(u: &mut Updater) -> Vec<Change> {
    let old_count = u.file.header().input_triangles;
    let edits = std::mem::take(&mut u.edits);
    // Sized once: grown by doubling, the list of 80 million changes would reserve 10 GB.
    let mut changes: Vec<Change> =
        Vec::with_capacity(edits.len() + old_count.saturating_sub(u.count) as usize);
    changes.extend(
        edits
            .into_iter()
            .map(|(prim, new)| Change {
                prim,
                old: u.stored(prim as u64).unwrap_or(PrimRecord::ABSENT),
                new,
            })
            .filter(|c| !c.old.same_bits(&c.new)),
    );
    for prim in u.count..old_count {
        changes.push(Change {
            prim: prim as u32,
            old: u.stored(prim).unwrap_or(PrimRecord::ABSENT),
            new: PrimRecord::ABSENT,
        });
    }
    debug_assert!(changes.windows(2).all(|w| w[0].prim < w[1].prim));
    changes
}

/// Refuses a change that moves a triangle out of the file's root cube, and counts the
/// primitives inserted, removed and moved.
fn check_changes(
    changes: &[Change],
    lattice: &Lattice,
    header: &Header,
    path: &Path,
    report: &mut UpdateReport,
) -> Result<(), Error> {
    let top_size = LATTICE_SIZE as f64;
    for c in changes {
        if holds_triangle(&c.new) {
            let t = lattice.map(&c.new.v);
            if (0..3).any(|k| t.lo[k] <= 0.0 || t.hi[k] >= top_size) {
                return Err(invalid(
                    path,
                    format!(
                        "primitive {} moves to {:?}, outside the file's root cube (min {:?}, \
                         edge {}): pack the scene again over bounds that hold all its frames",
                        c.prim, c.new.v, header.root_min, header.root_size
                    ),
                ));
            }
        }
        match (holds_triangle(&c.old), holds_triangle(&c.new)) {
            (false, true) => report.inserted += 1,
            (true, false) => report.removed += 1,
            (true, true) => report.moved += 1,
            (false, false) => {}
        }
    }
    Ok(())
}

/// The changed primitives, as a bitset (a bit per primitive id: 16 MB for 128 million).
struct ChangedSet(Vec<u64>);

impl ChangedSet {
    /// The primitives of `changes`, of `prims` primitive ids.
    fn new(changes: &[Change], prims: u64) -> ChangedSet {
        let mut changed = vec![0u64; prims.div_ceil(64) as usize];
        for c in changes {
            changed[c.prim as usize / 64] |= 1 << (c.prim % 64);
        }
        ChangedSet(changed)
    }

    fn contains(&self, p: u32) -> bool {
        self.0
            .get(p as usize / 64)
            .is_some_and(|w| w >> (p % 64) & 1 != 0)
    }
}

/// Where the changes reach the top tree.
struct Reach {
    /// The blocks to rebuild (an old or a new triangle overlaps one of their roots), sorted.
    blocks: Vec<u32>,
    /// The empty top-tree leaves a new triangle reaches, in node order.
    filled: Vec<usize>,
    /// The new triangles by the link or empty leaf they reach: (node, change) pairs, sorted
    /// by node.
    pairs: Vec<(u32, u32)>,
}

impl Reach {
    /// The changed triangles that reach top-tree node `i`.
    fn reaching<'a>(
        &'a self,
        i: usize,
        changes: &'a [Change],
    ) -> impl Iterator<Item = TriRecord> + 'a {
        let lo = self.pairs.partition_point(|p| (p.0 as usize) < i);
        let hi = self.pairs.partition_point(|p| (p.0 as usize) <= i);
        self.pairs[lo..hi].iter().map(|&(_, c)| {
            let c = &changes[c as usize];
            TriRecord {
                v: c.new.v,
                prim: c.prim,
            }
        })
    }
}

/// Changes a run of [`reached_by`] takes (a task of the parallel descent).
const RUN: usize = 1024;

/// Where the changes reach: blocks to rebuild (old or new triangle overlaps a root), and the
/// new triangles by link or empty leaf, as (node, change) pairs sorted by node.
fn reach_changes(
    top: &Top,
    lattice: &Lattice,
    changes: &[Change],
    path: &Path,
) -> Result<Reach, Error> {
    if changes.len() > u32::MAX as usize || top.nodes.len() > u32::MAX as usize {
        return Err(invalid(
            path,
            "too many changes or top-tree nodes for one update",
        ));
    }
    let reached: Vec<Reached> = changes
        .par_chunks(RUN)
        .enumerate()
        .map(|(run, cs)| reached_by(top, lattice, cs, run * RUN))
        .collect();
    let mut blocks: HashSet<u32> = HashSet::new();
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(reached.iter().map(|r| r.1.len()).sum());
    for (links, news) in reached {
        for i in links {
            if let TopKind::Link { block, .. } = top.nodes[i as usize].kind {
                blocks.insert(block);
            }
        }
        pairs.extend(news);
    }
    pairs.par_sort_unstable();
    let mut filled: Vec<usize> = Vec::new();
    for w in pairs.chunk_by(|a, b| a.0 == b.0) {
        let i = w[0].0 as usize;
        match top.nodes[i].kind {
            TopKind::Link { block, .. } => {
                blocks.insert(block);
            }
            _ => filled.push(i),
        }
    }
    let mut blocks: Vec<u32> = blocks.into_iter().collect();
    blocks.sort_unstable();
    Ok(Reach {
        blocks,
        filled,
        pairs,
    })
}

/// What a run of changes reaches (see [`Reached`]); `first` is the index of its first change
/// in the change list.
fn reached_by(top: &Top, lattice: &Lattice, cs: &[Change], first: usize) -> Reached {
    let mut links = Vec::new();
    let mut news = Vec::new();
    let mut buf = Vec::new();
    let mut stack = Vec::new();
    for (k, c) in cs.iter().enumerate() {
        if holds_triangle(&c.old) {
            buf.clear();
            descend(top, &lattice.map(&c.old.v), &mut stack, &mut buf);
            links.extend(
                buf.iter()
                    .filter(|&&i| matches!(top.nodes[i].kind, TopKind::Link { .. }))
                    .map(|&i| i as u32),
            );
        }
        if holds_triangle(&c.new) {
            buf.clear();
            descend(top, &lattice.map(&c.new.v), &mut stack, &mut buf);
            let at = (first + k) as u32;
            news.extend(buf.iter().map(|&i| (i as u32, at)));
        }
    }
    links.sort_unstable();
    links.dedup();
    (links, news)
}

/// The subtrees to build, and the top-tree nodes they replace: the roots of every reached
/// block together, in block order; then every empty leaf reached alone, in node order (the
/// order of the sorted pairs), so that block ids are handed out the same way on every run.
fn plan_jobs(
    top: &Top,
    directory: &[BlockEntry],
    reach: &Reach,
    path: &Path,
    report: &mut UpdateReport,
) -> Result<(Vec<Job>, HashSet<usize>), Error> {
    let mut jobs: Vec<Job> = Vec::new();
    let mut replaced: HashSet<usize> = HashSet::new();
    for &b in &reach.blocks {
        let Some(job) = block_job(top, directory, b, path)? else {
            continue;
        };
        replaced.extend(&job.nodes);
        report.subtrees_rebuilt += job.codes.len() as u64;
        jobs.push(job);
    }
    for &i in &reach.filled {
        replaced.insert(i);
        let n = top.nodes[i];
        jobs.push(Job {
            block: None,
            level: n.level,
            codes: vec![n.code],
            nodes: vec![i],
        });
    }
    report.empty_leaves_filled = reach.filled.len() as u64;
    report.subtrees_rebuilt += reach.filled.len() as u64;
    Ok((jobs, replaced))
}

/// The job that rebuilds block `b`'s roots (one level, Morton order); `None` for a block with
/// no roots.
fn block_job(
    top: &Top,
    directory: &[BlockEntry],
    b: u32,
    path: &Path,
) -> Result<Option<Job>, Error> {
    let e = directory
        .get(b as usize)
        .ok_or_else(|| invalid(path, format!("a link to block {b}, past the directory")))?;
    let mut roots = Vec::with_capacity(e.root_count as usize);
    for root in 0..e.root_count {
        let &(level, code) = top
            .roots
            .get(&(b, root))
            .ok_or_else(|| invalid(path, format!("root {root} of block {b} is not linked")))?;
        roots.push((level, code));
    }
    roots.sort_unstable_by_key(|r| r.1);
    let Some(&(level, _)) = roots.first() else {
        return Ok(None);
    };
    if roots.iter().any(|r| r.0 != level) {
        return Err(invalid(
            path,
            format!("block {b}: roots at different levels"),
        ));
    }
    Ok(Some(Job {
        block: Some(b),
        level,
        codes: roots.iter().map(|r| r.1).collect(),
        nodes: roots.iter().map(|r| top.at[r]).collect(),
    }))
}

/// The build options the file was packed with, as its header records them.
fn build_options(header: &Header) -> BuildOptions {
    BuildOptions {
        max_depth: header.max_depth,
        leaf_size: header.leaf_size,
        merge: header.flags & FLAG_MERGED != 0,
        leaf: if header.flags & FLAG_CLUSTERS != 0 {
            LeafKind::Cluster
        } else {
            LeafKind::List
        },
    }
}

/// How the new blocks are stored: compressed as asked, or as the file's blocks are.
fn block_options(header: &Header, opts: &UpdateOptions) -> BlockOptions {
    let lean = header.flags & FLAG_LEAN != 0;
    let (compress, lean) = match opts.compress {
        Some(c) => (c, false),
        None if lean => (None, true),
        None => (
            (header.flags & FLAG_COMPRESSED != 0).then_some(DEFAULT_ZSTD_LEVEL),
            false,
        ),
    };
    BlockOptions {
        block_size: opts.block_size,
        compress,
        chunk_groups: file_chunk_groups(header),
        lean,
    }
}

/// Groups per chunk of the blocks an update writes: the file's (or the default, in a file
/// with no groups).
pub(super) fn file_chunk_groups(header: &Header) -> u32 {
    match header.chunk_groups {
        0 => crate::physical::writer::DEFAULT_CHUNK_GROUPS,
        n => n,
    }
}

/// The writer of the new generation, and the offset it starts at: the directory with the
/// reached blocks' entries freed (and their roots' bounds dropped), appending after
/// everything the file holds.
fn open_generation(
    u: &Updater,
    top: &Top,
    blocks: &[u32],
    generation: u64,
) -> Result<(FileWriter<FileSink>, u64), Error> {
    let path = &u.path;
    let mut dir: Vec<BlockEntry> = u.file.directory().to_vec();
    let mut bounds: Vec<Vec<LinkBounds>> = dir
        .iter()
        .enumerate()
        .map(|(b, e)| {
            (0..if e.is_free() { 0 } else { e.root_count })
                .map(|r| top.bounds.get(&(b as u32, r)).copied().unwrap_or_default())
                .collect()
        })
        .collect();
    // The wide nodes' boxes of the roots kept (spec §8.7), from the wide links.
    let links: std::collections::HashMap<(u32, u32), crate::physical::wide::WorldBox> = u
        .file
        .records::<crate::physical::format::WideLink>(SectionKind::WideLinks)
        .iter()
        .map(|w| ((w.block, w.root), (w.lo, w.hi)))
        .collect();
    let mut boxes: Vec<Vec<crate::physical::wide::WorldBox>> = dir
        .iter()
        .enumerate()
        .map(|(b, e)| {
            (0..if e.is_free() { 0 } else { e.root_count })
                // A root with no wide link (never written) gets a box no grid holds: the
                // top tree's wide nodes then fail to build, and the update with them.
                .map(|r| {
                    let none = ([f32::NAN; 3], [f32::NAN; 3]);
                    links.get(&(b as u32, r)).copied().unwrap_or(none)
                })
                .collect()
        })
        .collect();
    for &b in blocks {
        dir[b as usize] = BlockEntry::zeroed();
        bounds[b as usize].clear();
        boxes[b as usize].clear();
    }
    let start = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len()
        .next_multiple_of(RAW_BLOCK_ALIGN);
    let io = |e: std::io::Error| Error::io(path, e);
    let mut handle = u.handle.try_clone().map_err(io)?;
    {
        use std::io::Seek;
        handle.seek(std::io::SeekFrom::Start(start)).map_err(io)?;
    }
    let chunks: Vec<PrimChunk> = u.file.records::<PrimChunk>(SectionKind::Prims).to_vec();
    let w = FileWriter::resume(
        FileSink::new(handle),
        start,
        generation,
        u.file.header().chunk_groups,
        dir,
        bounds,
        boxes,
        Some(chunks),
    )
    .map_err(io)?;
    Ok((w, start))
}

/// What building the new subtrees reads: the open generation's blocks, the changes and where
/// they reach, and how the new blocks are built and stored.
struct Sources<'a> {
    file: &'a OavmFile<MappedFile>,
    reader: BlockReader,
    path: &'a Path,
    changes: &'a [Change],
    changed: &'a ChangedSet,
    reach: &'a Reach,
    lattice: Lattice,
    build: BuildOptions,
    clusters: Option<ClusterGeometry>,
    block_opts: BlockOptions,
}

/// Builds a job's subtrees over the changed triangles that now reach its nodes and, for a
/// reached block, the triangles it stores but the changed ones. Returns them with the
/// block's leaves (none for an empty leaf filled).
fn build_job(src: &Sources<'_>, j: &Job) -> Result<(Subtree, Leaves), Error> {
    let mut leaves = Leaves::default();
    let mut records: Vec<TriRecord> = j
        .nodes
        .iter()
        .flat_map(|&i| src.reach.reaching(i, src.changes))
        .collect();
    if let Some(b) = j.block {
        let e = &src.file.directory()[b as usize];
        let raw = src
            .reader
            .read(src.file.bytes(), b, e)
            .map_err(|err| invalid(src.path, err))?;
        let view = BlockView::parse(&raw, b, e)
            .map_err(|w| invalid(src.path, format!("block {b}: {w}")))?;
        let (tris, counts) = block_triangles(&view);
        leaves = counts;
        records.extend(tris.into_iter().filter(|t| !src.changed.contains(t.prim)));
    }
    records.sort_unstable_by_key(|r| r.prim);
    records.dedup_by_key(|r| r.prim);
    let s = build_subtrees(
        &records,
        j.level,
        &j.codes,
        &src.lattice,
        &src.build,
        src.block_opts.block_size,
        0,
        src.clusters.as_ref(),
    )?;
    Ok((s, leaves))
}

/// The new generation's blocks and top tree, as the batches of jobs are built and written.
struct Rebuilt {
    /// Ids for new blocks: the free entries, lowest first; then `next_id` on, at the
    /// directory's end.
    free: std::vec::IntoIter<u32>,
    next_id: u32,
    /// The top tree: the nodes no job replaced, and the new subtrees' top nodes.
    top_nodes: Vec<TopNode>,
    /// One past the deepest level.
    level_end: u32,
    /// Leaves of the blocks removed, and of those written.
    removed: Leaves,
    added: Leaves,
    write_seconds: f64,
}

impl Rebuilt {
    /// Starts from the open generation's top tree less the `replaced` nodes; new blocks take
    /// the ids of the reached `blocks` and of the directory's free entries first (lowest
    /// first), then new ones at the directory's end, in increasing order.
    fn new(
        top: &Top,
        replaced: &HashSet<usize>,
        blocks: &[u32],
        directory: &[BlockEntry],
        level_count: u32,
    ) -> Rebuilt {
        let mut free: Vec<u32> = blocks.to_vec();
        free.extend(
            directory
                .iter()
                .enumerate()
                .filter(|(_, e)| e.is_free())
                .map(|(b, _)| b as u32),
        );
        free.sort_unstable();
        free.dedup();
        Rebuilt {
            free: free.into_iter(),
            next_id: directory.len() as u32,
            top_nodes: top
                .nodes
                .iter()
                .enumerate()
                .filter(|(i, _)| !replaced.contains(i))
                .map(|(_, n)| *n)
                .collect(),
            level_end: level_count,
            removed: Leaves::default(),
            added: Leaves::default(),
            write_seconds: 0.0,
        }
    }

    /// Builds and writes the jobs, a batch at a time (what is held is one batch's triangles
    /// and blocks), the jobs of a batch in parallel.
    fn run(
        &mut self,
        mut jobs: Vec<Job>,
        src: &Sources<'_>,
        w: &mut FileWriter<FileSink>,
        report: &mut UpdateReport,
    ) -> Result<(), Error> {
        let batch_size = 4 * rayon::current_num_threads().max(1);
        while !jobs.is_empty() {
            let batch: Vec<Job> = jobs.drain(..batch_size.min(jobs.len())).collect();
            let built: Vec<(Subtree, Leaves)> = batch
                .into_par_iter()
                .map(|j| build_job(src, &j))
                .collect::<Result<_, Error>>()?;
            let new_blocks = self.take(built);
            for b in &new_blocks {
                self.added.add(Leaves::of(b.unit.as_ref().nodes));
                report.volumes_after += b.unit.volumes.len() as u64;
            }
            self.write(new_blocks, src, w, report)?;
        }
        Ok(())
    }

    /// Takes a batch's subtrees: their blocks get ids, their top nodes join the top tree
    /// (links to the new ids). Returns the blocks.
    fn take(&mut self, built: Vec<(Subtree, Leaves)>) -> Vec<BlockParts> {
        let mut new_blocks: Vec<BlockParts> = Vec::new();
        for (s, leaves) in built {
            self.removed.add(leaves);
            let ids: Vec<u32> = s
                .split
                .blocks
                .iter()
                .map(|_| {
                    self.free.next().unwrap_or_else(|| {
                        self.next_id += 1;
                        self.next_id - 1
                    })
                })
                .collect();
            for mut n in s.split.top {
                if let TopKind::Link { block, root } = n.kind {
                    n.kind = TopKind::Link {
                        block: ids[block as usize],
                        root,
                    };
                }
                self.top_nodes.push(n);
            }
            for (mut b, id) in s.split.blocks.into_iter().zip(ids) {
                b.id = id;
                new_blocks.push(b);
            }
            self.level_end = self.level_end.max(s.level_end);
        }
        new_blocks
    }

    /// Stores a batch's blocks (in parallel) and places them in the new generation.
    fn write(
        &mut self,
        mut new_blocks: Vec<BlockParts>,
        src: &Sources<'_>,
        w: &mut FileWriter<FileSink>,
        report: &mut UpdateReport,
    ) -> Result<(), Error> {
        let tw = Instant::now();
        // Ids past the directory's end are placed in order (a writer fills the directory in
        // order); they were handed out in increasing order.
        new_blocks.sort_unstable_by_key(|b| b.id);
        let stored: Vec<StoredBlock> = new_blocks
            .par_iter()
            .map(|b| store_block(b.unit.as_ref(), b.root_level, b.id, &src.block_opts))
            .collect::<Result<_, _>>()?;
        for s in stored {
            w.place(s).map_err(|e| Error::io(src.path, e))?;
        }
        report.blocks_written += new_blocks.len() as u64;
        self.write_seconds += tw.elapsed().as_secs_f64();
        Ok(())
    }
}

/// The empty leaves among top-tree nodes.
fn count_empty(nodes: &[TopNode]) -> u64 {
    nodes
        .iter()
        .filter(|n| matches!(n.kind, TopKind::Empty { .. }))
        .count() as u64
}

/// Writes the primitive chunks the changes touch (and the one the new count cuts short), and
/// drops those past the new count. Returns how many were written.
fn write_prim_chunks(
    u: &Updater,
    changes: &[Change],
    old_count: u64,
    w: &mut FileWriter<FileSink>,
) -> std::io::Result<u64> {
    let new_count = u.count;
    let mut touched: Vec<u64> = changes
        .iter()
        .filter(|c| (c.prim as u64) < new_count)
        .map(|c| c.prim as u64 / PRIM_CHUNK)
        .collect();
    if new_count < old_count && !new_count.is_multiple_of(PRIM_CHUNK) {
        touched.push(new_count / PRIM_CHUNK);
    }
    touched.sort_unstable();
    touched.dedup();
    for &c in &touched {
        let lo = c * PRIM_CHUNK;
        let hi = (lo + PRIM_CHUNK).min(new_count);
        let records = records_after(u, changes, lo..hi);
        w.write_prim_chunk(c as usize, &records)?;
    }
    w.truncate_prim_chunks(new_count.div_ceil(PRIM_CHUNK) as usize);
    Ok(touched.len() as u64)
}

/// The new generation's header: the previous one with the triangle counts, the mesh bounds,
/// the leaf counts (the top tree's empty leaves before and after are the report's) and the
/// levels after the update.
fn header_after(
    u: &Updater,
    header: &Header,
    changes: &[Change],
    built: &Rebuilt,
    report: &UpdateReport,
) -> Header {
    let mut stored_triangles = header.stored_triangles;
    for c in changes {
        stored_triangles -= u64::from(holds_triangle(&c.old));
        stored_triangles += u64::from(holds_triangle(&c.new));
    }
    let (mesh_min, mesh_max) = mesh_bounds(u, header, changes);
    // Leaves: the previous counts, less the removed blocks' and the top tree's empty leaves
    // before, plus the new blocks' and the top tree's after.
    Header {
        input_triangles: u.count,
        stored_triangles,
        mesh_min,
        mesh_max,
        empty_leaves: header.empty_leaves - built.removed.empty - report.top_empty_before
            + built.added.empty
            + report.top_empty_after,
        solid_leaves: header.solid_leaves - built.removed.solid + built.added.solid,
        level_count: built.level_end.min(MAX_LEVEL + 1),
        ..*header
    }
}

/// The records of primitives `prims` after the update: the changed ones' new records (found
/// once, then walked in step, `changes` being in increasing primitive order), the others' as
/// stored ([`PrimRecord::ABSENT`] where none is).
fn records_after(u: &Updater, changes: &[Change], prims: std::ops::Range<u64>) -> Vec<PrimRecord> {
    let mut next = changes.partition_point(|c| (c.prim as u64) < prims.start);
    prims
        .map(|p| match changes.get(next) {
            Some(c) if c.prim as u64 == p => {
                next += 1;
                c.new
            }
            _ => u.stored(p).unwrap_or(PrimRecord::ABSENT),
        })
        .collect()
}

/// The bounds of every stored triangle after the update: the previous bounds widened by the
/// new triangles when no triangle that left touched them, else a pass over the whole table.
fn mesh_bounds(u: &Updater, header: &Header, changes: &[Change]) -> ([f32; 3], [f32; 3]) {
    let inside = |v: &[[f32; 3]; 3]| {
        v.iter()
            .all(|p| (0..3).all(|k| p[k] > header.mesh_min[k] && p[k] < header.mesh_max[k]))
    };
    let grow = |(mut lo, mut hi): ([f32; 3], [f32; 3]), v: &[[f32; 3]; 3]| {
        for p in v {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    };
    let empty = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let local = header.stored_triangles > 0
        && changes
            .iter()
            .all(|c| !holds_triangle(&c.old) || inside(&c.old.v));
    let (lo, hi) = if local {
        changes
            .iter()
            .filter(|c| holds_triangle(&c.new))
            .fold((header.mesh_min, header.mesh_max), |b, c| grow(b, &c.new.v))
    } else {
        (0..u.count.div_ceil(PRIM_CHUNK))
            .into_par_iter()
            .flat_map_iter(|c| {
                let lo = c * PRIM_CHUNK;
                records_after(u, changes, lo..(lo + PRIM_CHUNK).min(u.count))
            })
            .filter(holds_triangle)
            .fold(|| empty, |b, r| grow(b, &r.v))
            .reduce(
                || empty,
                |a, b| {
                    (
                        std::array::from_fn(|k| a.0[k].min(b.0[k])),
                        std::array::from_fn(|k| a.1[k].max(b.1[k])),
                    )
                },
            )
    };
    if lo[0] > hi[0] {
        // No triangle left: the bounds of nothing, as a pack of degenerate triangles has.
        return (
            header.root_min.map(|c| c as f32),
            header.root_min.map(|c| c as f32),
        );
    }
    (lo, hi)
}

/// Merges the top tree's empty leaves again (spec §5): links count as solid.
fn remerge_top(nodes: &mut [TopNode], merge_on: bool) {
    nodes.sort_unstable_by_key(|n| (n.level, n.code));
    let mut levels: Vec<BuildLevel> = Vec::new();
    let mut index: Vec<(usize, usize)> = Vec::with_capacity(nodes.len());
    for n in nodes.iter() {
        let l = n.level as usize;
        while levels.len() <= l {
            levels.push(BuildLevel {
                codes: Vec::new(),
                nodes: Vec::new(),
            });
        }
        index.push((l, levels[l].nodes.len()));
        levels[l].codes.push(n.code);
        levels[l].nodes.push(match n.kind {
            TopKind::Internal => BuildNode::Internal,
            TopKind::Empty { .. } => BuildNode::Leaf(Vec::new()),
            TopKind::Link { .. } => BuildNode::Leaf(vec![0]),
        });
    }
    let boxes = merge::merge_volumes(&levels, merge_on);
    for (n, &(l, i)) in nodes.iter_mut().zip(&index) {
        if let (TopKind::Empty { .. }, Some(Merged { volume, shape })) = (n.kind, boxes[l][i]) {
            n.kind = TopKind::Empty { volume, shape };
        }
    }
}

/// What [`compact`] did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CompactReport {
    pub file: String,
    /// The generation compacted (the file written is generation 1).
    pub generation: u64,
    pub bytes_before: u64,
    pub bytes_after: u64,
    pub blocks: u64,
    /// Free directory entries dropped.
    pub free_entries: u64,
    pub seconds: f64,
}

/// Writes the current generation of the file at `src` as a file of generation 1 at `dst`
/// (atomically; `dst` may be `src`, replaced when complete): its live blocks one after another
/// with new ids, the top tree linking to them, the primitive table in order; nothing of older
/// generations. Readers of the old file keep its inode.
pub fn compact(src: &Path, dst: &Path) -> Result<CompactReport, Error> {
    let t0 = Instant::now();
    // No update may run meanwhile: it would be lost when the compacted file replaces this one.
    let held = lock(src)?;
    let done = super::ropes::rewrite_file(src, dst, |file, sink| {
        let h = *file.header();
        let mut report = CompactReport {
            file: dst.display().to_string(),
            generation: h.generation,
            bytes_before: file.bytes().len() as u64,
            ..CompactReport::default()
        };
        let io = |e: std::io::Error| Error::io(dst, e);
        let top = read_top(file, src)?;
        let directory = file.directory();
        let reader = BlockReader::new(file);
        let mut ids: HashMap<u32, u32> = HashMap::new();
        let mut w = FileWriter::new(sink).map_err(io)?;
        w.set_geometries(
            crate::physical::read_geometries(file).map_err(|e| Error::format(src, e))?,
        );
        for (b, e) in directory.iter().enumerate() {
            if e.is_free() {
                report.free_entries += 1;
                continue;
            }
            let raw = reader
                .read(file.bytes(), b as u32, e)
                .map_err(|err| invalid(src, err))?;
            let view = BlockView::parse(&raw, b as u32, e)
                .map_err(|what| invalid(src, format!("block {b}: {what}")))?;
            let id = w.block_count();
            let opts = BlockOptions {
                block_size: crate::physical::DEFAULT_BLOCK_SIZE,
                compress: (e.codec == CODEC_ZSTD).then_some(DEFAULT_ZSTD_LEVEL),
                chunk_groups: file_chunk_groups(file.header()),
                lean: e.codec == CODEC_LEAN,
            };
            let stored = store_block(UnitRef::from(&view), e.root_level, id, &opts)?;
            w.push(stored).map_err(io)?;
            ids.insert(b as u32, id);
        }
        report.blocks = ids.len() as u64;
        let nodes: Vec<TopNode> = top
            .nodes
            .iter()
            .map(|n| match n.kind {
                TopKind::Link { block, root } => ids
                    .get(&block)
                    .map(|&block| TopNode {
                        kind: TopKind::Link { block, root },
                        ..*n
                    })
                    .ok_or_else(|| invalid(src, format!("a link to block {block}, which is free"))),
                _ => Ok(*n),
            })
            .collect::<Result<_, Error>>()?;
        let top_unit = assemble_top(nodes)?;
        if h.flags & FLAG_PRIMS != 0 {
            let mut records = Vec::with_capacity(h.input_triangles as usize);
            let chunks: &[PrimChunk] = file.records(SectionKind::Prims);
            for (c, ch) in chunks.iter().enumerate() {
                let len = ch.count as usize * std::mem::size_of::<PrimRecord>();
                let bytes = file
                    .bytes()
                    .get(ch.offset as usize..(ch.offset as usize).saturating_add(len))
                    .filter(|b| checksum(b) == ch.checksum)
                    .ok_or_else(|| invalid(src, format!("primitive chunk {c} is damaged")))?;
                records.extend(
                    bytes
                        .chunks_exact(std::mem::size_of::<PrimRecord>())
                        .map(bytemuck::pod_read_unaligned::<PrimRecord>),
                );
            }
            w.push_prims(&records).map_err(io)?;
        }
        let (sink, size) = w.finish(&h, top_unit.as_ref()).map_err(io)?;
        report.bytes_after = size;
        report.seconds = t0.elapsed().as_secs_f64();
        Ok((sink, size, report))
    });
    drop(held);
    done
}

/// The file at `path`, open for writing and locked against other updaters (`flock`).
fn lock(path: &Path) -> Result<std::fs::File, Error> {
    let handle = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    handle.try_lock().map_err(|e| match e {
        std::fs::TryLockError::WouldBlock => {
            invalid(path, "another update holds the file (it is locked)")
        }
        std::fs::TryLockError::Error(e) => Error::io(path, e),
    })?;
    Ok(handle)
}
