//! Ropes: the threaded KD-tree of Jiao, Chen and Zhang, and Popov et al.'s (2007) ropes to the
//! smallest node across each face.
//!
//! **The source's ropes** ([`KdTraversal::Ropes`]) are built top-down by *nodebox
//! inheritance*: a child inherits its parent's six clues (the node across each face of its
//! cell: −x, +x, −y, +y, −z, +z; none at the scene's boundary), then the clue across the
//! parent's split plane is set to the sibling (the below child's high clue is the above child,
//! and the other way round). A leaf's clue may thus be a large subtree across its face. **Popov's
//! ropes** ([`KdTraversal::Popov`]) push each leaf's clue down that subtree while one child
//! alone holds the whole face: through splits parallel to the face (to the child touching it)
//! and splits the face lies on one side of.
//!
//! **Traversal** needs no stack: from the node a rope names, the walk goes down to the leaf
//! holding the ray's point where it enters (on a split plane, the side the ray goes to), tests
//! the leaf's triangles, and leaves by the face its segment exits through (the leaf's cell is
//! stored, 24 bytes a leaf, and nothing is computed; the source finds the face with its 64-bit
//! `SplitStack` instead, as the `SplitStack` walk below does), taking that face's rope.
//! The walk ends at the scene's boundary, past the segment's end, or once the closest hit so far
//! lies before the leaf's exit. A ray that enters a node at one of its split planes (within the
//! tolerance: the other side may be a cell of no thickness holding triangles that lie in the
//! plane, which the ray meets there), lies in a split plane, or would not move past the last
//! exit (rounding), finishes with the stack walk from the root, so the answer stays exact
//! (10^6 random rays: 2.9 % of them on the kitchen, under 0.12 % on the robots and the Cornell
//! box; choosing a side by the direction instead lost 157 hits on the kitchen). Each rope taken counts a restart ([`Counters::restarts`]): the walk begins
//! again at the node the rope names.
//!
//! **Memory**: per leaf six 4-byte ropes and its cell as six f32 (48 bytes), stored per node
//! here (an interior node's entries are unused), so `48 * nodes` bytes are added to the tree's.
//!
//! **The `SplitStack` walk** ([`KdTraversal::SplitStack`]) follows the source without stored
//! cells. It is the stack walk with its stack of `(far node, tmin, tmax)` replaced by a 64-bit
//! register and the ropes:
//!
//! - **The register** holds, three bits per *fork* (a node whose two children the ray's
//!   interval both reaches, where the stack walk pushes), the face of the entered (near) child
//!   that the fork's split plane forms: `2a + 1` (its high face on axis `a`) when the ray goes
//!   up `a`, `2a` when it goes down. A push shifts the register left by three and ors the face
//!   in, a pop shifts it right; a marker bit above the oldest face (the register is 1 with no
//!   fork pending) tells how many are, at most [`SPLIT_STACK_FORKS`] (a 22nd finishes with the
//!   stack walk from the root). With `k` forks pending:
//!
//!   ```text
//!   bit  63 .. 3k+1   3k    3k-1 .. 3k-3   ...   5 .. 3      2 .. 0
//!        0  ..  0     1     oldest face    ...   face k-1    newest face (k)
//!   ```
//!
//!   After a leaf the newest face is the one the ray leaves it by: the stack walk's interval
//!   for the leaf ends at that fork's plane.
//! - **The node across**: by nodebox inheritance, the leaf's clue across that face was set by
//!   the deepest node of its path that forms the face, which is that fork (a deeper node
//!   forming it lies no further along the ray, so the walk would have met it as a newer fork,
//!   and none is pending), so the clue leads to the fork's far child: the node the stack walk
//!   pops. Its interval starts where the leaf's ends (the walk keeps that `t`).
//! - **Where its interval ends** is what a stack entry held besides: the `t` where the ray
//!   leaves that node's cell, no later than the clipped segment's end and no earlier than the
//!   interval's start (the stack walk's value: its interval ends are the planes its forks met
//!   on the ray's exit sides, and the path's other planes on those sides lie beyond them). It
//!   is read through the node's own clues on the three faces the ray goes towards. So every
//!   node, interior ones too, keeps its six clues, and a clue names the node across through
//!   the fork whose split forms the face (the node across is the fork's above child across a
//!   high face, the record after the fork across a low face): one 8-byte record gives both the
//!   node and the plane's position, where the source's leaf clue names the node and its stored
//!   cell the plane.
//!
//! The walk thus keeps the register, the node and its interval, and nothing per fork beyond its
//! three bits. It visits the stack walk's nodes in the stack walk's order (its counts are the
//! stack walk's), so its answers are the stack walk's; a ray lying in a split plane (the stack
//! walk pushes the above side over the same interval, which three bits cannot rebuild)
//! finishes with the stack walk from the root. Where it departs from the source: clues on every
//! node, not only on leaves, named by their forks. **Memory**: six 4-byte clues per node
//! (`24 * nodes` bytes, `6 * nodes` pointers), no cells. Each rope taken counts a restart.

