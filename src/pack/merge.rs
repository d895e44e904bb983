//! Adaptive merging of empty nodes into larger empty volumes (OAVM paper §2.3).
//!
//! The paper's procedure, in its terms:
//!
//! 1. **Type-1 and type-2 nodes.** An internal node all of whose descendants are empty leaves is
//!    *type-1*: it is empty as a whole and is merged *upward* into its parent's level, where it
//!    counts as one empty child. An internal node with at least one non-empty descendant is
//!    *type-2*: upward merging stops there.
//! 2. **Same-parent merging.** Inside a type-2 node, the empty children (empty leaves and type-1
//!    children) are merged with their face-adjacent empty siblings. Each empty child `c` gets a
//!    3-bit *direction attribute* `attr[c]`: bit `a` is set when its sibling across axis `a`
//!    (octant `c ^ (1 << a)`) is empty too. Merges are decided by bitwise AND of attributes: `c`
//!    pairs with its neighbour along `a` if `attr[c] & (1 << a)`; it forms a 2x2 quad in the plane
//!    of axes `a`, `b` if moreover `attr[c] & attr[c ^ (1 << a)] & (1 << b)` (the diagonal
//!    sibling is empty).
//! 3. **Nothing is deleted.** Every empty leaf stays in its level's table and refers to its merged
//!    volume in the volume table; type-1 nodes stay internal nodes with their empty leaves.
//!
//! **Deviation: boxes only.** The paper's merged volume is the union of all connected empty
//! siblings, which can be non-convex (seven empty octants form an L-shaped solid), while its
//! Liang–Barsky clipping assumes a box: a ray leaving a non-convex volume's bounding box may have
//! crossed a non-empty sibling. We keep every merged volume an axis-aligned box: each empty child
//! refers to the *largest* box of empty siblings that contains it: a quad (preferring the planes
//! xy, xz, yz in that order) over a pair (x, y, z) over itself. Boxes of different children may
//! overlap; that is harmless, since a ray only ever clips the box of the leaf it is in and every
//! box is entirely empty. `format-spec.md` §5 states the same rule.

use crate::mapping::morton::{cell_origin, cell_size};
use crate::pack::subdivide::{BuildLevel, BuildNode};
use crate::physical::format::{VolumeRecord, VolumeShape};

/// An empty leaf's merged volume: its box, and its shape relative to the leaf.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Merged {
    pub volume: VolumeRecord,
    pub shape: VolumeShape,
}

/// For every level, for every node: the volume an empty leaf refers to (`None` for other nodes).
pub type LeafBoxes = Vec<Vec<Option<Merged>>>;

/// The box of node `code` at `level`.
pub fn cell_box(code: u64, level: u32) -> VolumeRecord {
    let lo = cell_origin(code, level);
    let s = cell_size(level);
    VolumeRecord {
        lo,
        hi: lo.map(|c| c + s),
    }
}

/// Assigns a box to every empty leaf: its merged volume when `merge` is set, else its own cell.
pub fn merge_volumes(levels: &[BuildLevel], merge: bool) -> LeafBoxes {
    merge_volumes_from(levels, 0, merge)
}

/// [`merge_volumes`] for a subtree whose `levels[0]` is absolute level `base` (one node). An
/// all-empty subtree's box is its root's cell (the whole lattice for the whole tree).
pub fn merge_volumes_from(levels: &[BuildLevel], base: u32, merge: bool) -> LeafBoxes {
    let is_empty_leaf = |n: &BuildNode| matches!(n, BuildNode::Leaf(t) if t.is_empty());
    if !merge {
        return levels
            .iter()
            .enumerate()
            .map(|(l, lv)| {
                lv.nodes
                    .iter()
                    .zip(&lv.codes)
                    .map(|(n, &code)| {
                        is_empty_leaf(n).then(|| Merged {
                            volume: cell_box(code, base + l as u32),
                            shape: VolumeShape {
                                level: (base + l as u32) as u8,
                                axes: 0,
                            },
                        })
                    })
                    .collect()
            })
            .collect();
    }

    // Bottom-up: which nodes are empty as a whole (empty leaves and type-1 nodes).
    let mut all_empty: Vec<Vec<bool>> = vec![Vec::new(); levels.len()];
    for l in (0..levels.len()).rev() {
        let mut rank = 0usize;
        all_empty[l] = levels[l]
            .nodes
            .iter()
            .map(|n| match n {
                BuildNode::Leaf(t) => t.is_empty(),
                BuildNode::Internal => {
                    let first = 8 * rank;
                    rank += 1;
                    all_empty[l + 1][first..first + 8].iter().all(|&e| e)
                }
            })
            .collect();
    }

    // Top-down: the box of every all-empty node.
    let mut boxes: LeafBoxes = levels.iter().map(|lv| vec![None; lv.nodes.len()]).collect();
    for (i, &empty) in all_empty[0].iter().enumerate() {
        if empty {
            boxes[0][i] = Some(Merged {
                volume: cell_box(levels[0].codes[i], base),
                shape: VolumeShape {
                    level: base as u8,
                    axes: 0,
                },
            });
        }
    }
    for l in 0..levels.len().saturating_sub(1) {
        let mut rank = 0usize;
        for (idx, node) in levels[l].nodes.iter().enumerate() {
            if !matches!(node, BuildNode::Internal) {
                continue;
            }
            let first = 8 * rank;
            rank += 1;
            if all_empty[l][idx] {
                // Type-1: merged upward; its children share its box.
                for c in 0..8 {
                    boxes[l + 1][first + c] = boxes[l][idx];
                }
                continue;
            }
            // Type-2: same-parent merging of its empty children.
            let empty: [bool; 8] = std::array::from_fn(|c| all_empty[l + 1][first + c]);
            let parent = cell_box(levels[l].codes[idx], base + l as u32);
            let half = cell_size(base + l as u32 + 1);
            for c in 0..8 {
                if empty[c] {
                    let axes = merged_axes(&empty, c);
                    boxes[l + 1][first + c] = Some(Merged {
                        volume: group_box(&parent, half, c, axes),
                        shape: VolumeShape {
                            level: (base + l as u32) as u8 + 1,
                            axes,
                        },
                    });
                }
            }
        }
    }

    // Keep boxes on empty leaves only.
    for (lv, b) in levels.iter().zip(boxes.iter_mut()) {
        for (n, slot) in lv.nodes.iter().zip(b.iter_mut()) {
            if !is_empty_leaf(n) {
                *slot = None;
            }
        }
    }
    boxes
}

