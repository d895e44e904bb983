//! Shadow rays by the multi-index tree (Liang and Huang 2019) on the KD-tree: every walk (the
//! standard stack walk, the SATO order, the primitive index's, the adjacency index's, and the
//! `multi` variant choosing between the last two by prediction) gives the same any-hit answer
//! to every shadow ray of an orbit's frames, on real scenes, with point and area lights; those
//! answers agree with the f64 brute force (which shares no code with any walk) on both
//! outcomes; each index does the work it is for; prediction is counted from the frame before.

use crate::common::{bin, run, shared_scene};
use oavm::BuildOptions;
use oavm::Ray;
use oavm::geom::reference;
use oavm::logical::Walk;
use oavm_compare::Counters;
use oavm_compare::OavmAccel;
use oavm_compare::bench::BenchScene;
use oavm_compare::kdtree::{Adjacency, KdTree, PrimitiveIndex, SatoOrder, ShadowParams};
use oavm_compare::shadow::{
    self, KdShadow, LightKind, OavmShadow, ShadowOptions, ShadowPrep, ShadowSetup, ShadowVariant,
    ViewOverride,
};

fn options(light: LightKind) -> ShadowOptions {
    ShadowOptions {
        width: 96,
        height: 72,
        frames: 3,
        orbit_step: 1.0,
        tile: 8,
        light,
        samples: 4,
        closed_box: true,
        params: ShadowParams::default(),
        reps: 1,
        threads: vec![1],
    }
}

/// The scenes: BART scenes with their lights, the sibenik from inside with a light in the nave,
/// meshes closed in a box.
fn scene(rel: &str) -> BenchScene {
    let view = if rel.contains("sibenik") {
        ViewOverride {
            eye_target: Some(([-17.0, -10.0, 0.0], [10.0, -9.0, 0.0])),
            fov: 60.0,
            light_at: Some([3.0, -3.0, 2.0]),
            closed_box: false,
        }
    } else {
        ViewOverride {
            closed_box: true,
            ..ViewOverride::default()
        }
    };
    shadow::load_scene(&shared_scene(rel), &view).expect("load")
}

struct Walks {
    kd: KdTree,
    sato: SatoOrder,
    index: PrimitiveIndex,
    adj: Adjacency,
    setup: ShadowSetup,
}

fn walks(scene: &BenchScene, light: LightKind) -> Walks {
    let kd = KdTree::build(&scene.tris);
    let setup = ShadowSetup::new(scene, &kd, &scene.lights, &options(light));
    let lights = setup.light_points();
    let params = ShadowParams::default();
    Walks {
        sato: SatoOrder::build(&kd),
        index: PrimitiveIndex::build(&kd, &params),
        adj: Adjacency::build(&kd, &setup.visible, &lights, &params),
        kd,
        setup,
    }
}

/// The KD-tree prepared for the `multi` variant, as `oavm-bench` prepares it.
fn multi(w: &Walks) -> KdShadow<'_> {
    KdShadow::new(
        &w.kd,
        ShadowVariant::Multi,
        &ShadowPrep {
            visible: &w.setup.visible,
            lights: &w.setup.light_points(),
            params: ShadowParams::default(),
        },
    )
}

/// Per walk (standard, sato, primitive, adjacency), each ray's answer and work.
fn trace_all(w: &Walks, rays: &[Ray]) -> [Vec<(bool, Counters)>; 4] {
    let each = |f: &dyn Fn(&Ray, &mut Counters) -> bool| -> Vec<(bool, Counters)> {
        rays.iter()
            .map(|r| {
                let mut c = Counters::default();
                (f(r, &mut c), c)
            })
            .collect()
    };
    [
        each(&|r, c| w.kd.occluded_standard(r, c)),
        each(&|r, c| w.kd.occluded_sato(r, &w.sato, c)),
        each(&|r, c| w.kd.occluded_promoted(r, &w.index, c)),
        each(&|r, c| w.kd.occluded_adjacent(r, &w.adj, c)),
    ]
}

