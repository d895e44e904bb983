//! The classic octree's node record.

use bytemuck::{Pod, Zeroable};

/// A node of the pointer octree, 36 bytes: a kind word and eight words. An internal node
/// (`kind` = [`Node::INTERNAL`]) stores the indices of its 8 children in octant order (bit 0: x,
/// bit 1: y, bit 2: z; a set bit is the upper half); a leaf (`kind` = [`Node::LEAF`]) stores
/// the start and length of its run of the reference array in its first two words (length 0:
/// an empty leaf) and zeros in the other six. The classic octree spends the same room on either
/// kind, as a tagged union does.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Node {
    kind: u32,
    words: [u32; 8],
}
const _: () = assert!(std::mem::size_of::<Node>() == 36);

/// What a [`Node`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Internal([u32; 8]),
    Leaf { first: u32, count: u32 },
}

impl Node {
    pub const LEAF: u32 = 0;
    pub const INTERNAL: u32 = 1;

    pub(super) fn internal(children: [u32; 8]) -> Node {
        Node {
            kind: Node::INTERNAL,
            words: children,
        }
    }

    pub(super) fn leaf(first: u32, count: u32) -> Node {
        Node {
            kind: Node::LEAF,
            words: [first, count, 0, 0, 0, 0, 0, 0],
        }
    }

    #[inline(always)]
    pub(super) fn kind(&self) -> Kind {
        if self.kind == Node::INTERNAL {
            Kind::Internal(self.words)
        } else {
            Kind::Leaf {
                first: self.words[0],
                count: self.words[1],
            }
        }
    }
}
