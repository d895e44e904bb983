//! Steps 1 and 3 of the cluster build: a binary tree over boxes (the triangles' clipped boxes,
//! down to windows; then the groups' boxes, down to single groups) by binned SAH (Wald 2007)
//! or by median splits. See the parent module.

use super::BINS;

/// A primitive while building (a triangle, or a group): its f32 box and its index. Nodes own
/// contiguous ranges of these, which the build partitions in place. The boxes have a fourth
/// lane (0) so that the loops over them compile to 4-wide min and max.
#[derive(Clone, Copy, Debug)]
pub(super) struct PrimRef {
    lo: [f32; 4],
    hi: [f32; 4],
    pub id: u32,
}

impl PrimRef {
    pub fn new(lo: [f32; 3], hi: [f32; 3], id: u32) -> PrimRef {
        PrimRef {
            lo: [lo[0], lo[1], lo[2], 0.0],
            hi: [hi[0], hi[1], hi[2], 0.0],
            id,
        }
    }

    pub fn lo(&self) -> [f32; 3] {
        [self.lo[0], self.lo[1], self.lo[2]]
    }

    pub fn hi(&self) -> [f32; 3] {
        [self.hi[0], self.hi[1], self.hi[2]]
    }

    /// Twice the centroid (the scale does not matter to binning, and it saves a multiply).
    #[inline(always)]
    pub fn c(&self, k: usize) -> f32 {
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
    /// Inner: the right child. Leaf: the number of `PrimRef`s.
    pub b: u32,
    pub leaf: bool,
    /// Binary levels below this node (0 for a leaf).
    pub height: u32,
    /// Inner: half the surface area of its box, in f64 (no overflow for any f32 box); the
    /// collapse compares it for every child it may open. Leaf: 0.
    pub area: f64,
}

/// A node waiting to be built: `refs[start..end]`, at binary depth `depth`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Task {
    node: u32,
    start: u32,
    end: u32,
    depth: u32,
}

/// `min` and `max` for values known not to be NaN (every box coordinate is finite): one
/// instruction each, where `f32::min` must also handle NaN.
#[inline(always)]
pub(super) fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

#[inline(always)]
pub(super) fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

#[inline]
pub(super) fn half_area(lo: &[f32; 3], hi: &[f32; 3]) -> f64 {
    let d: [f64; 3] = std::array::from_fn(|k| (hi[k] as f64 - lo[k] as f64).max(0.0));
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// How nodes too large for a leaf are split.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Split {
    /// Binned SAH down to binary depth `max_depth`, median splits below it and where binning
    /// separates nothing.
    Sah { max_depth: u32 },
    /// Median splits only: a tree over `n` primitives is at most `ceil(log2(n / leaf_max)) + 1`
    /// levels deep.
    Median,
}

/// Builds the binary tree over `refs` (reordered: each leaf's primitives become contiguous)
/// into `nodes` (cleared by the caller), root at 0, children after their parent; a node is a
/// leaf when it holds at most `leaf_max` primitives.
pub(super) fn build(
    refs: &mut [PrimRef],
    leaf_max: usize,
    split: Split,
    nodes: &mut Vec<BinNode>,
    tasks: &mut Vec<Task>,
    also_leaf: impl Fn(&[PrimRef]) -> bool,
) {
    tasks.clear();
    let mut bins: Bins = [[EMPTY_BIN; BINS]; 3];
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
        if r.len() <= leaf_max || also_leaf(r) {
            node.leaf = true;
            node.a = t.start;
            node.b = r.len() as u32;
            continue;
        }
        node.area = half_area(&blo, &bhi);
        let sah = matches!(split, Split::Sah { max_depth } if t.depth < max_depth);
        let mid = sah
            .then(|| sah_split(r, &clo, &chi, &mut bins))
            .flatten()
            .unwrap_or_else(|| median_split(r, &clo, &chi, leaf_max));
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
        area: 0.0,
    }
}

