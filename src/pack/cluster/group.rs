//! Step 2 of the cluster build: the triangles of one window (up to 64 neighbours, a leaf of
//! step 1's tree) formed into groups of at most 8 triangles with at most 8 distinct corners.
//!
//! Greedy, as meshlet builders grow meshlets (meshoptimizer's `meshopt_buildMeshlets` prefers
//! the triangle that brings the fewest new vertices): a group starts from the remaining triangle
//! lowest along the window's longest axis (so groups sweep the window from one end instead of
//! leaving scattered remnants), then repeatedly takes the remaining triangle that adds the
//! fewest corners the group does not have yet, ties to the one that grows the group's box
//! least, while the group has fewer than 8 triangles and its corners stay within 8. Corners
//! are compared as bit patterns (see the parent module), through window-local vertex numbers
//! and bit masks, so a step costs a few instructions per remaining triangle.

use super::binary::{PrimRef, fmax, fmin, half_area};
use crate::physical::format::{GROUP_CORNERS, GROUP_LANES};

/// The most triangles a window may have (the masks below hold `3 * 64` vertices).
pub const MAX_WINDOW: usize = 64;

/// A group before it is written: its triangles (indices into the cluster's input) and the
/// union of their clipped boxes.
#[derive(Clone, Copy, Debug)]
pub(super) struct Draft {
    pub ids: [u32; GROUP_LANES],
    pub n: u8,
    pub lo: [f32; 3],
    pub hi: [f32; 3],
}

impl Draft {
    fn new(p: &PrimRef) -> Draft {
        let mut ids = [0; GROUP_LANES];
        ids[0] = p.id;
        Draft {
            ids,
            n: 1,
            lo: p.lo(),
            hi: p.hi(),
        }
    }

    pub(super) fn ids(&self) -> &[u32] {
        &self.ids[..self.n as usize]
    }

    /// Adds the triangles of `other` (the caller checked they fit).
    pub(super) fn absorb(&mut self, ids: &[u32], lo: &[f32; 3], hi: &[f32; 3]) {
        let n = self.n as usize;
        self.ids[n..n + ids.len()].copy_from_slice(ids);
        self.n += ids.len() as u8;
        self.lo = std::array::from_fn(|k| fmin(self.lo[k], lo[k]));
        self.hi = std::array::from_fn(|k| fmax(self.hi[k], hi[k]));
    }
}

/// A set of window-local vertices.
type Mask = [u64; 3];

fn count(m: &Mask) -> u32 {
    m.iter().map(|w| w.count_ones()).sum()
}

fn and_not(a: &Mask, b: &Mask) -> Mask {
    std::array::from_fn(|i| a[i] & !b[i])
}

/// Scratch for window-local vertex numbers: `local[v]` is valid for the window numbered
/// `stamp[v]`.
#[derive(Default)]
pub(super) struct Local {
    window: u32,
    stamp: Vec<u32>,
    local: Vec<u8>,
    /// The window's triangles' masks (kept, so that a window clears only its own).
    masks: Vec<Mask>,
}

impl Local {
    /// Makes room for a cluster with `vertices` distinct corners.
    pub(super) fn prepare(&mut self, vertices: usize) {
        if self.stamp.len() < vertices || self.window > u32::MAX / 2 {
            self.stamp.clear();
            self.stamp.resize(vertices.max(self.stamp.len()), 0);
            self.local.resize(self.stamp.len(), 0);
            self.window = 0;
        }
    }
}

/// Appends the groups of window `w` (1 to [`MAX_WINDOW`] triangles, whose corners have the
/// numbers `vid`) to `out`. `scratch` was prepared for the cluster's vertices.
pub(super) fn form(vid: &[[u32; 3]], w: &[PrimRef], out: &mut Vec<Draft>, scratch: &mut Local) {
    let m = w.len();
    debug_assert!((1..=MAX_WINDOW).contains(&m));
    // Window-local vertex numbers, as bits of a mask per triangle.
    scratch.window += 1;
    let mut next = 0usize;
    scratch.masks.clear();
    scratch.masks.resize(m, [0; 3]);
    let masks = &mut scratch.masks;
    for (i, p) in w.iter().enumerate() {
        for &v in &vid[p.id as usize] {
            let v = v as usize;
            if scratch.stamp[v] != scratch.window {
                scratch.stamp[v] = scratch.window;
                scratch.local[v] = next as u8;
                next += 1;
            }
            let l = scratch.local[v] as usize;
            masks[i][l / 64] |= 1 << (l % 64);
        }
    }
    // The window's longest axis (of its doubled centroids).
    let c = |p: &PrimRef, k: usize| p.c(k);
    let mut clo = [f32::INFINITY; 3];
    let mut chi = [f32::NEG_INFINITY; 3];
    for p in w {
        for k in 0..3 {
            clo[k] = fmin(clo[k], c(p, k));
            chi[k] = fmax(chi[k], c(p, k));
        }
    }
    let ext = |k: usize| chi[k] as f64 - clo[k] as f64;
    let axis = (0..3).fold(0, |a, k| if ext(k) > ext(a) { k } else { a });

    let mut remaining: u64 = if m == 64 { !0 } else { (1 << m) - 1 };
    while remaining != 0 {
        let mut seed = remaining.trailing_zeros() as usize;
        let mut r = remaining & (remaining - 1);
        while r != 0 {
            let t = r.trailing_zeros() as usize;
            r &= r - 1;
            if c(&w[t], axis) < c(&w[seed], axis) {
                seed = t;
            }
        }
        remaining &= !(1 << seed);
        let mut g = Draft::new(&w[seed]);
        let mut have = masks[seed];
        let mut corners = count(&have);
        while (g.n as usize) < GROUP_LANES && remaining != 0 {
            // (new corners, area of the grown box, triangle)
            let mut best: Option<(u32, f64, usize)> = None;
            let mut r = remaining;
            while r != 0 {
                let t = r.trailing_zeros() as usize;
                r &= r - 1;
                let new = count(&and_not(&masks[t], &have));
                if corners + new > GROUP_CORNERS as u32 || best.is_some_and(|b| new > b.0) {
                    continue;
                }
                let (tlo, thi) = (w[t].lo(), w[t].hi());
                let lo = std::array::from_fn(|k| fmin(g.lo[k], tlo[k]));
                let hi = std::array::from_fn(|k| fmax(g.hi[k], thi[k]));
                let area = half_area(&lo, &hi);
                if best.is_none_or(|(bn, ba, _)| new < bn || area < ba) {
                    best = Some((new, area, t));
                }
            }
            let Some((new, _, t)) = best else { break };
            remaining &= !(1 << t);
            g.absorb(&[w[t].id], &w[t].lo(), &w[t].hi());
            for (h, m) in have.iter_mut().zip(&masks[t]) {
                *h |= m;
            }
            corners += new;
        }
        out.push(g);
    }
}
