//! Watertight ray–triangle intersection.
//!
//! Woop, Benthin and Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013. The ray is
//! sheared so that it runs along +z from the origin; the triangle's 2D edge functions `U`, `V`,
//! `W` are then evaluated on the sheared vertices. Edges shared by two triangles produce the same
//! edge function with opposite sign in both, so a ray can never slip between them. Where an edge
//! function is exactly zero in f32 it is recomputed in f64 (the paper's fallback), so points on an
//! edge are classified consistently; a recomputed value too small for an f32 keeps its sign.
//!
//! Deviations from the paper: no backface culling, and the `t` range test divides once after
//! the sign tests instead of the paper's sign-xor trick; both give the same answers. Two rules
//! of `RAYS.md` the paper does not have: a hit whose `t` is not finite (a subnormal direction
//! makes `1 / d` infinite) is a miss, since `+inf` means a miss; and a ray whose origin lies on
//! the triangle hits it at `t = 0` whatever its direction (when `tmin <= 0`). The paper's `t`
//! of such a ray is 0 only up to rounding (its terms cancel, and may leave it just below 0), so
//! when the point is inside and `t` is negative by no more than the rounding error of `t`
//! (bounded as pbrt-v4 bounds it: Pharr, Jakob and Humphreys, *Physically Based Rendering*,
//! 4th ed., "Robust Triangle Intersections"), the hit counts at `t = 0`. That bound is only
//! computed on that rare path, and only about 0: a `t` short of a positive `tmin` (a shadow ray
//! leaving a surface) is a miss, as before.

use glam::Vec4;

use super::Ray;

/// Per-ray constants of the watertight test (paper §3, "precalculations").
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    // The fields are the group kernel's too (`super::group`), which repeats this file's
    // operations lane by lane.
    pub(super) origin: [f32; 3],
    /// Axis indices: `kz` is the dominant axis of the direction, `kx`/`ky` the other two in an
    /// order that keeps the triangle winding.
    pub(super) kx: usize,
    pub(super) ky: usize,
    pub(super) kz: usize,
    pub(super) sx: f32,
    pub(super) sy: f32,
    pub(super) sz: f32,
}

impl RayShear {
    /// Precomputes the shear for `ray`. The direction must be non-zero and finite
    /// ([`Ray::is_valid`]).
    #[inline]
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
            u = narrow(cx * by - cy * bx);
            v_ = narrow(ax * cy - ay * cx);
            w = narrow(bx * ay - by * ax);
        }
        // Inside when the three edge functions agree in sign. Evaluated without branches (the
        // outcome is unpredictable); the caller branches once, on the answer, which is mostly
        // "miss".
        let all_pos = (u >= 0.0) & (v_ >= 0.0) & (w >= 0.0);
        let all_neg = (u <= 0.0) & (v_ <= 0.0) & (w <= 0.0);
        let det = u + v_ + w;
        let (az, bz, cz) = (self.sz * a[2], self.sz * b[2], self.sz * c[2]);
        let t_scaled = u * az + v_ * bz + w * cz;
        let t = t_scaled / det;
        // det == 0 gives t = NaN or inf; NaN fails the range test, and det != 0 is required.
        // Non-finite vertices (rejected by the builder) give NaN too; an infinite t is a miss.
        let inside = (all_pos | all_neg) & (det != 0.0);
        // The range clamped to finite values: a hit at an infinite `t` is a miss.
        let (lo, hi) = (tmin.max(-f32::MAX), tmax.min(f32::MAX));
        if inside & (t >= lo) & (t <= hi) {
            return Some(t);
        }
        // Inside, but behind, with 0 in range: a hit at t = 0 if the origin lies on the
        // triangle (t just below 0 is then the rounding of the f32 test).
        if !(inside && t < 0.0 && tmin <= 0.0 && tmax >= 0.0) {
            return None;
        }
        origin_on_triangle(v, o).then_some(0.0)
    }
}

/// An edge function recomputed in f64 (paper §4.2), back in f32 with its sign kept: the f64
/// value's sign is exact (the products of two f32s are exact in f64, and their difference is
/// rounded once), but a value below the smallest f32 subnormal would round to 0 and read as
/// "on the edge" (a triangle a subnormal thick, seen by a ray along its plane, was then hit by
/// rays missing it by 1e-4 of its size); it becomes the smallest subnormal of its sign instead.
#[inline(always)]
pub(super) fn narrow(x: f64) -> f32 {
    let tiny = f32::from_bits(1);
    match x as f32 {
        0.0 if x > 0.0 => tiny,
        0.0 if x < 0.0 => -tiny,
        y => y,
    }
}

