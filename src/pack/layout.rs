//! Laying the built tree out as file records (format-spec §4-§7): node records per level in
//! Morton order, the rank directory, the volume table, references and triangles in leaf
//! (depth-first, i.e. global Morton) order, and each solid leaf's tight bounds.

use std::collections::HashMap;

use rayon::prelude::*;

use super::merge;
use super::subdivide::{BuildLevel, BuildNode, LatticeTri};
use crate::error::Error;
use crate::mapping::morton::{MAX_LEVEL, cell_origin, cell_size};
use crate::mapping::rank_words;
use crate::physical::format::{
    CELL_MARGIN, LeafBounds, LevelEntry, MAX_INLINE_REFS, NodeRecord, TriRecord, VolumeRecord,
    VolumeShape,
};
use crate::physical::writer::UnitParts;

/// A laid-out tree and its leaf counts.
pub(super) struct Laid {
    pub(super) tree: UnitParts,
    pub(super) empty_leaves: u64,
    pub(super) solid_leaves: u64,
}

/// Lays the tree out as file records: node records per level, the rank directory, the volume
/// table, references and triangles in leaf (depth-first, i.e. global Morton) order.
pub(super) fn layout(
    levels: &[BuildLevel],
    boxes: &merge::LeafBoxes,
    records: &[TriRecord],
    lattice: &[LatticeTri],
) -> Result<Laid, Error> {
    layout_from(levels, 0, boxes, records, lattice)
}

/// [`layout`] for a subtree whose `levels[0]` is absolute level `base`.
pub(super) fn layout_from(
    levels: &[BuildLevel],
    base: u32,
    boxes: &merge::LeafBoxes,
    records: &[TriRecord],
    lattice: &[LatticeTri],
) -> Result<Laid, Error> {
    let leaves = leaf_order(levels, base);
    let bounds = solid_bounds(levels, base, lattice);
    let parts = LeafParts::number(levels, &leaves, boxes, records)?;

    // Node records level by level, and the rank directory of each level.
    let mut level_entries = Vec::with_capacity(levels.len());
    let mut nodes = Vec::new();
    let mut ranks = Vec::new();
    let (mut empty_leaves, mut solid_leaves) = (0u64, 0u64);
    for (l, lv) in levels.iter().enumerate() {
        let start = nodes.len();
        nodes.extend(lv.nodes.iter().enumerate().map(|(i, n)| match n {
            BuildNode::Internal => NodeRecord::internal(),
            BuildNode::Leaf(t) if t.is_empty() => {
                empty_leaves += 1;
                NodeRecord::empty(parts.payload[l][i], parts.shapes[l][i])
            }
            BuildNode::Leaf(t) => {
                solid_leaves += 1;
                NodeRecord::solid(parts.payload[l][i], t.len() as u32, bounds[l][i])
            }
        }));
        let (words, internal_count) = rank_words(nodes[start..].iter().map(|r| r.is_internal()));
        level_entries.push(LevelEntry {
            node_count: lv.nodes.len() as u64,
            internal_count,
            node_start: start as u64,
            rank_start: ranks.len() as u64,
        });
        ranks.extend(words);
    }

    Ok(Laid {
        tree: UnitParts {
            levels: level_entries,
            nodes,
            ranks,
            volumes: parts.volumes,
            refs: parts.refs,
            triangles: parts.triangles,
            cluster_nodes: Vec::new(),
            groups: Vec::new(),
            ropes: Vec::new(),
            occluder_nodes: Vec::new(),
            occluders: Vec::new(),
        },
        empty_leaves,
        solid_leaves,
    })
}

/// All leaves as (key, level, index in the level), ordered by the key, the Morton code of
/// their lowest lattice corner: depth-first order, so the leaves (and with them references
/// and triangles) of a subtree are contiguous.
fn leaf_order(levels: &[BuildLevel], base: u32) -> Vec<(u64, u32, u32)> {
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
    leaves
}

/// Tight bounds of every solid leaf (spec §4.2), by level and index, in parallel; other nodes
/// get [`LeafBounds::FULL`].
fn solid_bounds(levels: &[BuildLevel], base: u32, lattice: &[LatticeTri]) -> Vec<Vec<LeafBounds>> {
    levels
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
        .collect()
}

