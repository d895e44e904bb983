//! Helpers shared by the unit tests of the comparison structures: meshes, rays, and the
//! comparison with brute force ([`check`]) every structure's tests go through.

use super::leaf::Tri;
use super::{Accelerator, Triangles};
use crate::Counters;
use oavm::geom::{Hit, Ray, reference};
use oavm::mesh::Mesh;
use oavm::rays::{Bounds, SplitMix64};

/// The mesh of the triangles `v` (each its own three vertices) and its `Triangles` (degenerate
/// ones dropped; primitive ids are indices into `v`).
pub(crate) fn tris_of(v: Vec<Tri>) -> (Triangles, Mesh) {
    let mut mesh = Mesh::default();
    for t in &v {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(t);
        mesh.triangles.push([base, base + 1, base + 2]);
    }
    let tris = Triangles::from_mesh(&mesh).unwrap();
    (tris, mesh)
}

/// Uniform numbers in `[0, 1)`.
pub(crate) fn rng(seed: u64) -> impl FnMut() -> f32 {
    let mut s = SplitMix64::new(seed);
    move || s.next_f64() as f32
}

/// `n` random triangles of size about 0.2 in the unit cube.
pub(crate) fn unit_soup(n: usize, seed: u64) -> Vec<Tri> {
    let mut r = rng(seed);
    (0..n)
        .map(|_| {
            let c = [r(), r(), r()];
            std::array::from_fn(|_| std::array::from_fn(|k| c[k] + 0.2 * (r() - 0.5)))
        })
        .collect()
}

/// A random triangle of size about `scale` in the cube `[0, 10]^3`.
pub(crate) fn rng_tri(rng: &mut SplitMix64, scale: f32) -> Tri {
    let base: [f32; 3] = std::array::from_fn(|_| rng.next_f64() as f32 * 10.0);
    std::array::from_fn(|_| {
        std::array::from_fn(|k| base[k] + (rng.next_f64() as f32 - 0.5) * scale)
    })
}

/// `n` triangles of [`rng_tri`].
pub(crate) fn soup(n: usize, scale: f32, seed: u64) -> Vec<Tri> {
    let mut rng = SplitMix64::new(seed);
    (0..n).map(|_| rng_tri(&mut rng, scale)).collect()
}

/// A flat grid of `n` x `n` quads (two triangles each) in the plane `z = 0`, cells of 1.
pub(crate) fn flat_grid(n: usize) -> Vec<Tri> {
    let mut v = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f32, j as f32);
            v.push([[x, y, 0.0], [x + 1.0, y, 0.0], [x + 1.0, y + 1.0, 0.0]]);
            v.push([[x, y, 0.0], [x + 1.0, y + 1.0, 0.0], [x, y + 1.0, 0.0]]);
        }
    }
    v
}

/// Random rays from around the unit cube, some axis-parallel, some starting inside.
pub(crate) fn unit_rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut r = rng(seed);
    (0..n)
        .map(|i| {
            let o = [r() * 1.6 - 0.3, r() * 1.6 - 0.3, r() * 1.6 - 0.3];
            let mut d = [r() - 0.5, r() - 0.5, r() - 0.5];
            if i % 4 == 0 {
                let k = i / 4 % 3;
                d = [0.0; 3];
                d[k] = if i % 8 == 0 { 1.0 } else { -1.0 };
            }
            Ray::new(o, d, 0.0, f32::INFINITY)
        })
        .collect()
}

/// A flat mesh and rays at it, drawn from `r`: `n` right triangles with legs `size` lying in the
/// plane `z = 0.5` over the unit square, and from each of `origins` random points one ray along
/// `z` toward the plane, one slanted toward it and, if `in_plane`, one lying in it.
pub(crate) fn flat_mesh_and_rays(
    r: &mut impl FnMut() -> f32,
    n: usize,
    size: f32,
    origins: usize,
    in_plane: bool,
) -> (Vec<Tri>, Vec<Ray>) {
    let tris = (0..n)
        .map(|_| {
            let (x, y) = (r(), r());
            [[x, y, 0.5], [x + size, y, 0.5], [x, y + size, 0.5]]
        })
        .collect();
    let mut rays = Vec::new();
    for _ in 0..origins {
        let o = [r(), r(), r() * 2.0 - 0.5];
        let d = if o[2] > 0.5 { -1.0 } else { 1.0 };
        rays.push(Ray::new(o, [0.0, 0.0, d], 0.0, f32::INFINITY));
        rays.push(Ray::new(o, [r() - 0.5, r() - 0.5, d], 0.0, f32::INFINITY));
        if in_plane {
            let d = [r() - 0.5, r() - 0.5, 0.0];
            rays.push(Ray::new([o[0], o[1], 0.5], d, 0.0, 9.0));
        }
    }
    (tris, rays)
}

/// Random rays from inside the unit cube with random ranges: `tmin` uniform in `tmin`, `tmax`
/// in `[0, 1.5)`, swapped if need be.
pub(crate) fn ranged_rays(n: usize, seed: u64, tmin: [f32; 2]) -> Vec<Ray> {
    let mut r = rng(seed);
    (0..n)
        .map(|_| {
            let o = [r(), r(), r()];
            let d = [r() - 0.5, r() - 0.5, r() - 0.5];
            let (a, b) = (r() * (tmin[1] - tmin[0]) + tmin[0], r() * 1.5);
            Ray::new(o, d, a.min(b), a.max(b))
        })
        .collect()
}

