//! A small renderer over the tracer: primary rays (closest hit) shaded by a point light, with
//! shadows (any hit), written as PNG. It is `oavm-trace`'s default job and a visual check that
//! a file is right.

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::error::Error;
use crate::geom::Ray;
use crate::logical::TraceError;
use crate::logical::{Counters, Scene};
use crate::rays::{Camera, cross, normalize, shadow_ray, sub};

#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub light: [f32; 3],
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RenderStats {
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    pub primary: Counters,
    pub shadow: Counters,
    pub hits: u64,
    pub shadowed: u64,
}

/// An RGB8 image, rows top to bottom.
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Renders `scene`: Lambert shading from a point light (two-sided), shadows by one any-hit ray per
/// visible point, a soft ambient term, a vertical gradient for the background.
pub fn render<D: AsRef<[u8]> + crate::physical::pager::BlockSource>(
    scene: &Scene<D>,
    opts: &RenderOptions,
) -> Result<(Image, RenderStats), Error> {
    if opts.width == 0 || opts.height == 0 || opts.width > 16384 || opts.height > 16384 {
        return Err(Error::Invalid(format!(
            "image size {}x{} must be between 1x1 and 16384x16384",
            opts.width, opts.height
        )));
    }
    let start = Instant::now();
    let tree = scene.tree();
    let width = opts.width as usize;
    // Rays are made row by row: the image is the only per-pixel allocation (3 bytes a pixel).
    let mut rgb = vec![0u8; width * opts.height as usize * 3];
    let stats = rgb
        .par_chunks_mut(width * 3)
        .enumerate()
        .try_fold(RenderStats::default, |mut s, (y, row)| {
            for (x, ray) in opts
                .camera
                .row(opts.width, opts.height, y as u32)
                .enumerate()
            {
                let px = shade(&tree, &ray, opts.light, &mut s)?;
                let bg = background(y as f64 / opts.height as f64);
                let c = px.unwrap_or(bg);
                row[3 * x..3 * x + 3].copy_from_slice(&c.map(to_srgb8));
            }
            Ok(s)
        })
        .try_reduce(RenderStats::default, |mut a, b| {
            a.primary += b.primary;
            a.shadow += b.shadow;
            a.hits += b.hits;
            a.shadowed += b.shadowed;
            Ok(a)
        })
        .map_err(|e: TraceError| Error::format(scene.path(), e.into()))?;
    let stats = RenderStats {
        width: opts.width,
        height: opts.height,
        seconds: start.elapsed().as_secs_f64(),
        ..stats
    };
    Ok((
        Image {
            width: opts.width,
            height: opts.height,
            rgb,
        },
        stats,
    ))
}

/// Linear colour of the surface seen by `ray`, or `None` for the background.
fn shade(
    tree: &crate::logical::Tree,
    ray: &Ray,
    light: [f32; 3],
    s: &mut RenderStats,
) -> Result<Option<[f64; 3]>, TraceError> {
    let Some(hit) = tree.intersect(ray, &mut s.primary)? else {
        return Ok(None);
    };
    s.hits += 1;
    let v = hit.v.map(|p| p.map(|c| c as f64));
    let mut n = normalize(cross(sub(v[1], v[0]), sub(v[2], v[0])));
    let d = ray.dir.map(|c| c as f64);
    if n[0] * d[0] + n[1] * d[1] + n[2] * d[2] > 0.0 {
        n = n.map(|c| -c); // two-sided: face the viewer
    }
    let p = ray.at(hit.t as f64);
    let l = normalize(sub(light.map(|c| c as f64), p));
    let lambert = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0);
    let lit = if lambert > 0.0 {
        let shadowed = tree.occluded(&shadow_ray(ray, hit.t, light), &mut s.shadow)?;
        s.shadowed += shadowed as u64;
        if shadowed { 0.0 } else { lambert }
    } else {
        0.0
    };
    let albedo = [0.80, 0.74, 0.66];
    // Ambient term from a hemisphere light, so shadowed parts keep their shape.
    let sky = 0.10 + 0.12 * (0.5 + 0.5 * n[1]);
    Ok(Some(std::array::from_fn(|k| {
        albedo[k] * (0.85 * lit + sky)
    })))
}

fn background(v: f64) -> [f64; 3] {
    let top = [0.32, 0.40, 0.52];
    let bottom = [0.08, 0.09, 0.11];
    std::array::from_fn(|k| top[k] + (bottom[k] - top[k]) * v)
}

fn to_srgb8(c: f64) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Writes `image` as an 8-bit RGB PNG, atomically.
pub fn write_png(path: &Path, image: &Image) -> Result<(), Error> {
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, image.width, image.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let png_err =
        |e: png::EncodingError| Error::Invalid(format!("{}: PNG encoding: {e}", path.display()));
    let mut w = enc.write_header().map_err(png_err)?;
    w.write_image_data(&image.rgb).map_err(png_err)?;
    w.finish().map_err(png_err)?;
    crate::physical::writer::write_atomic(path, &bytes)
}
