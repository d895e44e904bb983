//! Benchmark: the same rays through OAVM, obvhs and the bvh crate (and Embree 4 with the `embree`
//! feature), in one process.
//!
//!     cargo bench --bench trace -- [--scene NAME=PATH]... [--big PATH] [--only NAME,...]
//!         [--peers obvhs,bvh,embree] [--reps N] [--random N] [--json]
//!         [--leaf cluster|list] [--leaf-size K] [--max-depth D] [--no-merge]
//!     tools/embree.sh cargo bench --bench trace --features embree -- ...
//!     tools/bench_all.sh [ARGS...]    # the default scenes and a 10M-triangle one
//!
//! Scenes: by default the bunny, the dragon, BART's kitchen (at its default time) and Sibenik,
//! from `../shared/scenes` beside the crate; a missing file is an error, never a skip. `--scene`
//! replaces them (repeatable; `PATH` alone names the scene after its file), `--big PATH` adds a
//! scene named `big`, `--only` keeps the named scenes. `--peers` picks the peers (default: every
//! one built in).
//!
//! For each scene it builds the structures from the same triangles (OAVM in memory, not from a
//! file), generates primary rays (1024x768, the default camera of `oavm-trace`, which frames the
//! scene's bounds), `--random` random rays (default 10^6) and shadow rays toward the default
//! light from every primary hit, and traces every set on 1 and 2 threads.
//!
//! Timing: `--reps` repetitions (default 5), interleaved: each repetition times one full pass of
//! OAVM and then of every peer, the peers in an order that rotates from one repetition to the
//! next, so the machine's drift falls on all of them. Per tracer the median time gives Mrays/s;
//! per peer, the ratio `peer time / OAVM time` of each repetition (OAVM's speed over the peer's)
//! gives a median and a min–max range. The ratio is what to compare across machines.
//!
//! The output starts with what was measured: commit (`-dirty` with uncommitted changes), OAVM
//! format version, CPU, threads, peer versions and configuration (Embree's from the library
//! itself). Each row then gives speeds, ratios, disagreements and OAVM's work per ray (nodes,
//! leaves, merged volumes crossed, leaves culled by their tight bounds, triangles tested, blocks
//! asked of the pager); `--json` gives all of it, every counter and every repetition's times.
//!
//! Answers are cross-checked: every peer against OAVM on every ray (same hit/miss, t within 1e-4
//! of the diagonal); a disagreement rate above 0.01 % is reported loudly and fails the run (exit
//! status 1). Bad arguments exit with status 2 before anything is built.

#[path = "peers/mod.rs"]
mod peers;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, ValueEnum};
use oavm::pack::LeafKind;
use oavm::physical::AlignedBytes;
use oavm::rays::{Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Counters, Hit, Ray, Scene};
#[cfg(feature = "embree")]
use peers::EmbreeScene;
use peers::{BVH_TRAVERSAL, BvhCrateScene, OBVHS_PRESET, ObvhsScene, Tracer};
use rayon::prelude::*;
use serde_json::{Value, json};

/// One set of rays every tracer is measured on (the shape of `oavm_compare::bench::RaySet`; this
/// benchmark of the product does not depend on the comparison crate).
struct RaySet {
    name: &'static str,
    rays: Vec<Ray>,
    /// Any-hit queries (shadow rays), else closest hit.
    any: bool,
}

/// Thread counts every ray set is traced with.
const THREADS: [usize; 2] = [1, 2];
/// Disagreement rate with OAVM above which the run fails.
const MAX_DISAGREEMENT: f64 = 1e-4;
/// Primary rays: the image size of `oavm-trace`'s default render.
const IMAGE: (u32, u32) = (1024, 768);

// ---------------------------------------------------------------------------------------------
// Arguments
// ---------------------------------------------------------------------------------------------

