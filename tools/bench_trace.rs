//! Benchmark: the same rays through OAVM, obvhs and the bvh crate (and Embree 4 with the `embree`
//! feature), in one process.
//!
//!     cargo bench --bench trace -- [--scene NAME=PATH]... [--reps N] [--random N] [--json]
//!     tools/embree.sh cargo bench --bench trace --features embree -- ...
//!
//! Default scenes: the bunny and the dragon from `../shared/scenes`. For each scene it builds the
//! structures from the same triangles, generates primary rays (1024x768, the default camera
//! of `oavm-trace`), `--random` random rays (default 10^6) and shadow rays toward the default
//! light from every primary hit, and traces every set with every structure on 1 and 2 threads,
//! keeping the best of `--reps` runs. Throughput is printed as Mrays/s and as the ratio of OAVM to
//! each peer measured in the same run (the ratio is what to compare across machines). Answers are
//! cross-checked: every structure against OAVM on every ray (same hit/miss, t within 1e-4 of the
//! diagonal); a disagreement rate above 0.01 % is reported loudly and fails the run.

#[path = "peers/mod.rs"]
mod peers;

use std::path::PathBuf;
use std::time::Instant;

use oavm::rays::{Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray, Scene};
#[cfg(feature = "embree")]
use peers::EmbreeScene;
use peers::{BvhCrateScene, ObvhsScene, Tracer};
use rayon::prelude::*;
use serde_json::json;

struct Args {
    scenes: Vec<(String, PathBuf)>,
    reps: usize,
    random: usize,
    json: bool,
    opts: BuildOptions,
}

