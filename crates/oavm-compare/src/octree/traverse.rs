//! The classic octree's traversal.
//!
//! - per node, the ray's entry and exit `t` per axis (`t0`, `t1`) come from the parent; the
//!   node is entered if `max t0 <= min t1` and that interval meets `[tmin, tmax]` (`tmax`
//!   shrinks to the closest hit so far);
//! - negative direction components are handled by mirroring: with the bitmask `a` (bit `k` set
//!   where `dir[k] < 0`), the children are enumerated in the mirrored frame, where the ray runs
//!   toward `+` on every axis, and child `i` of the mirrored frame is child `i ^ a` of the tree;
//! - the first child is found from the mid-plane parameters `tm` against the node's entry
//!   `t` (Revelles' `first_node`, here against `max(entry, tmin)` so a ray starting inside the
//!   node starts in the child holding its origin), and each next child from the axis of the
//!   current child's exit (`new_node`): children come front to back, and the walk leaves the
//!   node when the exit axis already has its bit set;
//! - a zero direction component (either sign of zero) never crosses a plane: its slab is
//!   `(-inf, +inf)` if the origin is inside (else the ray misses the root), and its mid-plane
//!   parameter is `-inf` if the origin is on the upper side (the upper child is entered from
//!   the start) and `+inf` if not. These are set explicitly, so `0 * inf` never makes a NaN;
//!   every other parameter is finite, since f32 inputs scaled into f64 neither overflow nor
//!   vanish;
//! - a solid leaf's triangles go to the shared leaf test ([`crate::leaf`]). A leaf
//!   references every triangle overlapping its cell grown by
//!   `CELL_MARGIN` (2 lattice units, far more than the f64 rounding of the slab parameters), so
//!   a hit at `t` no later than the leaf's exit is final: no later leaf can hold a closer one,
//!   and the closest-hit query stops there. The any-hit query stops at the first hit.

use super::ClassicOctree;
use super::node::Kind;
use crate::Counters;
use crate::StructureStats;
use crate::leaf::{NO_HIT, Soup, Walk};
use oavm::geom::Ray;
use oavm::mapping::morton::LATTICE_SIZE;

/// A node's cell and the ray's parameters across it, in the mirrored frame.
#[derive(Clone, Copy)]
struct Cell {
    /// Lowest corner and edge, in lattice units.
    lo: [f64; 3],
    size: f64,
    /// Entry and exit `t` of the ray per axis.
    t0: [f64; 3],
    t1: [f64; 3],
}

/// One ray's walk down the octree.
struct Walker<'a, F> {
    tree: &'a ClassicOctree,
    /// The ray in lattice space.
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    /// Mirroring mask: bit `k` set where `d[k] < 0`.
    a: usize,
    tmin: f32,
    tmax: f32,
    /// What the last leaf test returned: the closest hit so far, or `NO_HIT`.
    bound: f32,
    leaf: F,
}

impl Walk for ClassicOctree {
    type Leaf = [u32];

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
        leaf: impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        if self.linear || self.nodes.is_empty() {
            return false;
        }
        let o: [f64; 3] =
            std::array::from_fn(|k| (ray.origin[k] as f64 - self.root_min[k]) * self.scale);
        let d: [f64; 3] = std::array::from_fn(|k| ray.dir[k] as f64 * self.scale);
        let mut w = Walker {
            tree: self,
            o,
            d,
            inv: std::array::from_fn(|k| if d[k] != 0.0 { 1.0 / d[k] } else { 0.0 }),
            a: (0..3).filter(|&k| d[k] < 0.0).map(|k| 1 << k).sum(),
            tmin: ray.tmin,
            tmax: ray.tmax,
            bound: NO_HIT,
            leaf,
        };
        let n = LATTICE_SIZE as f64;
        let mut t0 = [0f64; 3];
        let mut t1 = [0f64; 3];
        for k in 0..3 {
            if w.d[k] == 0.0 {
                if !(0.0..=n).contains(&w.o[k]) {
                    return true; // runs beside the root, never into it
                }
                t0[k] = f64::NEG_INFINITY;
                t1[k] = f64::INFINITY;
            } else {
                let (near, far) = if w.a >> k & 1 == 1 {
                    (n, 0.0)
                } else {
                    (0.0, n)
                };
                t0[k] = (near - w.o[k]) * w.inv[k];
                t1[k] = (far - w.o[k]) * w.inv[k];
            }
        }
        let root = Cell {
            lo: [0.0; 3],
            size: n,
            t0,
            t1,
        };
        w.visit(0, root, c);
        true
    }
}

impl<F: FnMut(&[u32], &mut Counters) -> f32> Walker<'_, F> {
    /// The far end of the interval still searched: the closest hit so far, or `tmax`.
    fn limit(&self) -> f32 {
        self.bound.min(self.tmax)
    }

    /// Revelles' `proc_subtree`: enters node `idx` over `cell`. Returns `true` when the walk is
    /// finished (a final hit was found).
    fn visit(&mut self, idx: u32, cell: Cell, c: &mut Counters) -> bool {
        c.nodes_visited += 1;
        let Cell { lo, size, t0, t1 } = cell;
        let tin = t0[0].max(t0[1]).max(t0[2]);
        let tout = t1[0].min(t1[1]).min(t1[2]);
        if tin > tout || tout < self.tmin as f64 || tin > self.limit() as f64 {
            return false;
        }
        let Some(node) = self.tree.nodes.get(idx as usize) else {
            return false; // never: indices are made by the build
        };
        match node.kind() {
            Kind::Leaf { first, count } => {
                c.leaves_visited += 1;
                if count == 0 {
                    return false;
                }
                let (first, count) = (first as usize, count as usize);
                let Some(list) = self.tree.refs.get(first..first + count) else {
                    return false;
                };
                // A hit no later than this leaf's exit is final (and STOP is below any exit).
                self.bound = (self.leaf)(list, c);
                self.bound as f64 <= tout
            }
            Kind::Internal(children) => {
                let half = size * 0.5;
                let tm: [f64; 3] = std::array::from_fn(|k| {
                    let mid = lo[k] + half;
                    if self.d[k] != 0.0 {
                        (mid - self.o[k]) * self.inv[k]
                    } else if self.o[k] >= mid {
                        f64::NEG_INFINITY
                    } else {
                        f64::INFINITY
                    }
                });
                // first_node: past the mid-plane of axis k at the start => upper (mirrored) half.
                let start = tin.max(self.tmin as f64);
                let mut ch = (0..3)
                    .filter(|&k| tm[k] < start)
                    .map(|k| 1usize << k)
                    .sum::<usize>();
                loop {
                    let bit = |k: usize| ch >> k & 1 == 1;
                    let actual = ch ^ self.a;
                    let child = Cell {
                        lo: std::array::from_fn(|k| {
                            if actual >> k & 1 == 1 {
                                lo[k] + half
                            } else {
                                lo[k]
                            }
                        }),
                        size: half,
                        t0: std::array::from_fn(|k| if bit(k) { tm[k] } else { t0[k] }),
                        t1: std::array::from_fn(|k| if bit(k) { t1[k] } else { tm[k] }),
                    };
                    if self.visit(children[actual], child, c) {
                        return true;
                    }
                    // new_node: leave the child across its nearest exit plane.
                    let mut axis = 0;
                    for k in 1..3 {
                        if child.t1[k] < child.t1[axis] {
                            axis = k;
                        }
                    }
                    if bit(axis) {
                        return false; // that plane is the node's own exit
                    }
                    ch |= 1 << axis;
                }
            }
        }
    }
}
