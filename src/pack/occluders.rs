//! Occluders (format-spec §8.5): the primitive index of Liang and Huang's multi-index tree for
//! shadow rays, carried over to OAVM. Large triangles are also stored at an internal node of
//! their block above their leaves; a shadow ray's top-down walk tests them when it enters the
//! node and stops there if one is hit, instead of descending to the leaf that holds it.
//!
//! **Choice** (the comparison KD-tree's, `oavm_compare::kdtree`'s shadow module, on the octree):
//! candidates are the triangles whose box's surface area exceeds `candidate_ratio` times the
//! mean over the file's distinct triangles. For each, and each internal node of its block from
//! the lowest holding all of its leaves under one root up to that root, the subtree's cost with
//! the triangle tested first is `C' = C_tri + (1 - P) * sum of the children's costs` (`P` the
//! area of the triangle's box clipped to the node's cell over the cell's, the costs by the SAH
//! with the KD-tree's constants: a leaf costs `C_tri` per triangle, an internal node `C_trav`
//! plus a quarter of each child's, a child's share of its parent's surface); the saving
//! `sum / C'` is weighted by `exp(-k d)`, `d` the levels above that lowest node; the node of
//! greatest weighted saving keeps the triangle if it exceeds `min_benefit`, and a node keeps the
//! `per_node` of greatest saving. A triangle is kept in its leaves too.
//!
//! Added to a finished file of clusters, block by block ([`add_occluders`]), holding one block
//! at a time; a first pass reads every block's triangles for the mean. Ropes and everything
//! else are kept as they are. A file of leaf lists is refused: it is walked leaf to leaf, whose
//! descents do not test occluders (only the top-down walk, of clusters, does).

use std::collections::HashMap;
use std::time::Instant;

use serde::Serialize;

use super::ropes::{block_root_codes, rewrite_file, roots_of};
use crate::error::Error;
use crate::mapping::morton::{self, LATTICE_SIZE, MAX_LEVEL};
use crate::mapping::{LevelInfos, TreeMap};
use crate::physical::format::*;
use crate::physical::writer::{FileWriter, Sink, UnitRef, store_block};
use crate::physical::{BlockOptions, BlockReader, BlockView, DEFAULT_ZSTD_LEVEL, OavmFile};

/// The cost of a triangle test and of a node visit in the estimates (pbrt's, the comparison
/// KD-tree's SAH constants).
pub const ISECT_COST: f64 = 80.0;
pub const TRAVERSAL_COST: f64 = 1.0;

/// The knobs of the multi-index tree's primitive index (module docs), here and on the
/// comparison KD-tree; the defaults are the source's middle values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ShadowParams {
    /// A triangle is a candidate occluder if its box's surface area is more than this times the
    /// mean (the source: 0.45 to 0.60 by scene).
    pub candidate_ratio: f64,
    /// The depth weight `exp(-k d)` (the source: about 0.6).
    pub depth_k: f64,
    /// A candidate is promoted if its best weighted saving exceeds this.
    pub min_benefit: f64,
    /// Most triangles promoted to one node.
    pub per_node: usize,
    /// Cells per side of the adjacency index's virtual grid (the KD-tree's).
    pub grid: u32,
}

impl Default for ShadowParams {
    fn default() -> Self {
        ShadowParams {
            candidate_ratio: 0.5,
            depth_k: 0.6,
            min_benefit: 1.0,
            per_node: 8,
            grid: 64,
        }
    }
}

/// What adding occluders did.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct OccluderReport {
    /// Seconds choosing them, of [`Self::seconds`].
    pub compute_seconds: f64,
    /// Seconds for the whole pass: two reads, decoding, choosing, encoding and writing.
    pub seconds: f64,
    /// Distinct triangles whose box area passed the candidate threshold.
    pub candidates: u64,
    /// Occluder records stored, and the internal nodes holding them.
    pub occluders: u64,
    pub occluder_nodes: u64,
    /// Bytes of occluder parts (8 per node entry, 40 per triangle).
    pub occluder_bytes: u64,
    pub bytes_before: u64,
    pub bytes_after: u64,
}

