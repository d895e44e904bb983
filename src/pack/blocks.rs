//! Splitting a tree into blocks (format-spec §8; a decision of the builder's): which subtrees go together into a block,
//! the block's own records with local indices, and the top tree that links to them.
//!
//! **Which subtrees.** Every node gets an estimate of its subtree's raw bytes (records, rank
//! words, volumes, references and triangles, counting a triangle once per reference: an upper
//! bound). Going down from the root, a node whose subtree fits the target size becomes a *block
//! root*, and so does every solid leaf, however large (a leaf cannot be split); an empty leaf
//! stays in the top tree (its record holds all a ray needs, spec §4.2), and so does an internal
//! node too large for one block, whose children are considered in turn. Roots are then taken in
//! leaf order (depth-first, i.e. by the Morton code of their lowest corner) and consecutive roots
//! of the same level are grouped into one block while the group fits the target: neighbours in
//! Morton order are neighbours in space, so a block is a compact region and a ray crossing it
//! stays in it for several steps.
//!
//! **A block's records** are those of its roots' subtrees, by level from the roots down (local
//! level 0 holds the roots in group order), each level in the order of the tree, so the mapping
//! rule of spec §4 holds inside the block. Volumes, references and triangles are renumbered
//! within the block, in the block's leaf order; a triangle referenced from two blocks is stored
//! in both, which is what makes every block self-contained (one fetch answers everything a ray
//! needs inside it).
//!
//! **The top tree** is every node that is not inside a block: internal nodes, empty leaves and
//! one *link* per block root. [`assemble_top`] lays a list of such nodes out as a unit, checking
//! that they form a tree (every internal node has its 8 children), so the streaming builder can
//! collect the top from many pieces.

use std::collections::HashMap;

use rayon::prelude::*;

use super::cluster::{ClusterBuilder, ClusterTri};
use crate::error::Error;
use crate::mapping::{ClusterGeometry, rank, rank_words};
use crate::physical::format::*;
use crate::physical::writer::{UnitParts, UnitRef};

/// One block's subtrees, with local indices.
#[derive(Clone, Debug)]
pub struct BlockParts {
    /// Its index in the block directory.
    pub id: u32,
    /// Absolute level of its roots.
    pub root_level: u32,
    pub unit: UnitParts,
}

/// A node of the top tree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TopKind {
    Internal,
    Empty {
        volume: VolumeRecord,
        shape: VolumeShape,
    },
    Link {
        block: u32,
        root: u32,
    },
}

/// A node of the top tree at its place: absolute level and Morton code.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TopNode {
    pub level: u32,
    pub code: u64,
    pub kind: TopKind,
}

/// A tree split into blocks and the top nodes that link to them.
#[derive(Clone, Debug, Default)]
pub struct Split {
    pub top: Vec<TopNode>,
    pub blocks: Vec<BlockParts>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Role {
    Top,
    Root,
    Inside,
}

fn bad(what: impl std::fmt::Display) -> Error {
    Error::Build(format!("splitting the tree into blocks: {what}"))
}

/// The node records of level `l` of `tree`.
fn level_nodes<'a>(tree: &UnitRef<'a>, l: usize) -> Result<&'a [NodeRecord], Error> {
    let e = &tree.levels[l];
    tree.nodes
        .get(e.node_start as usize..(e.node_start + e.node_count) as usize)
        .ok_or_else(|| bad(format!("level {l} runs past the nodes")))
}

/// The rank words of level `l` of `tree`.
fn level_ranks<'a>(tree: &UnitRef<'a>, l: usize) -> Result<&'a [RankWord], Error> {
    let e = &tree.levels[l];
    tree.ranks
        .get(e.rank_start as usize..(e.rank_start + e.node_count.div_ceil(64)) as usize)
        .ok_or_else(|| bad(format!("level {l} runs past the rank words")))
}

