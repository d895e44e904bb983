//! Shadow rays by the multi-index tree of Liang and Huang (2019), against the standard walk and
//! the SATO order (Nah and Manocha 2014), over the frames of a short camera move: what
//! `oavm-bench --shadow-variant` measures.
//!
//! **Variants** ([`ShadowVariant`]): `standard` (the structure's own any-hit walk), `sato` (a
//! fixed child order by surface area), `multi` (a primitive index for rays predicted occluded,
//! an adjacency index for rays predicted unoccluded). The structures' sides are in their
//! modules ([`super::kdtree`]'s `shadow`). Every variant gives the same answers, which
//! [`run`] checks ray for ray against `standard`.
//!
//! **Frames** ([`ShadowSetup`]): the scene's camera orbits its target, a few degrees a frame;
//! each frame's primary rays are traced and shadow rays go from their hits to the lights
//! ([`ShadowFrame`]), so consecutive frames see nearly the same image, as a renderer's do.
//!
//! **Prediction** (`multi`): the screen is cut into tiles; a ray's key is its tile and light.
//! In frame `k` the sample ray of each key (the one nearest the tile's centre) is traced like
//! the others, and its answer is the prediction for that key in frame `k + 1`: occluded, the
//! primitive-index walk; not, the adjacency walk. Frame 0 has no frame before it: its samples
//! are traced first, by the standard walk, their work counted with the frame's. A key whose
//! tile had no sample in the frame before (no primary hit there) takes the primitive-index
//! walk, the stack walk with a few more tests. Accuracy is the fraction of predicted rays whose
//! answer was the one predicted.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::bench::{BenchScene, ByOcclusion};
use super::kdtree::{Adjacency, KdTree, Precompute, PrimitiveIndex, SatoOrder, ShadowParams};
use super::{Accelerator, OavmAccel, Triangles};
use crate::Counters;
use oavm::error::Error;
use oavm::geom::{Hit, Ray};
use oavm::logical::Walk;
use oavm::pack::BuildOptions;
use oavm::rays::{Bounds, Camera, Light, ShadowFrame, orbit};

/// The variants `--shadow-variant` knows, in the order they are reported.
pub const SHADOW_VARIANTS: [&str; 3] = ["standard", "sato", "multi"];

/// The structures the variants are built for.
pub const SHADOW_STRUCTURES: [&str; 2] = ["kdtree", "oavm"];

/// A shadow-ray traversal (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ShadowVariant {
    Standard,
    Sato,
    Multi,
}

impl ShadowVariant {
    pub fn parse(s: &str) -> Result<ShadowVariant, Error> {
        match s {
            "standard" => Ok(ShadowVariant::Standard),
            "sato" => Ok(ShadowVariant::Sato),
            "multi" => Ok(ShadowVariant::Multi),
            _ => Err(Error::Invalid(format!(
                "unknown shadow variant {s:?}: expected one of {}",
                SHADOW_VARIANTS.join(", ")
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ShadowVariant::Standard => "standard",
            ShadowVariant::Sato => "sato",
            ShadowVariant::Multi => "multi",
        }
    }
}

/// How one ray walks: what a variant (and, for `multi`, its prediction) chose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadowWalk {
    Standard,
    Sato,
    /// The multi-index tree's walk for rays predicted occluded.
    Primitive,
    /// The multi-index tree's walk for rays predicted unoccluded.
    Adjacency,
}

/// What the variants need to be prepared: where shadow rays start and end.
pub struct ShadowPrep<'a> {
    /// The primary hits of the first frame.
    pub visible: &'a [[f32; 3]],
    /// The lights' points (a point light's point, an area light's corners and centre).
    pub lights: &'a [[f32; 3]],
    pub params: ShadowParams,
}

/// What a variant's precomputation built.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PrecomputeReport {
    pub seconds: f64,
    pub bytes: u64,
    /// `multi`: triangles that were candidates, triangles promoted to inner nodes.
    pub candidates: usize,
    pub promoted: usize,
    /// `multi`: leaves with adjacency links, of all leaves.
    pub linked_leaves: usize,
    pub leaves: usize,
}

/// A structure prepared for one shadow variant.
pub trait ShadowStructure: Send + Sync {
    /// Any hit by `walk` (the walks the variant was prepared for).
    fn occluded_by(&self, ray: &Ray, walk: ShadowWalk, c: &mut Counters) -> bool;
    /// Closest hit (for the frames' primary rays).
    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit;
    fn precompute(&self) -> PrecomputeReport;
}

