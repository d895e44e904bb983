//! Answers: OAVM against independent references, on real meshes (the in-suite version of
//! `tools/check.rs`, which runs the full-size check: 10^6 random rays, 1024x768 camera rays,
//! the full dragon), on valid but awkward meshes, and on the rays and scales a review found
//! answered wrongly.
//!
//! Scenes: the bunny (`bun_zipper.ply`, 69,451 triangles) and the dragon at resolution 3
//! (`dragon_vrip_res3.ply`, 47,794 triangles), packed in memory with default options. Ray sets,
//! as in the tool: [`RANDOM`] random rays and a [`WIDTH`] x [`HEIGHT`] camera (closest hit), and
//! shadow rays toward `default_light` from every primary hit OAVM finds (any hit).
//!
//! References:
//! - the f64 brute force (`oavm::geom::reference`, which shares no code with our f32 kernel) on
//!   a strided subset of every set (every `k`-th ray, at least [`BRUTE_BUNNY`] /
//!   [`BRUTE_DRAGON`] rays; brute force costs rays x triangles);
//! - obvhs (`tools/peers/mod.rs`: its CWBVH and Möller–Trumbore test, none of our code) on every
//!   ray.
//!
//! Agreement is the rule of `../shared/RAYS.md` (both miss, or both hit with
//! `|t1 - t2| <= 1e-4 L`), and a set passes at 99.99 %: at most `floor(n / 10^4)` of `n` rays may
//! disagree ([`allowed`]). The sizes make that threshold mean what it says: every set compared
//! with obvhs has at least 10^4 rays, so a rare grazing edge hit (where two correct tracers may
//! differ) is tolerated, while a traversal bug, which loses many rays, is not. The brute-force
//! subsets have fewer than 10^4 rays, so there 99.99 % means no disagreement at all.
//!
//! Build options must not change answers: merging off and a small leaf size give the same
//! answer as the default build on every ray.
//!
//! Timing (the optimised test profile, 2 shared cores): about 5 s for the whole file, most of it
//! brute force.

#[path = "../../tools/peers/mod.rs"]
mod peers;

use crate::common::*;
use oavm::geom::reference;
use oavm::pack::LeafKind;
use oavm::physical::AlignedBytes;
use oavm::rays::{Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray, Scene};
use peers::ObvhsScene;
use rayon::prelude::*;

const BUNNY: &str = "bunny/bun_zipper.ply";
const DRAGON_RES3: &str = "dragon/dragon_vrip_res3.ply";
/// Random rays per scene (closest hit).
const RANDOM: usize = 20_000;
/// Camera: 76,800 primary rays. The meshes fill only ~16 % of the framing camera's image, and the
/// shadow rays start at primary hits, so fewer pixels would leave fewer than [`MIN_SET`] shadow
/// rays ([`ray_sets`] checks).
const WIDTH: u32 = 320;
const HEIGHT: u32 = 240;
/// Brute-force rays per set (at least).
const BRUTE_BUNNY: usize = 3_000;
const BRUTE_DRAGON: usize = 2_000;
/// Every set traced by obvhs has at least this many rays, so 99.99 % allows a disagreement.
const MIN_SET: usize = 10_000;

/// Disagreements allowed among `n` rays at 99.99 % agreement.
fn allowed(n: usize) -> usize {
    n / 10_000
}

fn diagonal(mesh: &Mesh) -> f64 {
    bounds(mesh).diagonal()
}

fn closest(scene: &Scene<AlignedBytes>, rays: &[Ray]) -> Vec<Hit> {
    let mut out = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut out).expect("trace");
    out
}

fn any(scene: &Scene<AlignedBytes>, rays: &[Ray]) -> Vec<bool> {
    let mut out = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut out).expect("trace");
    out.into_iter().map(|o| o == 1).collect()
}

struct RaySets {
    random: Vec<Ray>,
    primary: Vec<Ray>,
    /// From the default build's primary hits.
    shadow: Vec<Ray>,
}

