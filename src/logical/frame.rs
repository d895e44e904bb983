//! A frame as a renderer traces it: primary rays (closest hit), then a shadow ray from every
//! hit toward a light (any hit), in *waves*: each wave's shadow rays right after its primary
//! rays, while the blocks they start in are still in memory. The primary rays of a benchmark
//! frame are a [`RaySet`]: random rays around the model or a camera's; a frame's figures are
//! [`Frame::figures`].

use std::time::Instant;

use serde::Serialize;

use super::order::Order;
use super::pager::BlockSource;
use super::scene::{BYTES_PER_RAY, Scene, max_rays_in_memory};
use super::trace::Counters;
use crate::error::Error;
use crate::geom::{Hit, Ray};
use crate::rays::{Bounds, Camera, random_rays, shadow_ray};

/// The primary rays of a benchmark frame (`oavm-trace --random N` or `--primary WxH`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RaySet {
    /// `count` rays from `seed`, their origins around the model and their directions uniform
    /// ([`random_rays`]: the sets of `cargo run --features tools --example rays`).
    Random { count: u64, seed: u64 },
    /// A camera's `width` x `height` primary rays ([`Camera::primary_rays`]).
    Primary { width: u32, height: u32 },
}

impl RaySet {
    /// The number of rays.
    pub fn count(&self) -> u64 {
        match *self {
            RaySet::Random { count, .. } => count,
            RaySet::Primary { width, height } => width as u64 * height as u64,
        }
    }

    /// The set's name in reports: `random` or `primary`.
    pub fn name(&self) -> &'static str {
        match self {
            RaySet::Random { .. } => "random",
            RaySet::Primary { .. } => "primary",
        }
    }

    /// The rays, around a model within `bounds` or from `camera`. An error, before any is made,
    /// if there are more than half of the memory available holds ([`max_rays_in_memory`]).
    pub fn rays(&self, bounds: &Bounds, camera: &Camera) -> Result<Vec<Ray>, Error> {
        let (count, max) = (self.count(), max_rays_in_memory());
        if count > max {
            return Err(Error::Invalid(format!(
                "{count} rays: at most {max} fit in half of the available memory \
                 ({BYTES_PER_RAY} bytes a ray); trace them in several runs"
            )));
        }
        Ok(match *self {
            RaySet::Random { count, seed } => random_rays(bounds, count as usize, seed),
            RaySet::Primary { width, height } => camera.primary_rays(width, height),
        })
    }
}

/// How [`Scene::trace_frame`] traces a frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameOptions {
    /// The point light of the shadow rays; `None`: primary rays only.
    pub light: Option<[f32; 3]>,
    /// Rays per wave, taken in the tracing order (0: all primary rays, then all shadow rays).
    pub wave: usize,
    /// The order of tracing (the answers are the same in every order).
    pub order: Order,
}

/// Work and time of one set of rays.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct SetStats {
    pub counters: Counters,
    pub seconds: f64,
}

/// The answers of a frame.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// Closest hit of each primary ray.
    pub hits: Vec<Hit>,
    /// The any-hit answer of each shadow ray (1: occluded), in the order of
    /// [`crate::rays::shadow_rays`]: the primary rays' order, those with a hit.
    pub occluded: Vec<u8>,
    pub primary: SetStats,
    pub shadow: SetStats,
}