/// The KD-tree with the indices of one variant.
pub struct KdShadow<'a> {
    kd: &'a KdTree,
    sato: Option<SatoOrder>,
    index: Option<PrimitiveIndex>,
    adj: Option<Adjacency>,
}

impl<'a> KdShadow<'a> {
    pub fn new(kd: &'a KdTree, variant: ShadowVariant, prep: &ShadowPrep) -> KdShadow<'a> {
        let mut s = KdShadow {
            kd,
            sato: None,
            index: None,
            adj: None,
        };
        match variant {
            ShadowVariant::Standard => {}
            ShadowVariant::Sato => s.sato = Some(SatoOrder::build(s.kd)),
            ShadowVariant::Multi => {
                s.index = Some(PrimitiveIndex::build(s.kd, &prep.params));
                s.adj = Some(Adjacency::build(
                    s.kd,
                    prep.visible,
                    prep.lights,
                    &prep.params,
                ));
            }
        }
        s
    }
}

impl ShadowStructure for KdShadow<'_> {
    fn occluded_by(&self, ray: &Ray, walk: ShadowWalk, c: &mut Counters) -> bool {
        match (walk, &self.sato, &self.index, &self.adj) {
            (ShadowWalk::Sato, Some(o), _, _) => self.kd.occluded_sato(ray, o, c),
            (ShadowWalk::Primitive, _, Some(i), _) => self.kd.occluded_promoted(ray, i, c),
            (ShadowWalk::Adjacency, _, _, Some(a)) => self.kd.occluded_adjacent(ray, a, c),
            _ => self.kd.occluded_standard(ray, c),
        }
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        Accelerator::intersect(self.kd, ray, c)
    }

    fn precompute(&self) -> PrecomputeReport {
        let mut r = PrecomputeReport::default();
        let mut add = |p: &Precompute| {
            r.seconds += p.seconds;
            r.bytes += p.bytes;
        };
        if let Some(o) = &self.sato {
            add(&o.cost);
        }
        if let Some(i) = &self.index {
            add(&i.cost);
            r.candidates = i.candidates;
            r.promoted = i.promoted();
        }
        if let Some(a) = &self.adj {
            add(&a.cost);
            r.linked_leaves = a.linked_leaves;
            r.leaves = a.leaves;
        }
        r
    }
}

/// OAVM (a file of clusters, packed in memory) with what one variant needs: `standard` is
/// its top-down walk; `sato` the same walk taking children in the SATO order
/// ([`oavm::logical::Tree::sato`]), which needs no precomputation (the boxes it orders by are
/// in the file already); `multi` adds occluders (spec §8.5) for its primitive walk (the
/// top-down walk testing them) and ropes (spec §8.4) for its adjacency walk (the leaf-to-leaf
/// walk from rope to rope, the step OAVM already has: what the source's adjacency index would
/// add is where the walk starts, and where links are built).
pub struct OavmShadow {
    /// The variant's file: walked top-down, or (`multi`) leaf to leaf by its ropes.
    acc: OavmAccel,
    /// `multi`: the same file walked top-down (a scene's walk is chosen when it is opened), for
    /// its primitive walk; otherwise `acc` walks top-down.
    top_down: Option<OavmAccel>,
    precompute: PrecomputeReport,
}

impl OavmShadow {
    pub fn new(
        plain: &OavmAccel,
        variant: ShadowVariant,
        params: &ShadowParams,
    ) -> Result<OavmShadow, Error> {
        let (acc, top_down, precompute) = match variant {
            ShadowVariant::Multi => {
                let (occ, report) = plain.with_occluders(params)?;
                let (acc, seconds, bytes) = occ.with_ropes()?;
                let added = bytes + report.bytes_after.saturating_sub(report.bytes_before);
                let top_down = acc.walked(Walk::TopDown)?;
                (
                    acc,
                    Some(top_down),
                    PrecomputeReport {
                        seconds: seconds + report.seconds,
                        bytes: added,
                        candidates: report.candidates as usize,
                        promoted: report.occluders as usize,
                        ..PrecomputeReport::default()
                    },
                )
            }
            _ => (plain.clone_scene()?, None, PrecomputeReport::default()),
        };
        Ok(OavmShadow {
            acc,
            top_down,
            precompute,
        })
    }
}