/// Splits `tree` (a unit whose level 0 holds nodes of absolute level `base_level` with codes
/// `base_codes`) into blocks of about `target` raw bytes, numbered from `first_block`.
pub fn partition(
    tree: UnitRef<'_>,
    base_level: u32,
    base_codes: &[u64],
    target: u64,
    first_block: u32,
    clusters: Option<&ClusterGeometry>,
) -> Result<Split, Error> {
    let nl = tree.levels.len();
    if nl == 0 {
        return Ok(Split::default());
    }
    if tree.levels[0].node_count != base_codes.len() as u64 {
        return Err(bad("level 0 and its codes differ in length"));
    }
    if base_level as usize + nl > MAX_LEVEL as usize + 1 {
        return Err(bad("the tree is deeper than the lattice"));
    }
    let plan = Plan::new(&tree, base_codes, target)?;
    let groups = plan.groups(base_level, target);
    if first_block as u64 + groups.len() as u64 > u32::MAX as u64 {
        return Err(bad("more blocks than 32-bit ids can number"));
    }
    let top = plan.top_nodes(&tree, base_level, &groups, first_block)?;

    // The blocks, in parallel.
    let blocks = groups
        .par_iter()
        .enumerate()
        .map(|(g, (l, group))| {
            let unit = extract(&tree, base_level, *l as usize, group, &plan.codes, clusters)?;
            Ok(BlockParts {
                id: first_block + g as u32,
                root_level: base_level + l,
                unit,
            })
        })
        .collect::<Result<Vec<_>, Error>>()?;
    Ok(Split { top, blocks })
}

/// What the split decides for each node of a tree, by local level and index in the level: its
/// subtree's estimated raw bytes, its Morton code, its role.
struct Plan {
    size: Vec<Vec<u64>>,
    codes: Vec<Vec<u64>>,
    roles: Vec<Vec<Role>>,
}

/// The role of a node whose parent stays in the top tree, `s` its subtree's bytes: an empty
/// leaf stays in the top tree, and so does an internal node larger than the `target`; any
/// other node is a block root.
fn classify(rec: &NodeRecord, s: u64, target: u64) -> Role {
    match rec.kind() {
        Some(NodeKind::Empty { .. }) => Role::Top,
        Some(NodeKind::Internal) if s > target => Role::Top,
        _ => Role::Root,
    }
}

impl Plan {
    /// The sizes (bottom-up), then the codes and roles (top-down) of `tree`'s nodes.
    fn new(tree: &UnitRef<'_>, base_codes: &[u64], target: u64) -> Result<Plan, Error> {
        let size = subtree_sizes(tree)?;
        let nl = tree.levels.len();
        let mut codes: Vec<Vec<u64>> = vec![base_codes.to_vec()];
        let mut roles: Vec<Vec<Role>> = vec![
            level_nodes(tree, 0)?
                .iter()
                .zip(&size[0])
                .map(|(r, &s)| classify(r, s, target))
                .collect(),
        ];
        for l in 0..nl - 1 {
            let nodes = level_nodes(tree, l)?;
            let next = level_nodes(tree, l + 1)?;
            let mut c = vec![0u64; next.len()];
            let mut role = vec![Role::Inside; next.len()];
            let mut r = 0usize;
            for (i, rec) in nodes.iter().enumerate() {
                if rec.kind() != Some(NodeKind::Internal) {
                    continue;
                }
                for o in 0..8 {
                    let k = 8 * r + o;
                    c[k] = codes[l][i] << 3 | o as u64;
                    if roles[l][i] == Role::Top {
                        role[k] = classify(&next[k], size[l + 1][k], target);
                    }
                }
                r += 1;
            }
            codes.push(c);
            roles.push(role);
        }
        Ok(Plan { size, codes, roles })
    }

