//! `oavm-bench SCENE...`: the OAVM paper's comparison, on our code and the same rays: a uniform
//! grid, the SAH KD-tree, the classic octree, a binned-SAH BVH and OAVM, built from the same
//! triangles, traced with the same primary, random and shadow rays, every answer checked against
//! OAVM's. The measuring is `oavm::compare::bench`; this is its command line.

use std::path::PathBuf;

use clap::Parser;
use oavm::build::{self, BuildOptions};
mod cli;

use cli::{LeafArg, main_with};
use oavm::compare::bench::{self, Options, Report, SceneResult};
use oavm::{Error, rays};

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
