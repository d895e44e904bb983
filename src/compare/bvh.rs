//! A binned-SAH bounding volume hierarchy, the modern reference of the comparison, built and
//! traversed as pbrt-v4 does (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 4th ed.,
//! §7.3 "Bounding Volume Hierarchies").
//!
//! **Build** (pbrt-v4 §7.3.2, `BVHAggregate::buildRecursive`), top-down over the triangles'
//! bounding boxes and centroids:
//!
//! - a node holding one triangle is a leaf;
//! - otherwise the centroids are put into [`BINS`] equal bins along *each* of the three axes
//!   (pbrt-v4 bins only the longest centroid axis, with 12 bins; trying all three costs a little
//!   build time and gives a tree at least as good), and every split between adjacent bins is
//!   priced with the surface area heuristic: `cost = C_trav + (n_a A_a + n_b A_b) / A` with
//!   traversal cost `C_trav = 1` and a triangle test costing 1 (pbrt-v4 uses `1/2` for
//!   traversal, and splits nodes of two triangles at equal counts without pricing them; here
//!   they are priced like any other);
//! - the node becomes a leaf when it holds at most [`MAX_PRIMS_IN_NODE`] triangles and the leaf
//!   cost `n` is no more than the best split's cost (pbrt-v4's rule); otherwise it is split at the
//!   cheapest bin boundary. `MAX_PRIMS_IN_NODE = 4` is pbrt-v4's default (`maxprimsinnode`): the
//!   scenes of the comparison are triangle meshes where tracing is bound by triangle tests, and a
//!   leaf of four fills exactly one four-lane test ([`RayShear::intersect4`]);
//! - where binning cannot separate the triangles (all centroids in one bin, or equal
//!   centroids), the node is split at the median triangle along the longest centroid axis
//!   (pbrt-v4's `EqualCounts` fallback), so leaves never hold more than `MAX_PRIMS_IN_NODE`.
//!
//! **Depth bound.** Traversal uses a fixed stack of [`STACK_SIZE`] = 64 entries (pbrt-v4's
//! `nodesToVisit[64]`), and a descent pushes one entry per interior node, so the tree must be
//! at most 64 nodes deep. SAH splits can be very unbalanced, so from depth [`SAH_MAX_DEPTH`]
//! (= 32) on the build uses median splits only: each halves the count, and as a node holds fewer
//! than `2^32` triangles, 31 more levels bring it to four or fewer, so leaves are at depth ≤ 63.
//! The traversal still checks the stack (no `unsafe`, no panic): if it ever overflowed, the ray
//! would be answered by testing every triangle, which is correct if slow (it never happens).
//!
//! The top levels are built in parallel (`rayon::join` on the two children of nodes holding
//! more than [`PARALLEL_MIN`] triangles).
//!
//! **Layout.** The tree is flattened to pbrt-v4's `LinearBVHNode` ([`LinearNode`], 32 bytes:
//! bounds, `primitivesOffset` or `secondChildOffset`, `nPrimitives`, split axis) in depth-first
//! order: the first child of an interior node follows it, the second is found by its offset.
//! Triangles are reordered into leaf order, so a leaf's triangles are one contiguous run.
//!
//! **Traversal** (pbrt-v4 §7.3.5, `BVHAggregate::Intersect`): the slab test with precomputed
//! reciprocal direction, made conservative by growing the far `t` by `2 γ(3)` as pbrt does;
//! children visited front to back (the near child first by the sign of the direction along the
//! node's split axis, the far one pushed); the closest-hit query shrinks `tmax` to each hit, so
//! farther boxes are culled; the any-hit query ([`Accelerator::occluded`]) stops at the first
//! hit. A zero direction component gives an infinite reciprocal; a slab then yields `±inf`, or
//! NaN where the origin lies exactly on the slab plane, and the NaN is ignored by the `max`/`min`
//! (the ray grazes that plane: treated as inside, conservatively).
//!
//! **Counting conventions** ([`StructureStats`], [`Counters`]):
//!
//! - `nodes` = all nodes of the flattened tree, interior and leaf;
//! - `pointers` = one `secondChildOffset` per interior node + one `primitivesOffset` per leaf
//!   (the first child of an interior node is implicit, next in the array);
//! - `bytes` = nodes × 32 + the reordered triangles (36 bytes each) + their primitive ids
//!   (4 bytes each);
//! - `nodes_visited` = nodes whose box was tested; `leaves_visited` = leaves whose box was hit,
//!   so their triangles were tested; `triangles_tested` = ray–triangle tests (a four-lane test of
//!   a leaf of three counts three).