impl ShadowStructure for OavmShadow {
    fn occluded_by(&self, ray: &Ray, walk: ShadowWalk, c: &mut Counters) -> bool {
        let top_down = self.top_down.as_ref().unwrap_or(&self.acc);
        match walk {
            ShadowWalk::Sato => top_down.occluded_walk(ray, true, false, c),
            // By ropes in `multi`'s file (the only variant that takes this walk).
            ShadowWalk::Adjacency => self.acc.occluded_walk(ray, false, false, c),
            ShadowWalk::Primitive => top_down.occluded_walk(ray, false, true, c),
            ShadowWalk::Standard => top_down.occluded_walk(ray, false, false, c),
        }
    }

    fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
        Accelerator::intersect(&self.acc, ray, c)
    }

    fn precompute(&self) -> PrecomputeReport {
        self.precompute
    }
}

/// The lights of a shadow benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    /// The scene's point lights (or the default light).
    Point,
    /// Each of them made a square area light (side 2 % of the scene's diagonal), sampled
    /// `samples` times per pixel.
    Quad,
}

/// What the shadow benchmark measures.
#[derive(Clone, Debug, Serialize)]
pub struct ShadowOptions {
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    /// Degrees the camera turns each frame.
    pub orbit_step: f64,
    /// Tile side, pixels.
    pub tile: u32,
    pub light: LightKind,
    /// Samples per pixel of an area light.
    pub samples: u32,
    /// Meshes (not BART scenes): enclose the mesh, camera and light in a closed box.
    pub closed_box: bool,
    pub params: ShadowParams,
    pub reps: usize,
    pub threads: Vec<usize>,
}

/// A scene's frames: cameras, lights and each frame's shadow rays.
pub struct ShadowSetup {
    pub frames: Vec<ShadowFrame>,
    pub lights: Vec<Light>,
    /// The primary hit points of frame 0.
    pub visible: Vec<[f32; 3]>,
    /// "scene" (its own lights), "view" (a light in the view: the scene's leave nearly every
    /// hit in shadow), "default" (a mesh's default light).
    pub light_source: &'static str,
}

/// The twelve triangles of the box `b`'s faces (outward or inward does not matter to a shadow
/// ray).
pub fn box_triangles(b: &Bounds) -> Vec<[[f32; 3]; 3]> {
    let p = |i: usize| -> [f32; 3] {
        std::array::from_fn(|k| if i >> k & 1 == 1 { b.max[k] } else { b.min[k] })
    };
    // Faces as corner indices (bit k: max on axis k).
    let faces = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    faces
        .iter()
        .flat_map(|f| [[p(f[0]), p(f[1]), p(f[2])], [p(f[0]), p(f[2]), p(f[3])]])
        .collect()
}

/// Adds a closed box around `scene`'s mesh, its camera and a light above it (5 % larger on every
/// side): the "dragon in a closed box" of the Table, where no ray leaves the scene.
pub fn close_in_box(scene: &mut BenchScene) -> Result<(), Error> {
    let cam = scene.camera();
    // Above, right and in front of the centre, nearer than the default light, so that the box
    // around it and the camera stays a room the mesh stands in.
    let c = scene.bounds.centre();
    let d = scene.bounds.diagonal();
    let off = [0.3, 0.7, 0.5];
    let light: [f32; 3] = std::array::from_fn(|k| (c[k] + off[k] * d) as f32);
    let mut pts: Vec<[f32; 3]> = vec![scene.bounds.min, scene.bounds.max, light];
    pts.push(cam.eye.map(|x| x as f32));
    let b = Bounds::of_points(pts);
    let pad = 0.05 * b.diagonal();
    let b = Bounds {
        min: b.min.map(|x| x - pad as f32),
        max: b.max.map(|x| x + pad as f32),
    };
    let base = scene.mesh.positions.len() as u32;
    for t in box_triangles(&b) {
        let i = scene.mesh.positions.len() as u32;
        scene.mesh.positions.extend(t);
        scene.mesh.triangles.push([i, i + 1, i + 2]);
    }
    debug_assert!(scene.mesh.positions.len() as u32 >= base);
    // The camera and the light stay where they were: the bounds now include the box.
    scene.view = Some((cam, Some(light)));
    scene.tris = Triangles::from_mesh(&scene.mesh)?;
    scene.bounds = Bounds::of_points(scene.tris.v.iter().flatten().copied());
    Ok(())
}

