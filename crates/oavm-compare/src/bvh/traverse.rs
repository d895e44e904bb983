//! The BVH's traversal.
//!
//! **Traversal** (pbrt-v4 §7.3.5, `BVHAggregate::Intersect`): the slab test with precomputed
//! reciprocal direction, made conservative by growing the far `t` by `2 γ(3)` as pbrt does;
//! children visited front to back (the near child first by the sign of the direction along the
//! node's split axis, the far one pushed); the closest-hit query shrinks `tmax` to each hit, so
//! farther boxes are culled; the any-hit query stops at the first hit. A zero direction
//! component gives an infinite reciprocal; a slab then yields `±inf`, or NaN where the origin
//! lies exactly on the slab plane, and the NaN is ignored by the `max`/`min` (the ray grazes
//! that plane: treated as inside, conservatively).
//!
//! Deviation: two triangles hit at the same closest `t` resolve to the lower primitive id, as in
//! every structure here (the shared leaf test), where pbrt-v4 keeps the first found (which, with
//! triangles in leaf order, depends on the build).

use std::ops::Range;

use super::Bvh;
use super::node::LinearNode;
use crate::Counters;
use crate::StructureStats;
use crate::leaf::{STOP, Soup, Walk};
use oavm::geom::Ray;

/// Entries of the traversal stack.
pub const STACK_SIZE: usize = 64;

impl Walk for Bvh {
    /// A leaf's triangles are a run of the soup, which is in leaf order.
    type Leaf = Range<usize>;

    fn soup(&self) -> &Soup {
        &self.soup
    }

    fn structure_stats(&self) -> &StructureStats {
        &self.stats
    }

    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut leaf: impl FnMut(&Range<usize>, &mut Counters) -> f32,
    ) -> bool {
        if self.linear {
            return false;
        }
        let inv: [f32; 3] = std::array::from_fn(|k| 1.0 / ray.dir[k]);
        let neg: [bool; 3] = std::array::from_fn(|k| inv[k] < 0.0);
        let mut tmax = ray.tmax;
        let mut stack = [0u32; STACK_SIZE];
        let mut sp = 0usize;
        let mut cur = 0usize;
        // (`get` fails never: the offsets are made by the build.)
        while let Some(node) = self.nodes.get(cur) {
            c.nodes_visited += 1;
            let mut next = None;
            if hits_box(node, ray, &inv, &neg, tmax) {
                if node.n_prims > 0 {
                    c.leaves_visited += 1;
                    let first = node.offset as usize;
                    let bound = leaf(&(first..first + node.n_prims as usize), c);
                    if bound == STOP {
                        return true;
                    }
                    // The closest hit so far, or the ray's own end.
                    tmax = bound.min(ray.tmax);
                } else {
                    // Near child next, far child on the stack.
                    let (near, far) = if neg[node.axis as usize] {
                        (node.offset, cur as u32 + 1)
                    } else {
                        (cur as u32 + 1, node.offset)
                    };
                    let Some(slot) = stack.get_mut(sp) else {
                        // Never (the build bounds the depth): answered by brute force.
                        return false;
                    };
                    *slot = far;
                    sp += 1;
                    next = Some(near as usize);
                }
            }
            cur = match next {
                Some(n) => n,
                None if sp == 0 => break,
                None => {
                    sp -= 1;
                    stack[sp] as usize
                }
            };
        }
        true
    }
}

/// pbrt-v4's `Bounds3::IntersectP` with precomputed reciprocal direction: the slab test over
/// `[tmin, tmax]`, far distances moved out by `2 γ(3)` of their magnitude (grown if positive,
/// shrunk toward zero if negative) so rounding never loses a box.
#[inline(always)]
fn hits_box(n: &LinearNode, ray: &Ray, inv: &[f32; 3], neg: &[bool; 3], tmax: f32) -> bool {
    const GROW: f32 = 1.0 + 2.0 * gamma(3);
    const SHRINK: f32 = 1.0 - 2.0 * gamma(3);
    let mut t0 = ray.tmin;
    let mut t1 = tmax;
    for k in 0..3 {
        let (near, far) = if neg[k] {
            (n.max[k], n.min[k])
        } else {
            (n.min[k], n.max[k])
        };
        let tn = (near - ray.origin[k]) * inv[k];
        let tf = (far - ray.origin[k]) * inv[k];
        let tf = tf * if tf > 0.0 { GROW } else { SHRINK };
        // NaN (origin on the plane of a slab the ray runs along) is ignored by max/min.
        t0 = t0.max(tn);
        t1 = t1.min(tf);
    }
    t0 <= t1
}

/// pbrt's `γ(n) = n ε / (1 - n ε)` with `ε` half an ulp of 1.
const fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5;
    (n as f32 * e) / (1.0 - n as f32 * e)
}