fn parse_args() -> Args {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    let mut a = Args {
        scenes: Vec::new(),
        reps: 3,
        random: 1_000_000,
        json: false,
        opts: BuildOptions::default(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut val = |name: &str| it.next().unwrap_or_else(|| panic!("{name} needs a value"));
        match arg.as_str() {
            "--bench" => {} // passed by `cargo bench`
            "--scene" => {
                let v = val("--scene");
                let (n, p) = v.split_once('=').unwrap_or(("scene", &v));
                a.scenes.push((n.to_string(), PathBuf::from(p)));
            }
            "--reps" => a.reps = val("--reps").parse().expect("--reps N"),
            "--random" => a.random = val("--random").parse().expect("--random N"),
            "--leaf-size" => a.opts.leaf_size = val("--leaf-size").parse().expect("--leaf-size K"),
            "--max-depth" => a.opts.max_depth = val("--max-depth").parse().expect("--max-depth D"),
            "--no-merge" => a.opts.merge = false,
            "--json" => a.json = true,
            other => panic!("unknown argument {other}"),
        }
    }
    if a.scenes.is_empty() {
        a.scenes
            .push(("bunny".into(), shared.join("bunny/bun_zipper.ply")));
        a.scenes
            .push(("dragon".into(), shared.join("dragon/dragon_vrip.ply")));
    }
    a
}

/// Best-of-`reps` seconds of `f`.
fn best_of(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
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

/// A peer tracer, dispatched once per pass (never per ray) so every peer's inner loop calls its
/// tracer directly, as OAVM's batch does.
#[derive(Clone, Copy)]
enum Peer<'a> {
    Obvhs(&'a ObvhsScene),
    Bvh(&'a BvhCrateScene),
    #[cfg(feature = "embree")]
    Embree(&'a EmbreeScene),
}

impl Peer<'_> {
    fn name(self) -> &'static str {
        match self {
            Peer::Obvhs(_) => "obvhs",
            Peer::Bvh(_) => "bvh",
            #[cfg(feature = "embree")]
            Peer::Embree(_) => "embree",
        }
    }

    /// Traces every ray (in parallel on the current rayon pool): closest hits into `hits`, or
    /// any-hit answers into `occluded` when `any`.
    fn trace(self, rays: &[Ray], any: bool, hits: &mut [Hit], occluded: &mut [bool]) {
        // Generic, so each peer's loop is compiled for it: no dynamic call per ray.
        fn run(s: &impl Tracer, rays: &[Ray], any: bool, hits: &mut [Hit], occluded: &mut [bool]) {
            if any {
                par_map(rays, occluded, |r| s.occluded(r));
            } else {
                par_map(rays, hits, |r| s.intersect(r));
            }
        }
        match self {
            Peer::Obvhs(s) => run(s, rays, any, hits, occluded),
            Peer::Bvh(s) => run(s, rays, any, hits, occluded),
            #[cfg(feature = "embree")]
            Peer::Embree(s) => run(s, rays, any, hits, occluded),
        }
    }
}

fn main() {
    let args = parse_args();
    let mut results = Vec::new();
    let mut failed = false;
    #[cfg(feature = "embree")]
    let mut embree_info = None;
    for (name, path) in &args.scenes {
        let mesh: Mesh = oavm::mesh::load(path).unwrap_or_else(|e| panic!("{e}"));
        let b = Bounds::of_points(mesh.positions.iter().copied());
        let diag = b.diagonal();

        let t = Instant::now();
        let (parts, stats) =
            oavm::build::build(&mesh, &args.opts, &oavm::build::Quiet).expect("build");
        let bytes = oavm::build::encode(&parts).expect("encode");
        let oavm_build = t.elapsed().as_secs_f64();
        let scene = Scene::from_bytes(bytes, "bench").expect("open");
        let t = Instant::now();
        let obvhs = ObvhsScene::build(&mesh.positions, &mesh.triangles);
        let obvhs_build = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let bvh = BvhCrateScene::build(&mesh.positions, &mesh.triangles);
        let bvh_build = t.elapsed().as_secs_f64();
        #[allow(unused_mut)]
        let mut peer_list = vec![Peer::Obvhs(&obvhs), Peer::Bvh(&bvh)];
        #[allow(unused_mut)]
        let mut builds = format!("obvhs {obvhs_build:.3} s, bvh {bvh_build:.3} s");
        #[cfg(feature = "embree")]
        let embree = {
            let t = Instant::now();
            let embree = EmbreeScene::build(&mesh.positions, &mesh.triangles);
            // Embree builds with its own (TBB) threads, all cores.
            builds += &format!(", embree {:.3} s", t.elapsed().as_secs_f64());
            embree
        };
        #[cfg(feature = "embree")]
        {
            peer_list.push(Peer::Embree(&embree));
            let info = embree.describe();
            if !args.json && embree_info.is_none() {
                println!("{info}");
            }
            embree_info = Some(info);
        }
        let peers = peer_list;
        eprintln!(
            "{name}: {} triangles; build oavm {oavm_build:.3} s ({} nodes), {builds}",
            mesh.triangles.len(),
            stats.nodes
        );

        let primary = Camera::framing(&b).primary_rays(1024, 768);
        let mut primary_hits = vec![Hit::MISS; primary.len()];
        scene
            .intersect_batch(&primary, &mut primary_hits)
            .expect("trace");
        let sets: Vec<(&str, Vec<Ray>, bool)> = vec![
            ("primary", primary.clone(), false),
            ("random", random_rays(&b, args.random, 1), false),
            (
                "shadow",
                shadow_rays(&primary, &primary_hits, default_light(&b)),
                true,
            ),
        ];

        for (set, rays, any) in &sets {
            let any = *any;
            // Answers once, for the cross-check.
            let mut ours = vec![Hit::MISS; rays.len()];
            let mut ours_occ = vec![0u8; rays.len()];
            let counters = if any {
                scene.occluded_batch(rays, &mut ours_occ).expect("trace")
            } else {
                scene.intersect_batch(rays, &mut ours).expect("trace")
            };
            let mut peer_hits = vec![Hit::MISS; rays.len()];
            let mut peer_occ = vec![false; rays.len()];
            let mut disagree = Vec::with_capacity(peers.len());
            for &peer in &peers {
                peer.trace(rays, any, &mut peer_hits, &mut peer_occ);
                let d = if any {
                    peer_occ
                        .iter()
                        .zip(&ours_occ)
                        .filter(|(p, o)| **p != (**o == 1))
                        .count()
                } else {
                    ours.iter()
                        .zip(&peer_hits)
                        .filter(|(a, b)| !a.agrees(b, diag))
                        .count()
                };
                let rate = d as f64 / rays.len().max(1) as f64;
                if rate > 1e-4 {
                    eprintln!(
                        "!!! {name} {set}: OAVM and {} disagree on {d} of {} rays ({:.4} %)",
                        peer.name(),
                        rays.len(),
                        rate * 100.0
                    );
                    failed = true;
                }
                disagree.push(d);
            }

            for threads in [1usize, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                let (t_oavm, t_peers) = pool.install(|| {
                    let t_oavm = best_of(args.reps, || {
                        if any {
                            scene.occluded_batch(rays, &mut ours_occ).expect("trace");
                        } else {
                            scene.intersect_batch(rays, &mut ours).expect("trace");
                        }
                    });
                    let t_peers: Vec<f64> = peers
                        .iter()
                        .map(|&peer| {
                            best_of(args.reps, || {
                                peer.trace(rays, any, &mut peer_hits, &mut peer_occ)
                            })
                        })
                        .collect();
                    (t_oavm, t_peers)
                });
                let m = |t: f64| rays.len() as f64 / t / 1e6;
                let nodes = counters.nodes_visited as f64 / counters.rays.max(1) as f64;
                let tris = counters.triangles_tested as f64 / counters.rays.max(1) as f64;
                let mut row = json!({
                    "scene": name, "set": set, "rays": rays.len(), "threads": threads,
                    "oavm_mrays_per_s": m(t_oavm),
                    "nodes_visited_per_ray": nodes,
                    "triangles_tested_per_ray": tris,
                });
                for ((peer, &t), &d) in peers.iter().zip(&t_peers).zip(&disagree) {
                    let p = peer.name();
                    row[format!("{p}_mrays_per_s")] = json!(m(t));
                    row[format!("oavm_over_{p}")] = json!(t / t_oavm);
                    row[format!("disagree_{p}")] = json!(d);
                }
                if !args.json {
                    let speeds: String = peers
                        .iter()
                        .zip(&t_peers)
                        .map(|(peer, &t)| format!(" | {} {:7.2}", peer.name(), m(t)))
                        .collect();
                    let ratios: String = peers
                        .iter()
                        .zip(&t_peers)
                        .map(|(peer, &t)| format!("  oavm/{} {:5.2}x", peer.name(), t / t_oavm))
                        .collect();
                    let disagreements: Vec<String> =
                        disagree.iter().map(|d| d.to_string()).collect();
                    println!(
                        "{name:<7} {set:<8} {threads}T {:>8} rays | oavm {:7.2}{speeds} Mrays/s |{ratios} | disagree {} | nodes {nodes:.1} tris {tris:.1} per ray",
                        rays.len(),
                        m(t_oavm),
                        disagreements.join("/"),
                    );
                }
                results.push(row);
            }
        }
    }
    if args.json {
        #[allow(unused_mut)]
        let mut out = json!({ "options": args.opts, "results": results });
        #[cfg(feature = "embree")]
        {
            out["embree"] = json!(embree_info);
        }
        println!("{}", serde_json::to_string_pretty(&out).unwrap_or_default());
    }
    if failed {
        std::process::exit(1);
    }
}