/// Traces the same rays through OAVM and its peers and prints speeds, ratios and work per ray.
#[derive(Parser, Debug)]
#[command(name = "bench_trace", bin_name = "cargo bench --bench trace --")]
struct Cli {
    /// A scene, NAME=PATH (or PATH, named after its file); repeatable. Replaces the default
    /// scenes (bunny, dragon, kitchen, sibenik).
    #[arg(long = "scene", value_name = "NAME=PATH", value_parser = parse_scene)]
    scenes: Vec<SceneSpec>,
    /// Adds the scene big=PATH (tools/bench_all.sh makes a 10M-triangle one).
    #[arg(long, value_name = "PATH")]
    big: Option<PathBuf>,
    /// Only the scenes with these names.
    #[arg(long, value_name = "NAME,...", value_delimiter = ',')]
    only: Vec<String>,
    /// The peers to trace (default: every one built in; embree needs the `embree` feature).
    #[arg(long, value_name = "PEER,...", value_delimiter = ',')]
    peers: Vec<PeerKind>,
    /// Timed repetitions of every pass (interleaved; medians are reported).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    reps: u32,
    /// Number of random rays.
    #[arg(long, default_value_t = 1_000_000)]
    random: usize,
    /// OAVM build: what a solid leaf holds, `cluster` (the default) or `list` (the paper's).
    #[arg(long, value_name = "KIND", value_parser = parse_leaf)]
    leaf: Option<LeafKind>,
    /// OAVM build: a leaf is subdivided while it holds more than K triangles.
    #[arg(long, value_name = "K")]
    leaf_size: Option<u32>,
    /// OAVM build: deepest level of a leaf.
    #[arg(long, value_name = "D")]
    max_depth: Option<u32>,
    /// OAVM build: do not merge empty leaves into volumes.
    #[arg(long)]
    no_merge: bool,
    /// Print one JSON document (and nothing else) on stdout.
    #[arg(long)]
    json: bool,
    /// Passed by `cargo bench`.
    #[arg(long = "bench", hide = true)]
    _bench: bool,
}

#[derive(Clone, Debug)]
struct SceneSpec {
    name: String,
    path: PathBuf,
}

fn parse_scene(s: &str) -> Result<SceneSpec, String> {
    let (name, path) = match s.split_once('=') {
        Some((name, path)) => (name.to_string(), PathBuf::from(path)),
        None => {
            let path = PathBuf::from(s);
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
            (stem.unwrap_or_default(), path)
        }
    };
    if name.is_empty() || path.as_os_str().is_empty() {
        return Err(format!("expected NAME=PATH or PATH, got {s:?}"));
    }
    Ok(SceneSpec { name, path })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum PeerKind {
    Obvhs,
    Bvh,
    Embree,
}

impl PeerKind {
    fn name(self) -> &'static str {
        match self {
            PeerKind::Obvhs => "obvhs",
            PeerKind::Bvh => "bvh",
            PeerKind::Embree => "embree",
        }
    }

    /// The peers this binary can trace.
    fn built_in() -> Vec<PeerKind> {
        let mut all = vec![PeerKind::Obvhs, PeerKind::Bvh];
        if cfg!(feature = "embree") {
            all.push(PeerKind::Embree);
        }
        all
    }
}

/// The arguments, checked: what the rest of the program runs.
struct Config {
    scenes: Vec<SceneSpec>,
    peers: Vec<PeerKind>,
    reps: usize,
    random: usize,
    json: bool,
    opts: BuildOptions,
}

/// The default scenes, in `../shared/scenes` beside the crate.
fn default_scenes() -> Vec<SceneSpec> {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    [
        ("bunny", "bunny/bun_zipper.ply"),
        ("dragon", "dragon/dragon_vrip.ply"),
        ("kitchen", "bart/kitchen/kitchen.aff"),
        ("sibenik", "sibenik/sibenik.obj"),
    ]
    .into_iter()
    .map(|(name, rel)| SceneSpec {
        name: name.into(),
        path: shared.join(rel),
    })
    .collect()
}

