//! The paper's "improved KD-tree": surface-area-heuristic splits with an empty-space bonus,
//! perfect splits, an O(N log N) build, and stack traversal.
//!
//! **Split choice** is pbrt-v3's `KdTreeAccel` (Pharr, Jakob and Humphreys, *Physically Based
//! Rendering*, 3rd ed., §4.4): a node of `N` triangles and surface area `A` split at a plane into
//! children of areas `A_b`, `A_a` holding `N_b`, `N_a` triangles costs
//! `1 + 80 (1 - b) (A_b N_b + A_a N_a) / A` (traversal cost 1, intersection cost 80, `b` = 0.5
//! when one side is empty, else 0) against `80 N` for a leaf. A node becomes a leaf when it holds
//! at most one triangle, at depth `round(8 + 1.3 floor(log2 N))` (capped at [`MAX_DEPTH_CAP`]),
//! when no plane lies strictly inside it, or when splitting does not pay: the best cost is more
//! than 4 times the leaf cost with fewer than 16 triangles, or the best split has been worse than
//! a leaf 3 times on the path from the root ("bad refines").
//!
//! **Build in O(N log N)**, the algorithm of Wald and Havran, "On building fast kd-trees for ray
//! tracing, and on doing that in O(N log N)" (IEEE Symposium on Interactive Ray Tracing 2006):
//! each triangle has a start and an end event per axis (or one *planar* event when it is flat
//! along that axis), sorted once at the root by (axis, position, type: end < planar < start).
//! At a node one sweep over its sorted events evaluates every candidate plane of all three axes;
//! planar triangles on the plane are tried on either side and put where they cost less (Wald and
//! Havran §4.2). Triangles are then classified left / right / both from the events on the chosen
//! axis, and the event list is split into the children's lists by one stable pass, so they stay
//! sorted without sorting. The triangles that straddle the plane are clipped to each child box
//! (*perfect splits*: [`clipped_bounds`], Sutherland–Hodgman on the real triangle, so a child
//! only keeps a triangle that really enters it, with the bounds of the part inside); only their
//! new events, O(sqrt N) per node for typical meshes, are sorted and merged in. Every level of the
//! tree therefore costs O(N) and the build O(N log N) after the one root sort. Clipped bounds are
//! rounded outward to f32, so a triangle's events always cover it. The build is sequential after
//! the root sort (rayon). Measured with `oavm-bench --structure kdtree` (release, 2 shared
//! cores) on the dragon: 55 ms for 11,102 triangles, 221 ms for 47,794, 757 ms for 202,520 and
//! 2.16 s for 871,306, i.e. 0.37, 0.30, 0.21 and 0.13 µs per `N log2 N`: no worse than
//! O(N log N), the per-triangle cost falling where the depth limit ends the finer meshes' trees
//! early.
//!
//! **Storage** is pbrt's 8-byte node ([`KdNode`]): an interior node stores its split position
//! (f32), its axis (2 bits) and the index of its above child (30 bits); the below child follows
//! it in the array (depth-first layout). A leaf stores its triangle count (30 bits) and either
//! the single triangle's index in place or an offset into the leaf primitive list. Node indices
//! and leaf sizes beyond 30 bits are refused by checked narrowing (a node that would need one is
//! made a leaf; an input that cannot be stored at all is traced by brute force instead).
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
//! **Counting** (the paper's Table 2 sense): `nodes` = all nodes, interior and leaves;
//! `pointers` = one above-child index per interior node plus one primitive-list offset per leaf
//! with more than one triangle (a one-triangle leaf holds the triangle's index in place of the
//! pointer, an empty leaf holds nothing); `bytes` = nodes (8 bytes each), the leaf primitive list
//! (4 bytes per entry), the triangles (36 bytes) and their primitive ids (4 bytes). While
//! tracing, `nodes_visited` counts every node visited (interior and leaf) and `leaves_visited`
//! the leaves among them.

use std::cmp::Ordering;
use std::time::Instant;

use rayon::prelude::*;

use super::grid::{clip_ray, finite_triangles, padded_bounds};
use super::{Accelerator, StructureStats, Triangles, brute_force, closer};
use crate::geom::triangle::RayShear;
use crate::geom::tribox::clipped_bounds;
use crate::geom::{Hit, Ray};
use crate::logical::Counters;

