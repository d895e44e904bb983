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
//!
//! **Stackless variants** ([`KdTraversal`], the comparison of the threaded KD-tree's source,
//! Jiao, Chen and Zhang). They make the same plane decisions with the same tolerance, but
//! where the stack walk pushes the far side they go on with the near side only and, once its
//! leaf is done, walk the rest of the ray (from that leaf's exit to the end of the clipped
//! segment) down again: from the root (*kd-restart*, Foley and Sugerman 2005), or from the
//! deepest node of the last descent that holds the whole rest of the segment, the node where
//! the descent first took both sides (*push-down*, same paper). *Short-stack* (Horn et al.
//! 2007) keeps the `n` far sides pushed last in a ring (the oldest overwritten when it is
//! full) and walks down again (push-down) only when it runs dry after dropping one. Each walk
//! down again counts a restart ([`Counters::restarts`]). A near side met over no length (the
//! ray at the plane, within the tolerance: the plane may hold triangles lying in it, in a cell
//! of no thickness, as the kitchen's walls do) is visited, its far side kept in one slot and
//! taken next, so that walking down again does not meet the same plane for ever; a second such
//! plane below the first, or a ray lying in a split plane (the stack walk visits both sides
//! with the same interval), finishes with the stack walk from the root, so the answer stays
//! exact at the cost of leaves tested twice (10^6 random rays: 0.7 % of them on the kitchen,
//! under 0.1 % on the robots and the Cornell box). Skipping that near side instead lost the
//! floor's hit on 534 of 10^6 random rays in the kitchen.

use super::KdTree;
use crate::Counters;
use crate::StructureStats;
use crate::aabb::clip_ray;
use crate::leaf::{NO_HIT, STOP, Soup, Walk};
use oavm::geom::Ray;

/// Entries of the traversal stack.
pub const STACK: usize = 64;

/// The most entries a short stack may have.
pub const MAX_SHORT_STACK: usize = 32;

/// How a ray walks the tree (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KdTraversal {
    /// pbrt's stack traversal.
    Stack,
    /// No stack: the rest of the ray walked down from the root after each leaf.
    Restart,
    /// No stack: the rest walked down from the deepest node holding all of it.
    PushDown,
    /// A ring of this many far sides (1..=[`MAX_SHORT_STACK`]); push-down when it runs dry
    /// after dropping one.
    ShortStack(usize),
    /// The source's ropes: nodebox inheritance, a clue per face of each leaf
    /// ([`super::ropes`]).
    Ropes,
    /// Popov et al.'s ropes to the smallest node across each face.
    Popov,
    /// The source's ropes walked with its `SplitStack`: nodebox inheritance, no stored cells,
    /// a 64-bit register of the faces that caused each fork ([`super::ropes`]).
    SplitStack,
}

impl KdTraversal {
    /// The name `oavm-bench` knows it by (`kdtree:stack` is the plain `kdtree`).
    pub fn name(self) -> &'static str {
        match self {
            KdTraversal::Stack => "kdtree",
            KdTraversal::Restart => "kdtree:restart",
            KdTraversal::PushDown => "kdtree:pushdown",
            KdTraversal::ShortStack(_) => "kdtree:shortstack",
            KdTraversal::Ropes => "kdtree:ropes",
            KdTraversal::Popov => "kdtree:popov",
            KdTraversal::SplitStack => "kdtree:splitstack",
        }
    }
}

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
    #[inline(always)]
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut leaf: impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        match self.traversal {
            KdTraversal::Stack => self.walk_stack(ray, c, &mut leaf),
            KdTraversal::Restart => self.walk_restart(ray, c, &mut leaf, false, 0),
            KdTraversal::PushDown => self.walk_restart(ray, c, &mut leaf, true, 0),
            KdTraversal::ShortStack(n) => {
                self.walk_restart(ray, c, &mut leaf, true, n.clamp(1, MAX_SHORT_STACK))
            }
            KdTraversal::Ropes | KdTraversal::Popov => self.walk_ropes(ray, c, &mut leaf),
            KdTraversal::SplitStack => self.walk_split_stack(ray, c, &mut leaf),
        }
    }
}

/// The ray as the walks use it: clipped to the root box, in f64, with the plane tolerance.
pub(super) struct KdRay {
    pub(super) t0: f64,
    pub(super) t1: f64,
    pub(super) o: [f64; 3],
    pub(super) d: [f64; 3],
    pub(super) inv: [f64; 3],
    pub(super) eps: f64,
}

