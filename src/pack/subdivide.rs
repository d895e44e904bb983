//! Octree subdivision (OAVM paper §2.1): the root cube is split into 8 children while a node
//! holds more than `K` triangles and is shallower than `D`; a triangle goes to every child it
//! really overlaps, decided by the exact triangle–box test, not to every child its bounding box
//! touches.
//!
//! The tree is built one level at a time: the children of a level's internal nodes, taken in
//! order and 8 at a time in octant order, *are* the next level in Morton order (format-spec
//! §4), so no sorting is needed and the result does not depend on how rayon splits the work.
//!
//! Public for the classic octree of `oavm-compare` (`crates/oavm-compare`), which calls
//! [`subdivide`] to have exactly OAVM's subdivision (the same `K`, `D` and triangle–cell
//! test), so that the comparison measures what merging and the pointerless mapping change, not
//! a different tree.

use rayon::prelude::*;

use crate::geom::tribox::triangle_overlaps_box;
use crate::mapping::morton::{MAX_LEVEL, cell_size};
use crate::physical::format::CELL_MARGIN;

/// A triangle in lattice coordinates, with its bounding box.
#[derive(Clone, Copy, Debug)]
pub struct LatticeTri {
    pub v: [[f64; 3]; 3],
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}
impl LatticeTri {
    pub fn new(v: [[f64; 3]; 3]) -> LatticeTri {
        let lo = std::array::from_fn(|k| v[0][k].min(v[1][k]).min(v[2][k]));
        let hi = std::array::from_fn(|k| v[0][k].max(v[1][k]).max(v[2][k]));
        LatticeTri { v, lo, hi }
    }
}

/// The mapping from world coordinates to the lattice of the root cube (spec §1, §2).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lattice {
    pub(crate) root_min: [f64; 3],
    pub(crate) root_size: f64,
    /// Lattice cells per world unit.
    pub(crate) scale: f64,
}

impl Lattice {
    /// The lattice of the root cube fitted to the bounds `lo..hi` (spec §2).
    pub(crate) fn fit(lo: [f32; 3], hi: [f32; 3]) -> Result<Lattice, crate::error::Error> {
        let (root_min, root_size) = crate::physical::format::root_cube(lo, hi);
        super::check_scale(root_size)?;
        Ok(Lattice::of_root(root_min, root_size))
    }

    /// The lattice of a given root cube (a file's).
    pub(crate) fn of_root(root_min: [f64; 3], root_size: f64) -> Lattice {
        Lattice {
            root_min,
            root_size,
            scale: crate::physical::format::LATTICE_SIZE as f64 / root_size,
        }
    }

    /// A triangle's corners on the lattice, as the builder maps them.
    pub(crate) fn map(&self, v: &[[f32; 3]; 3]) -> LatticeTri {
        LatticeTri::new(std::array::from_fn(|i| {
            std::array::from_fn(|k| (v[i][k] as f64 - self.root_min[k]) * self.scale)
        }))
    }
}

/// Whether `t` overlaps the cell of `code` at `level`, widened by the cell margin (spec §6).
pub(crate) fn overlaps_cell(t: &LatticeTri, code: u64, level: u32) -> bool {
    let s = crate::mapping::morton::cell_size(level) as f64;
    let o = crate::mapping::morton::cell_origin(code, level);
    let c: [f64; 3] = std::array::from_fn(|k| o[k] as f64 + s * 0.5);
    let half = [s * 0.5 + CELL_MARGIN; 3];
    // A triangle whose box lies inside the widened cell overlaps it.
    let inside = (0..3).all(|k| t.lo[k] >= c[k] - half[k] && t.hi[k] <= c[k] + half[k]);
    inside || triangle_overlaps_box(&t.v, c, half)
}

/// The cell of `code` at `level` widened by the cell margin (spec §6), low and high corners
/// in lattice units: the box [`overlaps_cell`] tests against.
pub(crate) fn widened_cell(code: u64, level: u32) -> ([f64; 3], [f64; 3]) {
    let s = crate::mapping::morton::cell_size(level) as f64;
    let o = crate::mapping::morton::cell_origin(code, level);
    (
        std::array::from_fn(|k| o[k] as f64 - CELL_MARGIN),
        std::array::from_fn(|k| o[k] as f64 + s + CELL_MARGIN),
    )
}