/// A camera and a light given instead of the scene's, and the closed box (module docs).
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewOverride {
    /// The camera's eye and target (its up is +y).
    pub eye_target: Option<([f64; 3], [f64; 3])>,
    /// Its vertical field of view, degrees.
    pub fov: f64,
    /// One point light instead of the scene's lights.
    pub light_at: Option<[f32; 3]>,
    /// A mesh (a scene without lights) is closed in a box ([`close_in_box`]).
    pub closed_box: bool,
}

/// Loads the scene at `path` as the shadow benchmark poses it.
pub fn load_scene(path: &std::path::Path, view: &ViewOverride) -> Result<BenchScene, Error> {
    let mut scene = BenchScene::load(path)?;
    if let Some((eye, target)) = view.eye_target {
        let cam = Camera::look_at(eye, target, [0.0, 1.0, 0.0], view.fov)
            .map_err(|e| Error::Invalid(format!("the camera given: {e}")))?;
        let light = scene.view.and_then(|(_, l)| l);
        scene.view = Some((cam, light));
    }
    if let Some(l) = view.light_at {
        scene.lights = vec![l];
        if let Some((_, light)) = &mut scene.view {
            *light = Some(l);
        }
    }
    if view.closed_box && scene.lights.is_empty() {
        close_in_box(&mut scene)?;
    }
    Ok(scene)
}

impl ShadowSetup {
    /// The frames of `scene` traced through `acc` (its primary hits).
    pub fn new(
        scene: &BenchScene,
        acc: &dyn Accelerator,
        scene_lights: &[[f32; 3]],
        opts: &ShadowOptions,
    ) -> ShadowSetup {
        let camera = scene.camera();
        let cams = orbit(&camera, opts.frames.max(1), opts.orbit_step);
        let primary: Vec<Vec<Ray>> = cams
            .iter()
            .map(|c| c.primary_rays(opts.width, opts.height))
            .collect();
        let hits: Vec<Vec<Hit>> = primary
            .iter()
            .map(|p| {
                let mut h = vec![Hit::MISS; p.len()];
                super::intersect_batch(acc, p, &mut h);
                h
            })
            .collect();
        let (points, light_source) =
            choose_lights(scene, acc, scene_lights, &camera, &primary[0], &hits[0]);
        let side = 0.02 * scene.bounds.diagonal() as f32;
        let lights: Vec<Light> = points
            .iter()
            .map(|&p| match opts.light {
                LightKind::Point => Light::Point(p),
                LightKind::Quad => Light::square(p, side),
            })
            .collect();
        let frames = primary
            .iter()
            .zip(&hits)
            .enumerate()
            .map(|(k, (p, h))| {
                ShadowFrame::new(
                    p,
                    h,
                    opts.width,
                    opts.height,
                    &lights,
                    opts.samples,
                    opts.tile,
                    k as u64 + 1,
                )
            })
            .collect();
        let visible = primary[0]
            .iter()
            .zip(&hits[0])
            .filter(|(_, h)| h.is_hit())
            .map(|(r, h)| r.at(h.t as f64).map(|x| x as f32))
            .collect();
        ShadowSetup {
            frames,
            lights,
            visible,
            light_source,
        }
    }

    /// The points of the lights the precomputation is told about.
    pub fn light_points(&self) -> Vec<[f32; 3]> {
        self.lights.iter().flat_map(|l| l.extent()).collect()
    }

    pub fn rays(&self) -> usize {
        self.frames.iter().map(|f| f.rays.len()).sum()
    }
}

/// The scene's own lights, unless they leave (nearly: all but 1 %) every primary hit of the
/// first frame in shadow, as the robots' light does (above the roof of the box enclosing their
/// city); then one light halfway between the camera and the point its central ray hits (as
/// [`super::bench::shadow_light`] chooses). A mesh has the default light.
fn choose_lights(
    scene: &BenchScene,
    acc: &dyn Accelerator,
    scene_lights: &[[f32; 3]],
    camera: &Camera,
    primary: &[Ray],
    hits: &[Hit],
) -> (Vec<[f32; 3]>, &'static str) {
    if scene_lights.is_empty() {
        let light = match &scene.view {
            Some((_, Some(l))) => *l,
            _ => oavm::rays::default_light(&scene.bounds),
        };
        return (vec![light], "default");
    }
    let mut lit = 0usize;
    let mut total = 0usize;
    for &l in scene_lights {
        let shadow = oavm::rays::shadow_rays(primary, hits, l);
        let mut occ = vec![0u8; shadow.len()];
        super::occluded_batch(acc, &shadow, &mut occ);
        lit += occ.iter().filter(|&&o| o == 0).count();
        total += shadow.len();
    }
    if lit as f64 >= 0.01 * total as f64 {
        return (scene_lights.to_vec(), "scene");
    }
    let eye = camera.eye.map(|c| c as f32);
    let dir: [f32; 3] = std::array::from_fn(|k| (camera.target[k] - camera.eye[k]) as f32);
    let hit = acc.intersect(
        &Ray::new(eye, dir, 0.0, f32::INFINITY),
        &mut Counters::default(),
    );
    let light = if hit.is_hit() {
        std::array::from_fn(|k| eye[k] + 0.5 * hit.t * dir[k])
    } else {
        eye
    };
    (vec![light], "view")
}

