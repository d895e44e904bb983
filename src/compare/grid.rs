//! Uniform grid with 3D-DDA traversal: the oldest structure of the paper's comparison.
//!
//! **Traversal** is the incremental 3D-DDA of Amanatides and Woo ("A Fast Voxel Traversal
//! Algorithm for Ray Tracing", Eurographics 1987): the ray is clipped to the grid's box, the cell
//! holding the entry point is found, and from then on the ray steps into the face neighbour
//! across whichever of the three next cell faces it meets first. The `t` of the next face on each
//! axis is recomputed from the cell index (`(lo + (i + 1) * size - o) / d`) instead of being
//! accumulated, so it cannot drift over long walks; the walk is in f64. Every cell's triangles
//! are tested with the ray's full `[tmin, closest-so-far]` range (no mailboxing; a triangle in
//! several cells is tested once per cell, and `triangles_tested` counts every test).
//!
//! - closest hit: the walk stops as soon as the closest hit so far has `t <=` the current cell's
//!   exit `t` (no later cell can hold anything closer), or the ray's range ends;
//! - any hit: the walk stops at the first hit.
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
//!
//! **Storage and counting** (the paper's Table 2 sense): a *node* is a cell (`nodes` = all
//! cells, empty or not); the *pointers* are the cells' list pointers, one offset per cell into
//! the flattened reference list (`pointers` = cells; the CSR array has one extra closing entry,
//! counted in `bytes`). `bytes` counts the offsets, the references (`u32` each), the triangles
//! (36 bytes) and their primitive ids (4 bytes). While tracing, `nodes_visited` counts the cells
//! the walk enters and `leaves_visited` the non-empty ones among them.
//!
//! **Limits.** Triangles with a non-finite coordinate are not indexed (they cannot be hit).
//! Reference counts beyond `u32` make the build retry with fewer cells; an input too large even
//! for one cell (more than `u32::MAX` triangles) is traced by brute force rather than refused.

use std::time::Instant;

use rayon::prelude::*;

use super::{Accelerator, StructureStats, Triangles, brute_force, closer};
use crate::geom::triangle::RayShear;
use crate::geom::tribox::triangle_overlaps_box;
use crate::geom::{Hit, Ray};
use crate::logical::Counters;

/// Target cells per triangle (λ in the module docs).
pub const LAMBDA: f64 = 4.0;
/// Most cells along one axis.
pub const MAX_RES: u32 = 512;
/// Most cells in all.
pub const MAX_CELLS: u64 = 1 << 24;
/// Every cell is grown by this fraction of its size on each side when triangles are binned.
pub const MARGIN_REL: f64 = 1e-4;

/// A uniform grid over the triangles' bounding box, cells stored CSR.
pub struct UniformGrid {
    /// The grid's box (the triangles' box, padded a little so no triangle lies on its faces).
    lo: [f64; 3],
    hi: [f64; 3],
    cell: [f64; 3],
    inv_cell: [f64; 3],
    res: [u32; 3],
    /// `offsets[c]..offsets[c + 1]` is cell `c`'s range of `refs`; cells are numbered x fastest.
    offsets: Vec<u32>,
    /// Triangle indices (into `tris`) of all cells, cell after cell.
    refs: Vec<u32>,
    tris: Vec<[[f32; 3]; 3]>,
    prim: Vec<u32>,
    /// Too large to index with 32 bits: every ray tests every triangle.
    brute: bool,
    stats: StructureStats,
}

