//! Rays: the batch files of `../shared/RAYS.md` ([`file`]), and the ray sets we measure and
//! render with: random rays ([`random_rays`], seeded by [`SplitMix64`]), a camera's primary rays
//! ([`Camera`]) and shadow rays toward a light ([`shadow_rays`]).

mod camera;
mod file;
mod lights;
mod rng;
mod sets;

pub(crate) use camera::unit;
pub use camera::{Bounds, Camera, PixelRays};
pub use file::{
    HIT_LISTS_MAGIC, Record, encode_hit_lists, encode_records, parse_hit_lists, parse_records,
    read, read_hit_lists, read_hits, read_occlusion, read_rays, write, write_hit_lists, write_hits,
    write_into, write_occlusion, write_rays,
};
pub use lights::{Light, ShadowFrame, orbit};
pub use rng::SplitMix64;
pub use sets::{SHADOW_EPSILON, default_light, random_rays, shadow_ray, shadow_rays};

#[cfg(test)]
mod tests {
    use super::*;

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
        let to_c = unit(glam::DVec3::from(b.centre()) - glam::DVec3::from(cam.eye));
        for (d, c) in mid.dir.iter().zip(to_c.to_array()) {
            assert!((*d as f64 - c).abs() < 1e-6);
        }
    }
}