/// Every walk answers every ray as the standard walk does, and as brute force does on a
/// strided subset (rays that graze an edge excepted, where both answers are right), which must
/// hold rays of both outcomes. Returns the four walks' work over all rays.
fn check_scene(rel: &str, light: LightKind) -> [Counters; 4] {
    let scene = scene(rel);
    let w = walks(&scene, light);
    let rays: Vec<Ray> = w
        .setup
        .frames
        .iter()
        .flat_map(|f| f.rays.iter().copied())
        .collect();
    assert!(rays.len() > 10_000, "{rel}: {} rays", rays.len());
    let all = trace_all(&w, &rays);
    for (name, walk) in ["sato", "primitive", "adjacency"].iter().zip(&all[1..]) {
        let differ = walk.iter().zip(&all[0]).filter(|(a, b)| a.0 != b.0).count();
        assert_eq!(differ, 0, "{rel} {light:?}: {name} differs from standard");
    }
    // The multi variant, prediction and all.
    let multi = multi(&w);
    let traced = shadow::trace_frames(&multi, ShadowVariant::Multi, &w.setup);
    let multi_answers: Vec<bool> = traced.answers.iter().flatten().map(|&o| o == 1).collect();
    let standard: Vec<bool> = all[0].iter().map(|a| a.0).collect();
    assert_eq!(
        multi_answers, standard,
        "{rel}: multi differs from standard"
    );
    // OAVM's variants (its SATO order, its rope walk for predicted-unoccluded rays).
    let build = BuildOptions::default();
    let plain = OavmAccel::build_walk(&scene.mesh, &build, Walk::TopDown).expect("oavm");
    for v in [
        ShadowVariant::Standard,
        ShadowVariant::Sato,
        ShadowVariant::Multi,
    ] {
        let o = OavmShadow::new(&plain, v, &ShadowParams::default()).expect("oavm variant");
        let traced = shadow::trace_frames(&o, v, &w.setup);
        let answers: Vec<bool> = traced.answers.iter().flatten().map(|&o| o == 1).collect();
        let differ = answers
            .iter()
            .zip(&standard)
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(
            differ, 0,
            "{rel}: OAVM {v:?} differs from the KD-tree's standard walk"
        );
        // (A scene of fewer triangles than a leaf holds is one leaf: no rope to follow.)
        if v == ShadowVariant::Multi && scene.tris.len() > build.leaf_size as usize {
            let all = traced.split[0] + traced.split[1];
            assert!(
                all.ropes_followed > 0,
                "{rel}: OAVM's multi followed no rope"
            );
        }
    }

    // Brute force on a strided subset.
    let tris = &scene.tris.v;
    let step = (rays.len() / 1500).max(1);
    let (mut occluded, mut lit, mut wrong) = (0, 0, 0);
    for (i, r) in rays.iter().enumerate().step_by(step) {
        let want = reference::occluded(tris, r);
        if want {
            occluded += 1;
        } else {
            lit += 1;
        }
        if want != standard[i] && !reference::grazes(tris, r) {
            wrong += 1;
        }
    }
    assert!(
        occluded >= 50 && lit >= 50,
        "{rel}: the subset must hold both outcomes ({occluded} occluded, {lit} lit)"
    );
    assert_eq!(wrong, 0, "{rel}: {wrong} answers differ from brute force");
    all.map(|walk| walk.iter().fold(Counters::default(), |a, (_, c)| a + *c))
}

#[test]
fn every_walk_answers_alike_on_bart_scenes() {
    for rel in ["bart/kitchen/kitchen.aff", "bart/robot/Robot.aff"] {
        check_scene(rel, LightKind::Point);
    }
    check_scene("bart/kitchen/kitchen.aff", LightKind::Quad);
}

#[test]
fn every_walk_answers_alike_on_meshes_in_a_box_and_inside_the_sibenik() {
    for rel in [
        "cornell_box/CornellBox-Original.obj",
        "bunny/bun_zipper.ply",
        "dragon/dragon_vrip_res4.ply",
    ] {
        check_scene(rel, LightKind::Quad);
    }
    check_scene("sibenik/sibenik.obj", LightKind::Point);
}

