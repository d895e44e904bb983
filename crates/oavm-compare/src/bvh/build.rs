//! Building the BVH.
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
//! **Depth bound.** Traversal uses a fixed stack of [`STACK_SIZE`](super::STACK_SIZE) = 64 entries (pbrt-v4's
//! `nodesToVisit[64]`), and a descent pushes one entry per interior node, so the tree must be
//! at most 64 nodes deep. SAH splits can be very unbalanced, so from depth [`SAH_MAX_DEPTH`]
//! (= 32) on the build uses median splits only: each halves the count, and as a node holds fewer
//! than `2^32` triangles, 31 more levels bring it to four or fewer, so leaves are at depth ≤ 63.
//! The traversal still checks the stack (no `unsafe`, no panic): if it ever overflowed, the ray
//! would be answered by testing every triangle, which is correct if slow (it never happens).
//!
//! The top levels are built in parallel (`rayon::join` on the two children of nodes holding
//! more than [`PARALLEL_MIN`] triangles).

use super::Bvh;
use super::node::LinearNode;
use crate::aabb::Aabb;
use crate::leaf::Soup;
use crate::{StructureStats, Triangles};

/// Bins per axis of the binned SAH.
pub const BINS: usize = 16;
/// Most triangles a leaf holds (pbrt-v4's default `maxprimsinnode`).
pub const MAX_PRIMS_IN_NODE: usize = 4;
/// Depth from which the build splits at the median only, to keep the tree within the stack.
pub const SAH_MAX_DEPTH: u32 = 32;
/// Nodes holding more triangles than this build their two children in parallel.
pub const PARALLEL_MIN: usize = 16 * 1024;
/// Largest triangle count the 32-bit offsets of [`LinearNode`] can index (a tree over `n`
/// triangles has at most `2n - 1` nodes).
const MAX_TRIANGLES: usize = (u32::MAX / 2) as usize;
/// Cost of visiting a node, relative to one triangle test.
const TRAVERSAL_COST: f64 = 1.0;

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

impl Bvh {
    /// Builds the BVH over `tris` (see the module documentation). Never panics: no triangles
    /// give a structure that misses everything.
    pub fn build(tris: &Triangles) -> Bvh {
        let t0 = std::time::Instant::now();
        let soup = Soup::finite(tris);
        let mut bvh = if soup.len() > MAX_TRIANGLES {
            Bvh {
                nodes: Vec::new(),
                soup,
                linear: true,
                stats: StructureStats::default(),
            }
        } else {
            Self::build_tree(soup)
        };
        bvh.stats = StructureStats {
            name: "bvh",
            build_seconds: t0.elapsed().as_secs_f64(),
            nodes: bvh.nodes.len() as u64,
            pointers: bvh.nodes.len() as u64,
            bytes: (bvh.nodes.len() * std::mem::size_of::<LinearNode>() + bvh.soup.bytes()) as u64,
        };
        bvh
    }

    /// The tree over `soup` (at most [`MAX_TRIANGLES`] triangles), which it reorders into leaf
    /// order.
    fn build_tree(soup: Soup) -> Bvh {
        if soup.is_empty() {
            return Bvh {
                nodes: Vec::new(),
                soup,
                linear: false,
                stats: StructureStats::default(),
            };
        }
        let mut info: Vec<PrimInfo> = soup
            .v
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let Aabb { lo, hi } = Aabb::of_triangle(v);
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
        let order: Vec<usize> = info.iter().map(|p| p.index as usize).collect();
        Bvh {
            nodes,
            soup: soup.permuted(&order),
            linear: false,
            stats: StructureStats::default(),
        }
    }
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