/// Whether `t`'s bounding box misses `cell` (a [`widened_cell`]) by more than rounding could
/// account for: then [`overlaps_cell`] is false too (its box-axis test separates them), and
/// the exact test can be skipped. Conservative: `false` says nothing. A walk that tests the
/// eight children of a node, of which a small triangle overlaps one or two, rejects the rest
/// with six comparisons instead of the triangle-box test.
#[inline]
pub(crate) fn box_misses(t: &LatticeTri, (lo, hi): &([f64; 3], [f64; 3])) -> bool {
    // Lattice coordinates are below 2^21 (and the slack far above f64's rounding there, about
    // 5e-10), so a gap larger than it is a real gap.
    const SLACK: f64 = 1e-6;
    (0..3).any(|k| t.lo[k] > hi[k] + SLACK || t.hi[k] < lo[k] - SLACK)
}

/// A node of the tree being built.
pub enum BuildNode {
    Internal,
    /// A leaf and the triangles (indices into the build's triangle list) it references; empty
    /// for an empty leaf.
    Leaf(Vec<u32>),
}

/// One level of the tree: nodes in Morton order, each with its code.
pub struct BuildLevel {
    pub codes: Vec<u64>,
    pub nodes: Vec<BuildNode>,
}

/// What happens to a node of the level being built.
enum Decision {
    Leaf(u64, Vec<u32>),
    Split(Box<[Pending; 8]>),
}

struct Pending {
    code: u64,
    tris: Vec<u32>,
    /// Triangle counts of the parent and grandparent (`u32::MAX` above the root).
    parent_count: u32,
    grand_count: u32,
}

/// Parameters of subdivision.
#[derive(Clone, Copy, Debug)]
pub struct SubdivideParams {
    pub max_depth: u32,
    pub leaf_size: u32,
}

/// Builds the levels of the octree over `tris`. `on_level` is told each finished level's node
/// count (for progress reporting).
pub fn subdivide(
    tris: &[LatticeTri],
    params: SubdivideParams,
    on_level: &(dyn Fn(u32, usize) + Sync),
) -> Vec<BuildLevel> {
    subdivide_from(tris, 0, 0, params, on_level)
}

/// Builds the subtree of node `code` at level `base` over `tris` (the triangles that overlap
/// the node's widened cell): `levels[i]` is absolute level `base + i`, codes are absolute. The
/// node is treated as having no ancestors (for the rule that stops where subdivision separates
/// nothing). Used by the streaming builder, one chunk of the tree at a time.
pub fn subdivide_from(
    tris: &[LatticeTri],
    base: u32,
    code: u64,
    params: SubdivideParams,
    on_level: &(dyn Fn(u32, usize) + Sync),
) -> Vec<BuildLevel> {
    let max_depth = params.max_depth.min(MAX_LEVEL);
    let mut levels = Vec::new();
    let mut current = vec![Pending {
        code,
        tris: (0..tris.len() as u32).collect(),
        parent_count: u32::MAX,
        grand_count: u32::MAX,
    }];
    for level in base.min(max_depth)..=max_depth {
        let split: Vec<Decision> = current
            .into_par_iter()
            .map(|p| {
                let count = p.tris.len() as u32;
                // Stop where the leaf is small enough, at the depth limit, or where two
                // subdivisions in a row separated nothing (triangles that all meet in one
                // point or line, or duplicates): further splits would only multiply references.
                let stuck = count == p.parent_count && count == p.grand_count;
                if count <= params.leaf_size || level == max_depth || stuck {
                    Decision::Leaf(p.code, p.tris)
                } else {
                    Decision::Split(Box::new(split_node(tris, &p, level)))
                }
            })
            .collect();
        let mut codes = Vec::with_capacity(split.len());
        let mut nodes = Vec::with_capacity(split.len());
        let mut next = Vec::new();
        for s in split {
            match s {
                Decision::Split(children) => {
                    codes.push(children[0].code >> 3);
                    nodes.push(BuildNode::Internal);
                    next.extend(*children);
                }
                Decision::Leaf(code, t) => {
                    codes.push(code);
                    nodes.push(BuildNode::Leaf(t));
                }
            }
        }
        on_level(level, nodes.len());
        levels.push(BuildLevel { codes, nodes });
        if next.is_empty() {
            break;
        }
        current = next;
    }
    levels
}

