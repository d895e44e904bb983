//! Ray, hit and occlusion files (`../shared/RAYS.md`) and the ray sets we measure with.
//!
//! All three files are a 16-byte header (4-byte magic, `u32` version 1, `u64` count) followed by
//! `count` records; the size must be exactly `16 + count * record_size`. Records are cast from
//! and to [`Ray`] and [`Hit`], whose layout is the record layout.

use std::path::Path;

use bytemuck::Pod;

use crate::error::Error;
use crate::geom::{Hit, Ray};

const VERSION: u32 = 1;
const HEADER: usize = 16;

fn read_records<T: Pod>(path: &Path, magic: &[u8; 4]) -> Result<Vec<T>, Error> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_records(&bytes, magic)
        .map_err(|what| Error::Invalid(format!("{}: {what}", path.display())))
}

/// Parses a batch file held in memory; the error says what is wrong (the caller names the file).
pub fn parse_records<T: Pod>(bytes: &[u8], magic: &[u8; 4]) -> Result<Vec<T>, String> {
    let name = String::from_utf8_lossy(magic);
    if bytes.len() < HEADER {
        return Err(format!(
            "{} bytes: too short for a {name} file header",
            bytes.len()
        ));
    }
    if &bytes[..4] != magic {
        return Err(format!(
            "magic {:?}, expected {name:?}",
            String::from_utf8_lossy(&bytes[..4])
        ));
    }
    let version = u32::from_le_bytes(bytes[4..8].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(format!(
            "{name} version {version}, this oavm reads version {VERSION}"
        ));
    }
    let count = u64::from_le_bytes(bytes[8..16].try_into().unwrap_or_default());
    let size = std::mem::size_of::<T>() as u64;
    let expected = count
        .checked_mul(size)
        .and_then(|n| n.checked_add(HEADER as u64));
    if expected != Some(bytes.len() as u64) {
        return Err(format!(
            "header says {count} records of {size} bytes, but the file has {} bytes (expected {})",
            bytes.len(),
            expected.map_or("more than 2^64".to_string(), |e| e.to_string())
        ));
    }
    // Copy out: the Vec<u8> read from disk has no alignment guarantee for T.
    Ok(bytes[HEADER..]
        .chunks_exact(size as usize)
        .map(bytemuck::pod_read_unaligned)
        .collect())
}

/// The bytes of a batch file holding `records`.
pub fn encode_records<T: Pod>(records: &[T], magic: &[u8; 4]) -> Vec<u8> {
    let body: &[u8] = bytemuck::cast_slice(records);
    let mut out = Vec::with_capacity(HEADER + body.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(records.len() as u64).to_le_bytes());
    out.extend_from_slice(body);
    out
}

fn write_records<T: Pod>(path: &Path, records: &[T], magic: &[u8; 4]) -> Result<(), Error> {
    crate::physical::writer::write_atomic(path, &encode_records(records, magic))
}

pub fn read_rays(path: &Path) -> Result<Vec<Ray>, Error> {
    read_records(path, b"RAYS")
}
pub fn write_rays(path: &Path, rays: &[Ray]) -> Result<(), Error> {
    write_records(path, rays, b"RAYS")
}
pub fn read_hits(path: &Path) -> Result<Vec<Hit>, Error> {
    read_records(path, b"HITS")
}
pub fn write_hits(path: &Path, hits: &[Hit]) -> Result<(), Error> {
    write_records(path, hits, b"HITS")
}
pub fn read_occlusion(path: &Path) -> Result<Vec<u8>, Error> {
    read_records(path, b"OCCL")
}
pub fn write_occlusion(path: &Path, occluded: &[u8]) -> Result<(), Error> {
    write_records(path, occluded, b"OCCL")
}

