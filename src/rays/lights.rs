//! Lights and short camera moves: the shadow rays of rendered frames, for the shadow-ray
//! traversals of the multi-index tree (Liang and Huang 2019), whose prediction needs frames
//! that follow one another (what a tile's rays did in frame `k` foretells frame `k + 1`).
//!
//! - [`Light`]: a point light, or a quad (parallelogram) area light sampled `n` times per pixel
//!   on a jittered grid;
//! - [`orbit`]: the cameras of a short move around a view (the eye turned about the target,
//!   around the up axis, a few degrees a frame);
//! - [`ShadowFrame`]: the shadow rays of one frame, each with the screen tile and light it
//!   belongs to, which is what prediction keys on.

use glam::DVec3;

use super::{Camera, SplitMix64, shadow_ray};
use crate::geom::{Hit, Ray};

/// A light that shadow rays go to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// A point.
    Point([f32; 3]),
    /// The parallelogram `corner + a u + b v`, `a` and `b` in `[0, 1]`.
    Quad {
        corner: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
    },
}

impl Light {
    /// A square area light of side `side` centred on `centre`, facing down (-y): the area light
    /// made from a point light.
    pub fn square(centre: [f32; 3], side: f32) -> Light {
        let h = 0.5 * side;
        Light::Quad {
            corner: [centre[0] - h, centre[1], centre[2] - h],
            u: [side, 0.0, 0.0],
            v: [0.0, 0.0, side],
        }
    }

    /// The point at `(a, b)` of the light (`[0, 1]^2`; a point light is its point).
    pub fn at(&self, a: f64, b: f64) -> [f32; 3] {
        match *self {
            Light::Point(p) => p,
            Light::Quad { corner, u, v } => std::array::from_fn(|k| {
                (corner[k] as f64 + a * u[k] as f64 + b * v[k] as f64) as f32
            }),
        }
    }

    /// The points a light's shadow rays may end at, for the structures' precomputation: the
    /// point, or the quad's corners and centre.
    pub fn extent(&self) -> Vec<[f32; 3]> {
        match self {
            Light::Point(p) => vec![*p],
            Light::Quad { .. } => [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)]
                .iter()
                .map(|&(a, b)| self.at(a, b))
                .collect(),
        }
    }

    /// Whether it is an area light (sampled more than once per pixel).
    pub fn is_area(&self) -> bool {
        matches!(self, Light::Quad { .. })
    }
}

/// The cameras of `frames` frames orbiting `camera`'s view: frame `i` turns the eye about the
/// target by `i * step_deg` degrees around the camera's up axis (frame 0 is `camera`).
pub fn orbit(camera: &Camera, frames: usize, step_deg: f64) -> Vec<Camera> {
    let target = DVec3::from(camera.target);
    let up = DVec3::from(camera.up);
    let axis = if up.length() > 0.0 {
        up / up.length()
    } else {
        DVec3::Y
    };
    let arm = DVec3::from(camera.eye) - target;
    (0..frames)
        .map(|i| {
            let q = glam::DQuat::from_axis_angle(axis, (i as f64 * step_deg).to_radians());
            Camera {
                eye: (target + q * arm).to_array(),
                ..*camera
            }
        })
        .collect()
}

/// The shadow rays of one frame: from each primary hit, one ray per point light and `samples`
/// per area light, in pixel order; each with its key, `tile * lights + light` (the screen tile
/// of `tile x tile` pixels its pixel lies in, row by row, and the light's index).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShadowFrame {
    pub rays: Vec<Ray>,
    pub keys: Vec<u32>,
    /// Each ray's distance in pixels from the centre of its tile, squared (which ray of a tile
    /// is its sample: the one nearest the centre).
    pub off_centre: Vec<u32>,
    /// Keys in all: tiles times lights.
    pub key_count: u32,
}

