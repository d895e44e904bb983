use super::*;
use crate::Accelerator;
use crate::Counters;
use crate::leaf::Tri;
use crate::test_util::{
    assert_one_visit_hits_one_triangle, awkward_rays, check, flat_grid, rng_tri, soup, tris_of,
};
use oavm::geom::{Hit, Ray, reference};
use oavm::rays::SplitMix64;

/// Builds the BVH over `v`, validates it and checks it against brute force on a few thousand
/// awkward rays, `min_hits` of them hitting.
fn check_structure(v: Vec<Tri>, min_hits: usize) -> Bvh {
    let (t, mesh) = tris_of(v);
    let bvh = Bvh::build(&t);
    validate(&bvh, t.len());
    check(&bvh, &mesh, &awkward_rays(&t, 3000, 7), min_hits);
    bvh
}

/// Structural checks: every triangle in exactly one leaf, leaves within bounds, children
/// inside parents, the depth within the stack.
fn validate(bvh: &Bvh, n: usize) {
    assert_eq!(bvh.soup.len(), n);
    if n == 0 {
        assert!(bvh.nodes.is_empty());
        return;
    }
    let mut seen = vec![false; n];
    let mut leaves = 0;
    for (i, node) in bvh.nodes.iter().enumerate() {
        if node.n_prims > 0 {
            leaves += 1;
            assert!(node.n_prims as usize <= MAX_PRIMS_IN_NODE);
            let range = node.offset as usize..node.offset as usize + node.n_prims as usize;
            for (s, tri) in seen[range.clone()].iter_mut().zip(&bvh.soup.v[range]) {
                assert!(!*s);
                *s = true;
                for p in tri {
                    for (k, &x) in p.iter().enumerate() {
                        assert!(node.min[k] <= x && x <= node.max[k]);
                    }
                }
            }
        } else {
            for ch in [i + 1, node.offset as usize] {
                let c = &bvh.nodes[ch];
                assert!(ch > i);
                for k in 0..3 {
                    assert!(node.min[k] <= c.min[k] && c.max[k] <= node.max[k]);
                }
            }
        }
    }
    assert!(seen.iter().all(|&s| s));
    assert_eq!(bvh.nodes.len(), 2 * leaves - 1);
    assert_eq!(bvh.stats.nodes, bvh.nodes.len() as u64);
    assert_eq!(bvh.stats.pointers, bvh.nodes.len() as u64);
    assert!(bvh.depth() < STACK_SIZE);
}

#[test]
fn empty_misses_everything() {
    let (t, _) = tris_of(vec![]);
    let bvh = Bvh::build(&t);
    let mut c = Counters::default();
    let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
    assert_eq!(bvh.intersect(&r, &mut c), Hit::MISS);
    assert!(!bvh.occluded(&r, &mut c));
    assert_eq!(bvh.stats().nodes, 0);
    // Only degenerate triangles: also empty.
    let (t, _) = tris_of(vec![[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]]);
    assert!(Bvh::build(&t).nodes.is_empty());
}

#[test]
fn single_triangle() {
    let bvh = check_structure(
        vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]],
        300,
    );
    assert_eq!(bvh.nodes.len(), 1);
    assert_one_visit_hits_one_triangle(&bvh);
}

#[test]
fn random_soups_agree_with_brute_force() {
    for (n, scale, seed) in [(2, 3.0, 1), (5, 3.0, 2), (100, 2.0, 3), (2000, 1.0, 4)] {
        let bvh = check_structure(soup(n, scale, seed), 300);
        assert!(bvh.nodes.len() > 1 || n < 2);
    }
}

#[test]
fn flat_mesh_and_axis_parallel_rays() {
    check_structure(flat_grid(20), 1000);
    // Rays straight down through grid vertices and edges hit (watertight).
    let (t, mesh) = tris_of(flat_grid(20));
    let bvh = Bvh::build(&t);
    let mut rays = Vec::new();
    for i in 0..=20 {
        let x = i as f32;
        let r = Ray::new([x, 7.5, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert!(
            reference::closest(&mesh.corners(), &r).is_hit(),
            "{r:?} passes through the mesh"
        );
        rays.push(r);
        // In the plane of the mesh, along x.
        rays.push(Ray::new(
            [-1.0, x, 0.0],
            [1.0, 0.0, 0.0],
            0.0,
            f32::INFINITY,
        ));
    }
    check(&bvh, &mesh, &rays, 21);
}

#[test]
fn identical_triangles_split_by_median() {
    // 1000 copies of one triangle: centroids coincide, so no SAH split exists; leaves must
    // still hold at most MAX_PRIMS_IN_NODE and the depth stay within the stack.
    let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]];
    let bvh = check_structure(vec![tri; 1000], 300);
    assert!(bvh.depth() <= 10);
}

#[test]
fn deep_unbalanced_input_stays_within_the_stack() {
    // Triangles at geometrically shrinking scales: SAH peels one off per level.
    let mut v = Vec::new();
    for i in 0..200 {
        let s = 0.8f32.powi(i);
        v.push([[s, 0.0, 0.0], [s * 1.01, 0.0, 0.0], [s, s * 0.01, 0.0]]);
    }
    let bvh = check_structure(v, 150);
    assert!(bvh.depth() < STACK_SIZE);
}

#[test]
fn non_finite_vertices_do_not_panic() {
    let mut rng = SplitMix64::new(5);
    let mut v: Vec<_> = (0..50).map(|_| rng_tri(&mut rng, 1.0)).collect();
    v.push([[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    v.push([[f32::INFINITY, 0.0, 0.0], [1.0, 2.0, 0.0], [0.0, 1.0, 3.0]]);
    v.push([[f32::NEG_INFINITY; 3], [f32::INFINITY; 3], [0.0, 1.0, 3.0]]);
    let (t, _) = tris_of(v);
    let bvh = Bvh::build(&t);
    let mut c = Counters::default();
    let (finite, _) = tris_of(soup(50, 1.0, 5));
    for r in awkward_rays(&finite, 500, 1) {
        bvh.intersect(&r, &mut c);
        bvh.occluded(&r, &mut c);
    }
}

#[test]
fn counts_are_sane() {
    let (t, _) = tris_of(soup(500, 1.0, 9));
    let bvh = Bvh::build(&t);
    let mut c = Counters::default();
    for r in awkward_rays(&t, 200, 3) {
        bvh.intersect(&r, &mut c);
    }
    assert!(c.nodes_visited >= c.leaves_visited);
    assert!(c.triangles_tested >= c.leaves_visited);
    assert!(c.triangles_tested <= c.leaves_visited * MAX_PRIMS_IN_NODE as u64);
    let s = bvh.stats();
    assert_eq!(s.bytes, s.nodes * 32 + t.len() as u64 * 40);
}