/// pbrt-v3's SAH constants.
pub const TRAVERSAL_COST: f64 = 1.0;
pub const ISECT_COST: f64 = 80.0;
pub const EMPTY_BONUS: f64 = 0.5;
pub const MAX_BAD_REFINES: u32 = 3;
/// Entries of the traversal stack.
pub const STACK: usize = 64;
/// Deepest tree built: a root-to-leaf path pushes at most one entry per interior node on it.
pub const MAX_DEPTH_CAP: u32 = STACK as u32 - 2;
/// Node indices and leaf sizes are stored in 30 bits.
const MAX_30: usize = (1 << 30) - 1;

/// pbrt's `KdAccelNode`, 8 bytes. Interior: `a` = split position (f32 bits), `b` = axis (low 2
/// bits) | above child index << 2. Leaf: `b` = 3 | triangle count << 2, `a` = the triangle's
/// index (one triangle) or the offset of the leaf's list in the primitive list.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KdNode {
    a: u32,
    b: u32,
}
const _: () = assert!(std::mem::size_of::<KdNode>() == 8);

impl KdNode {
    fn interior(axis: usize, split: f32, above: u32) -> KdNode {
        KdNode {
            a: split.to_bits(),
            b: axis as u32 | above << 2,
        }
    }
    fn leaf(count: u32, a: u32) -> KdNode {
        KdNode {
            a,
            b: 3 | count << 2,
        }
    }
    pub fn is_leaf(&self) -> bool {
        self.b & 3 == 3
    }
    fn axis(&self) -> usize {
        (self.b & 3) as usize
    }
    fn split(&self) -> f32 {
        f32::from_bits(self.a)
    }
    /// Above child (interior) or triangle count (leaf).
    fn upper(&self) -> u32 {
        self.b >> 2
    }
}

/// An SAH KD-tree over triangles (module docs).
pub struct KdTree {
    /// Root box for clipping rays (the triangles' box, padded).
    lo: [f64; 3],
    hi: [f64; 3],
    /// Scale of the scene (diagonal) and its centre, for the traversal tolerance.
    diag: f64,
    centre: [f64; 3],
    nodes: Vec<KdNode>,
    leaf_prims: Vec<u32>,
    tris: Vec<[[f32; 3]; 3]>,
    prim: Vec<u32>,
    max_depth: u32,
    /// Too large to store with 30-bit indices: every ray tests every triangle.
    brute: bool,
    stats: StructureStats,
}

const END: u8 = 0;
const PLANAR: u8 = 1;
const START: u8 = 2;

/// A triangle's bound on one axis (Wald and Havran's event).
#[derive(Clone, Copy, Debug)]
struct Event {
    pos: f32,
    tri: u32,
    axis: u8,
    kind: u8,
}

/// The event order: axis, position, type (end < planar < start), then triangle (for a
/// deterministic build). Positions are finite and never -0.
fn event_order(a: &Event, b: &Event) -> Ordering {
    a.axis
        .cmp(&b.axis)
        .then(a.pos.total_cmp(&b.pos))
        .then(a.kind.cmp(&b.kind))
        .then(a.tri.cmp(&b.tri))
}

/// Appends the events of triangle `tri` with bounds `[lo, hi]`.
fn push_events(out: &mut Vec<Event>, tri: u32, lo: [f32; 3], hi: [f32; 3]) {
    for k in 0..3 {
        // + 0.0 turns -0 into +0, which `total_cmp` would order before +0.
        let (l, h) = (lo[k] + 0.0, hi[k] + 0.0);
        let axis = k as u8;
        if l == h {
            out.push(Event {
                pos: l,
                tri,
                axis,
                kind: PLANAR,
            });
        } else {
            out.push(Event {
                pos: l,
                tri,
                axis,
                kind: START,
            });
            out.push(Event {
                pos: h,
                tri,
                axis,
                kind: END,
            });
        }
    }
}

/// The largest f32 not above `x`, and the smallest not below.
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x { f.next_down() } else { f }
}
fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

fn area(lo: [f32; 3], hi: [f32; 3]) -> f64 {
    let e: [f64; 3] = std::array::from_fn(|k| (hi[k] as f64 - lo[k] as f64).max(0.0));
    2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])
}

/// The best plane of a node.
#[derive(Clone, Copy, Debug)]
struct Split {
    cost: f64,
    axis: usize,
    pos: f32,
    /// Triangles lying in the plane go to the below (left) child.
    planar_left: bool,
}