/// Direction attributes (paper §2.3): bit `a` of `attr[c]` is set when child `c` and its sibling
/// across axis `a` are both empty.
fn attributes(empty: &[bool; 8]) -> [u8; 8] {
    std::array::from_fn(|c| {
        if !empty[c] {
            return 0;
        }
        (0..3)
            .filter(|&a| empty[c ^ (1 << a)])
            .fold(0u8, |m, a| m | 1 << a)
    })
}

/// The axes along which empty child `c` is merged with its siblings: the largest all-empty box
/// of siblings containing `c` (quad over pair over single, in a fixed order of preference).
fn merged_axes(empty: &[bool; 8], c: usize) -> u8 {
    let attr = attributes(empty);
    if attr[c] == 0b111 && (0..8).all(|s| empty[s]) {
        return 0b111; // all eight empty: only above a type-1 node, handled by upward merging
    }
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let plane = 1u8 << a | 1u8 << b;
        // c pairs along a and along b, and its neighbour along a pairs along b.
        if attr[c] & plane == plane && attr[c] & attr[c ^ (1 << a)] & (1 << b) != 0 {
            return plane;
        }
    }
    (0..3)
        .map(|a| 1u8 << a)
        .find(|bit| attr[c] & bit != 0)
        .unwrap_or(0)
}

/// The box of the siblings of child `c` merged along `axes`, inside `parent` whose children have
/// edge `half`.
fn group_box(parent: &VolumeRecord, half: u32, c: usize, axes: u8) -> VolumeRecord {
    let mut b = *parent;
    for k in 0..3 {
        if axes & (1 << k) == 0 {
            b.lo[k] = parent.lo[k] + ((c >> k) & 1) as u32 * half;
            b.hi[k] = b.lo[k] + half;
        }
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn empty_from(mask: u8) -> [bool; 8] {
        std::array::from_fn(|c| mask & (1 << c) != 0)
    }

    #[test]
    fn attributes_are_pairwise_emptiness() {
        // Children 0 (000) and 1 (001: +x) empty: each has the x attribute, nothing else.
        let e = empty_from(0b0000_0011);
        let a = attributes(&e);
        assert_eq!(a[0], 0b001);
        assert_eq!(a[1], 0b001);
        assert_eq!(a[2], 0);
    }

    #[test]
    fn picks_the_largest_box() {
        // Seven empty children (all but 7 = +x+y+z): the L-shape the paper would merge whole.
        let e = empty_from(0b0111_1111);
        // Child 0 can take the xy quad {0,1,2,3}.
        assert_eq!(merged_axes(&e, 0), 0b011);
        // Child 6 (+y+z): its xy quad {4,5,6,7} and xz quad {2,3,6,7} hold the solid child 7;
        // its yz quad {0,2,4,6} is all empty.
        assert_eq!(merged_axes(&e, 6), 0b110);
        // Only children 0 and 3 (diagonal): no face neighbour, single cells.
        let e = empty_from(0b0000_1001);
        assert_eq!(merged_axes(&e, 0), 0);
        assert_eq!(merged_axes(&e, 3), 0);
        // Children 0 and 4 (000, 100): a z pair.
        let e = empty_from(0b0001_0001);
        assert_eq!(merged_axes(&e, 4), 0b100);
    }

    #[test]
    fn every_box_is_all_empty_and_contains_its_cell() {
        for mask in 0u16..255 {
            let e = empty_from(mask as u8);
            let parent = VolumeRecord {
                lo: [0; 3],
                hi: [2; 3],
            };
            for c in 0..8 {
                if !e[c] {
                    continue;
                }
                let b = group_box(&parent, 1, c, merged_axes(&e, c));
                for (s, &empty_s) in e.iter().enumerate() {
                    let inside = (0..3).all(|k| {
                        let x = ((s >> k) & 1) as u32;
                        b.lo[k] <= x && x < b.hi[k]
                    });
                    if inside {
                        assert!(empty_s, "mask {mask:08b}: box of {c} covers non-empty {s}");
                    }
                    if s == c {
                        assert!(inside, "box of {c} does not contain it");
                    }
                }
            }
        }
    }
}