/// Whether `o` lies on triangle `v` (its plane, inside or on its edges), evaluated in f64 from
/// the f32 coordinates: the differences are exact and the products nearly so, so the only
/// allowance is the rounding of the f64 evaluation itself (32 ulps of the sum of the absolute
/// terms), not of the f32 coordinates: a point near the triangle is not on it (the f64
/// reference agrees).
#[cold]
pub(super) fn origin_on_triangle(v: &[[f32; 3]; 3], o: [f32; 3]) -> bool {
    type V = [f64; 3];
    let d = |a: [f32; 3], b: [f32; 3]| -> V { std::array::from_fn(|k| a[k] as f64 - b[k] as f64) };
    let cross = |a: V, b: V| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: V, b: V| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // The same products on absolute values: what bounds the rounding of each (a static filter
    // as in Shewchuk's predicates, term by term, so a sliver's long edges do not loosen it).
    let abs = |a: V| a.map(f64::abs);
    let cross_abs = |a: V, b: V| {
        let (a, b) = (abs(a), abs(b));
        [
            a[1] * b[2] + a[2] * b[1],
            a[2] * b[0] + a[0] * b[2],
            a[0] * b[1] + a[1] * b[0],
        ]
    };
    let ulps = 32.0 * f64::EPSILON;
    let (e1, e2) = (d(v[1], v[0]), d(v[2], v[0]));
    let (n, n_abs) = (cross(e1, e2), cross_abs(e1, e2));
    let s = d(o, v[0]);
    // `n` zero (a degenerate triangle) or NaN: not on it.
    let n_len = dot(n, n).sqrt();
    if n_len.is_nan() || n_len == 0.0 || dot(n, s).abs() > ulps * dot(n_abs, abs(s)) {
        return false;
    }
    // Each edge `a -> b`: `o` on its inner side (the side of the third corner), or on it.
    (0..3).all(|i| {
        let (a, b) = (v[i], v[(i + 1) % 3]);
        let (e, p) = (d(b, a), d(o, a));
        dot(cross(e, p), n) >= -ulps * dot(cross_abs(e, p), n_abs)
    })
}

impl RayShear {
    /// The origin-on-triangle rule of [`RayShear::intersect`] for the lanes `near` of
    /// [`RayShear::intersect4`] (inside, `t` below 0 by its sign bit, `tmin <= 0`): a hit at
    /// `t = 0` where the origin lies on the triangle.
    #[cold]
    #[inline(never)]
    fn origin_lanes(
        &self,
        tris: [&[[f32; 3]; 3]; 4],
        near: u32,
        tmax: f32,
        mask: &mut u32,
        ts: &mut [f32; 4],
    ) {
        for l in (0..4).filter(|l| near >> l & 1 == 1) {
            if tmax >= 0.0 && origin_on_triangle(tris[l], self.origin) {
                *mask |= 1 << l;
                ts[l] = 0.0;
            }
        }
    }

