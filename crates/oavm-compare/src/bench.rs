//! The OAVM paper's comparison (its Table 2 and Figs. 7-8), measured on our code: every structure
//! of [`STRUCTURES`] built from the same triangles and traced with the same three ray sets
//! (primary rays of the scene's camera, random rays through its box, shadow rays from the
//! primary hits), every answer checked against OAVM's by the agreement rule of `RAYS.md`
//! ([`Hit::agrees`]; any-hit answers exactly), each set timed as the best of `reps` runs per
//! thread count. Batch mode ([`batch`]) traces a given ray file through one structure.
//!
//! `oavm-bench` is this module's command line: it parses arguments into [`Options`], calls
//! [`bench_scene`] or [`batch`], and prints the [`Serialize`] results.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::{
    Accelerator, KD_VARIANTS, OAVM_VARIANTS, OavmAccel, STRUCTURES, StructureStats, Triangles,
};
use crate::Counters;
use oavm::error::Error;
use oavm::geom::{Hit, Ray};
use oavm::mesh::Mesh;
use oavm::pack::BuildOptions;
use oavm::rays::{self, Bounds, Camera};

/// A set fails when more than this fraction of its rays (0.01 %) disagree with OAVM.
pub const MAX_DISAGREEMENT: f64 = 1e-4;

/// Whether `disagree` of `rays` is more than [`MAX_DISAGREEMENT`] allows.
pub fn too_many(disagree: usize, rays: usize) -> bool {
    disagree as f64 > MAX_DISAGREEMENT * rays as f64
}

/// What to measure.
#[derive(Clone, Debug, Serialize)]
pub struct Options {
    /// OAVM's and the classic octree's subdivision (`K`, `D`).
    #[serde(rename = "options")]
    pub build: BuildOptions,
    /// Random rays per scene.
    pub random: usize,
    /// Primary (camera) image size.
    pub width: u32,
    pub height: u32,
    /// Timed runs per measurement; the best is kept.
    pub reps: usize,
    /// Thread counts to measure with.
    pub threads: Vec<usize>,
}

/// The structures named by `list` (names of [`STRUCTURES`], [`KD_VARIANTS`] or
/// [`OAVM_VARIANTS`], or `all`: the
/// structures), in the order given, repeats next to each other dropped; `kdtree:stack` is
/// `kdtree`.
pub fn parse_structures(list: &[String]) -> Result<Vec<&'static str>, Error> {
    let mut names: Vec<&'static str> = Vec::new();
    for s in list {
        match s.as_str() {
            "all" => names.extend(STRUCTURES),
            "kdtree:stack" => names.push("kdtree"),
            n => match STRUCTURES
                .iter()
                .chain(&KD_VARIANTS)
                .chain(&OAVM_VARIANTS)
                .find(|&&k| k == n)
            {
                Some(&k) => names.push(k),
                None => {
                    return Err(Error::Invalid(format!(
                        "unknown structure {n:?}: expected all or one of {}, {}, {}",
                        STRUCTURES.join(", "),
                        KD_VARIANTS.join(", "),
                        OAVM_VARIANTS.join(", ")
                    )));
                }
            },
        }
    }
    names.dedup();
    Ok(names)
}

/// The answers of one structure to one ray set: closest hits, or any-hit answers (1 or 0).
#[derive(Clone, Debug, PartialEq)]
pub enum Answers {
    Closest(Vec<Hit>),
    Any(Vec<u8>),
}

impl Answers {
    /// Traces `rays` through `acc` on the current rayon pool: any hit if `any`, else closest.
    pub fn trace(acc: &dyn Accelerator, rays: &[Ray], any: bool) -> (Counters, Answers) {
        if any {
            let mut occ = vec![0u8; rays.len()];
            let c = super::occluded_batch(acc, rays, &mut occ);
            (c, Answers::Any(occ))
        } else {
            let mut hits = vec![Hit::MISS; rays.len()];
            let c = super::intersect_batch(acc, rays, &mut hits);
            (c, Answers::Closest(hits))
        }
    }

