//! Step 1 of the cluster build: a binary tree over the triangles' clipped boxes, by binned SAH
//! (Wald 2007) or, in [`Mode::Shallow`], by median splits. See the parent module.

use super::{BINS, ClusterTri, GROUP_LANES, Mode, Params, fits_group};

/// A triangle while building: its (clipped, f32) box and its index in the cluster's input.
/// Nodes own contiguous ranges of these, which the build partitions in place.
#[derive(Clone, Copy, Debug)]
pub(super) struct PrimRef {
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    pub id: u32,
}

impl PrimRef {
    /// Twice the centroid (the scale does not matter to binning, and it saves a multiply).
    #[inline(always)]
    fn c(&self, k: usize) -> f32 {
        self.lo[k] + self.hi[k]
    }
}

/// A node of the binary tree: its box, and either its two children (node indices, both
/// greater than its own) or, for a leaf, its range of [`PrimRef`]s.
#[derive(Clone, Copy, Debug)]
pub(super) struct BinNode {
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    /// Inner: the left child. Leaf: the first `PrimRef`.
    pub a: u32,
    /// Inner: the right child. Leaf: the number of `PrimRef`s (`1..=8`).
    pub b: u32,
    pub leaf: bool,
    /// Binary levels below this node (0 for a leaf).
    pub height: u32,
}

impl BinNode {
    /// Half the surface area, in f64 (no overflow for any f32 box).
    pub fn area(&self) -> f64 {
        half_area(&self.lo, &self.hi)
    }
}

/// A node waiting to be built: `refs[start..end]`, at binary depth `depth`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Task {
    node: u32,
    start: u32,
    end: u32,
    depth: u32,
}

#[inline]
pub(super) fn half_area(lo: &[f32; 3], hi: &[f32; 3]) -> f64 {
    let d: [f64; 3] = std::array::from_fn(|k| (hi[k] as f64 - lo[k] as f64).max(0.0));
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// Builds the binary tree over `refs` (reordered: each leaf's triangles become contiguous) into
/// `nodes` (cleared by the caller), root at 0, children after their parent.
pub(super) fn build(
    refs: &mut [PrimRef],
    tris: &[ClusterTri],
    mode: Mode,
    params: &Params,
    nodes: &mut Vec<BinNode>,
    tasks: &mut Vec<Task>,
) {
    tasks.clear();
    nodes.push(empty_node());
    tasks.push(Task {
        node: 0,
        start: 0,
        end: refs.len() as u32,
        depth: 0,
    });
    while let Some(t) = tasks.pop() {
        let r = &mut refs[t.start as usize..t.end as usize];
        let (blo, bhi, clo, chi) = bounds(r);
        let node = &mut nodes[t.node as usize];
        node.lo = blo;
        node.hi = bhi;
        if fits_group(tris, r.iter().map(|p| p.id)) {
            node.leaf = true;
            node.a = t.start;
            node.b = r.len() as u32;
            continue;
        }
        let sah = mode == Mode::Sah && t.depth < params.sah_max_depth;
        let mid = sah
            .then(|| sah_split(r, &clo, &chi, params.sah_block))
            .flatten()
            .unwrap_or_else(|| median_split(r, &clo, &chi));
        let left = nodes.len() as u32;
        nodes.push(empty_node());
        nodes.push(empty_node());
        let node = &mut nodes[t.node as usize];
        node.a = left;
        node.b = left + 1;
        let mid = t.start + mid as u32;
        // The right child is popped first; either order gives the same tree.
        tasks.push(Task {
            node: left,
            start: t.start,
            end: mid,
            depth: t.depth + 1,
        });
        tasks.push(Task {
            node: left + 1,
            start: mid,
            end: t.end,
            depth: t.depth + 1,
        });
    }
    // Heights, children before parents (children have larger indices).
    for i in (0..nodes.len()).rev() {
        let n = nodes[i];
        if !n.leaf {
            nodes[i].height = 1 + nodes[n.a as usize].height.max(nodes[n.b as usize].height);
        }
    }
}

fn empty_node() -> BinNode {
    BinNode {
        lo: [0.0; 3],
        hi: [0.0; 3],
        a: 0,
        b: 0,
        leaf: false,
        height: 0,
    }
}

/// The box of `r` and the bounds of its (doubled) centroids.
fn bounds(r: &[PrimRef]) -> ([f32; 3], [f32; 3], [f32; 3], [f32; 3]) {
    let mut blo = [f32::INFINITY; 3];
    let mut bhi = [f32::NEG_INFINITY; 3];
    let mut clo = [f32::INFINITY; 3];
    let mut chi = [f32::NEG_INFINITY; 3];
    for p in r {
        for k in 0..3 {
            blo[k] = blo[k].min(p.lo[k]);
            bhi[k] = bhi[k].max(p.hi[k]);
            let c = p.c(k);
            clo[k] = clo[k].min(c);
            chi[k] = chi[k].max(c);
        }
    }
    (blo, bhi, clo, chi)
}

/// Where a split that cannot use the SAH cuts `n` triangles: after whole groups' worth (8
/// triangles) for half the groups, so that leaves end up full; a node of at most 8 triangles
/// (with too many corners) in half.
fn median_count(n: usize) -> usize {
    if n > GROUP_LANES {
        let groups = n.div_ceil(GROUP_LANES);
        groups.div_ceil(2) * GROUP_LANES
    } else {
        n.div_ceil(2)
    }
}

/// Splits `r` (more than one triangle) at [`median_count`] along the axis of the largest
/// centroid extent, ties by input order: with equal centroids, by count in input order.
/// Returns the number of triangles on the left.
fn median_split(r: &mut [PrimRef], clo: &[f32; 3], chi: &[f32; 3]) -> usize {
    let ext = |k: usize| chi[k] as f64 - clo[k] as f64;
    let axis = (0..3).fold(0, |a, k| if ext(k) > ext(a) { k } else { a });
    let m = median_count(r.len());
    r.select_nth_unstable_by(m, |p, q| {
        p.c(axis).total_cmp(&q.c(axis)).then(p.id.cmp(&q.id))
    });
    m
}

#[derive(Clone, Copy)]
struct Bin {
    lo: [f32; 3],
    hi: [f32; 3],
    n: u32,
}

const EMPTY_BIN: Bin = Bin {
    lo: [f32::INFINITY; 3],
    hi: [f32::NEG_INFINITY; 3],
    n: 0,
};

impl Bin {
    #[inline(always)]
    fn grow(&mut self, lo: &[f32; 3], hi: &[f32; 3], n: u32) {
        for k in 0..3 {
            self.lo[k] = self.lo[k].min(lo[k]);
            self.hi[k] = self.hi[k].max(hi[k]);
        }
        self.n += n;
    }
}

/// The bin of a (doubled) centroid `c` on an axis starting at `lo` with `scale` bins per unit.
#[inline(always)]
fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
    // c >= lo, so the product is >= 0 (or NaN for a zero extent, which is never binned); the
    // cast saturates.
    (((c - lo) * scale) as usize).min(BINS - 1)
}

