//! Bounds of the top tree's internal nodes, derived once per opened file from its link bounds
//! (spec §8.1), so that the top-down traversal of a file of clusters culls an internal node of
//! the top tree the way it culls a link: a ray that misses the box of every solid leaf below a
//! node skips the node, instead of descending through cells that hold nothing it can hit.
//!
//! The file stores bounds for links only (all zero for other nodes). An internal node's box is
//! the union of its children's: a link's box (widened by the cell margin, as the tracer tests
//! it), an internal child's union; empty leaves add nothing. Made on first use, not at open
//! (open stays O(1)): one visit of the top tree, 48 bytes per top-tree node record.
//!
//! Conservative whatever the bytes (the link bounds section is not validated at open): where
//! the computation cannot read what it needs (a link bounds record past the section, a rank
//! pointing past the next level, a level deeper than the lattice, a node that is neither
//! internal, empty nor a link), the node's box is its whole cell widened by the margin, which
//! contains everything the tracer may look for below it. A box never culls more than the link
//! bounds below it would: each is contained in the union.

use crate::mapping::TreeMap;
use crate::mapping::morton::{self, MAX_LEVEL};
use crate::physical::format::{CELL_MARGIN, KIND_EMPTY, KIND_INTERNAL, KIND_LINK, LinkBounds};

/// A box in lattice units, `[lo, hi]` per axis.
pub(crate) type LatticeBox = ([f64; 3], [f64; 3]);

/// The box of every top-tree node record, by record index (`node_start(level) + index`):
/// for a link, its link bounds widened by the margin; for an internal node, the union of its
/// children's boxes; for an empty leaf, an inverted box (never read by the tracer, which skips
/// empty leaves by their kind).
pub(crate) fn top_bounds(top: &TreeMap<'_>, link_bounds: &[LinkBounds]) -> Vec<LatticeBox> {
    let total = (0..top.level_count())
        .filter_map(|l| top.levels().get(l as usize))
        .map(|e| e.node_count)
        .sum::<u64>();
    // The top tree was validated at open: its records are in the file, so this is bounded by
    // the file's size.
    let mut boxes = vec![EMPTY; usize::try_from(total).unwrap_or(0)];
    if top.level_count() > 0 {
        visit(top, link_bounds, &mut boxes, 0, 0, [0; 3]);
    }
    boxes
}

const EMPTY: LatticeBox = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);

/// The cell `lo` (edge `size`) widened by the margin.
fn whole_cell(lo: [u32; 3], size: u32) -> LatticeBox {
    (
        lo.map(|c| c as f64 - CELL_MARGIN),
        lo.map(|c| c as f64 + size as f64 + CELL_MARGIN),
    )
}

fn union(a: LatticeBox, b: LatticeBox) -> LatticeBox {
    (
        std::array::from_fn(|k| a.0[k].min(b.0[k])),
        std::array::from_fn(|k| a.1[k].max(b.1[k])),
    )
}

/// The box of node `idx` of `level` (cell `lo`), stored in `boxes` and returned. Recursion is
/// at most `MAX_LEVEL` deep; each node of the tree is visited once.
fn visit(
    top: &TreeMap<'_>,
    link_bounds: &[LinkBounds],
    boxes: &mut [LatticeBox],
    level: u32,
    idx: u64,
    lo: [u32; 3],
) -> LatticeBox {
    let size = morton::cell_size(level);
    let at = top.node_start(level).saturating_add(idx);
    let Ok(rec) = top.node(level, idx) else {
        return whole_cell(lo, size);
    };
    let b = match rec.kind_bits() {
        KIND_EMPTY => EMPTY,
        KIND_LINK => match usize::try_from(at).ok().and_then(|i| link_bounds.get(i)) {
            Some(lb) => {
                let s256 = size as f64 / 256.0;
                (
                    std::array::from_fn(|a| lo[a] as f64 + lb.lo[a] as f64 * s256 - CELL_MARGIN),
                    std::array::from_fn(|a| {
                        lo[a] as f64 + (lb.hi[a] as f64 + 1.0) * s256 + CELL_MARGIN
                    }),
                )
            }
            None => whole_cell(lo, size),
        },
        KIND_INTERNAL if level < MAX_LEVEL => match top.children(level, idx) {
            Some((first, _, _)) => {
                let half = size / 2;
                (0..8u32).fold(EMPTY, |u, o| {
                    let clo = std::array::from_fn(|a| lo[a] + half * ((o >> a) & 1));
                    let c = visit(top, link_bounds, boxes, level + 1, first + o as u64, clo);
                    union(u, c)
                })
            }
            None => whole_cell(lo, size),
        },
        _ => whole_cell(lo, size),
    };
    if let Some(slot) = usize::try_from(at).ok().and_then(|i| boxes.get_mut(i)) {
        *slot = b;
    }
    b
}