    /// Rays that hit something.
    pub fn hits(&self) -> usize {
        match self {
            Answers::Closest(h) => h.iter().filter(|h| h.is_hit()).count(),
            Answers::Any(o) => o.iter().filter(|&&o| o == 1).count(),
        }
    }

    /// Rays answered differently from `reference` (closest hits by [`Hit::agrees`] with the
    /// scene's `diagonal`, any-hit answers exactly); answers of another kind or length disagree
    /// everywhere.
    pub fn disagreements(&self, reference: &Answers, diagonal: f64) -> usize {
        match (self, reference) {
            (Answers::Closest(a), Answers::Closest(b)) if a.len() == b.len() => a
                .iter()
                .zip(b)
                .filter(|(a, b)| !a.agrees(b, diagonal))
                .count(),
            (Answers::Any(a), Answers::Any(b)) if a.len() == b.len() => {
                a.iter().zip(b).filter(|(a, b)| a != b).count()
            }
            _ => self.len().max(reference.len()),
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Answers::Closest(h) => h.len(),
            Answers::Any(o) => o.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A scene to measure: its mesh and triangles, and for a BART AFF scene its own camera (the
/// animated camera path at the first frame, else the `v` block) and first light.
pub struct BenchScene {
    pub mesh: Mesh,
    pub tris: Triangles,
    pub bounds: Bounds,
    pub view: Option<(Camera, Option<[f32; 3]>)>,
    /// A BART scene's point lights, all of them (none for a mesh).
    pub lights: Vec<[f32; 3]>,
}

impl BenchScene {
    /// Loads a .ply, .obj or .aff file.
    pub fn load(path: &Path) -> Result<BenchScene, Error> {
        let is_aff = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("aff"));
        let mut lights = Vec::new();
        let (mesh, view) = if is_aff {
            let aff = oavm::mesh::load_aff(path, None)?;
            lights = aff.lights.iter().map(|l| l.map(|c| c as f32)).collect();
            let view = match aff.camera_path.or(aff.view) {
                Some(v) => {
                    let cam = Camera::look_at(v.from, v.at, v.up, v.angle_deg).map_err(|e| {
                        Error::Invalid(format!("{}: viewpoint: {e}", path.display()))
                    })?;
                    let light = aff.lights.first().map(|l| l.map(|c| c as f32));
                    Some((cam, light))
                }
                None => None,
            };
            (aff.mesh, view)
        } else {
            (oavm::mesh::load(path)?, None)
        };
        let tris = Triangles::from_mesh(&mesh)?;
        let bounds = Bounds::of_points(tris.v.iter().flatten().copied());
        Ok(BenchScene {
            mesh,
            tris,
            bounds,
            view,
            lights,
        })
    }

    /// The diagonal of the triangles' box: the scale of the agreement rule.
    pub fn diagonal(&self) -> f64 {
        self.bounds.diagonal()
    }

    /// `"scene"` for a scene traced from its own camera, `"framing"` for the default camera.
    pub fn camera_kind(&self) -> &'static str {
        if self.view.is_some() {
            "scene"
        } else {
            "framing"
        }
    }

    pub fn camera(&self) -> Camera {
        match &self.view {
            Some((cam, _)) => *cam,
            None => Camera::framing(&self.bounds),
        }
    }
}

/// One set of rays the structures are measured on.
pub struct RaySet {
    pub name: &'static str,
    pub rays: Vec<Ray>,
    /// Any-hit queries (shadow rays), else closest hit.
    pub any: bool,
}

/// The three ray sets of `scene`: `primary` (the camera, `width` x `height`), `random`
/// (`random` rays through the box, seed 1) and `shadow` (from every primary hit of `oavm` toward
/// the light of [`shadow_light`]).
pub fn ray_sets(scene: &BenchScene, oavm: &OavmAccel, opts: &Options) -> Vec<RaySet> {
    let camera = scene.camera();
    let primary = camera.primary_rays(opts.width, opts.height);
    let mut primary_hits = vec![Hit::MISS; primary.len()];
    super::intersect_batch(oavm, &primary, &mut primary_hits);
    let scene_light = scene.view.as_ref().map(|(_, light)| *light);
    let light = shadow_light(
        oavm,
        &camera,
        scene_light,
        &primary,
        &primary_hits,
        &scene.bounds,
    );
    let shadow = rays::shadow_rays(&primary, &primary_hits, light);
    vec![
        RaySet {
            name: "primary",
            rays: primary,
            any: false,
        },
        RaySet {
            name: "random",
            rays: rays::random_rays(&scene.bounds, opts.random, 1),
            any: false,
        },
        RaySet {
            name: "shadow",
            rays: shadow,
            any: true,
        },
    ]
}

/// The light of the shadow rays. Framed scenes: the default light. A BART scene: its first light,
/// unless that leaves (nearly) every primary hit in shadow, as the robots' light does (it is above
/// the roof of the box that encloses their city); then, as without a light, a light halfway
/// between the camera and the point its central ray hits, which sees much of the image and
/// leaves the rest in the shadow of what stands between.
pub fn shadow_light(
    oavm: &OavmAccel,
    camera: &Camera,
    scene_light: Option<Option<[f32; 3]>>,
    primary: &[Ray],
    hits: &[Hit],
    b: &Bounds,
) -> [f32; 3] {
    let Some(light) = scene_light else {
        return rays::default_light(b);
    };
    if let Some(l) = light {
        let shadow = rays::shadow_rays(primary, hits, l);
        let lit = Answers::trace(oavm, &shadow, true).1.hits();
        let lit = shadow.len() - lit;
        if lit as f64 >= 0.01 * shadow.len() as f64 {
            return l;
        }
    }
    let eye = camera.eye.map(|c| c as f32);
    let dir: [f32; 3] = std::array::from_fn(|k| (camera.target[k] - camera.eye[k]) as f32);
    let centre = Ray::new(eye, dir, 0.0, f32::INFINITY);
    let hit = oavm.intersect(&centre, &mut Counters::default());
    if hit.is_hit() {
        std::array::from_fn(|k| eye[k] + 0.5 * hit.t * dir[k])
    } else {
        eye
    }
}

/// The figures of one ray set through one structure.
#[derive(Clone, Debug, Serialize)]
pub struct SetResult {
    pub set: &'static str,
    pub rays: usize,
    /// Rays answered differently from OAVM ([`Answers::disagreements`]).
    pub disagree_with_oavm: usize,
    pub hits: usize,
    pub nodes_visited_per_ray: f64,
    pub leaves_visited_per_ray: f64,
    pub triangles_tested_per_ray: f64,
    /// Walks begun again per ray (the KD-tree's restart, push-down and short-stack walks; its
    /// rope walks count each rope taken here; 0 for the others).
    pub restarts_per_ray: f64,
    /// Ropes followed per ray by OAVM's rope walk (`oavm:ropes`; 0 for the others, the
    /// KD-tree's rope walks count theirs in `restarts_per_ray`).
    pub ropes_per_ray: f64,
    /// Any-hit sets: the work per ray of the rays found occluded and of those found
    /// unoccluded, apart (absent for closest-hit sets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub by_occlusion: Option<ByOcclusion>,
    /// (threads, Mrays/s), best of `reps`.
    pub mrays_per_s: Vec<(usize, f64)>,
}

/// Node and triangle tests per ray of an any-hit set's occluded and unoccluded rays (the
/// multi-index tree's measures, Liang and Huang 2019).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ByOcclusion {
    pub occluded_rays: u64,
    pub unoccluded_rays: u64,
    pub nodes_per_occluded_ray: f64,
    pub triangles_per_occluded_ray: f64,
    pub nodes_per_unoccluded_ray: f64,
    pub triangles_per_unoccluded_ray: f64,
}

impl ByOcclusion {
    pub(crate) fn of(split: &[Counters; 2]) -> ByOcclusion {
        let per = |x: u64, c: &Counters| x as f64 / c.rays.max(1) as f64;
        ByOcclusion {
            occluded_rays: split[1].rays,
            unoccluded_rays: split[0].rays,
            nodes_per_occluded_ray: per(split[1].nodes_visited, &split[1]),
            triangles_per_occluded_ray: per(split[1].triangles_tested, &split[1]),
            nodes_per_unoccluded_ray: per(split[0].nodes_visited, &split[0]),
            triangles_per_unoccluded_ray: per(split[0].triangles_tested, &split[0]),
        }
    }
}

/// One structure over one scene.
#[derive(Clone, Debug, Serialize)]
pub struct StructureResult {
    #[serde(flatten)]
    pub stats: StructureStats,
    pub build_ms: f64,
    pub sets: Vec<SetResult>,
}

/// Every structure over one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneResult {
    pub scene: String,
    pub path: String,
    pub input_triangles: usize,
    pub triangles: usize,
    pub diagonal: f64,
    /// "scene": a BART scene's own camera (its animated camera at the first frame, else its `v`
    /// block) and its first light (see [`shadow_light`]); "framing": the default camera and light
    /// around the bounds.
    pub camera: &'static str,
    pub structures: Vec<StructureResult>,
}