fn bad(what: impl std::fmt::Display) -> Error {
    Error::Build(format!("adding occluders: {what}"))
}

type Box3 = [[f64; 3]; 2];

fn area(b: &Box3) -> f64 {
    let e = |k: usize| (b[1][k] - b[0][k]).max(0.0);
    2.0 * (e(0) * e(1) + e(1) * e(2) + e(2) * e(0))
}

fn tri_box(v: &[[f32; 3]; 3]) -> Box3 {
    [
        std::array::from_fn(|k| v[0][k].min(v[1][k]).min(v[2][k]) as f64),
        std::array::from_fn(|k| v[0][k].max(v[1][k]).max(v[2][k]) as f64),
    ]
}

fn clip(a: &Box3, b: &Box3) -> Box3 {
    [
        std::array::from_fn(|k| a[0][k].max(b[0][k])),
        std::array::from_fn(|k| a[1][k].min(b[1][k])),
    ]
}

/// The triangles of a solid leaf: its references' records (lists) or its cluster's lanes.
fn leaf_triangles(
    view: &BlockView<'_>,
    rec: NodeRecord,
    out: &mut Vec<TriRecord>,
) -> Result<(), Error> {
    out.clear();
    if view.groups.is_empty() {
        let Some(NodeKind::Solid {
            first,
            inline_count,
            ..
        }) = rec.kind()
        else {
            return Err(bad("a solid leaf record is not one"));
        };
        let (refs, _) = leaf_refs(view.refs, first, inline_count)
            .ok_or_else(|| bad("leaf references out of range"))?;
        for &r in refs {
            out.push(
                *view
                    .triangles
                    .get(r as usize)
                    .ok_or_else(|| bad("reference out of range"))?,
            );
        }
        return Ok(());
    }
    let mut stack = vec![(rec.payload, 0usize)];
    while let Some((n, depth)) = stack.pop() {
        let node = view
            .cluster_nodes
            .get(n as usize)
            .ok_or_else(|| bad("cluster node out of range"))?;
        if depth >= MAX_CLUSTER_DEPTH || node.child_count as usize > CLUSTER_WIDTH {
            return Err(bad("cluster malformed"));
        }
        for i in 0..node.child_count as usize {
            if i < node.inner_count as usize {
                stack.push((node.node_base + i as u32, depth + 1));
            } else {
                let g = view
                    .groups
                    .get(node.group_base as usize + i - node.inner_count as usize)
                    .ok_or_else(|| bad("group out of range"))?;
                for l in 0..(g.count as usize).min(8) {
                    out.push(TriRecord {
                        v: g.triangle(l),
                        prim: g.prim[l],
                    });
                }
            }
        }
    }
    Ok(())
}

/// Every node of a block: its level, code and parent (node record indices), in record order.
struct Nodes {
    level: Vec<u32>,
    code: Vec<u64>,
    parent: Vec<u32>,
}

impl Nodes {
    /// The root above node `i` (itself, for a root).
    fn root_of(&self, mut i: u32) -> u32 {
        while let Some(&p) = self.parent.get(i as usize) {
            if p == u32::MAX {
                break;
            }
            i = p;
        }
        i
    }

    /// The lowest node above both `a` and `b` (`u32::MAX` if they are under different roots).
    fn lca(&self, mut a: u32, mut b: u32) -> u32 {
        while a != b {
            let (la, lb) = (self.level[a as usize], self.level[b as usize]);
            if la >= lb {
                a = self.parent[a as usize];
            } else {
                b = self.parent[b as usize];
            }
            if a == u32::MAX || b == u32::MAX {
                return u32::MAX;
            }
        }
        a
    }
}