/// The leaves' parts, numbered in leaf order: each empty leaf's volume (index in the volume
/// table, each distinct box stored once) and shape, each solid leaf's first reference word;
/// the references and the triangles they name (each stored once, in order of first use).
struct LeafParts {
    /// A leaf's payload (volume index or first reference word), by level and index.
    payload: Vec<Vec<u32>>,
    shapes: Vec<Vec<VolumeShape>>,
    refs: Vec<u32>,
    triangles: Vec<TriRecord>,
    volumes: Vec<VolumeRecord>,
}

impl LeafParts {
    /// Numbers the parts of `leaves` (in leaf order), whose empty leaves' merged volumes
    /// `boxes` gives and whose solid leaves reference `records`.
    fn number(
        levels: &[BuildLevel],
        leaves: &[(u64, u32, u32)],
        boxes: &merge::LeafBoxes,
        records: &[TriRecord],
    ) -> Result<LeafParts, Error> {
        let too_many = |what: &str, n: usize| {
            Error::Build(format!(
                "{n} {what}: more than this version's 32-bit indices can address; raise --leaf-size \
                 or lower --max-depth"
            ))
        };
        let mut parts = LeafParts {
            payload: levels.iter().map(|lv| vec![0; lv.nodes.len()]).collect(),
            shapes: levels
                .iter()
                .map(|lv| vec![VolumeShape { level: 0, axes: 0 }; lv.nodes.len()])
                .collect(),
            refs: Vec::new(),
            triangles: Vec::with_capacity(records.len()),
            volumes: Vec::new(),
        };
        let mut new_index = vec![u32::MAX; records.len()];
        let mut volume_index: HashMap<VolumeRecord, u32> = HashMap::new();
        let (refs, triangles, volumes) =
            (&mut parts.refs, &mut parts.triangles, &mut parts.volumes);
        for &(_, l, i) in leaves {
            let (l, i) = (l as usize, i as usize);
            let BuildNode::Leaf(tris) = &levels[l].nodes[i] else {
                continue;
            };
            if tris.is_empty() {
                let merged = boxes[l][i]
                    .ok_or_else(|| Error::Build("empty leaf without a volume".into()))?;
                let b = merged.volume;
                let next = volumes.len();
                let v = *volume_index.entry(b).or_insert_with(|| {
                    volumes.push(b);
                    next as u32
                });
                if volumes.len() > u32::MAX as usize {
                    return Err(too_many("volumes", volumes.len()));
                }
                parts.payload[l][i] = v;
                parts.shapes[l][i] = merged.shape;
            } else {
                if refs.len() + tris.len() + 1 > u32::MAX as usize {
                    return Err(too_many("triangle references", refs.len() + tris.len()));
                }
                parts.payload[l][i] = refs.len() as u32;
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
        Ok(parts)
    }
}

/// The tight bounds of a solid leaf: the box of the parts of its triangles inside its cell
/// (enlarged by the cell margin, like the cell the triangles were assigned to), in sixteenths of
/// the cell, rounded outward.
fn leaf_bounds(lattice: &[LatticeTri], tris: &[u32], code: u64, level: u32) -> LeafBounds {
    let size = cell_size(level) as f64;
    let origin = cell_origin(code, level).map(|c| c as f64);
    let m = CELL_MARGIN;
    let lo: [f64; 3] = std::array::from_fn(|k| origin[k] - m);
    let hi: [f64; 3] = std::array::from_fn(|k| origin[k] + size + m);
    let mut blo = [f64::INFINITY; 3];
    let mut bhi = [f64::NEG_INFINITY; 3];
    for &t in tris {
        let tri = &lattice[t as usize];
        // The exact clip (`geom::tribox::clipped_bounds`; a triangle wholly inside is its own
        // bounds); if rounding
        // leaves nothing of a triangle the exact test kept, fall back to its bounding box (still
        // conservative).
        let inside = (0..3).all(|k| tri.lo[k] >= lo[k] && tri.hi[k] <= hi[k]);
        let clipped = if inside {
            Some((tri.lo, tri.hi))
        } else {
            crate::geom::tribox::clipped_bounds(&tri.v, lo, hi)
        };
        let (a, b) = clipped.unwrap_or((
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