fn ray_sets(mesh: &Mesh, scene: &Scene<AlignedBytes>) -> RaySets {
    let b = bounds(mesh);
    let random = random_rays(&b, RANDOM, 1);
    let primary = Camera::framing(&b).primary_rays(WIDTH, HEIGHT);
    let shadow = shadow_rays(&primary, &closest(scene, &primary), default_light(&b));
    for (name, n) in [
        ("random", random.len()),
        ("primary", primary.len()),
        ("shadow", shadow.len()),
    ] {
        assert!(
            n >= MIN_SET,
            "{name}: {n} rays, fewer than {MIN_SET}: 99.99 % would demand exact agreement"
        );
    }
    RaySets {
        random,
        primary,
        shadow,
    }
}

/// The pairs of `pairs` (ray index, OAVM's answer, the reference's) that disagree, and the number
/// of pairs.
fn disagreements<A: Copy>(
    pairs: impl Iterator<Item = (usize, A, A)>,
    agrees: impl Fn(A, A) -> bool,
) -> (Vec<(usize, A, A)>, usize) {
    let mut n = 0;
    let mut bad = Vec::new();
    for (i, ours, theirs) in pairs {
        n += 1;
        if !agrees(ours, theirs) {
            bad.push((i, ours, theirs));
        }
    }
    (bad, n)
}

/// Fails the test if more than [`allowed`] of `pairs` disagree, naming the first few; returns the
/// number of rays compared.
fn assert_agreement<A: Copy + std::fmt::Debug>(
    what: &str,
    rays: &[Ray],
    pairs: impl Iterator<Item = (usize, A, A)>,
    agrees: impl Fn(A, A) -> bool,
) -> usize {
    let (bad, n) = disagreements(pairs, agrees);
    let shown: Vec<String> = bad
        .iter()
        .take(5)
        .map(|(i, o, t)| format!("ray {i} {:?}: oavm {o:?}, reference {t:?}", rays[*i]))
        .collect();
    assert!(
        bad.len() <= allowed(n),
        "{what}: {} of {n} rays disagree (at most {} allowed at 99.99 %):\n{}",
        bad.len(),
        allowed(n),
        shown.join("\n")
    );
    eprintln!("{what}: {} of {n} rays disagree", bad.len());
    n
}

/// The strided subset of at least `want` of `rays`: every `k`-th ray.
fn subset(rays: &[Ray], want: usize) -> Vec<usize> {
    (0..rays.len())
        .step_by((rays.len() / want).max(1))
        .collect()
}

/// OAVM (default build) against brute force on a strided subset of every set and against obvhs
/// on every ray.
fn check_against_references(rel: &str, brute_rays: usize) {
    let mesh = load_shared(rel);
    let diag = diagonal(&mesh);
    let scene = build_scene(&mesh, &BuildOptions::default());
    let obvhs = ObvhsScene::build(&mesh.positions, &mesh.triangles);
    let tris = corners(&mesh);
    let sets = ray_sets(&mesh, &scene);
    let hit_rule = |a: Hit, b: Hit| agree(a, b, diag);

    for (name, rays) in [("random", &sets.random), ("primary", &sets.primary)] {
        let ours = closest(&scene, rays);
        let hits = ours.iter().filter(|h| h.is_hit()).count();
        assert!(
            hits * 10 >= rays.len(),
            "{rel} {name}: only {hits} of {} rays hit; the check would prove little",
            rays.len()
        );

        let idx = subset(rays, brute_rays);
        let truth: Vec<Hit> = idx
            .par_iter()
            .map(|&i| reference::closest(&tris, &rays[i]))
            .collect();
        let n = assert_agreement(
            &format!("{rel} {name} vs brute force"),
            rays,
            idx.iter().zip(&truth).map(|(&i, &t)| (i, ours[i], t)),
            hit_rule,
        );
        assert!(n >= brute_rays);

        let theirs: Vec<Hit> = rays.par_iter().map(|r| obvhs.intersect(r)).collect();
        assert_agreement(
            &format!("{rel} {name} vs obvhs"),
            rays,
            (0..rays.len()).map(|i| (i, ours[i], theirs[i])),
            hit_rule,
        );
    }

    let rays = &sets.shadow;
    let ours = any(&scene, rays);
    let occluded = ours.iter().filter(|&&o| o).count();
    assert!(
        occluded > 0 && occluded < rays.len(),
        "{rel} shadow: {occluded} of {} rays occluded; the light should be partly blocked",
        rays.len()
    );
    let idx = subset(rays, brute_rays);
    let truth: Vec<bool> = idx
        .par_iter()
        .map(|&i| reference::occluded(&tris, &rays[i]))
        .collect();
    let n = assert_agreement(
        &format!("{rel} shadow vs brute force"),
        rays,
        idx.iter().zip(&truth).map(|(&i, &t)| (i, ours[i], t)),
        |a, b| a == b,
    );
    assert!(n >= brute_rays);
    let theirs: Vec<bool> = rays.par_iter().map(|r| obvhs.occluded(r)).collect();
    assert_agreement(
        &format!("{rel} shadow vs obvhs"),
        rays,
        (0..rays.len()).map(|i| (i, ours[i], theirs[i])),
        |a, b| a == b,
    );

    // Closest hit and any hit share the triangle test and the traversal: they must agree on
    // whether there is a hit on every ray, not 99.99 % of them.
    let hit = closest(&scene, &sets.random);
    let occ = any(&scene, &sets.random);
    let inconsistent: Vec<usize> = (0..hit.len())
        .filter(|&i| hit[i].is_hit() != occ[i])
        .collect();
    assert!(
        inconsistent.is_empty(),
        "{rel} random: closest hit and any hit disagree on {} rays, first {:?}",
        inconsistent.len(),
        &inconsistent[..inconsistent.len().min(5)]
    );
}

