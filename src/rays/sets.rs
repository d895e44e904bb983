//! The ray sets we measure with: random rays around a model, and shadow rays toward a light.

use super::{Bounds, SplitMix64};
use crate::geom::{Hit, Ray};

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