impl SceneResult {
    /// The sets whose disagreements with OAVM are more than [`MAX_DISAGREEMENT`] allows, one
    /// line each.
    pub fn failures(&self) -> Vec<String> {
        let mut out = Vec::new();
        for s in &self.structures {
            for set in &s.sets {
                if too_many(set.disagree_with_oavm, set.rays) {
                    out.push(format!(
                        "{} {} {}: {} of {} rays disagree with OAVM",
                        self.scene, s.stats.name, set.set, set.disagree_with_oavm, set.rays
                    ));
                }
            }
        }
        out
    }
}

/// Everything one run measured.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The file format OAVM was built in (spec §2 `version`): what a page of these figures
    /// says it measured.
    pub format_version: u32,
    #[serde(flatten)]
    pub options: Options,
    pub scenes: Vec<SceneResult>,
}

/// The name of a scene: its file name without the extension.
pub fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// Measures the structures `names` (of [`STRUCTURES`]) over the scene at `path`; `progress`
/// hears what is being done.
pub fn bench_scene(
    path: &Path,
    names: &[&str],
    opts: &Options,
    progress: &dyn Fn(&str),
) -> Result<SceneResult, Error> {
    let scene = BenchScene::load(path)?;
    let diag = scene.diagonal();
    progress(&format!(
        "{}: {} triangles",
        path.display(),
        scene.mesh.triangles.len()
    ));
    // OAVM first: every other structure is checked against it.
    let oavm = OavmAccel::build(&scene.mesh, &opts.build)?;
    let sets = ray_sets(&scene, &oavm, opts);
    let reference: Vec<Answers> = sets
        .iter()
        .map(|s| Answers::trace(&oavm, &s.rays, s.any).1)
        .collect();

    let mut structures = Vec::new();
    for &name in names {
        let t = Instant::now();
        let acc = super::build_structure(name, &scene.mesh, &scene.tris, &opts.build)?;
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!("  {name}: built in {build_ms:.1} ms"));
        let mut set_results = Vec::new();
        for (set, reference) in sets.iter().zip(&reference) {
            let (c, answers, by_occlusion) = if set.any {
                let mut occ = vec![0u8; set.rays.len()];
                let split = super::occluded_batch_split(acc.as_ref(), &set.rays, &mut occ);
                (
                    split[0] + split[1],
                    Answers::Any(occ),
                    Some(ByOcclusion::of(&split)),
                )
            } else {
                let (c, answers) = Answers::trace(acc.as_ref(), &set.rays, false);
                (c, answers, None)
            };
            let per = |x: u64| x as f64 / c.rays.max(1) as f64;
            set_results.push(SetResult {
                set: set.name,
                rays: set.rays.len(),
                disagree_with_oavm: answers.disagreements(reference, diag),
                hits: answers.hits(),
                nodes_visited_per_ray: per(c.nodes_visited),
                leaves_visited_per_ray: per(c.leaves_visited),
                triangles_tested_per_ray: per(c.triangles_tested),
                restarts_per_ray: per(c.restarts),
                ropes_per_ray: per(c.ropes_followed),
                by_occlusion,
                mrays_per_s: speeds(acc.as_ref(), set, opts)?,
            });
        }
        structures.push(StructureResult {
            stats: acc.stats().clone(),
            build_ms,
            sets: set_results,
        });
    }
    Ok(SceneResult {
        scene: scene_name(path),
        path: path.display().to_string(),
        input_triangles: scene.mesh.triangles.len(),
        triangles: scene.tris.len(),
        diagonal: diag,
        camera: scene.camera_kind(),
        structures,
    })
}

