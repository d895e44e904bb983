//! Renderers over the tracer, written as PNG:
//!
//! - [`render`], the simple one: primary rays (closest hit) shaded by a point light, with
//!   shadows (any hit). It is `oavm-trace`'s default job and a visual check that a file is
//!   right;
//! - [`render_shaded`], a Whitted-style ray tracer: a scene's materials and lights
//!   ([`Look`], from a BART scene's statements or a default for a plain mesh), shadow rays to
//!   every light, Phong highlights, reflection and refraction rays, recursively.
//!
//! Both trace tile by tile ([`TILE`]) on at most [`Scene::threads`] threads, and both give the
//! same image, byte for byte, whatever the number of threads and the order of the tiles.
//!
//! What they render is a [`Shot`]: the camera, light and image size that a [`ShotSpec`] asks
//! for (a BART scene's viewpoint, or a camera framing the model), as `oavm-trace` chooses them;
//! [`ShadedShot`] sets up a Whitted render of a shot with its scene's materials and lights.
//! What a render did is a [`RenderReport`] or a [`ShadedReport`]. [`animate`] renders the frames
//! of an animation, the file updated to each.

pub mod animate;
mod look;
mod report;
mod shot;
mod whitted;

pub use look::{Look, PLAIN_AMBIENT, PLAIN_BACKGROUND, PointLight};
pub use report::{RenderReport, RenderTotal, ShadedReport};
pub use shot::{DEFAULT_FOV, DEFAULT_SIZE, ShadedShot, Shot, ShotSpec};
pub use whitted::{
    DEFAULT_MAX_DEPTH, DEFAULT_MIN_WEIGHT, DEFAULT_WAVE_LIMIT, MAX_DEPTH_LIMIT, OFFSET,
    ShadedOptions, ShadedStats, render_shaded,
};

use std::time::Instant;

use serde::Serialize;

use crate::error::Error;
use crate::geom::Ray;
use crate::logical::{BlockSource, Counters, HitInfo, Order, Scene, TraceError, Tree, in_order};
use crate::mapping::morton;
use glam::DVec3;

use crate::output::Output;
use crate::rays::{Camera, shadow_ray, unit};

#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub light: [f32; 3],
    /// [`Order::None`]: tiles of [`TILE`] x [`TILE`] pixels row by row, top to bottom.
    /// [`Order::Morton`]: tiles in the Morton order of their positions, so that the rays traced
    /// together look at neighbouring parts of the model and need the same blocks
    /// ([`Order::Blocks`] renders the same way). [`Order::Stream`]: bands of rows, each
    /// band's primary rays and the shadow rays of its lit hits in one stream. The image is
    /// the same, byte for byte.
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
/// visible point, a soft ambient term, a vertical gradient for the background. Traces on at
/// most [`Scene::threads`] threads, tile by tile in the order `opts.order` asks; the image is
/// the same in every order.
pub fn render<D: AsRef<[u8]> + BlockSource>(
    scene: &Scene<D>,
    opts: &RenderOptions,
) -> Result<(Image, RenderStats), Error> {
    check_size(opts.width, opts.height)?;
    if opts.order == Order::Stream
        && let Some((rgb, stats)) = render_streamed(scene, opts)?
    {
        return Ok((
            Image {
                width: opts.width,
                height: opts.height,
                rgb,
            },
            stats,
        ));
    }
    let start = Instant::now();
    let tree = scene.tree();
    let tiles = tiles(opts.width, opts.height, opts.order);
    let pixels = opts.camera.pixels(opts.width, opts.height);
    // Each tile's pixels, row by row, then copied into the image.
    let mut done: Vec<Vec<u8>> = vec![Vec::new(); tiles.len()];
    let traced = in_order(&tiles, &mut done, 1, scene.threads(), |tiles, out, s| {
        for (&(_, tx, ty), px) in tiles.iter().zip(out) {
            let (x0, y0) = (tx * TILE, ty * TILE);
            let (x1, y1) = ((x0 + TILE).min(opts.width), (y0 + TILE).min(opts.height));
            px.reserve_exact(3 * ((x1 - x0) * (y1 - y0)) as usize);
            for y in y0..y1 {
                let bg = background(y as f64 / opts.height as f64);
                for x in x0..x1 {
                    let c = shade(&tree, &pixels.ray(x, y), opts.light, s)?.unwrap_or(bg);
                    px.extend(c.map(to_srgb8));
                }
            }
        }
        Ok(())
    });
    let stats: RenderStats = traced.map_err(|e: TraceError| scene.corrupt(e))?;
    scene.check_unchanged()?;
    Ok((
        assemble(&tiles, &done, opts.width, opts.height),
        RenderStats {
            width: opts.width,
            height: opts.height,
            seconds: start.elapsed().as_secs_f64(),
            ..stats
        },
    ))
}

