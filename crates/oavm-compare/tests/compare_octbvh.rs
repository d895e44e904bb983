//! The classic octree and the BVH of the comparison (`oavm_compare::{octree, bvh}`) answer
//! exactly like brute force on real meshes (the bunny, the dragon's third decimation) and on
//! awkward ones, closest hit and any hit; the octree has OAVM's node and pointer counts.

mod common;

use common::shared_scene;
use oavm::geom::reference;
use oavm::rays::{self, Bounds, Camera};
use oavm::{BuildOptions, Hit, Mesh, Ray};
use oavm_compare::Counters;
use oavm_compare::bvh::Bvh;
use oavm_compare::octree::ClassicOctree;
use oavm_compare::{Accelerator, Triangles};
use rayon::prelude::*;

fn load(rel: &str) -> Mesh {
    let path = shared_scene(rel);
    oavm::mesh::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn bounds_of(t: &Triangles) -> Bounds {
    Bounds::of_points(t.v.iter().flatten().copied())
}

/// The ray sets of a scene: 4,000 random rays, 6,912 camera rays, and the shadow rays of the
/// camera rays that hit (by brute force).
fn ray_sets(mesh: &Mesh, t: &Triangles) -> Vec<(&'static str, Vec<Ray>)> {
    let tris = mesh.corners();
    let b = bounds_of(t);
    // Small sets: the f64 brute force costs about 2 x 10^-7 s per ray and triangle here
    // (`cargo run --release -p oavm-compare --example check_structures` checks full-size sets).
    let random = rays::random_rays(&b, 4_000, 42);
    let primary = Camera::framing(&b).primary_rays(96, 72);
    let hits: Vec<Hit> = primary
        .par_iter()
        .map(|r| reference::closest(&tris, r))
        .collect();
    let shadow = rays::shadow_rays(&primary, &hits, rays::default_light(&b));
    vec![("random", random), ("primary", primary), ("shadow", shadow)]
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

fn check_scene(rel: &str) {
    let mesh = load(rel);
    let t = Triangles::from_mesh(&mesh).expect("triangles");
    let sets = ray_sets(&mesh, &t);
    for (set, rays) in &sets {
        assert!(rays.len() > 1000, "{rel} {set}: too few rays");
    }
    compare_all(&mesh, &sets, &BuildOptions::default(), rel, 0.05);
}

#[test]
fn bunny_agrees_with_brute_force() {
    check_scene("bunny/bun_zipper.ply");
}

#[test]
fn dragon_res3_agrees_with_brute_force() {
    check_scene("dragon/dragon_vrip_res3.ply");
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