use super::{KdTraversal, KdTree};
use crate::Counters;
use crate::leaf::NO_HIT;
use oavm::geom::Ray;

/// No node across this face: the scene's boundary.
pub(super) const NONE: u32 = u32::MAX;

/// Bits of one fork's face in the `SplitStack` register (faces 0..6: −x, +x, −y, +y, −z, +z).
const FACE_BITS: u32 = 3;
const FACE_MASK: u64 = (1 << FACE_BITS) - 1;

/// The forks the `SplitStack` register holds: [`FACE_BITS`] each and the marker in 64 bits.
pub const SPLIT_STACK_FORKS: usize = 21;
const _: () = assert!(
    FACE_BITS as usize * SPLIT_STACK_FORKS < 64
        && FACE_BITS as usize * (SPLIT_STACK_FORKS + 1) >= 64
);

/// A register at or above this has its marker above bit 60, at 63: it holds
/// [`SPLIT_STACK_FORKS`] forks, and a push would shift the marker out.
const SPLIT_STACK_FULL: u64 = 1 << (FACE_BITS as usize * (SPLIT_STACK_FORKS - 1) + 1);

/// A tree's ropes and leaf cells (module docs).
pub(super) struct Ropes {
    /// Per node: the node across each face (−x, +x, −y, +y, −z, +z) of a leaf, or [`NONE`]; for
    /// the `SplitStack` walk, of every node, and named by the fork whose split forms the face.
    pub(super) across: Vec<[u32; 6]>,
    /// Per node: its cell's low and high corners (none for the `SplitStack` walk).
    pub(super) cell: Vec<[[f32; 3]; 2]>,
}

impl Ropes {
    /// The ropes of `kd`'s nodes for walk `t`: Popov's pushed down to the smallest node across
    /// each face, the `SplitStack` walk's named by their forks and kept for every node.
    pub(super) fn build(kd: &KdTree, t: KdTraversal) -> Ropes {
        let (popov, forks) = (t == KdTraversal::Popov, t == KdTraversal::SplitStack);
        let n = kd.nodes.len();
        let mut r = Ropes {
            across: vec![[NONE; 6]; n],
            cell: if forks {
                Vec::new()
            } else {
                vec![[[0.0; 3]; 2]; n]
            },
        };
        if n == 0 {
            return r;
        }
        let root = [kd.lo.map(|x| x as f32), kd.hi.map(|x| x as f32)];
        let mut stack = vec![(0usize, [NONE; 6], root)];
        while let Some((i, clues, cell)) = stack.pop() {
            let Some(nd) = kd.nodes.get(i) else { continue };
            if let Some(c) = r.cell.get_mut(i) {
                *c = cell;
            }
            if nd.is_leaf() || forks {
                r.across[i] = clues;
            }
            if nd.is_leaf() {
                continue;
            }
            let (a, s) = (nd.axis(), nd.split());
            let (below, above) = (i + 1, nd.upper() as usize);
            let (mut cb, mut ca) = (clues, clues);
            if forks {
                (cb[2 * a + 1], ca[2 * a]) = (i as u32, i as u32);
            } else {
                (cb[2 * a + 1], ca[2 * a]) = (above as u32, below as u32);
            }
            let (mut lb, mut la) = (cell, cell);
            lb[1][a] = s;
            la[0][a] = s;
            stack.push((below, cb, lb));
            stack.push((above, ca, la));
        }
        if popov {
            for i in 0..n {
                if !kd.nodes[i].is_leaf() {
                    continue;
                }
                for f in 0..6 {
                    r.across[i][f] = push_down(kd, r.across[i][f], f, &r.cell[i]);
                }
            }
        }
        r
    }