/// Checks an image size: 1x1 to 16384x16384.
fn check_size(width: u32, height: u32) -> Result<(), Error> {
    if width == 0 || height == 0 || width > 16384 || height > 16384 {
        return Err(Error::Invalid(format!(
            "image size {width}x{height} must be between 1x1 and 16384x16384"
        )));
    }
    Ok(())
}

/// The tiles of a `width` x `height` image, `(Morton code, tile x, tile y)`, row by row
/// ([`Order::None`]) or in Morton order (any other order).
fn tiles(width: u32, height: u32, order: Order) -> Vec<(u64, u32, u32)> {
    let (tw, th) = (width.div_ceil(TILE), height.div_ceil(TILE));
    let mut tiles: Vec<(u64, u32, u32)> = (0..th)
        .flat_map(|ty| (0..tw).map(move |tx| (morton::encode([tx, ty, 0]), tx, ty)))
        .collect();
    if order != Order::None {
        tiles.sort_unstable();
    }
    tiles
}

/// The image from each tile's RGB8 pixels (`done`, row by row, in the order of `tiles`).
fn assemble(tiles: &[(u64, u32, u32)], done: &[Vec<u8>], width: u32, height: u32) -> Image {
    let w_px = width as usize;
    let mut rgb = vec![0u8; w_px * height as usize * 3];
    for (&(_, tx, ty), px) in tiles.iter().zip(done) {
        let (x0, y0) = ((tx * TILE) as usize, (ty * TILE) as usize);
        let w = ((tx * TILE + TILE).min(width) as usize - x0) * 3;
        for (dy, src) in px.chunks_exact(w).enumerate() {
            let at = ((y0 + dy) * w_px + x0) * 3;
            rgb[at..at + w].copy_from_slice(src);
        }
    }
    Image { width, height, rgb }
}

impl std::ops::Add for RenderStats {
    type Output = RenderStats;
    fn add(self, b: RenderStats) -> RenderStats {
        RenderStats {
            primary: self.primary + b.primary,
            shadow: self.shadow + b.shadow,
            hits: self.hits + b.hits,
            shadowed: self.shadowed + b.shadowed,
            ..self
        }
    }
}

/// Linear colour of the surface seen by `ray`, or `None` for the background.
fn shade(
    tree: &Tree,
    ray: &Ray,
    light: [f32; 3],
    s: &mut RenderStats,
) -> Result<Option<[f64; 3]>, TraceError> {
    let Some(hit) = tree.intersect(ray, &mut s.primary)? else {
        return Ok(None);
    };
    s.hits += 1;
    let (n, lambert) = surface(ray, hit.t, &hit.v, light);
    let lit = if lambert > 0.0 {
        let shadowed = tree.occluded(&shadow_ray(ray, hit.t, light), &mut s.shadow)?;
        s.shadowed += shadowed as u64;
        if shadowed { 0.0 } else { lambert }
    } else {
        0.0
    };
    Ok(Some(colour(n, lit)))
}

/// The surface `ray` hits at `t` on the triangle `v`: its normal, turned to face the viewer
/// (two-sided), and its Lambert term toward `light` (0: facing away, no shadow ray cast).
fn surface(ray: &Ray, t: f32, v: &[[f32; 3]; 3], light: [f32; 3]) -> (DVec3, f64) {
    let v = v.map(|p| DVec3::from(p.map(f64::from)));
    let mut n = unit((v[1] - v[0]).cross(v[2] - v[0]));
    if n.dot(DVec3::from(ray.dir.map(f64::from))) > 0.0 {
        n = -n; // two-sided: face the viewer
    }
    let p = DVec3::from(ray.at(t as f64));
    let l = unit(DVec3::from(light.map(f64::from)) - p);
    (n, n.dot(l).max(0.0))
}