/// SplitMix64 (Steele, Lea, Flood 2014). Written here rather than taken from `rand` because ray
/// sets must stay bit-identical across dependency upgrades, which `rand`'s `StdRng` does not
/// promise.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> SplitMix64 {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`, 53 bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// An axis-aligned box, world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Bounds {
    pub fn of_points(points: impl IntoIterator<Item = [f32; 3]>) -> Bounds {
        let mut b = Bounds {
            min: [f32::INFINITY; 3],
            max: [f32::NEG_INFINITY; 3],
        };
        for p in points {
            for (k, &c) in p.iter().enumerate() {
                b.min[k] = b.min[k].min(c);
                b.max[k] = b.max[k].max(c);
            }
        }
        b
    }

    pub fn centre(&self) -> [f64; 3] {
        std::array::from_fn(|k| (self.min[k] as f64 + self.max[k] as f64) * 0.5)
    }

    pub fn diagonal(&self) -> f64 {
        (0..3)
            .map(|k| (self.max[k] as f64 - self.min[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    }
}

/// `count` random rays: origins uniform in `bounds` enlarged by 10 % of its diagonal on every
/// side (so some start inside the mesh's box, some outside), directions uniform on the unit
/// sphere, `t` in `[0, inf)`.
pub fn random_rays(bounds: &Bounds, count: usize, seed: u64) -> Vec<Ray> {
    let mut rng = SplitMix64::new(seed);
    let pad = 0.1 * bounds.diagonal();
    (0..count)
        .map(|_| {
            let origin = std::array::from_fn(|k| {
                let lo = bounds.min[k] as f64 - pad;
                let hi = bounds.max[k] as f64 + pad;
                (lo + (hi - lo) * rng.next_f64()) as f32
            });
            // Uniform on the sphere: z uniform in [-1, 1], azimuth uniform.
            let z = 2.0 * rng.next_f64() - 1.0;
            let phi = std::f64::consts::TAU * rng.next_f64();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let dir = [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32];
            Ray::new(origin, dir, 0.0, f32::INFINITY)
        })
        .collect()
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f64; 3],
    pub target: [f64; 3],
    pub up: [f64; 3],
    /// Vertical field of view, degrees.
    pub fov_y: f64,
}

impl Camera {
    /// A camera that frames `bounds`: looking at its centre from the front (+z), a little from
    /// the right and above, at 0.8 of the distance at which the bounding sphere would just fit
    /// the view (meshes rarely fill their bounding sphere).
    pub fn framing(bounds: &Bounds) -> Camera {
        let c = bounds.centre();
        let radius = (0.5 * bounds.diagonal()).max(f64::MIN_POSITIVE);
        let fov_y: f64 = 40.0;
        let dist = radius / (fov_y.to_radians() * 0.5).sin() * 0.8;
        let dir = normalize([0.35, 0.3, 1.0]);
        Camera {
            eye: std::array::from_fn(|k| c[k] + dir[k] * dist),
            target: c,
            up: [0.0, 1.0, 0.0],
            fov_y,
        }
    }

    /// A camera at `from` looking at `at`, `up` giving the image's up direction, with a vertical
    /// field of view of `fov_deg` degrees (an NFF/AFF viewpoint). The error says which of these
    /// cannot make a camera: non-finite values, `from == at`, `up` parallel to the view
    /// direction, or a field of view outside (0, 180).
    pub fn look_at(
        from: [f64; 3],
        at: [f64; 3],
        up: [f64; 3],
        fov_deg: f64,
    ) -> Result<Camera, String> {
        if !from.iter().chain(&at).chain(&up).all(|c| c.is_finite()) {
            return Err("the camera's from, at and up must be finite".into());
        }
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(format!(
                "the field of view is {fov_deg} degrees; it must be between 0 and 180"
            ));
        }
        let f = sub(at, from);
        let fl = dot(f, f).sqrt();
        if !(fl.is_finite() && fl > 0.0) {
            return Err("the camera looks from the point it looks at".into());
        }
        let ul = dot(up, up).sqrt();
        let side = cross(f, up);
        if !(ul.is_finite() && ul > 0.0) || dot(side, side).sqrt() <= 1e-9 * fl * ul {
            return Err("the camera's up vector is zero or parallel to its view direction".into());
        }
        Ok(Camera {
            eye: from,
            target: at,
            up,
            fov_y: fov_deg,
        })
    }

    /// One ray through the centre of each pixel, row by row from the top left; unit directions.
    pub fn primary_rays(&self, width: u32, height: u32) -> Vec<Ray> {
        let mut rays = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            rays.extend(self.row(width, height, y));
        }
        rays
    }

    /// The rays of pixel row `y` of a `width` x `height` image (see [`Self::primary_rays`]).
    pub fn row(&self, width: u32, height: u32, y: u32) -> impl Iterator<Item = Ray> + use<> {
        let view = self.pixels(width, height);
        (0..width).map(move |x| view.ray(x, y))
    }

    /// The rays of a `width` x `height` image, pixel by pixel in any order.
    pub fn pixels(&self, width: u32, height: u32) -> PixelRays {
        PixelRays::new(self, width, height)
    }
}

/// A camera's basis for one image size, from which each pixel's ray is made: bit for bit the
/// ray [`Camera::row`] and [`Camera::primary_rays`] give for that pixel.
#[derive(Clone, Copy, Debug)]
pub struct PixelRays {
    f: [f64; 3],
    r: [f64; 3],
    u: [f64; 3],
    h: f64,
    w: f64,
    eye: [f32; 3],
    width: u32,
    height: u32,
}