fn block_nodes(
    map: &TreeMap<'_>,
    levels: &[LevelEntry],
    base: u32,
    roots: Vec<u64>,
) -> Result<Nodes, Error> {
    let total: u64 = levels.iter().map(|l| l.node_count).sum();
    let mut n = Nodes {
        level: Vec::with_capacity(total as usize),
        code: Vec::with_capacity(total as usize),
        parent: Vec::with_capacity(total as usize),
    };
    let mut codes: Vec<(u64, u32)> = roots.into_iter().map(|c| (c, u32::MAX)).collect();
    for (l, e) in levels.iter().enumerate() {
        let level = base + l as u32;
        if level > MAX_LEVEL || codes.len() as u64 != e.node_count {
            return Err(bad(format!("level {level} of a block is inconsistent")));
        }
        let mut next = Vec::with_capacity(e.internal_count as usize * 8);
        for (i, &(code, parent)) in codes.iter().enumerate() {
            let at = (e.node_start + i as u64) as u32;
            n.level.push(level);
            n.code.push(code);
            n.parent.push(parent);
            let rec = map.node(level, i as u64).map_err(bad)?;
            if rec.kind_bits() == KIND_INTERNAL {
                next.extend((0..8).map(|o| (code << 3 | o, at)));
            }
        }
        codes = next;
    }
    Ok(n)
}

/// The occluders of one block (spec §8.5): its node entries and triangles.
#[allow(clippy::too_many_arguments)]
fn block_occluders(
    view: &BlockView<'_>,
    map: &TreeMap<'_>,
    nodes: &Nodes,
    header: &Header,
    mean: f64,
    p: &ShadowParams,
    report: &mut OccluderReport,
) -> Result<(Vec<OccluderNode>, Vec<TriRecord>), Error> {
    let costs = Costs::of(view, map, nodes, mean, p)?;
    report.candidates += costs.leaves.len() as u64;
    // The best node of each candidate, per root its leaves are under.
    let mut chosen: Vec<(u32, f64, TriRecord)> = Vec::new();
    let mut by_root: HashMap<u32, u32> = HashMap::new();
    for (tri, ls) in costs.leaves.values() {
        by_root.clear();
        for &l in ls {
            let r = nodes.root_of(l);
            let e = by_root.entry(r).or_insert(l);
            *e = nodes.lca(*e, l);
        }
        let b = tri_box(&tri.v);
        for &home in by_root.values() {
            if home == u32::MAX {
                continue;
            }
            let best = best_node(nodes, &costs, header, p, home, &b);
            if best.0 > p.min_benefit {
                chosen.push((best.1, best.0, *tri));
            }
        }
    }
    chosen.sort_by(|a, b| {
        a.0.cmp(&b.0)
            .then(b.1.total_cmp(&a.1))
            .then(a.2.prim.cmp(&b.2.prim))
    });
    let (mut entries, mut out) = (Vec::new(), Vec::new());
    let mut k = 0;
    while k < chosen.len() {
        let node = chosen[k].0;
        entries.push(OccluderNode {
            node,
            first: out.len() as u32,
        });
        let mut m = 0;
        while k < chosen.len() && chosen[k].0 == node {
            if m < p.per_node {
                out.push(chosen[k].2);
                m += 1;
            }
            k += 1;
        }
    }
    Ok((entries, out))
}

/// A block's estimated costs (module docs), by node record: the sum of each node's children's,
/// which internal nodes are, and each candidate triangle (by primitive id) with its leaves.
struct Costs {
    kids: Vec<f64>,
    internal: Vec<bool>,
    leaves: HashMap<u32, (TriRecord, Vec<u32>)>,
}