/// One sweep over a node's sorted events: the SAH-best plane strictly inside `[lo, hi]`.
fn sweep(events: &[Event], n: usize, lo: [f32; 3], hi: [f32; 3]) -> Option<Split> {
    let sa = area(lo, hi);
    if sa.is_nan() || sa <= 0.0 {
        return None;
    }
    let inv_sa = 1.0 / sa;
    let mut nl = [0usize; 3];
    let mut nr = [n; 3];
    let mut best: Option<Split> = None;
    let mut i = 0;
    while i < events.len() {
        let (axis, pos) = (events[i].axis, events[i].pos);
        let mut count = [0usize; 3];
        for kind in [END, PLANAR, START] {
            while i < events.len()
                && events[i].axis == axis
                && events[i].pos == pos
                && events[i].kind == kind
            {
                count[kind as usize] += 1;
                i += 1;
            }
        }
        let [pe, pp, ps] = count;
        let a = axis as usize;
        nr[a] = nr[a].saturating_sub(pp + pe);
        if pos > lo[a] && pos < hi[a] {
            let (mut bh, mut al) = (hi, lo);
            bh[a] = pos;
            al[a] = pos;
            let (pb, pa) = (area(lo, bh) * inv_sa, area(al, hi) * inv_sa);
            let cost = |below: usize, above: usize| {
                let bonus = if below == 0 || above == 0 {
                    EMPTY_BONUS
                } else {
                    0.0
                };
                TRAVERSAL_COST
                    + ISECT_COST * (1.0 - bonus) * (pb * below as f64 + pa * above as f64)
            };
            let (left, right) = (cost(nl[a] + pp, nr[a]), cost(nl[a], nr[a] + pp));
            let (cost, planar_left) = if left <= right {
                (left, true)
            } else {
                (right, false)
            };
            if best.is_none_or(|b| cost < b.cost) {
                best = Some(Split {
                    cost,
                    axis: a,
                    pos,
                    planar_left,
                });
            }
        }
        nl[a] += ps + pp;
    }
    best
}