use crate::compare::{Accelerator, StructureStats, Triangles};
use crate::geom::triangle::RayShear;
use crate::geom::{Hit, Ray};
use crate::logical::Counters;

/// Bins per axis of the binned SAH.
pub const BINS: usize = 16;
/// Most triangles a leaf holds (pbrt-v4's default `maxprimsinnode`).
pub const MAX_PRIMS_IN_NODE: usize = 4;
/// Entries of the traversal stack.
pub const STACK_SIZE: usize = 64;
/// Depth from which the build splits at the median only, to keep the tree within the stack.
pub const SAH_MAX_DEPTH: u32 = 32;
/// Nodes holding more triangles than this build their two children in parallel.
pub const PARALLEL_MIN: usize = 16 * 1024;
/// Largest triangle count the 32-bit offsets of [`LinearNode`] can index (a tree over `n`
/// triangles has at most `2n - 1` nodes).
const MAX_TRIANGLES: usize = (u32::MAX / 2) as usize;
/// Cost of visiting a node, relative to one triangle test.
const TRAVERSAL_COST: f64 = 1.0;

/// pbrt-v4's `LinearBVHNode`: 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
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
    pad: u8,
}
const _: () = assert!(std::mem::size_of::<LinearNode>() == 32);

/// A binned-SAH BVH over a set of triangles.
pub struct Bvh {
    nodes: Vec<LinearNode>,
    /// Triangles in leaf order, with their primitive ids.
    tris: Vec<[[f32; 3]; 3]>,
    prim: Vec<u32>,
    /// No tree: too many triangles for 32-bit offsets; every ray tests every triangle.
    linear: bool,
    stats: StructureStats,
}

/// A triangle while building: its bounds, centroid and index in the input.
#[derive(Clone, Copy)]
struct PrimInfo {
    lo: [f32; 3],
    hi: [f32; 3],
    c: [f32; 3],
    index: u32,
}

enum BuildNode {
    Leaf {
        lo: [f32; 3],
        hi: [f32; 3],
        first: usize,
        count: usize,
    },
    Interior {
        lo: [f32; 3],
        hi: [f32; 3],
        axis: u8,
        children: Box<[BuildNode; 2]>,
        /// Nodes in this subtree, itself included.
        size: usize,
    },
}

impl BuildNode {
    fn size(&self) -> usize {
        match self {
            BuildNode::Leaf { .. } => 1,
            BuildNode::Interior { size, .. } => *size,
        }
    }
}

#[derive(Clone, Copy)]
struct Aabb {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };

    fn grow_box(&mut self, lo: &[f32; 3], hi: &[f32; 3]) {
        for k in 0..3 {
            self.lo[k] = self.lo[k].min(lo[k]);
            self.hi[k] = self.hi[k].max(hi[k]);
        }
    }

    fn grow_point(&mut self, p: &[f32; 3]) {
        self.grow_box(p, p);
    }

    fn union(mut self, o: &Aabb) -> Aabb {
        self.grow_box(&o.lo, &o.hi);
        self
    }

    /// Surface area, in f64 (no overflow or underflow for any f32 box); 0 for an empty box.
    fn area(&self) -> f64 {
        let e: [f64; 3] = std::array::from_fn(|k| (self.hi[k] as f64 - self.lo[k] as f64).max(0.0));
        2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])
    }
}

