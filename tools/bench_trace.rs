//! Benchmark: the same rays through OAVM, obvhs and the bvh crate, in one process.
//!
//!     cargo bench --bench trace -- [--scene NAME=PATH]... [--reps N] [--random N] [--json]
//!
//! Default scenes: the bunny and the dragon from `../shared/scenes`. For each scene it builds the
//! three structures from the same triangles, generates primary rays (1024x768, the default camera
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
use peers::{BvhCrateScene, ObvhsScene};
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

fn main() {
    let args = parse_args();
    let mut results = Vec::new();
    let mut failed = false;
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
        eprintln!(
            "{name}: {} triangles; build oavm {oavm_build:.3} s ({} nodes), obvhs {obvhs_build:.3} s, bvh {bvh_build:.3} s",
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
            // Answers once, for the cross-check.
            let mut ours = vec![Hit::MISS; rays.len()];
            let mut ours_occ = vec![0u8; rays.len()];
            let counters = if *any {
                scene.occluded_batch(rays, &mut ours_occ).expect("trace")
            } else {
                scene.intersect_batch(rays, &mut ours).expect("trace")
            };
            let mut obvhs_hits = vec![Hit::MISS; rays.len()];
            let mut bvh_hits = vec![Hit::MISS; rays.len()];
            let mut peer_occ = vec![false; rays.len()];
            let mut disagree = [0usize; 2];
            if *any {
                par_map(rays, &mut peer_occ, |r| obvhs.occluded(r));
                disagree[0] = peer_occ
                    .iter()
                    .zip(&ours_occ)
                    .filter(|(p, o)| **p != (**o == 1))
                    .count();
                par_map(rays, &mut peer_occ, |r| bvh.occluded(r));
                disagree[1] = peer_occ
                    .iter()
                    .zip(&ours_occ)
                    .filter(|(p, o)| **p != (**o == 1))
                    .count();
            } else {
                let agree = |a: &Hit, b: &Hit| a.agrees(b, diag);
                par_map(rays, &mut obvhs_hits, |r| obvhs.intersect(r));
                par_map(rays, &mut bvh_hits, |r| bvh.intersect(r));
                disagree[0] = ours
                    .iter()
                    .zip(&obvhs_hits)
                    .filter(|(a, b)| !agree(a, b))
                    .count();
                disagree[1] = ours
                    .iter()
                    .zip(&bvh_hits)
                    .filter(|(a, b)| !agree(a, b))
                    .count();
            }
            for (peer, d) in ["obvhs", "bvh"].iter().zip(disagree) {
                let rate = d as f64 / rays.len().max(1) as f64;
                if rate > 1e-4 {
                    eprintln!(
                        "!!! {name} {set}: OAVM and {peer} disagree on {d} of {} rays ({:.4} %)",
                        rays.len(),
                        rate * 100.0
                    );
                    failed = true;
                }
            }

            for threads in [1usize, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                let (t_oavm, t_obvhs, t_bvh) = pool.install(|| {
                    let t_oavm = best_of(args.reps, || {
                        if *any {
                            scene.occluded_batch(rays, &mut ours_occ).expect("trace");
                        } else {
                            scene.intersect_batch(rays, &mut ours).expect("trace");
                        }
                    });
                    let t_obvhs = best_of(args.reps, || {
                        if *any {
                            par_map(rays, &mut peer_occ, |r| obvhs.occluded(r));
                        } else {
                            par_map(rays, &mut obvhs_hits, |r| obvhs.intersect(r));
                        }
                    });
                    let t_bvh = best_of(args.reps, || {
                        if *any {
                            par_map(rays, &mut peer_occ, |r| bvh.occluded(r));
                        } else {
                            par_map(rays, &mut bvh_hits, |r| bvh.intersect(r));
                        }
                    });
                    (t_oavm, t_obvhs, t_bvh)
                });
                let m = |t: f64| rays.len() as f64 / t / 1e6;
                let row = json!({
                    "scene": name, "set": set, "rays": rays.len(), "threads": threads,
                    "oavm_mrays_per_s": m(t_oavm), "obvhs_mrays_per_s": m(t_obvhs), "bvh_mrays_per_s": m(t_bvh),
                    "oavm_over_obvhs": t_obvhs / t_oavm, "oavm_over_bvh": t_bvh / t_oavm,
                    "disagree_obvhs": disagree[0], "disagree_bvh": disagree[1],
                    "nodes_visited_per_ray": counters.nodes_visited as f64 / counters.rays.max(1) as f64,
                    "triangles_tested_per_ray": counters.triangles_tested as f64 / counters.rays.max(1) as f64,
                });
                if !args.json {
                    println!(
                        "{name:<7} {set:<8} {threads}T {:>8} rays | oavm {:7.2} | obvhs {:7.2} | bvh {:7.2} Mrays/s | oavm/obvhs {:5.2}x  oavm/bvh {:5.2}x | disagree {}/{} | nodes {:.1} tris {:.1} per ray",
                        rays.len(),
                        m(t_oavm),
                        m(t_obvhs),
                        m(t_bvh),
                        t_obvhs / t_oavm,
                        t_bvh / t_oavm,
                        disagree[0],
                        disagree[1],
                        counters.nodes_visited as f64 / counters.rays.max(1) as f64,
                        counters.triangles_tested as f64 / counters.rays.max(1) as f64,
                    );
                }
                results.push(row);
            }
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "options": args.opts, "results": results }))
                .unwrap_or_default()
        );
    }
    if failed {
        std::process::exit(1);
    }
}
