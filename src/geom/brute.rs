//! Brute force: every ray against every triangle. The reference the tracer is checked against
//! (it shares only the watertight triangle test with the tracer, none of the traversal).

use super::triangle::RayShear;
use super::{Hit, Ray};
use crate::mesh::Mesh;

/// Closest hit of `ray` over all triangles of `mesh`; ties keep the lowest primitive id.
pub fn intersect(mesh: &Mesh, ray: &Ray) -> Hit {
    if !ray.is_valid() {
        return Hit::MISS;
    }
    let shear = RayShear::new(ray);
    let mut best = Hit::MISS;
    let mut tmax = ray.tmax;
    for i in 0..mesh.triangles.len() {
        if let Some(t) = shear.intersect(&mesh.triangle(i), ray.tmin, tmax)
            && (!best.is_hit() || t < best.t)
        {
            best = Hit { t, prim: i as u32 };
            tmax = t;
        }
    }
    best
}

/// Whether any triangle of `mesh` is hit with `tmin <= t <= tmax`.
pub fn occluded(mesh: &Mesh, ray: &Ray) -> bool {
    if !ray.is_valid() {
        return false;
    }
    let shear = RayShear::new(ray);
    (0..mesh.triangles.len()).any(|i| {
        shear
            .intersect(&mesh.triangle(i), ray.tmin, ray.tmax)
            .is_some()
    })
}
