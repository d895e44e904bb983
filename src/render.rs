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
use crate::logical::{Counters, Order, Scene};
use crate::mapping::morton;
use crate::rays::{Camera, cross, normalize, shadow_ray, sub};

#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub light: [f32; 3],
    /// [`Order::None`]: pixel rows in parallel, top to bottom. [`Order::Morton`]: tiles of
    /// [`TILE`] x [`TILE`] pixels in the Morton order of their positions, so that the rays
    /// traced together look at neighbouring parts of the model and need the same blocks
    /// ([`Order::Blocks`] renders the same way). The image is the same, byte for byte.
    pub order: Order,
}

/// Side of a render tile, pixels.
pub const TILE: u32 = 16;

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
    let sum = |mut a: RenderStats, b: RenderStats| {
        a.primary += b.primary;
        a.shadow += b.shadow;
        a.hits += b.hits;
        a.shadowed += b.shadowed;
        a
    };
    if opts.order != Order::None {
        let (rgb, stats) =
            render_tiles(&tree, opts, sum).map_err(|e| Error::format(scene.path(), e.into()))?;
        return Ok((
            Image {
                width: opts.width,
                height: opts.height,
                rgb,
            },
            RenderStats {
                width: opts.width,
                height: opts.height,
                seconds: start.elapsed().as_secs_f64(),
                ..stats
            },
        ));
    }
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
        .try_reduce(RenderStats::default, |a, b| Ok(sum(a, b)))
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

/// The image (RGB8) and statistics of `opts`, traced tile by tile in Morton order.
fn render_tiles(
    tree: &crate::logical::Tree,
    opts: &RenderOptions,
    sum: impl Fn(RenderStats, RenderStats) -> RenderStats,
) -> Result<(Vec<u8>, RenderStats), TraceError> {
    let (tw, th) = (opts.width.div_ceil(TILE), opts.height.div_ceil(TILE));
    let mut tiles: Vec<(u64, u32, u32)> = (0..th)
        .flat_map(|ty| (0..tw).map(move |tx| (morton::encode([tx, ty, 0]), tx, ty)))
        .collect();
    tiles.sort_unstable();
    let pixels = opts.camera.pixels(opts.width, opts.height);
    // Each tile's pixels, row by row, then copied into the image.
    let done = tiles
        .par_iter()
        .map(|&(_, tx, ty)| {
            let mut s = RenderStats::default();
            let (x0, y0) = (tx * TILE, ty * TILE);
            let (x1, y1) = ((x0 + TILE).min(opts.width), (y0 + TILE).min(opts.height));
            let mut px = Vec::with_capacity(3 * ((x1 - x0) * (y1 - y0)) as usize);
            for y in y0..y1 {
                let bg = background(y as f64 / opts.height as f64);
                for x in x0..x1 {
                    let c = shade(tree, &pixels.ray(x, y), opts.light, &mut s)?.unwrap_or(bg);
                    px.extend(c.map(to_srgb8));
                }
            }
            Ok((tx, ty, px, s))
        })
        .collect::<Result<Vec<_>, TraceError>>()?;
    let width = opts.width as usize;
    let mut rgb = vec![0u8; width * opts.height as usize * 3];
    let mut stats = RenderStats::default();
    for (tx, ty, px, s) in done {
        stats = sum(stats, s);
        let (x0, y0) = ((tx * TILE) as usize, (ty * TILE) as usize);
        let w = ((tx * TILE + TILE).min(opts.width) as usize - x0) * 3;
        for (dy, src) in px.chunks_exact(w).enumerate() {
            let at = ((y0 + dy) * width + x0) * 3;
            rgb[at..at + w].copy_from_slice(src);
        }
    }
    Ok((rgb, stats))
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