impl Bvh {
    /// Builds the BVH over `tris` (see the module documentation). Never panics: no triangles
    /// give a structure that misses everything.
    pub fn build(tris: &Triangles) -> Bvh {
        let t0 = std::time::Instant::now();
        let n = tris.len().min(tris.prim.len());
        let mut bvh = if n > MAX_TRIANGLES {
            Bvh {
                nodes: Vec::new(),
                tris: tris.v[..n].to_vec(),
                prim: tris.prim[..n].to_vec(),
                linear: true,
                stats: StructureStats::default(),
            }
        } else {
            Self::build_tree(tris, n)
        };
        bvh.stats = StructureStats {
            name: "bvh",
            build_seconds: t0.elapsed().as_secs_f64(),
            nodes: bvh.nodes.len() as u64,
            pointers: bvh.nodes.len() as u64,
            bytes: (bvh.nodes.len() * std::mem::size_of::<LinearNode>()
                + bvh.tris.len() * std::mem::size_of::<[[f32; 3]; 3]>()
                + bvh.prim.len() * 4) as u64,
        };
        bvh
    }

    fn build_tree(tris: &Triangles, n: usize) -> Bvh {
        if n == 0 {
            return Bvh {
                nodes: Vec::new(),
                tris: Vec::new(),
                prim: Vec::new(),
                linear: false,
                stats: StructureStats::default(),
            };
        }
        let mut info: Vec<PrimInfo> = tris.v[..n]
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let lo = std::array::from_fn(|k| v[0][k].min(v[1][k]).min(v[2][k]));
                let hi = std::array::from_fn(|k| v[0][k].max(v[1][k]).max(v[2][k]));
                PrimInfo {
                    lo,
                    hi,
                    // Centroid of the box (pbrt-v4), computed so it cannot overflow.
                    c: std::array::from_fn(|k| lo[k] * 0.5 + hi[k] * 0.5),
                    index: i as u32, // i < n <= MAX_TRIANGLES
                }
            })
            .collect();
        let root = build_recursive(&mut info, 0, 0);
        let mut nodes = Vec::with_capacity(root.size());
        flatten(&root, &mut nodes);
        drop(root);
        let order = info.iter().map(|p| p.index as usize);
        Bvh {
            nodes,
            tris: order.clone().map(|i| tris.v[i]).collect(),
            prim: order.map(|i| tris.prim[i]).collect(),
            linear: false,
            stats: StructureStats::default(),
        }
    }

    /// The flattened nodes (depth-first), for tests and reports.
    pub fn nodes(&self) -> &[LinearNode] {
        &self.nodes
    }

    /// Depth of the deepest leaf (the root is at depth 0); 0 for an empty tree.
    pub fn depth(&self) -> usize {
        let mut deepest = 0;
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, d)) = stack.pop() {
            let Some(node) = self.nodes.get(i) else {
                continue;
            };
            deepest = deepest.max(d);
            if node.n_prims == 0 {
                stack.push((i + 1, d + 1));
                stack.push((node.offset as usize, d + 1));
            }
        }
        deepest
    }

    /// The traversal shared by both queries; `ANY` stops at the first hit.
    fn trace<const ANY: bool>(&self, ray: &Ray, c: &mut Counters) -> Hit {
        if !ray.is_valid() || self.tris.is_empty() {
            return Hit::MISS;
        }
        let shear = RayShear::new(ray);
        if self.linear {
            return self.test_range::<ANY>(&shear, ray, 0, self.tris.len(), Hit::MISS, c);
        }
        let inv: [f32; 3] = std::array::from_fn(|k| 1.0 / ray.dir[k]);
        let neg: [bool; 3] = std::array::from_fn(|k| inv[k] < 0.0);
        let mut best = Hit::MISS;
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
                    let h = self.test_range::<ANY>(
                        &shear,
                        ray,
                        first,
                        first + node.n_prims as usize,
                        best,
                        c,
                    );
                    if h.is_hit() {
                        if ANY {
                            return h;
                        }
                        best = h;
                        tmax = h.t;
                    }
                } else {
                    // Near child next, far child on the stack.
                    let (near, far) = if neg[node.axis as usize] {
                        (node.offset, cur as u32 + 1)
                    } else {
                        (cur as u32 + 1, node.offset)
                    };
                    match stack.get_mut(sp) {
                        Some(slot) => {
                            *slot = far;
                            sp += 1;
                            next = Some(near as usize);
                        }
                        None => {
                            // Never (the build bounds the depth): answer by brute force.
                            return self.test_range::<ANY>(
                                &shear,
                                ray,
                                0,
                                self.tris.len(),
                                Hit::MISS,
                                c,
                            );
                        }
                    }
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
        best
    }

    /// Tests triangles `first..end` (four at a time), keeping the closest hit below `best`
    /// (or returning the first hit, for `ANY`).
    fn test_range<const ANY: bool>(
        &self,
        shear: &RayShear,
        ray: &Ray,
        first: usize,
        end: usize,
        mut best: Hit,
        c: &mut Counters,
    ) -> Hit {
        let Some(tris) = self.tris.get(first..end) else {
            return best;
        };
        c.triangles_tested += tris.len() as u64;
        for (ci, chunk) in tris.chunks(4).enumerate() {
            let base = first + ci * 4;
            // Short chunks repeat their last triangle (its lanes answer the same).
            let lane = |l: usize| &chunk[l.min(chunk.len() - 1)];
            let tmax = if best.is_hit() { best.t } else { ray.tmax };
            let (mask, t) = shear.intersect4([lane(0), lane(1), lane(2), lane(3)], ray.tmin, tmax);
            if mask == 0 {
                continue;
            }
            for (l, &tl) in t.iter().enumerate().take(chunk.len()) {
                if mask >> l & 1 == 1 && (!best.is_hit() || tl < best.t) {
                    best = Hit {
                        t: tl,
                        prim: self.prim[base + l],
                    };
                    if ANY {
                        return best;
                    }
                }
            }
        }
        best
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

/// Builds the subtree over `prims`, whose first triangle is at `offset` in the final order.
fn build_recursive(prims: &mut [PrimInfo], offset: usize, depth: u32) -> BuildNode {
    let n = prims.len();
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for p in prims.iter() {
        bounds.grow_box(&p.lo, &p.hi);
        cb.grow_point(&p.c);
    }
    let leaf = BuildNode::Leaf {
        lo: bounds.lo,
        hi: bounds.hi,
        first: offset,
        count: n,
    };
    if n <= 1 {
        return leaf;
    }
    let axis = (0..3)
        .max_by(|&a, &b| {
            (cb.hi[a] as f64 - cb.lo[a] as f64).total_cmp(&(cb.hi[b] as f64 - cb.lo[b] as f64))
        })
        .unwrap_or(0);

    let mut mid = None;
    let mut split_axis = axis;
    if depth < SAH_MAX_DEPTH {
        match sah_split(prims, &bounds, &cb) {
            SahChoice::Leaf => return leaf,
            SahChoice::Split(k, m) => {
                split_axis = k;
                mid = Some(m);
            }
            SahChoice::None if n <= MAX_PRIMS_IN_NODE => return leaf,
            SahChoice::None => {}
        }
    } else if n <= MAX_PRIMS_IN_NODE {
        return leaf;
    }
    let mid = match mid {
        Some(m) => m,
        None => {
            // Median split along the longest centroid axis (pbrt-v4's EqualCounts).
            let m = n / 2;
            prims.select_nth_unstable_by(m, |a, b| a.c[axis].total_cmp(&b.c[axis]));
            split_axis = axis;
            m
        }
    };
    let (left, right) = prims.split_at_mut(mid);
    let (l, r) = if n > PARALLEL_MIN {
        rayon::join(
            || build_recursive(left, offset, depth + 1),
            || build_recursive(right, offset + mid, depth + 1),
        )
    } else {
        (
            build_recursive(left, offset, depth + 1),
            build_recursive(right, offset + mid, depth + 1),
        )
    };
    let size = 1 + l.size() + r.size();
    BuildNode::Interior {
        lo: bounds.lo,
        hi: bounds.hi,
        axis: split_axis as u8,
        children: Box::new([l, r]),
        size,
    }
}

enum SahChoice {
    /// A leaf is no dearer than the best split.
    Leaf,
    /// Split along axis `.0`: `prims[.. .1]` go left (the slice has been partitioned).
    Split(usize, usize),
    /// Binning cannot separate the triangles.
    None,
}

/// The binned SAH over all three axes: finds the cheapest split, partitions `prims` by it.
fn sah_split(prims: &mut [PrimInfo], bounds: &Aabb, cb: &Aabb) -> SahChoice {
    let n = prims.len();
    let total = bounds.area();
    // (cost, axis, bins on the left)
    let mut best: Option<(f64, usize, usize)> = None;
    for k in 0..3 {
        let (lo, hi) = (cb.lo[k], cb.hi[k]);
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        let bin_of = bin_fn(lo, hi);
        let mut counts = [0usize; BINS];
        let mut boxes = [Aabb::EMPTY; BINS];
        for p in prims.iter() {
            let b = bin_of(p.c[k]);
            counts[b] += 1;
            boxes[b].grow_box(&p.lo, &p.hi);
        }
        // Sweep from the right: area and count of bins i.. for every i.
        let mut right_area = [0f64; BINS];
        let mut right_count = [0usize; BINS];
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for i in (1..BINS).rev() {
            acc = acc.union(&boxes[i]);
            cnt += counts[i];
            right_area[i] = acc.area();
            right_count[i] = cnt;
        }
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for i in 0..BINS - 1 {
            acc = acc.union(&boxes[i]);
            cnt += counts[i];
            let rc = right_count[i + 1];
            if cnt == 0 || rc == 0 {
                continue;
            }
            let cost = if total > 0.0 {
                TRAVERSAL_COST + (cnt as f64 * acc.area() + rc as f64 * right_area[i + 1]) / total
            } else {
                TRAVERSAL_COST + n as f64
            };
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, k, i + 1));
            }
        }
    }
    let Some((cost, k, left_bins)) = best else {
        return SahChoice::None;
    };
    if n <= MAX_PRIMS_IN_NODE && n as f64 <= cost {
        return SahChoice::Leaf;
    }
    let bin_of = bin_fn(cb.lo[k], cb.hi[k]);
    // In-place partition: triangles in bins below `left_bins` first.
    let mut i = 0;
    for j in 0..n {
        if bin_of(prims[j].c[k]) < left_bins {
            prims.swap(i, j);
            i += 1;
        }
    }
    if i == 0 || i == n {
        return SahChoice::None; // cannot happen: both sides were counted non-empty
    }
    SahChoice::Split(k, i)
}