    /// Bytes stored: six ropes and (but for the `SplitStack` walk) a cell per node.
    pub(super) fn bytes(&self) -> usize {
        self.across.len() * 24 + self.cell.len() * 24
    }
}

/// The smallest node under `t` that holds all of face `f` of a leaf whose cell is `leaf`.
pub(super) fn push_down(kd: &KdTree, mut t: u32, f: usize, leaf: &[[f32; 3]; 2]) -> u32 {
    let (fa, high) = (f / 2, f % 2 == 1);
    while let Some(nd) = kd.nodes.get(t as usize) {
        if nd.is_leaf() {
            break;
        }
        let (a, s) = (nd.axis(), nd.split());
        let (below, above) = (t + 1, nd.upper());
        t = if a == fa {
            // Parallel to the face: the child beside it.
            let at = if high { leaf[1][a] } else { leaf[0][a] };
            if high {
                if s <= at { above } else { below }
            } else if s >= at {
                below
            } else {
                above
            }
        } else if leaf[1][a] <= s {
            below
        } else if leaf[0][a] >= s {
            above
        } else {
            break;
        };
    }
    t
}

impl KdTree {
    /// The rope walk (module docs).
    pub(super) fn walk_ropes(
        &self,
        ray: &Ray,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some(ropes) = self.ropes.as_ref() else {
            return self.walk_stack(ray, c, leaf);
        };
        let Some(r) = self.kd_ray(ray) else {
            return true;
        };
        let (mut node, mut tmin) = (0u32, r.t0);
        let mut bound = NO_HIT as f64;
        loop {
            // Down to the leaf holding the ray's point at `tmin`.
            let n = loop {
                let Some(n) = self.nodes.get(node as usize) else {
                    return self.walk_stack(ray, c, leaf);
                };
                c.nodes_visited += 1;
                if n.is_leaf() {
                    break n;
                }
                let a = n.axis();
                let s = n.split() as f64;
                if r.d[a] != 0.0 && ((s - r.o[a]) * r.inv[a] - tmin).abs() <= r.eps {
                    // The ray is at this plane, whose other side may hold triangles lying in
                    // it (a cell of no thickness): the stack walk visits both.
                    return self.walk_stack(ray, c, leaf);
                }
                let p = r.o[a] + tmin * r.d[a];
                node = if p < s || (p == s && r.d[a] < 0.0) {
                    node + 1
                } else if p > s || r.d[a] > 0.0 {
                    n.upper()
                } else {
                    // Lying in the plane.
                    return self.walk_stack(ray, c, leaf);
                };
            };
            match self.visit_leaf(n, c, leaf) {
                Some(b) => bound = b.unwrap_or(bound),
                None => return true,
            }
            // Out through the face the segment leaves by.
            let [lo, hi] = ropes.cell[node as usize];
            let (mut exit, mut face) = (f64::INFINITY, 0);
            for k in 0..3 {
                let (plane, f) = if r.d[k] > 0.0 {
                    (hi[k], 2 * k + 1)
                } else if r.d[k] < 0.0 {
                    (lo[k], 2 * k)
                } else {
                    continue;
                };
                let t = (plane as f64 - r.o[k]) * r.inv[k];
                if t < exit {
                    (exit, face) = (t, f);
                }
            }
            if exit >= r.t1 || bound < exit - r.eps {
                return true;
            }
            if exit <= tmin {
                return self.walk_stack(ray, c, leaf);
            }
            let next = ropes.across[node as usize][face];
            if next == NONE {
                return true;
            }
            c.restarts += 1;
            (node, tmin) = (next, exit);
        }
    }