impl Config {
    /// Checks the arguments (scene names, files, peers, build options) before anything runs.
    fn from_cli(cli: Cli) -> Result<Config, String> {
        let mut scenes = if cli.scenes.is_empty() {
            default_scenes()
        } else {
            cli.scenes
        };
        if let Some(path) = cli.big {
            scenes.push(SceneSpec {
                name: "big".into(),
                path,
            });
        }
        for (i, s) in scenes.iter().enumerate() {
            if scenes[..i].iter().any(|t| t.name == s.name) {
                return Err(format!("two scenes are named {:?}", s.name));
            }
        }
        if !cli.only.is_empty() {
            let names: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
            if let Some(unknown) = cli.only.iter().find(|n| !names.contains(&n.as_str())) {
                return Err(format!(
                    "--only {unknown}: no such scene (the scenes are {})",
                    names.join(", ")
                ));
            }
            scenes.retain(|s| cli.only.contains(&s.name));
        }
        let missing: Vec<String> = scenes
            .iter()
            .filter(|s| !s.path.is_file())
            .map(|s| format!("  {}: {}", s.name, s.path.display()))
            .collect();
        if !missing.is_empty() {
            return Err(format!(
                "scene files not found:\n{}\n(the default scenes are read from ../shared/scenes \
                 beside the crate; --only picks some, --scene NAME=PATH names others)",
                missing.join("\n")
            ));
        }

        let built_in = PeerKind::built_in();
        let peers = if cli.peers.is_empty() {
            built_in.clone()
        } else {
            cli.peers
        };
        for (i, p) in peers.iter().enumerate() {
            if peers[..i].contains(p) {
                return Err(format!("--peers names {} twice", p.name()));
            }
        }
        if let Some(p) = peers.iter().find(|p| !built_in.contains(p)) {
            return Err(format!(
                "--peers {}: not built in; run `tools/embree.sh cargo bench --bench trace \
                 --features embree -- ...`",
                p.name()
            ));
        }

        let mut opts = BuildOptions::with_leaf(cli.leaf.unwrap_or(LeafKind::Cluster));
        if let Some(k) = cli.leaf_size {
            opts.leaf_size = k;
        }
        if let Some(d) = cli.max_depth {
            opts.max_depth = d;
        }
        opts.merge = !cli.no_merge;
        opts.validate().map_err(|e| e.to_string())?;

        Ok(Config {
            scenes,
            peers,
            reps: cli.reps as usize,
            random: cli.random,
            json: cli.json,
            opts,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// What was measured: the header
// ---------------------------------------------------------------------------------------------

/// The commit of the sources this benchmark was built from, `-dirty` if tracked files differ
/// from it; asked of git at run time in the crate's directory (`cargo bench` rebuilds after any
/// change to the sources, so that is the commit built). `unknown` without git.
fn commit() -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .arg("-C")
            .arg(env!("CARGO_MANIFEST_DIR"))
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    match git(&["rev-parse", "--short", "HEAD"]) {
        Some(head) => match git(&["status", "--porcelain", "--untracked-files=no"]) {
            Some(changes) if !changes.is_empty() => format!("{head}-dirty"),
            _ => head,
        },
        None => "unknown".into(),
    }
}

/// The CPU's model name from `/proc/cpuinfo` (Linux), or `unknown CPU`.
fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| {
            info.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, model)| model.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

/// The version of `krate` in the crate's Cargo.lock (what the benchmark was compiled with).
fn locked_version(krate: &str) -> &'static str {
    const LOCK: &str = include_str!("../Cargo.lock");
    let entry = format!("name = \"{krate}\"\nversion = \"");
    LOCK.split_once(entry.as_str())
        .and_then(|(_, rest)| rest.split_once('"'))
        .map_or("?", |(version, _)| version)
}

/// Embree's own description of the library and of the scene configuration, asked of an empty
/// scene so that it can head the output.
#[cfg(feature = "embree")]
fn embree_description() -> String {
    EmbreeScene::build(&[], &[]).describe()
}

#[cfg(not(feature = "embree"))]
fn embree_description() -> String {
    unreachable!("Config::from_cli keeps the peers built in")
}

fn header(config: &Config) -> Value {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let mut peers = serde_json::Map::new();
    for &p in &config.peers {
        let about = match p {
            PeerKind::Obvhs => format!(
                "obvhs {} (CWBVH8, preset {OBVHS_PRESET}, single-threaded build)",
                locked_version("obvhs")
            ),
            PeerKind::Bvh => format!(
                "bvh {} (binned SAH, build_par, {BVH_TRAVERSAL:?} traversal)",
                locked_version("bvh")
            ),
            PeerKind::Embree => embree_description(),
        };
        peers.insert(p.name().into(), json!(about));
    }
    json!({
        "commit": commit(),
        "oavm_format_version": oavm::physical::format::VERSION,
        "cpu": cpu_model(),
        "cores": cores,
        "threads": THREADS,
        "reps": config.reps,
        "random_rays": config.random,
        "image": [IMAGE.0, IMAGE.1],
        "options": config.opts,
        "peers": peers,
    })
}

fn print_header(h: &Value, peers: &[PeerKind]) {
    let o = &h["options"];
    println!(
        "commit {}, OAVM format version {}, {} ({} cores available), traced on {} threads",
        h["commit"].as_str().unwrap_or_default(),
        h["oavm_format_version"],
        h["cpu"].as_str().unwrap_or_default(),
        h["cores"],
        THREADS.map(|t| t.to_string()).join(" and "),
    );
    println!(
        "OAVM built in memory: {} leaves of size {}, max depth {}, merge {}; {} interleaved reps, medians",
        o["leaf"].as_str().unwrap_or_default(),
        o["leaf_size"],
        o["max_depth"],
        if o["merge"] == true { "on" } else { "off" },
        h["reps"]
    );
    for p in peers {
        println!(
            "peer: {}",
            h["peers"][p.name()].as_str().unwrap_or_default()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Scenes
// ---------------------------------------------------------------------------------------------

/// A peer's structure over a scene's triangles.
enum PeerScene {
    Obvhs(ObvhsScene),
    Bvh(BvhCrateScene),
    #[cfg(feature = "embree")]
    Embree(EmbreeScene),
}

impl PeerScene {
    fn build(kind: PeerKind, positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> PeerScene {
        match kind {
            PeerKind::Obvhs => PeerScene::Obvhs(ObvhsScene::build(positions, triangles)),
            PeerKind::Bvh => PeerScene::Bvh(BvhCrateScene::build(positions, triangles)),
            #[cfg(feature = "embree")]
            PeerKind::Embree => PeerScene::Embree(EmbreeScene::build(positions, triangles)),
            #[cfg(not(feature = "embree"))]
            PeerKind::Embree => unreachable!("Config::from_cli keeps the peers built in"),
        }
    }

    /// Traces every ray (in parallel on the current rayon pool): closest hits into `hits`, or
    /// any-hit answers into `occluded` when `any`. Dispatched once per pass, never per ray, so
    /// every peer's inner loop calls its tracer directly, as OAVM's batch does.
    fn trace(&self, rays: &[Ray], any: bool, hits: &mut [Hit], occluded: &mut [bool]) {
        // Generic, so each peer's loop is compiled for it: no dynamic call per ray.
        fn run(s: &impl Tracer, rays: &[Ray], any: bool, hits: &mut [Hit], occluded: &mut [bool]) {
            if any {
                par_map(rays, occluded, |r| s.occluded(r));
            } else {
                par_map(rays, hits, |r| s.intersect(r));
            }
        }
        match self {
            PeerScene::Obvhs(s) => run(s, rays, any, hits, occluded),
            PeerScene::Bvh(s) => run(s, rays, any, hits, occluded),
            #[cfg(feature = "embree")]
            PeerScene::Embree(s) => run(s, rays, any, hits, occluded),
        }
    }
}

fn par_map<T: Send>(rays: &[Ray], out: &mut [T], f: impl Fn(&Ray) -> T + Sync) {
    out.par_chunks_mut(256)
        .zip(rays.par_chunks(256))
        .for_each(|(o, r)| {
            for (o, r) in o.iter_mut().zip(r) {
                *o = f(r);
            }
        });
}

/// A scene's structures, built from the same triangles.
struct Built {
    scene: Scene<AlignedBytes>,
    /// In the order of `Config::peers`.
    peers: Vec<(PeerKind, PeerScene)>,
    bounds: Bounds,
    /// Triangles, build times and OAVM's tree, for the output.
    info: Value,
}

fn seconds_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Loads `spec` and builds OAVM (encoded in memory) and every peer. Only the structures are
/// kept: the mesh and OAVM's build-time tree are dropped before tracing.
fn build_scene(spec: &SceneSpec, config: &Config) -> Result<Built, String> {
    eprintln!("{}: loading {}", spec.name, spec.path.display());
    let t = Instant::now();
    let mesh = oavm::mesh::load(&spec.path).map_err(|e| format!("{}: {e}", spec.name))?;
    let load_s = seconds_since(t);
    let bounds = Bounds::of_points(mesh.positions.iter().copied());

    let t = Instant::now();
    let (bytes, stats) = {
        let (parts, stats) = oavm::pack::build(&mesh, &config.opts, &oavm::pack::Quiet)
            .map_err(|e| format!("{}: OAVM build: {e}", spec.name))?;
        let bytes =
            oavm::pack::encode(&parts).map_err(|e| format!("{}: OAVM encode: {e}", spec.name))?;
        (bytes, stats)
    };
    let mut build_s = vec![("oavm", seconds_since(t))];
    // Progress: a big scene's builds take minutes.
    eprintln!("{}: oavm built in {:.1} s", spec.name, build_s[0].1);
    let file_bytes = bytes.as_ref().len();
    let scene = Scene::from_bytes(bytes, spec.name.as_str())
        .map_err(|e| format!("{}: OAVM open: {e}", spec.name))?;

    let mut peers = Vec::new();
    for &kind in &config.peers {
        // Embree builds with its own (TBB) threads, OAVM and bvh on rayon's, all on every core;
        // obvhs builds on one thread (its `parallel` feature is off).
        let t = Instant::now();
        let peer = PeerScene::build(kind, &mesh.positions, &mesh.triangles);
        let seconds = seconds_since(t);
        eprintln!("{}: {} built in {seconds:.1} s", spec.name, kind.name());
        build_s.push((kind.name(), seconds));
        peers.push((kind, peer));
    }

    let rss = oavm::os::peak_rss_bytes();
    let info = json!({
        "scene": spec.name,
        "path": spec.path,
        "vertices": mesh.positions.len(),
        "triangles": mesh.triangles.len(),
        "load_seconds": load_s,
        "build_seconds": build_s.iter().copied().collect::<std::collections::BTreeMap<_, _>>(),
        "peak_rss_bytes_after_build": rss,
        "oavm": {
            "bytes": file_bytes,
            "nodes": stats.nodes,
            "depth": stats.depth,
            "triangles": stats.triangles,
            "refs_per_triangle": stats.refs_per_triangle,
        },
    });
    let line = format!(
        "{}: {} triangles, loaded in {load_s:.2} s; build {}; OAVM {} nodes, depth {}, {:.1} MB; \
         peak RSS so far {}",
        spec.name,
        mesh.triangles.len(),
        build_s
            .iter()
            .map(|(name, s)| format!("{name} {s:.3} s"))
            .collect::<Vec<_>>()
            .join(", "),
        stats.nodes,
        stats.depth,
        file_bytes as f64 / 1e6,
        rss.map_or("unknown".into(), |b| format!(
            "{:.2} GiB",
            b as f64 / (1u64 << 30) as f64
        )),
    );
    if config.json {
        eprintln!("{line}");
    } else {
        println!("{line}");
    }
    Ok(Built {
        scene,
        peers,
        bounds,
        info,
    })
}

// ---------------------------------------------------------------------------------------------
// Ray sets, cross-check, timing
// ---------------------------------------------------------------------------------------------

fn ray_sets(built: &Built, random: usize) -> Result<Vec<RaySet>, String> {
    let b = &built.bounds;
    let primary = Camera::framing(b).primary_rays(IMAGE.0, IMAGE.1);
    let mut primary_hits = vec![Hit::MISS; primary.len()];
    built
        .scene
        .intersect_batch(&primary, &mut primary_hits)
        .map_err(|e| e.to_string())?;
    let shadow = shadow_rays(&primary, &primary_hits, default_light(b));
    Ok(vec![
        RaySet {
            name: "primary",
            rays: primary,
            any: false,
        },
        RaySet {
            name: "random",
            rays: random_rays(b, random, 1),
            any: false,
        },
        RaySet {
            name: "shadow",
            rays: shadow,
            any: true,
        },
    ])
}

/// Answer buffers, reused by every pass over one ray set.
struct Answers {
    oavm_hits: Vec<Hit>,
    oavm_occluded: Vec<u8>,
    peer_hits: Vec<Hit>,
    peer_occluded: Vec<bool>,
}

impl Answers {
    fn new(n: usize) -> Answers {
        Answers {
            oavm_hits: vec![Hit::MISS; n],
            oavm_occluded: vec![0; n],
            peer_hits: vec![Hit::MISS; n],
            peer_occluded: vec![false; n],
        }
    }
}

fn trace_oavm(
    scene: &Scene<AlignedBytes>,
    set: &RaySet,
    a: &mut Answers,
) -> Result<Counters, String> {
    let counters = if set.any {
        scene.occluded_batch(&set.rays, &mut a.oavm_occluded)
    } else {
        scene.intersect_batch(&set.rays, &mut a.oavm_hits)
    };
    counters.map_err(|e| e.to_string())
}

fn trace_peer(peer: &PeerScene, set: &RaySet, a: &mut Answers) {
    peer.trace(&set.rays, set.any, &mut a.peer_hits, &mut a.peer_occluded);
}

/// Traces the set once with OAVM (its work counters are the result) and once with every peer,
/// and counts per peer the rays whose answers differ from OAVM's; reports a rate above
/// [`MAX_DISAGREEMENT`] on stderr.
fn cross_check(
    built: &Built,
    scene_name: &str,
    set: &RaySet,
    a: &mut Answers,
) -> Result<(Counters, Vec<usize>, bool), String> {
    let counters = trace_oavm(&built.scene, set, a)?;
    let diag = built.bounds.diagonal();
    let mut disagree = Vec::new();
    let mut failed = false;
    for (kind, peer) in &built.peers {
        trace_peer(peer, set, a);
        let d = if set.any {
            a.peer_occluded
                .iter()
                .zip(&a.oavm_occluded)
                .filter(|(p, o)| **p != (**o == 1))
                .count()
        } else {
            a.oavm_hits
                .iter()
                .zip(&a.peer_hits)
                .filter(|(o, p)| !o.agrees(p, diag))
                .count()
        };
        let rate = d as f64 / set.rays.len().max(1) as f64;
        if rate > MAX_DISAGREEMENT {
            eprintln!(
                "!!! {scene_name} {}: OAVM and {} disagree on {d} of {} rays ({:.4} %)",
                set.name,
                kind.name(),
                set.rays.len(),
                rate * 100.0
            );
            failed = true;
        }
        disagree.push(d);
    }
    Ok((counters, disagree, failed))
}

/// Seconds of every timed pass: `oavm[rep]`, `peers[peer][rep]`.
struct Times {
    oavm: Vec<f64>,
    peers: Vec<Vec<f64>>,
}

/// Times `reps` interleaved repetitions on a pool of `threads`: each repetition one pass of OAVM,
/// then one of every peer, starting with peer `rep % peers` so that no peer always runs right
/// after OAVM.
fn time_passes(
    built: &Built,
    set: &RaySet,
    a: &mut Answers,
    threads: usize,
    reps: usize,
) -> Result<Times, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    let n = built.peers.len();
    let mut times = Times {
        oavm: Vec::with_capacity(reps),
        peers: vec![Vec::with_capacity(reps); n],
    };
    pool.install(|| {
        for rep in 0..reps {
            let t = Instant::now();
            trace_oavm(&built.scene, set, a)?;
            times.oavm.push(seconds_since(t));
            for i in (0..n).map(|k| (rep + k) % n) {
                let t = Instant::now();
                trace_peer(&built.peers[i].1, set, a);
                times.peers[i].push(seconds_since(t));
            }
        }
        Ok(times)
    })
}

/// The median (the mean of the middle two for an even count); NaN for none.
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

// ---------------------------------------------------------------------------------------------
// Rows
// ---------------------------------------------------------------------------------------------

/// The counters of every field as a JSON object, and each divided by the number of rays.
fn counters_json(c: &Counters) -> (Value, Value) {
    let total = serde_json::to_value(c).unwrap_or_default();
    let rays = c.rays.max(1) as f64;
    let per_ray: serde_json::Map<String, Value> = total
        .as_object()
        .into_iter()
        .flatten()
        .filter(|(k, _)| *k != "rays")
        .filter_map(|(k, v)| Some((k.clone(), json!(v.as_f64()? / rays))))
        .collect();
    (total, Value::Object(per_ray))
}

/// One row: a scene's ray set on a number of threads.
fn row(
    built: &Built,
    scene_name: &str,
    set: &RaySet,
    threads: usize,
    times: &Times,
    counters: &Counters,
    disagree: &[usize],
) -> Value {
    let rays = set.rays.len() as f64;
    let mrays = |seconds: f64| rays / seconds / 1e6;
    let oavm_median = median(&times.oavm);
    let mut peers = serde_json::Map::new();
    for (((kind, _), t), d) in built.peers.iter().zip(&times.peers).zip(disagree) {
        let ratios: Vec<f64> = t.iter().zip(&times.oavm).map(|(p, o)| p / o).collect();
        let peer_median = median(t);
        peers.insert(
            kind.name().into(),
            json!({
                "mrays_per_s": mrays(peer_median),
                "median_seconds": peer_median,
                "seconds": t,
                // OAVM's speed over the peer's: the peer's time over OAVM's, per repetition.
                "oavm_over_peer": {
                    "median": median(&ratios),
                    "min": ratios.iter().copied().fold(f64::INFINITY, f64::min),
                    "max": ratios.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    "per_rep": ratios,
                },
                "disagree": d,
            }),
        );
    }
    let (total, per_ray) = counters_json(counters);
    json!({
        "scene": scene_name,
        "set": set.name,
        "any_hit": set.any,
        "rays": set.rays.len(),
        "threads": threads,
        "oavm": {
            "mrays_per_s": mrays(oavm_median),
            "median_seconds": oavm_median,
            "seconds": times.oavm,
        },
        "peers": peers,
        "counters": total,
        "counters_per_ray": per_ray,
    })
}

/// A row as one line of text: speeds, ratios with their range, disagreements, work per ray;
/// the peers in the order given.
fn print_row(r: &Value, peers: &[PeerKind]) {
    let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    let peers: Vec<(&str, &Value)> = peers
        .iter()
        .map(|p| (p.name(), &r["peers"][p.name()]))
        .collect();
    let speeds: String = peers
        .iter()
        .map(|(name, p)| format!(" {name} {:7.2}", f(&p["mrays_per_s"])))
        .collect();
    let ratios: String = peers
        .iter()
        .map(|(name, p)| {
            let q = &p["oavm_over_peer"];
            format!(
                " oavm/{name} {:5.2}x [{:.2}-{:.2}]",
                f(&q["median"]),
                f(&q["min"]),
                f(&q["max"])
            )
        })
        .collect();
    let disagree: Vec<String> = peers
        .iter()
        .map(|(_, p)| p["disagree"].to_string())
        .collect();
    let c = &r["counters_per_ray"];
    println!(
        "{:<8} {:<8} {:>8} rays {}T | Mrays/s oavm {:7.2}{speeds} |{ratios} | disagree {} | \
         per ray: nodes {:.1} leaves {:.1} vols {:.1} culled {:.1} tris {:.1} blocks {:.2}",
        r["scene"].as_str().unwrap_or_default(),
        r["set"].as_str().unwrap_or_default(),
        r["rays"],
        r["threads"],
        f(&r["oavm"]["mrays_per_s"]),
        disagree.join("/"),
        f(&c["nodes_visited"]),
        f(&c["leaves_visited"]),
        f(&c["volumes_crossed"]),
        f(&c["leaves_culled"]),
        f(&c["triangles_tested"]),
        f(&c["requested"]),
    );
}

// ---------------------------------------------------------------------------------------------
// Main
// ---------------------------------------------------------------------------------------------

/// Everything a run produced, for `--json`.
struct Report {
    scenes: Vec<Value>,
    rows: Vec<Value>,
    /// Some peer disagreed with OAVM beyond [`MAX_DISAGREEMENT`].
    failed: bool,
}

/// Benchmarks one scene: builds, cross-checks and times every ray set.
fn bench_scene(spec: &SceneSpec, config: &Config, report: &mut Report) -> Result<(), String> {
    let built = build_scene(spec, config)?;
    report.scenes.push(built.info.clone());
    for set in ray_sets(&built, config.random)? {
        let mut answers = Answers::new(set.rays.len());
        let (counters, disagree, failed) = cross_check(&built, &spec.name, &set, &mut answers)?;
        report.failed |= failed;
        for threads in THREADS {
            let times = time_passes(&built, &set, &mut answers, threads, config.reps)?;
            let r = row(
                &built, &spec.name, &set, threads, &times, &counters, &disagree,
            );
            if !config.json {
                print_row(&r, &config.peers);
            }
            report.rows.push(r);
        }
    }
    Ok(())
}

fn run(config: &Config) -> Result<bool, String> {
    let header = header(config);
    if !config.json {
        print_header(&header, &config.peers);
    }
    let mut report = Report {
        scenes: Vec::new(),
        rows: Vec::new(),
        failed: false,
    };
    for spec in &config.scenes {
        bench_scene(spec, config, &mut report)?;
    }
    if config.json {
        let out = json!({ "header": header, "scenes": report.scenes, "results": report.rows });
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
    }
    Ok(!report.failed)
}

fn main() -> ExitCode {
    // Clap prints bad arguments with the usage and exits with status 2.
    let config = match Config::from_cli(Cli::parse()) {
        Ok(config) => config,
        Err(e) => {
            eprintln!("bench_trace: error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&config) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => {
            eprintln!("bench_trace: peers disagreed with OAVM (see above)");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("bench_trace: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn parse_leaf(s: &str) -> Result<LeafKind, String> {
    match s {
        "cluster" => Ok(LeafKind::Cluster),
        "list" => Ok(LeafKind::List),
        _ => Err(format!("{s}: cluster or list")),
    }
}
