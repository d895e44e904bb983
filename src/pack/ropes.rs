//! Ropes (format-spec §8.4): the threaded KD-tree's links (Jiao, Chen and Zhang; Havran's and
//! Popov's ropes) carried over to the octree. For every leaf and link of a file, and for each
//! face of the box a walk crosses there (its cell, or an empty leaf's merged volume), the
//! smallest node that contains everything just across the face: Samet's neighbour of equal or
//! larger size, generalised to a volume's face. A walk that leaves the box by that face goes to
//! the node the rope names and descends from there, instead of finding the lowest common
//! ancestor of its old and new cell and descending from it.
//!
//! Ropes are added to a finished file, block by block ([`add_ropes`]): a block's ropes lead
//! to its own nodes or to the top tree (never into another block, whose nodes the rope could
//! only name with the block's index too), so each block needs only itself and the top tree,
//! and the pass holds one block at a time whatever the size of the file. `oavm-pack --ropes`
//! runs it after the pack; it works on any file, of lists or of clusters.

use std::collections::HashMap;
use std::time::Instant;

use serde::Serialize;

use crate::error::Error;
use crate::mapping::morton::{self, LATTICE_SIZE, MAX_LEVEL};
use crate::mapping::{LevelInfos, TreeMap};
use crate::physical::format::*;
use crate::physical::writer::FileSink;
use crate::physical::writer::{FileWriter, Sink, UnitRef, store_block};
use crate::physical::{BlockOptions, BlockReader, BlockView, DEFAULT_ZSTD_LEVEL, OavmFile};

/// What adding ropes did.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RopeReport {
    /// Seconds spent finding the ropes (the descents), of [`Self::seconds`].
    pub compute_seconds: f64,
    /// Seconds for the whole pass: reading, decoding, finding, encoding and writing.
    pub seconds: f64,
    /// Leaves and links given ropes (six each).
    pub roped_nodes: u64,
    /// Ropes stored: six per leaf and link (the source's pointer count; internal nodes' rope
    /// records are zero and not counted).
    pub ropes: u64,
    /// Ropes leading out of the root cube.
    pub exits: u64,
    /// Ropes of a block's leaves that lead to the top tree (the node across is outside the
    /// block).
    pub to_top: u64,
    /// Bytes of rope records (24 per node record, internal nodes included).
    pub rope_bytes: u64,
    /// The file's size before and after.
    pub bytes_before: u64,
    pub bytes_after: u64,
}

fn bad(what: impl std::fmt::Display) -> Error {
    Error::Build(format!("adding ropes: {what}"))
}

/// The exit box of a node a walk stops at (spec §10): a link's or solid leaf's cell, an empty
/// leaf's volume rebuilt from its shape as the tracer rebuilds it.
fn exit_box(rec: NodeRecord, level: u32, code: u64) -> ([u32; 3], [u32; 3]) {
    let lo = morton::cell_origin(code, level);
    if rec.kind_bits() == KIND_EMPTY {
        rec.shape_bits().box_around(lo)
    } else {
        let s = morton::cell_size(level);
        (lo, lo.map(|x| x + s))
    }
}

/// Descends `map` from node `idx` of `level` toward cell `lo` while the node is internal and
/// above `stop`: the node reached, its level and record.
fn descend_to(
    map: &TreeMap<'_>,
    mut level: u32,
    mut idx: u64,
    lo: [u32; 3],
    stop: u32,
) -> Result<(u32, u64, NodeRecord), Error> {
    loop {
        let rec = map.node(level, idx).map_err(bad)?;
        if rec.kind_bits() != KIND_INTERNAL || level >= stop {
            return Ok((level, idx, rec));
        }
        idx = map
            .child(level, idx, morton::octant_of_point(lo, level + 1))
            .map_err(bad)?;
        level += 1;
    }
}

/// The smallest node containing the lattice cells `lo..=hi`, found by descending from the top
/// tree's root: a rope to a top-tree node (with [`ROPE_TOP`]), or, where the descent enters
/// block `own` (the block whose ropes these are), to that block's node.
fn target(
    top: &TreeMap<'_>,
    own: Option<(u32, &TreeMap<'_>)>,
    lo: [u32; 3],
    hi: [u32; 3],
) -> Result<u32, Error> {
    let stop = morton::common_level(lo, hi);
    let index = |map: &TreeMap<'_>, level: u32, idx: u64| {
        let i = map.node_start(level) + idx;
        u32::try_from(i)
            .ok()
            .filter(|&i| i <= ROPE_MAX_INDEX)
            .ok_or_else(|| bad(format!("node {i} is past what a rope can name")))
    };
    let (level, idx, rec) = descend_to(top, 0, 0, lo, stop)?;
    if rec.kind_bits() == KIND_LINK {
        let (b, root) = rec.link_bits();
        if let Some((_, map)) = own.filter(|(id, _)| *id == b) {
            let (level, idx, _) = descend_to(map, level, root as u64, lo, stop)?;
            return index(map, level, idx);
        }
    }
    Ok(index(top, level, idx)? | ROPE_TOP)
}