/// The bin of a centroid coordinate, for centroid bounds `lo < hi` along the axis.
fn bin_fn(lo: f32, hi: f32) -> impl Fn(f32) -> usize {
    let scale = BINS as f64 / (hi as f64 - lo as f64);
    move |x: f32| (((x as f64 - lo as f64) * scale) as usize).min(BINS - 1)
}

/// Appends `node`'s subtree to `out` in depth-first order.
fn flatten(node: &BuildNode, out: &mut Vec<LinearNode>) {
    match node {
        BuildNode::Leaf {
            lo,
            hi,
            first,
            count,
        } => out.push(LinearNode {
            min: *lo,
            max: *hi,
            // first < n <= MAX_TRIANGLES, count <= MAX_PRIMS_IN_NODE: both fit.
            offset: u32::try_from(*first).unwrap_or(u32::MAX),
            n_prims: u16::try_from(*count).unwrap_or(u16::MAX),
            axis: 0,
            pad: 0,
        }),
        BuildNode::Interior {
            lo,
            hi,
            axis,
            children,
            ..
        } => {
            let me = out.len();
            out.push(LinearNode {
                min: *lo,
                max: *hi,
                offset: 0,
                n_prims: 0,
                axis: *axis,
                pad: 0,
            });
            flatten(&children[0], out);
            // The node count is below 2 * MAX_TRIANGLES <= u32::MAX.
            out[me].offset = u32::try_from(out.len()).unwrap_or(u32::MAX);
            flatten(&children[1], out);
        }
    }
}

