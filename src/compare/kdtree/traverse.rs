//! The KD-tree's traversal.
//!
//! **Traversal** is pbrt's front-to-back descent with a fixed-size stack ([`STACK`] entries; the
//! depth cap keeps a path's pushes below it, and a push that would not fit ends in a brute-force
//! answer rather than an overflow). The child the ray meets first along its direction is visited
//! first, the other pushed with its `t` interval; a popped node whose interval starts after the
//! closest hit so far is skipped (pbrt ends the walk there instead, which is the same while the
//! stack is ordered by entry `t`; a ray lying in a split plane pushes the second side with the
//! same interval and breaks that order, so we skip and pop on). Plane decisions carry a tolerance of `1e-6` of the scene's
//! size (in `t`), so rounding can only make the walk visit an extra node, never skip one; a ray
//! parallel to a plane and lying on it visits both sides. Triangles are tested with the ray's
//! full `[tmin, closest-so-far]` range; the any-hit walk stops at the first hit.

use super::KdTree;
use crate::compare::StructureStats;
use crate::compare::aabb::clip_ray;
use crate::compare::leaf::{NO_HIT, STOP, Soup, Walk};
use crate::geom::Ray;
use crate::logical::Counters;

/// Entries of the traversal stack.
pub const STACK: usize = 64;

impl Walk for KdTree {
    type Leaf = [u32];

    fn soup(&self) -> &Soup {
        &self.soup
    }

    fn structure_stats(&self) -> &StructureStats {
        &self.stats
    }

    /// Returns `false` if the walk could not be completed (a full stack: never, by the depth
    /// cap) or there is no tree.
    #[inline]
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut leaf: impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some((t0, t1)) = clip_ray(ray, self.lo, self.hi) else {
            return true;
        };
        let o = ray.origin.map(|x| x as f64);
        let d = ray.dir.map(|x| x as f64);
        let inv = d.map(|x| 1.0 / x);
        let dist = (0..3)
            .map(|k| (o[k] - self.centre[k]).abs())
            .fold(0.0, f64::max);
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let eps = 1e-6 * (self.diag + dist) / norm;
        let mut stack = [(0u32, 0.0f64, 0.0f64); STACK];
        let mut sp = 0;
        let (mut node, mut tmin, mut tmax) = (0u32, t0, t1);
        let mut bound = NO_HIT as f64;
        loop {
            // A node starting after the closest hit is skipped. Not a `break` as in pbrt: the
            // stack is ordered by `tmin` except below an entry pushed for a ray lying in a
            // plane (both sides, same interval), so later entries may still start earlier.
            let node_ref = if bound < tmin - eps {
                None
            } else {
                self.nodes.get(node as usize)
            };
            if let Some(n) = node_ref {
                c.nodes_visited += 1;
                if !n.is_leaf() {
                    let a = n.axis();
                    let split = n.split() as f64;
                    let (below, above) = (node + 1, n.upper());
                    if d[a] == 0.0 {
                        // Parallel to the plane: the side holding the ray, both if it lies in it.
                        if o[a] < split {
                            node = below;
                        } else if o[a] > split {
                            node = above;
                        } else {
                            let Some(slot) = stack.get_mut(sp) else {
                                return false;
                            };
                            *slot = (above, tmin, tmax);
                            sp += 1;
                            node = below;
                        }
                        continue;
                    }
                    let tp = (split - o[a]) * inv[a];
                    let (near, far) = if d[a] > 0.0 {
                        (below, above)
                    } else {
                        (above, below)
                    };
                    if tp > tmax + eps {
                        node = near;
                    } else if tp < tmin - eps {
                        node = far;
                    } else {
                        let tp = tp.clamp(tmin, tmax);
                        let Some(slot) = stack.get_mut(sp) else {
                            return false;
                        };
                        *slot = (far, tp, tmax);
                        sp += 1;
                        node = near;
                        tmax = tp;
                    }
                    continue;
                }
                c.leaves_visited += 1;
                let prims = self.leaf_list(n);
                if !prims.is_empty() {
                    let b = leaf(prims, c);
                    if b == STOP {
                        return true;
                    }
                    bound = b as f64;
                }
            }
            if sp == 0 {
                return true;
            }
            sp -= 1;
            (node, tmin, tmax) = stack[sp];
        }
    }
}
