//! The BVH's node record.
//!
//! **Layout.** The tree is flattened to pbrt-v4's `LinearBVHNode` ([`LinearNode`], 32 bytes:
//! bounds, `primitivesOffset` or `secondChildOffset`, `nPrimitives`, split axis) in depth-first
//! order: the first child of an interior node follows it, the second is found by its offset.
//! Triangles are reordered into leaf order, so a leaf's triangles are one contiguous run.

use bytemuck::{Pod, Zeroable};

/// pbrt-v4's `LinearBVHNode`: 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LinearNode {
    pub min: [f32; 3],
    pub max: [f32; 3],
    /// A leaf's first triangle (`primitivesOffset`) or an interior node's second child
    /// (`secondChildOffset`).
    pub offset: u32,
    /// Triangles of a leaf; 0 for an interior node.
    pub n_prims: u16,
    /// Split axis of an interior node.
    pub axis: u8,
    pub(super) pad: u8,
}
const _: () = assert!(std::mem::size_of::<LinearNode>() == 32);