    /// The watertight test on four triangles at once (SSE lanes through `glam::Vec4`), with the
    /// same operations in the same order as [`RayShear::intersect`], so every lane's answer is
    /// bit-for-bit the scalar answer. Returns the lanes that hit (bit `i` for `tris[i]`) and
    /// their `t`.
    #[inline(always)]
    pub fn intersect4(&self, tris: [&[[f32; 3]; 3]; 4], tmin: f32, tmax: f32) -> (u32, [f32; 4]) {
        let o = self.origin;
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        if kx > 2 || ky > 2 || kz > 2 {
            return (0, [0.0; 4]); // never: lets the compiler drop the bounds checks below
        }
        // Corner `v`, axis `k`, relative to the origin, for the four triangles.
        let rel = |v: usize, k: usize| {
            Vec4::new(tris[0][v][k], tris[1][v][k], tris[2][v][k], tris[3][v][k])
                - Vec4::splat(o[k])
        };
        let (sx, sy, sz) = (
            Vec4::splat(self.sx),
            Vec4::splat(self.sy),
            Vec4::splat(self.sz),
        );
        let (az, bz, cz) = (rel(0, kz), rel(1, kz), rel(2, kz));
        let ax = rel(0, kx) - sx * az;
        let ay = rel(0, ky) - sy * az;
        let bx = rel(1, kx) - sx * bz;
        let by = rel(1, ky) - sy * bz;
        let cx = rel(2, kx) - sx * cz;
        let cy = rel(2, ky) - sy * cz;
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        let zero = Vec4::ZERO;
        if (u.cmpeq(zero) | v.cmpeq(zero) | w.cmpeq(zero)).any() {
            // Paper §4.2, per lane: recompute the edge functions in double precision.
            let (mut ua, mut va, mut wa) = (u.to_array(), v.to_array(), w.to_array());
            let (axa, aya, bxa, bya, cxa, cya) = (
                ax.to_array(),
                ay.to_array(),
                bx.to_array(),
                by.to_array(),
                cx.to_array(),
                cy.to_array(),
            );
            for l in 0..4 {
                if ua[l] == 0.0 || va[l] == 0.0 || wa[l] == 0.0 {
                    let (ax, ay, bx, by, cx, cy) = (
                        axa[l] as f64,
                        aya[l] as f64,
                        bxa[l] as f64,
                        bya[l] as f64,
                        cxa[l] as f64,
                        cya[l] as f64,
                    );
                    ua[l] = narrow(cx * by - cy * bx);
                    va[l] = narrow(ax * cy - ay * cx);
                    wa[l] = narrow(bx * ay - by * ax);
                }
            }
            (u, v, w) = (
                Vec4::from_array(ua),
                Vec4::from_array(va),
                Vec4::from_array(wa),
            );
        }
        let all_pos = u.cmpge(zero) & v.cmpge(zero) & w.cmpge(zero);
        let all_neg = u.cmple(zero) & v.cmple(zero) & w.cmple(zero);
        let det = u + v + w;
        let (szaz, szbz, szcz) = (sz * az, sz * bz, sz * cz);
        let t_scaled = u * szaz + v * szbz + w * szcz;
        let t = t_scaled / det;
        let inside = (all_pos | all_neg) & det.cmpne(zero);
        // The range clamped to finite values: a hit at an infinite `t` (a subnormal direction)
        // is a miss.
        let (lo, hi) = (tmin.max(-f32::MAX), tmax.min(f32::MAX));
        let inside = inside.bitmask();
        let mut mask = inside & (t.cmpge(Vec4::splat(lo)) & t.cmple(Vec4::splat(hi))).bitmask();
        let mut ts = t.to_array();
        // Inside, but behind, with 0 in range: a hit at t = 0 if the origin lies on the
        // triangle (the scalar test's rule, lane by lane). Shadow rays, whose tmin is above 0,
        // never look; the lanes that do are rare and are looked at out of line.
        if tmin <= 0.0 {
            let near = inside & t.is_negative_bitmask() & !mask;
            if near != 0 {
                self.origin_lanes(tris, near, tmax, &mut mask, &mut ts);
            }
        }
        (mask, ts)
    }
}

impl RayShear {
    /// Whether a hit of this ray on triangle `v` (one [`RayShear::intersect`] found) is the
    /// triangle's to report when hits are counted or listed: false only for a ray through an
    /// edge or a corner that a neighbour owns, so that a ray through an edge shared by two
    /// triangles, or through a corner shared by a fan, meets the surface once, not twice.
    ///
    /// The rule is the rasterizer's fill rule on the sheared plane the test works in. An edge
    /// function exactly 0 (after the f64 recompute, where it is exact) puts the ray on that
    /// edge; the edge goes to the triangle for which it runs, in the orientation that makes
    /// the triangle's edge functions positive inside, with `dy > 0`, or `dy == 0` and
    /// `dx > 0`. Two triangles on either side of an edge see it run in opposite directions
    /// (their corners are the same f32 values, sheared alike, so the direction's signs are
    /// exact), so exactly one of them owns it; the rule is the point moved by an
    /// infinitesimal `(-e, e^2)` or `(e, -e^2)` (simulation of simplicity), so a corner too
    /// goes to exactly one triangle of a fan around it. A ray along a fold (both triangles on
    /// one side of the edge as the ray sees them) meets both or neither: it touches the
    /// surface without crossing it.
    pub fn owns(&self, v: &[[f32; 3]; 3]) -> bool {
        let o = self.origin;
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        // Sheared as `intersect` shears them, operation for operation.
        let p = v.map(|p| {
            let (x, y, z) = (p[kx] - o[kx], p[ky] - o[ky], p[kz] - o[kz]);
            [x - self.sx * z, y - self.sy * z]
        });
        let edge = |i: usize, j: usize| p[j][0] * p[i][1] - p[j][1] * p[i][0];
        // `u` is the edge b -> c, `v` c -> a, `w` a -> b, as in `intersect`.
        let mut f = [edge(1, 2), edge(2, 0), edge(0, 1)];
        if f.contains(&0.0) {
            let wide = p.map(|q| q.map(f64::from));
            let exact =
                |i: usize, j: usize| narrow(wide[j][0] * wide[i][1] - wide[j][1] * wide[i][0]);
            f = [exact(1, 2), exact(2, 0), exact(0, 1)];
        }
        let det = f[0] + f[1] + f[2];
        if !f.contains(&0.0) || det == 0.0 || det.is_nan() {
            return true;
        }
        let flip = if det < 0.0 { -1.0 } else { 1.0 };
        (0..3).all(|e| {
            let (i, j) = ((e + 1) % 3, (e + 2) % 3);
            let (dx, dy) = (flip * (p[j][0] - p[i][0]), flip * (p[j][1] - p[i][1]));
            f[e] != 0.0 || dy > 0.0 || (dy == 0.0 && dx > 0.0)
        })
    }
}