/// The binned-SAH split of `r` (Wald 2007 §3): each axis with a centroid extent is cut into
/// [`BINS`] equal bins, and every boundary between bins is priced `A_l * blocks(n_l) +
/// A_r * blocks(n_r)` (the parent's area and the traversal cost are the same for every
/// candidate, so they are left out); ties go to the more even split, then to the lower axis and
/// bin. Partitions `r` and returns the left count, or `None` if no boundary separates anything.
fn sah_split(r: &mut [PrimRef], clo: &[f32; 3], chi: &[f32; 3], block: u32) -> Option<usize> {
    let mut scale = [0f32; 3];
    let mut live = [false; 3];
    for k in 0..3 {
        let ext = chi[k] - clo[k];
        if ext > 0.0 && ext.is_finite() {
            // Slightly under BINS / ext, so the largest centroid falls in the last bin, not past.
            scale[k] = BINS as f32 * 0.999_99 / ext;
            live[k] = scale[k].is_finite() && scale[k] > 0.0;
        }
    }
    if !live.iter().any(|&l| l) {
        return None;
    }
    let mut bins = [[EMPTY_BIN; BINS]; 3];
    for p in r.iter() {
        for k in 0..3 {
            if live[k] {
                bins[k][bin_of(p.c(k), clo[k], scale[k])].grow(&p.lo, &p.hi, 1);
            }
        }
    }
    let blocks = |n: u32| n.div_ceil(block) as f64;
    let total = r.len() as u32;
    // (cost, imbalance, axis, last bin of the left side)
    let mut best: Option<(f64, u32, usize, usize)> = None;
    for k in 0..3 {
        if !live[k] {
            continue;
        }
        // Right sides: area and count of bins i.. .
        let mut right_area = [0f64; BINS];
        let mut acc = EMPTY_BIN;
        for i in (1..BINS).rev() {
            let b = &bins[k][i];
            acc.grow(&b.lo, &b.hi, b.n);
            right_area[i] = if acc.n > 0 {
                half_area(&acc.lo, &acc.hi)
            } else {
                0.0
            };
        }
        let mut left = EMPTY_BIN;
        for i in 0..BINS - 1 {
            let b = &bins[k][i];
            left.grow(&b.lo, &b.hi, b.n);
            let nl = left.n;
            let nr = total - nl;
            if nl == 0 || nr == 0 {
                continue;
            }
            let cost = half_area(&left.lo, &left.hi) * blocks(nl) + right_area[i + 1] * blocks(nr);
            let imbalance = nl.abs_diff(nr);
            let better = match best {
                None => true,
                Some((c, im, _, _)) => cost < c || (cost == c && imbalance < im),
            };
            if better {
                best = Some((cost, imbalance, k, i));
            }
        }
    }
    let (_, _, k, split) = best?;
    // In-place partition: bins 0..=split to the left.
    let (lo, s) = (clo[k], scale[k]);
    let mut i = 0;
    let mut j = r.len();
    while i < j {
        if bin_of(r[i].c(k), lo, s) <= split {
            i += 1;
        } else {
            j -= 1;
            r.swap(i, j);
        }
    }
    Some(i)
}
