//! Every hit along a ray (`Scene::list_intersections`, `count_intersections`): against an f64
//! brute force over every triangle of real meshes (every hit, in order, with its barycentrics),
//! and exactly once per crossing where rays pass through shared edges and corners (a grid and a
//! closed box built so that rays meet them exactly).

use oavm::geom::reference;
use oavm::pack::LeafKind;
use oavm::rays::{SplitMix64, random_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray};
use rayon::prelude::*;

use crate::common::{bounds, build_scene, corners, load_shared, mesh};

/// Every hit of `ray` over `tris` in f64, ordered by `t` then id: `(t, id, u, v)`.
fn brute_force(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Vec<(f64, u32, f64, f64)> {
    let mut out: Vec<_> = tris
        .iter()
        .enumerate()
        .filter_map(|(i, tri)| {
            let t = reference::hit_t(tri, ray)?;
            let m = reference::meet(tri, ray)?;
            Some((t, i as u32, m.u, m.v))
        })
        .collect();
    out.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    out
}

/// Lists every hit of random rays (lines across the mesh's box, so most cross it several
/// times) and compares each ray's list with the brute force: the same triangles in the same
/// order, `t` within `RAYS.md`'s tolerance, `u`, `v` within 1e-3. Rays passing within rounding
/// of an edge are excused (the reference is not watertight) and counted. Returns how many rays
/// had two hits or more.
fn compare(rel: &str, rays: usize) -> usize {
    let m = load_shared(rel);
    let scene = build_scene(&m, &BuildOptions::default());
    let tris = corners(&m);
    let diag = bounds(&m).diagonal();
    let rays = random_rays(&bounds(&m), rays, 11);
    let (all, counters) = scene.list_intersections(&rays).expect("list");
    assert_eq!(all.rays(), rays.len());
    assert_eq!(counters.rays, rays.len() as u64);
    let mut counts = vec![0u32; rays.len()];
    scene
        .count_intersections(&rays, &mut counts)
        .expect("count");
    let mut closest = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(&rays, &mut closest).expect("closest");
    let truth: Vec<_> = rays.par_iter().map(|r| brute_force(&tris, r)).collect();
    let (mut several, mut grazing) = (0, 0);
    for (i, want) in truth.iter().enumerate() {
        let got = all.of(i);
        assert_eq!(
            counts[i] as usize,
            got.len(),
            "{rel} ray {i}: count and list differ"
        );
        // The first of the list is the closest hit (either id at a tie).
        match got.first() {
            None => assert!(
                !closest[i].is_hit(),
                "{rel} ray {i}: no hit listed, closest {:?}",
                closest[i]
            ),
            Some(h) => assert_eq!(
                h.t, closest[i].t,
                "{rel} ray {i}: first hit is not the closest"
            ),
        }
        for w in got.windows(2) {
            assert!(
                (w[0].t, w[0].prim) < (w[1].t, w[1].prim),
                "{rel} ray {i}: not in order of t"
            );
        }
        let same = got.len() == want.len()
            && got.iter().zip(want).all(|(g, w)| {
                g.prim == w.1
                    && (g.t as f64 - w.0).abs() <= 1e-4 * diag
                    && (g.u as f64 - w.2).abs() <= 1e-3
                    && (g.v as f64 - w.3).abs() <= 1e-3
            });
        if !same {
            // Hits at the same t (a fold, coplanar triangles) may be listed in another order.
            let set = |v: Vec<u32>| {
                let mut v = v;
                v.sort();
                v
            };
            let same_set = set(got.iter().map(|h| h.prim).collect())
                == set(want.iter().map(|w| w.1).collect());
            if !(same_set || reference::grazes(&tris, &rays[i])) {
                panic!(
                    "{rel} ray {i} {:?}: listed {got:?}, brute force {want:?}",
                    rays[i]
                );
            }
            grazing += !same_set as usize;
        }
        several += (want.len() >= 2) as usize;
    }
    eprintln!(
        "{rel}: {several} of {} rays hit twice or more, {grazing} grazing",
        rays.len()
    );
    assert!(
        grazing * 1000 <= rays.len(),
        "{rel}: {grazing} grazing rays of {}",
        rays.len()
    );
    several
}

#[test]
fn every_hit_matches_the_brute_force_on_the_bunny_and_the_dragon() {
    assert!(compare("bunny/bun_zipper.ply", 1500) > 150);
    assert!(compare("dragon/dragon_vrip_res3.ply", 1000) > 120);
}

#[test]
fn every_hit_matches_the_brute_force_on_sibenik_and_the_kitchen() {
    assert!(compare("sibenik/sibenik.obj", 800) > 150);
    assert!(compare("bart/kitchen/kitchen.aff", 1500) > 120);
}

/// A `n` x `n` grid of unit squares (corners at whole numbers, `z` a plane of exact slope),
/// each cut along a random diagonal, each triangle's corners in a random order.
fn grid(n: u32, seed: u64) -> Mesh {
    let mut rng = SplitMix64::new(seed);
    let z = |x: u32, y: u32| 0.25 * x as f32 - 0.125 * y as f32;
    let positions = (0..=n)
        .flat_map(|y| (0..=n).map(move |x| [x as f32, y as f32, z(x, y)]))
        .collect();
    let at = |x: u32, y: u32| y * (n + 1) + x;
    let mut triangles = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let (a, b, c, d) = (at(x, y), at(x + 1, y), at(x + 1, y + 1), at(x, y + 1));
            triangles.extend(halves(&mut rng, [a, b, c, d]));
        }
    }
    mesh(positions, triangles)
}