/// The box of `r` and the bounds of its (doubled) centroids.
fn bounds(r: &[PrimRef]) -> ([f32; 3], [f32; 3], [f32; 3], [f32; 3]) {
    let mut blo = [f32::INFINITY; 4];
    let mut bhi = [f32::NEG_INFINITY; 4];
    let mut clo = [f32::INFINITY; 4];
    let mut chi = [f32::NEG_INFINITY; 4];
    for p in r {
        for k in 0..4 {
            blo[k] = fmin(blo[k], p.lo[k]);
            bhi[k] = fmax(bhi[k], p.hi[k]);
            let c = p.lo[k] + p.hi[k];
            clo[k] = fmin(clo[k], c);
            chi[k] = fmax(chi[k], c);
        }
    }
    let three = |a: [f32; 4]| [a[0], a[1], a[2]];
    (three(blo), three(bhi), three(clo), three(chi))
}

/// Splits `r` (more than `leaf_max` primitives) along the axis of the largest centroid
/// extent, ties in input order (so with equal centroids, by count in input order), after half
/// its leaves' worth: leaves end up full, and the tree is balanced.
/// Returns the number of primitives on the left.
fn median_split(r: &mut [PrimRef], clo: &[f32; 3], chi: &[f32; 3], leaf_max: usize) -> usize {
    let ext = |k: usize| chi[k] as f64 - clo[k] as f64;
    let axis = (0..3).fold(0, |a, k| if ext(k) > ext(a) { k } else { a });
    let m = r.len().div_ceil(leaf_max).div_ceil(2) * leaf_max;
    r.select_nth_unstable_by(m, |p, q| {
        p.c(axis).total_cmp(&q.c(axis)).then(p.id.cmp(&q.id))
    });
    m
}

#[derive(Clone, Copy)]
struct Bin {
    lo: [f32; 4],
    hi: [f32; 4],
    n: u32,
}

const EMPTY_BIN: Bin = Bin {
    lo: [f32::INFINITY; 4],
    hi: [f32::NEG_INFINITY; 4],
    n: 0,
};

impl Bin {
    #[inline(always)]
    fn grow(&mut self, lo: &[f32; 4], hi: &[f32; 4], n: u32) {
        for k in 0..4 {
            self.lo[k] = fmin(self.lo[k], lo[k]);
            self.hi[k] = fmax(self.hi[k], hi[k]);
        }
        self.n += n;
    }

    fn area(&self) -> f64 {
        half_area(
            &[self.lo[0], self.lo[1], self.lo[2]],
            &[self.hi[0], self.hi[1], self.hi[2]],
        )
    }
}

/// The bin (of `nb`) of a (doubled) centroid `c` on an axis starting at `lo` with `scale` bins
/// per unit.
#[inline(always)]
fn bin_of(c: f32, lo: f32, scale: f32, nb: usize) -> usize {
    // c >= lo, so the product is >= 0 (or NaN for an axis of infinite extent, scale 0, which is
    // never read); the cast saturates (NaN to 0), and the clamp keeps any value a bin. (To i32,
    // not usize: the saturating conversion is a few instructions shorter, and this is the
    // build's innermost loop.)
    (((c - lo) * scale) as i32).max(0).min(nb as i32 - 1) as usize
}

/// Bins of the three axes: scratch of [`build`], reset by [`sah_split`] where it bins.
type Bins = [[Bin; BINS]; 3];

