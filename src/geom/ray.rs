//! Rays and hits as the batch files of `../shared/RAYS.md` store them.
//!
//! [`Ray`] and [`Hit`] are `#[repr(C)]` `Pod` records whose layout *is* the record layout of the
//! `RAYS` and `HITS` files (32 and 8 bytes, little-endian), so a batch file is read and written by
//! casting, with no per-ray conversion.

use bytemuck::{Pod, Zeroable};

/// One ray: `origin + t * dir` for `t` in `[tmin, tmax]` (32 bytes, the `RAYS` record).
///
/// The direction is used as stored, never renormalised, so `t` is in units of `dir`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Ray {
    pub origin: [f32; 3],
    pub tmin: f32,
    pub dir: [f32; 3],
    pub tmax: f32,
}
const _: () = assert!(std::mem::size_of::<Ray>() == 32);

impl Ray {
    pub fn new(origin: [f32; 3], dir: [f32; 3], tmin: f32, tmax: f32) -> Ray {
        Ray {
            origin,
            tmin,
            dir,
            tmax,
        }
    }

    /// A ray that can hit something: finite origin and direction, a non-zero direction and
    /// `tmin <= tmax` (with no NaN). Any other ray is answered as a miss (`RAYS.md`).
    pub fn is_valid(&self) -> bool {
        self.origin.iter().all(|c| c.is_finite())
            && self.dir.iter().all(|c| c.is_finite())
            && self.dir.iter().any(|&c| c != 0.0)
            && self.tmin <= self.tmax
    }

    /// The point at parameter `t`, in f64 (exact for the f32 inputs up to one rounding).
    pub fn at(&self, t: f64) -> [f64; 3] {
        std::array::from_fn(|i| self.origin[i] as f64 + t * self.dir[i] as f64)
    }
}

/// The answer to a closest-hit query (8 bytes, the `HITS` record).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Hit {
    /// `t` of the closest hit; `+inf` for a miss.
    pub t: f32,
    /// Primitive id of the triangle hit (its index in the input mesh); `u32::MAX` for a miss.
    pub prim: u32,
}
const _: () = assert!(std::mem::size_of::<Hit>() == 8);

impl Hit {
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        prim: u32::MAX,
    };

    pub fn is_hit(&self) -> bool {
        self.prim != u32::MAX
    }

    /// The agreement rule of `RAYS.md`, the one every comparison uses: both miss, or both hit
    /// with `|t1 - t2| <= AGREEMENT_TOLERANCE * diagonal`, where `diagonal` is that of the
    /// mesh's bounding box. (Either primitive id is right where two triangles are hit at the
    /// same `t`, so ids are not compared.)
    pub fn agrees(&self, other: &Hit, diagonal: f64) -> bool {
        self.is_hit() == other.is_hit()
            && (!self.is_hit()
                || (self.t as f64 - other.t as f64).abs() <= AGREEMENT_TOLERANCE * diagonal)
    }
}

/// `RAYS.md`: two hits agree when their `t` differ by at most this fraction of the diagonal of
/// the mesh's bounding box.
pub const AGREEMENT_TOLERANCE: f64 = 1e-4;

/// A closest hit with its surface attributes: what a renderer or a measurement needs beyond
/// `t` and the primitive id (28 bytes; not a file record).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct HitAttributes {
    /// `t` of the closest hit; `+inf` for a miss (as [`Hit::t`]).
    pub t: f32,
    /// Primitive id of the triangle hit; `u32::MAX` for a miss (as [`Hit::prim`]).
    pub prim: u32,
    /// Barycentric coordinates of the hit point in the triangle `(v0, v1, v2)` as the mesh gives
    /// its corners: the point is `(1 - u - v) v0 + u v1 + v v2` (Embree's convention), with
    /// `u, v >= 0` and `u + v <= 1`. NaN for a miss.
    pub u: f32,
    pub v: f32,
    /// The unit geometric normal `(v1 - v0) x (v2 - v0) / |...|`: it follows the winding of the
    /// corners (counter-clockwise seen from the side it points to), whichever side the ray came
    /// from. NaN for a miss.
    pub normal: [f32; 3],
}
const _: () = assert!(std::mem::size_of::<HitAttributes>() == 28);

