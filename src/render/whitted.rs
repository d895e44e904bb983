//! A Whitted-style ray tracer over the tracer, with the materials and lights of a [`Look`]:
//! [`render_shaded`], whose documentation gives the shading model.

use std::time::Instant;

use glam::DVec3;
use serde::Serialize;

use super::look::Look;
use super::{Image, TILE, assemble, check_size, tiles};
use crate::error::Error;
use crate::geom::Ray;
use crate::logical::{BlockSource, Counters, HitInfo, Order, Scene, TraceError, Tree, in_order};
use crate::mesh::aff::AffMaterial;
use crate::rays::{Camera, SHADOW_EPSILON, unit};

/// Bounces by default: 5 levels of reflection and refraction, the depth quoted from BART's
/// guidelines for rendering its scenes.
pub const DEFAULT_MAX_DEPTH: u32 = 5;
/// The most bounces [`ShadedOptions::max_depth`] may ask (each bounce can double the rays of a
/// pixel).
pub const MAX_DEPTH_LIMIT: u32 = 16;
/// The weight under which a ray is not cast: a quarter of an 8-bit step of a fully lit pixel.
pub const DEFAULT_MIN_WEIGHT: f64 = 1.0 / 1024.0;
/// How far a ray leaving a surface starts from it, relative to the scene's scale (see
/// [`render_shaded`]).
pub const OFFSET: f64 = 1e-5;
/// The most points and light terms a tile's waves keep by default
/// ([`ShadedOptions::wave_limit`]): 2^18, about 25 MB a thread.
pub const DEFAULT_WAVE_LIMIT: usize = 1 << 18;

/// What [`render_shaded`] renders and how.
#[derive(Clone, Copy, Debug)]
pub struct ShadedOptions {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    /// Bounces of reflection and refraction after the primary ray (0: none), at most
    /// [`MAX_DEPTH_LIMIT`]; [`DEFAULT_MAX_DEPTH`] by default.
    pub max_depth: u32,
    /// Rays whose weight in the pixel would be below this are not cast
    /// ([`DEFAULT_MIN_WEIGHT`] by default).
    pub min_weight: f64,
    /// Shadow rays (off: every light reaches every surface that faces it).
    pub shadows: bool,
    /// [`Order::None`]: tiles row by row; any other: tiles in the Morton order of their
    /// positions (neighbouring tiles together, which need the same blocks). The image is the
    /// same.
    pub order: Order,
    /// Each tile's rays are traced in waves through the batch calls: its primary rays, then
    /// their shadow rays, then the reflected and refracted rays of the points they hit, and
    /// so on. A wave's tile keeps its tree of rays (a point per closest-hit ray, a term per
    /// light) until the tile is done: a tile that would keep more than this many is traced ray
    /// by ray, depth first, instead, whose memory is only its depth ([`DEFAULT_WAVE_LIMIT`];
    /// 0: every tile ray by ray). The image and the counts are the same either way.
    pub wave_limit: usize,
}

impl ShadedOptions {
    /// A `width` x `height` image from `camera`, with the defaults.
    pub fn new(width: u32, height: u32, camera: Camera) -> ShadedOptions {
        ShadedOptions {
            width,
            height,
            camera,
            max_depth: DEFAULT_MAX_DEPTH,
            min_weight: DEFAULT_MIN_WEIGHT,
            shadows: true,
            order: Order::Morton,
            wave_limit: DEFAULT_WAVE_LIMIT,
        }
    }
}

