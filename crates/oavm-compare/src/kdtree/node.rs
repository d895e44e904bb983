//! The KD-tree's node record, pbrt's `KdAccelNode`.
//!
//! **Storage** is pbrt's 8-byte node ([`KdNode`]): an interior node stores its split position
//! (f32), its axis (2 bits) and the index of its above child (30 bits); the below child follows
//! it in the array (depth-first layout). A leaf stores its triangle count (30 bits) and either
//! the single triangle's index in place or an offset into the leaf primitive list. Node indices
//! and leaf sizes beyond 30 bits are refused by checked narrowing (a node that would need one is
//! made a leaf; an input that cannot be stored at all is traced by brute force instead).

use bytemuck::{Pod, Zeroable};

/// Node indices and leaf sizes are stored in 30 bits.
pub(super) const MAX_30: usize = (1 << 30) - 1;

/// pbrt's `KdAccelNode`, 8 bytes. Interior: `a` = split position (f32 bits), `b` = axis (low 2
/// bits) | above child index << 2. Leaf: `b` = 3 | triangle count << 2, `a` = the triangle's
/// index (one triangle) or the offset of the leaf's list in the primitive list.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct KdNode {
    pub(super) a: u32,
    b: u32,
}
const _: () = assert!(std::mem::size_of::<KdNode>() == 8);

impl KdNode {
    /// `axis` < 3, `above` <= [`MAX_30`].
    pub(super) fn interior(axis: usize, split: f32, above: u32) -> KdNode {
        KdNode {
            a: split.to_bits(),
            b: axis as u32 | above << 2,
        }
    }
    /// `count` <= [`MAX_30`].
    pub(super) fn leaf(count: u32, a: u32) -> KdNode {
        KdNode {
            a,
            b: 3 | count << 2,
        }
    }
    pub fn is_leaf(&self) -> bool {
        self.b & 3 == 3
    }
    pub(super) fn axis(&self) -> usize {
        (self.b & 3) as usize
    }
    pub(super) fn split(&self) -> f32 {
        f32::from_bits(self.a)
    }
    /// Above child (interior) or triangle count (leaf).
    pub(super) fn upper(&self) -> u32 {
        self.b >> 2
    }
}
