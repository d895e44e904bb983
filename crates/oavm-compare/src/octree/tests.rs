use super::*;
use crate::Counters;
use crate::leaf::Tri;
use crate::test_util::{
    assert_one_visit_hits_one_triangle, awkward_rays, check, flat_grid, soup, tris_of,
};
use crate::{Accelerator, Triangles};
use oavm::geom::{Hit, Ray};
use oavm::pack::BuildOptions;
use oavm::rays::SplitMix64;

fn opts(leaf_size: u32, max_depth: u32) -> BuildOptions {
    BuildOptions {
        max_depth,
        leaf_size,
        merge: true,
        leaf: oavm::pack::LeafKind::List,
    }
}

/// Builds the octree over `v`, checks its node and pointer counts against OAVM's, and every
/// answer for a few thousand awkward rays against brute force, `min_hits` of them hitting.
fn check_octree(v: Vec<Tri>, o: &BuildOptions, min_hits: usize) -> (ClassicOctree, Triangles) {
    let (t, mesh) = tris_of(v);
    let oct = ClassicOctree::build(&t, o);
    let (_, s) = oavm::pack::build(&mesh, o, &oavm::pack::Quiet).expect("OAVM build");
    assert_eq!(oct.stats().nodes, s.nodes, "nodes");
    assert_eq!(
        oct.stats().pointers,
        s.pointers.pointer_octree_total,
        "pointers"
    );
    assert_eq!(oct.counts(), (s.internal_nodes, s.solid_leaves));
    check(&oct, &mesh, &awkward_rays(&t, 3000, 11), min_hits);
    (oct, t)
}

#[test]
fn node_records_are_36_bytes_as_counted() {
    assert_eq!(std::mem::size_of::<Node>(), 36);
    let (t, _) = tris_of(soup(500, 1.0, 7));
    let oct = ClassicOctree::build(&t, &opts(4, 16));
    let want = 36 * oct.nodes.len() + 4 * oct.refs.len() + 40 * t.len();
    assert_eq!(oct.stats().bytes, want as u64);
}

#[test]
fn empty_misses_everything() {
    for v in [
        vec![],
        vec![[[0.0; 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]],
        vec![[[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]],
    ] {
        let (t, _) = tris_of(v);
        let oct = ClassicOctree::build(&t, &BuildOptions::default());
        let mut c = Counters::default();
        let r = Ray::new([0.1, 0.1, 5.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
        assert_eq!(oct.intersect(&r, &mut c), Hit::MISS);
        assert!(!oct.occluded(&r, &mut c));
        assert_eq!(oct.stats().nodes, 0);
    }
}

#[test]
fn single_triangle_is_one_leaf() {
    let v = vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]];
    let (oct, _) = check_octree(v, &BuildOptions::default(), 300);
    assert_eq!(oct.stats().nodes, 1);
    assert_eq!(oct.stats().pointers, 1);
    assert_one_visit_hits_one_triangle(&oct);
}

#[test]
fn random_soups_agree_with_brute_force_and_oavm_counts() {
    for (n, scale, seed, k, d) in [
        (10, 3.0, 1, 1, 16),
        (200, 2.0, 2, 4, 16),
        (2000, 1.0, 3, 8, 16),
        (2000, 1.0, 4, 32, 16),
        (2000, 1.0, 5, 2, 3),
    ] {
        let (oct, _) = check_octree(soup(n, scale, seed), &opts(k, d), 500);
        assert!(
            oct.counts().0 > 0,
            "{n} triangles, K = {k}: the tree should be split"
        );
    }
}

#[test]
fn triangles_on_cell_faces() {
    // A flat grid in z = 0: the root cube is centred on it, so the mesh lies in the root's
    // mid-plane, and the grid lines fall on cell faces along x and y (20 cells a side, the
    // root's centre at 10). Rays along the plane, through grid lines and vertices.
    let (oct, _) = check_octree(flat_grid(20), &opts(4, 16), 1000);
    let (_, mesh) = tris_of(flat_grid(20));
    let mut rays = Vec::new();
    for i in 0..=40 {
        let x = i as f32 * 0.5;
        rays.extend([
            Ray::new([x, 10.0, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
            Ray::new([x, x, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
            Ray::new([-1.0, x, 0.0], [1.0, 0.0, 0.0], 0.0, f32::INFINITY),
            Ray::new([x, 10.0, 0.0], [0.0, -1.0, 0.0], 0.0, f32::INFINITY),
            Ray::new([10.0, 10.0, 0.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
        ]);
    }
    check(&oct, &mesh, &rays, 80);
    // Boxes of axis-aligned quads on the faces of cells of several levels: a cube made of
    // 12 triangles with corners on lattice planes of the root, nested.
    let mut v = Vec::new();
    for s in [8.0f32, 4.0, 2.0, 1.0] {
        let c = [[-s, -s, -s], [s, -s, -s], [s, s, -s], [-s, s, -s]];
        let top = c.map(|p| [p[0], p[1], s]);
        v.push([c[0], c[1], c[2]]);
        v.push([c[0], c[2], c[3]]);
        v.push([top[0], top[2], top[1]]);
        v.push([top[0], top[3], top[2]]);
        for e in 0..4 {
            let f = (e + 1) % 4;
            v.push([c[e], c[f], top[f]]);
            v.push([c[e], top[f], top[e]]);
        }
    }
    check_octree(v, &opts(2, 8), 1000);
}

#[test]
fn rays_starting_inside_and_axis_parallel() {
    let v = soup(1000, 1.5, 21);
    let (_, mesh) = tris_of(v.clone());
    let (oct, t) = check_octree(v, &opts(4, 16), 1000);
    let mut rng = SplitMix64::new(3);
    let mut rays = Vec::new();
    for _ in 0..2000 {
        let o: [f32; 3] =
            std::array::from_fn(|k| t.min[k] + (t.max[k] - t.min[k]) * rng.next_f64() as f32);
        let mut d = [0f32; 3];
        let a = (rng.next_u64() % 3) as usize;
        d[a] = if rng.next_u64().is_multiple_of(2) {
            1.0
        } else {
            -1.0
        };
        if rng.next_u64().is_multiple_of(2) {
            d[(a + 1) % 3] = rng.next_f64() as f32 - 0.5;
        }
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
    }
    check(&oct, &mesh, &rays, 100);
}

#[test]
fn closest_hit_stops_early() {
    // A stack of parallel planes: a ray straight through should not visit every leaf.
    let mut v = Vec::new();
    for z in 0..64 {
        let z = z as f32;
        v.push([[0.0, 0.0, z], [10.0, 0.0, z], [0.0, 10.0, z]]);
    }
    let (oct, _) = check_octree(v, &opts(1, 10), 1000);
    let r = Ray::new([1.0, 1.0, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY);
    let mut c = Counters::default();
    assert_eq!(oct.intersect(&r, &mut c), Hit { t: 1.0, prim: 0 });
    assert!(c.triangles_tested < 8, "{c:?}");
    let mut c2 = Counters::default();
    let r = Ray::new([1.0, 1.0, 70.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    assert_eq!(oct.intersect(&r, &mut c2), Hit { t: 7.0, prim: 63 });
    assert!(c2.triangles_tested < 8, "{c2:?}");
}
