//! The reference answers that tests and checks measure every structure against: a brute force
//! over every triangle in double precision (Möller and Trumbore, "Fast, Minimum Storage
//! Ray/Triangle Intersection", 1997), which shares no code with the single-precision
//! watertight kernel ([`super::triangle`]) the structures use, so a defect of that kernel
//! cannot hide in its own reference.
//!
//! In f64 the products of coordinates of any f32 mesh neither underflow nor overflow, a ray
//! whose origin lies in a triangle's plane gets `t` of exactly 0 where the plane is axis-aligned
//! (every term of the numerator is 0), and a hit whose `t` does not fit an f32 (a subnormal
//! direction) is a miss, as `RAYS.md` records a miss with `t = +inf`. It is not watertight: a
//! ray within rounding of an edge shared by two triangles may miss both; [`Meet::margin`] tells
//! such rays apart, so a comparison can excuse them and nothing else.

use super::{Hit, Ray};

type V = [f64; 3];

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: V, b: V) -> V {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Where the line of a ray meets the plane of a triangle, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Meet {
    /// Barycentric coordinates of the point (of the second and third corners).
    pub u: f64,
    pub v: f64,
    /// The ray's parameter there.
    pub t: f64,
}

impl Meet {
    /// How far inside the triangle the point is: the smallest barycentric coordinate (0 on an
    /// edge, negative outside). A disagreement with the reference on a ray whose margin is
    /// within rounding of 0 for a triangle it meets is a grazing hit on an edge, which
    /// `RAYS.md` allows either way.
    pub fn margin(&self) -> f64 {
        self.u.min(self.v).min(1.0 - self.u - self.v)
    }
}

/// Where the line of `ray` meets the plane of `tri`; `None` for a ray parallel to the plane or
/// a degenerate triangle.
pub fn meet(tri: &[[f32; 3]; 3], ray: &Ray) -> Option<Meet> {
    let [a, b, c] = tri.map(|p| p.map(f64::from));
    let o = ray.origin.map(f64::from);
    let d = ray.dir.map(f64::from);
    let (e1, e2) = (sub(b, a), sub(c, a));
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let s = sub(o, a);
    let q = cross(s, e1);
    Some(Meet {
        u: dot(s, p) / det,
        v: dot(d, q) / det,
        t: dot(e2, q) / det,
    })
}

/// `t` of the hit of `ray` on `tri`, if it hits it with `tmin <= t <= tmax` and `t` is
/// finite as an f32.
pub fn hit_t(tri: &[[f32; 3]; 3], ray: &Ray) -> Option<f64> {
    if !ray.is_valid() {
        return None;
    }
    let Meet { u, v, t } = meet(tri, ray)?;
    let inside = u >= 0.0 && v >= 0.0 && u + v <= 1.0;
    let in_range = t >= ray.tmin as f64 && t <= ray.tmax as f64 && (t as f32).is_finite();
    (inside && in_range).then_some(t)
}

/// The closest hit of `ray` over `tris` (triangle `i` has primitive id `i`); ties keep the
/// lowest id.
pub fn closest(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Hit {
    let mut best: Option<(f64, usize)> = None;
    for (i, tri) in tris.iter().enumerate() {
        if let Some(t) = hit_t(tri, ray)
            && best.is_none_or(|(b, _)| t < b)
        {
            best = Some((t, i));
        }
    }
    best.map_or(Hit::MISS, |(t, i)| Hit {
        t: t as f32,
        prim: i as u32,
    })
}

/// Whether `ray` hits any of `tris` with `tmin <= t <= tmax`.
pub fn occluded(tris: &[[[f32; 3]; 3]], ray: &Ray) -> bool {
    tris.iter().any(|tri| hit_t(tri, ray).is_some())
}

/// How close (relative to the size of the edge and of the coordinates) a ray must pass to an
/// edge or a corner to graze it: well above f32 rounding (about 6e-8 of a coordinate).
pub const GRAZING: f64 = 1e-5;

/// Whether `ray` passes within [`GRAZING`] of an edge (or a corner) of one of `tris`, at a `t`
/// within its range (or within rounding of it): where a watertight f32 tracer and this
/// reference may both be right, one hitting the triangle on one side of the edge, the other the
/// triangle on the other side or neither.
pub fn grazes(tris: &[[[f32; 3]; 3]], ray: &Ray) -> bool {
    if !ray.is_valid() {
        return false;
    }
    let o = ray.origin.map(f64::from);
    let d = ray.dir.map(f64::from);
    let dd = dot(d, d);
    let slack = 1e-6 * (1.0 + (ray.tmin as f64).abs());
    let in_range = |t: f64| t >= ray.tmin as f64 - slack && t <= ray.tmax as f64 + slack;
    tris.iter().any(|tri| {
        let v = tri.map(|p| p.map(f64::from));
        (0..3).any(|k| {
            let (a, b) = (v[k], v[(k + 1) % 3]);
            let e = sub(b, a);
            let size = dot(e, e).sqrt();
            let scale = a
                .iter()
                .chain(&b)
                .chain(&o)
                .fold(0.0f64, |m, c| m.max(c.abs()));
            let tol = GRAZING * size + 1e-6 * scale;
            // The closest points of the ray's line o + t d and the segment a + s e, s in [0, 1].
            let w = sub(o, a);
            let (de, ee) = (dot(d, e), dot(e, e));
            let (dw, ew) = (dot(d, w), dot(e, w));
            let den = dd * ee - de * de;
            let mut s = if den > 0.0 {
                (dd * ew - de * dw) / den
            } else {
                0.0
            };
            s = s.clamp(0.0, 1.0);
            // The ray's t closest to the segment's point at s; outside the ray's range, the
            // range's nearer end, and the segment's point closest to it (Ericson, *Real-Time
            // Collision Detection*, 5.1.9): a ray that starts beside an edge and leaves it
            // grazes it too.
            let mut t = (s * de - dw) / dd;
            if !in_range(t) {
                t = t.clamp(ray.tmin as f64, ray.tmax as f64);
                let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                s = if ee > 0.0 {
                    (dot(sub(p, a), e) / ee).clamp(0.0, 1.0)
                } else {
                    0.0
                };
            }
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            let q = [a[0] + s * e[0], a[1] + s * e[1], a[2] + s * e[2]];
            let gap = sub(p, q);
            dot(gap, gap).sqrt() <= tol
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    #[test]
    fn hits_misses_and_ranges() {
        let down = |x, y| Ray::new([x, y, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(hit_t(&TRI, &down(0.25, 0.25)), Some(2.0));
        assert_eq!(hit_t(&TRI, &down(0.75, 0.75)), None);
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -4.0], 0.0, 0.49);
        assert_eq!(hit_t(&TRI, &r), None);
        assert_eq!(closest(&[TRI, TRI], &down(0.25, 0.25)).prim, 0);
        assert!(occluded(&[TRI], &down(0.1, 0.1)));
        assert!(meet(&TRI, &down(0.25, 0.25)).unwrap().margin() > 0.2);
        assert!(meet(&TRI, &down(0.75, 0.75)).unwrap().margin() < 0.0);
    }

    #[test]
    fn an_origin_on_the_triangle_hits_at_zero_from_any_direction() {
        for d in [
            [0.3, 0.2, -1.0],
            [1.0, 0.1, 0.01],
            [-0.7, 0.9, 0.2],
            [0.0, 0.0, 1.0],
        ] {
            let r = Ray::new([0.2, 0.3, 0.0], d, 0.0, f32::INFINITY);
            assert_eq!(hit_t(&TRI, &r), Some(0.0), "{d:?}");
        }
    }

    #[test]
    fn rays_through_edges_and_corners_graze_others_do_not() {
        let through = |p: [f32; 3]| Ray::new([p[0], p[1], 2.0], [0.0, 0.0, -1.0], 0.0, 9.0);
        assert!(grazes(&[TRI], &through([0.0, 0.0, 0.0])), "a corner");
        assert!(grazes(&[TRI], &through([0.5, 0.5, 0.0])), "the hypotenuse");
        assert!(grazes(&[TRI], &through([0.3, 0.0, 0.0])), "an edge");
        assert!(!grazes(&[TRI], &through([0.25, 0.25, 0.0])), "inside");
        assert!(!grazes(&[TRI], &through([0.9, 0.9, 0.0])), "outside");
        // Through a corner, but behind the ray's range.
        let behind = Ray::new([0.0, 0.0, 2.0], [0.0, 0.0, 1.0], 0.0, 9.0);
        assert!(!grazes(&[TRI], &behind));
        // Starting beside an edge (within rounding of it) and leaving it: the line's closest
        // approach is behind the origin, the ray's is the origin.
        let leaving = Ray::new([0.5, -5e-6, 0.0], [0.0, -1.0, 1.0], 0.0, 9.0);
        assert!(grazes(&[TRI], &leaving), "starting on an edge");
        let away = Ray::new([0.5, -1e-3, 0.0], [0.0, -1.0, 1.0], 0.0, 9.0);
        assert!(!grazes(&[TRI], &away), "starting clear of it");
    }

    #[test]
    fn a_hit_beyond_the_f32_range_is_a_miss() {
        let r = Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -1e-40], 0.0, f32::INFINITY);
        assert_eq!(hit_t(&TRI, &r), None);
    }
}