/// (threads, Mrays/s) of `set` through `acc` for every thread count, best of `reps` runs.
fn speeds(acc: &dyn Accelerator, set: &RaySet, opts: &Options) -> Result<Vec<(usize, f64)>, Error> {
    best_speeds(&opts.threads, opts.reps, set.rays.len(), || {
        Answers::trace(acc, &set.rays, set.any);
    })
}

/// (threads, Mrays/s) of `run`, which traces `rays` rays, on a pool of each thread count, best
/// of `reps` runs.
pub(crate) fn best_speeds(
    threads: &[usize],
    reps: usize,
    rays: usize,
    run: impl Fn() + Sync,
) -> Result<Vec<(usize, f64)>, Error> {
    let mut out = Vec::new();
    for &threads in threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| Error::Invalid(format!("cannot start {threads} threads: {e}")))?;
        let best = (0..reps.max(1))
            .map(|_| {
                let t = Instant::now();
                pool.install(&run);
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min);
        out.push((threads, rays as f64 / best / 1e6));
    }
    Ok(out)
}

/// What batch mode reports: one structure, one ray file.
#[derive(Clone, Debug, Serialize)]
pub struct BatchResult {
    pub structure: &'static str,
    pub rays: usize,
    /// Closest-hit batches: rays that hit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hits: Option<usize>,
    /// Any-hit batches: rays occluded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occluded: Option<usize>,
    pub seconds: f64,
    pub mrays_per_s: f64,
    pub threads: usize,
    pub build_ms: f64,
    pub nodes_visited: u64,
    pub triangles_tested: u64,
    pub disagree_with_oavm: usize,
}