/// The answers and work of one variant over every frame.
pub struct Traced {
    pub answers: Vec<Vec<u8>>,
    /// Work of the unoccluded (`[0]`) and occluded (`[1]`) rays; frame 0's samples (`multi`)
    /// are counted with the rays they were (`rays` counts each ray once).
    pub split: [Counters; 2],
    pub prediction: Option<Prediction>,
}

/// How well `multi`'s prediction did.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Prediction {
    /// Rays whose key had a prediction, and those whose answer was the one predicted.
    pub predicted: u64,
    pub correct: u64,
    pub accuracy: f64,
    /// Rays that took each walk.
    pub primitive_walks: u64,
    pub adjacency_walks: u64,
    /// Frame 0's sample rays traced before the frame (by the standard walk).
    pub warmup_rays: u64,
}

/// Traces every frame of `setup` through `s` by `variant`, on the current rayon pool.
pub fn trace_frames(
    s: &dyn ShadowStructure,
    variant: ShadowVariant,
    setup: &ShadowSetup,
) -> Traced {
    let mut out = Traced {
        answers: Vec::with_capacity(setup.frames.len()),
        split: [Counters::default(); 2],
        prediction: (variant == ShadowVariant::Multi).then(Prediction::default),
    };
    // Per key: 0 unoccluded, 1 occluded, 2 no prediction.
    let mut predicted: Vec<u8> = Vec::new();
    for (k, f) in setup.frames.iter().enumerate() {
        let samples = f.samples();
        if variant == ShadowVariant::Multi && k == 0 {
            predicted = vec![2; f.key_count as usize];
            let mut warm = Counters::default();
            for (key, &i) in samples.iter().enumerate() {
                if let Some(r) = f.rays.get(i as usize) {
                    predicted[key] = s.occluded_by(r, ShadowWalk::Standard, &mut warm) as u8;
                }
            }
            // The warm-up's work, not its rays, joins the unoccluded rays' (its rays are
            // traced again in the frame).
            warm.rays = 0;
            out.split[0] += warm;
            if let Some(p) = &mut out.prediction {
                p.warmup_rays += samples.iter().filter(|&&i| i != u32::MAX).count() as u64;
            }
        }
        let walk_of = |i: usize| match variant {
            ShadowVariant::Standard => ShadowWalk::Standard,
            ShadowVariant::Sato => ShadowWalk::Sato,
            ShadowVariant::Multi => match predicted.get(f.keys[i] as usize) {
                Some(0) => ShadowWalk::Adjacency,
                _ => ShadowWalk::Primitive,
            },
        };
        let mut answers = vec![0u8; f.rays.len()];
        let (split, right, prim) = f
            .rays
            .par_chunks(256)
            .zip(answers.par_chunks_mut(256))
            .enumerate()
            .map(|(ci, (rays, out))| {
                let mut split = [Counters::default(); 2];
                let (mut right, mut prim) = (0u64, 0u64);
                for (j, (r, o)) in rays.iter().zip(out).enumerate() {
                    let i = ci * 256 + j;
                    let walk = walk_of(i);
                    let mut c = Counters {
                        rays: 1,
                        ..Counters::default()
                    };
                    *o = s.occluded_by(r, walk, &mut c) as u8;
                    split[*o as usize] += c;
                    prim += (walk == ShadowWalk::Primitive) as u64;
                    right += (predicted.get(f.keys[i] as usize) == Some(o)) as u64;
                }
                (split, right, prim)
            })
            .reduce(
                || ([Counters::default(); 2], 0, 0),
                |a, b| ([a.0[0] + b.0[0], a.0[1] + b.0[1]], a.1 + b.1, a.2 + b.2),
            );
        out.split[0] += split[0];
        out.split[1] += split[1];
        if let Some(p) = &mut out.prediction {
            let with = f
                .keys
                .iter()
                .filter(|&&k| predicted.get(k as usize).is_some_and(|&v| v < 2))
                .count() as u64;
            p.predicted += with;
            p.correct += right;
            p.primitive_walks += prim;
            p.adjacency_walks += f.rays.len() as u64 - prim;
            // The next frame's prediction: this frame's samples' answers.
            predicted = samples
                .iter()
                .map(|&i| answers.get(i as usize).copied().unwrap_or(2))
                .collect();
        }
        out.answers.push(answers);
    }
    if let Some(p) = &mut out.prediction {
        p.accuracy = p.correct as f64 / p.predicted.max(1) as f64;
    }
    out
}