    /// The node across face `f` of node `i` and the position of the plane the face lies on,
    /// through the `SplitStack` walk's ropes (named by forks); `None` at the scene's boundary.
    #[inline(always)]
    fn across_fork(&self, ropes: &Ropes, i: u32, f: usize) -> Option<(u32, f64)> {
        let q = *ropes.across.get(i as usize)?.get(f)?;
        let fork = self.nodes.get(q as usize)?;
        let next = if f % 2 == 1 { fork.upper() } else { q + 1 };
        Some((next, fork.split() as f64))
    }

    /// The `SplitStack` walk (module docs).
    pub(super) fn walk_split_stack(
        &self,
        ray: &Ray,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.brute {
            return false;
        }
        let Some(ropes) = self.ropes.as_ref() else {
            return self.walk_stack(ray, c, leaf);
        };
        let Some(r) = self.kd_ray(ray) else {
            return true;
        };
        // The faces of the pending forks, newest in the low bits, under a marker bit.
        let mut split_stack = 1u64;
        let (mut node, mut tmin, mut tmax) = (0u32, r.t0, r.t1);
        let mut bound = NO_HIT as f64;
        loop {
            let Some(n) = self.nodes.get(node as usize) else {
                return self.walk_stack(ray, c, leaf);
            };
            c.nodes_visited += 1;
            if !n.is_leaf() {
                // The stack walk's plane decision, written out as there (see `walk_stack`);
                // a fork records the face its plane forms instead of pushing the far side.
                let a = n.axis();
                let split = n.split() as f64;
                let (below, above) = (node + 1, n.upper());
                if r.d[a] == 0.0 {
                    // Parallel to the plane: the side holding the ray; lying in it, the stack
                    // walk visits both sides over the same interval.
                    if r.o[a] < split {
                        node = below;
                    } else if r.o[a] > split {
                        node = above;
                    } else {
                        return self.walk_stack(ray, c, leaf);
                    }
                    continue;
                }
                let tp = (split - r.o[a]) * r.inv[a];
                let (near, far, face) = if r.d[a] > 0.0 {
                    (below, above, 2 * a as u64 + 1)
                } else {
                    (above, below, 2 * a as u64)
                };
                if tp > tmax + r.eps {
                    node = near;
                } else if tp < tmin - r.eps {
                    node = far;
                } else {
                    if split_stack >= SPLIT_STACK_FULL {
                        return self.walk_stack(ray, c, leaf);
                    }
                    split_stack = split_stack << FACE_BITS | face;
                    node = near;
                    tmax = tp.clamp(tmin, tmax);
                }
                continue;
            }
            match self.visit_leaf(n, c, leaf) {
                Some(b) => bound = b.unwrap_or(bound),
                None => return true,
            }
            if split_stack == 1 {
                return true;
            }
            // Out by the face of the newest fork, to its far side, which starts where this
            // leaf ends. If that is past the closest hit so far, so are the older forks' far
            // sides (they start further along): the walk ends, as pbrt's does.
            let face = (split_stack & FACE_MASK) as usize;
            split_stack >>= FACE_BITS;
            tmin = tmax;
            if bound < tmin - r.eps {
                return true;
            }
            let Some((next, _)) = self.across_fork(ropes, node, face) else {
                return self.walk_stack(ray, c, leaf);
            };
            // Its interval ends where the ray leaves its cell.
            let mut exit = r.t1;
            for k in 0..3 {
                let f = if r.d[k] > 0.0 {
                    2 * k + 1
                } else if r.d[k] < 0.0 {
                    2 * k
                } else {
                    continue;
                };
                if let Some((_, plane)) = self.across_fork(ropes, next, f) {
                    exit = exit.min((plane - r.o[k]) * r.inv[k]);
                }
            }
            c.restarts += 1;
            (node, tmax) = (next, exit.max(tmin));
        }
    }
}

impl KdTraversal {
    /// Whether the walk needs ropes.
    pub(super) fn has_ropes(self) -> bool {
        matches!(
            self,
            KdTraversal::Ropes | KdTraversal::Popov | KdTraversal::SplitStack
        )
    }
}
