//! `oavm-bench SCENE...`: the OAVM paper's comparison, on our code and the same rays: a uniform
//! grid, the SAH KD-tree, the classic octree, a binned-SAH BVH and OAVM, built from the same
//! triangles, traced with the same primary, random and shadow rays, every answer checked against
//! OAVM's.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use oavm::build::{self, BuildOptions};
mod cli;

use cli::main_with;
use oavm::compare::{self, Accelerator, Triangles};
use oavm::rays::{self, Bounds, Camera};
use oavm::{Counters, Error, Hit, Ray};
use serde::Serialize;

/// Builds the structures of the OAVM paper's comparison over each scene and traces the same rays
/// through all of them.
#[derive(Parser, Debug)]
#[command(name = "oavm-bench", version)]
struct Args {
    /// Scenes: .ply, .obj or .aff files.
    #[arg(required = true)]
    scenes: Vec<PathBuf>,
    /// Structures to build: grid, kdtree, octree, bvh, oavm or all (repeat or separate by commas).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    structure: Vec<String>,
    /// Random rays per scene.
    #[arg(long, default_value_t = 1_000_000)]
    random: usize,
    /// Primary (camera) image size.
    #[arg(long, default_value_t = 1024)]
    width: u32,
    #[arg(long, default_value_t = 768)]
    height: u32,
    /// Timed runs per measurement; the best is kept.
    #[arg(long, default_value_t = 3)]
    reps: usize,
    /// Thread counts to measure with.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    threads: Vec<usize>,
    /// OAVM's and the classic octree's leaf size K.
    #[arg(long, default_value_t = build::DEFAULT_LEAF_SIZE)]
    leaf_size: u32,
    /// OAVM's and the classic octree's maximum depth D.
    #[arg(long, default_value_t = build::DEFAULT_MAX_DEPTH)]
    max_depth: u32,
    /// Batch mode: trace this RAYS file through the one --structure given.
    #[arg(long, value_name = "RAYS")]
    rays: Option<PathBuf>,
    /// Batch mode: write closest hits here (HITS file).
    #[arg(
        long,
        value_name = "HITS",
        requires = "rays",
        conflicts_with = "occluded"
    )]
    hits: Option<PathBuf>,
    /// Batch mode: write any-hit answers here (OCCL file).
    #[arg(long, value_name = "OCCL", requires = "rays")]
    occluded: Option<PathBuf>,
    /// Print one JSON object with every figure.
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct SetResult {
    set: &'static str,
    rays: usize,
    /// Rays answered differently from OAVM (closest: hit/miss or t beyond 1e-4 of the diagonal).
    disagree_with_oavm: usize,
    hits: usize,
    nodes_visited_per_ray: f64,
    leaves_visited_per_ray: f64,
    triangles_tested_per_ray: f64,
    /// (threads, Mrays/s), best of `reps`.
    mrays_per_s: Vec<(usize, f64)>,
}

#[derive(Serialize)]
struct StructureResult {
    #[serde(flatten)]
    stats: compare::StructureStats,
    build_ms: f64,
    sets: Vec<SetResult>,
}

#[derive(Serialize)]
struct SceneResult {
    scene: String,
    path: String,
    input_triangles: usize,
    triangles: usize,
    diagonal: f64,
    /// "scene": a BART scene's own camera (its animated camera at the first frame, else its `v`
    /// block) and its first light (see `shadow_light`); "framing": the default camera and light around the bounds.
    camera: &'static str,
    structures: Vec<StructureResult>,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    main_with("oavm-bench", || run(&args))
}