    /// The block roots in leaf order, grouped: consecutive roots of the same level share a
    /// block while the group fits the `target`. Each group: the local level and the roots'
    /// indices in it.
    fn groups(&self, base_level: u32, target: u64) -> Vec<(u32, Vec<u32>)> {
        let key =
            |l: usize, i: usize| self.codes[l][i] << (3 * (MAX_LEVEL - base_level - l as u32));
        let mut roots: Vec<(u64, u32, u32)> = Vec::new();
        for (l, role) in self.roles.iter().enumerate() {
            for (i, r) in role.iter().enumerate() {
                if *r == Role::Root {
                    roots.push((key(l, i), l as u32, i as u32));
                }
            }
        }
        roots.sort_unstable();
        let mut groups: Vec<(u32, Vec<u32>)> = Vec::new();
        let mut group_size = 0u64;
        for &(_, l, i) in &roots {
            let s = self.size[l as usize][i as usize];
            match groups.last_mut() {
                Some((gl, g)) if *gl == l && group_size + s <= target => {
                    g.push(i);
                    group_size += s;
                }
                _ => {
                    groups.push((l, vec![i]));
                    group_size = s;
                }
            }
        }
        groups
    }

    /// The top tree's nodes: those whose role is the top's, then a link per block root (block
    /// ids from `first_block`, in group order).
    fn top_nodes(
        &self,
        tree: &UnitRef<'_>,
        base_level: u32,
        groups: &[(u32, Vec<u32>)],
        first_block: u32,
    ) -> Result<Vec<TopNode>, Error> {
        let codes = &self.codes;
        let mut top = Vec::new();
        for (l, role) in self.roles.iter().enumerate() {
            let nodes = level_nodes(tree, l)?;
            for (i, r) in role.iter().enumerate() {
                if *r != Role::Top {
                    continue;
                }
                let kind = match nodes[i].kind() {
                    Some(NodeKind::Internal) => TopKind::Internal,
                    Some(NodeKind::Empty { volume, shape }) => TopKind::Empty {
                        volume: *tree
                            .volumes
                            .get(volume as usize)
                            .ok_or_else(|| bad("an empty leaf's volume is out of range"))?,
                        shape,
                    },
                    _ => return Err(bad("a solid leaf in the top tree")),
                };
                top.push(TopNode {
                    level: base_level + l as u32,
                    code: codes[l][i],
                    kind,
                });
            }
        }
        for (g, (l, group)) in groups.iter().enumerate() {
            for (j, &i) in group.iter().enumerate() {
                top.push(TopNode {
                    level: base_level + l,
                    code: codes[*l as usize][i as usize],
                    kind: TopKind::Link {
                        block: first_block + g as u32,
                        root: j as u32,
                    },
                });
            }
        }
        Ok(top)
    }
}

/// Every node's estimated subtree bytes, by level, bottom-up: its record and share of a rank
/// word, plus its children's, an empty leaf's volume, a solid leaf's references and a
/// triangle per reference (an upper bound).
fn subtree_sizes(tree: &UnitRef<'_>) -> Result<Vec<Vec<u64>>, Error> {
    let nl = tree.levels.len();
    let mut size: Vec<Vec<u64>> = vec![Vec::new(); nl];
    for l in (0..nl).rev() {
        let nodes = level_nodes(tree, l)?;
        let mut v = Vec::with_capacity(nodes.len());
        let mut r = 0usize;
        for rec in nodes {
            // A record and its share of a rank word.
            let mut s = 10u64;
            match rec.kind() {
                Some(NodeKind::Internal) => {
                    let kids = size
                        .get(l + 1)
                        .and_then(|k| k.get(8 * r..8 * r + 8))
                        .ok_or_else(|| {
                            bad(format!("an internal node of level {l} has no children"))
                        })?;
                    s += kids.iter().sum::<u64>();
                    r += 1;
                }
                Some(NodeKind::Empty { .. }) => s += std::mem::size_of::<VolumeRecord>() as u64,
                Some(NodeKind::Solid {
                    first,
                    inline_count,
                    ..
                }) => {
                    let (refs, range) = leaf_refs(tree.refs, first, inline_count)
                        .ok_or_else(|| bad(format!("a leaf of level {l} has bad references")))?;
                    s += 4 * range.len() as u64
                        + std::mem::size_of::<TriRecord>() as u64 * refs.len() as u64;
                }
                _ => return Err(bad(format!("an invalid record on level {l}"))),
            }
            v.push(s);
        }
        size[l] = v;
    }
    Ok(size)
}