/// What a shaded render did. Every figure is a sum over pixels, the same for any number of
/// threads.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ShadedStats {
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    /// Rays of every kind.
    pub rays: u64,
    pub mrays_per_s: f64,
    /// The camera's rays (one a pixel), closest hit.
    pub primary: Counters,
    /// Shadow rays, any hit.
    pub shadow: Counters,
    /// Reflected rays (mirror reflections and total internal reflections), closest hit.
    pub reflection: Counters,
    /// Refracted rays, closest hit.
    pub refraction: Counters,
    /// Primary rays that hit.
    pub hits: u64,
    /// Closest hits of every kind: the points shaded. With shadows on,
    /// `shadow.rays + facing_away = surface_hits × lights`.
    pub surface_hits: u64,
    /// Shadow rays that found an occluder.
    pub shadowed: u64,
    /// Pairs of a point shaded and a light behind its surface (no shadow ray cast).
    pub facing_away: u64,
    /// Refractions past the critical angle, traced as reflections.
    pub total_internal_reflections: u64,
    /// Reflection or refraction rays not cast for [`ShadedOptions::max_depth`].
    pub depth_limited: u64,
    /// Reflection or refraction rays not cast for [`ShadedOptions::min_weight`].
    pub weight_limited: u64,
    /// Tiles traced ray by ray, their waves past [`ShadedOptions::wave_limit`].
    pub ray_by_ray_tiles: u64,
}

impl std::ops::Add for ShadedStats {
    type Output = ShadedStats;
    fn add(self, b: ShadedStats) -> ShadedStats {
        ShadedStats {
            primary: self.primary + b.primary,
            shadow: self.shadow + b.shadow,
            reflection: self.reflection + b.reflection,
            refraction: self.refraction + b.refraction,
            hits: self.hits + b.hits,
            surface_hits: self.surface_hits + b.surface_hits,
            shadowed: self.shadowed + b.shadowed,
            facing_away: self.facing_away + b.facing_away,
            total_internal_reflections: self.total_internal_reflections
                + b.total_internal_reflections,
            depth_limited: self.depth_limited + b.depth_limited,
            weight_limited: self.weight_limited + b.weight_limited,
            ray_by_ray_tiles: self.ray_by_ray_tiles + b.ray_by_ray_tiles,
            ..self
        }
    }
}