/// One variant over one scene.
#[derive(Clone, Debug, Serialize)]
pub struct VariantResult {
    pub variant: ShadowVariant,
    pub structure: &'static str,
    pub precompute: PrecomputeReport,
    pub rays: u64,
    pub occluded: u64,
    /// Rays answered otherwise than by the structure's `standard` (must be 0).
    pub disagree_with_standard: u64,
    /// Rays answered otherwise than by the KD-tree's standard walk (must be 0).
    pub disagree_with_kdtree: u64,
    #[serde(flatten)]
    pub by_occlusion: ByOcclusion,
    pub promoted_tested_per_ray: f64,
    pub links_followed_per_ray: f64,
    pub restarts_per_ray: f64,
    /// Change against `standard`, percent: node and triangle tests per occluded and per
    /// unoccluded ray (the standard walk is always traced, for the answers).
    pub change: Option<Change>,
    pub prediction: Option<Prediction>,
    /// (threads, Mrays/s) over all frames, best of `reps`.
    pub mrays_per_s: Vec<(usize, f64)>,
    /// (threads, percent) change of traversal time against `standard`.
    pub time_change: Vec<(usize, f64)>,
}

/// Percent changes against the standard walk.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Change {
    pub nodes_occluded: f64,
    pub triangles_occluded: f64,
    pub nodes_unoccluded: f64,
    pub triangles_unoccluded: f64,
}

impl Change {
    fn of(b: &ByOcclusion, by: &ByOcclusion) -> Change {
        Change {
            nodes_occluded: pct(b.nodes_per_occluded_ray, by.nodes_per_occluded_ray),
            triangles_occluded: pct(b.triangles_per_occluded_ray, by.triangles_per_occluded_ray),
            nodes_unoccluded: pct(b.nodes_per_unoccluded_ray, by.nodes_per_unoccluded_ray),
            triangles_unoccluded: pct(
                b.triangles_per_unoccluded_ray,
                by.triangles_per_unoccluded_ray,
            ),
        }
    }
}

/// Every variant over one scene.
#[derive(Clone, Debug, Serialize)]
pub struct ShadowSceneResult {
    pub scene: String,
    pub triangles: usize,
    pub closed_box: bool,
    pub lights: usize,
    pub light_source: &'static str,
    pub frames: usize,
    pub rays_per_frame: Vec<usize>,
    pub variants: Vec<VariantResult>,
}

fn pct(new: f64, old: f64) -> f64 {
    if old == 0.0 {
        0.0
    } else {
        100.0 * (new - old) / old
    }
}