/// Each index does what it is for: the primitive index's triangles are tested at inner nodes
/// and stop some occluded rays there, with fewer nodes than the standard walk; the adjacency
/// walk follows its links and visits fewer nodes per unoccluded ray.
#[test]
fn the_indices_do_their_work() {
    let scene = scene("bart/kitchen/kitchen.aff");
    let w = walks(&scene, LightKind::Point);
    let rays = &w.setup.frames[0].rays;
    let all = trace_all(&w, rays);
    let [standard, _, primitive, adjacency] = &all;
    assert!(w.index.promoted() > 0);
    let promoted: u64 = primitive.iter().map(|(_, c)| c.promoted_tested).sum();
    assert!(promoted > 0, "no promoted triangle was tested");
    let stopped_early = primitive
        .iter()
        .zip(standard)
        .filter(|(p, s)| p.0 && p.1.nodes_visited < s.1.nodes_visited)
        .count();
    assert!(
        stopped_early > 100,
        "{stopped_early} occluded rays stopped earlier"
    );
    let links: u64 = adjacency.iter().map(|(_, c)| c.ropes_followed).sum();
    assert!(links > rays.len() as u64, "{links} links followed");
    let nodes_unoccluded = |walk: &Vec<(bool, Counters)>| -> u64 {
        walk.iter()
            .filter(|(o, _)| !o)
            .map(|(_, c)| c.nodes_visited)
            .sum()
    };
    let (a, s) = (nodes_unoccluded(adjacency), nodes_unoccluded(standard));
    assert!(
        (a as f64) < 0.8 * s as f64,
        "adjacency walk: {a} nodes for the unoccluded rays, standard {s}"
    );
    // The adjacency index holds links only where the shadow rays go.
    assert!(w.adj.linked_leaves > 0 && w.adj.linked_leaves < w.adj.leaves);
}

/// The prediction of frame k + 1 is frame k's sample answers, and frame 0's are its own: the
/// counts `multi` reports are recounted here from the standard walk's answers.
#[test]
fn prediction_comes_from_the_frame_before() {
    let scene = scene("bart/kitchen/kitchen.aff");
    let w = walks(&scene, LightKind::Point);
    let multi = multi(&w);
    let traced = shadow::trace_frames(&multi, ShadowVariant::Multi, &w.setup);
    let p = traced.prediction.expect("multi predicts");
    let (mut predicted, mut correct, mut primitive) = (0u64, 0u64, 0u64);
    let mut guess: Option<Vec<Option<bool>>> = None;
    for f in &w.setup.frames {
        let answers: Vec<bool> = f
            .rays
            .iter()
            .map(|r| w.kd.occluded_standard(r, &mut Counters::default()))
            .collect();
        let sample_answers: Vec<Option<bool>> = f
            .samples()
            .iter()
            .map(|&i| answers.get(i as usize).copied())
            .collect();
        let g = guess.take().unwrap_or_else(|| sample_answers.clone());
        for (k, &a) in f.keys.iter().zip(&answers) {
            match g[*k as usize] {
                Some(o) => {
                    predicted += 1;
                    correct += (o == a) as u64;
                    primitive += o as u64;
                }
                None => primitive += 1,
            }
        }
        guess = Some(sample_answers);
    }
    assert_eq!(
        (p.predicted, p.correct, p.primitive_walks),
        (predicted, correct, primitive)
    );
    assert!(p.accuracy > 0.6 && p.accuracy < 1.0, "{}", p.accuracy);
    assert!(p.adjacency_walks > 0 && p.primitive_walks > 0);
}