/// Builds with `options` give the default build's answer on every ray of every set.
fn check_options_do_not_change_answers(rel: &str) {
    let mesh = load_shared(rel);
    let diag = diagonal(&mesh);
    let default = build_scene(&mesh, &BuildOptions::default());
    let sets = ray_sets(&mesh, &default);
    let want_random = closest(&default, &sets.random);
    let want_primary = closest(&default, &sets.primary);
    let want_shadow = any(&default, &sets.shadow);
    let variants = [
        (
            "merge off",
            BuildOptions {
                merge: false,
                ..BuildOptions::default()
            },
        ),
        (
            "leaf size 4",
            BuildOptions {
                leaf_size: 4,
                ..BuildOptions::default()
            },
        ),
    ];
    for (label, opts) in variants {
        let scene = build_scene(&mesh, &opts);
        for (name, rays, want) in [
            ("random", &sets.random, &want_random),
            ("primary", &sets.primary, &want_primary),
        ] {
            let got = closest(&scene, rays);
            let bad: Vec<usize> = (0..rays.len())
                .filter(|&i| !agree(got[i], want[i], diag))
                .collect();
            assert!(
                bad.is_empty(),
                "{rel} {name}, {label}: {} of {} rays differ from the default build, first {:?}",
                bad.len(),
                rays.len(),
                bad.iter()
                    .take(3)
                    .map(|&i| (i, got[i], want[i]))
                    .collect::<Vec<_>>()
            );
        }
        let got = any(&scene, &sets.shadow);
        let bad = (0..got.len()).filter(|&i| got[i] != want_shadow[i]).count();
        assert_eq!(
            bad, 0,
            "{rel} shadow, {label}: any-hit answers differ from the default build"
        );
    }
}

#[test]
fn bunny_agrees_with_brute_force_and_obvhs() {
    check_against_references(BUNNY, BRUTE_BUNNY);
}

#[test]
fn dragon_res3_agrees_with_brute_force_and_obvhs() {
    check_against_references(DRAGON_RES3, BRUTE_DRAGON);
}

#[test]
fn bunny_answers_do_not_depend_on_merging_or_leaf_size() {
    check_options_do_not_change_answers(BUNNY);
}

#[test]
fn dragon_res3_answers_do_not_depend_on_merging_or_leaf_size() {
    check_options_do_not_change_answers(DRAGON_RES3);
}

/// The bounding-box diagonal of the synthetic answers below.
const SYNTHETIC_DIAGONAL: f64 = 2.0;

/// Answers to 20,000 rays, and the same answers with `wrong` of them wrong (a `t` off by three
/// tolerances, lost hits) and two that still agree (`t` off by half a tolerance; another triangle
/// at the same `t`, as through a shared edge).
fn answers_with_errors(wrong: usize) -> (Vec<Ray>, Vec<Hit>, Vec<Hit>) {
    let tol = 1e-4 * SYNTHETIC_DIAGONAL as f32;
    let rays = vec![Ray::new([0.0; 3], [0.0, 0.0, 1.0], 0.0, f32::INFINITY); 20_000];
    let right: Vec<Hit> = (0..rays.len())
        .map(|i| Hit {
            t: 1.0 + i as f32 * 1e-5,
            prim: i as u32,
        })
        .collect();
    let mut ours = right.clone();
    ours[7].t += 0.5 * tol;
    ours[11].prim = 3;
    for k in 0..wrong {
        let i = 100 * (k + 1);
        if k % 2 == 0 {
            ours[i].t += 3.0 * tol;
        } else {
            ours[i] = Hit::MISS;
        }
    }
    (rays, ours, right)
}