impl Accelerator for Bvh {
    fn stats(&self) -> &StructureStats {
        &self.stats
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        self.trace::<false>(ray, c)
    }

    fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
        self.trace::<true>(ray, c).is_hit()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rays::SplitMix64;

    /// `Triangles` from raw triangles (degenerate ones dropped, as `Triangles::from_mesh` does).
    pub(crate) fn triangles(v: Vec<[[f32; 3]; 3]>) -> Triangles {
        let mut t = Triangles {
            min: [f32::INFINITY; 3],
            max: [f32::NEG_INFINITY; 3],
            ..Triangles::default()
        };
        for (i, tri) in v.into_iter().enumerate() {
            if crate::build::is_degenerate(&tri) {
                continue;
            }
            for p in &tri {
                for (k, &x) in p.iter().enumerate() {
                    t.min[k] = t.min[k].min(x);
                    t.max[k] = t.max[k].max(x);
                }
            }
            t.v.push(tri);
            t.prim.push(i as u32);
        }
        t
    }

    fn brute(t: &Triangles, ray: &Ray) -> Hit {
        if !ray.is_valid() {
            return Hit::MISS;
        }
        let sh = RayShear::new(ray);
        let mut best = Hit::MISS;
        for (v, &p) in t.v.iter().zip(&t.prim) {
            let tmax = if best.is_hit() { best.t } else { ray.tmax };
            if let Some(h) = sh.intersect(v, ray.tmin, tmax)
                && (!best.is_hit() || h < best.t)
            {
                best = Hit { t: h, prim: p };
            }
        }
        best
    }