impl<D: AsRef<[u8]> + BlockSource> Scene<D> {
    /// Traces `rays` and, with a light, their shadow rays, in waves (see the module docs).
    /// The answers are those of [`Self::intersect_batch`] and of
    /// [`Self::occluded_batch`] on [`crate::rays::shadow_rays`], whatever the wave and order.
    pub fn trace_frame(&self, rays: &[Ray], opts: &FrameOptions) -> Result<Frame, Error> {
        let mut frame = Frame {
            hits: vec![Hit::MISS; rays.len()],
            ..Frame::default()
        };
        let Some(light) = opts.light else {
            let t = Instant::now();
            frame.primary.counters =
                self.intersect_batch_ordered(rays, &mut frame.hits, opts.order)?;
            frame.primary.seconds = t.elapsed().as_secs_f64();
            return Ok(frame);
        };
        // A stream is not cut into waves: it orders the blocks itself, and the more rays it
        // holds, the more share each block read.
        let wave = match opts.wave {
            _ if opts.order == Order::Stream => rays.len().max(1),
            0 => rays.len().max(1),
            n => n,
        };
        // Per primary ray: its shadow ray's answer (for those with a hit).
        let mut occ_of = vec![0u8; rays.len()];
        // (Chunk by chunk, the primary rays are traced, then the shadow rays, each set in
        // Morton order: `logical::chunked`.)
        if opts.order == Order::Stream && !self.chunked() {
            // One stream for both sets: a shadow walk begins where its primary walk ends, in
            // the block held. The time is split between the sets in proportion to the time
            // the workers spent walking each.
            let t = Instant::now();
            if let Some(([primary, shadow], share)) =
                self.stream_frame(rays, light, &mut frame.hits, &mut occ_of)?
            {
                let seconds = t.elapsed().as_secs_f64();
                frame.primary = SetStats {
                    counters: primary,
                    seconds: seconds * (1.0 - share),
                };
                frame.shadow = SetStats {
                    counters: shadow,
                    seconds: seconds * share,
                };
                frame.occluded = shadow_answers(&frame.hits, &occ_of);
                return Ok(frame);
            }
        }
        if wave >= rays.len() {
            let t = Instant::now();
            frame.primary.counters =
                self.intersect_batch_ordered(rays, &mut frame.hits, opts.order)?;
            frame.primary.seconds = t.elapsed().as_secs_f64();
            let idx: Vec<u32> = (0..rays.len() as u32).collect();
            self.shadow_wave(rays, &frame.hits, &idx, light, opts.order, &mut occ_of)
                .map(|s| frame.shadow = s)?;
        } else {
            // Waves of consecutive rays in the tracing order: each a region of space (and of
            // the image), whose shadow rays start in the blocks its primary rays just read. A
            // wave is a run of that order already, so it is traced as given (not sorted again).
            let t = Instant::now();
            let perm: Vec<u32> = self
                .permutation(rays, opts.order)?
                .unwrap_or_else(|| (0..rays.len() as u32).collect());
            let wave_order = match opts.order {
                Order::None => Order::None,
                _ => Order::Given,
            };
            frame.primary.seconds += t.elapsed().as_secs_f64();
            for idx in perm.chunks(wave) {
                let t = Instant::now();
                let wr: Vec<Ray> = idx.iter().map(|&i| rays[i as usize]).collect();
                let mut wh = vec![Hit::MISS; wr.len()];
                frame.primary.counters += self.intersect_batch_ordered(&wr, &mut wh, wave_order)?;
                for (&i, h) in idx.iter().zip(&wh) {
                    frame.hits[i as usize] = *h;
                }
                frame.primary.seconds += t.elapsed().as_secs_f64();
                let s = self.shadow_wave(&wr, &wh, idx, light, opts.order, &mut occ_of)?;
                frame.shadow.counters += s.counters;
                frame.shadow.seconds += s.seconds;
            }
        }
        frame.occluded = shadow_answers(&frame.hits, &occ_of);
        Ok(frame)
    }

    /// Traces the shadow rays of those of `rays` that `hits` says hit (`idx`: each ray's index
    /// in the frame), writing each answer at its primary ray's index in `occ_of`.
    fn shadow_wave(
        &self,
        rays: &[Ray],
        hits: &[Hit],
        idx: &[u32],
        light: [f32; 3],
        order: Order,
        occ_of: &mut [u8],
    ) -> Result<SetStats, Error> {
        let t = Instant::now();
        let (shadow, owners): (Vec<Ray>, Vec<u32>) = rays
            .iter()
            .zip(hits)
            .zip(idx)
            .filter(|((_, h), _)| h.is_hit())
            .map(|((r, h), &i)| (shadow_ray(r, h.t, light), i))
            .unzip();
        let mut occ = vec![0u8; shadow.len()];
        let counters = self.occluded_batch_ordered(&shadow, &mut occ, order)?;
        for (&i, o) in owners.iter().zip(&occ) {
            occ_of[i as usize] = *o;
        }
        Ok(SetStats {
            counters,
            seconds: t.elapsed().as_secs_f64(),
        })
    }
}

/// The shadow answers in the order of [`crate::rays::shadow_rays`] (the primary rays with a
/// hit), from the answers by primary ray.
fn shadow_answers(hits: &[Hit], occ_of: &[u8]) -> Vec<u8> {
    hits.iter()
        .zip(occ_of)
        .filter(|(h, _)| h.is_hit())
        .map(|(_, &o)| o)
        .collect()
}
