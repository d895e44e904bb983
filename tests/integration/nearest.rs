//! Distance queries (`Scene::closest_points`, `Scene::occupancy`) against a brute force over every
//! triangle written here (projection onto the plane, else the nearest edge: not the library's
//! algorithm), on real meshes, paged and chunked; occupancy on a closed box through its edges
//! and corners.

use oavm::BuildOptions;
use oavm::logical::ClosestPoint;
use oavm::rays::SplitMix64;
use rayon::prelude::*;

use crate::all_hits::closed_box;
use crate::common::{bounds, build_scene, corners, load_shared};

type V = [f64; 3];
fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V, b: V) -> V {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Squared distance from `q` to segment `a b`.
fn segment_d2(q: V, a: V, b: V) -> f64 {
    let d = sub(b, a);
    let len = dot(d, d);
    let s = if len > 0.0 {
        (dot(sub(q, a), d) / len).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let p = [a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]];
    dot(sub(q, p), sub(q, p))
}

/// Squared distance from `q` to triangle `t`: to its plane where `q` projects inside it, else to
/// its nearest edge.
fn triangle_d2(q: V, t: &[[f32; 3]; 3]) -> f64 {
    let [a, b, c] = t.map(|p| p.map(f64::from));
    let n = cross(sub(b, a), sub(c, a));
    let nn = dot(n, n);
    if nn > 0.0 {
        let h = dot(sub(q, a), n) / nn;
        let p = [q[0] - h * n[0], q[1] - h * n[1], q[2] - h * n[2]];
        let inside = [(a, b), (b, c), (c, a)]
            .iter()
            .all(|&(x, y)| dot(cross(sub(y, x), sub(p, x)), n) >= 0.0);
        if inside {
            return h * h * nn;
        }
    }
    segment_d2(q, a, b)
        .min(segment_d2(q, b, c))
        .min(segment_d2(q, c, a))
}

fn brute(tris: &[[[f32; 3]; 3]], q: [f32; 3]) -> (f64, u32) {
    let q = q.map(f64::from);
    let mut best = (f64::INFINITY, u32::MAX);
    for (i, t) in tris.iter().enumerate() {
        let d2 = triangle_d2(q, t);
        if d2 < best.0 {
            best = (d2, i as u32);
        }
    }
    (best.0.sqrt(), best.1)
}

/// Points around and inside the mesh's box, and near its surface (corners moved a little).
fn points(mesh: &oavm::Mesh, n: usize, seed: u64) -> Vec<[f32; 3]> {
    let b = bounds(mesh);
    let mut rng = SplitMix64::new(seed);
    let diag = b.diagonal();
    let mut out: Vec<[f32; 3]> = (0..n / 2)
        .map(|_| {
            std::array::from_fn(|k| {
                let (lo, hi) = (b.min[k] as f64 - 0.2 * diag, b.max[k] as f64 + 0.2 * diag);
                (lo + (hi - lo) * rng.next_f64()) as f32
            })
        })
        .collect();
    for _ in 0..n - n / 2 {
        let v = mesh.positions[(rng.next_u64() % mesh.positions.len() as u64) as usize];
        out.push(std::array::from_fn(|k| {
            v[k] + ((rng.next_f64() - 0.5) * 1e-3 * diag) as f32
        }));
    }
    out
}

fn compare(rel: &str, n: usize) {
    let m = load_shared(rel);
    let scene = build_scene(&m, &BuildOptions::default());
    let tris = corners(&m);
    let diag = bounds(&m).diagonal();
    let pts = points(&m, n, 3);
    let mut got = vec![ClosestPoint::NONE; pts.len()];
    let c = scene
        .closest_points(&pts, f32::INFINITY, &mut got)
        .expect("closest");
    let want: Vec<(f64, u32)> = pts.par_iter().map(|p| brute(&tris, *p)).collect();
    let mut other_triangle = 0;
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(
            (g.distance as f64 - w.0).abs() <= 1e-6 * diag,
            "{rel} point {i} {:?}: {g:?}, brute force {w:?}",
            pts[i]
        );
        // The point is on its triangle, at the distance given.
        let t = &tris[g.prim as usize];
        let p = g.point.map(f64::from);
        assert!(
            triangle_d2(p, t).sqrt() <= 1e-6 * diag,
            "{rel} point {i}: not on its triangle"
        );
        let d = dot(sub(p, pts[i].map(f64::from)), sub(p, pts[i].map(f64::from))).sqrt();
        assert!((d - w.0).abs() <= 1e-6 * diag);
        let from_uv: V = std::array::from_fn(|k| {
            let [a, b, c] = t.map(|v| v[k] as f64);
            (1.0 - g.u as f64 - g.v as f64) * a + g.u as f64 * b + g.v as f64 * c
        });
        assert!(
            dot(sub(from_uv, p), sub(from_uv, p)).sqrt() <= 1e-5 * diag,
            "{rel} point {i}: u, v"
        );
        // Another triangle only at the same distance (a shared edge or corner).
        other_triangle += (g.prim != w.1) as usize;
    }
    assert!(
        other_triangle * 10 < pts.len(),
        "{rel}: {other_triangle} points nearest another triangle"
    );
    assert_eq!(c.rays, pts.len() as u64);
    // Within a distance: the points farther than it have none.
    let limit = (0.02 * diag) as f32;
    let mut near = vec![ClosestPoint::NONE; pts.len()];
    scene
        .closest_points(&pts, limit, &mut near)
        .expect("closest within");
    let (mut some, mut none) = (0, 0);
    for (g, w) in near.iter().zip(&want) {
        if w.0 < limit as f64 * (1.0 - 1e-6) {
            assert!((g.distance as f64 - w.0).abs() <= 1e-6 * diag);
            some += 1;
        } else if w.0 > limit as f64 * (1.0 + 1e-6) {
            assert_eq!(g.prim, u32::MAX);
            none += 1;
        }
    }
    assert!(
        some > n / 4 && none > n / 8,
        "{rel}: {some} within, {none} beyond"
    );
}