/// `oavm-bench --shadow-variant`: every variant reported, none disagreeing, and a ray file
/// traced in batch mode gives the standard walk's answers byte for byte.
#[test]
fn bench_reports_variants_and_traces_ray_files() {
    let cornell = shared_scene("cornell_box/CornellBox-Original.obj");
    let (o, out, err) = run(bin("oavm-bench").arg(&cornell).args([
        "--shadow-variant",
        "standard,sato,multi",
        "--closed-box",
        "--width",
        "64",
        "--height",
        "48",
        "--frames",
        "2",
        "--reps",
        "1",
        "--threads",
        "1",
        "--light",
        "quad",
        "--json",
    ]));
    assert!(o.status.success(), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    let variants = v["scenes"][0]["variants"].as_array().expect("variants");
    let names: Vec<(&str, &str)> = variants
        .iter()
        .map(|x| {
            (
                x["structure"].as_str().unwrap(),
                x["variant"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        names,
        [
            ("kdtree", "standard"),
            ("kdtree", "sato"),
            ("kdtree", "multi"),
            ("oavm", "standard"),
            ("oavm", "sato"),
            ("oavm", "multi")
        ]
    );
    for x in variants {
        assert_eq!(x["disagree_with_standard"], 0);
        assert_eq!(x["disagree_with_kdtree"], 0);
        assert!(x["rays"].as_u64().unwrap() > 1000);
        assert!(x["occluded_rays"].as_u64().unwrap() > 0);
        assert!(x["unoccluded_rays"].as_u64().unwrap() > 0);
    }
    let acc = variants[2]["prediction"]["accuracy"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&acc));
    assert!(variants[2]["precompute"]["bytes"].as_u64().unwrap() > 0);

    // Batch mode.
    let dir = tempfile::tempdir().unwrap();
    let scene = scene("cornell_box/CornellBox-Original.obj");
    let w = walks(&scene, LightKind::Quad);
    let rays = &w.setup.frames[0].rays;
    let rays_path = dir.path().join("shadow.rays");
    oavm::rays::write_rays(&rays_path, rays).unwrap();
    let mut files = Vec::new();
    for (structure, variant) in [
        ("kdtree", "standard"),
        ("kdtree", "multi"),
        ("oavm", "multi"),
    ] {
        let occl = dir.path().join(format!("{structure}-{variant}.occl"));
        let (o, out, err) = run(bin("oavm-bench")
            .arg(&cornell)
            .args([
                "--closed-box",
                "--structure",
                structure,
                "--shadow-variant",
                variant,
                "--rays",
            ])
            .arg(&rays_path)
            .arg("--occluded")
            .arg(&occl));
        assert!(o.status.success(), "{err}");
        assert!(out.contains("\"disagree_with_standard\": 0"), "{out}");
        files.push(std::fs::read(&occl).unwrap());
    }
    assert_eq!(files[0], files[1]);
    assert_eq!(files[0], files[2]);
    let occ = oavm::rays::read_occlusion(&dir.path().join("oavm-multi.occl"), u64::MAX).unwrap();
    let want: Vec<u8> = rays
        .iter()
        .map(|r| w.kd.occluded_standard(r, &mut Counters::default()) as u8)
        .collect();
    assert_eq!(occ, want);
    // One variant only with a ray file.
    let (o, _, err) = run(bin("oavm-bench")
        .arg(&cornell)
        .args(["--shadow-variant", "standard,multi", "--rays"])
        .arg(&rays_path)
        .arg("--occluded")
        .arg(dir.path().join("x.occl")));
    assert!(!o.status.success() && err.contains("one variant"), "{err}");
}

/// Occluders in the file (format-spec §8.5), as `oavm-pack --occluders` adds them: the file
/// verifies; OAVM's top-down walk testing them answers every shadow ray of the frames as the
/// walk that ignores them (which the tests above hold to the KD-tree's and brute force); it
/// tests them, and stops some occluded rays at one, with fewer nodes. A file of lists (walked
/// leaf to leaf) is refused.
#[test]
fn occluders_in_the_file_answer_alike_and_verify() {
    let scene = scene("bart/kitchen/kitchen.aff");
    let w = walks(&scene, LightKind::Point);
    let rays: Vec<Ray> = w
        .setup
        .frames
        .iter()
        .flat_map(|f| f.rays.iter().copied())
        .collect();
    let params = ShadowParams::default();
    let lists = BuildOptions::with_leaf(oavm::pack::LeafKind::List);
    let (parts, _) = oavm::pack::build(&scene.mesh, &lists, &oavm::pack::Quiet).expect("build");
    let file = oavm::physical::OavmFile::open(oavm::pack::encode(&parts).expect("encode")).unwrap();
    let e = oavm::pack::occluders::add_occluders(&file, &params, Vec::new()).unwrap_err();
    assert!(e.to_string().contains("clusters"), "{e}");
    for leaf in [oavm::pack::LeafKind::Cluster] {
        let opts = BuildOptions::with_leaf(leaf);
        let (parts, _) = oavm::pack::build(&scene.mesh, &opts, &oavm::pack::Quiet).expect("build");
        let plain = oavm::pack::encode(&parts).expect("encode");
        let file = oavm::physical::OavmFile::open(plain).expect("open");
        let (bytes, _, report) =
            oavm::pack::occluders::add_occluders(&file, &ShadowParams::default(), Vec::new())
                .expect("occluders");
        assert!(
            report.occluders > 0 && report.occluder_nodes > 0,
            "{report:?}"
        );
        assert_eq!(report.bytes_after, bytes.len() as u64);
        // The top-down walk, which tests occluders (a file of lists is walked leaf to leaf by
        // default).
        let s = oavm::Scene::from_bytes_with(
            oavm::physical::AlignedBytes::from_slice(&bytes),
            "occ.oavm",
            &oavm::logical::SceneOptions {
                walk: Walk::TopDown,
                ..Default::default()
            },
        )
        .expect("open");
        let v = s.verify().expect("verify");
        assert!(v.is_ok(), "{leaf:?}: {:?}", v.defects);
        let tree = s.tree();
        let (mut promoted, mut earlier, mut occluded) = (0u64, 0usize, 0usize);
        for r in &rays {
            let (mut a, mut b) = (oavm::Counters::default(), oavm::Counters::default());
            let with = tree.occluders(true).occluded(r, &mut a).expect("trace");
            let without = tree.occluders(false).occluded(r, &mut b).expect("trace");
            assert_eq!(with, without, "{leaf:?}: occluders changed an answer");
            promoted += a.promoted_tested;
            occluded += with as usize;
            earlier += (with && a.nodes_visited < b.nodes_visited) as usize;
        }
        assert!(promoted > 0, "{leaf:?}: no occluder was tested");
        assert!(
            occluded > 1000 && earlier > 10,
            "{leaf:?}: {earlier} of {occluded} occluded rays stopped earlier"
        );
    }
}

/// Three of the 37.7 million shadow rays of the kitchen's 8 frames at 1024x768 that the
/// adjacency walk once answered otherwise than the stack walk: each leaves a leaf through an
/// edge (two faces within the tolerance), where a triangle of a diagonal neighbour, which the
/// stack walk visits, is hit by the watertight test (the f64 reference misses all three: they
/// graze). The index is the one the benchmark builds (frame 0's hits, the six lights).
#[test]
fn the_adjacency_walk_visits_the_leaves_around_an_edge() {
    let scene = scene("bart/kitchen/kitchen.aff");
    let kd = KdTree::build(&scene.tris);
    let opts = ShadowOptions {
        width: 1024,
        height: 768,
        frames: 1,
        light: LightKind::Point,
        ..options(LightKind::Point)
    };
    let setup = ShadowSetup::new(&scene, &kd, &scene.lights, &opts);
    let params = ShadowParams::default();
    let adj = Adjacency::build(&kd, &setup.visible, &setup.light_points(), &params);
    let rays = [
        (
            [3.4000008, 9.171049e-8, 1.2451634],
            [-3.1500008, 1.3999999, -0.24516346],
        ),
        (
            [0.1078943, 0.39652315, -3.7500002],
            [2.042106, 1.6034769, 4.8500004],
        ),
        (
            [2.3392766, 0.059516784, 1.5058309],
            [2.0107234, 1.3404832, -0.50583094],
        ),
    ];
    for (o, d) in rays {
        let r = Ray::new(o, d, 1e-4, 0.9999);
        let standard = kd.occluded_standard(&r, &mut Counters::default());
        assert!(standard, "{o:?}: the stack walk finds a hit");
        assert_eq!(
            kd.occluded_adjacent(&r, &adj, &mut Counters::default()),
            standard,
            "{o:?}"
        );
    }
}
