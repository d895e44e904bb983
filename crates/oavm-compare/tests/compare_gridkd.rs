//! The uniform grid and the KD-tree of `oavm_compare` against brute force on real meshes.
//!
//! Scenes: the bunny (`bun_zipper.ply`) and the dragon at resolution 3 (`dragon_vrip_res3.ply`).
//! Ray sets per scene: [`RANDOM`] random rays and a [`WIDTH`] x [`HEIGHT`] camera (closest hit
//! and any hit on both), and shadow rays toward `default_light` from every brute-force primary
//! hit (any hit, and closest hit too). Every ray is compared with the f64 brute force
//! (`oavm::geom::reference`), which shares no code with the structures.
//!
//! Agreement is the rule of `../shared/RAYS.md` (both miss, or both hit with
//! `|t1 - t2| <= 1e-4 L`); a set passes when at most 0.01 % of its rays disagree
//! ([`allowed`]), and the any-hit answers must agree with brute force's on the same budget.
//! The brute-force closest hits are computed once per scene and shared by both structures; the
//! brute-force any-hit answer of a ray is whether its brute-force closest hit exists (the same
//! question: both search `[tmin, tmax]`), except on the shadow rays, where
//! `brute::occluded` itself is called.

mod common;

use oavm::geom::reference;
use oavm::rays::{Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{Hit, Mesh, Ray};
use oavm_compare::Counters;
use oavm_compare::grid::UniformGrid;
use oavm_compare::kdtree::KdTree;
use oavm_compare::{Accelerator, Triangles};
use rayon::prelude::*;

/// The sets are small because the f64 brute force they are checked against costs about
/// 2 x 10^-7 s per ray and triangle here; `cargo run --release -p oavm-compare --example check_structures`
/// checks all five structures on full-size sets.
const RANDOM: usize = 4_000;
/// 6,912 camera rays (their shadow rays, about 2,000, must be at least 1,000).
const WIDTH: u32 = 96;
const HEIGHT: u32 = 72;

fn allowed(n: usize) -> usize {
    n / 10_000
}

struct Set {
    name: &'static str,
    rays: Vec<Ray>,
    closest: Vec<Hit>,
    occluded: Vec<bool>,
}

fn sets(mesh: &Mesh) -> (Vec<Set>, f64) {
    let tris = mesh.corners();
    let b = Bounds::of_points(mesh.positions.iter().copied());
    let brute_all = |rays: &[Ray]| -> Vec<Hit> {
        rays.par_iter()
            .map(|r| reference::closest(&tris, r))
            .collect()
    };
    let random = random_rays(&b, RANDOM, 0x5eed);
    let camera = Camera::framing(&b).primary_rays(WIDTH, HEIGHT);
    let (rc, cc) = (brute_all(&random), brute_all(&camera));
    let shadow = shadow_rays(&camera, &cc, default_light(&b));
    let sc = brute_all(&shadow);
    let so: Vec<bool> = shadow
        .par_iter()
        .map(|r| reference::occluded(&tris, r))
        .collect();
    let occ = |h: &[Hit]| h.iter().map(Hit::is_hit).collect::<Vec<_>>();
    let out = vec![
        Set {
            name: "random",
            occluded: occ(&rc),
            rays: random,
            closest: rc,
        },
        Set {
            name: "camera",
            occluded: occ(&cc),
            rays: camera,
            closest: cc,
        },
        Set {
            name: "shadow",
            rays: shadow,
            closest: sc,
            occluded: so,
        },
    ];
    (out, b.diagonal().max(f64::MIN_POSITIVE))
}

/// Compares `acc` with the brute-force answers of every set; panics on too many disagreements.
fn compare(scene: &str, acc: &dyn Accelerator, sets: &[Set], diag: f64) {
    for set in sets {
        let n = set.rays.len();
        let (hits, c): (Vec<(Hit, bool)>, Vec<Counters>) = set
            .rays
            .par_iter()
            .map(|r| {
                let mut c = Counters::default();
                let h = acc.intersect(r, &mut c);
                let o = acc.occluded(r, &mut c);
                ((h, o), c)
            })
            .unzip();
        let c = c.into_iter().fold(Counters::default(), |a, b| a + b);
        let mut bad_c = 0;
        let mut bad_o = 0;
        let mut exact = 0;
        for (i, &(h, o)) in hits.iter().enumerate() {
            let b = set.closest[i];
            if !b.agrees(&h, diag) {
                bad_c += 1;
                if bad_c <= 3 {
                    eprintln!(
                        "{scene} {} {}: ray {i} {:?}: brute {b:?}, got {h:?}",
                        acc.stats().name,
                        set.name,
                        set.rays[i]
                    );
                }
            }
            exact += (b == h) as usize;
            if o != set.occluded[i] {
                bad_o += 1;
                if bad_o <= 3 {
                    eprintln!(
                        "{scene} {} {}: any hit of ray {i} {:?}: brute {}, got {o}",
                        acc.stats().name,
                        set.name,
                        set.rays[i],
                        set.occluded[i]
                    );
                }
            }
        }
        let brute_hits = set.closest.iter().filter(|h| h.is_hit()).count();
        eprintln!(
            "{scene} {} {}: {n} rays, {brute_hits} hit, {bad_c} closest / {bad_o} any-hit \
             disagreements, {exact} identical (t and prim); {c:?}",
            acc.stats().name,
            set.name
        );
        assert!(n >= 1000, "{} set too small: {n}", set.name);
        assert!(
            brute_hits > n / 20,
            "{} set: too few hits ({brute_hits})",
            set.name
        );
        assert!(c.nodes_visited > 0 && c.triangles_tested > 0);
        assert_eq!(c.rays, 0, "structures must not count rays");
        assert!(bad_c <= allowed(n), "{} closest: {bad_c} of {n}", set.name);
        assert!(bad_o <= allowed(n), "{} any hit: {bad_o} of {n}", set.name);
    }
}

fn check_scene(rel: &str) {
    // A missing scene is a failure: these tests need ../shared/scenes.
    let path = common::shared_scene(rel);
    let mesh = oavm::mesh::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let tris = Triangles::from_mesh(&mesh).expect("triangles");
    assert!(tris.len() > 40_000);
    let (sets, diag) = sets(&mesh);
    let grid = UniformGrid::build(&tris);
    let s = grid.stats();
    eprintln!("{rel}: {s:?}");
    assert!(s.nodes > 1000 && s.bytes > 36 * tris.len() as u64);
    compare(rel, &grid, &sets, diag);
    let kd = KdTree::build(&tris);
    let s = kd.stats();
    eprintln!("{rel}: {s:?}");
    assert!(s.nodes > 1000 && s.pointers > 0 && s.bytes > 36 * tris.len() as u64);
    compare(rel, &kd, &sets, diag);
}

#[test]
fn bunny_matches_brute_force() {
    check_scene("bunny/bun_zipper.ply");
}

#[test]
fn dragon_res3_matches_brute_force() {
    check_scene("dragon/dragon_vrip_res3.ply");
}

/// The KD-tree's traversal variants (kd-restart, push-down, short-stack, the source's ropes
/// walked with stored cells or with its `SplitStack` register, and Popov's) on the scenes of the
/// threaded KD-tree's comparison: the kitchen and the robots (BART, axis-aligned walls on split
/// planes, cells of no thickness) and the Cornell box. Each gives the stack walk's closest and
/// any hit on every one of 20,000 random rays (grazing or not: these walks must reach the same
/// leaves' triangles; the `SplitStack` walk visits the very same nodes), and the stack walk
/// itself agrees with the f64 brute force on a strided 1,000 of them.
#[test]
fn kd_traversal_variants_give_the_stack_walks_answers_on_architecture() {
    use oavm_compare::kdtree::KdTraversal;
    for rel in [
        "bart/kitchen/kitchen.aff",
        "bart/robot/Robot.aff",
        "cornell_box/CornellBox-Original.obj",
    ] {
        let path = common::shared_scene(rel);
        let scene = oavm_compare::bench::BenchScene::load(&path)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let tris = &scene.tris;
        let rays = random_rays(&scene.bounds, 20_000, 0xd1ff);
        let stack = KdTree::build(tris);
        let mut stack_counts = Counters::default();
        let want: Vec<(Hit, bool)> = rays
            .iter()
            .map(|r| {
                (
                    stack.intersect(r, &mut stack_counts),
                    stack.occluded(r, &mut stack_counts),
                )
            })
            .collect();
        let hits = want.iter().filter(|w| w.0.is_hit()).count();
        assert!(hits > 4_000, "{rel}: {hits} hits");
        // The reference itself, on a strided subset.
        let corners = scene.mesh.corners();
        let diag = scene.diagonal();
        for (r, w) in rays.iter().zip(&want).step_by(20) {
            if reference::grazes(&corners, r) {
                continue;
            }
            let b = reference::closest(&corners, r);
            assert!(
                b.agrees(&w.0, diag),
                "{rel}: stack walk {w:?}, brute {b:?}, {r:?}"
            );
        }
        for t in [
            KdTraversal::Restart,
            KdTraversal::PushDown,
            KdTraversal::ShortStack(4),
            KdTraversal::Ropes,
            KdTraversal::Popov,
            KdTraversal::SplitStack,
        ] {
            let kd = KdTree::build(tris).with_traversal(t);
            let mut c = Counters::default();
            let differ = rays
                .iter()
                .zip(&want)
                .filter(|(r, w)| (kd.intersect(r, &mut c), kd.occluded(r, &mut c)) != **w)
                .count();
            assert_eq!(
                differ, 0,
                "{rel}, {t:?}: {differ} rays differ from the stack walk"
            );
            if t != KdTraversal::ShortStack(4) {
                assert!(c.restarts > 10_000, "{rel}, {t:?}: {c:?}");
            }
            if t == KdTraversal::SplitStack {
                // It is the stack walk, with ropes and a register for its stack: the same
                // nodes, leaves and triangles (no ray here lies in a split plane or has more
                // forks pending than the register holds, which would take the stack walk).
                c.restarts = 0;
                assert_eq!(c, stack_counts, "{rel}: the stack walk's counts");
            }
        }
    }
}
