//! Smoke test of the peer tracers (`tools/peers/mod.rs`): builds the obvhs and `bvh` crate peers
//! (and Embree with the `embree` feature: `tools/embree.sh cargo run --release --example
//! peers_smoke --features embree,tools`) on a mesh (the Stanford bunny by default), traces seeded
//! random rays through them and through brute force, and checks that they agree as `../shared/RAYS.md` defines it (both miss, or both
//! hit with `|t1 - t2| <= 1e-4 * L`, `L` the bounding-box diagonal) on at least 99.99 % of rays.
//! Prints build times and Mrays/s, single-threaded and with rayon. Exits 1 on disagreement.
//!
//! ```text
//! cargo run --release --features tools --example peers_smoke [-- [--compare] [--speed-only] [MESH.obj]]
//! ```
//!
//! `--compare` also times every obvhs build preset and every `bvh` crate traversal, which is how
//! `OBVHS_PRESET` and `BVH_TRAVERSAL` were chosen; `--speed-only` skips the checks (and brute
//! force, which takes most of the run).

#[path = "peers/mod.rs"]
mod peers;

use std::hint::black_box;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use oavm::{Hit, Mesh, Ray};
use peers::{BvhCrateScene, BvhTraversal, ObvhsScene};
use rayon::prelude::*;