/// The binned-SAH split of `r` (Wald 2007 §3): each axis with a centroid extent is cut into
/// [`BINS`] equal bins (fewer for a node of few primitives: `2n`, at least 4), and every
/// boundary between bins is priced `A_l * n_l + A_r * n_r`
/// (the parent's area and the traversal cost are the same for every candidate, so they are
/// left out); ties go to the more even split, then to the lower axis and bin. Partitions `r`
/// and returns the left count, or `None` if no boundary separates anything. `bins` is scratch.
fn sah_split(r: &mut [PrimRef], clo: &[f32; 3], chi: &[f32; 3], bins: &mut Bins) -> Option<usize> {
    let nb = (2 * r.len()).clamp(4, BINS);
    let mut scale = [0f32; 3];
    let mut live = [false; 3];
    for k in 0..3 {
        let ext = chi[k] - clo[k];
        if ext > 0.0 && ext.is_finite() {
            // Slightly under nb / ext, so the largest centroid falls in the last bin, not past.
            scale[k] = nb as f32 * 0.999_99 / ext;
            live[k] = scale[k].is_finite() && scale[k] > 0.0;
        }
    }
    if !live.iter().any(|&l| l) {
        return None;
    }
    // Every axis is binned, the three (and a fourth, unused lane) at once, so that the bin
    // numbers are computed 4-wide; an axis without extent has scale 0, all in bin 0, unread.
    for axis in bins.iter_mut() {
        axis[..nb].fill(EMPTY_BIN);
    }
    let lo4 = [clo[0], clo[1], clo[2], 0.0];
    let scale4 = [scale[0], scale[1], scale[2], 0.0];
    for p in r.iter() {
        let b: [usize; 4] = std::array::from_fn(|k| bin_of(p.c(k), lo4[k], scale4[k], nb));
        for k in 0..3 {
            bins[k][b[k]].grow(&p.lo, &p.hi, 1);
        }
    }
    let total = r.len() as u32;
    // The best candidate so far: its (cost, imbalance), axis and last bin of the left side.
    // Updated by selects, not branches: which candidate wins is as unpredictable as the data.
    let (mut best_cost, mut best_imbalance) = (f64::INFINITY, u32::MAX);
    let (mut best_axis, mut best_bin) = (0usize, 0usize);
    let mut found = false;
    for k in 0..3 {
        if !live[k] {
            continue;
        }
        let bk = &bins[k][..nb];
        // The non-empty bins, in order, gathered without a branch. A boundary after an empty
        // bin prices the same as the one before it (which is found first and kept), and one
        // with nothing on a side is no split: the candidates are the boundaries after each
        // non-empty bin but the last.
        let mut idx = [0usize; BINS];
        let mut m = 0;
        for (i, b) in bk.iter().enumerate() {
            idx[m] = i;
            m += (b.n > 0) as usize;
        }
        // Right sides: area of the non-empty bins t.. .
        let mut right_area = [0f64; BINS];
        let mut acc = EMPTY_BIN;
        for t in (1..m).rev() {
            let b = &bk[idx[t]];
            acc.grow(&b.lo, &b.hi, b.n);
            right_area[t] = acc.area();
        }
        let mut left = EMPTY_BIN;
        for t in 0..m.saturating_sub(1) {
            let b = &bk[idx[t]];
            left.grow(&b.lo, &b.hi, b.n);
            let nl = left.n;
            let nr = total - nl;
            let cost = left.area() * nl as f64 + right_area[t + 1] * nr as f64;
            let imbalance = nl.abs_diff(nr);
            // Costs are finite (coordinates below 2^123, counts below 2^32), so the first
            // candidate beats the initial infinity.
            let better = (cost < best_cost) | ((cost == best_cost) & (imbalance < best_imbalance));
            best_cost = if better { cost } else { best_cost };
            best_imbalance = if better { imbalance } else { best_imbalance };
            best_axis = if better { k } else { best_axis };
            best_bin = if better { idx[t] } else { best_bin };
            found |= better;
        }
    }
    if !found {
        return None;
    }
    let (k, split) = (best_axis, best_bin);
    // In-place partition: bins 0..=split to the left.
    let (lo, s) = (clo[k], scale[k]);
    let mut i = 0;
    let mut j = r.len();
    while i < j {
        if bin_of(r[i].c(k), lo, s, nb) <= split {
            i += 1;
        } else {
            j -= 1;
            r.swap(i, j);
        }
    }
    Some(i)
}