/// The records of the subtrees rooted at nodes `group` of local level `l0` (absolute level
/// `base_level + l0`), with local indices; with `clusters`, every solid leaf made a cluster
/// (spec §7.1) instead of a list of references.
fn extract(
    tree: &UnitRef<'_>,
    base_level: u32,
    l0: usize,
    group: &[u32],
    codes: &[Vec<u64>],
    clusters: Option<&ClusterGeometry>,
) -> Result<UnitParts, Error> {
    let local = block_nodes(tree, l0, group)?;

    // Leaves in leaf order: volumes, references and triangles renumbered.
    let mut leaves: Vec<(u64, u32, u32, u64)> = Vec::new();
    let mut records: Vec<Vec<NodeRecord>> = Vec::with_capacity(local.len());
    for (d, idx) in local.iter().enumerate() {
        let l = l0 + d;
        let nodes = level_nodes(tree, l)?;
        let mut recs = Vec::with_capacity(idx.len());
        for (j, &i) in idx.iter().enumerate() {
            let rec = nodes[i as usize];
            if rec.kind() != Some(NodeKind::Internal) {
                // Codes are absolute: the leaf's lowest corner on the full lattice (shifting by
                // the local level would drop the roots' own bits, which order a block of roots
                // below the whole tree's root).
                let shift = 3 * (MAX_LEVEL as usize - base_level as usize - l);
                let code = codes[l][i as usize];
                leaves.push((code << shift, d as u32, j as u32, code));
            }
            recs.push(rec);
        }
        records.push(recs);
    }
    leaves.sort_unstable();
    let mut parts = BlockLeaves::new(tree);
    for &(_, d, j, code) in &leaves {
        let rec = &mut records[d as usize][j as usize];
        *rec = match rec.kind() {
            Some(NodeKind::Empty { volume, shape }) => parts.empty(volume, shape)?,
            Some(NodeKind::Solid {
                first,
                inline_count,
                bounds,
            }) => {
                let (leaf, _) = leaf_refs(tree.refs, first, inline_count)
                    .ok_or_else(|| bad("a leaf's references are out of range"))?;
                match clusters {
                    Some(geometry) => {
                        let level = base_level + l0 as u32 + d;
                        let cell = geometry.widened_cell(level, code);
                        parts.cluster(leaf, cell, bounds)?
                    }
                    None => parts.list(leaf, bounds)?,
                }
            }
            _ => return Err(bad("an invalid leaf record")),
        };
    }
    let (levels, nodes, ranks) = lay_levels(records);
    Ok(UnitParts {
        levels,
        nodes,
        ranks,
        volumes: parts.volumes,
        refs: parts.refs,
        triangles: parts.triangles,
        cluster_nodes: parts.cluster_nodes,
        groups: parts.groups,
        ropes: Vec::new(),
        occluder_nodes: Vec::new(),
        occluders: Vec::new(),
    })
}

/// The indices in `tree` of the nodes of the subtrees rooted at nodes `group` of level `l0`,
/// by level from the roots down.
fn block_nodes(tree: &UnitRef<'_>, l0: usize, group: &[u32]) -> Result<Vec<Vec<u32>>, Error> {
    let mut local: Vec<Vec<u32>> = vec![group.to_vec()];
    loop {
        let d = local.len() - 1;
        let l = l0 + d;
        let nodes = level_nodes(tree, l)?;
        let ranks = level_ranks(tree, l)?;
        let mut next = Vec::new();
        for &i in &local[d] {
            if nodes[i as usize].kind() == Some(NodeKind::Internal) {
                let c = 8 * rank(ranks, i as usize) as u32;
                next.extend(c..c + 8);
            }
        }
        if next.is_empty() {
            return Ok(local);
        }
        local.push(next);
    }
}

