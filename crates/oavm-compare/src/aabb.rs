//! Axis-aligned boxes as the comparison structures use them: f32 boxes with their surface area
//! (the SAH of the KD-tree and the BVH), the padded f64 box of a grid or KD-tree root, and the
//! f64 slab test that clips a ray to it.

use super::leaf::Tri;
use oavm::geom::Ray;

/// An f32 box; [`Aabb::EMPTY`] grows into the box of what is added to it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Aabb {
    pub(crate) lo: [f32; 3],
    pub(crate) hi: [f32; 3],
}

impl Aabb {
    pub(crate) const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };

    pub(crate) fn grow_box(&mut self, lo: &[f32; 3], hi: &[f32; 3]) {
        for k in 0..3 {
            self.lo[k] = self.lo[k].min(lo[k]);
            self.hi[k] = self.hi[k].max(hi[k]);
        }
    }

    pub(crate) fn grow_point(&mut self, p: &[f32; 3]) {
        self.grow_box(p, p);
    }

    pub(crate) fn union(mut self, o: &Aabb) -> Aabb {
        self.grow_box(&o.lo, &o.hi);
        self
    }

    /// The box of one triangle.
    pub(crate) fn of_triangle(t: &Tri) -> Aabb {
        Aabb {
            lo: std::array::from_fn(|k| t[0][k].min(t[1][k]).min(t[2][k])),
            hi: std::array::from_fn(|k| t[0][k].max(t[1][k]).max(t[2][k])),
        }
    }

    /// Surface area, in f64 (no overflow or underflow for any f32 box); 0 for an empty box.
    pub(crate) fn area(&self) -> f64 {
        let e: [f64; 3] = std::array::from_fn(|k| (self.hi[k] as f64 - self.lo[k] as f64).max(0.0));
        2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])
    }
}

/// The bounding box of `tris`, padded on every side by `1e-5` of its diagonal (so no triangle
/// lies on a face of it and a flat mesh gets a box with volume); `None` for no triangles.
pub(crate) fn padded_bounds(tris: &[Tri]) -> Option<([f64; 3], [f64; 3])> {
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