fn run(args: &Args) -> Result<(), Error> {
    let mut names: Vec<&str> = Vec::new();
    for s in &args.structure {
        match s.as_str() {
            "all" => names.extend(compare::STRUCTURES),
            n if compare::STRUCTURES.contains(&n) => names.push(n),
            n => {
                return Err(Error::Invalid(format!(
                    "unknown structure {n:?}: expected all or one of {}",
                    compare::STRUCTURES.join(", ")
                )));
            }
        }
    }
    names.dedup();
    let opts = BuildOptions {
        leaf_size: args.leaf_size,
        max_depth: args.max_depth,
        merge: true,
    };
    opts.validate()?;
    if args.rays.is_some() {
        return batch(args, &names, &opts);
    }

    let mut failed = Vec::new();
    let mut results = Vec::new();
    for path in &args.scenes {
        let r = bench_scene(args, path, &names, &opts)?;
        for s in &r.structures {
            for set in &s.sets {
                if set.disagree_with_oavm as f64 > 1e-4 * set.rays as f64 {
                    failed.push(format!(
                        "{} {} {}: {} of {} rays disagree with OAVM",
                        r.scene, s.stats.name, set.set, set.disagree_with_oavm, set.rays
                    ));
                }
            }
        }
        if !args.json {
            print_scene(&r)?;
        }
        results.push(r);
    }
    if args.json {
        let out = serde_json::json!({ "options": opts, "random": args.random, "width": args.width,
            "height": args.height, "reps": args.reps, "scenes": results });
        write_out(&(serde_json::to_string_pretty(&out).unwrap_or_default() + "\n"))?;
    }
    if !failed.is_empty() {
        for f in &failed {
            eprintln!("oavm-bench: DISAGREEMENT: {f}");
        }
        return Err(Error::Invalid(format!(
            "{} sets disagree with OAVM beyond 0.01 %",
            failed.len()
        )));
    }
    Ok(())
}