/// The quad `a b c d` cut along a diagonal chosen at random, each half's corners rotated and
/// perhaps swapped at random (windings mixed).
fn halves(rng: &mut SplitMix64, [a, b, c, d]: [u32; 4]) -> [[u32; 3]; 2] {
    let mut halves = match rng.next_u64() % 2 {
        0 => [[a, b, c], [a, c, d]],
        _ => [[a, b, d], [b, c, d]],
    };
    for t in &mut halves {
        t.rotate_left((rng.next_u64() % 3) as usize);
        if rng.next_u64().is_multiple_of(2) {
            t.swap(0, 1);
        }
    }
    halves
}

/// Small clusters, so that many triangles straddle several leaves and are found in each.
fn fine() -> BuildOptions {
    BuildOptions {
        leaf_size: 16,
        leaf: LeafKind::Cluster,
        ..BuildOptions::default()
    }
}

#[test]
fn a_ray_through_a_shared_edge_or_corner_meets_the_grid_once() {
    let n = 24;
    let g = grid(n, 3);
    let scene = build_scene(&g, &fine());
    let dirs = [
        [0.0, 0.0, -1.0],
        [0.3, 0.1, -1.0],
        [-0.2, 0.7, -0.5],
        [1.0, 0.0, -0.25],
        [0.577, -0.577, 0.577],
        [1.0, 1.0, 0.0],
    ];
    let mut rays = Vec::new();
    // Through every inner corner, every edge's midpoint (axis edges and diagonals).
    for i in 2..2 * n as i32 - 1 {
        for j in 2..2 * n as i32 - 1 {
            let (x, y) = (i as f32 / 2.0, j as f32 / 2.0);
            let at = [x, y, 0.25 * x - 0.125 * y];
            for d in dirs {
                let o = std::array::from_fn(|k| at[k] - 3.0 * d[k]);
                rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
            }
        }
    }
    let mut counts = vec![0u32; rays.len()];
    scene
        .count_intersections(&rays, &mut counts)
        .expect("count");
    let wrong: Vec<_> = (0..rays.len()).filter(|&i| counts[i] != 1).collect();
    assert!(
        wrong.is_empty(),
        "{} of {} rays met the grid other than once: {:?}",
        wrong.len(),
        rays.len(),
        wrong
            .iter()
            .take(5)
            .map(|&i| (rays[i], counts[i]))
            .collect::<Vec<_>>()
    );
    // The rays did pass through edges and corners: the brute force (not watertight) meets
    // several triangles, or none, for many of them.
    let tris = corners(&g);
    let shared = rays
        .par_iter()
        .filter(|r| brute_force(&tris, r).len() != 1)
        .count();
    assert!(
        shared * 4 > rays.len(),
        "only {shared} of {} rays met an edge or a corner",
        rays.len()
    );
}