impl ShadowFrame {
    /// The shadow rays from the hits `hits` of the primary rays `primary` of a `width` x
    /// `height` image (row by row) towards `lights`, `samples` per area light (jittered on a
    /// grid of `ceil(sqrt(samples))` per side, seeded by `seed`, the pixel and the light).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        primary: &[Ray],
        hits: &[Hit],
        width: u32,
        height: u32,
        lights: &[Light],
        samples: u32,
        tile: u32,
        seed: u64,
    ) -> ShadowFrame {
        let tile = tile.max(1);
        let tiles_x = width.div_ceil(tile);
        let tiles = tiles_x * height.div_ceil(tile);
        let nl = lights.len() as u32;
        let samples = samples.max(1);
        let side = (samples as f64).sqrt().ceil() as u32;
        let mut f = ShadowFrame {
            key_count: tiles * nl,
            ..ShadowFrame::default()
        };
        for (i, (r, h)) in primary.iter().zip(hits).enumerate() {
            if !h.is_hit() || width == 0 {
                continue;
            }
            let (x, y) = (i as u32 % width, i as u32 / width);
            let t = (y / tile) * tiles_x + x / tile;
            let (cx, cy) = ((x % tile) * 2 + 1, (y % tile) * 2 + 1);
            let off = (cx.abs_diff(tile) / 2).pow(2) + (cy.abs_diff(tile) / 2).pow(2);
            for (li, light) in lights.iter().enumerate() {
                let key = t * nl + li as u32;
                if !light.is_area() {
                    f.push(shadow_ray(r, h.t, light.at(0.0, 0.0)), key, off);
                    continue;
                }
                let mut rng = SplitMix64::new(
                    seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (li as u64) << 56,
                );
                for s in 0..samples {
                    let (gx, gy) = (s % side, s / side);
                    let a = (gx as f64 + rng.next_f64()) / side as f64;
                    let b = (gy as f64 + rng.next_f64()) / side as f64;
                    f.push(shadow_ray(r, h.t, light.at(a, b)), key, off);
                }
            }
        }
        f
    }

    fn push(&mut self, ray: Ray, key: u32, off: u32) {
        self.rays.push(ray);
        self.keys.push(key);
        self.off_centre.push(off);
    }

    /// Per key, the index of its sample ray (the first of those nearest the tile's centre),
    /// `u32::MAX` for a key with no ray.
    pub fn samples(&self) -> Vec<u32> {
        let mut best = vec![(u32::MAX, u32::MAX); self.key_count as usize];
        for (i, (&k, &off)) in self.keys.iter().zip(&self.off_centre).enumerate() {
            if let Some(b) = best.get_mut(k as usize)
                && off < b.0
            {
                *b = (off, i as u32);
            }
        }
        best.into_iter().map(|(_, i)| i).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_turns_about_the_target_keeping_the_distance() {
        let cam = Camera::look_at([0.0, 1.0, 5.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 40.0).unwrap();
        let cams = orbit(&cam, 4, 90.0);
        assert_eq!(cams[0], cam);
        let d = |c: &Camera| (DVec3::from(c.eye) - DVec3::from(c.target)).length();
        for c in &cams {
            assert!((d(c) - d(&cam)).abs() < 1e-12);
            assert!((c.eye[1] - 1.0).abs() < 1e-12);
        }
        // A quarter turn about +y takes +z to +x.
        assert!((cams[1].eye[0] - 5.0).abs() < 1e-9 && cams[1].eye[2].abs() < 1e-9);
    }

    #[test]
    fn frames_key_rays_by_tile_and_light_and_pick_the_central_sample() {
        // 4 x 2 pixels, tiles of 2: two tiles across, one down; pixel 5 missed.
        let primary: Vec<Ray> = (0..8)
            .map(|i| Ray::new([i as f32, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY))
            .collect();
        let mut hits = vec![Hit { t: 1.0, prim: 0 }; 8];
        hits[5] = Hit::MISS;
        let lights = [
            Light::Point([0.0, 10.0, 0.0]),
            Light::square([0.0, 10.0, 0.0], 1.0),
        ];
        let f = ShadowFrame::new(&primary, &hits, 4, 2, &lights, 4, 2, 7);
        assert_eq!(f.key_count, 4);
        assert_eq!(f.rays.len(), 7 * 5);
        // Pixel 6 (x 2, y 1): tile 1; its point-light ray has key 2, its area rays key 3.
        let of6: Vec<u32> = (0..f.rays.len())
            .filter(|&i| f.rays[i].origin[0] == 6.0)
            .map(|i| f.keys[i])
            .collect();
        assert_eq!(of6, [2, 3, 3, 3, 3]);
        // Area samples end on the light, spread over it.
        let ends: Vec<[f64; 3]> = (0..5).map(|i| f.rays[i].at(1.0)).collect();
        assert!(ends[1..].iter().all(|e| (e[1] - 10.0).abs() < 1e-5));
        assert!(ends[1..].iter().any(|e| e[0] < 0.0) && ends[1..].iter().any(|e| e[0] > 0.0));
        // Every key has a sample, and it is one of its rays.
        let s = f.samples();
        for (k, &i) in s.iter().enumerate() {
            assert_eq!(f.keys[i as usize], k as u32);
        }
        // Same seed, same rays.
        assert_eq!(f, ShadowFrame::new(&primary, &hits, 4, 2, &lights, 4, 2, 7));
    }
}