impl UniformGrid {
    pub fn build(tris: &Triangles) -> UniformGrid {
        let start = Instant::now();
        let (v, prim) = finite_triangles(tris);
        let mut g = UniformGrid {
            lo: [0.0; 3],
            hi: [0.0; 3],
            cell: [1.0; 3],
            inv_cell: [1.0; 3],
            res: [0; 3],
            offsets: vec![0],
            refs: Vec::new(),
            tris: v,
            prim,
            brute: false,
            stats: StructureStats {
                name: "grid",
                ..StructureStats::default()
            },
        };
        if let Some((lo, hi)) = padded_bounds(&g.tris) {
            g.lo = lo;
            g.hi = hi;
            let ext: [f64; 3] = std::array::from_fn(|k| hi[k] - lo[k]);
            let mut target = (LAMBDA * g.tris.len() as f64).clamp(1.0, MAX_CELLS as f64);
            loop {
                g.res = resolution(ext, target);
                g.cell = std::array::from_fn(|k| ext[k] / g.res[k] as f64);
                g.inv_cell = std::array::from_fn(|k| 1.0 / g.cell[k]);
                if let Some((offsets, refs)) = g.bin() {
                    g.offsets = offsets;
                    g.refs = refs;
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
        let cells = g.offsets.len().saturating_sub(1) as u64;
        g.stats.build_seconds = start.elapsed().as_secs_f64();
        g.stats.nodes = cells;
        g.stats.pointers = cells;
        g.stats.bytes = (std::mem::size_of::<UniformGrid>()
            + 4 * g.offsets.len()
            + 4 * g.refs.len()
            + std::mem::size_of::<[[f32; 3]; 3]>() * g.tris.len()
            + 4 * g.prim.len()) as u64;
        g
    }

    /// Grid resolution (cells per axis).
    pub fn resolution(&self) -> [u32; 3] {
        self.res
    }

    /// Triangle references stored over all cells.
    pub fn references(&self) -> usize {
        self.refs.len()
    }

    /// Bins every triangle into the cells it overlaps and lays the lists out CSR; `None` if the
    /// references do not fit `u32` offsets.
    fn bin(&self) -> Option<(Vec<u32>, Vec<u32>)> {
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
            .tris
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut out = Vec::with_capacity(chunk.len() * 3);
                for (j, t) in chunk.iter().enumerate() {
                    let Ok(id) = u32::try_from(ci * CHUNK + j) else {
                        continue; // beyond u32: caught by the caller's size check
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
        if u32::try_from(self.tris.len()).is_err() {
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
        Some((offsets.into_iter().map(|o| o as u32).collect(), refs))
    }

    /// The cell index along axis `k` holding coordinate `x`, clamped to the grid.
    #[inline]
    fn cell_coord(&self, k: usize, x: f64) -> usize {
        let i = ((x - self.lo[k]) * self.inv_cell[k]).floor();
        // NaN (never: finite inputs) maps to 0 through the saturating cast.
        (i.max(0.0) as usize).min(self.res[k] as usize - 1)
    }

    /// Walks the cells `ray` crosses, front to back, calling `visit(triangles, exit_t, c)` on
    /// each non-empty one until it returns `true`.
    #[inline]
    fn walk(
        &self,
        ray: &Ray,
        c: &mut Counters,
        mut visit: impl FnMut(&[u32], f64, &mut Counters) -> bool,
    ) {
        let Some((t0, t1)) = clip_ray(ray, self.lo, self.hi) else {
            return;
        };
        let o = ray.origin.map(|x| x as f64);
        let d = ray.dir.map(|x| x as f64);
        let res = self.res.map(|r| r as i64);
        let mut cell = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        for k in 0..3 {
            cell[k] = self.cell_coord(k, o[k] + t0 * d[k]) as i64;
        }
        let face_t = |k: usize, i: i64| {
            let face = if d[k] > 0.0 { i + 1 } else { i };
            (self.lo[k] + face as f64 * self.cell[k] - o[k]) / d[k]
        };
        for k in 0..3 {
            if d[k] != 0.0 {
                next[k] = face_t(k, cell[k]);
            }
        }
        // Each step moves one index by one cell in the ray's direction, so the walk leaves the
        // grid after at most res_x + res_y + res_z steps.
        loop {
            let exit = next[0].min(next[1]).min(next[2]).min(t1);
            c.nodes_visited += 1;
            let idx = ((cell[2] * res[1] + cell[1]) * res[0] + cell[0]) as usize;
            let (a, b) = (self.offsets[idx] as usize, self.offsets[idx + 1] as usize);
            if a < b {
                c.leaves_visited += 1;
                if visit(&self.refs[a..b], exit, c) {
                    return;
                }
            }
            if exit >= t1 {
                return;
            }
            let k = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            cell[k] += if d[k] > 0.0 { 1 } else { -1 };
            if cell[k] < 0 || cell[k] >= res[k] {
                return;
            }
            next[k] = face_t(k, cell[k]);
        }
    }

    fn brute_intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        brute_force(&self.tris, &self.prim, ray, c)
    }
}

impl Accelerator for UniformGrid {
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
        self.walk(ray, c, |list, exit, c| {
            for &i in list {
                c.triangles_tested += 1;
                let i = i as usize;
                if let Some(t) = sh.intersect(&self.tris[i], ray.tmin, tmax)
                    && closer(&mut best, t, self.prim[i])
                {
                    tmax = t;
                }
            }
            best.is_hit() && best.t as f64 <= exit
        });
        best
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
        self.walk(ray, c, |list, _, c| {
            for &i in list {
                c.triangles_tested += 1;
                if sh
                    .intersect(&self.tris[i as usize], ray.tmin, ray.tmax)
                    .is_some()
                {
                    found = true;
                    return true;
                }
            }
            false
        });
        found
    }
}

/// The triangles with finite coordinates and their primitive ids.
pub(crate) fn finite_triangles(tris: &Triangles) -> (Vec<[[f32; 3]; 3]>, Vec<u32>) {
    let keep = |t: &[[f32; 3]; 3]| t.iter().flatten().all(|c| c.is_finite());
    if tris.v.iter().all(keep) && tris.prim.len() == tris.v.len() {
        return (tris.v.clone(), tris.prim.clone());
    }
    tris.v
        .iter()
        .zip(&tris.prim)
        .filter(|(t, _)| keep(t))
        .map(|(t, &p)| (*t, p))
        .unzip()
}

/// The bounding box of `tris`, padded on every side by `1e-5` of its diagonal (so no triangle
/// lies on a face of it and a flat mesh gets a box with volume); `None` for no triangles.
pub(crate) fn padded_bounds(tris: &[[[f32; 3]; 3]]) -> Option<([f64; 3], [f64; 3])> {
    if tris.is_empty() {
        return None;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in tris.iter().flatten() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let scale = (0..3)
        .map(|k| lo[k].abs().max(hi[k].abs()))
        .fold(0.0, f64::max);
    let pad = (1e-5 * diag)
        .max(1e-6 * scale)
        .max(f64::MIN_POSITIVE * 1e10);
    Some((lo.map(|x| x - pad), hi.map(|x| x + pad)))
}

/// The part `[t0, t1]` of `ray`'s range `[tmin, tmax]` inside the box `[lo, hi]` (slab test in
/// f64), if any.
#[inline]
pub(crate) fn clip_ray(ray: &Ray, lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, f64)> {
    let mut t0 = ray.tmin as f64;
    let mut t1 = ray.tmax as f64;
    for k in 0..3 {
        let o = ray.origin[k] as f64;
        let d = ray.dir[k] as f64;
        if d == 0.0 {
            if o < lo[k] || o > hi[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo[k] - o) / d, (hi[k] - o) / d);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1).then_some((t0, t1))
}

/// Cells per axis for a box of extents `ext` and a budget of `target` cells (module docs).
fn resolution(ext: [f64; 3], target: f64) -> [u32; 3] {
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geom::brute;
    use crate::mesh::Mesh;

    pub(crate) fn tris_of(v: Vec<[[f32; 3]; 3]>) -> (Triangles, Mesh) {
        let mut mesh = Mesh::default();
        for t in &v {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend_from_slice(t);
            mesh.triangles.push([base, base + 1, base + 2]);
        }
        let tris = Triangles::from_mesh(&mesh).unwrap();
        (tris, mesh)
    }

    pub(crate) fn rng(seed: u64) -> impl FnMut() -> f32 {
        let mut s = crate::rays::SplitMix64::new(seed);
        move || s.next_f64() as f32
    }

    /// A random triangle soup in the unit cube.
    pub(crate) fn soup(n: usize, seed: u64) -> Vec<[[f32; 3]; 3]> {
        let mut r = rng(seed);
        (0..n)
            .map(|_| {
                let c = [r(), r(), r()];
                std::array::from_fn(|_| std::array::from_fn(|k| c[k] + 0.2 * (r() - 0.5)))
            })
            .collect()
    }

    /// Random rays from around the unit cube, some axis-parallel, some starting inside.
    pub(crate) fn rays(n: usize, seed: u64) -> Vec<Ray> {
        let mut r = rng(seed);
        (0..n)
            .map(|i| {
                let o = [r() * 1.6 - 0.3, r() * 1.6 - 0.3, r() * 1.6 - 0.3];
                let mut d = [r() - 0.5, r() - 0.5, r() - 0.5];
                if i % 4 == 0 {
                    let k = i / 4 % 3;
                    d = [0.0; 3];
                    d[k] = if i % 8 == 0 { 1.0 } else { -1.0 };
                }
                Ray::new(o, d, 0.0, f32::INFINITY)
            })
            .collect()
    }

    /// Compares closest and any hit of `acc` with brute force on `rays`; returns the number of
    /// rays that hit (so a test can insist the comparison was not vacuous).
    pub(crate) fn check(acc: &dyn Accelerator, mesh: &Mesh, rays: &[Ray]) -> usize {
        let mut c = Counters::default();
        let mut hits = 0;
        for r in rays {
            let b = brute::intersect(mesh, r);
            let h = acc.intersect(r, &mut c);
            assert_eq!(b, h, "closest hit of {r:?}");
            assert_eq!(brute::occluded(mesh, r), acc.occluded(r, &mut c), "{r:?}");
            hits += b.is_hit() as usize;
        }
        assert!(c.nodes_visited > 0 || hits == 0);
        hits
    }

    #[test]
    fn resolution_follows_the_cube_root_rule_and_handles_flat_boxes() {
        assert_eq!(resolution([1.0; 3], 4000.0), [15, 15, 15]);
        let r = resolution([2.0, 1.0, 1.0], 4000.0);
        assert!(r[0] >= 2 * r[1] - 1 && r[0] <= 2 * r[1] + 1, "{r:?}");
        let r = resolution([1.0, 1.0, 1e-9], 4000.0);
        assert_eq!(r[2], 1);
        assert!(r[0] * r[1] <= 4000 && r[0] * r[1] > 3000, "{r:?}");
        assert_eq!(resolution([1.0; 3], 1e12), [MAX_RES; 3]);
        assert_eq!(resolution([1.0; 3], 1.0), [1; 3]);
    }

    #[test]
    fn random_soup_matches_brute_force() {
        let (tris, mesh) = tris_of(soup(500, 1));
        let g = UniformGrid::build(&tris);
        assert!(g.resolution().iter().all(|&r| r > 1));
        assert!(g.references() >= tris.len());
        let hits = check(&g, &mesh, &rays(4000, 2));
        assert!(hits > 500, "{hits}");
        let s = g.stats();
        assert_eq!(s.nodes, s.pointers);
        assert!(s.bytes > 36 * 500);
    }

    #[test]
    fn empty_and_single_triangle() {
        let g = UniformGrid::build(&Triangles::default());
        let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        let mut c = Counters::default();
        assert_eq!(g.intersect(&r, &mut c), Hit::MISS);
        assert!(!g.occluded(&r, &mut c));

        let (tris, mesh) = tris_of(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
        let g = UniformGrid::build(&tris);
        let down = Ray::new([0.25, 0.25, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(g.intersect(&down, &mut c), Hit { t: 1.0, prim: 0 });
        check(&g, &mesh, &rays(2000, 3));
        let mut hits = 0;
        let mut r = rng(4);
        for _ in 0..500 {
            let ray = Ray::new([r(), r(), 1.0], [r() - 0.5, r() - 0.5, -1.0], 0.0, 10.0);
            hits += check(&g, &mesh, &[ray]);
        }
        assert!(hits > 100);
        // Invalid rays miss.
        let bad = Ray::new([0.25, 0.25, 1.0], [0.0; 3], 0.0, 1.0);
        assert_eq!(g.intersect(&bad, &mut c), Hit::MISS);
    }

    /// A flat mesh (all triangles in z = 0.5), whose box has no volume, and a mesh whose
    /// triangles all lie in a plane that is a face between cells.
    #[test]
    fn flat_meshes_and_triangles_on_cell_faces() {
        let mut r = rng(5);
        let flat: Vec<_> = (0..400)
            .map(|_| {
                let (x, y) = (r(), r());
                [[x, y, 0.5], [x + 0.05, y, 0.5], [x, y + 0.05, 0.5]]
            })
            .collect();
        let (tris, mesh) = tris_of(flat.clone());
        let g = UniformGrid::build(&tris);
        assert_eq!(g.resolution()[2], 1);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = [r(), r(), r() * 2.0 - 0.5];
            let d = if o[2] > 0.5 { -1.0 } else { 1.0 };
            let axis = Ray::new(o, [0.0, 0.0, d], 0.0, f32::INFINITY);
            let slanted = Ray::new(o, [r() - 0.5, r() - 0.5, d], 0.0, f32::INFINITY);
            hits += check(&g, &mesh, &[axis, slanted]);
        }
        assert!(hits > 300, "{hits}");

        // A block of soup plus a plane of triangles at x = 0.5 exactly, which (for an even
        // resolution along x over the unit box) is a face between cells; rays along x and
        // through the plane from both sides, starting inside the grid.
        let mut v = soup(300, 6);
        v.push([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        v.push([[1.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 0.0]]);
        for i in 0..200 {
            let (y, z) = ((i % 20) as f32 / 20.0, (i / 20) as f32 / 10.0);
            v.push([[0.5, y, z], [0.5, y + 0.05, z], [0.5, y, z + 0.1]]);
        }
        let (tris, mesh) = tris_of(v);
        let g = UniformGrid::build(&tris);
        let mut hits = 0;
        for i in 0..4000 {
            let o = [r(), r(), r()];
            let d = match i % 4 {
                0 => [1.0, 0.0, 0.0],
                1 => [-1.0, 0.0, 0.0],
                2 => [r() - 0.5, r() * 0.01, 0.0],
                _ => [r() - 0.5, r() - 0.5, r() - 0.5],
            };
            hits += check(&g, &mesh, &[Ray::new(o, d, 0.0, f32::INFINITY)]);
            // Rays lying in the plane of the cell face.
            let o = [0.5, r(), r()];
            let d = [0.0, r() - 0.5, r() - 0.5];
            hits += check(&g, &mesh, &[Ray::new(o, d, 0.0, f32::INFINITY)]);
        }
        assert!(hits > 1000, "{hits}");
    }

    #[test]
    fn range_limits_are_respected() {
        let (tris, mesh) = tris_of(soup(300, 7));
        let g = UniformGrid::build(&tris);
        let mut r = rng(8);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = [r(), r(), r()];
            let d = [r() - 0.5, r() - 0.5, r() - 0.5];
            let (a, b) = (r() * 0.5, r() * 1.5);
            hits += check(&g, &mesh, &[Ray::new(o, d, a.min(b), a.max(b))]);
        }
        assert!(hits > 300, "{hits}");
    }

    #[test]
    fn counters_count_cells() {
        let (tris, _) = tris_of(soup(200, 9));
        let g = UniformGrid::build(&tris);
        let mut c = Counters::default();
        let r = Ray::new([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        g.occluded(&Ray { tmax: -1.0, ..r }, &mut c);
        assert_eq!(c, Counters::default()); // invalid: nothing visited
        let miss = Ray::new([-1.0, 0.5, 0.5], [-1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        g.intersect(&miss, &mut c);
        assert_eq!(c.nodes_visited, 0);
        g.intersect(&r, &mut c);
        assert!(c.nodes_visited >= 1 && c.nodes_visited <= g.resolution()[0] as u64);
        assert!(c.leaves_visited <= c.nodes_visited);
        assert_eq!(c.rays, 0);
    }
}