/// Builds each of `structures` (of [`SHADOW_STRUCTURES`]) for each of `variants` over
/// `scene` and traces its frames (module docs), checking every answer against the structure's
/// standard walk and the KD-tree's; `progress` hears what is being done.
pub fn run(
    scene: &BenchScene,
    structures: &[&str],
    variants: &[ShadowVariant],
    opts: &ShadowOptions,
    build: &BuildOptions,
    progress: &dyn Fn(&str),
) -> Result<ShadowSceneResult, Error> {
    if let Some(s) = structures.iter().find(|s| !SHADOW_STRUCTURES.contains(s)) {
        return Err(Error::Invalid(format!(
            "--shadow-variant runs on {} (not {s:?})",
            SHADOW_STRUCTURES.join(", ")
        )));
    }
    let kd = KdTree::build(&scene.tris);
    let setup = ShadowSetup::new(scene, &kd, &scene.lights, opts);
    progress(&format!(
        "{} frames, {} shadow rays, {} lights ({})",
        setup.frames.len(),
        setup.rays(),
        setup.lights.len(),
        setup.light_source
    ));
    let lights = setup.light_points();
    let prep = ShadowPrep {
        visible: &setup.visible,
        lights: &lights,
        params: opts.params,
    };
    // The KD-tree's standard answers: every structure's must be these.
    let kd_answers = trace_frames(
        &KdShadow::new(&kd, ShadowVariant::Standard, &prep),
        ShadowVariant::Standard,
        &setup,
    )
    .answers;
    let plain = if structures.contains(&"oavm") {
        Some(OavmAccel::build_walk(&scene.mesh, build, Walk::TopDown)?)
    } else {
        None
    };
    let mut results: Vec<VariantResult> = Vec::new();
    for &structure in structures {
        let make = |v: ShadowVariant| -> Result<Box<dyn ShadowStructure + '_>, Error> {
            Ok(match (structure, &plain) {
                ("oavm", Some(plain)) => Box::new(OavmShadow::new(plain, v, &opts.params)?),
                _ => Box::new(KdShadow::new(&kd, v, &prep)),
            })
        };
        // The structure's own standard walk: the reference its variants are measured against.
        let reference = trace_frames(
            make(ShadowVariant::Standard)?.as_ref(),
            ShadowVariant::Standard,
            &setup,
        );
        let standard = ByOcclusion::of(&reference.split);
        let first = results.len();
        for &v in variants {
            let s = make(v)?;
            let pre = s.precompute();
            progress(&format!(
                "  {structure} {}: prepared in {:.3} s",
                v.name(),
                pre.seconds
            ));
            let traced = trace_frames(s.as_ref(), v, &setup);
            let differ = |b: &[Vec<u8>]| -> u64 {
                traced
                    .answers
                    .iter()
                    .zip(b)
                    .map(|(a, b)| a.iter().zip(b).filter(|(x, y)| x != y).count() as u64)
                    .sum()
            };
            let speeds = super::bench::best_speeds(&opts.threads, opts.reps, setup.rays(), || {
                trace_frames(s.as_ref(), v, &setup);
            })?;
            let all = traced.split[0] + traced.split[1];
            let per = |x: u64| x as f64 / all.rays.max(1) as f64;
            let by = ByOcclusion::of(&traced.split);
            results.push(VariantResult {
                variant: v,
                structure: if structure == "oavm" {
                    "oavm"
                } else {
                    "kdtree"
                },
                precompute: pre,
                rays: all.rays,
                occluded: traced.split[1].rays,
                disagree_with_standard: differ(&reference.answers),
                disagree_with_kdtree: differ(&kd_answers),
                change: Some(Change::of(&by, &standard)),
                by_occlusion: by,
                promoted_tested_per_ray: per(all.promoted_tested),
                links_followed_per_ray: per(all.ropes_followed),
                restarts_per_ray: per(all.restarts),
                prediction: traced.prediction,
                mrays_per_s: speeds,
                time_change: Vec::new(),
            });
        }
        // Time is the inverse of speed (measured only if standard was asked for).
        let ours = &mut results[first..];
        let standard_speeds = ours
            .iter()
            .find(|r| r.variant == ShadowVariant::Standard)
            .map(|r| r.mrays_per_s.clone())
            .unwrap_or_default();
        for r in ours {
            r.time_change = r
                .mrays_per_s
                .iter()
                .filter_map(|&(th, m)| {
                    let (_, s) = standard_speeds.iter().find(|(t, _)| *t == th)?;
                    Some((th, pct(*s / m, 1.0)))
                })
                .collect();
        }
    }
    Ok(ShadowSceneResult {
        scene: String::new(),
        triangles: scene.tris.len(),
        closed_box: opts.closed_box,
        lights: setup.lights.len(),
        light_source: setup.light_source,
        frames: setup.frames.len(),
        rays_per_frame: setup.frames.iter().map(|f| f.rays.len()).collect(),
        variants: results,
    })
}

/// Rays of a ray file that share a prediction (`multi` in batch mode): the file's order stands
/// for the screen's, as a renderer writes its shadow rays pixel by pixel.
pub const BATCH_TILE: usize = 64;

/// What batch mode reports.
#[derive(Clone, Debug, Serialize)]
pub struct ShadowBatchResult {
    pub structure: &'static str,
    pub variant: ShadowVariant,
    pub rays: usize,
    pub occluded: usize,
    pub seconds: f64,
    pub mrays_per_s: f64,
    pub threads: usize,
    pub precompute: PrecomputeReport,
    pub nodes_visited: u64,
    pub triangles_tested: u64,
    /// Rays answered otherwise than by the KD-tree's standard walk (must be 0).
    pub disagree_with_standard: usize,
    pub prediction: Option<Prediction>,
}

