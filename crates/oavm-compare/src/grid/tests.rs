use super::build::resolution;
use super::*;
use crate::Accelerator;
use crate::Counters;
use crate::Triangles;
use crate::test_util::{
    check, flat_mesh_and_rays, ranged_rays, rng, tris_of, unit_rays, unit_soup,
};
use oavm::geom::{Hit, Ray};

#[test]
fn resolution_follows_the_cube_root_rule_and_handles_flat_boxes() {
    assert_eq!(resolution([1.0; 3], 4000.0), [15, 15, 15]);
    let r = resolution([2.0, 1.0, 1.0], 4000.0);
    assert!(r[0] >= 2 * r[1] - 1 && r[0] <= 2 * r[1] + 1, "{r:?}");
    let r = resolution([1.0, 1.0, 1e-9], 4000.0);
    assert_eq!(r[2], 1);
    assert!(r[0] * r[1] <= 4000 && r[0] * r[1] > 3000, "{r:?}");
    assert_eq!(resolution([1.0; 3], 1e12), [MAX_RES; 3]);
    assert_eq!(resolution([1.0; 3], 1.0), [1; 3]);
}

#[test]
fn random_soup_matches_brute_force() {
    let (tris, mesh) = tris_of(unit_soup(500, 1));
    let g = UniformGrid::build(&tris);
    assert!(g.resolution().iter().all(|&r| r > 1));
    assert!(g.references() >= tris.len());
    check(&g, &mesh, &unit_rays(4000, 2), 500);
    let s = g.stats();
    assert_eq!(s.nodes, s.pointers);
    assert!(s.bytes > 36 * 500);
}

/// `bytes` counts the grid's own record: its size is part of the figures `oavm-bench` reports.
#[test]
#[cfg(target_pointer_width = "64")]
fn bytes_count_the_record_the_lists_and_the_triangles() {
    assert_eq!(std::mem::size_of::<UniformGrid>(), 256);
    let (tris, _) = tris_of(unit_soup(100, 3));
    let g = UniformGrid::build(&tris);
    let cells = g.stats().nodes as usize;
    let want = 256 + 4 * (cells + 1) + 4 * g.references() + 40 * tris.len();
    assert_eq!(g.stats().bytes, want as u64);
}

#[test]
fn empty_and_single_triangle() {
    let g = UniformGrid::build(&Triangles::default());
    let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
    let mut c = Counters::default();
    assert_eq!(g.intersect(&r, &mut c), Hit::MISS);
    assert!(!g.occluded(&r, &mut c));

    let (tris, mesh) = tris_of(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
    let g = UniformGrid::build(&tris);
    let down = Ray::new([0.25, 0.25, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    assert_eq!(g.intersect(&down, &mut c), Hit { t: 1.0, prim: 0 });
    check(&g, &mesh, &unit_rays(2000, 3), 20);
    let mut r = rng(4);
    let rays: Vec<_> = (0..500)
        .map(|_| Ray::new([r(), r(), 1.0], [r() - 0.5, r() - 0.5, -1.0], 0.0, 10.0))
        .collect();
    check(&g, &mesh, &rays, 100);
    // Invalid rays miss.
    let bad = Ray::new([0.25, 0.25, 1.0], [0.0; 3], 0.0, 1.0);
    assert_eq!(g.intersect(&bad, &mut c), Hit::MISS);
}

/// A flat mesh (all triangles in z = 0.5), whose box has no volume, and a mesh whose
/// triangles all lie in a plane that is a face between cells.
#[test]
fn flat_meshes_and_triangles_on_cell_faces() {
    let mut r = rng(5);
    let (flat, rays) = flat_mesh_and_rays(&mut r, 400, 0.05, 3000, false);
    let (tris, mesh) = tris_of(flat);
    let g = UniformGrid::build(&tris);
    assert_eq!(g.resolution()[2], 1);
    check(&g, &mesh, &rays, 300);

    // A block of soup plus a plane of triangles at x = 0.5 exactly, which (for an even
    // resolution along x over the unit box) is a face between cells; rays along x and
    // through the plane from both sides, starting inside the grid.
    let mut v = unit_soup(300, 6);
    v.push([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    v.push([[1.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 0.0]]);
    for i in 0..200 {
        let (y, z) = ((i % 20) as f32 / 20.0, (i / 20) as f32 / 10.0);
        v.push([[0.5, y, z], [0.5, y + 0.05, z], [0.5, y, z + 0.1]]);
    }
    let (tris, mesh) = tris_of(v);
    let g = UniformGrid::build(&tris);
    let mut rays = Vec::new();
    for i in 0..4000 {
        let o = [r(), r(), r()];
        let d = match i % 4 {
            0 => [1.0, 0.0, 0.0],
            1 => [-1.0, 0.0, 0.0],
            2 => [r() - 0.5, r() * 0.01, 0.0],
            _ => [r() - 0.5, r() - 0.5, r() - 0.5],
        };
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
        // Rays lying in the plane of the cell face.
        let o = [0.5, r(), r()];
        let d = [0.0, r() - 0.5, r() - 0.5];
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
    }
    check(&g, &mesh, &rays, 1000);
}

#[test]
fn range_limits_are_respected() {
    let (tris, mesh) = tris_of(unit_soup(300, 7));
    let g = UniformGrid::build(&tris);
    let rays = ranged_rays(3000, 8, [0.0, 0.5]);
    check(&g, &mesh, &rays, 300);
}

#[test]
fn counters_count_cells() {
    let (tris, _) = tris_of(unit_soup(200, 9));
    let g = UniformGrid::build(&tris);
    let mut c = Counters::default();
    let r = Ray::new([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
    g.occluded(&Ray { tmax: -1.0, ..r }, &mut c);
    assert_eq!(c, Counters::default()); // invalid: nothing visited
    let miss = Ray::new([-1.0, 0.5, 0.5], [-1.0, 0.0, 0.0], 0.0, f32::INFINITY);
    g.intersect(&miss, &mut c);
    assert_eq!(c.nodes_visited, 0);
    g.intersect(&r, &mut c);
    assert!(c.nodes_visited >= 1 && c.nodes_visited <= g.resolution()[0] as u64);
    assert!(c.leaves_visited <= c.nodes_visited);
    assert_eq!(c.rays, 0);
}