    /// Checks every ray's closest hit and any hit against brute force; returns the number of
    /// hits (so callers can check their rays hit something).
    pub(crate) fn check_against_brute(acc: &dyn Accelerator, t: &Triangles, rays: &[Ray]) -> usize {
        let diag = (0..3)
            .map(|k| (t.max[k] as f64 - t.min[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
            .max(1e-30);
        let mut hits = 0;
        let mut c = Counters::default();
        for r in rays {
            let want = brute(t, r);
            let got = acc.intersect(r, &mut c);
            assert_eq!(
                want.is_hit(),
                got.is_hit(),
                "ray {r:?}: brute {want:?}, got {got:?}"
            );
            if want.is_hit() {
                hits += 1;
                assert!(
                    ((want.t - got.t).abs() as f64) <= 1e-4 * diag,
                    "ray {r:?}: brute {want:?}, got {got:?}"
                );
            }
            assert_eq!(acc.occluded(r, &mut c), want.is_hit(), "occluded {r:?}");
        }
        assert_eq!(c.rays, 0, "the batch counts rays, not the structure");
        hits
    }

    pub(crate) fn rng_tri(rng: &mut SplitMix64, scale: f32) -> [[f32; 3]; 3] {
        let base: [f32; 3] = std::array::from_fn(|_| rng.next_f64() as f32 * 10.0);
        std::array::from_fn(|_| {
            std::array::from_fn(|k| base[k] + (rng.next_f64() as f32 - 0.5) * scale)
        })
    }

    /// Random rays around `t`'s bounds, plus awkward ones: axis-parallel, with zero direction
    /// components, starting inside, through vertices, limited `tmin`/`tmax`.
    pub(crate) fn test_rays(t: &Triangles, n: usize, seed: u64) -> Vec<Ray> {
        let mut rng = SplitMix64::new(seed);
        let lo = t.min;
        let hi = t.max;
        let mut rays = Vec::new();
        let point = |rng: &mut SplitMix64, pad: f32| -> [f32; 3] {
            std::array::from_fn(|k| {
                let e = (hi[k] - lo[k]).max(1e-3);
                lo[k] - pad * e + (1.0 + 2.0 * pad) * e * rng.next_f64() as f32
            })
        };
        for i in 0..n {
            let o = point(&mut rng, 0.3);
            let target = match i % 3 {
                0 => point(&mut rng, 0.0),
                // Toward a vertex or an edge midpoint: exercises shared edges.
                1 => {
                    t.v.get(rng.next_u64() as usize % t.v.len().max(1))
                        .map_or(o, |v| v[0])
                }
                _ => {
                    t.v.get(rng.next_u64() as usize % t.v.len().max(1))
                        .map_or(o, |v| std::array::from_fn(|k| (v[1][k] + v[2][k]) * 0.5))
                }
            };
            let mut d: [f32; 3] = std::array::from_fn(|k| target[k] - o[k]);
            match i % 7 {
                // Zero one or two components.
                1 => d[(i / 7) % 3] = 0.0,
                2 => {
                    d[(i / 7) % 3] = 0.0;
                    d[(i / 7 + 1) % 3] = 0.0;
                }
                3 => d[(i / 7) % 3] = -0.0,
                _ => {}
            }
            if d.iter().all(|&x| x == 0.0) {
                d = [0.0, 0.0, 1.0];
            }
            let (tmin, tmax) = match i % 5 {
                0 => (0.0, 0.5),
                1 => (0.3, f32::INFINITY),
                2 => (-1.0, 2.0),
                _ => (0.0, f32::INFINITY),
            };
            rays.push(Ray::new(o, d, tmin, tmax));
        }
        // Axis-parallel rays through a lattice of points, both ways along each axis, from
        // inside and outside.
        for a in 0..3 {
            for s in [-1.0f32, 1.0] {
                for _ in 0..n / 20 {
                    let o = point(&mut rng, 0.1);
                    let mut d = [0.0; 3];
                    d[a] = s;
                    rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
                }
            }
        }
        // Invalid rays miss.
        rays.push(Ray::new([0.0; 3], [0.0; 3], 0.0, 1.0));
        rays.push(Ray::new([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, 1.0));
        rays.push(Ray::new([0.0; 3], [1.0, 0.0, 0.0], 2.0, 1.0));
        rays
    }

    fn soup(n: usize, scale: f32, seed: u64) -> Triangles {
        let mut rng = SplitMix64::new(seed);
        triangles((0..n).map(|_| rng_tri(&mut rng, scale)).collect())
    }

    /// A flat grid of `n` x `n` quads (two triangles each) in the plane `z = 0`, cells of 1.
    pub(crate) fn flat_grid(n: usize) -> Triangles {
        let mut v = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, y) = (i as f32, j as f32);
                v.push([[x, y, 0.0], [x + 1.0, y, 0.0], [x + 1.0, y + 1.0, 0.0]]);
                v.push([[x, y, 0.0], [x + 1.0, y + 1.0, 0.0], [x, y + 1.0, 0.0]]);
            }
        }
        triangles(v)
    }

    fn check_structure(t: &Triangles) -> Bvh {
        let bvh = Bvh::build(t);
        validate(&bvh, t.len());
        let rays = test_rays(t, 3000, 7);
        check_against_brute(&bvh, t, &rays);
        bvh
    }

    /// Structural checks: every triangle in exactly one leaf, leaves within bounds, children
    /// inside parents, the depth within the stack.
    fn validate(bvh: &Bvh, n: usize) {
        assert_eq!(bvh.tris.len(), n);
        if n == 0 {
            assert!(bvh.nodes.is_empty());
            return;
        }
        let mut seen = vec![false; n];
        let mut leaves = 0;
        for (i, node) in bvh.nodes.iter().enumerate() {
            if node.n_prims > 0 {
                leaves += 1;
                assert!(node.n_prims as usize <= MAX_PRIMS_IN_NODE);
                let range = node.offset as usize..node.offset as usize + node.n_prims as usize;
                for (s, tri) in seen[range.clone()].iter_mut().zip(&bvh.tris[range]) {
                    assert!(!*s);
                    *s = true;
                    for p in tri {
                        for (k, &x) in p.iter().enumerate() {
                            assert!(node.min[k] <= x && x <= node.max[k]);
                        }
                    }
                }
            } else {
                for ch in [i + 1, node.offset as usize] {
                    let c = &bvh.nodes[ch];
                    assert!(ch > i);
                    for k in 0..3 {
                        assert!(node.min[k] <= c.min[k] && c.max[k] <= node.max[k]);
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(bvh.nodes.len(), 2 * leaves - 1);
        assert_eq!(bvh.stats.nodes, bvh.nodes.len() as u64);
        assert_eq!(bvh.stats.pointers, bvh.nodes.len() as u64);
        assert!(bvh.depth() < STACK_SIZE);
    }

    #[test]
    fn empty_misses_everything() {
        let t = triangles(vec![]);
        let bvh = Bvh::build(&t);
        let mut c = Counters::default();
        let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        assert_eq!(bvh.intersect(&r, &mut c), Hit::MISS);
        assert!(!bvh.occluded(&r, &mut c));
        assert_eq!(bvh.stats().nodes, 0);
        // Only degenerate triangles: also empty.
        let t = triangles(vec![[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]]);
        assert!(Bvh::build(&t).nodes.is_empty());
    }

    #[test]
    fn single_triangle() {
        let t = triangles(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
        let bvh = check_structure(&t);
        assert_eq!(bvh.nodes.len(), 1);
        let mut c = Counters::default();
        let h = bvh.intersect(
            &Ray::new([0.25, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
            &mut c,
        );
        assert_eq!(h, Hit { t: 2.0, prim: 0 });
        assert_eq!(
            (c.nodes_visited, c.leaves_visited, c.triangles_tested),
            (1, 1, 1)
        );
    }

    #[test]
    fn random_soups_agree_with_brute_force() {
        for (n, scale, seed) in [(2, 3.0, 1), (5, 3.0, 2), (100, 2.0, 3), (2000, 1.0, 4)] {
            let t = soup(n, scale, seed);
            let bvh = check_structure(&t);
            assert!(bvh.nodes.len() > 1 || n < 2);
        }
    }

    #[test]
    fn flat_mesh_and_axis_parallel_rays() {
        let t = flat_grid(20);
        check_structure(&t);
        // Rays straight down through grid vertices and edges hit (watertight).
        let bvh = Bvh::build(&t);
        let mut c = Counters::default();
        for i in 0..=20 {
            let x = i as f32;
            let r = Ray::new([x, 7.5, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
            let want = brute(&t, &r);
            assert!(want.is_hit(), "{r:?} passes through the mesh");
            assert_eq!(bvh.intersect(&r, &mut c), want, "{r:?}");
            // In the plane of the mesh, along x.
            let r = Ray::new([-1.0, x, 0.0], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
            assert_eq!(
                bvh.intersect(&r, &mut c).is_hit(),
                brute(&t, &r).is_hit(),
                "{r:?}"
            );
        }
    }

    #[test]
    fn identical_triangles_split_by_median() {
        // 1000 copies of one triangle: centroids coincide, so no SAH split exists; leaves must
        // still hold at most MAX_PRIMS_IN_NODE and the depth stay within the stack.
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]];
        let t = triangles(vec![tri; 1000]);
        let bvh = check_structure(&t);
        assert!(bvh.depth() <= 10);
    }

    #[test]
    fn deep_unbalanced_input_stays_within_the_stack() {
        // Triangles at geometrically shrinking scales: SAH peels one off per level.
        let mut v = Vec::new();
        for i in 0..200 {
            let s = 0.8f32.powi(i);
            v.push([[s, 0.0, 0.0], [s * 1.01, 0.0, 0.0], [s, s * 0.01, 0.0]]);
        }
        let t = triangles(v);
        let bvh = check_structure(&t);
        assert!(bvh.depth() < STACK_SIZE);
    }

    #[test]
    fn non_finite_vertices_do_not_panic() {
        let mut rng = SplitMix64::new(5);
        let mut v: Vec<_> = (0..50).map(|_| rng_tri(&mut rng, 1.0)).collect();
        v.push([[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        v.push([[f32::INFINITY, 0.0, 0.0], [1.0, 2.0, 0.0], [0.0, 1.0, 3.0]]);
        v.push([[f32::NEG_INFINITY; 3], [f32::INFINITY; 3], [0.0, 1.0, 3.0]]);
        let t = triangles(v);
        let bvh = Bvh::build(&t);
        let mut c = Counters::default();
        for r in test_rays(&soup(50, 1.0, 5), 500, 1) {
            bvh.intersect(&r, &mut c);
            bvh.occluded(&r, &mut c);
        }
    }

    #[test]
    fn counts_are_sane() {
        let t = soup(500, 1.0, 9);
        let bvh = Bvh::build(&t);
        let mut c = Counters::default();
        for r in test_rays(&t, 200, 3) {
            bvh.intersect(&r, &mut c);
        }
        assert!(c.nodes_visited >= c.leaves_visited);
        assert!(c.triangles_tested >= c.leaves_visited);
        assert!(c.triangles_tested <= c.leaves_visited * MAX_PRIMS_IN_NODE as u64);
        let s = bvh.stats();
        assert_eq!(s.bytes, s.nodes * 32 + t.len() as u64 * 40);
    }
}
