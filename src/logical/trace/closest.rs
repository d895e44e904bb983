//! The closest point of the surface to a query point: a best-first descent of the same wide
//! nodes the wide walk uses (spec §8.7), the top tree's, then each block's through the pager (so
//! a file larger than memory is queried within its budget), down to the triangle groups.
//!
//! A heap holds the nodes, links and groups not yet opened, keyed by the squared distance from
//! the point to their box (f64, from the boxes' exact f32 faces: a lower bound of the distance to
//! anything inside); the nearest is opened first, and the descent ends when the nearest left is
//! farther than the closest point found. Triangles are measured in f64 (Ericson, *Real-Time
//! Collision Detection*, 5.1.5), so the answer is the exact nearest triangle up to that rounding;
//! ties keep the smallest primitive id.
//!
//! Bounded whatever the bytes: every pop is paid from a budget of the top tree's nodes and twice
//! its links (a link and its block's first entry) plus, for each block entered, eight entries per wide node it has (a tree opens each entry
//! once); past it, the bytes are not a tree.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashSet};

use super::wide::bad;
use super::{Counters, Fetched, TraceError, Tree};
use crate::logical::held::WideHeld;
use crate::physical::format::{ClusterNode, TriGroup};

/// The closest point of the surface to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// The point on the surface.
    pub point: [f64; 3],
    /// Its squared distance from the query point.
    pub d2: f64,
    /// The triangle it lies on, and that triangle's corners.
    pub prim: u32,
    pub tri: [[f32; 3]; 3],
    /// Barycentric coordinates of the point: `(1 - u - v) v0 + u v1 + v v2`.
    pub u: f64,
    pub v: f64,
}

/// What the heap holds: a top-tree node, a link, a block's node, or a block's group.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Item {
    Top(u32),
    Link(u32),
    Node(u32, u32),
    Group(u32, u32),
}

/// An entry keyed by the bits of its (non-negative) squared distance, which order as the values.
type Entry = Reverse<(u64, Item)>;

thread_local! {
    /// The descent's heap and the blocks it entered, kept per thread so that a query costs no
    /// allocation once they have grown.
    static SCRATCH: std::cell::Cell<(BinaryHeap<Entry>, HashSet<u32>)> =
        std::cell::Cell::new((BinaryHeap::new(), HashSet::new()));
}

impl<'a> Tree<'a> {
    /// The closest point of the surface to `p` within `sqrt(max_d2)` of it (`None`: no
    /// triangle that near, or a file of leaf lists, which has no wide nodes).
    pub fn closest_point(
        &self,
        p: [f32; 3],
        max_d2: f64,
        c: &mut Counters,
    ) -> Result<Option<Nearest>, TraceError> {
        if !self.clusters || self.wide_top.is_empty() || p.iter().any(|x| !x.is_finite()) {
            return Ok(None);
        }
        let (mut heap, mut entered) = SCRATCH.take();
        heap.clear();
        entered.clear();
        let found = self.descend(p.map(f64::from), max_d2, c, &mut heap, &mut entered);
        SCRATCH.set((heap, entered));
        found
    }

    /// [`Self::closest_point`]'s descent from `q`, on `heap` and `entered` (empty).
    fn descend(
        &self,
        q: [f64; 3],
        max_d2: f64,
        c: &mut Counters,
        heap: &mut BinaryHeap<Entry>,
        entered: &mut HashSet<u32>,
    ) -> Result<Option<Nearest>, TraceError> {
        heap.push(Reverse((0, Item::Top(0))));
        let mut best: Option<Nearest> = None;
        let mut best_d2 = max_d2;
        // Each link pays for itself and for the first entry of its block, whose own entries
        // are paid for when it is entered.
        let mut budget = self.wide_top.len() + 2 * self.wide_links.len();
        c.rays += 1;
        while let Some(Reverse((key, item))) = heap.pop() {
            if f64::from_bits(key) > best_d2 {
                break;
            }
            budget = budget
                .checked_sub(1)
                .ok_or_else(|| bad("wide nodes that do not form a tree", None))?;
            match item {
                Item::Top(n) => {
                    let node = self.wide_top.get(n as usize);
                    let node = node.ok_or_else(|| bad("wide node index out of range", None))?;
                    c.nodes_visited += 1;
                    push_children(heap, node, &q, best_d2, |i, inner| match inner {
                        true => Item::Top(node.node_base.wrapping_add(i)),
                        false => Item::Link(node.group_base.wrapping_add(i)),
                    });
                }
                Item::Link(l) => {
                    let link = self.wide_links.get(l as usize);
                    let link = link.ok_or_else(|| bad("wide link index out of range", None))?;
                    heap.push(Reverse((key, Item::Node(link.block, link.root))));
                }
                Item::Node(b, n) | Item::Group(b, n) => {
                    let group = matches!(item, Item::Group(..));
                    self.in_block(b, c, |h, c| {
                        if entered.insert(b) {
                            budget = budget.saturating_add(8 * h.nodes.len() + 8);
                        }
                        if group {
                            return self.measure(h, n, &q, (&mut best, &mut best_d2), c);
                        }
                        let node = h.nodes.get(n as usize);
                        let node =
                            node.ok_or_else(|| bad("wide node index out of range", Some(b)))?;
                        c.nodes_visited += 1;
                        push_children(heap, node, &q, best_d2, |i, inner| match inner {
                            true => Item::Node(b, node.node_base.wrapping_add(i)),
                            false => Item::Group(b, node.group_base.wrapping_add(i)),
                        });
                        Ok(())
                    })?;
                }
            }
        }
        Ok(best)
    }