/// Renders `scene` with the materials and lights of `look` in Whitted's way (Whitted, "An
/// Improved Illumination Model for Shaded Display", CACM 1980). Traces on at most
/// [`Scene::threads`] threads, tile by tile; the image is the same, byte for byte, for any
/// number of threads and any order.
///
/// # Shading
///
/// At the closest hit of a ray, with the material `m` of the primitive hit (see
/// [`crate::mesh::aff`] for what `f` and `fm` give):
///
/// ```text
/// colour = ambient ⊙ m.ambient
///        + Σ over lights L not shadowed:  L.colour ⊙ (m.diffuse (n·l) + m.specular (r·v)^m.shine)
///        + m.specular ⊙ colour(reflected ray)
///        + m.transmittance × colour(refracted ray)
/// ```
///
/// - `n` is the triangle's geometric normal turned toward the ray (two-sided surfaces), `l` the
///   unit direction to the light, `v` to the viewer, `r` the mirror of `l` about `n`. A light
///   behind the surface (`n·l <= 0`) adds nothing and casts no shadow ray
///   ([`ShadedStats::facing_away`]). The Phong term is added only for `shine > 0` and `r·v > 0`.
///   Lights do not fall off with distance (NFF's point lights).
/// - Shadows: one any-hit ray per light ([`Tree::occluded`]), from the hit point lifted off the
///   surface toward the light (see below) to the light, `t` in `[0, 1 - SHADOW_EPSILON]` of the
///   unnormalised segment. Every surface blocks light, transmissive ones too (an any-hit query
///   cannot tell which surface it met).
/// - Reflection: when the specular colour is not black, a ray in the mirror direction `d - 2
///   (d·n) n`, weighted by the specular colour.
/// - Refraction: when `transmittance > 0`, a ray bent by Snell's law. The ray enters the object
///   when it meets the side the geometric normal points to (the winding's front: meshes wound
///   counter-clockwise seen from outside, as NFF asks and as the spheres and cones of the AFF
///   reader are), going from index 1 to `ior`, and leaves it otherwise (`ior` to 1). Past the
///   critical angle the ray is reflected instead (total internal reflection,
///   [`ShadedStats::total_internal_reflections`]), with the same weight.
/// - Recursion stops at [`ShadedOptions::max_depth`] bounces ([`DEFAULT_MAX_DEPTH`]: 5, the
///   depth quoted from BART's guidelines for rendering its scenes) or when the weight a ray's
///   colour would have in the pixel (the product of the specular colours' largest channels and
///   transmittances along its path) is below [`ShadedOptions::min_weight`].
///
/// Materials are read defensively: colours and lights below zero (or NaN, or infinite) count
/// as 0; the specular colour and the transmittance are clamped to `[0, 1]` (so that a ray's
/// weight never grows); a `shine` that is negative or not finite is 0; an `ior` that is not a
/// positive finite number is 1 (BART's opaque materials write `ior` 0). A light at a position
/// that is not finite is left out.
///
/// # Offsets
///
/// A ray leaving a surface starts at the hit point moved [`OFFSET`] times the scene's scale
/// (the larger of its bounding box's diagonal and its largest coordinate, so that the offset
/// is far above the `f32` rounding of a point anywhere in it) along the normal, to the side the
/// ray leaves to (toward the viewer for reflections and shadow rays, away for refractions), with
/// `tmin` 0: it cannot meet its own triangle again whatever its angle to it, where an offset
/// along the ray (a `tmin`) shrinks toward nothing for a grazing ray.
///
/// # Output
///
/// A pixel's colour is written as it comes out, clamped to `[0, 1]` and scaled to 8 bits, with no
/// transfer curve (no sRGB or gamma encoding): NFF's and BART's colours are display values, set
/// by their authors for renderers that wrote the shaded value to the frame buffer. (Encoded as
/// sRGB, the BART scenes come out washed out: the kitchen's ambient term alone, `am 2.5` times
/// its materials' ambient colours of about 0.2, is 0.5, which sRGB shows at 73 %.) Unlike
/// [`super::render`], whose colours are linear and sRGB-encoded.
pub fn render_shaded<D: AsRef<[u8]> + BlockSource>(
    scene: &Scene<D>,
    opts: &ShadedOptions,
    look: &Look,
) -> Result<(Image, ShadedStats), Error> {
    check_size(opts.width, opts.height)?;
    if opts.max_depth > MAX_DEPTH_LIMIT {
        return Err(Error::Invalid(format!(
            "a depth of {} bounces: at most {MAX_DEPTH_LIMIT}",
            opts.max_depth
        )));
    }
    if !(opts.min_weight >= 0.0 && opts.min_weight.is_finite()) {
        return Err(Error::Invalid(format!(
            "a minimum ray weight of {}: it must be a finite number, 0 or more",
            opts.min_weight
        )));
    }
    let start = Instant::now();
    let tree = scene.tree();
    let h = scene.file().header();
    let shader = Shader::new(&tree, look, opts, scale(h.mesh_min, h.mesh_max));
    let tiles = tiles(opts.width, opts.height, opts.order);
    let pixels = opts.camera.pixels(opts.width, opts.height);
    let mut done: Vec<Vec<u8>> = vec![Vec::new(); tiles.len()];
    let traced = in_order(&tiles, &mut done, 1, scene.threads(), |tiles, out, s| {
        let mut waves = Waves::default();
        for (&(_, tx, ty), px) in tiles.iter().zip(out) {
            let (x0, y0) = (tx * TILE, ty * TILE);
            let (x1, y1) = ((x0 + TILE).min(opts.width), (y0 + TILE).min(opts.height));
            px.reserve_exact(3 * ((x1 - x0) * (y1 - y0)) as usize);
            let rays = (y0..y1).flat_map(|y| (x0..x1).map(move |x| pixels.ray(x, y)));
            let before = *s;
            if shader.tile_in_waves(rays.clone(), opts.wave_limit, &mut waves, s)? {
                px.extend(waves.pixels().flat_map(|c| c.to_array().map(to_display8)));
                continue;
            }
            // Ray by ray: a tile whose waves would outgrow their limit (its counts so far
            // undone).
            *s = before;
            s.ray_by_ray_tiles += 1;
            for ray in rays {
                let c = shader.radiance(&ray, Kind::Primary, 0, 1.0, s)?;
                px.extend(c.to_array().map(to_display8));
            }
        }
        Ok(())
    });
    let stats: ShadedStats = traced.map_err(|e: TraceError| scene.corrupt(e))?;
    scene.check_unchanged()?;
    let seconds = start.elapsed().as_secs_f64();
    let rays =
        stats.primary.rays + stats.shadow.rays + stats.reflection.rays + stats.refraction.rays;
    Ok((
        assemble(&tiles, &done, opts.width, opts.height),
        ShadedStats {
            width: opts.width,
            height: opts.height,
            seconds,
            rays,
            mrays_per_s: rays as f64 / seconds.max(1e-12) / 1e6,
            ..stats
        },
    ))
}