/// The six ropes of a node whose walk box is `lo..hi` (spec §8.4 face order).
fn ropes_of(
    top: &TreeMap<'_>,
    own: Option<(u32, &TreeMap<'_>)>,
    lo: [u32; 3],
    hi: [u32; 3],
    report: &mut RopeReport,
) -> Result<RopeRecord, Error> {
    let mut rec = RopeRecord::default();
    for a in 0..3 {
        for positive in [false, true] {
            // The layer of cells just across the face, as wide as the box.
            let across = if positive {
                hi[a]
            } else {
                lo[a].wrapping_sub(1)
            };
            let rope = if across >= LATTICE_SIZE || hi.iter().any(|&h| h > LATTICE_SIZE) {
                report.exits += 1;
                ROPE_EXIT
            } else {
                let mut a_lo = lo;
                let mut a_hi = hi.map(|h| h - 1);
                a_lo[a] = across;
                a_hi[a] = across;
                let r = target(top, own, a_lo, a_hi)?;
                if own.is_some() && r & ROPE_TOP != 0 {
                    report.to_top += 1;
                }
                r
            };
            rec.across[2 * a + positive as usize] = rope;
        }
    }
    report.ropes += 6;
    report.roped_nodes += 1;
    Ok(rec)
}

/// The ropes of every node of a unit (the top tree, or block `own`) whose level-0 nodes have
/// the codes `roots`; internal nodes get zero records.
fn unit_ropes(
    map: &TreeMap<'_>,
    levels: &[LevelEntry],
    base: u32,
    roots: Vec<u64>,
    top: &TreeMap<'_>,
    own: Option<u32>,
    report: &mut RopeReport,
) -> Result<Vec<RopeRecord>, Error> {
    let total: u64 = levels.iter().map(|l| l.node_count).sum();
    let mut out = vec![RopeRecord::default(); total as usize];
    let mut codes = roots;
    for (l, e) in levels.iter().enumerate() {
        let level = base + l as u32;
        if level > MAX_LEVEL || codes.len() as u64 != e.node_count {
            return Err(bad(format!("level {level} of a unit is inconsistent")));
        }
        let mut next = Vec::with_capacity(e.internal_count as usize * 8);
        for (i, &code) in codes.iter().enumerate() {
            let rec = map.node(level, i as u64).map_err(bad)?;
            if rec.kind_bits() == KIND_INTERNAL {
                next.extend((0..8).map(|o| code << 3 | o));
                continue;
            }
            let (lo, hi) = exit_box(rec, level, code);
            let own_map = own.map(|b| (b, map));
            out[(e.node_start + i as u64) as usize] = ropes_of(top, own_map, lo, hi, report)?;
        }
        codes = next;
    }
    Ok(out)
}

/// Rewrites the file `file` into `sink` with ropes (spec §8.4): every block read, checked and
/// decoded as the pager does, given its ropes and stored again (compressed again where it
/// was), then the top tree with its own. Answers are unchanged; only the walk that follows
/// ropes reads them.
pub fn add_ropes<D: AsRef<[u8]>, S: Sink>(
    file: &OavmFile<D>,
    sink: S,
) -> Result<(S, u64, RopeReport), Error> {
    let t0 = Instant::now();
    let mut report = RopeReport {
        bytes_before: file.bytes().len() as u64,
        ..RopeReport::default()
    };
    let header = *file.header();
    if header.flags & FLAG_PRIMS != 0 {
        return Err(bad(
            "an updatable file (it holds the primitive table, format-spec §8.6) cannot take them: \
             an update would have to rewrite them in every block; pack without --updatable",
        ));
    }
    let top_levels = file.levels();
    let top_infos = LevelInfos::new(top_levels, 0);
    let top_nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    let top_ranks: &[RankWord] = file.records(SectionKind::Ranks);
    let top = TreeMap::new(&top_infos, top_levels, top_nodes, top_ranks);
    let io = |e: std::io::Error| bad(e);

    // The codes of every block's roots, from the links to them.
    let t = Instant::now();
    let root_codes = block_root_codes(&top, top_levels).map_err(bad)?;
    let top_ropes = unit_ropes(&top, top_levels, 0, vec![0], &top, None, &mut report)?;
    report.compute_seconds += t.elapsed().as_secs_f64();

    let reader = BlockReader::new(file);
    let mut w = FileWriter::new(sink).map_err(io)?;
    w.set_geometries(crate::physical::read_geometries(file).map_err(bad)?);
    for (id, entry) in file.directory().iter().enumerate() {
        let id = id as u32;
        let raw = reader
            .read(file.bytes(), id, entry)
            .map_err(|e| bad(format!("{e}")))?;
        let view =
            BlockView::parse(&raw, id, entry).map_err(|what| bad(format!("block {id}: {what}")))?;
        let roots = roots_of(&root_codes, id, view.header.root_count).map_err(bad)?;
        let infos = LevelInfos::new(view.levels, view.header.root_level);
        let map = TreeMap::new(&infos, view.levels, view.nodes, view.ranks);
        let t = Instant::now();
        let ropes = unit_ropes(
            &map,
            view.levels,
            view.header.root_level,
            roots,
            &top,
            Some(id),
            &mut report,
        )?;
        report.compute_seconds += t.elapsed().as_secs_f64();
        report.rope_bytes += (ropes.len() * std::mem::size_of::<RopeRecord>()) as u64;
        let unit = UnitRef {
            ropes: &ropes,
            ..UnitRef::from(&view)
        };
        let opts = BlockOptions {
            compress: (entry.codec == CODEC_ZSTD).then_some(DEFAULT_ZSTD_LEVEL),
            lean: entry.codec == CODEC_LEAN,
            // The file's chunks: a block rebuilt keeps the size all its blocks share.
            chunk_groups: super::update::file_chunk_groups(&header),
            ..BlockOptions::default()
        };
        let stored = store_block(unit, view.header.root_level, id, &opts)?;
        w.push(stored).map_err(io)?;
    }
    report.rope_bytes += (top_ropes.len() * std::mem::size_of::<RopeRecord>()) as u64;
    let top_unit = UnitRef {
        levels: top_levels,
        nodes: top_nodes,
        ranks: top_ranks,
        volumes: file.records(SectionKind::Volumes),
        refs: &[],
        triangles: &[],
        cluster_nodes: &[],
        groups: &[],
        ropes: &top_ropes,
        occluder_nodes: &[],
        occluders: &[],
    };
    let (sink, size) = w.finish(&header, top_unit).map_err(io)?;
    report.bytes_after = size;
    report.seconds = t0.elapsed().as_secs_f64();
    Ok((sink, size, report))
}

/// The codes of every block's roots, by (block, root), from the links to them in the top tree
/// `top` (whose level table is `levels`).
pub(super) fn block_root_codes(
    top: &TreeMap<'_>,
    levels: &[LevelEntry],
) -> Result<HashMap<(u32, u32), u64>, String> {
    let mut root_codes = HashMap::new();
    let mut codes = vec![0u64];
    for (l, e) in levels.iter().enumerate() {
        let mut next = Vec::with_capacity(e.internal_count as usize * 8);
        for (i, &code) in codes.iter().enumerate() {
            let rec = top.node(l as u32, i as u64).map_err(|e| e.to_string())?;
            match rec.kind_bits() {
                KIND_INTERNAL => next.extend((0..8).map(|o| code << 3 | o)),
                KIND_LINK => {
                    let (b, root) = rec.link_bits();
                    root_codes.insert((b, root), code);
                }
                _ => {}
            }
        }
        codes = next;
    }
    Ok(root_codes)
}

/// The codes of the `count` roots of block `id` ([`block_root_codes`]).
pub(super) fn roots_of(
    root_codes: &HashMap<(u32, u32), u64>,
    id: u32,
    count: u32,
) -> Result<Vec<u64>, String> {
    (0..count)
        .map(|r| {
            root_codes
                .get(&(id, r))
                .copied()
                .ok_or_else(|| format!("root {r} of block {id} is not linked"))
        })
        .collect()
}

/// Runs `pass` (which rewrites a file into a sink) from the file at `src` into `dst`, written
/// atomically (`dst` may be `src`: the new file replaces it when complete).
pub(super) fn rewrite_file<R>(
    src: &std::path::Path,
    dst: &std::path::Path,
    pass: impl FnOnce(&OavmFile<crate::os::MappedFile>, FileSink) -> Result<(FileSink, u64, R), Error>,
) -> Result<R, Error> {
    let map = crate::os::MappedFile::open(src).map_err(|e| Error::io(src, e))?;
    let file = OavmFile::open(map).map_err(|e| Error::format(src, e))?;
    let inputs: &[&std::path::Path] = if src == dst { &[] } else { &[src] };
    let mut out = crate::output::Output::create(dst, inputs)?;
    let path = out.path().to_owned();
    let ioe = |e: std::io::Error| Error::io(&path, e);
    let f = out.file().try_clone().map_err(ioe)?;
    let (sink, _, report) = pass(&file, FileSink::new(f))?;
    sink.into_file().map_err(ioe)?;
    out.commit()?;
    Ok(report)
}

/// [`add_ropes`] from the file at `src` into `dst`, written atomically (`dst` may be `src`:
/// the new file replaces it when complete).
pub fn add_ropes_file(src: &std::path::Path, dst: &std::path::Path) -> Result<RopeReport, Error> {
    rewrite_file(src, dst, add_ropes)
}