impl PixelRays {
    fn new(c: &Camera, width: u32, height: u32) -> PixelRays {
        let f = normalize(sub(c.target, c.eye));
        let r = normalize(cross(f, c.up));
        let u = cross(r, f);
        let h = (c.fov_y.to_radians() * 0.5).tan();
        let w = h * width as f64 / height as f64;
        PixelRays {
            f,
            r,
            u,
            h,
            w,
            eye: c.eye.map(|x| x as f32),
            width,
            height,
        }
    }

    /// The ray through the centre of pixel `(x, y)` (`(0, 0)` is the top left).
    #[inline]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        let sy = (1.0 - (y as f64 + 0.5) / self.height as f64 * 2.0) * self.h;
        let sx = ((x as f64 + 0.5) / self.width as f64 * 2.0 - 1.0) * self.w;
        let (f, r, u) = (self.f, self.r, self.u);
        let d = normalize(std::array::from_fn(|k| f[k] + sx * r[k] + sy * u[k]));
        Ray::new(self.eye, d.map(|x| x as f32), 0.0, f32::INFINITY)
    }
}

/// A default point light for `bounds`: above, right and in front of the centre.
pub fn default_light(bounds: &Bounds) -> [f32; 3] {
    let c = bounds.centre();
    let d = bounds.diagonal().max(f64::MIN_POSITIVE);
    let off = [0.6, 1.2, 0.9];
    std::array::from_fn(|k| (c[k] + off[k] * d) as f32)
}

/// Relative `t` at both ends of a shadow ray, which keeps it off the surface it starts on and
/// the light it ends at.
pub const SHADOW_EPSILON: f32 = 1e-4;

/// The shadow ray from the hit point of `primary` at `t` to `light`: direction `light - p`
/// (unnormalised, so `t` in `[eps, 1 - eps]` spans the segment).
pub fn shadow_ray(primary: &Ray, t: f32, light: [f32; 3]) -> Ray {
    let p = primary.at(t as f64);
    let dir = std::array::from_fn(|k| (light[k] as f64 - p[k]) as f32);
    Ray::new(
        p.map(|x| x as f32),
        dir,
        SHADOW_EPSILON,
        1.0 - SHADOW_EPSILON,
    )
}

/// Shadow rays toward `light` from every primary ray that hit.
pub fn shadow_rays(primary: &[Ray], hits: &[Hit], light: [f32; 3]) -> Vec<Ray> {
    primary
        .iter()
        .zip(hits)
        .filter(|(_, h)| h.is_hit())
        .map(|(r, h)| shadow_ray(r, h.t, light))
        .collect()
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(crate) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if l > 0.0 { a.map(|x| x / l) } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batch_files_round_trip_and_reject_bad_sizes() {
        let rays = vec![Ray::new(
            [1.0, 2.0, 3.0],
            [0.0, 0.0, 1.0],
            0.5,
            f32::INFINITY,
        )];
        let bytes = encode_records(&rays, b"RAYS");
        assert_eq!(bytes.len(), 16 + 32);
        assert_eq!(parse_records::<Ray>(&bytes, b"RAYS").unwrap(), rays);
        assert!(
            parse_records::<Ray>(&bytes[..47], b"RAYS")
                .unwrap_err()
                .contains("header says 1")
        );
        assert!(
            parse_records::<Ray>(&bytes, b"HITS")
                .unwrap_err()
                .contains("magic")
        );
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert!(
            parse_records::<Ray>(&v2, b"RAYS")
                .unwrap_err()
                .contains("version 2")
        );
        let mut huge = bytes.clone();
        huge[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(parse_records::<Ray>(&huge, b"RAYS").is_err());
    }

    #[test]
    fn generators_are_deterministic() {
        let b = Bounds {
            min: [0.0; 3],
            max: [1.0; 3],
        };
        assert_eq!(random_rays(&b, 100, 7), random_rays(&b, 100, 7));
        assert_ne!(random_rays(&b, 100, 7), random_rays(&b, 100, 8));
        let cam = Camera::framing(&b);
        let rays = cam.primary_rays(4, 3);
        assert_eq!(rays.len(), 12);
        // The centre of the image looks at the centre of the box.
        let mid = cam.primary_rays(1, 1)[0];
        let to_c = normalize(sub(b.centre(), cam.eye));
        for (d, c) in mid.dir.iter().zip(to_c) {
            assert!((*d as f64 - c).abs() < 1e-6);
        }
    }
}