/// The scale offsets are relative to: the larger of the box's diagonal and its largest
/// coordinate (1 for an empty box).
fn scale(min: [f32; 3], max: [f32; 3]) -> f64 {
    let diag = (0..3)
        .map(|k| (max[k] as f64 - min[k] as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let far = min
        .iter()
        .chain(&max)
        .map(|c| (*c as f64).abs())
        .fold(0.0, f64::max);
    let s = diag.max(far);
    if s.is_finite() && s > 0.0 { s } else { 1.0 }
}

/// A material as the shader reads it (see the clamping in [`render_shaded`]).
#[derive(Clone, Copy, Debug)]
struct Surface {
    ambient: DVec3,
    diffuse: DVec3,
    specular: DVec3,
    shine: f64,
    transmittance: f64,
    ior: f64,
}

/// `x` if it is a finite number above 0, else 0.
fn positive(x: f32) -> f64 {
    if x.is_finite() && x > 0.0 {
        x as f64
    } else {
        0.0
    }
}

fn colour(c: [f32; 3]) -> DVec3 {
    DVec3::from(c.map(positive))
}

impl Surface {
    fn new(m: &AffMaterial) -> Surface {
        Surface {
            ambient: colour(m.ambient),
            diffuse: colour(m.diffuse),
            specular: colour(m.specular).min(DVec3::ONE),
            shine: positive(m.shine),
            transmittance: positive(m.transmittance).min(1.0),
            ior: match positive(m.ior) {
                0.0 => 1.0,
                ior => ior,
            },
        }
    }
}

/// Which counters a closest-hit ray counts in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Primary,
    Reflection,
    Refraction,
}

/// The look, read once for the whole image, and the tree.
struct Shader<'a> {
    tree: &'a Tree<'a>,
    look: &'a Look,
    surfaces: Vec<Surface>,
    default: Surface,
    /// Position and colour.
    lights: Vec<(DVec3, DVec3)>,
    ambient: DVec3,
    background: DVec3,
    /// [`OFFSET`] times the scene's scale.
    eps: f64,
    max_depth: u32,
    min_weight: f64,
    shadows: bool,
}