/// Merges two lists sorted by [`event_order`].
fn merge(a: Vec<Event>, b: Vec<Event>) -> Vec<Event> {
    if b.is_empty() {
        return a;
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if event_order(&a[i], &b[j]) != Ordering::Greater {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// Whether an event opens a triangle's entry on axis 0: exactly one per triangle of a node.
fn first(e: &Event) -> bool {
    e.axis == 0 && e.kind != END
}

const BOTH: u8 = 0;
const LEFT: u8 = 1;
const RIGHT: u8 = 2;

struct Builder<'a> {
    tris: &'a [[[f32; 3]; 3]],
    /// Per triangle: its side of the current split (scratch).
    side: Vec<u8>,
    nodes: Vec<KdNode>,
    leaf_prims: Vec<u32>,
    /// Something did not fit 30/32-bit storage.
    overflow: bool,
}

impl Builder<'_> {
    fn node(
        &mut self,
        events: Vec<Event>,
        n: usize,
        lo: [f32; 3],
        hi: [f32; 3],
        depth: u32,
        mut bad: u32,
    ) {
        let at = self.nodes.len();
        // A node leaves room for its two children's indices within 30 bits.
        if n <= 1 || depth == 0 || at + 2 >= MAX_30 {
            return self.leaf(&events);
        }
        let leaf_cost = ISECT_COST * n as f64;
        let Some(s) = sweep(&events, n, lo, hi) else {
            return self.leaf(&events);
        };
        if s.cost > leaf_cost {
            bad += 1;
        }
        if (s.cost > 4.0 * leaf_cost && n < 16) || bad >= MAX_BAD_REFINES {
            return self.leaf(&events);
        }
        let (mut below_hi, mut above_lo) = (hi, lo);
        below_hi[s.axis] = s.pos;
        above_lo[s.axis] = s.pos;
        let (el, nl, er, nr) = self.split(events, &s, lo, below_hi, above_lo, hi);
        self.nodes.push(KdNode::default());
        self.node(el, nl, lo, below_hi, depth - 1, bad);
        let above = self.nodes.len();
        self.node(er, nr, above_lo, hi, depth - 1, bad);
        match u32::try_from(above) {
            Ok(above) if (above as usize) <= MAX_30 => {
                self.nodes[at] = KdNode::interior(s.axis, s.pos, above)
            }
            _ => self.overflow = true,
        }
    }

    fn leaf(&mut self, events: &[Event]) {
        let mut ids: Vec<u32> = events.iter().filter(|e| first(e)).map(|e| e.tri).collect();
        ids.sort_unstable();
        let node = match ids.len() {
            0 => KdNode::leaf(0, 0),
            1 => KdNode::leaf(1, ids[0]),
            k => match u32::try_from(self.leaf_prims.len()) {
                Ok(offset) if k <= MAX_30 => {
                    self.leaf_prims.extend_from_slice(&ids);
                    KdNode::leaf(k as u32, offset)
                }
                _ => {
                    self.overflow = true;
                    KdNode::leaf(0, 0)
                }
            },
        };
        self.nodes.push(node);
    }

    /// Splits a node's events into its children's (Wald and Havran §5.3), clipping the
    /// triangles that straddle the plane to each child (perfect splits).
    fn split(
        &mut self,
        events: Vec<Event>,
        s: &Split,
        below_lo: [f32; 3],
        below_hi: [f32; 3],
        above_lo: [f32; 3],
        above_hi: [f32; 3],
    ) -> (Vec<Event>, usize, Vec<Event>, usize) {
        for e in &events {
            self.side[e.tri as usize] = BOTH;
        }
        for e in events.iter().filter(|e| e.axis as usize == s.axis) {
            let side = &mut self.side[e.tri as usize];
            match e.kind {
                END if e.pos <= s.pos => *side = LEFT,
                START if e.pos >= s.pos => *side = RIGHT,
                PLANAR => {
                    *side = if e.pos < s.pos || (e.pos == s.pos && s.planar_left) {
                        LEFT
                    } else {
                        RIGHT
                    }
                }
                _ => {}
            }
        }
        let (mut el, mut er) = (Vec::new(), Vec::new());
        let (mut nl, mut nr) = (0, 0);
        let mut both = Vec::new();
        for e in &events {
            match self.side[e.tri as usize] {
                LEFT => {
                    el.push(*e);
                    nl += first(e) as usize;
                }
                RIGHT => {
                    er.push(*e);
                    nr += first(e) as usize;
                }
                _ if first(e) => both.push(e.tri),
                _ => {}
            }
        }
        drop(events);
        let (mut bl, mut br) = (Vec::new(), Vec::new());
        let to64 = |p: [f32; 3]| p.map(|c| c as f64);
        for &t in &both {
            let tv = self.tris[t as usize].map(to64);
            for (lo, hi, out, count) in [
                (below_lo, below_hi, &mut bl, &mut nl),
                (above_lo, above_hi, &mut br, &mut nr),
            ] {
                if let Some((l, h)) = clipped_bounds(&tv, to64(lo), to64(hi)) {
                    push_events(out, t, l.map(f32_down), h.map(f32_up));
                    *count += 1;
                }
            }
        }
        bl.sort_unstable_by(event_order);
        br.sort_unstable_by(event_order);
        (merge(el, bl), nl, merge(er, br), nr)
    }
}

impl KdTree {
    pub fn build(tris: &Triangles) -> KdTree {
        let start = Instant::now();
        let (v, prim) = finite_triangles(tris);
        let n = v.len();
        let max_depth = if n == 0 {
            0
        } else {
            ((8.0 + 1.3 * n.ilog2() as f64).round() as u32).min(MAX_DEPTH_CAP)
        };
        let mut kd = KdTree {
            lo: [0.0; 3],
            hi: [0.0; 3],
            diag: 0.0,
            centre: [0.0; 3],
            nodes: Vec::new(),
            leaf_prims: Vec::new(),
            tris: Vec::new(),
            prim,
            max_depth,
            brute: false,
            stats: StructureStats {
                name: "kdtree",
                ..StructureStats::default()
            },
        };
        if let Some((lo, hi)) = padded_bounds(&v) {
            kd.lo = lo;
            kd.hi = hi;
            kd.centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
            kd.diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
            if u32::try_from(n).is_ok() {
                // Root: every triangle's bounds, sorted once.
                let mut events = Vec::with_capacity(6 * n);
                let (mut rlo, mut rhi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                for (i, t) in v.iter().enumerate() {
                    let lo: [f32; 3] = std::array::from_fn(|k| t[0][k].min(t[1][k]).min(t[2][k]));
                    let hi: [f32; 3] = std::array::from_fn(|k| t[0][k].max(t[1][k]).max(t[2][k]));
                    for k in 0..3 {
                        rlo[k] = rlo[k].min(lo[k]);
                        rhi[k] = rhi[k].max(hi[k]);
                    }
                    push_events(&mut events, i as u32, lo, hi);
                }
                events.par_sort_unstable_by(event_order);
                let mut b = Builder {
                    tris: &v,
                    side: vec![BOTH; n],
                    nodes: Vec::new(),
                    leaf_prims: Vec::new(),
                    overflow: false,
                };
                b.node(events, n, rlo, rhi, max_depth, 0);
                if b.overflow {
                    kd.brute = true;
                } else {
                    kd.nodes = b.nodes;
                    kd.leaf_prims = b.leaf_prims;
                }
            } else {
                kd.brute = true;
            }
        }
        kd.tris = v;
        let interior = kd.nodes.iter().filter(|n| !n.is_leaf()).count();
        let lists = kd
            .nodes
            .iter()
            .filter(|n| n.is_leaf() && n.upper() > 1)
            .count();
        kd.stats.build_seconds = start.elapsed().as_secs_f64();
        kd.stats.nodes = kd.nodes.len() as u64;
        kd.stats.pointers = (interior + lists) as u64;
        kd.stats.bytes = (std::mem::size_of::<KdTree>()
            + std::mem::size_of::<KdNode>() * kd.nodes.len()
            + 4 * kd.leaf_prims.len()
            + std::mem::size_of::<[[f32; 3]; 3]>() * kd.tris.len()
            + 4 * kd.prim.len()) as u64;
        kd
    }

    /// The depth limit the build used.
    pub fn max_depth(&self) -> u32 {
        self.max_depth
    }

    /// Depth of the deepest leaf (the root has depth 0) and the number of leaves.
    pub fn depth_and_leaves(&self) -> (u32, usize) {
        let (mut deepest, mut leaves) = (0, 0);
        let mut stack = vec![(0usize, 0u32)];
        while let Some((i, d)) = stack.pop() {
            let Some(n) = self.nodes.get(i) else { continue };
            if n.is_leaf() {
                deepest = deepest.max(d);
                leaves += 1;
            } else {
                stack.push((i + 1, d + 1));
                stack.push((n.upper() as usize, d + 1));
            }
        }
        (deepest, leaves)
    }

    /// Walks the nodes `ray` crosses front to back, calling `leaf(triangles, c)` on each leaf;
    /// `leaf` returns the `t` of the closest hit so far (`+inf` for none, `-inf` to stop). Returns
    /// `false` if the walk could not be completed (a full stack: never, by the depth cap).
    #[inline]
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut leaf: impl FnMut(&[u32], &mut Counters) -> f64,
    ) -> bool {
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
        let mut bound = f64::INFINITY;
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
                let count = n.upper() as usize;
                let prims = if count == 1 {
                    std::slice::from_ref(&n.a)
                } else {
                    let at = n.a as usize;
                    self.leaf_prims.get(at..at + count).unwrap_or(&[])
                };
                if !prims.is_empty() {
                    bound = leaf(prims, c);
                    if bound == f64::NEG_INFINITY {
                        return true;
                    }
                }
            }
            if sp == 0 {
                return true;
            }
            sp -= 1;
            (node, tmin, tmax) = stack[sp];
        }
    }

    fn brute_intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        brute_force(&self.tris, &self.prim, ray, c)
    }
}

