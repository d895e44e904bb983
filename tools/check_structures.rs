//! Correctness check of the comparison structures (issue 3): the uniform grid, KD-tree, classic
//! octree, BVH and OAVM, every one against brute force, on the same rays.
//!
//! ```text
//! cargo run --release -p oavm-compare --example check_structures -- [MESH]... [--random N] [--width W --height H]
//!     [--brute N] [--judge N] [--structure LIST]
//! ```
//!
//! Default meshes: the bunny and the dragon from `../shared/scenes`. For each, every structure of
//! `oavm_compare::STRUCTURES` (or of `--structure`, names as `oavm-bench` takes them, the
//! traversal variants included: `kdtree:restart`, ..., `oavm:ropes`; `oavm` is always added, its
//! primary hits start the shadow rays) is built from the same triangles and traces three sets: `random`
//! (`--random` rays, default 10^6, closest hit), `primary` (`--width` x `--height`, default
//! 1024x768, from the default camera, closest hit) and `shadow` (from OAVM's primary hits toward
//! the default light, any hit). Brute force (`oavm::geom::reference`: every triangle in f64,
//! sharing no code with the structures' watertight test) answers
//!
//! - a strided subset of every set (every `k`-th ray, at least `--brute` rays; default 10^4 for
//!   meshes up to 200,000 triangles, 2,000 above: brute force costs rays x triangles), against
//!   which every structure is compared; and
//! - every ray on which the structures do not all agree (up to `--judge` per set, default
//!   10^5), so a wrong answer of any structure on *any* ray of the set is found unless all of them
//!   give the same wrong answer, which the subset bounds.
//!
//! Agreement is `../shared/RAYS.md`'s rule (same hit or miss, `t` within 1e-4 of the bounding-box
//! diagonal). A structure passes a set when brute force finds it wrong on at most 0.01 % of the
//! subset and on at most 0.01 % of all rays among the judged ones. Exits 1 if any check fails.

use std::path::PathBuf;
use std::process::ExitCode;

use oavm::geom::reference;
use oavm::rays::{Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Hit, Ray};
use oavm_compare::{Accelerator, STRUCTURES, Triangles};
use rayon::prelude::*;

const REQUIRED: f64 = 0.9999;

struct Config {
    meshes: Vec<PathBuf>,
    random: usize,
    width: u32,
    height: u32,
    brute: Option<usize>,
    judge: usize,
    structures: Vec<&'static str>,
}

fn parse_args() -> Result<Config, String> {
    let mut c = Config {
        meshes: Vec::new(),
        random: 1_000_000,
        width: 1024,
        height: 768,
        brute: None,
        judge: 100_000,
        structures: STRUCTURES.to_vec(),
    };
    let mut it = std::env::args().skip(1);
    let num = |flag: &str, v: Option<String>| -> Result<usize, String> {
        v.and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("{flag} needs a non-negative integer"))
    };
    while let Some(a) = it.next() {
        match a.as_str() {
            "--random" => c.random = num(&a, it.next())?,
            "--width" => c.width = num(&a, it.next())? as u32,
            "--height" => c.height = num(&a, it.next())? as u32,
            "--brute" => c.brute = Some(num(&a, it.next())?),
            "--judge" => c.judge = num(&a, it.next())?,
            "--structure" => {
                let list: Vec<String> = it
                    .next()
                    .ok_or("--structure needs a list")?
                    .split(',')
                    .map(str::to_string)
                    .collect();
                c.structures =
                    oavm_compare::bench::parse_structures(&list).map_err(|e| e.to_string())?;
                if !c.structures.contains(&"oavm") {
                    c.structures.push("oavm");
                }
            }
            f if f.starts_with('-') => return Err(format!("unknown flag {f}")),
            p => c.meshes.push(PathBuf::from(p)),
        }
    }
    if c.meshes.is_empty() {
        let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
        c.meshes.push(shared.join("bunny/bun_zipper.ply"));
        c.meshes.push(shared.join("dragon/dragon_vrip.ply"));
    }
    Ok(c)
}

/// An answer: closest hit or any hit, compared by RAYS.md's rule.
#[derive(Clone, Copy, PartialEq)]
enum Answer {
    Closest(Hit),
    Any(bool),
}

fn agree(a: Answer, b: Answer, diag: f64) -> bool {
    match (a, b) {
        (Answer::Closest(x), Answer::Closest(y)) => x.agrees(&y, diag),
        (Answer::Any(x), Answer::Any(y)) => x == y,
        _ => false,
    }
}

fn answers(acc: &dyn Accelerator, rays: &[Ray], any: bool) -> Vec<Answer> {
    if any {
        let mut out = vec![0u8; rays.len()];
        oavm_compare::occluded_batch(acc, rays, &mut out);
        out.into_iter().map(|o| Answer::Any(o == 1)).collect()
    } else {
        let mut out = vec![Hit::MISS; rays.len()];
        oavm_compare::intersect_batch(acc, rays, &mut out);
        out.into_iter().map(Answer::Closest).collect()
    }
}