impl KdTree {
    /// The ray clipped and prepared, `None` if it misses the root box.
    #[inline(always)]
    pub(super) fn kd_ray(&self, ray: &Ray) -> Option<KdRay> {
        let (t0, t1) = clip_ray(ray, self.lo, self.hi)?;
        let o = ray.origin.map(|x| x as f64);
        let d = ray.dir.map(|x| x as f64);
        let dist = (0..3)
            .map(|k| (o[k] - self.centre[k]).abs())
            .fold(0.0, f64::max);
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Some(KdRay {
            t0,
            t1,
            o,
            d,
            inv: d.map(|x| 1.0 / x),
            eps: 1e-6 * (self.diag + dist) / norm,
        })
    }

    /// Visits leaf `n`: tests its triangles (if it has any) through `leaf`. `None` if the walk
    /// is over ([`STOP`]: an any hit); else the new bound, if the leaf had triangles.
    #[inline(always)]
    pub(super) fn visit_leaf(
        &self,
        n: &super::KdNode,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> Option<Option<f64>> {
        c.leaves_visited += 1;
        let prims = self.leaf_list(n);
        if prims.is_empty() {
            return Some(None);
        }
        match leaf(prims, c) {
            STOP => None,
            b => Some(Some(b as f64)),
        }
    }

    /// The kd-restart, push-down and short-stack walks (module docs): `push_down` restarts
    /// from the deepest node holding the rest of the segment (else the root), `short` is the
    /// short stack's size (0: none).
    fn walk_restart(
        &self,
        ray: &Ray,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
        push_down: bool,
        short: usize,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some(r) = self.kd_ray(ray) else {
            return true;
        };
        let mut ring = [(0u32, 0.0f64, 0.0f64); MAX_SHORT_STACK];
        let (mut top, mut len) = (0usize, 0usize);
        let mut dropped = false;
        let (mut node, mut tmin, mut tmax) = (0u32, r.t0, r.t1);
        // Where the next walk down starts, and whether this descent has not yet taken both
        // sides of a plane (so the node it is at holds all of `[tmin, t1]`).
        let (mut restart_at, mut whole) = (0u32, true);
        let mut seg_start = r.t0;
        // The far side of a plane the ray is at (see the walk down).
        let mut tie: Option<(u32, f64, f64)> = None;
        let mut bound = NO_HIT as f64;
        loop {
            let node_ref = if bound < tmin - r.eps {
                None
            } else {
                self.nodes.get(node as usize)
            };
            if let Some(n) = node_ref {
                c.nodes_visited += 1;
                if !n.is_leaf() {
                    // The stack walk's plane decision, written out as there (one form of it
                    // in every walk; unlike the stack walk, these measured no faster for it
                    // than through a helper returning an enum: kitchen, primary rays, 0.56 to
                    // 0.59 against 0.57 to 0.61 Mrays/s for kd-restart). The far side the stack
                    // walk would push is dropped, kept in the ring or kept as the tie.
                    let a = n.axis();
                    let split = n.split() as f64;
                    let (below, above) = (node + 1, n.upper());
                    let child = if r.d[a] == 0.0 {
                        // Parallel to the plane: the side holding the ray; lying in it, the
                        // stack walk visits both sides with the same interval.
                        if r.o[a] < split {
                            below
                        } else if r.o[a] > split {
                            above
                        } else {
                            return self.walk_stack(ray, c, leaf);
                        }
                    } else {
                        let tp = (split - r.o[a]) * r.inv[a];
                        let (near, far) = if r.d[a] > 0.0 {
                            (below, above)
                        } else {
                            (above, below)
                        };
                        if tp > tmax + r.eps {
                            near
                        } else if tp < tmin - r.eps {
                            far
                        } else {
                            let tp = tp.clamp(tmin, tmax);
                            if short == 0 && tp <= tmin {
                                // Without a stack, a near side met over no length (the ray at
                                // the plane, which may hold triangles lying in it) keeps its
                                // far side in one slot, so that walking down again does not
                                // meet it once more.
                                if tie.is_some() {
                                    return self.walk_stack(ray, c, leaf);
                                }
                                tie = Some((far, tp, tmax));
                            } else if short > 0 {
                                if len == short {
                                    dropped = true;
                                } else {
                                    len += 1;
                                }
                                ring[top] = (far, tp, tmax);
                                top = (top + 1) % short;
                            } else {
                                dropped = true;
                            }
                            whole = false;
                            node = near;
                            tmax = tp;
                            continue;
                        }
                    };
                    node = child;
                    if whole && push_down {
                        restart_at = child;
                    }
                    continue;
                }
                match self.visit_leaf(n, c, leaf) {
                    Some(b) => bound = b.unwrap_or(bound),
                    None => return true,
                }
            }
            if len > 0 {
                top = (top + short - 1) % short;
                len -= 1;
                (node, tmin, tmax) = ring[top];
                continue;
            }
            if let Some(t) = tie.take() {
                (node, tmin, tmax) = t;
                continue;
            }
            // Nothing was dropped: the walk is complete, as the stack walk's would be.
            if !dropped || tmax >= r.t1 || bound < tmax - r.eps {
                return true;
            }
            if tmax <= seg_start {
                // No progress since the last walk down: finish with the stack walk.
                return self.walk_stack(ray, c, leaf);
            }
            c.restarts += 1;
            seg_start = tmax;
            (node, tmin, tmax) = (restart_at, seg_start, r.t1);
            whole = true;
            dropped = false;
        }
    }

    /// pbrt's stack walk (module docs).
    #[inline(always)]
    pub(super) fn walk_stack(
        &self,
        ray: &Ray,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some(r) = self.kd_ray(ray) else {
            return true;
        };
        self.stack_core(&r, r.t0, c, leaf, &mut Plain)
    }

    /// The stack walk of `r` over `[t0, r.t1]`, with `hooks` (the shadow-ray walks'
    /// occluders tested at inner nodes and fixed child order; [`Plain`] for none).
    #[inline(always)]
    pub(super) fn stack_core(
        &self,
        r: &KdRay,
        t0: f64,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
        hooks: &mut impl StackHooks,
    ) -> bool {
        let mut stack = [(0u32, 0.0f64, 0.0f64); STACK];
        let mut sp = 0;
        let (mut node, mut tmin, mut tmax) = (0u32, t0, r.t1);
        let mut bound = NO_HIT as f64;
        loop {
            // A node starting after the closest hit is skipped. Not a `break` as in pbrt: the
            // stack is ordered by `tmin` except below an entry pushed for a ray lying in a
            // plane (both sides, same interval), so later entries may still start earlier.
            let node_ref = if bound < tmin - r.eps {
                None
            } else {
                self.nodes.get(node as usize)
            };
            if let Some(n) = node_ref {
                c.nodes_visited += 1;
                if !n.is_leaf() {
                    if hooks.inner(node, c) {
                        return true;
                    }
                    // The far side (or, for a ray lying in the plane, the above side over the
                    // same interval) is pushed; the walk goes on with the other.
                    // The plane decision is written out: through a helper returning an enum
                    // (one child, both, in the plane) this walk ran at 0.65x on the kitchen
                    // (1.71 against 2.62 Mrays/s, primary rays).
                    let a = n.axis();
                    let split = n.split() as f64;
                    let (below, above) = (node + 1, n.upper());
                    if r.d[a] == 0.0 {
                        // Parallel to the plane: the side holding the ray, both if it lies in it.
                        if r.o[a] < split {
                            node = below;
                        } else if r.o[a] > split {
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
                    let tp = (split - r.o[a]) * r.inv[a];
                    let (near, far) = if r.d[a] > 0.0 {
                        (below, above)
                    } else {
                        (above, below)
                    };
                    if tp > tmax + r.eps {
                        node = near;
                    } else if tp < tmin - r.eps {
                        node = far;
                    } else {
                        let tp = tp.clamp(tmin, tmax);
                        let Some(slot) = stack.get_mut(sp) else {
                            return false;
                        };
                        if hooks.far_first(node, near == below) {
                            *slot = (near, tmin, tp);
                            node = far;
                            tmin = tp;
                        } else {
                            *slot = (far, tp, tmax);
                            node = near;
                            tmax = tp;
                        }
                        sp += 1;
                    }
                    continue;
                }
                match self.visit_leaf(n, c, leaf) {
                    Some(b) => bound = b.unwrap_or(bound),
                    None => return true,
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

/// What the shadow-ray walks add to the stack walk ([`KdTree::stack_core`]); the defaults add
/// nothing.
pub(super) trait StackHooks {
    /// Called at each interior node the walk visits; `true` ends the walk (an occluder found).
    #[inline(always)]
    fn inner(&mut self, _node: u32, _c: &mut Counters) -> bool {
        false
    }
    /// Whether, where the ray crosses both children of `node`, the far one is visited first
    /// (`near_is_below`: the ray meets the below child first).
    #[inline(always)]
    fn far_first(&self, _node: u32, _near_is_below: bool) -> bool {
        false
    }
}

/// The plain stack walk: no hooks.
pub(super) struct Plain;

impl StackHooks for Plain {}