/// Whether a hit casts its shadow ray: its surface faces the light.
fn casts(ray: &Ray, hit: &HitInfo, light: [f32; 3]) -> bool {
    surface(ray, hit.t, &hit.v, light).1 > 0.0
}

/// The linear colour of a surface with normal `n` lit by `lit` (the Lambert term, 0 in
/// shadow).
fn colour(n: DVec3, lit: f64) -> [f64; 3] {
    let albedo = [0.80, 0.74, 0.66];
    // Ambient term from a hemisphere light, so shadowed parts keep their shape.
    let sky = 0.10 + 0.12 * (0.5 + 0.5 * n.y);
    std::array::from_fn(|k| albedo[k] * (0.85 * lit + sky))
}

/// Pixels a streamed render traces at once (bands of whole rows): the rays, their hits and
/// shadow answers of a band take about 100 bytes a pixel.
const BAND_PIXELS: usize = 1 << 22;

/// [`render`] with [`Order::Stream`]: bands of rows, each band's primary rays and the
/// shadow rays of its lit hits in one stream ([`Scene::trace_frame`]'s), then shaded as
/// [`shade`] does. `None` for a file that is not streamed (leaf lists).
fn render_streamed<D: AsRef<[u8]> + BlockSource>(
    scene: &Scene<D>,
    opts: &RenderOptions,
) -> Result<Option<(Vec<u8>, RenderStats)>, Error> {
    let start = Instant::now();
    let (w, h) = (opts.width as usize, opts.height as usize);
    let pixels = opts.camera.pixels(opts.width, opts.height);
    let rows = (BAND_PIXELS / w).max(1);
    let mut rgb = vec![0u8; w * h * 3];
    let mut stats = RenderStats::default();
    for y0 in (0..h).step_by(rows) {
        let y1 = (y0 + rows).min(h);
        let rays: Vec<Ray> = (y0..y1)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| pixels.ray(x as u32, y as u32))
            .collect();
        let mut hits: Vec<Option<(f32, [[f32; 3]; 3])>> = vec![None; rays.len()];
        let mut occluded = vec![0u8; rays.len()];
        let map = |_: &Ray, h: Option<HitInfo>| h.map(|h| (h.t, h.v));
        let Some(([primary, shadow], _)) =
            scene.stream_shaded(&rays, opts.light, casts, map, &mut hits, &mut occluded)?
        else {
            return Ok(None);
        };
        stats.primary += primary;
        stats.shadow += shadow;
        for (i, ((ray, hit), &occ)) in rays.iter().zip(&hits).zip(&occluded).enumerate() {
            let y = y0 + i / w;
            let c = match hit {
                None => background(y as f64 / h as f64),
                Some((t, v)) => {
                    stats.hits += 1;
                    stats.shadowed += occ as u64;
                    let (n, lambert) = surface(ray, *t, v, opts.light);
                    colour(n, if occ == 1 { 0.0 } else { lambert })
                }
            };
            let at = (y0 * w + i) * 3;
            rgb[at..at + 3].copy_from_slice(&c.map(to_srgb8));
        }
    }
    stats.width = opts.width;
    stats.height = opts.height;
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(Some((rgb, stats)))
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

/// Writes `image` as an 8-bit RGB PNG into `out` (created before the render) and commits it.
pub fn write_png(mut out: Output, image: &Image) -> Result<(), Error> {
    let path = out.path().to_owned();
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, image.width, image.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let png_err =
        |e: png::EncodingError| Error::Invalid(format!("{}: PNG encoding: {e}", path.display()));
    let mut w = enc.write_header().map_err(png_err)?;
    w.write_image_data(&image.rgb).map_err(png_err)?;
    w.finish().map_err(png_err)?;
    use std::io::Write;
    out.file()
        .write_all(&bytes)
        .map_err(|e| Error::io(&path, e))?;
    out.commit()
}
