//! `oavm-bench SCENE...`: the OAVM paper's comparison, on our code and the same rays: a uniform
//! grid, the SAH KD-tree, the classic octree, a binned-SAH BVH and OAVM, built from the same
//! triangles, traced with the same primary, random and shadow rays, every answer checked against
//! OAVM's. The measuring is `oavm_compare::bench`; this is its command line.

use std::path::PathBuf;

use clap::Parser;
use oavm::pack::{self, BuildOptions};
mod cli;

use cli::{LeafArg, main_with};
use oavm::{Error, rays};
use oavm_compare::bench::{self, Options, Report, SceneResult};
use oavm_compare::kdtree::ShadowParams;
use oavm_compare::shadow::{self, LightKind, ShadowOptions, ShadowVariant, ViewOverride};

/// Builds the structures of the OAVM paper's comparison over each scene and traces the same rays
/// through all of them.
#[derive(Parser, Debug)]
#[command(name = "oavm-bench", version)]
struct Args {
    /// Scenes: .ply, .obj or .aff files.
    #[arg(required = true)]
    scenes: Vec<PathBuf>,
    /// Structures to build: grid, kdtree, octree, bvh, oavm or all (repeat or separate by
    /// commas); the KD-tree's traversals: kdtree:stack (the plain kdtree), kdtree:restart,
    /// kdtree:pushdown, kdtree:shortstack (4 entries), kdtree:splitstack (the source's ropes
    /// with a SplitStack register), kdtree:ropes (ropes with leaf cells), kdtree:popov (ropes to
    /// the smallest node, leaf boxes); OAVM's leaf-to-leaf walks: oavm:morton, oavm:ropes. None
    /// of those are part of all.
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
    /// What OAVM's solid leaves hold: `cluster` (the default structure) or `list` (the OAVM
    /// paper's structure).
    #[arg(long, value_enum, default_value_t = LeafArg::Cluster)]
    leaf: LeafArg,
    /// OAVM's and the classic octree's leaf size K [default: 512 for clusters, 32 for lists].
    #[arg(long)]
    leaf_size: Option<u32>,
    /// OAVM's and the classic octree's maximum depth D.
    #[arg(long, default_value_t = pack::DEFAULT_MAX_DEPTH)]
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
    /// Shadow rays instead (the multi-index tree of Liang and Huang): these traversals of the
    /// --structure (kdtree) over the frames of a camera orbit, each checked against standard:
    /// standard, sato (children by surface area), multi (primitive and adjacency indices chosen
    /// by prediction). With --rays and --occluded, exactly one.
    #[arg(long, value_delimiter = ',', value_name = "VARIANTS")]
    shadow_variant: Vec<String>,
    /// Shadow rays: frames of the orbit.
    #[arg(long, default_value_t = 8)]
    frames: usize,
    /// Shadow rays: degrees the camera turns each frame.
    #[arg(long, default_value_t = 1.0)]
    orbit_step: f64,
    /// Shadow rays: prediction tile side, pixels.
    #[arg(long, default_value_t = 16)]
    tile: u32,
    /// Shadow rays: the scene's point lights, or each made a square area light (side 2 % of the
    /// scene's diagonal).
    #[arg(long, value_enum, default_value_t = LightArg::Point)]
    light: LightArg,
    /// Shadow rays: samples per pixel of an area light.
    #[arg(long, default_value_t = 4)]
    light_samples: u32,
    /// Shadow rays, meshes: enclose the mesh, the camera and the light in a closed box.
    #[arg(long)]
    closed_box: bool,
    /// Shadow rays, multi: candidate occluders' box area over the mean (the source: 0.45-0.60).
    #[arg(long, default_value_t = 0.5)]
    candidate_ratio: f64,
    /// Shadow rays, multi: the depth weight exp(-k d).
    #[arg(long, default_value_t = 0.6)]
    depth_k: f64,
    /// Shadow rays, multi: the weighted saving C/C' a triangle must exceed to be promoted.
    #[arg(long, default_value_t = 1.0)]
    min_benefit: f64,
    /// Shadow rays: camera position (replaces the scene's or framing camera's; with --target).
    #[arg(long, value_parser = cli::parse_vec3, allow_hyphen_values = true, requires = "target")]
    eye: Option<[f64; 3]>,
    /// Shadow rays: the point the camera looks at.
    #[arg(long, value_parser = cli::parse_vec3, allow_hyphen_values = true, requires = "eye")]
    target: Option<[f64; 3]>,
    /// Shadow rays: vertical field of view of --eye's camera, degrees.
    #[arg(long, default_value_t = 40.0)]
    fov: f64,
    /// Shadow rays: one point light here instead of the scene's lights.
    #[arg(long, value_parser = cli::parse_vec3, allow_hyphen_values = true)]
    light_at: Option<[f64; 3]>,
    /// Shadow rays, multi: most triangles promoted to one node.
    #[arg(long, default_value_t = 8)]
    per_node: usize,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum LightArg {
    Point,
    Quad,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    main_with("oavm-bench", || run(&args))
}

fn run(args: &Args) -> Result<(), Error> {
    let names = bench::parse_structures(&args.structure)?;
    let opts = Options {
        build: BuildOptions {
            leaf_size: args
                .leaf_size
                .unwrap_or(args.leaf.kind().default_leaf_size()),
            leaf: args.leaf.kind(),
            max_depth: args.max_depth,
            merge: true,
        },
        random: args.random,
        width: args.width,
        height: args.height,
        reps: args.reps,
        threads: args.threads.clone(),
    };
    opts.build.validate()?;
    if !args.shadow_variant.is_empty() {
        return shadow(args, &opts.build);
    }
    if let Some(rays_path) = &args.rays {
        return batch(args, rays_path, &names, &opts.build);
    }

    let progress = |s: &str| eprintln!("oavm-bench: {s}");
    let mut failed = Vec::new();
    let mut scenes = Vec::new();
    for path in &args.scenes {
        let r = bench::bench_scene(path, &names, &opts, &progress)?;
        failed.extend(r.failures());
        if !args.json {
            print_scene(&r)?;
        }
        scenes.push(r);
    }
    if args.json {
        cli::print_json(&Report {
            format_version: oavm::physical::format::VERSION,
            options: opts,
            scenes,
        })?;
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

/// Batch mode: one structure, one ray file, answers in the formats of RAYS.md, checked against
/// OAVM.
fn batch(
    args: &Args,
    rays_path: &std::path::Path,
    names: &[&'static str],
    build: &BuildOptions,
) -> Result<(), Error> {
    let ([name], [scene]) = (names, &args.scenes[..]) else {
        return Err(Error::Invalid(
            "--rays needs exactly one scene and exactly one --structure (not all)".into(),
        ));
    };
    let out = match (&args.hits, &args.occluded) {
        (Some(h), _) => h,
        (None, Some(o)) => o,
        (None, None) => {
            return Err(Error::Invalid(
                "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
            ));
        }
    };
    // Checked before the work: not an input, a directory, a device...
    let out = oavm::output::Output::create(out, &[scene.as_path(), rays_path])?;
    let rays = rays::read_rays(rays_path, u32::MAX as u64)?;
    let (result, answers) = bench::batch(scene, name, &rays, args.occluded.is_some(), build)?;
    match answers {
        bench::Answers::Closest(hits) => rays::write_into(out, &hits)?,
        bench::Answers::Any(occ) => rays::write_into(out, &occ)?,
    }
    cli::print_json(&result)?;
    match result.failure() {
        Some(f) => Err(Error::Invalid(f)),
        None => Ok(()),
    }
}

/// The shadow-ray benchmark (`--shadow-variant`).
fn shadow(args: &Args, build: &BuildOptions) -> Result<(), Error> {
    let variants = args
        .shadow_variant
        .iter()
        .map(|v| ShadowVariant::parse(v))
        .collect::<Result<Vec<_>, _>>()?;
    // The default `all` means the KD-tree and OAVM here.
    let structures: Vec<&str> = if args.structure == ["all"] {
        shadow::SHADOW_STRUCTURES.to_vec()
    } else {
        let mut v = Vec::new();
        for s in &args.structure {
            match shadow::SHADOW_STRUCTURES.iter().find(|&&k| k == s) {
                Some(k) => v.push(*k),
                None => {
                    return Err(Error::Invalid(format!(
                        "--shadow-variant runs on {} (not {s:?})",
                        shadow::SHADOW_STRUCTURES.join(", ")
                    )));
                }
            }
        }
        v
    };
    let fine = |x: f64| x.is_finite() && x >= 0.0;
    if ![args.candidate_ratio, args.depth_k, args.min_benefit]
        .into_iter()
        .all(fine)
    {
        return Err(Error::Invalid(
            "--candidate-ratio, --depth-k and --min-benefit must be finite and not negative".into(),
        ));
    }
    let params = ShadowParams {
        candidate_ratio: args.candidate_ratio,
        depth_k: args.depth_k,
        min_benefit: args.min_benefit,
        per_node: args.per_node,
        ..ShadowParams::default()
    };
    let view = ViewOverride {
        eye_target: args.eye.zip(args.target),
        fov: args.fov,
        light_at: args.light_at.map(|l| l.map(|x| x as f32)),
        closed_box: args.closed_box,
    };
    if let Some(rays_path) = &args.rays {
        let ([variant], [scene], [structure], Some(out)) = (
            &variants[..],
            &args.scenes[..],
            &structures[..],
            &args.occluded,
        ) else {
            return Err(Error::Invalid(
                "--rays with --shadow-variant needs exactly one scene, one variant, one \
                 --structure and --occluded"
                    .into(),
            ));
        };
        let out = oavm::output::Output::create(out, &[scene.as_path(), rays_path])?;
        let rays = rays::read_rays(rays_path, u32::MAX as u64)?;
        let scene = shadow::load_scene(scene, &view)?;
        let (result, answers) =
            shadow::batch_file(&scene, structure, *variant, &rays, params, build)?;
        rays::write_into(out, &answers)?;
        cli::print_json(&result)?;
        if result.disagree_with_standard > 0 {
            return Err(Error::Invalid(format!(
                "DISAGREEMENT: {} of {} rays differ from the standard walk",
                result.disagree_with_standard, result.rays
            )));
        }
        return Ok(());
    }
    if args.frames == 0 || args.tile == 0 || args.light_samples == 0 {
        return Err(Error::Invalid(
            "--frames, --tile and --light-samples must be at least 1".into(),
        ));
    }
    let sopts = ShadowOptions {
        width: args.width,
        height: args.height,
        frames: args.frames,
        orbit_step: args.orbit_step,
        tile: args.tile,
        light: match args.light {
            LightArg::Point => LightKind::Point,
            LightArg::Quad => LightKind::Quad,
        },
        samples: args.light_samples,
        closed_box: args.closed_box,
        params,
        reps: args.reps,
        threads: args.threads.clone(),
    };
    let progress = |s: &str| eprintln!("oavm-bench: {s}");
    let mut scenes = Vec::new();
    let mut failed = 0;
    for path in &args.scenes {
        let scene = shadow::load_scene(path, &view)?;
        progress(&format!(
            "{}: {} triangles",
            path.display(),
            scene.tris.len()
        ));
        let mut r = shadow::run(&scene, &structures, &variants, &sopts, build, &progress)?;
        r.scene = bench::scene_name(path);
        failed += r
            .variants
            .iter()
            .filter(|v| v.disagree_with_standard > 0)
            .count();
        if !args.json {
            print_shadow(&r)?;
        }
        scenes.push(r);
    }
    if args.json {
        cli::print_json(&serde_json::json!({
            "format_version": oavm::physical::format::VERSION,
            "shadow": sopts,
            "scenes": scenes,
        }))?;
    }
    if failed > 0 {
        return Err(Error::Invalid(format!(
            "DISAGREEMENT: {failed} variants answered otherwise than the standard walk"
        )));
    }
    Ok(())
}

fn print_shadow(r: &shadow::ShadowSceneResult) -> Result<(), Error> {
    let mut t = format!(
        "\n{} ({} triangles, {} lights: {}, {} frames, {} shadow rays)\n{:<7} {:<9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>10} {:>10} {:>8} {:>22}\n",
        r.scene,
        r.triangles,
        r.lights,
        r.light_source,
        r.frames,
        r.rays_per_frame.iter().sum::<usize>(),
        "struct",
        "variant",
        "occluded",
        "nodes/occ",
        "tris/occ",
        "nodes/un",
        "tris/un",
        "predict",
        "prep s",
        "prep bytes",
        "disagree",
        "Mrays/s (threads)"
    );
    for v in &r.variants {
        let b = &v.by_occlusion;
        let speed: Vec<String> = v
            .mrays_per_s
            .iter()
            .map(|(th, m)| format!("{m:.2} ({th})"))
            .collect();
        let acc = v
            .prediction
            .map_or("-".to_string(), |p| format!("{:.1} %", 100.0 * p.accuracy));
        t.push_str(&format!(
            "{:<7} {:<9} {:>9} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>8} {:>10.3} {:>10} {:>8} {:>22}\n",
            v.structure,
            v.variant.name(),
            v.occluded,
            b.nodes_per_occluded_ray,
            b.triangles_per_occluded_ray,
            b.nodes_per_unoccluded_ray,
            b.triangles_per_unoccluded_ray,
            acc,
            v.precompute.seconds,
            v.precompute.bytes,
            v.disagree_with_standard + v.disagree_with_kdtree,
            speed.join(" ")
        ));
    }
    write_out(&t)
}

fn print_scene(r: &SceneResult) -> Result<(), Error> {
    // The structure column fits the longest name (`kdtree:shortstack`).
    let w = r
        .structures
        .iter()
        .map(|s| s.stats.name.len())
        .max()
        .unwrap_or(0)
        .max(8);
    let mut t = format!(
        "\n{} ({} triangles, {} stored)\n{:<w$} {:>10} {:>9} {:>9} {:>11}  {:<8} {:>10} {:>10} {:>10} {:>22}\n",
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
                    "{:<w$} {:>10.1} {:>9} {:>9} {:>11}",
                    s.stats.name, s.build_ms, s.stats.nodes, s.stats.pointers, s.stats.bytes
                )
            } else {
                format!("{:<w$} {:>10} {:>9} {:>9} {:>11}", "", "", "", "", "")
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

fn write_out(s: &str) -> Result<(), Error> {
    cli::print_text(s)
}
