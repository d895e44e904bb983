//! Building the grid: its resolution, then every triangle binned into the cells it overlaps.
//!
//! **Resolution.** The usual heuristic (Cleary and Wyvill 1988; pbrt-v1's `GridAccel`; Wald et
//! al., "Ray Tracing Animated Scenes using Coherent Grid Traversal", SIGGRAPH 2006): cells per
//! axis `n_k = e_k * cbrt(λ N / V)` for a box of extents `e` and volume `V` holding `N`
//! triangles, i.e. about `λ` cells per triangle with cells as close to cubes as the box allows.
//! We take **λ = 4** ([`LAMBDA`]): with the exact triangle–cell test a typical scanned-mesh
//! triangle lands in 2–4 cells, so λ = 4 gives roughly one triangle reference per non-empty cell
//! and most cells on a ray empty and cheap, which is the range (λ ≈ 3–5) the cited work finds
//! best; pbrt-v1's `3 cbrt(N)` cells on the longest axis is the same rule with a smaller λ for
//! elongated boxes. Each axis is clamped to `[1, 512]` ([`MAX_RES`]) and the total to
//! [`MAX_CELLS`]. The `n_k` are found by bisection on the scale `cbrt(λ N / V)` (the largest
//! scale whose rounded, clamped cell counts stay within the budget), which equals the formula on
//! ordinary boxes and also does the right thing for flat meshes, whose volume is zero: they get
//! a 2D grid of about `λ N` cells.
//!
//! **Binning.** A triangle is referenced by every cell it overlaps: the cells its bounding box
//! covers, each confirmed with the exact separating-axis test
//! ([`triangle_overlaps_box`], Akenine-Möller 2001), a triangle that covers a single cell without
//! the test. Each cell box is grown by a small margin ([`MARGIN_REL`] of a cell plus a few f32
//! ulps of the scene's coordinates), as the OAVM builder grows its cells by `CELL_MARGIN`: a
//! triangle on (or within rounding of) a cell face is in both cells, so the early stop at a
//! cell's exit `t` never loses a hit just across the face. The binning runs on rayon over chunks
//! of triangles; the cell lists are then laid out CSR-style by a counting sort (count pass,
//! prefix sum, fill pass), which keeps each cell's list in triangle order and the build
//! deterministic.

use std::time::Instant;

use rayon::prelude::*;

use super::UniformGrid;
use super::node::Cells;
use crate::aabb::padded_bounds;
use crate::leaf::Soup;
use crate::{StructureStats, Triangles};
use oavm::geom::tribox::triangle_overlaps_box;

/// Target cells per triangle (λ in the module docs).
pub const LAMBDA: f64 = 4.0;
/// Most cells along one axis.
pub const MAX_RES: u32 = 512;
/// Most cells in all.
pub const MAX_CELLS: u64 = 1 << 24;
/// Every cell is grown by this fraction of its size on each side when triangles are binned.
pub const MARGIN_REL: f64 = 1e-4;

impl UniformGrid {
    pub fn build(tris: &Triangles) -> UniformGrid {
        let start = Instant::now();
        let mut g = UniformGrid {
            lo: [0.0; 3],
            hi: [0.0; 3],
            cell: [1.0; 3],
            inv_cell: [1.0; 3],
            res: [0; 3],
            cells: Cells::default(),
            soup: Soup::finite(tris),
            brute: false,
            stats: StructureStats {
                name: "grid",
                ..StructureStats::default()
            },
        };
        if let Some((lo, hi)) = padded_bounds(&g.soup.v) {
            g.lo = lo;
            g.hi = hi;
            let ext: [f64; 3] = std::array::from_fn(|k| hi[k] - lo[k]);
            let mut target = (LAMBDA * g.soup.len() as f64).clamp(1.0, MAX_CELLS as f64);
            loop {
                g.res = resolution(ext, target);
                g.cell = std::array::from_fn(|k| ext[k] / g.res[k] as f64);
                g.inv_cell = std::array::from_fn(|k| 1.0 / g.cell[k]);
                if let Some(cells) = g.bin() {
                    g.cells = cells;
                    break;
                }
                if g.res == [1; 3] {
                    g.brute = true;
                    g.res = [0; 3];
                    break;
                }
                target = (target / 8.0).max(1.0);
            }
        }
        let cells = g.cells.count() as u64;
        g.stats.build_seconds = start.elapsed().as_secs_f64();
        g.stats.nodes = cells;
        g.stats.pointers = cells;
        g.stats.bytes =
            (std::mem::size_of::<UniformGrid>() + g.cells.bytes() + g.soup.bytes()) as u64;
        g
    }