impl Costs {
    /// The costs, bottom-up (children follow their parents in record order), and each
    /// candidate's leaves: a triangle whose box's area is over `p.candidate_ratio` times the
    /// `mean`.
    fn of(
        view: &BlockView<'_>,
        map: &TreeMap<'_>,
        nodes: &Nodes,
        mean: f64,
        p: &ShadowParams,
    ) -> Result<Costs, Error> {
        let n = nodes.level.len();
        let mut cost = vec![0f64; n];
        let mut kids = vec![0f64; n];
        let mut internal = vec![false; n];
        let mut leaves: HashMap<u32, (TriRecord, Vec<u32>)> = HashMap::new();
        let mut tris = Vec::new();
        for i in (0..n).rev() {
            let rec = map
                .node(nodes.level[i], i as u64 - map.node_start(nodes.level[i]))
                .map_err(bad)?;
            match rec.kind_bits() {
                KIND_INTERNAL => {
                    internal[i] = true;
                    cost[i] = TRAVERSAL_COST + 0.25 * kids[i];
                }
                KIND_SOLID => {
                    leaf_triangles(view, rec, &mut tris)?;
                    cost[i] = ISECT_COST * tris.len() as f64;
                    for t in &tris {
                        if area(&tri_box(&t.v)) > p.candidate_ratio * mean {
                            leaves
                                .entry(t.prim)
                                .or_insert_with(|| (*t, Vec::new()))
                                .1
                                .push(i as u32);
                        }
                    }
                }
                _ => {}
            }
            if let Some(&parent) = nodes.parent.get(i)
                && let Some(k) = kids.get_mut(parent as usize)
            {
                *k += cost[i];
            }
        }
        Ok(Costs {
            kids,
            internal,
            leaves,
        })
    }
}

/// The node of greatest weighted saving for a triangle whose box is `b` and whose leaves are
/// all under node `home`, from `home` (a triangle of one leaf: from the leaf's parent) up to
/// its root: (saving, node), the node `u32::MAX` if none saves anything.
fn best_node(
    nodes: &Nodes,
    costs: &Costs,
    header: &Header,
    p: &ShadowParams,
    home: u32,
    b: &Box3,
) -> (f64, u32) {
    let unit = header.root_size / LATTICE_SIZE as f64;
    let cell = |i: usize| -> Box3 {
        let lo = morton::cell_origin(nodes.code[i], nodes.level[i]);
        let s = morton::cell_size(nodes.level[i]) as f64 * unit;
        let lo: [f64; 3] = std::array::from_fn(|k| header.root_min[k] + lo[k] as f64 * unit);
        [lo, std::array::from_fn(|k| lo[k] + s)]
    };
    let kids = &costs.kids;
    let mut node = if costs.internal[home as usize] {
        home
    } else {
        nodes.parent[home as usize]
    };
    let mut best = (0.0, u32::MAX);
    while node != u32::MAX {
        let i = node as usize;
        let c = cell(i);
        let hit = (area(&clip(b, &c)) / area(&c).max(f64::MIN_POSITIVE)).min(1.0);
        let with = ISECT_COST + (1.0 - hit) * kids[i];
        let d = nodes.level[home as usize].saturating_sub(nodes.level[i]) as f64;
        let benefit = kids[i] / with * (-p.depth_k * d).exp();
        if benefit > best.0 {
            best = (benefit, node);
        }
        node = nodes.parent[i];
    }
    best
}