/// A block's leaf parts as its leaves are taken in leaf order: the volumes, references and
/// triangles (or cluster nodes and groups) of the tree, renumbered within the block, each
/// stored once.
struct BlockLeaves<'t, 'a> {
    tree: &'t UnitRef<'a>,
    volumes: Vec<VolumeRecord>,
    /// The tree's volume indices to the block's.
    volume_map: HashMap<u32, u32>,
    refs: Vec<u32>,
    triangles: Vec<TriRecord>,
    /// The tree's triangle indices to the block's.
    tri_map: HashMap<u32, u32>,
    cluster_nodes: Vec<ClusterNode>,
    groups: Vec<TriGroup>,
    cluster_tris: Vec<ClusterTri>,
    /// One builder per block: its scratch buffers serve every cluster of the block.
    builder: ClusterBuilder,
}

impl<'t, 'a> BlockLeaves<'t, 'a> {
    fn new(tree: &'t UnitRef<'a>) -> Self {
        BlockLeaves {
            tree,
            volumes: Vec::new(),
            volume_map: HashMap::new(),
            refs: Vec::new(),
            triangles: Vec::new(),
            tri_map: HashMap::new(),
            cluster_nodes: Vec::new(),
            groups: Vec::new(),
            cluster_tris: Vec::new(),
            builder: ClusterBuilder::new(),
        }
    }

    /// The record of an empty leaf whose volume is the tree's `volume`.
    fn empty(&mut self, volume: u32, shape: VolumeShape) -> Result<NodeRecord, Error> {
        let v = match self.volume_map.get(&volume) {
            Some(&v) => v,
            None => {
                let b = *self
                    .tree
                    .volumes
                    .get(volume as usize)
                    .ok_or_else(|| bad("an empty leaf's volume is out of range"))?;
                self.volumes.push(b);
                let v = self.volumes.len() as u32 - 1;
                self.volume_map.insert(volume, v);
                v
            }
        };
        Ok(NodeRecord::empty(v, shape))
    }

    /// The record of a solid leaf made a cluster of the triangles the tree's references `leaf`
    /// name, clipped to its widened `cell` (world units).
    fn cluster(
        &mut self,
        leaf: &[u32],
        cell: ([f64; 3], [f64; 3]),
        bounds: LeafBounds,
    ) -> Result<NodeRecord, Error> {
        self.cluster_tris.clear();
        for &t in leaf {
            let r = self
                .tree
                .triangles
                .get(t as usize)
                .ok_or_else(|| bad("a reference is out of range"))?;
            self.cluster_tris.push(ClusterTri {
                v: r.v,
                prim: r.prim,
            });
        }
        let Ok(root) = u32::try_from(self.cluster_nodes.len()) else {
            return Err(bad("a block with more than 2^32 cluster nodes"));
        };
        self.builder
            .build_into(
                &self.cluster_tris,
                cell,
                &mut self.cluster_nodes,
                &mut self.groups,
            )
            .map_err(|e| bad(format!("building a cluster: {e}")))?;
        Ok(NodeRecord::cluster(root, bounds))
    }

    /// The record of a solid leaf holding the tree's references `leaf` as a list of the
    /// block's (with a count word before more than [`MAX_INLINE_REFS`]), sorted.
    fn list(&mut self, leaf: &[u32], bounds: LeafBounds) -> Result<NodeRecord, Error> {
        let refs = &mut self.refs;
        let payload = refs.len() as u32;
        if leaf.len() > MAX_INLINE_REFS as usize {
            refs.push(leaf.len() as u32);
        }
        let start = refs.len();
        for &t in leaf {
            let local = match self.tri_map.get(&t) {
                Some(&x) => x,
                None => {
                    let r = *self
                        .tree
                        .triangles
                        .get(t as usize)
                        .ok_or_else(|| bad("a reference is out of range"))?;
                    self.triangles.push(r);
                    let x = self.triangles.len() as u32 - 1;
                    self.tri_map.insert(t, x);
                    x
                }
            };
            refs.push(local);
        }
        refs[start..].sort_unstable();
        Ok(NodeRecord::solid(payload, leaf.len() as u32, bounds))
    }
}