/// Splits node `p` of `level` into its 8 children.
fn split_node(tris: &[LatticeTri], p: &Pending, level: u32) -> [Pending; 8] {
    let half = cell_size(level + 1) as f64;
    let origin = crate::mapping::morton::cell_origin(p.code, level).map(|c| c as f64);
    let mid: [f64; 3] = std::array::from_fn(|k| origin[k] + half);

    // Large nodes are split in parallel chunks, concatenated in chunk order (deterministic).
    const CHUNK: usize = 16 * 1024;
    let lists: [Vec<u32>; 8] = if p.tris.len() > 2 * CHUNK {
        let parts: Vec<[Vec<u32>; 8]> = p
            .tris
            .par_chunks(CHUNK)
            .map(|chunk| assign(tris, chunk, origin, mid, half))
            .collect();
        std::array::from_fn(|o| {
            let mut v = Vec::with_capacity(parts.iter().map(|p| p[o].len()).sum());
            for part in &parts {
                v.extend_from_slice(&part[o]);
            }
            v
        })
    } else {
        assign(tris, &p.tris, origin, mid, half)
    };
    let count = p.tris.len() as u32;
    let mut lists = lists.into_iter();
    std::array::from_fn(|o| Pending {
        code: p.code << 3 | o as u64,
        tris: lists.next().unwrap_or_default(),
        parent_count: count,
        grand_count: p.parent_count,
    })
}

/// Distributes `ids` over the 8 children of the cell with lowest corner `origin`, centre `mid`
/// and child edge `half`.
fn assign(
    tris: &[LatticeTri],
    ids: &[u32],
    origin: [f64; 3],
    mid: [f64; 3],
    half: f64,
) -> [Vec<u32>; 8] {
    let mut out: [Vec<u32>; 8] = Default::default();
    // Per axis: may the triangle reach the lower child (side 0), the upper child (side 1)? A
    // triangle on one side only is certain to overlap the child there, given it overlaps the
    // parent; only triangles straddling a mid-plane need the exact test. As bits: bit k of
    // `lower` (`upper`) says whether the lower (upper) side of axis `k` may be reached.
    //
    // In two passes over a run of triangles: the first only reads boxes and computes these
    // bits, with no branch, so that the processor has many of the triangles' cache misses in
    // flight at once (a node's triangles are scattered over the array); the second sends them.
    const RUN: usize = 64;
    for run in ids.chunks(RUN) {
        let mut sides = [(0usize, 0usize); RUN];
        for (s, &id) in sides.iter_mut().zip(run) {
            let t = &tris[id as usize];
            let (mut lower, mut upper) = (0usize, 0usize);
            for (k, ((&lo, &hi), &m)) in t.lo.iter().zip(&t.hi).zip(&mid).enumerate() {
                lower |= ((lo <= m + CELL_MARGIN) as usize) << k;
                upper |= ((hi >= m - CELL_MARGIN) as usize) << k;
            }
            *s = (lower, upper);
        }
        for (&(lower, upper), &id) in sides.iter().zip(run) {
            if lower & upper == 0 {
                // One child at most: octant bit k is 1 where only the upper side is reached (a
                // triangle that reaches neither side of an axis reaches no child).
                if lower | upper == 0b111 {
                    out[upper].push(id);
                }
                continue;
            }
            let t = &tris[id as usize];
            for (o, list) in out.iter_mut().enumerate() {
                // Octant `o` is reached where every axis reaches the side its bit names.
                if (upper & o) | (lower & !o & 0b111) != 0b111 {
                    continue;
                }
                let bit = |k: usize| (o >> k) & 1;
                let c: [f64; 3] = std::array::from_fn(|k| origin[k] + half * (bit(k) as f64 + 0.5));
                let h = [half * 0.5 + CELL_MARGIN; 3];
                if triangle_overlaps_box(&t.v, c, h) {
                    list.push(id);
                }
            }
        }
    }
    out
}
