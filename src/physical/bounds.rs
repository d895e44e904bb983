//! Link bounds (format-spec §8.1): the box, inside a block root's cell, of the tight bounds of
//! every solid leaf below that root. The writer computes them from each block's own records and
//! stores them beside the top tree's links, so a tracer can pass a block a ray cannot hit
//! without paging it in; `verify` computes them again from the blocks and compares.

use super::format::{LevelEntry, LinkBounds, NodeKind, NodeRecord};

/// A box inside a node's cell, as fractions of the cell (`0..=1` per axis). The fractions are
/// dyadic (sixteenths of a leaf's cell, halved once per level up), so f64 holds them exactly.
type Frac = ([f64; 3], [f64; 3]);

fn union(a: Option<Frac>, b: Frac) -> Frac {
    match a {
        None => b,
        Some((lo, hi)) => (
            std::array::from_fn(|k| lo[k].min(b.0[k])),
            std::array::from_fn(|k| hi[k].max(b.1[k])),
        ),
    }
}

/// The bounds of each root (level 0) of a unit whose level table is `levels` and records are
/// `nodes`, in root order. A root with no solid leaf below it (which a valid file does not
/// have) gets the whole cell. `Err` names a record that is not a block's (a link, invalid bits)
/// or a level table that does not match the records; the work is linear in the records.
pub fn root_bounds(
    levels: &[LevelEntry],
    nodes: &[NodeRecord],
) -> Result<Vec<LinkBounds>, &'static str> {
    // From the deepest level up: the box of each node's solid leaves, relative to its cell.
    let mut below: Vec<Option<Frac>> = Vec::new();
    for e in levels.iter().rev() {
        let start = usize::try_from(e.node_start).map_err(|_| "level past the records")?;
        let count = usize::try_from(e.node_count).map_err(|_| "level past the records")?;
        let recs = start
            .checked_add(count)
            .and_then(|end| nodes.get(start..end))
            .ok_or("level past the records")?;
        let mut here: Vec<Option<Frac>> = Vec::with_capacity(recs.len());
        let mut rank = 0usize;
        for rec in recs {
            here.push(match rec.kind() {
                Some(NodeKind::Empty { .. }) => None,
                Some(NodeKind::Solid { bounds, .. }) => Some((
                    bounds.lo.map(|v| v as f64 / 16.0),
                    bounds.hi.map(|v| (v as f64 + 1.0) / 16.0),
                )),
                Some(NodeKind::Internal) => {
                    let children = below
                        .get(8 * rank..8 * rank + 8)
                        .ok_or("internal node without children")?;
                    rank += 1;
                    let mut acc = None;
                    for (o, c) in children.iter().enumerate() {
                        if let Some((lo, hi)) = c {
                            let off: [f64; 3] = std::array::from_fn(|k| ((o >> k) & 1) as f64);
                            let child = (
                                std::array::from_fn(|k| (off[k] + lo[k]) / 2.0),
                                std::array::from_fn(|k| (off[k] + hi[k]) / 2.0),
                            );
                            acc = Some(union(acc, child));
                        }
                    }
                    acc
                }
                Some(NodeKind::Link { .. }) | None => return Err("invalid node record in a block"),
            });
        }
        if 8 * rank != below.len() {
            return Err("internal nodes do not match the next level");
        }
        below = here;
    }
    Ok(below
        .into_iter()
        .map(|b| b.map_or(LinkBounds::FULL, |(lo, hi)| LinkBounds::enclosing(lo, hi)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physical::format::{LeafBounds, VolumeShape};

    fn level(node_count: u64, internal_count: u64, node_start: u64) -> LevelEntry {
        LevelEntry {
            node_count,
            internal_count,
            node_start,
            rank_start: 0,
        }
    }

    #[test]
    fn a_solid_root_keeps_its_leaf_bounds_in_256ths() {
        let b = LeafBounds {
            lo: [1, 0, 15],
            hi: [2, 15, 15],
        };
        let nodes = [NodeRecord::solid(0, 1, b)];
        let got = root_bounds(&[level(1, 0, 0)], &nodes).unwrap();
        assert_eq!(got[0].lo, [16, 0, 240]);
        assert_eq!(got[0].hi, [47, 255, 255]);
    }

    #[test]
    fn children_are_placed_by_octant_and_empty_ones_add_nothing() {
        // One internal root; its child in octant 7 (x, y, z high) is solid with full bounds,
        // its child in octant 0 solid in its lowest sixteenth, the rest empty.
        let corner = LeafBounds {
            lo: [0; 3],
            hi: [0; 3],
        };
        let mut nodes = vec![NodeRecord::internal()];
        for o in 0..8 {
            nodes.push(match o {
                0 => NodeRecord::solid(0, 1, corner),
                7 => NodeRecord::solid(1, 1, LeafBounds::FULL),
                _ => NodeRecord::empty(0, VolumeShape { level: 1, axes: 0 }),
            });
        }
        let got = root_bounds(&[level(1, 1, 0), level(8, 0, 1)], &nodes).unwrap();
        assert_eq!(got[0].lo, [0; 3]);
        assert_eq!(got[0].hi, [255; 3]);
        // Without the octant-7 child, only the corner's 1/32 of the root remains: 8 256ths.
        nodes[8] = NodeRecord::empty(0, VolumeShape { level: 1, axes: 0 });
        let got = root_bounds(&[level(1, 1, 0), level(8, 0, 1)], &nodes).unwrap();
        assert_eq!(got[0].lo, [0; 3]);
        assert_eq!(got[0].hi, [7; 3]);
    }

    #[test]
    fn bad_tables_are_errors_not_panics() {
        let nodes = [NodeRecord::internal()];
        assert!(root_bounds(&[level(1, 1, 0)], &nodes).is_err());
        assert!(root_bounds(&[level(5, 0, u64::MAX)], &nodes).is_err());
        let link = [NodeRecord::link(0, 0)];
        assert!(root_bounds(&[level(1, 0, 0)], &link).is_err());
    }
}
