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
//! stored: the source rebuilds it from its 64-bit `SplitStack` of the faces that caused each
//! fork; a CPU stores it for 24 bytes a leaf and computes nothing), taking that face's rope.
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

use super::{KdTraversal, KdTree};
use crate::compare::leaf::NO_HIT;
use crate::geom::Ray;
use crate::logical::Counters;

/// No node across this face: the scene's boundary.
pub(super) const NONE: u32 = u32::MAX;

/// A tree's ropes and leaf cells (module docs).
pub(super) struct Ropes {
    /// Per node: the node across each face (−x, +x, −y, +y, −z, +z) of a leaf, or [`NONE`].
    pub(super) across: Vec<[u32; 6]>,
    /// Per node: its cell's low and high corners.
    pub(super) cell: Vec<[[f32; 3]; 2]>,
}

impl Ropes {
    /// The ropes of `kd`'s nodes (`popov`: pushed down to the smallest node across each face).
    pub(super) fn build(kd: &KdTree, popov: bool) -> Ropes {
        let n = kd.nodes.len();
        let mut r = Ropes {
            across: vec![[NONE; 6]; n],
            cell: vec![[[0.0; 3]; 2]; n],
        };
        if n == 0 {
            return r;
        }
        let root = [kd.lo.map(|x| x as f32), kd.hi.map(|x| x as f32)];
        let mut stack = vec![(0usize, [NONE; 6], root)];
        while let Some((i, clues, cell)) = stack.pop() {
            let Some(nd) = kd.nodes.get(i) else { continue };
            r.cell[i] = cell;
            if nd.is_leaf() {
                r.across[i] = clues;
                continue;
            }
            let (a, s) = (nd.axis(), nd.split());
            let (below, above) = (i + 1, nd.upper() as usize);
            let (mut cb, mut ca) = (clues, clues);
            cb[2 * a + 1] = above as u32;
            ca[2 * a] = below as u32;
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

    /// Bytes stored: six ropes and a cell per node.
    pub(super) fn bytes(&self) -> usize {
        self.across.len() * (24 + 24)
    }
}

/// The smallest node under `t` that holds all of face `f` of a leaf whose cell is `leaf`.
fn push_down(kd: &KdTree, mut t: u32, f: usize, leaf: &[[f32; 3]; 2]) -> u32 {
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
}

impl KdTraversal {
    /// Whether the walk needs ropes.
    pub(super) fn has_ropes(self) -> bool {
        matches!(self, KdTraversal::Ropes | KdTraversal::Popov)
    }
}
