//! End-to-end tests of `oavm-bench`, the OAVM paper's comparison driver: the real binary on real
//! scenes (the Cornell box, BART's museum, the bundled bunny), small ray sets, in a temporary
//! directory. It must build all five structures, find no disagreement with OAVM, report the
//! figures the paper's tables need, trace ray files in RAYS.md's formats, and refuse bad usage.
//! OAVM, the reference of the binary's own check, is itself checked against brute force
//! (`oavm::geom::reference`, the f64 brute force) on the same rays, and so are the hit counts the binary reports.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use oavm::geom::reference;
use oavm::pack::LeafKind;
use oavm::rays::{self, Bounds};
use oavm::{BuildOptions, Hit, Mesh, Ray};
use oavm_compare::bench::{self, BenchScene};
use oavm_compare::{OavmAccel, Triangles};
use rayon::prelude::*;
use serde_json::Value;
use tempfile::TempDir;

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oavm-bench"))
}

fn run(cmd: &mut Command) -> Output {
    cmd.stdin(Stdio::null())
        .output()
        .expect("cannot spawn oavm-bench")
}

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}--- stderr\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

const SMALL: [&str; 10] = [
    "--random",
    "3000",
    "--width",
    "48",
    "--height",
    "36",
    "--reps",
    "1",
    "--threads",
    "1",
];

/// `SMALL` as the library's options, OAVM's leaves of kind `leaf` (`--leaf`).
fn small_options(leaf: LeafKind) -> bench::Options {
    bench::Options {
        build: BuildOptions::with_leaf(leaf),
        random: 3000,
        width: 48,
        height: 36,
        reps: 1,
        threads: vec![1],
    }
}

/// A scene of `../shared/scenes`; its absence is a failure, not a reason to skip.
fn shared(rel: &str) -> PathBuf {
    let p = common::shared_scene(rel);
    assert!(
        p.is_file(),
        "{} is missing: these tests need ../shared/scenes",
        p.display()
    );
    p
}

/// Brute-force answers to `rays` (closest hits, or any-hit answers for `any`) and how many hit.
fn brute_answers(mesh: &Mesh, rays: &[Ray], any: bool) -> (bench::Answers, usize) {
    let tris = mesh.corners();
    let a = if any {
        bench::Answers::Any(
            rays.par_iter()
                .map(|r| reference::occluded(&tris, r) as u8)
                .collect(),
        )
    } else {
        bench::Answers::Closest(
            rays.par_iter()
                .map(|r| reference::closest(&tris, r))
                .collect(),
        )
    };
    let hits = a.hits();
    (a, hits)
}

/// The paper's comparison (its tables count OAVM with leaf lists, `--leaf list`, K = 32): all
/// five structures agree with OAVM, report their figures, and the classic octree, OAVM's
/// subdivision with pointers, stores more pointers than OAVM.
#[test]
fn all_structures_agree_with_oavm_and_report_the_tables_figures() {
    let scenes = structures_agree_with_oavm(LeafKind::List);
    for sc in &scenes {
        let structs = sc["structures"].as_array().expect("structures");
        let by = |n: &str| structs.iter().find(|s| s["name"] == n).unwrap();
        assert!(
            by("octree")["pointers"].as_u64() > by("oavm")["pointers"].as_u64(),
            "{}: {} {}",
            sc["scene"],
            by("octree"),
            by("oavm")
        );
    }
}

/// The same with the default structure, OAVM of clusters (K = 512): all five structures agree
/// with it and report their figures. The octree is still OAVM's subdivision (same nodes), but
/// with leaves of 512 triangles the pointer comparison is not the paper's and does not go one
/// way: the Cornell box's 36 triangles are one leaf, 1 pointer for the octree against OAVM's
/// rank word and leaf offset.
#[test]
fn all_structures_agree_with_oavm_of_clusters() {
    structures_agree_with_oavm(LeafKind::Cluster);
}