/// The checks above can fail: a wrong `t` or a lost hit counts, rounding within tolerance and
/// another primitive id at the same `t` do not.
#[test]
fn the_agreement_rule_counts_wrong_answers() {
    let (_, ours, right) = answers_with_errors(3);
    let (bad, n) = disagreements((0..ours.len()).map(|i| (i, ours[i], right[i])), |a, b| {
        agree(a, b, SYNTHETIC_DIAGONAL)
    });
    assert_eq!(n, 20_000);
    assert_eq!(
        bad.iter().map(|b| b.0).collect::<Vec<_>>(),
        vec![100, 200, 300]
    );
    assert_eq!(allowed(9_999), 0);
    assert_eq!(allowed(10_000), 1);
    assert_eq!(allowed(20_000), 2);
}

/// Two wrong answers in 20,000 rays are within 99.99 %...
#[test]
fn two_wrong_answers_in_20000_pass() {
    let (rays, ours, right) = answers_with_errors(2);
    assert_agreement(
        "two wrong",
        &rays,
        (0..rays.len()).map(|i| (i, ours[i], right[i])),
        |a, b| agree(a, b, SYNTHETIC_DIAGONAL),
    );
}

/// ...and a third fails.
#[test]
#[should_panic(expected = "3 of 20000 rays disagree (at most 2 allowed")]
fn three_wrong_answers_in_20000_fail() {
    let (rays, ours, right) = answers_with_errors(3);
    assert_agreement(
        "three wrong",
        &rays,
        (0..rays.len()).map(|i| (i, ours[i], right[i])),
        |a, b| agree(a, b, SYNTHETIC_DIAGONAL),
    );
}

// Valid but awkward meshes: they build, verify and trace like the f64 reference.

/// A bumpy grid surface of `n x n` quads with corners transformed by `f`.
fn grid(n: u32, f: impl Fn(f64, f64, f64) -> [f32; 3]) -> Mesh {
    let mut m = Mesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
            let h = 0.15 * (u * 9.0).sin() * (v * 7.0).cos();
            m.positions.push(f(u, v, h));
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            m.triangles.push([a, a + 1, a + n + 2]);
            m.triangles.push([a, a + n + 2, a + n + 1]);
        }
    }
    m
}

/// Random and camera rays through `m` agree with the f64 reference, which must find at least
/// `min_hits` hits among them.
fn check(m: &Mesh, opts: &BuildOptions, min_hits: usize, label: &str) {
    let scene = build_scene(m, opts);
    let b = bounds(m);
    let mut rays = random_rays(&b, 3000, 11);
    rays.extend(Camera::framing(&b).primary_rays(48, 36));
    compare_with_reference(m, &scene, &rays, 1).require(min_hits, 2, label);
}

fn small_leaves() -> BuildOptions {
    BuildOptions {
        leaf_size: 2,
        ..BuildOptions::default()
    }
}