/// Batch mode: any-hit answers of a ray file through the KD-tree by `variant`, checked against
/// the standard walk. With no frames to learn from, `multi` is prepared from the rays
/// themselves (their starts stand for the visible points, their distinct ends, up to 64, for
/// the lights), and predicts each run of [`BATCH_TILE`] rays from the first of the run, traced
/// first by the standard walk.
pub fn batch_file(
    scene: &BenchScene,
    structure: &str,
    variant: ShadowVariant,
    rays: &[Ray],
    params: ShadowParams,
    build: &BuildOptions,
) -> Result<(ShadowBatchResult, Vec<u8>), Error> {
    let kd = KdTree::build(&scene.tris);
    let visible: Vec<[f32; 3]> = rays.iter().take(1 << 20).map(|r| r.origin).collect();
    let mut lights: Vec<[f32; 3]> = Vec::new();
    for r in rays.iter().filter(|r| r.tmax.is_finite()) {
        let e = r.at(r.tmax as f64).map(|x| x as f32);
        if !lights.contains(&e) {
            lights.push(e);
            if lights.len() == 64 {
                break;
            }
        }
    }
    let prep = ShadowPrep {
        visible: &visible,
        lights: &lights,
        params,
    };
    let plain;
    let s: Box<dyn ShadowStructure + '_> = if structure == "oavm" {
        plain = OavmAccel::build_walk(&scene.mesh, build, Walk::TopDown)?;
        Box::new(OavmShadow::new(&plain, variant, &params)?)
    } else {
        Box::new(KdShadow::new(&kd, variant, &prep))
    };
    let t = Instant::now();
    let mut out = vec![0u8; rays.len()];
    let (c, pred) = rays
        .par_chunks(BATCH_TILE)
        .zip(out.par_chunks_mut(BATCH_TILE))
        .map(|(rays, out)| {
            let mut c = Counters::default();
            let mut p = Prediction::default();
            let guess = (variant == ShadowVariant::Multi).then(|| {
                p.warmup_rays += 1;
                s.occluded_by(&rays[0], ShadowWalk::Standard, &mut c)
            });
            for (r, o) in rays.iter().zip(out) {
                let walk = match (variant, guess) {
                    (ShadowVariant::Standard, _) => ShadowWalk::Standard,
                    (ShadowVariant::Sato, _) => ShadowWalk::Sato,
                    (_, Some(false)) => ShadowWalk::Adjacency,
                    _ => ShadowWalk::Primitive,
                };
                c.rays += 1;
                *o = s.occluded_by(r, walk, &mut c) as u8;
                if let Some(g) = guess {
                    p.predicted += 1;
                    p.correct += (g as u8 == *o) as u64;
                    p.primitive_walks += g as u64;
                    p.adjacency_walks += !g as u64;
                }
            }
            (c, p)
        })
        .reduce(
            || (Counters::default(), Prediction::default()),
            |a, b| {
                (
                    a.0 + b.0,
                    Prediction {
                        predicted: a.1.predicted + b.1.predicted,
                        correct: a.1.correct + b.1.correct,
                        accuracy: 0.0,
                        primitive_walks: a.1.primitive_walks + b.1.primitive_walks,
                        adjacency_walks: a.1.adjacency_walks + b.1.adjacency_walks,
                        warmup_rays: a.1.warmup_rays + b.1.warmup_rays,
                    },
                )
            },
        );
    let seconds = t.elapsed().as_secs_f64();
    let mut reference = vec![0u8; rays.len()];
    super::occluded_batch(&kd, rays, &mut reference);
    let prediction = (variant == ShadowVariant::Multi).then(|| Prediction {
        accuracy: pred.correct as f64 / pred.predicted.max(1) as f64,
        ..pred
    });
    let result = ShadowBatchResult {
        structure: if structure == "oavm" {
            "oavm"
        } else {
            "kdtree"
        },
        variant,
        rays: rays.len(),
        occluded: out.iter().filter(|&&o| o == 1).count(),
        seconds,
        mrays_per_s: rays.len() as f64 / seconds.max(1e-12) / 1e6,
        threads: rayon::current_num_threads(),
        precompute: s.precompute(),
        nodes_visited: c.nodes_visited,
        triangles_tested: c.triangles_tested,
        disagree_with_standard: out.iter().zip(&reference).filter(|(a, b)| a != b).count(),
        prediction,
    };
    Ok((result, out))
}