const DEFAULT_MESH: &str = "../shared/scenes/bunny/stanford-bunny.obj";
const SEED: u64 = 0x5eed_0a7d_2024;
/// Required share of rays on which two tracers agree.
const REQUIRED: f64 = 0.9999;

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => {
            eprintln!("peers_smoke: FAILED (see the lines marked FAIL)");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("peers_smoke: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<bool, String> {
    let mut compare = false;
    let mut speed_only = false;
    let mut path = None;
    for arg in std::env::args().skip(1) {
        match arg.as_str() {
            "--compare" => compare = true,
            "--speed-only" => speed_only = true,
            "-h" | "--help" => {
                println!(
                    "usage: peers_smoke [--compare] [--speed-only] [MESH.obj]   (default {DEFAULT_MESH})"
                );
                return Ok(true);
            }
            a if a.starts_with('-') => return Err(format!("unknown option {a}")),
            a => path = Some(a.to_string()),
        }
    }
    let path = path.unwrap_or_else(|| {
        // Relative to the crate, so the tool runs from any directory through cargo.
        format!("{}/{DEFAULT_MESH}", env!("CARGO_MANIFEST_DIR"))
    });

    let Mesh {
        positions,
        triangles,
        ..
    } = load_obj(&path)?;
    let (lo, hi) = bounds(&positions);
    let diag = (0..3)
        .map(|i| ((hi[i] - lo[i]) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let tol = (1e-4 * diag) as f32;
    println!(
        "mesh {path}: {} triangles, {} vertices in use, bbox diagonal L = {diag:.6}, tolerance 1e-4 L = {tol:.3e}",
        triangles.len(),
        positions.len()
    );
    println!("rayon threads: {}", rayon::current_num_threads());

    // Build.
    let start = Instant::now();
    let obvhs = ObvhsScene::build(&positions, &triangles);
    let obvhs_build = start.elapsed();
    let start = Instant::now();
    let bvhc = BvhCrateScene::build(&positions, &triangles);
    let bvh_build = start.elapsed();
    println!(
        "build obvhs CWBVH ({}, single-threaded): {:.3} s, {} nodes",
        peers::OBVHS_PRESET,
        obvhs_build.as_secs_f64(),
        obvhs.node_count()
    );
    println!(
        "build bvh crate (binned SAH, build_par + flatten): {:.3} s, depth {}",
        bvh_build.as_secs_f64(),
        bvhc.depth()
    );

    // Rays.
    let sets = ray_sets(lo, hi, diag as f32);

    let mut ok = true;
    if !speed_only {
        ok &= check(&positions, &triangles, &sets, diag, &obvhs, &bvhc);
        ok &= check_tiny_meshes();
    }

    // Speed, on the primary set.
    let primary = &sets[0].rays;
    println!(
        "\nspeed on set `{}` ({} rays; best of repeated passes)",
        sets[0].name,
        primary.len()
    );
    println!(
        "{:<26}{:>14}{:>14}{:>14}{:>14}",
        "", "closest 1T", "closest par", "occluded 1T", "occluded par"
    );
    speed_row("obvhs", primary, &|r| obvhs.intersect(r), &|r| {
        obvhs.occluded(r)
    });
    speed_row("bvh", primary, &|r| bvhc.intersect(r), &|r| {
        bvhc.occluded(r)
    });
    #[cfg(feature = "embree")]
    {
        let embree = peers::EmbreeScene::build(&positions, &triangles);
        speed_row("embree", primary, &|r| embree.intersect(r), &|r| {
            embree.occluded(r)
        });
    }

    if compare {
        let all: Vec<Ray> = sets.iter().flat_map(|s| s.rays.iter().copied()).collect();
        ok &= compare_choices(&positions, &triangles, primary, &all, &obvhs, &bvhc, diag);
    }

    println!(
        "\n{}",
        if ok {
            "peers_smoke: all checks passed"
        } else {
            "peers_smoke: some checks FAILED"
        }
    );
    Ok(ok)
}

// ---------------------------------------------------------------------------------------------

/// The agreement checks: every peer against brute force and each other, on every ray set.
fn check(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    sets: &[RaySet],
    diag: f64,
    obvhs: &ObvhsScene,
    bvhc: &BvhCrateScene,
) -> bool {
    let all: Vec<Ray> = sets.iter().flat_map(|s| s.rays.iter().copied()).collect();
    let mut ok = true;
    // Reference answers.
    let start = Instant::now();
    let reference: Vec<Hit> = all
        .par_iter()
        .map(|r| peers::brute_force_intersect(positions, triangles, r))
        .collect();
    let bf_time = start.elapsed();
    let reference_occl: Vec<bool> = all
        .par_iter()
        .map(|r| peers::brute_force_occluded(positions, triangles, r))
        .collect();
    println!(
        "brute force: {} rays in {:.2} s with rayon ({:.4} Mrays/s)",
        all.len(),
        bf_time.as_secs_f64(),
        all.len() as f64 / bf_time.as_secs_f64() / 1e6
    );
    let hits = reference.iter().filter(|h| h.is_hit()).count();
    println!("rays hitting (brute force): {hits} of {}", all.len());

    let obvhs_hits: Vec<Hit> = all.par_iter().map(|r| obvhs.intersect(r)).collect();
    let bvh_hits: Vec<Hit> = all.par_iter().map(|r| bvhc.intersect(r)).collect();
    let obvhs_occl: Vec<bool> = all.par_iter().map(|r| obvhs.occluded(r)).collect();
    let bvh_occl: Vec<bool> = all.par_iter().map(|r| bvhc.occluded(r)).collect();

    println!(
        "\nagreement (closest hit: both miss, or both hit with |dt| <= 1e-4 L; occlusion: same answer)"
    );
    print!("{:<34}", "");
    for set in sets {
        print!("{:>14}", set.name);
    }
    println!("{:>16}", "all");
    let pairs: [(&str, &[Hit], &[Hit]); 3] = [
        ("obvhs vs brute force", &obvhs_hits, &reference),
        ("bvh vs brute force", &bvh_hits, &reference),
        ("obvhs vs bvh", &obvhs_hits, &bvh_hits),
    ];
    for (name, a, b) in pairs {
        let agree: Vec<bool> = a.iter().zip(b).map(|(x, y)| x.agrees(y, diag)).collect();
        ok &= report(name, sets, &agree, REQUIRED);
    }
    let prim_same = |a: &[Hit], b: &[Hit]| {
        a.iter()
            .zip(b)
            .filter(|(x, y)| x.is_hit() && x.prim == y.prim)
            .count()
    };
    let occl_pairs: [(&str, &[bool], &[bool]); 2] = [
        (
            "obvhs occluded vs brute force",
            &obvhs_occl,
            &reference_occl,
        ),
        ("bvh occluded vs brute force", &bvh_occl, &reference_occl),
    ];
    for (name, a, b) in occl_pairs {
        let agree: Vec<bool> = a.iter().zip(b).map(|(x, y)| x == y).collect();
        ok &= report(name, sets, &agree, REQUIRED);
    }
    // Occlusion must be exactly "the closest-hit query found something", peer by peer.
    let self_pairs: [(&str, &[bool], &[Hit]); 3] = [
        ("obvhs occluded == hit", &obvhs_occl, &obvhs_hits),
        ("bvh occluded == hit", &bvh_occl, &bvh_hits),
        ("brute occluded == hit", &reference_occl, &reference),
    ];
    for (name, a, b) in self_pairs {
        let agree: Vec<bool> = a.iter().zip(b).map(|(x, y)| *x == y.is_hit()).collect();
        ok &= report(name, sets, &agree, 1.0);
    }
    println!(
        "same primitive id where both hit: obvhs/brute {}, bvh/brute {} of {hits} (ties on shared edges may differ)",
        prim_same(&obvhs_hits, &reference),
        prim_same(&bvh_hits, &reference)
    );

    // Inclusive ends: re-trace rays with tmax (then tmin) set to the t each peer found itself.
    println!(
        "\nend points: each peer re-traces its own hits of set `{}` with tmax = t, then tmin = t",
        sets[0].name
    );
    let own_hits = |hits: &[Hit]| -> Vec<(Ray, Hit)> {
        sets[0]
            .rays
            .iter()
            .zip(hits)
            .filter(|(_, h)| h.is_hit())
            .map(|(r, h)| (*r, *h))
            .take(2000)
            .collect()
    };
    // `checked == false` only reports.
    let ends = |name: &str,
                cases: &[(Ray, Hit)],
                trace: &(dyn Fn(&Ray) -> Hit + Sync),
                checked: bool|
     -> bool {
        let bad_tmax = cases
            .par_iter()
            .filter(|(r, h)| trace(&Ray { tmax: h.t, ..*r }).t != h.t)
            .count();
        let bad_tmin = cases
            .par_iter()
            .filter(|(r, h)| trace(&Ray { tmin: h.t, ..*r }).t != h.t)
            .count();
        let fine = bad_tmax == 0 && bad_tmin == 0;
        println!(
            "  {name:<32} {} rays: t == tmax lost {bad_tmax}, t == tmin lost {bad_tmin}  {}",
            cases.len(),
            if !checked {
                "(info)"
            } else if fine {
                "ok"
            } else {
                "FAIL"
            }
        );
        fine || !checked
    };
    ok &= ends(
        "obvhs",
        &own_hits(&obvhs_hits),
        &|r| obvhs.intersect(r),
        true,
    );
    ok &= ends("bvh", &own_hits(&bvh_hits), &|r| bvhc.intersect(r), true);
    ok &= ends(
        "brute force",
        &own_hits(&reference),
        &|r| peers::brute_force_intersect(positions, triangles, r),
        true,
    );
    let stock_hits: Vec<Hit> = sets[0]
        .rays
        .par_iter()
        .map(|r| obvhs.intersect_stock(r))
        .collect();
    ends(
        "obvhs stock ray_traverse",
        &own_hits(&stock_hits),
        &|r| obvhs.intersect_stock(r),
        false,
    );

    #[cfg(feature = "embree")]
    {
        ok &= check_embree(
            positions,
            triangles,
            sets,
            &all,
            &reference,
            &reference_occl,
            diag,
        );
    }

    // What obvhs's own entry point would have answered (information, not a check).
    let stock: Vec<Hit> = all.par_iter().map(|r| obvhs.intersect_stock(r)).collect();
    let agree: Vec<bool> = stock
        .iter()
        .zip(&reference)
        .map(|(x, y)| x.agrees(y, diag))
        .collect();
    report("(info) obvhs stock ray_traverse", sets, &agree, 0.0);

    ok
}

/// Embree (feature `embree`) against brute force on every set: closest hits, occlusion and
/// consistency of the two (checked); hits at exactly `tmin`/`tmax` (reported).
#[cfg(feature = "embree")]
fn check_embree(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    sets: &[RaySet],
    all: &[Ray],
    reference: &[Hit],
    reference_occl: &[bool],
    diag: f64,
) -> bool {
    let start = Instant::now();
    let embree = peers::EmbreeScene::build(positions, triangles);
    println!(
        "\n{}: build {:.3} s (Embree's own threads)",
        embree.describe(),
        start.elapsed().as_secs_f64()
    );
    let hits: Vec<Hit> = all.par_iter().map(|r| embree.intersect(r)).collect();
    let occl: Vec<bool> = all.par_iter().map(|r| embree.occluded(r)).collect();
    let mut ok = true;
    let agree: Vec<bool> = hits
        .iter()
        .zip(reference)
        .map(|(x, y)| x.agrees(y, diag))
        .collect();
    ok &= report("embree vs brute force", sets, &agree, REQUIRED);
    let agree: Vec<bool> = occl
        .iter()
        .zip(reference_occl)
        .map(|(x, y)| x == y)
        .collect();
    ok &= report("embree occluded vs brute force", sets, &agree, REQUIRED);
    let agree: Vec<bool> = occl
        .iter()
        .zip(&hits)
        .map(|(x, y)| *x == y.is_hit())
        .collect();
    ok &= report("embree occluded == hit", sets, &agree, 1.0);
    let both = hits
        .iter()
        .zip(reference)
        .filter(|(x, y)| x.is_hit() && y.is_hit())
        .count();
    let same = hits
        .iter()
        .zip(reference)
        .filter(|(x, y)| x.is_hit() && x.prim == y.prim)
        .count();
    println!("same primitive id where both hit: embree/brute {same} of {both}");
    // Inclusive ends, as for the other peers: re-trace own hits with tmax = t, then tmin = t.
    // Information only: Embree's Möller test compares in scaled units (`absDen * tnear < T`,
    // `T <= absDen * tfar`) and reports `t = T / absDen`, so its own `t` given back as an end
    // can fall either side; its documentation guarantees nothing for hits "exactly at (or very
    // close to) tnear or tfar". No benchmark ray has a hit at an end.
    let cases: Vec<(Ray, Hit)> = sets[0]
        .rays
        .iter()
        .zip(&hits)
        .filter(|(_, h)| h.is_hit())
        .map(|(r, h)| (*r, *h))
        .take(2000)
        .collect();
    let bad_tmax = cases
        .par_iter()
        .filter(|(r, h)| embree.intersect(&Ray { tmax: h.t, ..*r }).t != h.t)
        .count();
    let bad_tmin = cases
        .par_iter()
        .filter(|(r, h)| embree.intersect(&Ray { tmin: h.t, ..*r }).t != h.t)
        .count();
    println!(
        "  {:<32} {} rays: t == tmax lost {bad_tmax}, t == tmin lost {bad_tmin}  (info)",
        "embree",
        cases.len(),
    );
    ok
}

/// Empty, one-triangle and degenerate meshes, with rays whose answers are known exactly.
fn check_tiny_meshes() -> bool {
    let (o, z) = ([0.25, 0.25, 1.0], [-0.0, 0.0, -2.0]);
    let up = |tmin, tmax| Ray::new(o, z, tmin, tmax);
    let one = Mesh {
        geometries: Vec::new(),
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        triangles: vec![[0, 1, 2]],
    };
    // Triangle 0 is degenerate (a repeated corner) and lies across the ray; triangle 1 is `one`
    // moved down by 1.
    let degenerate = Mesh {
        positions: vec![
            [0.0, 0.0, 0.5],
            [1.0, 1.0, 0.5],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, -1.0],
            [0.0, 1.0, -1.0],
        ],
        triangles: vec![[0, 1, 0], [2, 3, 4]],
    };
    let empty = Mesh::default();
    let hit = |t, prim| Hit { t, prim };
    let cases: Vec<(&str, &Mesh, Ray, Hit)> = vec![
        ("empty mesh", &empty, up(0.0, f32::INFINITY), Hit::MISS),
        ("one triangle", &one, up(0.0, f32::INFINITY), hit(0.5, 0)),
        ("t == tmax", &one, up(0.0, 0.5), hit(0.5, 0)),
        ("t == tmin", &one, up(0.5, 0.5), hit(0.5, 0)),
        ("t > tmax", &one, up(0.0, 0.4999), Hit::MISS),
        ("t < tmin", &one, up(0.5001, f32::INFINITY), Hit::MISS),
        (
            "behind, tmin < 0",
            &one,
            Ray::new([0.25, 0.25, -1.0], z, -1.0, 0.0),
            hit(-0.5, 0),
        ),
        (
            "t < 1e-4",
            &one,
            Ray::new([0.25, 0.25, 1e-5], z, 0.0, 1.0),
            hit(5e-6, 0),
        ),
        ("invalid (tmin > tmax)", &one, up(1.0, 0.0), Hit::MISS),
        (
            "degenerate skipped",
            &degenerate,
            up(0.0, f32::INFINITY),
            hit(1.0, 1),
        ),
    ];
    let mut ok = true;
    println!("\ntiny meshes (exact answers)");
    for (name, mesh, ray, want) in cases {
        let obvhs = ObvhsScene::build(&mesh.positions, &mesh.triangles);
        let bvhc = BvhCrateScene::build(&mesh.positions, &mesh.triangles);
        let brute = peers::brute_force_intersect(&mesh.positions, &mesh.triangles, &ray);
        #[allow(unused_mut)]
        let mut got = vec![
            ("obvhs", obvhs.intersect(&ray)),
            ("bvh", bvhc.intersect(&ray)),
            ("brute force", brute),
        ];
        #[allow(unused_mut)]
        let mut occl = vec![
            obvhs.occluded(&ray),
            bvhc.occluded(&ray),
            peers::brute_force_occluded(&mesh.positions, &mesh.triangles, &ray),
        ];
        #[cfg(feature = "embree")]
        {
            let embree = peers::EmbreeScene::build(&mesh.positions, &mesh.triangles);
            got.push(("embree", embree.intersect(&ray)));
            occl.push(embree.occluded(&ray));
        }
        for ((peer, h), o) in got.into_iter().zip(occl) {
            // The one-triangle t are exact in every formulation (powers of two), so compare exactly.
            if h != want || o != want.is_hit() {
                println!("  {name:<24} {peer}: got {h:?} occluded {o}, want {want:?}  FAIL");
                ok = false;
            }
        }
    }
    if ok {
        #[cfg(not(feature = "embree"))]
        println!("  obvhs, bvh and brute force: all cases ok");
        #[cfg(feature = "embree")]
        println!("  obvhs, bvh, embree and brute force: all cases ok");
    }
    ok
}

/// One agreement line: per set and overall; `required` applies to the overall share.
fn report(name: &str, sets: &[RaySet], agree: &[bool], required: f64) -> bool {
    print!("{name:<34}");
    let mut at = 0;
    for set in sets {
        let n = set.rays.len();
        let good = agree[at..at + n].iter().filter(|&&a| a).count();
        print!("{:>14}", format!("{good}/{n}"));
        at += n;
    }
    let good = agree.iter().filter(|&&a| a).count();
    let share = good as f64 / agree.len() as f64;
    let pass = share >= required;
    println!(
        "{:>16}  {}",
        format!("{:.4} %", 100.0 * share),
        if required == 0.0 {
            ""
        } else if pass {
            "ok"
        } else {
            "FAIL"
        }
    );
    pass
}

/// Best pass of a closure over all rays, in Mrays/s, single-threaded or with rayon.
fn mrays(rays: &[Ray], parallel: bool, f: &(dyn Fn(&Ray) -> f32 + Sync)) -> f64 {
    let mut best = Duration::MAX;
    let mut spent = Duration::ZERO;
    let mut passes = 0;
    while passes < 3 || (spent < Duration::from_millis(500) && passes < 1000) {
        let start = Instant::now();
        let sum: f32 = if parallel {
            rays.par_iter().map(|r| f(black_box(r))).sum()
        } else {
            rays.iter().map(|r| f(black_box(r))).sum()
        };
        black_box(sum);
        let took = start.elapsed();
        best = best.min(took);
        spent += took;
        passes += 1;
    }
    rays.len() as f64 / best.as_secs_f64() / 1e6
}

fn speed_row(
    name: &str,
    rays: &[Ray],
    closest: &(dyn Fn(&Ray) -> Hit + Sync),
    occluded: &(dyn Fn(&Ray) -> bool + Sync),
) {
    // Sum finite t (and hit counts) so that no pass can be optimised away.
    let c = |r: &Ray| {
        let h = closest(r);
        if h.is_hit() { h.t } else { 0.0 }
    };
    let o = |r: &Ray| occluded(r) as u32 as f32;
    println!(
        "{name:<26}{:>14.3}{:>14.3}{:>14.3}{:>14.3}",
        mrays(rays, false, &c),
        mrays(rays, true, &c),
        mrays(rays, false, &o),
        mrays(rays, true, &o)
    );
}

/// `--compare`: every obvhs preset and every `bvh` crate traversal, timed on the same rays.
fn compare_choices(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    rays: &[Ray],
    all: &[Ray],
    obvhs: &ObvhsScene,
    bvhc: &BvhCrateScene,
    diag: f64,
) -> bool {
    let mut ok = true;
    println!(
        "\nobvhs presets (build single-threaded; closest hit: work per ray and Mrays/s, same rays)"
    );
    println!(
        "{:<18}{:>10}{:>8}{:>12}{:>12}{:>14}{:>14}",
        "preset", "build s", "nodes", "nodes/ray", "tris/ray", "closest 1T", "occluded 1T"
    );
    let mut answers: Option<Vec<Hit>> = None;
    for (name, params) in peers::obvhs_presets() {
        let start = Instant::now();
        let scene = ObvhsScene::build_with(positions, triangles, params);
        let build = start.elapsed();
        let c = |r: &Ray| {
            let h = scene.intersect(r);
            if h.is_hit() { h.t } else { 0.0 }
        };
        let o = |r: &Ray| scene.occluded(r) as u32 as f32;
        let mut stats = peers::TraceStats::default();
        for r in rays {
            scene.intersect_counting(r, &mut stats);
        }
        println!(
            "{name:<18}{:>10.3}{:>8}{:>12.2}{:>12.2}{:>14.3}{:>14.3}",
            build.as_secs_f64(),
            scene.node_count(),
            stats.nodes as f64 / rays.len() as f64,
            stats.triangles as f64 / rays.len() as f64,
            mrays(rays, false, &c),
            mrays(rays, false, &o)
        );
        let hits: Vec<Hit> = rays.par_iter().map(|r| scene.intersect(r)).collect();
        if let Some(first) = &answers {
            let good = hits
                .iter()
                .zip(first)
                .filter(|(a, b)| a.agrees(b, diag))
                .count();
            if (good as f64) < REQUIRED * rays.len() as f64 {
                println!(
                    "  FAIL: {name} agrees with fastest_build on only {good} of {} rays",
                    rays.len()
                );
                ok = false;
            }
        } else {
            answers = Some(hits);
        }
    }
    let stock = |r: &Ray| {
        let h = obvhs.intersect_stock(r);
        if h.is_hit() { h.t } else { 0.0 }
    };
    println!(
        "{:<18}{:>68.3}   (obvhs's own ray_traverse, {}, for the cost of our node test)",
        "stock traversal",
        mrays(rays, false, &stock),
        peers::OBVHS_PRESET
    );

    println!(
        "\nbvh crate traversals (closest hit, single-threaded Mrays/s; {:?} = default)",
        peers::BVH_TRAVERSAL
    );
    // Answers are compared on every set (negative tmin takes other paths), speed on `rays`.
    let default: Vec<Hit> = all.par_iter().map(|r| bvhc.intersect(r)).collect();
    for traversal in BvhTraversal::ALL {
        let c = |r: &Ray| {
            let h = bvhc.intersect_with(r, traversal);
            if h.is_hit() { h.t } else { 0.0 }
        };
        let hits: Vec<Hit> = all
            .par_iter()
            .map(|r| bvhc.intersect_with(r, traversal))
            .collect();
        let same = hits.iter().zip(&default).filter(|(a, b)| a == b).count();
        println!(
            "{:<18}{:>14.3}   identical answers: {same}/{}",
            format!("{traversal:?}"),
            mrays(rays, false, &c),
            all.len()
        );
        ok &= same == all.len();
    }
    ok
}

// ---------------------------------------------------------------------------------------------
// Mesh

/// Positions and triangles of an OBJ, models concatenated in file order (ids as in RAYS.md).
/// tobj keeps only the vertices that faces use.
fn load_obj(path: &str) -> Result<Mesh, String> {
    let options = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let (models, _materials) =
        tobj::load_obj(path, &options).map_err(|e| format!("{path}: {e}"))?;
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for model in &models {
        let base = positions.len() as u32;
        let mesh = &model.mesh;
        positions.extend(mesh.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        triangles.extend(
            mesh.indices
                .chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]]),
        );
    }
    if triangles.is_empty() {
        return Err(format!("{path}: no triangles"));
    }
    Ok(Mesh {
        positions,
        triangles,
    })
}

fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for i in 0..3 {
            lo[i] = lo[i].min(p[i]);
            hi[i] = hi[i].max(p[i]);
        }
    }
    (lo, hi)
}

// ---------------------------------------------------------------------------------------------
// Rays

/// SplitMix64 (Steele, Lea, Flood 2014): tiny, seeded, good enough for test rays.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    fn coin(&mut self) -> bool {
        self.next_u64() >> 63 == 1
    }

    /// Uniform on the unit sphere (Archimedes: z uniform, azimuth uniform).
    fn sphere(&mut self) -> [f32; 3] {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f32::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        [r * phi.cos(), r * phi.sin(), z]
    }
}

struct RaySet {
    name: &'static str,
    rays: Vec<Ray>,
}

fn ray_sets(lo: [f32; 3], hi: [f32; 3], diag: f32) -> Vec<RaySet> {
    let mut rng = SplitMix64(SEED);
    // Origins uniform in the bounding box enlarged by 10 % (5 % on each side).
    let origin = |rng: &mut SplitMix64| -> [f32; 3] {
        std::array::from_fn(|i| {
            let pad = 0.05 * (hi[i] - lo[i]);
            rng.range(lo[i] - pad, hi[i] + pad)
        })
    };
    let len = |d: [f32; 3]| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();

    // Half the directions unit length, half scaled by a length in [0.5, 3).
    let random = (0..20_000)
        .map(|i| {
            let o = origin(&mut rng);
            let s = if i % 2 == 0 { 1.0 } else { rng.range(0.5, 3.0) };
            let d = rng.sphere().map(|c| c * s);
            Ray::new(o, d, 0.0, f32::INFINITY)
        })
        .collect();

    // Segments: tmin > 0, finite tmax, both in units of the (scaled) direction.
    let segments = (0..2_000)
        .map(|_| {
            let o = origin(&mut rng);
            let d = rng.sphere().map(|c| c * rng.range(0.5, 3.0));
            let unit = diag / len(d);
            let tmin = rng.range(0.001, 0.25) * unit;
            let tmax = tmin + rng.range(0.0, 0.75) * unit;
            Ray::new(o, d, tmin, tmax)
        })
        .collect();

    // Axis-aligned, the other components +0.0 or -0.0 at random.
    let axis = (0..1_000)
        .map(|_| {
            let o = origin(&mut rng);
            let k = (rng.next_u64() % 3) as usize;
            let s = if rng.coin() { 1.0 } else { -1.0 } * rng.range(0.5, 3.0);
            let d = std::array::from_fn(|i| {
                if i == k {
                    s
                } else if rng.coin() {
                    -0.0
                } else {
                    0.0
                }
            });
            Ray::new(o, d, 0.0, f32::INFINITY)
        })
        .collect();

    // Segments reaching behind the origin: tmin < 0, tmax infinite or finite.
    let behind = (0..1_000)
        .map(|i| {
            let o = origin(&mut rng);
            let d = rng.sphere().map(|c| c * rng.range(0.5, 3.0));
            let unit = diag / len(d);
            let tmin = -rng.range(0.0, 1.0) * unit;
            let tmax = if i % 2 == 0 {
                f32::INFINITY
            } else {
                rng.range(-0.5, 0.5) * unit
            };
            Ray::new(o, d, tmin, tmax.max(tmin))
        })
        .collect();

    // Rays that must miss (RAYS.md): non-finite, zero direction, tmin > tmax.
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let mid = std::array::from_fn(|i| 0.5 * (lo[i] + hi[i]));
    let invalid = vec![
        Ray::new([nan, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, inf),
        Ray::new(mid, [0.0, 0.0, 0.0], 0.0, inf),
        Ray::new(mid, [-0.0, 0.0, -0.0], 0.0, inf),
        Ray::new(mid, [inf, 0.0, 0.0], 0.0, inf),
        Ray::new(mid, [nan, 1.0, 0.0], 0.0, inf),
        Ray::new(mid, [0.0, 1.0, 0.0], 1.0, 0.5),
        Ray::new(mid, [0.0, 1.0, 0.0], nan, inf),
        Ray::new(mid, [0.0, 1.0, 0.0], 0.0, nan),
    ];

    vec![
        RaySet {
            name: "random",
            rays: random,
        },
        RaySet {
            name: "segments",
            rays: segments,
        },
        RaySet {
            name: "axis ±0",
            rays: axis,
        },
        RaySet {
            name: "tmin<0",
            rays: behind,
        },
        RaySet {
            name: "invalid",
            rays: invalid,
        },
    ]
}
