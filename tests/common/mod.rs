//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use oavm::geom::brute;
use oavm::physical::AlignedBytes;
use oavm::rays::Bounds;
use oavm::{BuildOptions, Hit, Mesh, Ray, Scene};

/// A scene from `../shared/scenes`, relative to the crate.
pub fn shared_scene(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes")
        .join(rel)
}

/// Builds `mesh` and opens the result from memory.
pub fn build_scene(mesh: &Mesh, opts: &BuildOptions) -> Scene<AlignedBytes> {
    let (parts, _) = oavm::build::build(mesh, opts, &|_| {}).expect("build");
    let bytes = oavm::physical::writer::encode(&parts);
    let scene = Scene::from_bytes(bytes, "test.oavm").expect("open");
    let report = scene.verify();
    assert!(report.is_ok(), "verify: {:?}", report.defects);
    scene
}

pub fn bounds(mesh: &Mesh) -> Bounds {
    Bounds::of_points(mesh.positions.iter().copied())
}

/// The agreement rule of RAYS.md ([`Hit::agrees`]).
pub fn agree(a: Hit, b: Hit, diag: f64) -> bool {
    a.agrees(&b, diag)
}

/// Traces `rays` (closest hit and any hit) and compares every `stride`-th ray with brute force.
/// Returns the number of disagreements (closest, any) and of rays compared.
pub fn compare_with_brute(
    mesh: &Mesh,
    scene: &Scene<AlignedBytes>,
    rays: &[Ray],
    stride: usize,
) -> (usize, usize, usize) {
    let diag = bounds(mesh).diagonal().max(f64::MIN_POSITIVE);
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits).expect("trace");
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ).expect("trace any");
    let (mut bad_c, mut bad_a, mut n) = (0, 0, 0);
    for i in (0..rays.len()).step_by(stride.max(1)) {
        n += 1;
        let r = brute::intersect(mesh, &rays[i]);
        if !agree(r, hits[i], diag) {
            bad_c += 1;
            if bad_c <= 3 {
                eprintln!(
                    "closest mismatch ray {i} {:?}: brute {r:?} oavm {:?}",
                    rays[i], hits[i]
                );
            }
        }
        if brute::occluded(mesh, &rays[i]) != (occ[i] == 1) {
            bad_a += 1;
            if bad_a <= 3 {
                eprintln!("any-hit mismatch ray {i} {:?}", rays[i]);
            }
        }
        // Closest and any hit must be consistent with each other on every ray.
        assert_eq!(
            hits[i].is_hit(),
            occ[i] == 1,
            "closest/any disagree on ray {i}"
        );
    }
    (bad_c, bad_a, n)
}