/// Rewrites the file `file` into `sink` with occluders chosen by `params` (module docs; spec
/// §8.5): every block read, checked and decoded as the pager does, given its occluders and
/// stored again (compressed again where it was); the top tree is kept. Answers are unchanged.
pub fn add_occluders<D: AsRef<[u8]>, S: Sink>(
    file: &OavmFile<D>,
    params: &ShadowParams,
    sink: S,
) -> Result<(S, u64, OccluderReport), Error> {
    let t0 = Instant::now();
    let mut report = OccluderReport {
        bytes_before: file.bytes().len() as u64,
        ..OccluderReport::default()
    };
    let mut header = *file.header();
    if header.flags & FLAG_PRIMS != 0 {
        return Err(bad(
            "an updatable file (it holds the primitive table, format-spec §8.6) cannot take them: \
             an update would have to rewrite them in every block; pack without --updatable",
        ));
    }
    if header.flags & FLAG_CLUSTERS == 0 {
        return Err(bad(
            "occluders are tested by the top-down walk, which needs a file of clusters \
             (`oavm-pack --leaf cluster`); this one holds leaf lists",
        ));
    }
    let top_levels = file.levels();
    let top_infos = LevelInfos::new(top_levels, 0);
    let top_nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    let top_ranks: &[RankWord] = file.records(SectionKind::Ranks);
    let top = TreeMap::new(&top_infos, top_levels, top_nodes, top_ranks);
    let io = |e: std::io::Error| bad(e);

    // The codes of every block's roots, from the links to them.
    let root_codes = block_root_codes(&top, top_levels).map_err(bad)?;

    // The mean box area of the distinct triangles.
    let reader = BlockReader::new(file);
    let t = Instant::now();
    let mut seen = vec![0u64; (header.input_triangles as usize).div_ceil(64)];
    let (mut sum, mut count) = (0f64, 0u64);
    let mut tris = Vec::new();
    for (id, entry) in file.directory().iter().enumerate() {
        let id = id as u32;
        let raw = reader
            .read(file.bytes(), id, entry)
            .map_err(|e| bad(format!("{e}")))?;
        let view =
            BlockView::parse(&raw, id, entry).map_err(|what| bad(format!("block {id}: {what}")))?;
        let infos = LevelInfos::new(view.levels, view.header.root_level);
        let map = TreeMap::new(&infos, view.levels, view.nodes, view.ranks);
        for (l, e) in view.levels.iter().enumerate() {
            for i in 0..e.node_count {
                let rec = map
                    .node(view.header.root_level + l as u32, i)
                    .map_err(bad)?;
                if rec.kind_bits() != KIND_SOLID {
                    continue;
                }
                leaf_triangles(&view, rec, &mut tris)?;
                for t in &tris {
                    let (w, b) = (t.prim as usize / 64, t.prim % 64);
                    if let Some(word) = seen.get_mut(w)
                        && *word >> b & 1 == 0
                    {
                        *word |= 1 << b;
                        sum += area(&tri_box(&t.v));
                        count += 1;
                    }
                }
            }
        }
    }
    let mean = sum / count.max(1) as f64;
    report.compute_seconds += t.elapsed().as_secs_f64();

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
        let nodes = block_nodes(&map, view.levels, view.header.root_level, roots)?;
        let (entries, occluders) =
            block_occluders(&view, &map, &nodes, &header, mean, params, &mut report)?;
        report.compute_seconds += t.elapsed().as_secs_f64();
        report.occluder_nodes += entries.len() as u64;
        report.occluders += occluders.len() as u64;
        report.occluder_bytes += (8 * entries.len() + 40 * occluders.len()) as u64;
        let unit = UnitRef {
            occluder_nodes: &entries,
            occluders: &occluders,
            ..UnitRef::from(&view)
        };
        let opts = BlockOptions {
            compress: (entry.codec == CODEC_ZSTD).then_some(DEFAULT_ZSTD_LEVEL),
            lean: entry.codec == CODEC_LEAN,
            // The file's chunks: a block rebuilt keeps the size all its blocks share.
            chunk_groups: super::update::file_chunk_groups(&header),
            ..BlockOptions::default()
        };
        w.push(store_block(unit, view.header.root_level, id, &opts)?)
            .map_err(io)?;
    }
    let top_unit = UnitRef {
        levels: top_levels,
        nodes: top_nodes,
        ranks: top_ranks,
        volumes: file.records(SectionKind::Volumes),
        refs: &[],
        triangles: &[],
        cluster_nodes: &[],
        groups: &[],
        ropes: file.records(SectionKind::Ropes),
        occluder_nodes: &[],
        occluders: &[],
    };
    header.flags |= FLAG_OCCLUDERS;
    let (sink, size) = w.finish(&header, top_unit).map_err(io)?;
    report.bytes_after = size;
    report.seconds = t0.elapsed().as_secs_f64();
    Ok((sink, size, report))
}

/// [`add_occluders`] from the file at `src` into `dst`, written atomically (`dst` may be
/// `src`: the new file replaces it when complete).
pub fn add_occluders_file(
    src: &std::path::Path,
    dst: &std::path::Path,
    params: &ShadowParams,
) -> Result<OccluderReport, Error> {
    rewrite_file(src, dst, |file, sink| add_occluders(file, params, sink))
}
