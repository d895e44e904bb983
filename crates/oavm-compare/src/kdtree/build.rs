//! Building the KD-tree.
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

use std::cmp::Ordering;
use std::time::Instant;

use rayon::prelude::*;

use super::KdTree;
use super::node::{KdNode, MAX_30};
use super::traverse::{KdTraversal, STACK};
use crate::aabb::{Aabb, padded_bounds};
use crate::leaf::{Soup, Tri};
use crate::{StructureStats, Triangles};
use oavm::geom::tribox::clipped_bounds;

/// pbrt-v3's SAH constants.
pub const TRAVERSAL_COST: f64 = 1.0;
pub const ISECT_COST: f64 = 80.0;
pub const EMPTY_BONUS: f64 = 0.5;
pub const MAX_BAD_REFINES: u32 = 3;
/// Deepest tree built: a root-to-leaf path pushes at most one entry per interior node on it.
pub const MAX_DEPTH_CAP: u32 = STACK as u32 - 2;

const END: u8 = 0;
const PLANAR: u8 = 1;
const START: u8 = 2;

/// A triangle's bound on one axis (Wald and Havran's event).
#[derive(Clone, Copy, Debug)]
pub(super) struct Event {
    pos: f32,
    tri: u32,
    axis: u8,
    kind: u8,
}

/// The event order: axis, position, type (end < planar < start), then triangle (for a
/// deterministic build). Positions are finite and never -0.
pub(super) fn event_order(a: &Event, b: &Event) -> Ordering {
    a.axis
        .cmp(&b.axis)
        .then(a.pos.total_cmp(&b.pos))
        .then(a.kind.cmp(&b.kind))
        .then(a.tri.cmp(&b.tri))
}

/// Appends the events of triangle `tri` with bounds `[lo, hi]`.
pub(super) fn push_events(out: &mut Vec<Event>, tri: u32, lo: [f32; 3], hi: [f32; 3]) {
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
pub(super) fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x { f.next_down() } else { f }
}
pub(super) fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

fn area(lo: [f32; 3], hi: [f32; 3]) -> f64 {
    Aabb { lo, hi }.area()
}

/// The best plane of a node.
#[derive(Clone, Copy, Debug)]
pub(super) struct Split {
    pub(super) cost: f64,
    pub(super) axis: usize,
    pub(super) pos: f32,
    /// Triangles lying in the plane go to the below (left) child.
    pub(super) planar_left: bool,
}

/// One sweep over a node's sorted events: the SAH-best plane strictly inside `[lo, hi]`.
pub(super) fn sweep(events: &[Event], n: usize, lo: [f32; 3], hi: [f32; 3]) -> Option<Split> {
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
    tris: &'a [Tri],
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
        let soup = Soup::finite(tris);
        let n = soup.len();
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
            soup: Soup::default(),
            max_depth,
            brute: false,
            traversal: KdTraversal::Stack,
            ropes: None,
            stats: StructureStats {
                name: "kdtree",
                ..StructureStats::default()
            },
        };
        if let Some((lo, hi)) = padded_bounds(&soup.v) {
            kd.lo = lo;
            kd.hi = hi;
            kd.centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
            kd.diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
            if u32::try_from(n).is_ok() {
                // Root: every triangle's bounds, sorted once.
                let mut events = Vec::with_capacity(6 * n);
                let mut root = Aabb::EMPTY;
                for (i, t) in soup.v.iter().enumerate() {
                    let b = Aabb::of_triangle(t);
                    root.grow_box(&b.lo, &b.hi);
                    push_events(&mut events, i as u32, b.lo, b.hi);
                }
                events.par_sort_unstable_by(event_order);
                let mut b = Builder {
                    tris: &soup.v,
                    side: vec![BOTH; n],
                    nodes: Vec::new(),
                    leaf_prims: Vec::new(),
                    overflow: false,
                };
                b.node(events, n, root.lo, root.hi, max_depth, 0);
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
        kd.soup = soup;
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
            + kd.soup.bytes()) as u64;
        kd
    }
}