impl BatchResult {
    /// Why the batch failed its check against OAVM, if it did.
    pub fn failure(&self) -> Option<String> {
        too_many(self.disagree_with_oavm, self.rays).then(|| {
            format!(
                "DISAGREEMENT: {} of {} rays differ from OAVM",
                self.disagree_with_oavm, self.rays
            )
        })
    }
}

/// Batch mode: traces `rays` through the structure `name` built over the scene at `path` (any
/// hit if `any`, else closest), timed once on the current rayon pool, and checks the answers
/// against OAVM's.
pub fn batch(
    path: &Path,
    name: &'static str,
    rays: &[Ray],
    any: bool,
    build: &BuildOptions,
) -> Result<(BatchResult, Answers), Error> {
    let scene = BenchScene::load(path)?;
    let acc = super::build_structure(name, &scene.mesh, &scene.tris, build)?;
    let oavm = OavmAccel::build(&scene.mesh, build)?;
    let t = Instant::now();
    let (c, answers) = Answers::trace(acc.as_ref(), rays, any);
    let seconds = t.elapsed().as_secs_f64();
    let (_, reference) = Answers::trace(&oavm, rays, any);
    let hits = answers.hits();
    let result = BatchResult {
        structure: name,
        rays: rays.len(),
        hits: (!any).then_some(hits),
        occluded: any.then_some(hits),
        seconds,
        mrays_per_s: rays.len() as f64 / seconds.max(1e-12) / 1e6,
        threads: rayon::current_num_threads(),
        build_ms: acc.stats().build_seconds * 1e3,
        nodes_visited: c.nodes_visited,
        triangles_tested: c.triangles_tested,
        disagree_with_oavm: answers.disagreements(&reference, scene.diagonal()),
    };
    Ok((result, answers))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{tris_of, unit_rays, unit_soup};

    /// A structure that answers like another except on every `n`-th call: a miss instead of a
    /// closest hit, the opposite any-hit answer.
    struct Faulty<'a> {
        inner: &'a dyn Accelerator,
        every: u64,
    }

    impl Accelerator for Faulty<'_> {
        fn stats(&self) -> &StructureStats {
            self.inner.stats()
        }
        fn intersect(&self, ray: &Ray, c: &mut Counters) -> Hit {
            let h = self.inner.intersect(ray, c);
            if (ray.origin[0].to_bits() as u64).is_multiple_of(self.every) {
                Hit::MISS
            } else {
                h
            }
        }
        fn occluded(&self, ray: &Ray, c: &mut Counters) -> bool {
            let o = self.inner.occluded(ray, c);
            o ^ (ray.origin[0].to_bits() as u64).is_multiple_of(self.every)
        }
    }

    /// The check against OAVM counts exactly the rays a structure gets wrong.
    #[test]
    fn disagreements_are_counted_ray_for_ray() {
        let (tris, mesh) = tris_of(unit_soup(400, 3));
        let opts = BuildOptions::default();
        let oavm = OavmAccel::build(&mesh, &opts).unwrap();
        let bvh = crate::bvh::Bvh::build(&tris);
        let rays = unit_rays(3000, 4);
        let diag = Bounds::of_points(tris.v.iter().flatten().copied()).diagonal();
        let bad = |r: &Ray| (r.origin[0].to_bits() as u64).is_multiple_of(3);
        let faulty = Faulty {
            inner: &bvh,
            every: 3,
        };
        for any in [false, true] {
            let (_, want) = Answers::trace(&oavm, &rays, any);
            let (_, good) = Answers::trace(&bvh, &rays, any);
            let (_, wrong) = Answers::trace(&faulty, &rays, any);
            assert!(want.hits() > 500, "{}", want.hits());
            assert_eq!(good.disagreements(&want, diag), 0);
            let expected = match &want {
                // Only the hits that became misses are wrong.
                Answers::Closest(h) => rays
                    .iter()
                    .zip(h)
                    .filter(|(r, h)| bad(r) && h.is_hit())
                    .count(),
                Answers::Any(_) => rays.iter().filter(|r| bad(r)).count(),
            };
            assert!(expected > 100, "{expected}");
            assert_eq!(wrong.disagreements(&want, diag), expected, "any: {any}");
            assert!(too_many(expected, rays.len()));
        }
        // Answers of another kind never agree.
        let (_, closest) = Answers::trace(&bvh, &rays, false);
        let (_, any) = Answers::trace(&bvh, &rays, true);
        assert_eq!(closest.disagreements(&any, diag), rays.len());
        // A closest hit moved by more than the tolerance disagrees; within it, it agrees.
        let h = Hit { t: 1.0, prim: 0 };
        let near = Answers::Closest(vec![Hit {
            t: 1.0 + 0.5e-4,
            ..h
        }]);
        let far = Answers::Closest(vec![Hit { t: 1.0 + 2e-4, ..h }]);
        let one = Answers::Closest(vec![h]);
        assert_eq!(near.disagreements(&one, 1.0), 0);
        assert_eq!(far.disagreements(&one, 1.0), 1);
    }

    #[test]
    fn structures_are_parsed_in_order_with_all() {
        let names =
            |v: &[&str]| parse_structures(&v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        assert_eq!(names(&["all"]).unwrap(), STRUCTURES);
        assert_eq!(names(&["bvh", "bvh", "grid"]).unwrap(), ["bvh", "grid"]);
        assert_eq!(
            names(&[
                "kdtree:stack",
                "kdtree:restart",
                "kdtree:pushdown",
                "kdtree:shortstack"
            ])
            .unwrap(),
            [
                "kdtree",
                "kdtree:restart",
                "kdtree:pushdown",
                "kdtree:shortstack"
            ]
        );
        let e = names(&["octtree"]).unwrap_err().to_string();
        assert!(
            e.contains("unknown structure") && e.contains("kdtree"),
            "{e}"
        );
    }
}