fn scene_name(path: &std::path::Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

fn bench_scene(
    args: &Args,
    path: &std::path::Path,
    names: &[&str],
    opts: &BuildOptions,
) -> Result<SceneResult, Error> {
    let (mesh, view) = load_scene(path)?;
    let tris = Triangles::from_mesh(&mesh)?;
    let b = Bounds::of_points(tris.v.iter().flatten().copied());
    let diag = b.diagonal();
    let (camera, scene_light, camera_kind) = match view {
        Some((cam, light)) => (cam, Some(light), "scene"),
        None => (Camera::framing(&b), None, "framing"),
    };
    eprintln!(
        "oavm-bench: {}: {} triangles",
        path.display(),
        mesh.triangles.len()
    );

    // OAVM first: every other structure is checked against it.
    let oavm = compare::OavmAccel::build(&mesh, opts)?;
    let primary = camera.primary_rays(args.width, args.height);
    let mut primary_hits = vec![Hit::MISS; primary.len()];
    compare::intersect_batch(&oavm, &primary, &mut primary_hits);
    let light = shadow_light(&oavm, &camera, scene_light, &primary, &primary_hits, &b);
    let sets: [(&'static str, Vec<Ray>, bool); 3] = [
        ("primary", primary.clone(), false),
        ("random", rays::random_rays(&b, args.random, 1), false),
        (
            "shadow",
            rays::shadow_rays(&primary, &primary_hits, light),
            true,
        ),
    ];
    let reference: Vec<(Vec<Hit>, Vec<u8>)> = sets
        .iter()
        .map(|(_, rays, any)| answers(&oavm, rays, *any).1)
        .collect();

    let mut structures = Vec::new();
    for &name in names {
        let t = Instant::now();
        let acc: Box<dyn Accelerator> = if name == "oavm" {
            Box::new(compare::OavmAccel::build(&mesh, opts)?)
        } else {
            compare::build_structure(name, &mesh, &tris, opts)?
        };
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        eprintln!("oavm-bench:   {name}: built in {build_ms:.1} ms");
        let mut set_results = Vec::new();
        for ((set, rays, any), (ref_hits, ref_occ)) in sets.iter().zip(&reference) {
            let (c, (hits, occ)) = answers(acc.as_ref(), rays, *any);
            let disagree = if *any {
                occ.iter().zip(ref_occ).filter(|(a, b)| a != b).count()
            } else {
                hits.iter()
                    .zip(ref_hits)
                    .filter(|(a, b)| !a.agrees(b, diag))
                    .count()
            };
            let mut mrays = Vec::new();
            for &threads in &args.threads {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .map_err(|e| Error::Invalid(format!("cannot start {threads} threads: {e}")))?;
                let best = (0..args.reps.max(1))
                    .map(|_| {
                        let t = Instant::now();
                        pool.install(|| answers(acc.as_ref(), rays, *any));
                        t.elapsed().as_secs_f64()
                    })
                    .fold(f64::INFINITY, f64::min);
                mrays.push((threads, rays.len() as f64 / best / 1e6));
            }
            let per = |x: u64| x as f64 / c.rays.max(1) as f64;
            set_results.push(SetResult {
                set,
                rays: rays.len(),
                disagree_with_oavm: disagree,
                hits: if *any {
                    occ.iter().filter(|&&o| o == 1).count()
                } else {
                    hits.iter().filter(|h| h.is_hit()).count()
                },
                nodes_visited_per_ray: per(c.nodes_visited),
                leaves_visited_per_ray: per(c.leaves_visited),
                triangles_tested_per_ray: per(c.triangles_tested),
                mrays_per_s: mrays,
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
        input_triangles: mesh.triangles.len(),
        triangles: tris.len(),
        diagonal: diag,
        camera: camera_kind,
        structures,
    })
}

/// The light of the shadow rays. Framed scenes: the default light. A BART scene: its first light,
/// unless that leaves (nearly) every primary hit in shadow, as the robots' light does (it is above
/// the roof of the box that encloses their city); then, as without a light, a light halfway
/// between the camera and the point its central ray hits, which sees much of the image and
/// leaves the rest in the shadow of what stands between.
fn shadow_light(
    oavm: &compare::OavmAccel,
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
        let mut occ = vec![0u8; shadow.len()];
        compare::occluded_batch(oavm, &shadow, &mut occ);
        let lit = occ.iter().filter(|&&o| o == 0).count();
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

/// A scene's mesh, and for a BART AFF scene its own camera (the animated camera path at the
/// first frame, else the `v` block) and first light.
type SceneView = Option<(Camera, Option<[f32; 3]>)>;

fn load_scene(path: &std::path::Path) -> Result<(oavm::mesh::Mesh, SceneView), Error> {
    let is_aff = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("aff"));
    if !is_aff {
        return Ok((oavm::mesh::load(path)?, None));
    }
    let aff = oavm::mesh::load_aff(path, None)?;
    let view = match aff.camera_path.or(aff.view) {
        Some(v) => {
            let cam = Camera::look_at(v.from, v.at, v.up, v.angle_deg)
                .map_err(|e| Error::Invalid(format!("{}: viewpoint: {e}", path.display())))?;
            let light = aff.lights.first().map(|l| l.map(|c| c as f32));
            Some((cam, light))
        }
        None => None,
    };
    Ok((aff.mesh, view))
}

/// Traces `rays` through `acc`: closest hits, or any-hit answers for `any`.
fn answers(acc: &dyn Accelerator, rays: &[Ray], any: bool) -> (Counters, (Vec<Hit>, Vec<u8>)) {
    if any {
        let mut occ = vec![0u8; rays.len()];
        let c = compare::occluded_batch(acc, rays, &mut occ);
        (c, (Vec::new(), occ))
    } else {
        let mut hits = vec![Hit::MISS; rays.len()];
        let c = compare::intersect_batch(acc, rays, &mut hits);
        (c, (hits, Vec::new()))
    }
}

fn print_scene(r: &SceneResult) -> Result<(), Error> {
    let mut t = format!(
        "\n{} ({} triangles, {} stored)\n{:<8} {:>10} {:>9} {:>9} {:>11}  {:<8} {:>10} {:>10} {:>10} {:>22}\n",
        r.scene,
        r.input_triangles,
        r.triangles,
        "struct",
        "build ms",
        "nodes",
        "pointers",
        "bytes",
        "rays",
        "nodes/ray",
        "tris/ray",
        "disagree",
        "Mrays/s (threads)"
    );
    for s in &r.structures {
        for (i, set) in s.sets.iter().enumerate() {
            let head = if i == 0 {
                format!(
                    "{:<8} {:>10.1} {:>9} {:>9} {:>11}",
                    s.stats.name, s.build_ms, s.stats.nodes, s.stats.pointers, s.stats.bytes
                )
            } else {
                format!("{:<8} {:>10} {:>9} {:>9} {:>11}", "", "", "", "", "")
            };
            let speed: Vec<String> = set
                .mrays_per_s
                .iter()
                .map(|(th, m)| format!("{m:.2} ({th})"))
                .collect();
            t.push_str(&format!(
                "{head}  {:<8} {:>10.2} {:>10.2} {:>10} {:>22}\n",
                set.set,
                set.nodes_visited_per_ray,
                set.triangles_tested_per_ray,
                set.disagree_with_oavm,
                speed.join(" ")
            ));
        }
    }
    write_out(&t)
}

/// Batch mode: one structure, one ray file, answers in the formats of RAYS.md, checked against
/// OAVM.
fn batch(args: &Args, names: &[&str], opts: &BuildOptions) -> Result<(), Error> {
    let (Some(rays_path), [name], [scene]) = (&args.rays, names, &args.scenes[..]) else {
        return Err(Error::Invalid(
            "--rays needs exactly one scene and exactly one --structure (not all)".into(),
        ));
    };
    if args.hits.is_none() && args.occluded.is_none() {
        return Err(Error::Invalid(
            "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
        ));
    }
    let (mesh, _) = load_scene(scene)?;
    let tris = Triangles::from_mesh(&mesh)?;
    let diag = Bounds::of_points(tris.v.iter().flatten().copied()).diagonal();
    let out_path = args
        .occluded
        .as_deref()
        .or(args.hits.as_deref())
        .unwrap_or(rays_path);
    let out = oavm::output::Output::create(out_path, &[scene, rays_path])?;
    let rays = rays::read_rays(rays_path, u32::MAX as u64)?;
    let acc = compare::build_structure(name, &mesh, &tris, opts)?;
    let oavm = compare::OavmAccel::build(&mesh, opts)?;
    let any = args.occluded.is_some();
    let t = Instant::now();
    let (c, (hits, occ)) = answers(acc.as_ref(), &rays, any);
    let seconds = t.elapsed().as_secs_f64();
    let (_, (ref_hits, ref_occ)) = answers(&oavm, &rays, any);
    let disagree = if any {
        rays::write_into(out, &occ)?;
        occ.iter().zip(&ref_occ).filter(|(a, b)| a != b).count()
    } else {
        rays::write_into(out, &hits)?;
        hits.iter()
            .zip(&ref_hits)
            .filter(|(a, b)| !a.agrees(b, diag))
            .count()
    };
    let answered = if any {
        occ.iter().filter(|&&o| o == 1).count()
    } else {
        hits.iter().filter(|h| h.is_hit()).count()
    };
    let v = serde_json::json!({
        "structure": name, "rays": rays.len(), if any { "occluded" } else { "hits" }: answered,
        "seconds": seconds, "mrays_per_s": rays.len() as f64 / seconds.max(1e-12) / 1e6,
        "threads": rayon::current_num_threads(), "build_ms": acc.stats().build_seconds * 1e3,
        "nodes_visited": c.nodes_visited, "triangles_tested": c.triangles_tested,
        "disagree_with_oavm": disagree,
    });
    write_out(&(serde_json::to_string_pretty(&v).unwrap_or_default() + "\n"))?;
    if disagree as f64 > 1e-4 * rays.len() as f64 {
        return Err(Error::Invalid(format!(
            "DISAGREEMENT: {disagree} of {} rays differ from OAVM",
            rays.len()
        )));
    }
    Ok(())
}

fn write_out(s: &str) -> Result<(), Error> {
    std::io::stdout()
        .lock()
        .write_all(s.as_bytes())
        .map_err(|e| Error::io("stdout", e))
}