impl HitAttributes {
    pub const MISS: HitAttributes = HitAttributes {
        t: f32::INFINITY,
        prim: u32::MAX,
        u: f32::NAN,
        v: f32::NAN,
        normal: [f32::NAN; 3],
    };

    /// The attributes of `ray` hitting the triangle with corners `tri` (id `prim`) at `t`. The
    /// barycentrics are solved in f64 from the ray itself (Moller-Trumbore), not from the point
    /// at the rounded `t`, and clamped into the triangle: the watertight test accepts hits on
    /// an edge that a non-watertight solve puts a rounding outside it.
    pub fn new(ray: &Ray, t: f32, prim: u32, tri: &[[f32; 3]; 3]) -> HitAttributes {
        let p = |i: usize| tri[i].map(|c| c as f64);
        let (v0, v1, v2) = (p(0), p(1), p(2));
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let (e1, e2) = (sub(v1, v0), sub(v2, v0));
        let d = ray.dir.map(|c| c as f64);
        let o = ray.origin.map(|c| c as f64);
        let pv = cross(d, e2);
        let det = dot(e1, pv);
        let (mut u, mut v) = if det != 0.0 && det.is_finite() {
            let tv = sub(o, v0);
            let qv = cross(tv, e1);
            (dot(tv, pv) / det, dot(d, qv) / det)
        } else {
            // A ray in the triangle's plane (the watertight test hit its edge): the
            // barycentrics of the point at `t`, projected onto the plane.
            let w = sub(ray.at(t as f64), v0);
            let (d00, d01, d11) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
            let (d20, d21) = (dot(w, e1), dot(w, e2));
            let den = d00 * d11 - d01 * d01;
            ((d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den)
        };
        if !(u.is_finite() && v.is_finite()) {
            (u, v) = (0.0, 0.0);
        }
        u = u.clamp(0.0, 1.0);
        v = v.clamp(0.0, 1.0);
        if u + v > 1.0 {
            let s = u + v;
            (u, v) = (u / s, v / s);
        }
        let n = cross(e1, e2);
        let len = dot(n, n).sqrt();
        HitAttributes {
            t,
            prim,
            u: u as f32,
            v: v as f32,
            normal: n.map(|c| (c / len) as f32),
        }
    }

    /// The closest-hit record (`t` and the primitive id).
    pub fn hit(&self) -> Hit {
        Hit {
            t: self.t,
            prim: self.prim,
        }
    }
}

/// One hit of a ray, in a list of every hit ([`AllHits`]); 16 bytes, the record of the
/// all-hits file (`RAYS.md` style, magic `HITL`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ListedHit {
    /// Where along the ray, in units of its direction.
    pub t: f32,
    /// The triangle's primitive id.
    pub prim: u32,
    /// Barycentric coordinates of the point, `(1 - u - v) v0 + u v1 + v v2`
    /// ([`HitAttributes`]' convention).
    pub u: f32,
    pub v: f32,
}

/// Every hit of each ray of a batch: ray `i`'s are `hits[splits[i]..splits[i + 1]]`, ordered
/// by `t`, then primitive id (Open3D's `ray_splits`, with `splits[0] = 0`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AllHits {
    pub splits: Vec<u64>,
    pub hits: Vec<ListedHit>,
}

impl AllHits {
    /// The hits of ray `i`.
    pub fn of(&self, i: usize) -> &[ListedHit] {
        &self.hits[self.splits[i] as usize..self.splits[i + 1] as usize]
    }

    /// How many rays.
    pub fn rays(&self) -> usize {
        self.splits.len().saturating_sub(1)
    }

    /// How many hits each ray has.
    pub fn counts(&self) -> Vec<u32> {
        self.splits
            .windows(2)
            .map(|w| (w[1] - w[0]) as u32)
            .collect()
    }
}
