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
