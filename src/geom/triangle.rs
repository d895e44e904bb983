//! Watertight ray–triangle intersection.
//!
//! Woop, Benthin and Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013. The ray is
//! sheared so that it runs along +z from the origin; the triangle's 2D edge functions `U`, `V`,
//! `W` are then evaluated on the sheared vertices. Edges shared by two triangles produce the same
//! edge function with opposite sign in both, so a ray can never slip between them. Where an edge
//! function is exactly zero in f32 it is recomputed in f64 (the paper's fallback), so points on an
//! edge are classified consistently.
//!
//! Deviation from the paper: no backface culling, and the `t` range test divides once after the
//! sign tests instead of the paper's sign-xor trick; both give the same answers.

use super::Ray;

/// Per-ray constants of the watertight test (paper §3, "precalculations").
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    origin: [f32; 3],
    /// Axis indices: `kz` is the dominant axis of the direction, `kx`/`ky` the other two in an
    /// order that keeps the triangle winding.
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl RayShear {
    /// Precomputes the shear for `ray`. The direction must be non-zero and finite
    /// ([`Ray::is_valid`]).
    pub fn new(ray: &Ray) -> RayShear {
        let d = ray.dir;
        let a = [d[0].abs(), d[1].abs(), d[2].abs()];
        let kz = if a[0] >= a[1] && a[0] >= a[2] {
            0
        } else if a[1] >= a[2] {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        RayShear {
            origin: ray.origin,
            kx,
            ky,
            kz,
            sx: d[kx] / d[kz],
            sy: d[ky] / d[kz],
            sz: 1.0 / d[kz],
        }
    }

    /// The `t` at which the ray hits triangle `v`, if it does with `tmin <= t <= tmax`.
    #[inline(always)]
    pub fn intersect(&self, v: &[[f32; 3]; 3], tmin: f32, tmax: f32) -> Option<f32> {
        let o = self.origin;
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        if kx > 2 || ky > 2 || kz > 2 {
            return None; // never: lets the compiler drop the bounds checks below
        }
        // Vertices relative to the origin, then sheared so the ray runs along +z.
        let rel = |p: &[f32; 3]| [p[kx] - o[kx], p[ky] - o[ky], p[kz] - o[kz]];
        let (a, b, c) = (rel(&v[0]), rel(&v[1]), rel(&v[2]));
        let ax = a[0] - self.sx * a[2];
        let ay = a[1] - self.sy * a[2];
        let bx = b[0] - self.sx * b[2];
        let by = b[1] - self.sy * b[2];
        let cx = c[0] - self.sx * c[2];
        let cy = c[1] - self.sy * c[2];

        let mut u = cx * by - cy * bx;
        let mut v_ = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v_ == 0.0 || w == 0.0 {
            // Paper §4.2: recompute the edge functions in double precision on the edges.
            let (ax, ay, bx, by, cx, cy) = (
                ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64,
            );
            u = (cx * by - cy * bx) as f32;
            v_ = (ax * cy - ay * cx) as f32;
            w = (bx * ay - by * ax) as f32;
        }
        // Inside when the three edge functions agree in sign. Evaluated without branches (the
        // outcome is unpredictable); the caller branches once, on the answer, which is mostly
        // "miss".
        let all_pos = (u >= 0.0) & (v_ >= 0.0) & (w >= 0.0);
        let all_neg = (u <= 0.0) & (v_ <= 0.0) & (w <= 0.0);
        let det = u + v_ + w;
        let t_scaled = u * (self.sz * a[2]) + v_ * (self.sz * b[2]) + w * (self.sz * c[2]);
        let t = t_scaled / det;
        // det == 0 gives t = NaN or inf; NaN fails the range test, and det != 0 is required.
        // Non-finite vertices (rejected by the builder) give NaN too.
        let hit = (all_pos | all_neg) & (det != 0.0) & (t >= tmin) & (t <= tmax);
        hit.then_some(t)
    }
}

/// Intersects `ray` with one triangle (convenience for brute-force references and tests).
pub fn intersect_triangle(ray: &Ray, v: &[[f32; 3]; 3]) -> Option<f32> {
    if !ray.is_valid() {
        return None;
    }
    RayShear::new(ray).intersect(v, ray.tmin, ray.tmax)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    #[test]
    fn hits_inside_misses_outside() {
        let down = |x, y| Ray::new([x, y, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(intersect_triangle(&down(0.25, 0.25), &TRI), Some(2.0));
        assert_eq!(intersect_triangle(&down(0.75, 0.75), &TRI), None);
        assert_eq!(intersect_triangle(&down(-0.1, 0.2), &TRI), None);
    }

    #[test]
    fn t_is_in_units_of_the_direction_and_range_is_inclusive() {
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -4.0], 0.0, 0.5);
        assert_eq!(intersect_triangle(&r, &TRI), Some(0.5));
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -4.0], 0.5, 0.5);
        assert_eq!(intersect_triangle(&r, &TRI), Some(0.5));
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -4.0], 0.0, 0.49);
        assert_eq!(intersect_triangle(&r, &TRI), None);
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -4.0], 0.51, 9.0);
        assert_eq!(intersect_triangle(&r, &TRI), None);
    }

    #[test]
    fn shared_edge_is_watertight() {
        // Two triangles sharing the diagonal of the unit square; rays exactly on the diagonal,
        // from many directions, must hit at least one of them.
        let t1 = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]];
        let t2 = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        for i in 1..100 {
            let s = i as f32 / 100.0;
            for d in [[0.0, 0.0, -1.0], [0.3, 0.1, -1.0], [-0.2, 0.7, -0.5]] {
                // Start at height 2 above the diagonal point (s, s, 0): t = 2 / -d.z there.
                let t = 2.0 / -d[2];
                let o = [s - d[0] * t, s - d[1] * t, 2.0];
                let r = Ray::new(o, d, 0.0, f32::INFINITY);
                let h1 = intersect_triangle(&r, &t1);
                let h2 = intersect_triangle(&r, &t2);
                assert!(
                    h1.is_some() || h2.is_some(),
                    "ray {r:?} slipped through the edge"
                );
            }
        }
    }

    #[test]
    fn degenerate_triangles_are_never_hit() {
        let line = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let point = [[0.5, 0.5, 0.5]; 3];
        let r = Ray::new([1.0, 0.0, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(intersect_triangle(&r, &line), None);
        let r = Ray::new([0.5, 0.5, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(intersect_triangle(&r, &point), None);
    }

    #[test]
    fn invalid_rays_miss() {
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, 0.0], 0.0, 9.0);
        assert_eq!(intersect_triangle(&r, &TRI), None);
        let r = Ray::new([f32::NAN, 0.2, 2.0], [0.0, 0.0, -1.0], 0.0, 9.0);
        assert_eq!(intersect_triangle(&r, &TRI), None);
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -1.0], 3.0, 1.0);
        assert_eq!(intersect_triangle(&r, &TRI), None);
    }
}