fn brute_answer(tris: &[[[f32; 3]; 3]], ray: &Ray, any: bool) -> Answer {
    if any {
        Answer::Any(reference::occluded(tris, ray))
    } else {
        Answer::Closest(reference::closest(tris, ray))
    }
}

fn run(c: &Config) -> Result<bool, String> {
    let mut ok = true;
    let opts = BuildOptions::default();
    println!(
        "{:<8} {:<8} {:<18} {:>9} {:>16} {:>10} {:>20} {:>6}",
        "mesh", "set", "struct", "rays", "brute subset", "agree %", "wrong among judged", "pass"
    );
    for path in &c.meshes {
        let name = path
            .file_stem()
            .map_or("mesh".into(), |s| s.to_string_lossy().into_owned());
        let mesh = oavm::mesh::load(path).map_err(|e| e.to_string())?;
        let corners = mesh.corners();
        let tris = Triangles::from_mesh(&mesh).map_err(|e| e.to_string())?;
        let b = Bounds::of_points(tris.v.iter().flatten().copied());
        let diag = b.diagonal();
        let accs: Vec<Box<dyn Accelerator>> = c
            .structures
            .iter()
            .map(|s| {
                oavm_compare::build_structure(s, &mesh, &tris, &opts).map_err(|e| e.to_string())
            })
            .collect::<Result<_, _>>()?;
        let oavm = accs
            .iter()
            .position(|a| a.stats().name == "oavm")
            .ok_or("no oavm structure")?;
        let primary = Camera::framing(&b).primary_rays(c.width, c.height);
        let mut primary_hits = vec![Hit::MISS; primary.len()];
        oavm_compare::intersect_batch(accs[oavm].as_ref(), &primary, &mut primary_hits);
        let shadow = shadow_rays(&primary, &primary_hits, default_light(&b));
        let sets: [(&str, Vec<Ray>, bool); 3] = [
            ("random", random_rays(&b, c.random, 1), false),
            ("primary", primary, false),
            ("shadow", shadow, true),
        ];
        let want = c
            .brute
            .unwrap_or(if tris.len() <= 200_000 { 10_000 } else { 2_000 });
        for (set, rays, any) in &sets {
            let all: Vec<Vec<Answer>> = accs
                .iter()
                .map(|a| answers(a.as_ref(), rays, *any))
                .collect();
            let stride = (rays.len() / want.max(1)).max(1);
            let subset: Vec<usize> = if want == 0 {
                Vec::new()
            } else {
                (0..rays.len()).step_by(stride).collect()
            };
            // Rays on which the structures do not all agree with OAVM.
            let split: Vec<usize> = (0..rays.len())
                .filter(|&i| all.iter().any(|a| !agree(a[i], all[oavm][i], diag)))
                .take(c.judge)
                .collect();
            let judged: Vec<usize> = {
                let mut v: Vec<usize> = subset.iter().chain(&split).copied().collect();
                v.sort_unstable();
                v.dedup();
                v
            };
            let truth: Vec<Answer> = judged
                .par_iter()
                .map(|&i| brute_answer(&corners, &rays[i], *any))
                .collect();
            let truth_of = |i: usize| truth[judged.binary_search(&i).unwrap_or(0)];
            for (a, acc) in all.iter().zip(&accs) {
                let sub_wrong = subset
                    .iter()
                    .filter(|&&i| !agree(a[i], truth_of(i), diag))
                    .count();
                let split_wrong = split
                    .iter()
                    .filter(|&&i| !agree(a[i], truth_of(i), diag))
                    .count();
                let sub_ok = sub_wrong as f64 <= (1.0 - REQUIRED) * subset.len() as f64;
                let all_ok = split_wrong as f64 <= (1.0 - REQUIRED) * rays.len() as f64;
                let pass = sub_ok && all_ok;
                ok &= pass;
                println!(
                    "{:<8} {:<8} {:<18} {:>9} {:>7} / {:<6} {:>10.4} {:>9} of {:<8} {:>6}",
                    name,
                    set,
                    acc.stats().name,
                    rays.len(),
                    sub_wrong,
                    subset.len(),
                    100.0 * (1.0 - sub_wrong as f64 / subset.len().max(1) as f64),
                    split_wrong,
                    split.len(),
                    if pass { "ok" } else { "FAIL" }
                );
            }
        }
    }
    Ok(ok)
}

fn main() -> ExitCode {
    match parse_args().and_then(|c| run(&c)) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => {
            eprintln!("check_structures: FAILED");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("check_structures: {e}");
            ExitCode::from(2)
        }
    }
}