/// The surface of the box `[0, n]^3` as a grid of unit squares on each face, cut along random
/// diagonals, corners in random order: closed, with exact corners and edge midpoints.
pub(crate) fn closed_box(n: u32, seed: u64) -> Mesh {
    let mut rng = SplitMix64::new(seed);
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut id = |p: [u32; 3], positions: &mut Vec<[f32; 3]>| {
        *index.entry(p).or_insert_with(|| {
            positions.push(p.map(|c| c as f32));
            positions.len() as u32 - 1
        })
    };
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for side in [0, n] {
            for a in 0..n {
                for b in 0..n {
                    let p = |da: u32, db: u32| {
                        let mut p = [0; 3];
                        p[axis] = side;
                        p[(axis + 1) % 3] = a + da;
                        p[(axis + 2) % 3] = b + db;
                        p
                    };
                    let [q0, q1, q2, q3] =
                        [p(0, 0), p(1, 0), p(1, 1), p(0, 1)].map(|q| id(q, &mut positions));
                    triangles.extend(halves(&mut rng, [q0, q1, q2, q3]));
                }
            }
        }
    }
    mesh(positions, triangles)
}

#[test]
fn a_ray_across_a_closed_box_through_its_edges_and_corners_crosses_it_twice() {
    let n = 6;
    let b = closed_box(n, 5);
    let scene = build_scene(&b, &fine());
    let mut rng = SplitMix64::new(9);
    let centre = n as f64 / 2.0;
    let mut rays = Vec::new();
    // From every corner and edge midpoint of the surface's grid, inward (toward a point near
    // the centre), starting outside.
    for p in &b.positions {
        for half in [
            [0.0, 0.0, 0.0],
            [0.5, 0.0, 0.0],
            [0.0, 0.5, 0.0],
            [0.0, 0.0, 0.5],
            [0.5, 0.5, 0.0],
        ] {
            let at: [f32; 3] = std::array::from_fn(|k| p[k] + half[k]);
            if at.iter().any(|&c| c > n as f32) {
                continue;
            }
            let aim: [f64; 3] = std::array::from_fn(|_| centre + (rng.next_f64() - 0.5));
            let d: [f32; 3] = std::array::from_fn(|k| (aim[k] - at[k] as f64) as f32);
            let o = std::array::from_fn(|k| at[k] - 2.0 * d[k]);
            rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
        }
    }
    let (all, _) = scene.list_intersections(&rays).expect("list");
    let wrong: Vec<_> = (0..rays.len()).filter(|&i| all.of(i).len() != 2).collect();
    assert!(
        wrong.is_empty(),
        "{} of {} rays crossed the box other than twice: {:?}",
        wrong.len(),
        rays.len(),
        wrong
            .iter()
            .take(5)
            .map(|&i| (rays[i], all.of(i).to_vec()))
            .collect::<Vec<_>>()
    );
    assert!(rays.len() > 500);
}

#[test]
fn rays_the_walk_cannot_take_are_refused_and_rays_that_miss_by_rule_have_no_hit() {
    let scene = build_scene(&grid(4, 1), &BuildOptions::default());
    let nan = Ray::new([f32::NAN, 0.0, 0.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    let zero = Ray::new([1.0, 1.0, 5.0], [0.0; 3], 0.0, f32::INFINITY);
    let (all, _) = scene.list_intersections(&[nan, zero]).expect("list");
    assert_eq!(all.splits, [0, 0, 0]);
    let behind = Ray::new([1.5, 1.5, 5.0], [0.0, 0.0, -1.0], -1.0, f32::INFINITY);
    let e = scene.list_intersections(&[
        Ray::new([1.5, 1.5, 5.0], [0.0, 0.0, -1.0], 0.0, 9.0),
        behind,
    ]);
    let msg = e.expect_err("tmin < 0 is refused").to_string();
    assert!(msg.contains("ray 1") && msg.contains("tmin"), "{msg}");
    let lists = BuildOptions {
        leaf: LeafKind::List,
        ..BuildOptions::default()
    };
    let scene = build_scene(&grid(4, 1), &lists);
    let msg = scene
        .list_intersections(&[zero])
        .expect_err("leaf lists")
        .to_string();
    assert!(msg.contains("leaf lists"), "{msg}");
}