    /// Bins every triangle into the cells it overlaps and lays the lists out CSR; `None` if the
    /// references do not fit `u32` offsets.
    fn bin(&self) -> Option<Cells> {
        let res = self.res.map(|r| r as usize);
        let cells = res[0] * res[1] * res[2];
        let scale = (0..3)
            .map(|k| self.lo[k].abs().max(self.hi[k].abs()))
            .fold(0.0, f64::max);
        let margin: [f64; 3] =
            std::array::from_fn(|k| MARGIN_REL * self.cell[k] + 8.0 * f32::EPSILON as f64 * scale);
        const CHUNK: usize = 4096;
        // (cell, triangle) pairs, chunk by chunk in triangle order.
        let pairs: Vec<Vec<(u32, u32)>> = self
            .soup
            .v
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut out = Vec::with_capacity(chunk.len() * 3);
                for (j, t) in chunk.iter().enumerate() {
                    let Ok(id) = u32::try_from(ci * CHUNK + j) else {
                        continue; // beyond u32: caught by the size check below
                    };
                    let tv: [[f64; 3]; 3] = t.map(|p| p.map(|c| c as f64));
                    let mut c0 = [0usize; 3];
                    let mut c1 = [0usize; 3];
                    for k in 0..3 {
                        let lo = tv[0][k].min(tv[1][k]).min(tv[2][k]) - margin[k];
                        let hi = tv[0][k].max(tv[1][k]).max(tv[2][k]) + margin[k];
                        c0[k] = self.cell_coord(k, lo);
                        c1[k] = self.cell_coord(k, hi);
                    }
                    let single = c0 == c1;
                    for z in c0[2]..=c1[2] {
                        for y in c0[1]..=c1[1] {
                            for x in c0[0]..=c1[0] {
                                let i = [x, y, z];
                                let hit = single || {
                                    let c: [f64; 3] = std::array::from_fn(|k| {
                                        self.lo[k] + (i[k] as f64 + 0.5) * self.cell[k]
                                    });
                                    let h: [f64; 3] =
                                        std::array::from_fn(|k| 0.5 * self.cell[k] + margin[k]);
                                    triangle_overlaps_box(&tv, c, h)
                                };
                                if hit {
                                    // cells <= MAX_CELLS < 2^32
                                    let cell = (z * res[1] + y) * res[0] + x;
                                    out.push((cell as u32, id));
                                }
                            }
                        }
                    }
                }
                out
            })
            .collect();
        if u32::try_from(self.soup.len()).is_err() {
            return None;
        }
        // Count pass, prefix sum, fill pass.
        let mut offsets = vec![0u64; cells + 1];
        for &(c, _) in pairs.iter().flatten() {
            offsets[c as usize + 1] += 1;
        }
        for i in 0..cells {
            offsets[i + 1] += offsets[i];
        }
        let total = offsets[cells];
        if u32::try_from(total).is_err() {
            return None;
        }
        let mut cursor = offsets.clone();
        let mut refs = vec![0u32; total as usize];
        for &(c, t) in pairs.iter().flatten() {
            let at = &mut cursor[c as usize];
            refs[*at as usize] = t;
            *at += 1;
        }
        Some(Cells::new(
            offsets.into_iter().map(|o| o as u32).collect(),
            refs,
        ))
    }
}

/// Cells per axis for a box of extents `ext` and a budget of `target` cells (module docs).
pub(super) fn resolution(ext: [f64; 3], target: f64) -> [u32; 3] {
    let longest = ext[0].max(ext[1]).max(ext[2]);
    let e = ext.map(|x| x / longest);
    let cells = |s: f64| e.map(|x| (x * s).round().clamp(1.0, MAX_RES as f64) as u32);
    let count = |r: [u32; 3]| r.iter().map(|&x| x as f64).product::<f64>();
    let shortest = e[0].min(e[1]).min(e[2]).max(1e-300);
    let (mut lo, mut hi) = (0.0, 2.0 * MAX_RES as f64 / shortest);
    if count(cells(hi)) <= target {
        return cells(hi);
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if count(cells(mid)) <= target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    cells(lo)
}