/// The level table, node records and rank words of levels given record by record.
fn lay_levels(records: Vec<Vec<NodeRecord>>) -> (Vec<LevelEntry>, Vec<NodeRecord>, Vec<RankWord>) {
    let mut levels = Vec::with_capacity(records.len());
    let mut nodes = Vec::with_capacity(records.iter().map(Vec::len).sum());
    let mut ranks = Vec::new();
    for recs in records {
        let (words, internal_count) = rank_words(recs.iter().map(|r| r.is_internal()));
        levels.push(LevelEntry {
            node_count: recs.len() as u64,
            internal_count,
            node_start: nodes.len() as u64,
            rank_start: ranks.len() as u64,
        });
        ranks.extend(words);
        nodes.extend(recs);
    }
    (levels, nodes, ranks)
}

/// Lays the top tree out from its nodes, in any order: sorted by level and Morton code, checked
/// to form a tree from the root (every internal node has exactly its 8 children), empty leaves'
/// volumes numbered in leaf order without duplicates.
pub fn assemble_top(mut nodes: Vec<TopNode>) -> Result<UnitParts, Error> {
    nodes.sort_unstable_by_key(|n| (n.level, n.code));
    let mut by_level: Vec<&[TopNode]> = Vec::new();
    let mut rest: &[TopNode] = &nodes;
    while let Some(first) = rest.first() {
        if first.level as usize != by_level.len() {
            return Err(bad(format!("the top tree has no level {}", by_level.len())));
        }
        let n = rest.iter().take_while(|x| x.level == first.level).count();
        by_level.push(&rest[..n]);
        rest = &rest[n..];
    }
    if by_level.first().map(|l| l.len()) != Some(1) || nodes[0].code != 0 {
        return Err(bad("the top tree has no single root"));
    }
    for l in 0..by_level.len() {
        let expected = by_level[l]
            .iter()
            .filter(|n| n.kind == TopKind::Internal)
            .flat_map(|n| (0..8).map(move |o| n.code << 3 | o));
        let actual = by_level.get(l + 1).copied().unwrap_or(&[]);
        if !expected.eq(actual.iter().map(|n| n.code)) {
            return Err(bad(format!(
                "the top tree's level {} is not the children of level {l}",
                l + 1
            )));
        }
    }
    let mut leaves: Vec<(u64, usize, usize)> = Vec::new();
    for (l, lv) in by_level.iter().enumerate() {
        for (i, n) in lv.iter().enumerate() {
            if matches!(n.kind, TopKind::Empty { .. }) {
                leaves.push((n.code << (3 * (MAX_LEVEL as usize - l)), l, i));
            }
        }
    }
    leaves.sort_unstable();
    let mut volumes = Vec::new();
    let mut index: HashMap<VolumeRecord, u32> = HashMap::new();
    let mut vol_of: HashMap<(usize, usize), u32> = HashMap::new();
    for &(_, l, i) in &leaves {
        if let TopKind::Empty { volume, .. } = by_level[l][i].kind {
            let next = volumes.len() as u32;
            let v = *index.entry(volume).or_insert_with(|| {
                volumes.push(volume);
                next
            });
            vol_of.insert((l, i), v);
        }
    }
    let records: Vec<Vec<NodeRecord>> = by_level
        .iter()
        .enumerate()
        .map(|(l, lv)| {
            lv.iter()
                .enumerate()
                .map(|(i, n)| match n.kind {
                    TopKind::Internal => NodeRecord::internal(),
                    TopKind::Empty { shape, .. } => NodeRecord::empty(vol_of[&(l, i)], shape),
                    TopKind::Link { block, root } => NodeRecord::link(block, root),
                })
                .collect()
        })
        .collect();
    let (levels, nodes, ranks) = lay_levels(records);
    Ok(UnitParts {
        levels,
        nodes,
        ranks,
        volumes,
        refs: Vec::new(),
        triangles: Vec::new(),
        cluster_nodes: Vec::new(),
        groups: Vec::new(),
        ropes: Vec::new(),
        occluder_nodes: Vec::new(),
        occluders: Vec::new(),
    })
}