#[test]
fn closest_points_are_the_brute_force_s() {
    compare("bunny/bun_zipper.ply", 800);
    compare("dragon/dragon_vrip_res3.ply", 500);
    compare("bart/kitchen/kitchen.aff", 400);
}

#[test]
fn occupancy_of_a_closed_box_is_exact_through_its_edges_and_corners() {
    let n = 6;
    let b = closed_box(n, 7);
    let scene = build_scene(&b, &BuildOptions::default());
    let mut rng = SplitMix64::new(1);
    let mut pts: Vec<[f32; 3]> = (0..4000)
        .map(|_| std::array::from_fn(|_| (-1.0 + (n as f64 + 2.0) * rng.next_f64()) as f32))
        .collect();
    // Points on the grid's planes inside and outside, whose rays pass through edges and corners.
    for i in 0..=2 * n + 2 {
        for j in 0..=2 * n + 2 {
            pts.push([i as f32 / 2.0 - 0.5, j as f32 / 2.0 - 0.5, 3.0]);
            pts.push([i as f32 / 2.0 - 0.5, 3.0, j as f32 / 2.0 - 0.25]);
        }
    }
    let mut occ = vec![0u8; pts.len()];
    scene.occupancy(&pts, &mut occ).expect("occupancy");
    let on_surface = |p: &[f32; 3]| {
        p.iter().any(|&c| c == 0.0 || c == n as f32)
            && p.iter().all(|&c| (0.0..=n as f32).contains(&c))
    };
    let mut inside = 0;
    for (p, &o) in pts.iter().zip(&occ) {
        if on_surface(p) {
            continue;
        }
        let want = p.iter().all(|&c| c > 0.0 && c < n as f32);
        assert_eq!(o == 1, want, "{p:?}");
        inside += want as usize;
    }
    assert!(inside > 500);
    // Its closest points, against the box's own distance (a small file: one block, a top tree
    // of one node).
    let mut near = vec![ClosestPoint::NONE; pts.len()];
    scene
        .closest_points(&pts, f32::INFINITY, &mut near)
        .expect("closest");
    let side = n as f64;
    for (p, c) in pts.iter().zip(&near) {
        let q = p.map(f64::from);
        let out: f64 = q
            .iter()
            .map(|&x| (-x).max(x - side).max(0.0).powi(2))
            .sum::<f64>()
            .sqrt();
        let want = if out > 0.0 {
            out
        } else {
            q.iter()
                .map(|&x| x.min(side - x))
                .fold(f64::INFINITY, f64::min)
        };
        assert!(
            (c.distance as f64 - want).abs() < 1e-5,
            "{p:?}: {c:?}, want {want}"
        );
    }
}