/// Intersects `ray` with one triangle (convenience for brute-force references and tests).
pub fn intersect_triangle(ray: &Ray, v: &[[f32; 3]; 3]) -> Option<f32> {
    if !ray.is_valid() {
        return None;
    }
    RayShear::new(ray).intersect(v, ray.tmin, ray.tmax)
}

/// A triangle whose edges' cross product is exactly zero in f64 (coincident or collinear
/// corners): it has no area and no ray can hit it (`RAYS.md`: degenerate triangles keep their
/// ids but are never hit), so it is not stored.
pub fn is_degenerate(v: &[[f32; 3]; 3]) -> bool {
    let e1: [f64; 3] = std::array::from_fn(|k| v[1][k] as f64 - v[0][k] as f64);
    let e2: [f64; 3] = std::array::from_fn(|k| v[2][k] as f64 - v[0][k] as f64);
    let c = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    c == [0.0; 3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::reference;

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

    /// A triangle a subnormal thick (x between 0 and 1.7e-43, from `fuzz/regressions/pack/
    /// subnormal_offset_origin`), seen by rays along its plane: the f32 edge functions
    /// underflow to 0 and the f64 ones are below the smallest f32, so only their kept sign
    /// tells a ray passing 6e-6 beside the triangle (a miss) from one through it (a hit). The
    /// f64 reference decides both.
    #[test]
    fn underflowing_edge_functions_keep_their_sign() {
        let thin = [
            [f32::from_bits(121), 0.046508845, -0.046851568],
            [f32::from_bits(15), f32::from_bits(16), f32::from_bits(17)],
            [0.0, 0.059399605, -0.0496514],
        ];
        let beside = Ray::new(
            [0.0, f32::from_bits(15), -0.0496572],
            [0.0, 1.0, 0.0],
            0.0,
            f32::INFINITY,
        );
        assert_eq!(reference::hit_t(&thin, &beside), None);
        assert_eq!(intersect_triangle(&beside, &thin), None, "scalar");
        let shear = RayShear::new(&beside);
        assert_eq!(
            shear.intersect4([&thin; 4], 0.0, f32::INFINITY).0,
            0,
            "four lanes"
        );
        // Through it, from the side it faces: a hit at the reference's `t`.
        let through = Ray::new([1.0, 0.0353, -0.0322], [-1.0, 0.0, 0.0], 0.0, f32::INFINITY);
        let want = reference::hit_t(&thin, &through).expect("the reference hits it");
        let got = intersect_triangle(&through, &thin).expect("a hit");
        assert!((f64::from(got) - want).abs() < 1e-6, "{got} vs {want}");
    }

    /// The four-lane test gives bit-for-bit the scalar answers, edge cases included.
    #[test]
    fn four_lanes_equal_scalar() {
        let mut s = 0x1234_5678_9abc_def0u64;
        let mut r = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            // Small integers make exact zeros (edges through the ray) common.
            ((s >> 40) % 9) as f32 * 0.25 - 1.0
        };
        for _ in 0..20_000 {
            let tris: [[[f32; 3]; 3]; 4] =
                std::array::from_fn(|_| std::array::from_fn(|_| std::array::from_fn(|_| r())));
            let ray = Ray::new(
                [r(), r(), r() + 3.0],
                [r() * 0.3, r() * 0.3, -1.0],
                0.0,
                5.0,
            );
            let sh = RayShear::new(&ray);
            let (mask, t) =
                sh.intersect4([&tris[0], &tris[1], &tris[2], &tris[3]], ray.tmin, ray.tmax);
            for l in 0..4 {
                let scalar = sh.intersect(&tris[l], ray.tmin, ray.tmax);
                assert_eq!(
                    scalar.is_some(),
                    mask >> l & 1 == 1,
                    "lane {l} of {tris:?} {ray:?}"
                );
                if let Some(ts) = scalar {
                    assert_eq!(ts.to_bits(), t[l].to_bits());
                }
            }
        }
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

    /// A 6 x 6 grid of unit squares in a tilted plane, each cut along a diagonal chosen at
    /// random, each triangle's corners in a random order (windings mixed); `(x, y)` corners
    /// are whole numbers, so vertices and edge midpoints are exact.
    fn grid(seed: u64) -> Vec<[[f32; 3]; 3]> {
        let mut s = seed;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as u32
        };
        let z = |x: f32, y: f32| 0.25 * x - 0.125 * y;
        let p = |x: i32, y: i32| [x as f32, y as f32, z(x as f32, y as f32)];
        let mut tris = Vec::new();
        for x in 0..6 {
            for y in 0..6 {
                let (a, b, c, d) = (p(x, y), p(x + 1, y), p(x + 1, y + 1), p(x, y + 1));
                let halves = if next() % 2 == 0 {
                    [[a, b, c], [a, c, d]]
                } else {
                    [[a, b, d], [b, c, d]]
                };
                for mut t in halves {
                    t.rotate_left(next() as usize % 3);
                    if next() % 2 == 0 {
                        t.swap(0, 1);
                    }
                    tris.push(t);
                }
            }
        }
        tris
    }

    #[test]
    fn a_ray_through_an_edge_or_a_corner_is_owned_once() {
        let dirs = [
            [0.0, 0.0, -1.0],
            [0.0, 0.0, 1.0],
            [0.3, 0.1, -1.0],
            [-0.2, 0.7, -0.5],
            [1.0, 0.0, -0.25],
            [0.0, -1.0, 0.2],
            [0.577, -0.577, 0.577],
            [1.0, 1.0, 0.0],
        ];
        // Through corners, edge midpoints (of the axis edges and of both diagonals), and
        // points inside the interior squares.
        let mut targets = Vec::new();
        for i in 2..=10 {
            for j in 2..=10 {
                targets.push((i as f32 / 2.0, j as f32 / 2.0));
                targets.push((i as f32 / 2.0 + 0.1, j as f32 / 2.0 + 0.3));
            }
        }
        let (mut edges, mut owned_edges) = (0, 0);
        for seed in 0..8 {
            let tris = grid(seed);
            for &(x, y) in &targets {
                let at = [x, y, 0.25 * x - 0.125 * y];
                for d in dirs {
                    // From 3 units back along the direction, toward the point.
                    let o = std::array::from_fn(|k| at[k] - 3.0 * d[k]);
                    let r = Ray::new(o, d, 0.0, f32::INFINITY);
                    let shear = RayShear::new(&r);
                    let hit: Vec<_> = tris
                        .iter()
                        .filter(|t| shear.intersect(t, 0.0, f32::INFINITY).is_some())
                        .collect();
                    let owners = hit.iter().filter(|t| shear.owns(t)).count();
                    assert_eq!(
                        owners,
                        1,
                        "seed {seed}, ray {r:?}: {} hit, {owners} own it",
                        hit.len()
                    );
                    edges += (hit.len() > 1) as usize;
                    owned_edges += (hit.len() > 1 && owners == 1) as usize;
                }
            }
        }
        // The rays must have met edges and corners (several triangles hit) for this to test
        // the rule at all.
        assert!(edges > 500, "only {edges} rays met an edge or a corner");
        assert_eq!(edges, owned_edges);
    }

    #[test]
    fn a_hit_inside_is_always_owned() {
        let r = Ray::new([0.25, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert!(RayShear::new(&r).owns(&TRI));
        let flipped = [TRI[0], TRI[2], TRI[1]];
        assert!(RayShear::new(&r).owns(&flipped));
    }
}
