//! The structures of the comparison (`oavm_compare`: the uniform grid, the KD-tree and its
//! traversal variants, the classic octree, the BVH) against brute force on real meshes and on
//! awkward ones, closest hit and any hit; the classic octree has OAVM's node and pointer counts.
//! One binary, so that the brute force of each scene is computed once for all four structures.
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

use crate::common::shared_scene;
use oavm::geom::reference;
use oavm::rays::{self, Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray};
use oavm_compare::Counters;
use oavm_compare::bvh::Bvh;
use oavm_compare::grid::UniformGrid;
use oavm_compare::kdtree::KdTree;
use oavm_compare::octree::ClassicOctree;
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
    let mesh = load(rel);
    let tris = Triangles::from_mesh(&mesh).expect("triangles");
    assert!(tris.len() > 40_000);
    let (sets, diag) = sets(&mesh);
    // The grid and the KD-tree: at most 0.01 % of each set's rays may disagree.
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
    // The classic octree and the BVH: no disagreement but on grazing rays.
    let octree = ClassicOctree::build(&tris, &BuildOptions::default());
    let bvh = Bvh::build(&tris);
    let corners = mesh.corners();
    let mut failures = Vec::new();
    for set in &sets {
        let reference: Vec<(Hit, bool)> = set
            .closest
            .iter()
            .copied()
            .zip(set.occluded.iter().copied())
            .collect();
        for acc in [&octree as &dyn Accelerator, &bvh] {
            let label = format!("{rel} {} {}", set.name, acc.stats().name);
            let (c, a) = disagreements(acc, &set.rays, &reference, &corners, diag, &label);
            if c + a > 0 {
                failures.push(format!("{label}: {c} closest, {a} any-hit disagreements"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
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
        let path = shared_scene(rel);
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
        let strided: Vec<(&Ray, &(Hit, bool))> = rays.iter().zip(&want).step_by(20).collect();
        strided.par_iter().for_each(|(r, w)| {
            if reference::grazes(&corners, r) {
                return;
            }
            let b = reference::closest(&corners, r);
            assert!(
                b.agrees(&w.0, diag),
                "{rel}: stack walk {w:?}, brute {b:?}, {r:?}"
            );
        });
        let variants = [
            KdTraversal::Restart,
            KdTraversal::PushDown,
            KdTraversal::ShortStack(4),
            KdTraversal::Ropes,
            KdTraversal::Popov,
            KdTraversal::SplitStack,
        ];
        variants.into_par_iter().for_each(|t| {
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
        });
    }
}

fn load(rel: &str) -> Mesh {
    let path = shared_scene(rel);
    oavm::mesh::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn bounds_of(t: &Triangles) -> Bounds {
    Bounds::of_points(t.v.iter().flatten().copied())
}

/// Counts the rays of `rays` on which `acc` disagrees with brute force (closest hit by the rule
/// of RAYS.md; any hit exactly), printing the first few.
fn disagreements(
    acc: &dyn Accelerator,
    rays: &[Ray],
    reference: &[(Hit, bool)],
    tris: &[[[f32; 3]; 3]],
    diag: f64,
    label: &str,
) -> (usize, usize) {
    let (mut bad_c, mut bad_a) = (0, 0);
    let mut c = Counters::default();
    for (i, (r, &(want, want_any))) in rays.iter().zip(reference).enumerate() {
        let got = acc.intersect(r, &mut c);
        let any = acc.occluded(r, &mut c);
        let agree = want.agrees(&got, diag) && any == want_any;
        if agree || reference::grazes(tris, r) {
            // (A ray through an edge or a corner: either answer may be right.)
            continue;
        }
        if !want.agrees(&got, diag) {
            bad_c += 1;
            if bad_c <= 3 {
                eprintln!("{label}: closest ray {i} {r:?}: brute {want:?}, got {got:?}");
            }
        }
        if any != want_any {
            bad_a += 1;
            if bad_a <= 3 {
                eprintln!("{label}: any-hit ray {i} {r:?}: brute {want_any}, got {any}");
            }
        }
    }
    assert_eq!(c.rays, 0, "{label}: structures must not count rays");
    assert!(c.nodes_visited >= c.leaves_visited, "{label}: {c:?}");
    (bad_c, bad_a)
}

/// The f64 reference's closest and any hit of each ray.
fn brute_answers(tris: &[[[f32; 3]; 3]], rays: &[Ray]) -> Vec<(Hit, bool)> {
    rays.par_iter()
        .map(|r| (reference::closest(tris, r), reference::occluded(tris, r)))
        .collect()
}

/// Builds both structures over `mesh` and compares them with brute force on `sets`, each of
/// which brute force must find at least `min_hit_fraction` of its rays to hit (a comparison on
/// rays that miss everything proves nothing).
fn compare_all(
    mesh: &Mesh,
    sets: &[(&'static str, Vec<Ray>)],
    opts: &BuildOptions,
    name: &str,
    min_hit_fraction: f64,
) {
    let t = Triangles::from_mesh(mesh).expect("triangles");
    let diag = bounds_of(&t).diagonal().max(f64::MIN_POSITIVE);
    let octree = ClassicOctree::build(&t, opts);
    let bvh = Bvh::build(&t);
    let mut failures = Vec::new();
    let tris = mesh.corners();
    for (set, rays) in sets {
        let reference = brute_answers(&tris, rays);
        let hits = reference.iter().filter(|(h, _)| h.is_hit()).count();
        eprintln!("{name} {set}: {} rays, {hits} hit", rays.len());
        assert!(
            hits as f64 >= min_hit_fraction * rays.len() as f64,
            "{name} {set}: brute force hit only {hits} of {} rays",
            rays.len()
        );
        for acc in [&octree as &dyn Accelerator, &bvh] {
            let label = format!("{name} {set} {}", acc.stats().name);
            let (c, a) = disagreements(acc, rays, &reference, &tris, diag, &label);
            if c + a > 0 {
                failures.push(format!("{label}: {c} closest, {a} any-hit disagreements"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The classic octree is OAVM's subdivision: the same nodes, and the pointers a pointer octree
/// over it stores (`PointerCounts::pointer_octree_total`), for several `K` and `D`.
#[test]
fn octree_counts_equal_oavms_on_the_bunny() {
    let mesh = load("bunny/bun_zipper.ply");
    let t = Triangles::from_mesh(&mesh).expect("triangles");
    for opts in [
        BuildOptions::default(),
        BuildOptions {
            leaf_size: 8,
            ..BuildOptions::default()
        },
        BuildOptions {
            leaf_size: 4,
            max_depth: 6,
            merge: false,
            ..BuildOptions::default()
        },
    ] {
        let (_, s) = oavm::pack::build(&mesh, &opts, &oavm::pack::Quiet).expect("OAVM build");
        let octree = ClassicOctree::build(&t, &opts);
        assert_eq!(octree.stats().nodes, s.nodes, "{opts:?}");
        assert_eq!(
            octree.stats().pointers,
            s.pointers.pointer_octree_total,
            "{opts:?}"
        );
        assert!(s.nodes > 1000, "the bunny's tree should be deep: {opts:?}");
    }
}

/// Rays that run along axes, lie in planes of the lattice or of the mesh, have zero components
/// or start inside: from a grid of points over the mesh's bounds (vertices included).
fn awkward_rays(m: &Mesh, extra: usize) -> Vec<Ray> {
    let b = Bounds::of_points(m.positions.iter().copied());
    let mut out = rays::random_rays(&b, extra, 5);
    out.extend(Camera::framing(&b).primary_rays(40, 30));
    let at = |u: [f32; 3]| -> [f32; 3] {
        std::array::from_fn(|k| b.min[k] + (b.max[k] - b.min[k]) * u[k])
    };
    let steps = [-0.1f32, 0.0, 0.25, 0.5, 0.75, 1.0, 1.1];
    for &x in &steps {
        for &y in &steps {
            for &z in &steps {
                let o = at([x, y, z]);
                for axis in 0..3 {
                    for s in [1.0f32, -1.0] {
                        let mut d = [0.0f32; 3];
                        d[axis] = s;
                        out.push(Ray::new(o, d, 0.0, f32::INFINITY));
                        // One zero component, the others oblique.
                        let mut d2 = [0.3f32, -0.7, 0.5];
                        d2[axis] = 0.0;
                        out.push(Ray::new(o, d2, 0.0, f32::INFINITY));
                        let mut d3 = [-0.0f32, 0.0, -0.0];
                        d3[axis] = -s;
                        out.push(Ray::new(o, d3, 0.0, 3.0));
                    }
                }
            }
        }
    }
    // Through every vertex (for small meshes), from a point outside and from the centre.
    let c = b.centre().map(|x| x as f32);
    for p in m.positions.iter().take(200) {
        for o in [c, at([1.3, 1.2, 1.1])] {
            let d: [f32; 3] = std::array::from_fn(|k| p[k] - o[k]);
            if d.iter().any(|&x| x != 0.0) {
                out.push(Ray::new(o, d, 0.0, f32::INFINITY));
                out.push(Ray::new(o, d, 0.0, 1.0));
            }
        }
    }
    out
}

fn quad_mesh(quads: &[[[f32; 3]; 4]]) -> Mesh {
    let mut m = Mesh::default();
    for q in quads {
        let i = m.positions.len() as u32;
        m.positions.extend_from_slice(q);
        m.triangles.push([i, i + 1, i + 2]);
        m.triangles.push([i, i + 2, i + 3]);
    }
    m
}

#[test]
fn awkward_meshes_agree_with_brute_force() {
    let opts = BuildOptions {
        leaf_size: 2,
        ..BuildOptions::default()
    };
    // A single triangle.
    let single = Mesh {
        geometries: Vec::new(),
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        triangles: vec![[0, 1, 2]],
    };
    // A flat mesh: a 16 x 16 grid in z = 0 (the root's mid-plane, grid lines on cell faces).
    let mut flat = Vec::new();
    for i in 0..16 {
        for j in 0..16 {
            let (x, y) = (i as f32, j as f32);
            flat.push([
                [x, y, 0.0],
                [x + 1.0, y, 0.0],
                [x + 1.0, y + 1.0, 0.0],
                [x, y + 1.0, 0.0],
            ]);
        }
    }
    let flat = quad_mesh(&flat);
    // Axis-aligned quads on the planes of cells of several levels (the root is centred on the
    // cube of edge 16, so planes at 0, ±4, ±8 are cell faces), crossing each other.
    let mut faces = Vec::new();
    for p in [-8.0f32, -4.0, 0.0, 4.0, 8.0] {
        faces.push([
            [p, -8.0, -8.0],
            [p, 8.0, -8.0],
            [p, 8.0, 8.0],
            [p, -8.0, 8.0],
        ]);
        faces.push([
            [-8.0, p, -8.0],
            [8.0, p, -8.0],
            [8.0, p, 8.0],
            [-8.0, p, 8.0],
        ]);
        faces.push([
            [-8.0, -8.0, p],
            [8.0, -8.0, p],
            [8.0, 8.0, p],
            [-8.0, 8.0, p],
        ]);
    }
    let faces = quad_mesh(&faces);
    // Degenerate triangles mixed in (dropped by both, never hit).
    let mut mixed = flat.clone();
    mixed.positions.push([3.0, 3.0, 0.0]);
    let k = mixed.positions.len() as u32 - 1;
    mixed.triangles.push([k, k, k]);
    mixed.triangles.push([0, 1, k]);

    for (name, m) in [
        ("single", &single),
        ("flat", &flat),
        ("cell faces", &faces),
        ("mixed", &mixed),
    ] {
        let rays = awkward_rays(m, 2000);
        compare_all(m, &[("awkward", rays)], &opts, name, 0.05);
        compare_all(
            m,
            &[("awkward default K", awkward_rays(m, 500))],
            &BuildOptions::default(),
            name,
            0.05,
        );
    }
}