#[test]
fn single_triangle() {
    let m = mesh(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    check(&m, &BuildOptions::default(), 20, "single triangle");
    let scene = build_scene(&m, &BuildOptions::default());
    let r = Ray::new([0.2, 0.2, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    let mut h = [Hit::MISS];
    scene.intersect_batch(&[r], &mut h).unwrap();
    assert_eq!(h[0], Hit { t: 1.0, prim: 0 });
}

#[test]
fn flat_mesh() {
    let m = grid(24, |u, v, _| [u as f32, v as f32, 0.0]);
    check(&m, &small_leaves(), 300, "flat grid");
}

#[test]
fn far_from_the_origin() {
    let m = grid(20, |u, v, h| {
        [(1.0e6 + u) as f32, (-2.0e6 + v) as f32, (5.0e5 + h) as f32]
    });
    check(&m, &small_leaves(), 300, "far from origin");
}

#[test]
fn long_slivers() {
    // 200 needles, 1000 times longer than wide, crossing the box in a fan.
    let mut m = Mesh::default();
    for i in 0..200u32 {
        let a = i as f32 * 0.031;
        let (c, s) = (a.cos(), a.sin());
        let base = m.positions.len() as u32;
        m.positions.push([-c, -s, 0.001 * i as f32]);
        m.positions.push([c, s, 0.001 * i as f32]);
        m.positions
            .push([c + 0.002 * s, s - 0.002 * c, 0.001 * i as f32 + 0.001]);
        m.triangles.push([base, base + 1, base + 2]);
    }
    check(&m, &small_leaves(), 50, "slivers");
}

#[test]
fn duplicate_and_degenerate_triangles() {
    let mut m = grid(12, |u, v, h| [u as f32, h as f32, v as f32]);
    let n = m.triangles.len();
    // Every triangle twice, plus collinear and point triangles, which keep ids but never hit.
    for i in 0..n {
        let t = m.triangles[i];
        m.triangles.push(t);
    }
    m.triangles.push([0, 0, 0]);
    let base = m.positions.len() as u32;
    m.positions
        .extend([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [0.4, 0.4, 0.4]]); // collinear
    m.triangles.push([base, base + 1, base + 2]);
    check(&m, &small_leaves(), 300, "duplicates and degenerate");
    let (_, stats) = oavm::pack::build(&m, &small_leaves(), &oavm::pack::Quiet).unwrap();
    assert_eq!(stats.degenerate_triangles, 2);
    // Ten copies of one big quad: subdivision must stop (no separation), not explode.
    let mut q = Mesh {
        geometries: Vec::new(),
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        triangles: Vec::new(),
    };
    for _ in 0..10 {
        q.triangles.push([0, 1, 2]);
        q.triangles.push([0, 2, 3]);
    }
    let (_, stats) = oavm::pack::build(
        &q,
        &BuildOptions {
            leaf_size: 1,
            max_depth: 21,
            ..BuildOptions::default()
        },
        &oavm::pack::Quiet,
    )
    .unwrap();
    assert!(
        stats.nodes < 1000,
        "stacked duplicates made {} nodes",
        stats.nodes
    );
    check(
        &q,
        &BuildOptions {
            leaf_size: 1,
            max_depth: 21,
            ..BuildOptions::default()
        },
        300,
        "stacked quads",
    );
}

#[test]
fn only_degenerate_triangles_give_an_empty_tree() {
    let m = mesh(
        vec![[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        vec![[0, 1, 2]],
    );
    let scene = build_scene(&m, &BuildOptions::default());
    let b = bounds(&m);
    let rays = random_rays(&b, 3000, 11);
    let c = compare_with_reference(&m, &scene, &rays, 1);
    assert_eq!(
        (c.reference_hits, c.closest, c.any, c.grazing),
        (0, 0, 0, 0),
        "{c:?}"
    );
    // Nor does a ray along the degenerate triangle's line hit it.
    let mut h = [Hit { t: 0.0, prim: 0 }];
    let along = Ray::new([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 0.0, f32::INFINITY);
    scene.intersect_batch(&[along], &mut h).unwrap();
    assert_eq!(h[0], Hit::MISS);
}

#[test]
fn invalid_rays_are_misses() {
    let m = grid(8, |u, v, h| [u as f32, v as f32, h as f32]);
    let scene = build_scene(&m, &BuildOptions::default());
    let rays = [
        Ray::new([0.5, 0.5, 2.0], [0.0, 0.0, 0.0], 0.0, f32::INFINITY),
        Ray::new([f32::NAN, 0.5, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
        Ray::new(
            [0.5, 0.5, 2.0],
            [0.0, 0.0, f32::INFINITY],
            0.0,
            f32::INFINITY,
        ),
        Ray::new([0.5, 0.5, 2.0], [0.0, 0.0, -1.0], 5.0, 1.0),
        Ray::new([0.5, 0.5, 2.0], [0.0, 0.0, -1.0], f32::NAN, 9.0),
    ];
    let mut h = [Hit { t: 0.0, prim: 0 }; 5];
    scene.intersect_batch(&rays, &mut h).unwrap();
    assert!(h.iter().all(|h| *h == Hit::MISS), "{h:?}");
    // A valid control ray does hit.
    let mut c = [Hit::MISS];
    scene
        .intersect_batch(
            &[Ray::new(
                [0.5, 0.5, 2.0],
                [0.0, 0.0, -1.0],
                0.0,
                f32::INFINITY,
            )],
            &mut c,
        )
        .unwrap();
    assert!(c[0].is_hit());
}

#[test]
fn axis_parallel_rays_on_cell_faces() {
    // Rays exactly along lattice planes and through cell edges and corners of a dense mesh:
    // the cases where a traversal could slip between cells.
    let m = grid(32, |u, v, h| [u as f32, v as f32, h as f32]);
    let scene = build_scene(&m, &small_leaves());
    let mut rays = Vec::new();
    for i in 0..=64 {
        let s = i as f32 / 64.0;
        rays.push(Ray::new([s, s, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY));
        rays.push(Ray::new(
            [s, 0.5, 2.0],
            [0.0, 0.0, -1.0],
            0.0,
            f32::INFINITY,
        ));
        rays.push(Ray::new(
            [-1.0, s, 0.0],
            [1.0, 0.0, 0.0],
            0.0,
            f32::INFINITY,
        ));
        rays.push(Ray::new(
            [s, -1.0, 0.05],
            [0.0, 1.0, 0.0],
            0.0,
            f32::INFINITY,
        ));
        rays.push(Ray::new(
            [-1.0, -1.0, s * 0.2 - 0.1],
            [1.0, 1.0, 0.0],
            0.0,
            f32::INFINITY,
        ));
    }
    compare_with_reference(&m, &scene, &rays, 1).require(100, 0, "axis-parallel rays");
}

// Rays and scales a review found answered wrongly (each failed before its fix).

/// A ray with a subnormal direction: `1 / d` overflows, and the kernel's `t` with it. A hit at
/// an infinite `t` is a miss (`RAYS.md`: `t = +inf` means a miss), never a hit record with
/// `t = +inf`.
#[test]
fn a_hit_whose_t_is_not_finite_is_a_miss() {
    let m = mesh(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    let scene = build_scene(&m, &BuildOptions::default());
    let rays = [
        Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -1e-40], 0.0, f32::INFINITY),
        Ray::new([0.2, 0.2, 2.0], [1e-45, 1e-45, -1e-39], 0.0, f32::INFINITY),
        // Away from the triangle, with an unbounded range behind: the hit is at t = -inf.
        Ray::new(
            [0.2, 0.2, 2.0],
            [0.0, 0.0, 1e-40],
            f32::NEG_INFINITY,
            f32::INFINITY,
        ),
        // A control: the same origin with a normal direction hits.
        Ray::new([0.2, 0.2, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
    ];
    let mut h = [Hit::MISS; 4];
    scene.intersect_batch(&rays, &mut h).unwrap();
    assert_eq!(h[0], Hit::MISS, "{:?}", h[0]);
    assert_eq!(h[1], Hit::MISS, "{:?}", h[1]);
    assert_eq!(h[2], Hit::MISS, "{:?}", h[2]);
    assert_eq!(h[3], Hit { t: 2.0, prim: 0 });
    let mut o = [9u8; 4];
    scene.occluded_batch(&rays, &mut o).unwrap();
    assert_eq!(o, [0, 0, 0, 1]);
    // The reference agrees: a hit beyond the f32 range is none.
    let tris = corners(&m);
    for r in &rays[..3] {
        assert_eq!(reference::closest(&tris, r), Hit::MISS, "{r:?}");
    }
}

/// Rays whose origin lies on a triangle hit it at `t = 0` whatever their direction (`RAYS.md`
/// counts `tmin <= t`), as the f64 reference says: before, rays leaving a flat mesh at a slant
/// were missed when the rounding of `t` came out just below 0.
#[test]
fn a_ray_whose_origin_lies_on_a_triangle_hits_it_at_zero() {
    let mut rng = oavm::rays::SplitMix64::new(5);
    let mut on_plane = |n: usize, lo: f64, hi: f64| -> Vec<Ray> {
        (0..n)
            .map(|_| {
                let o = [
                    (lo + (hi - lo) * rng.next_f64()) as f32,
                    (lo + (hi - lo) * rng.next_f64()) as f32,
                    0.0,
                ];
                let z = 2.0 * rng.next_f64() - 1.0;
                let phi = std::f64::consts::TAU * rng.next_f64();
                let r = (1.0 - z * z).sqrt();
                let d = [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32];
                Ray::new(o, d, 0.0, f32::INFINITY)
            })
            .collect()
    };
    // A flat grid of 32 x 32 squares in the plane z = 0, origins on it.
    let flat = grid(32, |u, v, _| [u as f32, v as f32, 0.0]);
    let scene = build_scene(&flat, &small_leaves());
    let rays = on_plane(4000, 0.01, 0.99);
    let c = compare_with_reference(&flat, &scene, &rays, 1);
    c.require(3900, 20, "origins on a flat mesh");
    // Each at t = 0 up to the rounding of t (the reference's t is exactly 0 here).
    let mut h = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(&rays, &mut h).unwrap();
    let at_zero = h
        .iter()
        .filter(|h| h.is_hit() && (0.0..1e-6).contains(&h.t))
        .count();
    assert!(at_zero >= 3900, "{at_zero} of {} hit at t = 0", rays.len());
    // A single triangle, origins inside it.
    let one = mesh(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    let scene = build_scene(&one, &BuildOptions::default());
    let rays: Vec<Ray> = on_plane(4000, 0.0, 1.0)
        .into_iter()
        .filter(|r| r.origin[0] + r.origin[1] < 0.98 && r.origin[0].min(r.origin[1]) > 0.01)
        .collect();
    assert!(rays.len() > 1500);
    compare_with_reference(&one, &scene, &rays, 1).require(rays.len() - 5, 5, "single triangle");
    // Shadow rays start on surfaces too, with tmin above 0: the rule does not make them hit
    // the surface they leave.
    let leave = Ray::new([0.3, 0.3, 0.0], [0.2, 0.1, 1.0], 1e-4, 1.0 - 1e-4);
    let mut o = [9u8];
    scene.occluded_batch(&[leave], &mut o).unwrap();
    assert_eq!(o, [0]);
}

/// The bunny scaled by `s`.
fn scaled_bunny(s: f64) -> Mesh {
    let b = load_shared("bunny/bun_zipper.ply");
    Mesh {
        geometries: Vec::new(),
        positions: b
            .positions
            .iter()
            .map(|p| p.map(|c| (c as f64 * s) as f32))
            .collect(),
        triangles: b.triangles,
    }
}

/// A mesh at any finite scale is traced like the f64 reference says, or refused when packed
/// with an error that says why: before, the bunny at 1e-20 lost a fifth of its hits and at
/// 1e-30 all of them, with no error.
#[test]
fn meshes_at_any_scale_trace_right_or_are_refused() {
    // The limits of the f32 kernel, with room: the bunny's root cube is ~0.155 times the scale.
    // (The scales side by side: each is a pack and a single-threaded f64 brute force.)
    [1e-9, 1e-3, 1e3, 5e11].into_par_iter().for_each(|s| {
        let m = scaled_bunny(s);
        let scene = build_scene(&m, &BuildOptions::default());
        let rays = random_rays(&bounds(&m), 1500, 3);
        compare_with_reference(&m, &scene, &rays, 1).require(300, 2, &format!("bunny x {s:e}"));
    });
    for s in [1e-30, 1e-20, 1e-12, 1e13, 1e20, 1e30] {
        let m = scaled_bunny(s);
        let e = oavm::pack::build(&m, &BuildOptions::default(), &oavm::pack::Quiet)
            .err()
            .unwrap_or_else(|| panic!("the bunny x {s:e} was packed"))
            .to_string();
        assert!(e.contains("rescale the mesh"), "{e}");
    }
    // Through the CLI: exit 1, the reason, no output.
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("tiny.ply");
    std::fs::write(&ply, binary_ply(&scaled_bunny(1e-20))).unwrap();
    let out = dir.path().join("tiny.oavm");
    let (o, _, err) = run(bin("oavm-pack").arg(&ply).arg(&out));
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("rescale the mesh"), "{err}");
    assert!(!out.exists());
    // The streaming pack refuses it too.
    let (o, _, err) = run(bin("oavm-pack")
        .arg(&ply)
        .arg(&out)
        .args(["--mem-budget", "64M"]));
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("rescale the mesh"), "{err}");
    assert!(!out.exists());
}

/// A file of clusters and a file of leaf lists find the same closest hit, to the bit of its `t`,
/// on Sibenik, whose walls and floors are axis-aligned planes: the boxes of a cluster lie flat
/// in them, where a box test's rounded entry may exceed the exact one. Where two triangles are
/// hit at exactly the same `t`, lists keep the first in their leaf (format 3's answer) and
/// clusters the smallest id, so a cluster's primitive is never the larger of the two. 10^6
/// random rays: the three of them that a traversal culling such boxes by their raw entry got
/// wrong (a farther triangle's hit, 2e-6 farther; once the larger id of a tie) are among them.
#[test]
fn sibenik_clusters_and_lists_find_the_same_closest_hits() {
    let mesh = load_shared("sibenik/sibenik.obj");
    let clusters = build_scene(&mesh, &BuildOptions::default());
    let lists = build_scene(&mesh, &BuildOptions::with_leaf(LeafKind::List));
    let b = bounds(&mesh);
    let random = random_rays(&b, 1_000_000, 1);
    let primary = Camera::framing(&b).primary_rays(WIDTH, HEIGHT);
    for (name, rays) in [("random", &random), ("primary", &primary)] {
        let (c, l) = (closest(&clusters, rays), closest(&lists, rays));
        let same = |c: &Hit, l: &Hit| c.t.to_bits() == l.t.to_bits() && c.prim <= l.prim;
        let differ: Vec<usize> = (0..rays.len()).filter(|&i| !same(&c[i], &l[i])).collect();
        let hits = c.iter().filter(|h| h.prim != Hit::MISS.prim).count();
        assert!(hits > rays.len() / 10, "{name}: only {hits} hits");
        assert!(
            differ.is_empty(),
            "{name}: {} rays differ, first {:?}",
            differ.len(),
            differ
                .iter()
                .take(3)
                .map(|&i| (i, c[i], l[i]))
                .collect::<Vec<_>>()
        );
    }
    let shadow = shadow_rays(&primary, &closest(&clusters, &primary), default_light(&b));
    assert_eq!(any(&clusters, &shadow), any(&lists, &shadow));
}

/// A slab of 5,000 small random triangles, 1 long in x and 0.1 in y and z: the root cube is the
/// slab's x extent on every axis, so the boxes of the top tree's nodes (the union of the link
/// bounds below them, derived at open) are thin in y and z. The traversal that culls by them
/// must cull some internal node of the top tree and still find every hit that an f64 brute force
/// finds; and the file verifies (every link's bounds hold its block's triangles).
#[test]
fn top_tree_boxes_cull_rays_and_lose_no_hit() {
    let mut rng = oavm::rays::SplitMix64::new(7);
    let mut r = || rng.next_f64() as f32;
    let mut mesh = Mesh::default();
    for i in 0..5_000u32 {
        let c = [r(), 0.45 + 0.1 * r(), 0.45 + 0.1 * r()];
        for _ in 0..3 {
            let s = [0.2, 0.02, 0.02];
            mesh.positions
                .push(std::array::from_fn(|k| c[k] + s[k] * (r() - 0.5)));
        }
        mesh.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let opts = BuildOptions {
        leaf_size: 8,
        ..BuildOptions::default()
    };
    let (parts, _) = oavm::pack::build(&mesh, &opts, &oavm::pack::Quiet).unwrap();
    let scene = Scene::from_bytes(oavm::pack::encode(&parts).unwrap(), "memory").unwrap();
    assert!(scene.verify().unwrap().defects.is_empty());
    let tree = scene.tree();
    assert!(
        tree.map().level_count() > 2,
        "the top tree must have internal nodes to test"
    );
    let bounds = oavm::rays::Bounds::of_points(mesh.positions.iter().copied());
    let rays: Vec<Ray> = random_rays(&bounds, 8_000, 3);
    let tris = mesh.corners();
    let diag = bounds.diagonal();
    let mut c = oavm::Counters::default();
    let mut hits = 0;
    for ray in &rays {
        let got = tree.intersect(ray, &mut c).unwrap();
        let got = got.map_or(Hit::MISS, |g| Hit {
            t: g.t,
            prim: g.prim,
        });
        let want = reference::closest(&tris, ray);
        hits += want.is_hit() as usize;
        if !reference::grazes(&tris, ray) {
            assert!(want.agrees(&got, diag), "{ray:?}: {want:?} against {got:?}");
        }
    }
    assert!(hits > 80, "{hits} hits");
    assert!(c.top_nodes_culled > 0, "{c:?}");
}