impl<'a> Shader<'a> {
    fn new(tree: &'a Tree<'a>, look: &'a Look, opts: &ShadedOptions, scale: f64) -> Shader<'a> {
        Shader {
            tree,
            look,
            surfaces: look.materials.iter().map(Surface::new).collect(),
            default: Surface::new(&AffMaterial::DEFAULT),
            lights: look
                .lights
                .iter()
                .filter(|l| l.position.iter().all(|c| c.is_finite()))
                .map(|l| (DVec3::from(l.position), colour(l.colour)))
                .collect(),
            ambient: colour(look.ambient),
            background: colour(look.background),
            eps: OFFSET * scale,
            max_depth: opts.max_depth,
            min_weight: opts.min_weight,
            shadows: opts.shadows,
        }
    }

    /// The surface of primitive `prim`, as [`Look::material`] finds its material.
    fn surface(&self, prim: u32) -> &Surface {
        let index = self
            .look
            .material_of
            .get(prim as usize)
            .map_or(0, |&m| m as usize);
        self.surfaces.get(index).unwrap_or(&self.default)
    }

    /// The counters of rays of `kind`.
    fn counters(kind: Kind, s: &mut ShadedStats) -> &mut Counters {
        match kind {
            Kind::Primary => &mut s.primary,
            Kind::Reflection => &mut s.reflection,
            Kind::Refraction => &mut s.refraction,
        }
    }

    /// The linear colour `ray` brings back, `depth` bounces from the camera, weighing `weight`
    /// in its pixel: traced ray by ray, depth first.
    fn radiance(
        &self,
        ray: &Ray,
        kind: Kind,
        depth: u32,
        weight: f64,
        s: &mut ShadedStats,
    ) -> Result<DVec3, TraceError> {
        let Some(hit) = self.tree.intersect(ray, Self::counters(kind, s))? else {
            return Ok(self.background);
        };
        let mut lights = Vec::new();
        let (mut c, bounces) = self.shade(ray, kind, depth, weight, &hit, s, &mut lights);
        for l in &lights {
            let lit = match &l.shadow {
                Some(shadow) => !self.tree.occluded(shadow, &mut s.shadow)?,
                None => true,
            };
            c = l.add_to(c, lit, s);
        }
        for b in bounces.into_iter().flatten() {
            c += b.factor * self.radiance(&b.ray, b.kind, depth + 1, b.weight, s)?;
        }
        Ok(c)
    }

    /// Shades the closest hit `hit` of `ray` (`depth` bounces from the camera, weighing
    /// `weight`): its colour before the lights (the ambient term), each light's terms appended
    /// to `lights` (in the lights' order, each with the shadow ray that decides it), and the
    /// reflected and refracted rays it casts, in that order. The colour is then the ambient
    /// term, plus each light's terms where its shadow ray is not occluded, plus each bounce's
    /// factor times the colour it brings back ([`Self::radiance`]).
    #[allow(clippy::too_many_arguments)]
    fn shade(
        &self,
        ray: &Ray,
        kind: Kind,
        depth: u32,
        weight: f64,
        hit: &HitInfo,
        s: &mut ShadedStats,
        lights: &mut Vec<LightTerm>,
    ) -> (DVec3, [Option<Bounce>; 2]) {
        s.surface_hits += 1;
        s.hits += (kind == Kind::Primary) as u64;
        let m = *self.surface(hit.prim);
        let d = unit(DVec3::from(ray.dir.map(f64::from)));
        let v = hit.v.map(|p| DVec3::from(p.map(f64::from)));
        let n = unit((v[1] - v[0]).cross(v[2] - v[0]));
        // A triangle the tracer hits has an area; should its normal still vanish in f64, it
        // faces the ray.
        let n = if n.is_finite() && n != DVec3::ZERO {
            n
        } else {
            -d
        };
        let front = n.dot(d) < 0.0;
        let ns = if front { n } else { -n };
        let p = DVec3::from(ray.at(hit.t as f64));
        let lifted = p + ns * self.eps;

        let c = self.ambient * m.ambient;
        for &(light, light_colour) in &self.lights {
            let l = unit(light - p);
            let ndl = ns.dot(l);
            if ndl <= 0.0 || ndl.is_nan() {
                s.facing_away += 1;
                continue;
            }
            let shadow = self.shadows.then(|| {
                Ray::new(
                    f32s(lifted),
                    f32s(light - lifted),
                    0.0,
                    1.0 - SHADOW_EPSILON,
                )
            });
            let mut specular = None;
            if m.shine > 0.0 && m.specular != DVec3::ZERO {
                let r = 2.0 * ndl * ns - l;
                let rv = -r.dot(d);
                if rv > 0.0 {
                    specular = Some(light_colour * m.specular * rv.powf(m.shine));
                }
            }
            lights.push(LightTerm {
                shadow,
                diffuse: light_colour * m.diffuse * ndl,
                specular,
            });
        }

        let mut bounces = [None, None];
        let mirror = d - 2.0 * d.dot(ns) * ns;
        if m.specular != DVec3::ZERO
            && let Some(w) = self.next_weight(weight, m.specular.max_element(), depth, s)
        {
            bounces[0] = Some(Bounce {
                ray: Ray::new(f32s(lifted), f32s(mirror), 0.0, f32::INFINITY),
                kind: Kind::Reflection,
                weight: w,
                factor: m.specular,
            });
        }
        if m.transmittance > 0.0
            && let Some(w) = self.next_weight(weight, m.transmittance, depth, s)
        {
            let eta = if front { 1.0 / m.ior } else { m.ior };
            let cos_i = -d.dot(ns);
            let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
            let (ray, kind) = if k < 0.0 {
                s.total_internal_reflections += 1;
                let r = Ray::new(f32s(lifted), f32s(mirror), 0.0, f32::INFINITY);
                (r, Kind::Reflection)
            } else {
                let t = eta * d + (eta * cos_i - k.sqrt()) * ns;
                let r = Ray::new(f32s(p - ns * self.eps), f32s(t), 0.0, f32::INFINITY);
                (r, Kind::Refraction)
            };
            bounces[1] = Some(Bounce {
                ray,
                kind,
                weight: w,
                factor: DVec3::splat(m.transmittance),
            });
        }
        (c, bounces)
    }

    /// Renders one tile's pixels, whose primary rays are `rays`, in waves (see
    /// [`ShadedOptions::wave_limit`]) into `w` ([`Waves::pixels`]); false, with nothing of it
    /// certain, if it would keep more than `limit` points and light terms.
    fn tile_in_waves(
        &self,
        rays: impl Iterator<Item = Ray>,
        limit: usize,
        w: &mut Waves,
        s: &mut ShadedStats,
    ) -> Result<bool, TraceError> {
        w.points.clear();
        w.casts.clear();
        for ray in rays {
            w.casts.push(Cast {
                point: w.points.len() as u32,
                ray,
                kind: Kind::Primary,
                depth: 0,
                weight: 1.0,
            });
            w.points.push(Point::new(self.background));
        }
        w.pixels = w.points.len();
        if w.pixels > limit {
            return Ok(false);
        }
        while !w.casts.is_empty() {
            // The closest hits, one batch per kind of ray (each kind has its counters).
            w.hits.clear();
            w.hits.resize(w.casts.len(), None);
            for kind in [Kind::Primary, Kind::Reflection, Kind::Refraction] {
                w.rays.clear();
                w.rays
                    .extend(w.casts.iter().filter(|c| c.kind == kind).map(|c| c.ray));
                if w.rays.is_empty() {
                    continue;
                }
                self.tree
                    .intersect_each(&w.rays, Self::counters(kind, s), &mut w.answers)?;
                let slots = w.casts.iter().enumerate().filter(|(_, c)| c.kind == kind);
                for ((i, _), &hit) in slots.zip(&w.answers) {
                    w.hits[i] = hit;
                }
            }
            // Shade what they hit, in order; the next wave is their bounces.
            w.lights.clear();
            w.owners.clear();
            w.next.clear();
            for (cast, hit) in w.casts.iter().zip(&w.hits) {
                let Some(hit) = hit else { continue };
                let (c, bounces) = self.shade(
                    &cast.ray,
                    cast.kind,
                    cast.depth,
                    cast.weight,
                    hit,
                    s,
                    &mut w.lights,
                );
                w.owners.resize(w.lights.len(), cast.point);
                let at = cast.point as usize;
                w.points[at].colour = c;
                for (slot, b) in bounces.into_iter().enumerate() {
                    let Some(b) = b else { continue };
                    let child = w.points.len() as u32;
                    w.points.push(Point::new(self.background));
                    w.points[at].bounces[slot] = Some((child, b.factor));
                    w.next.push(Cast {
                        point: child,
                        ray: b.ray,
                        kind: b.kind,
                        depth: cast.depth + 1,
                        weight: b.weight,
                    });
                }
                if w.points.len() + w.lights.len() > limit {
                    return Ok(false);
                }
            }
            // The shadow rays, in one batch; then each light's terms, in order.
            w.rays.clear();
            w.rays.extend(w.lights.iter().filter_map(|l| l.shadow));
            self.tree
                .occluded_each(&w.rays, &mut s.shadow, &mut w.occluded)?;
            let mut shadows = w.occluded.iter();
            for (l, &owner) in w.lights.iter().zip(&w.owners) {
                let lit = l.shadow.is_none() || shadows.next() == Some(&false);
                let p = &mut w.points[owner as usize];
                p.colour = l.add_to(p.colour, lit, s);
            }
            std::mem::swap(&mut w.casts, &mut w.next);
        }
        // Each point's bounces were cast after it: from the last point back, each adds what
        // its bounces brought back, as the ray-by-ray recursion does on its way up.
        for i in (0..w.points.len()).rev() {
            for slot in 0..2 {
                if let Some((child, factor)) = w.points[i].bounces[slot] {
                    let brought = w.points[child as usize].colour;
                    w.points[i].colour += factor * brought;
                }
            }
        }
        Ok(true)
    }

    /// The weight of a ray cast from a point of weight `weight` through a factor `factor`, or
    /// `None` (counted) when it is not cast: too deep, or weighing too little.
    fn next_weight(
        &self,
        weight: f64,
        factor: f64,
        depth: u32,
        s: &mut ShadedStats,
    ) -> Option<f64> {
        if depth >= self.max_depth {
            s.depth_limited += 1;
            return None;
        }
        let w = weight * factor;
        if w < self.min_weight {
            s.weight_limited += 1;
            return None;
        }
        Some(w)
    }
}

/// A light's share of a shaded point: added to its colour if the shadow ray (if any) is not
/// occluded.
struct LightTerm {
    shadow: Option<Ray>,
    diffuse: DVec3,
    specular: Option<DVec3>,
}

impl LightTerm {
    /// `c` with this term added if the light reaches the point (`lit`), counted otherwise.
    fn add_to(&self, mut c: DVec3, lit: bool, s: &mut ShadedStats) -> DVec3 {
        if !lit {
            s.shadowed += 1;
            return c;
        }
        c += self.diffuse;
        if let Some(sp) = self.specular {
            c += sp;
        }
        c
    }
}

/// A reflected or refracted ray a shaded point casts, and the factor its colour is added by.
struct Bounce {
    ray: Ray,
    kind: Kind,
    weight: f64,
    factor: DVec3,
}

/// A closest-hit ray of a wave: the point whose colour it brings back.
struct Cast {
    point: u32,
    ray: Ray,
    kind: Kind,
    depth: u32,
    weight: f64,
}

/// A point of a tile's ray tree: its colour (the background until its ray hits), and its
/// bounces' points with their factors.
#[derive(Clone, Copy)]
struct Point {
    colour: DVec3,
    bounces: [Option<(u32, DVec3)>; 2],
}

impl Point {
    fn new(background: DVec3) -> Point {
        Point {
            colour: background,
            bounces: [None, None],
        }
    }
}

/// A tile's waves: its ray tree (the first [`Waves::pixels`] points are its pixels) and the
/// buffers of a wave, kept from tile to tile.
#[derive(Default)]
struct Waves {
    points: Vec<Point>,
    pixels: usize,
    casts: Vec<Cast>,
    next: Vec<Cast>,
    hits: Vec<Option<HitInfo>>,
    answers: Vec<Option<HitInfo>>,
    rays: Vec<Ray>,
    lights: Vec<LightTerm>,
    /// The point of each light term.
    owners: Vec<u32>,
    occluded: Vec<bool>,
}

impl Waves {
    /// The colours of the tile's pixels, row by row.
    fn pixels(&self) -> impl Iterator<Item = DVec3> + '_ {
        self.points[..self.pixels].iter().map(|p| p.colour)
    }
}

fn f32s(v: DVec3) -> [f32; 3] {
    v.to_array().map(|x| x as f32)
}

/// A display value in `[0, 1]` (clamped; NaN is 0) as 8 bits, with no transfer curve.
fn to_display8(c: f64) -> u8 {
    let c = if c > 0.0 { c.min(1.0) } else { 0.0 };
    (c * 255.0 + 0.5) as u8
}