/// Runs `oavm-bench --leaf LEAF` on two scenes and checks what holds for either kind of leaf:
/// every structure agrees with OAVM, reports its figures, and the octree has OAVM's nodes; and
/// OAVM itself agrees with brute force on the same ray sets, and so does every structure's
/// reported hit count. Returns the report's scenes.
fn structures_agree_with_oavm(leaf: LeafKind) -> Vec<Value> {
    let cornell = shared("cornell_box/CornellBox-Original.obj");
    let museum = shared("bart/museum/museum5.aff");
    let kind = match leaf {
        LeafKind::Cluster => "cluster",
        LeafKind::List => "list",
    };
    let o = run(bench()
        .args(SMALL)
        .args(["--leaf", kind, "--json"])
        .arg(&cornell)
        .arg(&museum));
    assert!(o.status.success(), "{}", describe(&o));
    let v: Value = serde_json::from_slice(&o.stdout).expect("JSON on stdout");
    assert_eq!(v["options"]["leaf"], kind, "{}", v["options"]);
    assert_eq!(
        v["options"]["leaf_size"],
        leaf.default_leaf_size(),
        "{}",
        v["options"]
    );
    let scenes = v["scenes"].as_array().expect("scenes").clone();
    assert_eq!(scenes.len(), 2);
    for sc in &scenes {
        let structs = sc["structures"].as_array().expect("structures");
        let names: Vec<&str> = structs
            .iter()
            .map(|s| s["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, oavm_compare::STRUCTURES, "{}", sc["scene"]);
        let by = |n: &str| structs.iter().find(|s| s["name"] == n).unwrap();
        // The classic octree is OAVM's subdivision with pointers: same nodes.
        assert_eq!(by("octree")["nodes"], by("oavm")["nodes"]);
        for s in structs {
            assert!(s["nodes"].as_u64().unwrap() > 0, "{s}");
            assert!(s["bytes"].as_u64().unwrap() > 0, "{s}");
            assert!(s["build_ms"].as_f64().unwrap() >= 0.0, "{s}");
            let sets = s["sets"].as_array().unwrap();
            let set_names: Vec<&str> = sets.iter().map(|x| x["set"].as_str().unwrap()).collect();
            assert_eq!(set_names, ["primary", "random", "shadow"]);
            for x in sets {
                assert_eq!(x["disagree_with_oavm"], 0, "{} {}", s["name"], x);
                assert!(x["rays"].as_u64().unwrap() > 0);
                assert!(x["nodes_visited_per_ray"].as_f64().unwrap() > 0.0, "{x}");
                // Only the KD-tree's stackless walks begin again.
                assert_eq!(x["restarts_per_ray"].as_f64(), Some(0.0), "{x}");
                let speeds = x["mrays_per_s"].as_array().unwrap();
                assert_eq!(speeds.len(), 1);
                assert!(speeds[0][1].as_f64().unwrap() > 0.0);
                check_by_occlusion(x);
            }
            // Primary rays inside a closed room hit something.
            assert!(sets[0]["hits"].as_u64().unwrap() > 0, "{s}");
        }
    }
    // BART scenes are traced from their own camera; the Cornell box is framed.
    assert_eq!(scenes[0]["camera"], "framing");
    assert_eq!(scenes[1]["camera"], "scene");

    // "No disagreement with OAVM" means something only if OAVM is right: the same ray sets,
    // made by the library as the binary makes them, through OAVM and brute force. Every
    // structure's reported hit count must be brute force's (within the 0.01 % a set may
    // disagree by), and brute force must find plenty of hits.
    let opts = small_options(leaf);
    for (path, sc) in [cornell, museum].iter().zip(&scenes) {
        let scene = BenchScene::load(path).unwrap();
        let oavm = OavmAccel::build(&scene.mesh, &opts.build).unwrap();
        let sets = bench::ray_sets(&scene, &oavm, &opts);
        let diag = scene.diagonal();
        for (i, set) in sets.iter().enumerate() {
            let label = format!("{} {}", sc["scene"], set.name);
            let (want, hits) = brute_answers(&scene.mesh, &set.rays, set.any);
            assert!(
                hits * 10 > set.rays.len(),
                "{label}: brute force hit only {hits}"
            );
            let (_, got) = bench::Answers::trace(&oavm, &set.rays, set.any);
            let bad = got.disagreements(&want, diag);
            assert!(
                !bench::too_many(bad, set.rays.len()),
                "{label}: OAVM disagrees with brute force on {bad} rays"
            );
            for s in sc["structures"].as_array().unwrap() {
                let x = &s["sets"][i];
                assert_eq!(x["set"], set.name);
                assert_eq!(x["rays"].as_u64(), Some(set.rays.len() as u64), "{label}");
                let reported = x["hits"].as_u64().unwrap() as usize;
                assert!(
                    reported.abs_diff(hits) <= bad + set.rays.len() / 10_000,
                    "{label} {}: {reported} hits reported, brute force {hits}",
                    s["name"]
                );
            }
        }
    }
    scenes
}

/// The shadow (any-hit) set splits its work between the rays found occluded and those found
/// unoccluded: the two counts are its hits and the rest, both occur, and the two averages,
/// weighted by them, give the set's own; closest-hit sets have no split.
fn check_by_occlusion(x: &Value) {
    let b = &x["by_occlusion"];
    if x["set"] != "shadow" {
        assert!(b.is_null(), "{x}");
        return;
    }
    let f = |k: &str| b[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {x}"));
    let (occ, unocc) = (f("occluded_rays"), f("unoccluded_rays"));
    assert_eq!(occ as u64, x["hits"].as_u64().unwrap(), "{x}");
    assert_eq!((occ + unocc) as u64, x["rays"].as_u64().unwrap(), "{x}");
    assert!(occ > 0.0 && unocc > 0.0, "{x}");
    for (per_occ, per_unocc, all) in [
        (
            "nodes_per_occluded_ray",
            "nodes_per_unoccluded_ray",
            "nodes_visited_per_ray",
        ),
        (
            "triangles_per_occluded_ray",
            "triangles_per_unoccluded_ray",
            "triangles_tested_per_ray",
        ),
    ] {
        let mean = (f(per_occ) * occ + f(per_unocc) * unocc) / (occ + unocc);
        let want = x[all].as_f64().unwrap();
        assert!(
            (mean - want).abs() <= 1e-9 * want.max(1.0),
            "{all}: {mean} vs {want}: {x}"
        );
    }
}

#[test]
fn batch_mode_writes_rays_md_answers_equal_to_the_library() {
    let dir = TempDir::new().unwrap();
    let bunny = common::data("bunny.ply");
    let mesh = oavm::mesh::load(&bunny).unwrap();
    let tris = Triangles::from_mesh(&mesh).unwrap();
    let b = Bounds::of_points(tris.v.iter().flatten().copied());
    let rays_in = rays::random_rays(&b, 5000, 7);
    let rays_path = dir.path().join("r.rays");
    rays::write_rays(&rays_path, &rays_in).unwrap();
    let diag = b.diagonal();
    let (brute_hits, n) = brute_answers(&mesh, &rays_in, false);
    assert!(n > 1000, "brute force hit only {n} of the rays");
    for name in oavm_compare::STRUCTURES {
        let hits_path = dir.path().join(format!("{name}.hits"));
        let occ_path = dir.path().join(format!("{name}.occl"));
        for (flag, out) in [("--hits", &hits_path), ("--occluded", &occ_path)] {
            let o = run(bench()
                .arg(&bunny)
                .args(["--structure", name, "--rays"])
                .arg(&rays_path)
                .arg(flag)
                .arg(out));
            assert!(o.status.success(), "{name} {flag}: {}", describe(&o));
            let v: Value = serde_json::from_slice(&o.stdout).unwrap();
            assert_eq!(v["disagree_with_oavm"], 0, "{name} {flag}");
            assert_eq!(v["rays"], 5000);
        }
        let acc =
            oavm_compare::build_structure(name, &mesh, &tris, &BuildOptions::default()).unwrap();
        let mut want = vec![Hit::MISS; rays_in.len()];
        oavm_compare::intersect_batch(acc.as_ref(), &rays_in, &mut want);
        let got = rays::read_hits(&hits_path, u64::MAX).unwrap();
        assert_eq!(got.len(), want.len());
        assert!(
            got.iter()
                .zip(&want)
                .all(|(a, b)| a.t.to_bits() == b.t.to_bits() && a.prim == b.prim),
            "{name}: the HITS file differs from the library's answers"
        );
        let bad = bench::Answers::Closest(got).disagreements(&brute_hits, diag);
        assert!(
            bad <= 1,
            "{name}: {bad} closest hits disagree with brute force"
        );
        let occ = rays::read_occlusion(&occ_path, u64::MAX).unwrap();
        assert!(
            occ.iter().zip(&want).all(|(&o, h)| (o == 1) == h.is_hit()),
            "{name}: any hit and closest hit differ on full-length rays"
        );
    }
}

fn assert_usage_error(o: &Output, needle: &str) {
    assert!(!o.status.success(), "{}", describe(o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(needle),
        "expected {needle:?} in:\n{}",
        describe(o)
    );
    assert!(!err.contains("panicked"), "{}", describe(o));
}

#[test]
fn bad_usage_is_refused_clearly() {
    let dir = TempDir::new().unwrap();
    let bunny = common::data("bunny.ply");
    let rays_path = dir.path().join("r.rays");
    rays::write_rays(
        &rays_path,
        &rays::random_rays(&Bounds::of_points([[0.0; 3], [1.0; 3]]), 10, 1),
    )
    .unwrap();
    assert_usage_error(
        &run(bench().arg(&bunny).args(["--structure", "octtree"])),
        "unknown structure",
    );
    assert_usage_error(
        &run(bench()
            .arg(&bunny)
            .arg("--rays")
            .arg(&rays_path)
            .arg("--hits")
            .arg(dir.path().join("h"))),
        "exactly one --structure",
    );
    assert_usage_error(
        &run(bench()
            .arg(&bunny)
            .args(["--structure", "bvh", "--rays"])
            .arg(&rays_path)),
        "--hits",
    );
    let missing: &Path = &dir.path().join("missing.ply");
    assert_usage_error(&run(bench().args(SMALL).arg(missing)), "missing.ply");
    let not_rays = dir.path().join("bad.rays");
    std::fs::write(&not_rays, b"not a ray file").unwrap();
    assert_usage_error(
        &run(bench()
            .arg(&bunny)
            .args(["--structure", "grid", "--rays"])
            .arg(&not_rays)
            .arg("--hits")
            .arg(dir.path().join("h"))),
        "bad.rays",
    );
}

/// The KD-tree's traversal variants run as structures of their own: on the Cornell box and the
/// robots, each agrees with OAVM on every ray of every set, keeps the tree's nodes, and the
/// stackless ones report their restarts (ropes taken, walks begun again); the rope walks count
/// their ropes in bytes and pointers.
#[test]
fn kd_traversal_variants_run_as_structures() {
    for rel in [
        "cornell_box/CornellBox-Original.obj",
        "bart/robot/Robot.aff",
    ] {
        let o = run(bench()
            .arg(shared(rel))
            .args([
                "--structure",
                "kdtree:stack,kdtree:restart,kdtree:pushdown,kdtree:shortstack,kdtree:ropes,kdtree:popov",
                "--random",
                "20000",
                "--width",
                "64",
                "--height",
                "48",
                "--reps",
                "1",
                "--threads",
                "1",
                "--json",
            ]));
        assert!(o.status.success(), "{}", describe(&o));
        let v: Value = serde_json::from_slice(&o.stdout).expect("json");
        let structs = v["scenes"][0]["structures"].as_array().unwrap();
        let names: Vec<&str> = structs
            .iter()
            .map(|s| s["name"].as_str().unwrap())
            .collect();
        assert_eq!(
            names,
            [
                "kdtree",
                "kdtree:restart",
                "kdtree:pushdown",
                "kdtree:shortstack",
                "kdtree:ropes",
                "kdtree:popov"
            ]
        );
        let plain = &structs[0];
        for s in structs {
            assert_eq!(s["nodes"], plain["nodes"], "{rel}: {s}");
            let ropes =
                s["name"].as_str().unwrap().ends_with("ropes") || s["name"] == "kdtree:popov";
            let more = |k: &str| s[k].as_u64().unwrap() > plain[k].as_u64().unwrap();
            assert_eq!(more("bytes"), ropes, "{rel}: {s}");
            assert_eq!(more("pointers"), ropes, "{rel}: {s}");
            for x in s["sets"].as_array().unwrap() {
                assert_eq!(x["disagree_with_oavm"], 0, "{rel}: {} {x}", s["name"]);
                let restarts = x["restarts_per_ray"].as_f64().unwrap();
                match s["name"].as_str().unwrap() {
                    "kdtree" => assert_eq!(restarts, 0.0),
                    "kdtree:shortstack" => {}
                    n => assert!(restarts > 0.1, "{rel}: {n} {x}"),
                }
            }
        }
    }
}