    /// Runs `f` on block `b` as the wide walk sees it, fetched through the pager.
    fn in_block<R>(
        &self,
        b: u32,
        c: &mut Counters,
        f: impl FnOnce(&WideHeld<'_>, &mut Counters) -> Result<R, TraceError>,
    ) -> Result<R, TraceError> {
        if b as usize >= self.directory.len() {
            return Err(bad(
                "wide link to a block the directory does not have",
                Some(b),
            ));
        }
        match self.fetch(b, &mut c.page)? {
            (b, Fetched::Direct(raw), ready) => f(&ready.wide(b, raw), c),
            (b, paged, ready) => f(&ready.wide(b, &paged), c),
        }
    }

    /// Measures the triangles of group `gi` of block `h` from `q`, keeping the nearest.
    fn measure(
        &self,
        h: &WideHeld<'_>,
        gi: u32,
        q: &[f64; 3],
        (best, best_d2): (&mut Option<Nearest>, &mut f64),
        c: &mut Counters,
    ) -> Result<(), TraceError> {
        let out = || bad("triangle group index out of range", Some(h.id));
        let chunk;
        let g: &TriGroup = match h.groups.get(gi as usize) {
            Some(g) => g,
            None => {
                let ch = self.chunked(h.id, h.raw).ok_or_else(out)?;
                chunk = ch.group(h.id, gi as u64, &mut c.page)?;
                chunk.0.groups().get(chunk.1).ok_or_else(out)?
            }
        };
        c.groups_tested += 1;
        for l in 0..(g.count as usize).min(8) {
            c.triangles_tested += 1;
            let tri = g.triangle(l);
            let (point, u, v) = closest_on_triangle(q, &tri);
            let d2 = (0..3).map(|k| (point[k] - q[k]).powi(2)).sum::<f64>();
            let prim = g.prim[l];
            let better =
                d2 < *best_d2 || (d2 == *best_d2 && best.as_ref().is_some_and(|b| prim < b.prim));
            if better && d2 <= *best_d2 {
                *best_d2 = d2;
                *best = Some(Nearest {
                    point,
                    d2,
                    prim,
                    tri,
                    u,
                    v,
                });
            }
        }
        Ok(())
    }
}

/// Pushes the live children of `n` whose boxes are within `best_d2` of `q`, each as `item(i,
/// inner)` (`i` counted from the first inner child, or from the first leaf child).
fn push_children(
    heap: &mut BinaryHeap<Entry>,
    n: &ClusterNode,
    q: &[f64; 3],
    best_d2: f64,
    item: impl Fn(u32, bool) -> Item,
) {
    let view = n.view();
    let inner = n.inner_count as u32;
    for i in 0..(n.child_count as u32).min(8) {
        let (lo, hi) = view.child_box(i as usize);
        let d2: f64 = (0..3)
            .map(|k| {
                let (l, h) = (lo[k] as f64, hi[k] as f64);
                let d = (l - q[k]).max(q[k] - h).max(0.0);
                d * d
            })
            .sum();
        // NaN faces (bytes that are not a box) are opened, not skipped: never a missed triangle.
        let d2 = if d2.is_nan() { 0.0 } else { d2 };
        if d2 <= best_d2 {
            let it = if i < inner {
                item(i, true)
            } else {
                item(i - inner, false)
            };
            heap.push(Reverse((d2.to_bits(), it)));
        }
    }
}

/// The point of triangle `t` closest to `q`, and its barycentric coordinates `(u, v)` (the
/// point is `(1 - u - v) t0 + u t1 + v t2`), in f64 (Ericson, 5.1.5). A degenerate triangle
/// gives the closest point of its longest edge.
pub fn closest_on_triangle(q: &[f64; 3], t: &[[f32; 3]; 3]) -> ([f64; 3], f64, f64) {
    let [a, b, c] = t.map(|p| p.map(f64::from));
    let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let at = |u: f64, v: f64| std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]));
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(*q, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, 0.0, 0.0);
    }
    let bp = sub(*q, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (b, 1.0, 0.0);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let u = d1 / (d1 - d3);
        return (at(u, 0.0), u, 0.0);
    }
    let cp = sub(*q, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (c, 0.0, 1.0);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let v = d2 / (d2 - d6);
        return (at(0.0, v), 0.0, v);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (at(1.0 - w, w), 1.0 - w, w);
    }
    let denom = va + vb + vc;
    let (u, v) = (vb / denom, vc / denom);
    if !(u.is_finite() && v.is_finite()) {
        // Degenerate (zero area): the nearest of its three edges' closest points.
        let seg = |p: [f64; 3], r: [f64; 3], up: f64, vp: f64, ur: f64, vr: f64| {
            let d = sub(r, p);
            let len = dot(d, d);
            let s = if len > 0.0 {
                (dot(sub(*q, p), d) / len).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let pt: [f64; 3] = std::array::from_fn(|k| p[k] + s * d[k]);
            (pt, up + s * (ur - up), vp + s * (vr - vp))
        };
        let dist = |x: &([f64; 3], f64, f64)| dot(sub(x.0, *q), sub(x.0, *q));
        let cands = [
            seg(a, b, 0.0, 0.0, 1.0, 0.0),
            seg(b, c, 1.0, 0.0, 0.0, 1.0),
            seg(c, a, 0.0, 1.0, 0.0, 0.0),
        ];
        return cands
            .into_iter()
            .min_by(|x, y| dist(x).total_cmp(&dist(y)))
            .unwrap_or((a, 0.0, 0.0));
    }
    (at(u, v), u, v)
}