/// The single triangle `(0,0,0), (1,0,0), (0,1,0)` alone in `acc` is hit from `z = 2` at
/// `t = 2` by one visit of one node, a leaf, and one triangle test.
pub(crate) fn assert_one_visit_hits_one_triangle(acc: &dyn Accelerator) {
    let mut c = Counters::default();
    let r = Ray::new([0.25, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    assert_eq!(acc.intersect(&r, &mut c), Hit { t: 2.0, prim: 0 });
    assert_eq!(
        (c.nodes_visited, c.leaves_visited, c.triangles_tested),
        (1, 1, 1)
    );
}

/// Random rays around `t`'s bounds, plus awkward ones: axis-parallel, with zero direction
/// components, starting inside, through vertices and edge midpoints, limited `tmin`/`tmax`, and
/// three invalid rays.
pub(crate) fn awkward_rays(t: &Triangles, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = SplitMix64::new(seed);
    let (lo, hi) = (t.min, t.max);
    let mut rays = Vec::new();
    let point = |rng: &mut SplitMix64, pad: f32| -> [f32; 3] {
        std::array::from_fn(|k| {
            let e = (hi[k] - lo[k]).max(1e-3);
            lo[k] - pad * e + (1.0 + 2.0 * pad) * e * rng.next_f64() as f32
        })
    };
    for i in 0..n {
        let o = point(&mut rng, 0.3);
        let target = match i % 3 {
            0 => point(&mut rng, 0.0),
            // Toward a vertex or an edge midpoint: exercises shared edges.
            1 => {
                t.v.get(rng.next_u64() as usize % t.v.len().max(1))
                    .map_or(o, |v| v[0])
            }
            _ => {
                t.v.get(rng.next_u64() as usize % t.v.len().max(1))
                    .map_or(o, |v| std::array::from_fn(|k| (v[1][k] + v[2][k]) * 0.5))
            }
        };
        let mut d: [f32; 3] = std::array::from_fn(|k| target[k] - o[k]);
        match i % 7 {
            // Zero one or two components.
            1 => d[(i / 7) % 3] = 0.0,
            2 => {
                d[(i / 7) % 3] = 0.0;
                d[(i / 7 + 1) % 3] = 0.0;
            }
            3 => d[(i / 7) % 3] = -0.0,
            _ => {}
        }
        if d.iter().all(|&x| x == 0.0) {
            d = [0.0, 0.0, 1.0];
        }
        let (tmin, tmax) = match i % 5 {
            0 => (0.0, 0.5),
            1 => (0.3, f32::INFINITY),
            2 => (-1.0, 2.0),
            _ => (0.0, f32::INFINITY),
        };
        rays.push(Ray::new(o, d, tmin, tmax));
    }
    // Axis-parallel rays, both ways along each axis, from inside and outside.
    for a in 0..3 {
        for s in [-1.0f32, 1.0] {
            for _ in 0..n / 20 {
                let o = point(&mut rng, 0.1);
                let mut d = [0.0; 3];
                d[a] = s;
                rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
            }
        }
    }
    // Invalid rays miss.
    rays.push(Ray::new([0.0; 3], [0.0; 3], 0.0, 1.0));
    rays.push(Ray::new([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, 1.0));
    rays.push(Ray::new([0.0; 3], [1.0, 0.0, 0.0], 2.0, 1.0));
    rays
}

/// Compares the closest and any hit of `acc` with the f64 reference (`geom::reference`, which
/// shares no code with the structures' f32 test) on every ray of `rays`, closest hits by the
/// agreement rule ([`Hit::agrees`](oavm::geom::Hit::agrees)), any hits exactly (rays grazing
/// an edge aside, `reference::grazes`), and requires at least `min_hits` of the rays to hit, so
/// that a comparison is never vacuous. Returns the number of rays that hit.
pub(crate) fn check(acc: &dyn Accelerator, mesh: &Mesh, rays: &[Ray], min_hits: usize) -> usize {
    let diag = Bounds::of_points(mesh.positions.iter().copied())
        .diagonal()
        .max(f64::MIN_POSITIVE);
    let tris = mesh.corners();
    let mut c = Counters::default();
    let mut hits = 0;
    for r in rays {
        let want = reference::closest(&tris, r);
        let got = acc.intersect(r, &mut c);
        let occluded = acc.occluded(r, &mut c);
        hits += want.is_hit() as usize;
        if reference::grazes(&tris, r) {
            continue;
        }
        assert!(
            want.agrees(&got, diag),
            "{r:?}: reference {want:?}, got {got:?}"
        );
        assert_eq!(reference::occluded(&tris, r), occluded, "any hit of {r:?}");
    }
    assert_eq!(c.rays, 0, "the batch counts rays, not the structure");
    assert!(c.nodes_visited >= c.leaves_visited, "{c:?}");
    assert!(
        hits >= min_hits,
        "{hits} of {} rays hit, fewer than {min_hits}",
        rays.len()
    );
    hits
}