impl Accelerator for KdTree {
    fn stats(&self) -> &StructureStats {
        &self.stats
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        if !ray.is_valid() || self.tris.is_empty() {
            return Hit::MISS;
        }
        if self.brute {
            return self.brute_intersect(ray, c);
        }
        let sh = RayShear::new(ray);
        let mut best = Hit::MISS;
        let mut tmax = ray.tmax;
        let complete = self.walk(ray, c, |prims, c| {
            for &i in prims {
                c.triangles_tested += 1;
                let i = i as usize;
                if let Some(t) = sh.intersect(&self.tris[i], ray.tmin, tmax)
                    && closer(&mut best, t, self.prim[i])
                {
                    tmax = t;
                }
            }
            if best.is_hit() {
                best.t as f64
            } else {
                f64::INFINITY
            }
        });
        if complete {
            best
        } else {
            self.brute_intersect(ray, c)
        }
    }

    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
        if !ray.is_valid() || self.tris.is_empty() {
            return false;
        }
        if self.brute {
            return self.brute_intersect(ray, c).is_hit();
        }
        let sh = RayShear::new(ray);
        let mut found = false;
        let complete = self.walk(ray, c, |prims, c| {
            for &i in prims {
                c.triangles_tested += 1;
                if sh
                    .intersect(&self.tris[i as usize], ray.tmin, ray.tmax)
                    .is_some()
                {
                    found = true;
                    return f64::NEG_INFINITY;
                }
            }
            f64::INFINITY
        });
        if complete {
            found
        } else {
            self.brute_intersect(ray, c).is_hit()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::grid::tests::{check, rays, rng, soup, tris_of};

    /// Every triangle is referenced by some leaf, and the tree respects its depth limit.
    fn check_structure(kd: &KdTree, n: usize) {
        assert!(!kd.brute);
        let (depth, leaves) = kd.depth_and_leaves();
        assert!(depth <= kd.max_depth(), "{depth} > {}", kd.max_depth());
        assert_eq!(leaves, kd.nodes.iter().filter(|x| x.is_leaf()).count());
        let mut seen = vec![false; n];
        for nd in kd.nodes.iter().filter(|x| x.is_leaf()) {
            match nd.upper() {
                0 => {}
                1 => seen[nd.a as usize] = true,
                k => {
                    for &i in &kd.leaf_prims[nd.a as usize..][..k as usize] {
                        seen[i as usize] = true;
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s), "a triangle is in no leaf");
    }

    #[test]
    fn random_soup_matches_brute_force() {
        let (tris, mesh) = tris_of(soup(800, 11));
        let kd = KdTree::build(&tris);
        check_structure(&kd, 800);
        let s = kd.stats();
        assert!(s.nodes > 100 && s.pointers > 50, "{s:?}");
        assert!(check(&kd, &mesh, &rays(5000, 12)) > 800);
    }

    #[test]
    fn event_sweep_counts_planar_triangles() {
        // Two triangles flat in x at x = 0.5 and one spanning [0, 1]: at the plane x = 0.5 the
        // sweep sees 1 triangle on the left, 2 planar and 1 on the right.
        let mut ev = Vec::new();
        push_events(&mut ev, 0, [0.5, 0.0, 0.0], [0.5, 1.0, 1.0]);
        push_events(&mut ev, 1, [0.5, 0.0, 0.0], [0.5, 1.0, 1.0]);
        push_events(&mut ev, 2, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
        ev.sort_by(event_order);
        let s = sweep(&ev, 3, [0.0; 3], [1.0; 3]).unwrap();
        assert_eq!((s.axis, s.pos), (0, 0.5));
        // Both sides cost the same; ties go left.
        assert!(s.planar_left);
        assert!(s.cost < ISECT_COST * 3.0);
    }

    #[test]
    fn empty_single_and_invalid() {
        let kd = KdTree::build(&Triangles::default());
        let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        let mut c = Counters::default();
        assert_eq!(kd.intersect(&r, &mut c), Hit::MISS);
        assert!(!kd.occluded(&r, &mut c));
        assert_eq!(kd.stats().nodes, 0);

        let (tris, mesh) = tris_of(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
        let kd = KdTree::build(&tris);
        assert_eq!(kd.stats().nodes, 1);
        assert_eq!(kd.stats().pointers, 0);
        let down = Ray::new([0.25, 0.25, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(kd.intersect(&down, &mut c), Hit { t: 1.0, prim: 0 });
        check(&kd, &mesh, &rays(2000, 13));
        let bad = Ray::new([0.25, 0.25, 1.0], [f32::NAN, 0.0, -1.0], 0.0, 9.0);
        assert_eq!(kd.intersect(&bad, &mut c), Hit::MISS);
        assert!(!kd.occluded(&bad, &mut c));
    }

    #[test]
    fn flat_mesh_and_planes_of_triangles_on_split_planes() {
        let mut r = rng(14);
        let flat: Vec<_> = (0..600)
            .map(|_| {
                let (x, y) = (r(), r());
                [[x, y, 0.5], [x + 0.04, y, 0.5], [x, y + 0.04, 0.5]]
            })
            .collect();
        let (tris, mesh) = tris_of(flat);
        let kd = KdTree::build(&tris);
        check_structure(&kd, 600);
        assert!(kd.stats().nodes > 50);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = [r(), r(), r() * 2.0 - 0.5];
            let d = if o[2] > 0.5 { -1.0 } else { 1.0 };
            let axis = Ray::new(o, [0.0, 0.0, d], 0.0, f32::INFINITY);
            let slanted = Ray::new(o, [r() - 0.5, r() - 0.5, d], 0.0, f32::INFINITY);
            let inplane = Ray::new([o[0], o[1], 0.5], [r() - 0.5, r() - 0.5, 0.0], 0.0, 9.0);
            hits += check(&kd, &mesh, &[axis, slanted, inplane]);
        }
        assert!(hits > 500, "{hits}");

        // Soup plus stacks of triangles flat in x at x = 0.25, 0.5, 0.75 (planar events, likely
        // split planes) and triangles meeting them edge-on; rays along every axis and slanted,
        // starting inside the tree.
        let mut v = soup(300, 15);
        for &x in &[0.25f32, 0.5, 0.75] {
            for i in 0..100 {
                let (y, z) = ((i % 10) as f32 / 10.0, (i / 10) as f32 / 10.0);
                v.push([[x, y, z], [x, y + 0.1, z], [x, y, z + 0.1]]);
                v.push([[x, y, z], [x + 0.05, y + 0.1, z], [x, y, z + 0.1]]);
            }
        }
        let n = v.len();
        let (tris, mesh) = tris_of(v);
        let kd = KdTree::build(&tris);
        check_structure(&kd, n);
        let mut hits = 0;
        for i in 0..6000 {
            let o = [r(), r(), r()];
            let mut d = [r() - 0.5, r() - 0.5, r() - 0.5];
            if i % 2 == 0 {
                d = [0.0; 3];
                d[i / 2 % 3] = if i % 4 == 0 { 1.0 } else { -1.0 };
            }
            hits += check(&kd, &mesh, &[Ray::new(o, d, 0.0, f32::INFINITY)]);
            // Rays lying in the planes.
            let o = [[0.25f32, 0.5, 0.75][i % 3], r(), r()];
            let d = [0.0, r() - 0.5, r() - 0.5];
            hits += check(&kd, &mesh, &[Ray::new(o, d, 0.0, f32::INFINITY)]);
        }
        assert!(hits > 2000, "{hits}");
    }

    #[test]
    fn range_limits_and_negative_tmin() {
        let (tris, mesh) = tris_of(soup(400, 16));
        let kd = KdTree::build(&tris);
        let mut r = rng(17);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = [r(), r(), r()];
            let d = [r() - 0.5, r() - 0.5, r() - 0.5];
            let (a, b) = (r() * 2.0 - 1.0, r() * 1.5);
            hits += check(&kd, &mesh, &[Ray::new(o, d, a.min(b), a.max(b))]);
        }
        assert!(hits > 300, "{hits}");
    }

    #[test]
    fn depth_is_limited_on_a_pathological_stack() {
        // 2000 identical-footprint triangles stacked along z: splits cannot separate many of
        // them cheaply, so bad refines and the depth limit must end the recursion.
        let v: Vec<_> = (0..2000)
            .map(|i| {
                let z = i as f32 * 1e-3;
                [[0.0, 0.0, z], [1.0, 0.0, z + 0.5], [0.0, 1.0, z + 0.25]]
            })
            .collect();
        let (tris, mesh) = tris_of(v);
        let kd = KdTree::build(&tris);
        check_structure(&kd, 2000);
        assert_eq!(kd.max_depth(), (8.0 + 1.3 * 10.0f64).round() as u32);
        let mut c = Counters::default();
        let hits = check(&kd, &mesh, &rays(500, 18));
        assert!(hits > 50, "{hits}");
        let r = Ray::new([0.1, 0.1, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY);
        let h = kd.intersect(&r, &mut c);
        assert!(h.is_hit());
        assert!(c.nodes_visited >= c.leaves_visited && c.leaves_visited >= 1);
        assert_eq!(c.rays, 0);
    }

    #[test]
    fn outward_rounding() {
        let x = 0.1f64;
        assert!((f32_down(x) as f64) <= x && (f32_up(x) as f64) >= x);
        assert!(f32_down(x) < f32_up(x));
        assert_eq!(f32_down(0.5), 0.5);
        assert_eq!(f32_up(0.5), 0.5);
    }
}
