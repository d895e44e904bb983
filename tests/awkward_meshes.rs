//! Valid but awkward meshes build, verify and trace exactly like brute force.

mod common;

use common::*;
use oavm::rays::{Camera, random_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray};

fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh {
        positions,
        triangles,
    }
}

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

fn check(m: &Mesh, opts: &BuildOptions, label: &str) {
    let scene = build_scene(m, opts);
    let b = bounds(m);
    let mut rays = random_rays(&b, 3000, 11);
    rays.extend(Camera::framing(&b).primary_rays(48, 36));
    let (bad_c, bad_a, n) = compare_with_brute(m, &scene, &rays, 1);
    assert_eq!(
        (bad_c, bad_a),
        (0, 0),
        "{label}: disagreements with brute force over {n} rays"
    );
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
    check(&m, &BuildOptions::default(), "single triangle");
    let scene = build_scene(&m, &BuildOptions::default());
    let r = Ray::new([0.2, 0.2, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    let mut h = [Hit::MISS];
    scene.intersect_batch(&[r], &mut h).unwrap();
    assert_eq!(h[0], Hit { t: 1.0, prim: 0 });
}

#[test]
fn flat_mesh() {
    let m = grid(24, |u, v, _| [u as f32, v as f32, 0.0]);
    check(&m, &small_leaves(), "flat grid");
}

#[test]
fn far_from_the_origin() {
    let m = grid(20, |u, v, h| {
        [(1.0e6 + u) as f32, (-2.0e6 + v) as f32, (5.0e5 + h) as f32]
    });
    check(&m, &small_leaves(), "far from origin");
}

#[test]
fn tiny_and_huge_scales() {
    let tiny = grid(16, |u, v, h| {
        [(u * 1e-30) as f32, (v * 1e-30) as f32, (h * 1e-30) as f32]
    });
    check(&tiny, &small_leaves(), "1e-30 scale");
    let huge = grid(16, |u, v, h| {
        [(u * 1e30) as f32, (v * 1e30) as f32, (h * 1e30) as f32]
    });
    check(&huge, &small_leaves(), "1e30 scale");
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
    check(&m, &small_leaves(), "slivers");
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
    check(&m, &small_leaves(), "duplicates and degenerate");
    let (_, stats) = oavm::build::build(&m, &small_leaves(), &|_| {}).unwrap();
    assert_eq!(stats.degenerate_triangles, 2);
    // Ten copies of one big quad: subdivision must stop (no separation), not explode.
    let mut q = Mesh {
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
    let (_, stats) = oavm::build::build(
        &q,
        &BuildOptions {
            leaf_size: 1,
            max_depth: 21,
            merge: true,
        },
        &|_| {},
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
            merge: true,
        },
        "stacked quads",
    );
}

#[test]
fn only_degenerate_triangles_give_an_empty_tree() {
    let m = mesh(
        vec![[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        vec![[0, 1, 2]],
    );
    check(&m, &BuildOptions::default(), "only degenerate");
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
    let (bad_c, bad_a, n) = compare_with_brute(&m, &scene, &rays, 1);
    assert_eq!((bad_c, bad_a), (0, 0), "over {n} rays");
}
