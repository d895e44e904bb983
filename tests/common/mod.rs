//! Fixtures shared by the integration tests: the shared scenes (a missing `../shared` is a
//! failure, never a skip), scenes built in memory, the f64 reference and the comparison with it
//! (which requires hits: a comparison that passes with none proves nothing), and helpers to run
//! the binaries; `layout`, the format's byte layout as the spec gives it (which the corruption
//! tests, `tests/corruption/`, also use).
#![allow(dead_code)]

pub mod layout;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use oavm::geom::reference;
use oavm::physical::AlignedBytes;
use oavm::rays::Bounds;
use oavm::{BuildOptions, Hit, Mesh, Ray, Scene};
use rayon::prelude::*;

/// A scene from `../shared/scenes`, relative to the crate. Panics (fails the test) if it is
/// missing: the tests need `../shared` beside the checkout, as CI provides it.
pub fn shared_scene(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes")
        .join(rel);
    assert!(
        p.exists(),
        "{} is missing: the tests read ../shared/scenes beside the checkout (CI provides it)",
        p.display()
    );
    p
}

/// A mesh of `../shared/scenes`.
pub fn load_shared(rel: &str) -> Mesh {
    let path = shared_scene(rel);
    oavm::mesh::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A mesh from positions and triangles.
pub fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh {
        geometries: Vec::new(),
        positions,
        triangles,
    }
}

/// The corners of every triangle of `mesh`, by primitive id (the reference's input).
pub fn corners(mesh: &Mesh) -> Vec<[[f32; 3]; 3]> {
    (0..mesh.triangles.len())
        .map(|i| mesh.triangle(i))
        .collect()
}

/// Builds `mesh` and opens the result from memory; the file must verify.
pub fn build_scene(mesh: &Mesh, opts: &BuildOptions) -> Scene<AlignedBytes> {
    let (parts, _) = oavm::pack::build(mesh, opts, &oavm::pack::Quiet).expect("build");
    let bytes = oavm::pack::encode(&parts).expect("encode");
    let scene = Scene::from_bytes(bytes, "test.oavm").expect("open");
    let report = scene.verify().expect("verify");
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

/// How the tracer's answers compare with the f64 reference's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Comparison {
    /// Rays compared.
    pub rays: usize,
    /// Rays the reference says hit something (closest hit) / are occluded (any hit).
    pub reference_hits: usize,
    pub reference_occluded: usize,
    /// Disagreements (RAYS.md's rule), not counting grazing hits on edges.
    pub closest: usize,
    pub any: usize,
    /// Disagreements excused as grazing hits on an edge (`reference::Meet::margin` within
    /// rounding of 0 for a triangle the ray meets).
    pub grazing: usize,
}

impl Comparison {
    /// Fails unless every ray agrees (grazing edge hits aside, at most `grazing` of them) and
    /// the reference found at least `min_hits` hits: agreement on misses alone proves nothing.
    pub fn require(&self, min_hits: usize, grazing: usize, what: &str) {
        assert!(
            self.closest == 0 && self.any == 0,
            "{what}: {self:?} disagree with the f64 reference"
        );
        assert!(
            self.grazing <= grazing,
            "{what}: {self:?}: too many grazing disagreements"
        );
        assert!(
            self.reference_hits >= min_hits,
            "{what}: {self:?}: the reference found fewer than {min_hits} hits"
        );
    }
}

/// Traces `rays` (closest hit and any hit) and compares every `stride`-th ray with the f64
/// reference over `mesh`'s triangles.
pub fn compare_with_reference<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    mesh: &Mesh,
    scene: &Scene<D>,
    rays: &[Ray],
    stride: usize,
) -> Comparison {
    let tris = corners(mesh);
    let diag = bounds(mesh).diagonal().max(f64::MIN_POSITIVE);
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits).expect("trace");
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ).expect("trace any");
    let mut c = Comparison::default();
    let picked: Vec<usize> = (0..rays.len()).step_by(stride.max(1)).collect();
    // The f64 reference, most of a comparison's time, on every core.
    let references: Vec<_> = picked
        .par_iter()
        .map(|&i| {
            let want = reference::closest(&tris, &rays[i]);
            (want, reference::occluded(&tris, &rays[i]))
        })
        .collect();
    for (&i, &(want, occluded)) in picked.iter().zip(&references) {
        c.rays += 1;
        let ray = &rays[i];
        // Closest and any hit must be consistent with each other on every ray.
        assert_eq!(
            hits[i].is_hit(),
            occ[i] == 1,
            "closest/any disagree on ray {i} {ray:?}"
        );
        c.reference_hits += want.is_hit() as usize;
        c.reference_occluded += occluded as usize;
        if !agree(want, hits[i], diag) {
            if reference::grazes(&tris, ray) {
                c.grazing += 1;
            } else {
                c.closest += 1;
                if c.closest <= 3 {
                    eprintln!(
                        "closest mismatch ray {i} {ray:?}: reference {want:?}, oavm {:?}",
                        hits[i]
                    );
                }
            }
        }
        if occluded != (occ[i] == 1) && !reference::grazes(&tris, ray) {
            c.any += 1;
            if c.any <= 3 {
                eprintln!("any-hit mismatch ray {i} {ray:?}: reference {occluded}");
            }
        }
    }
    c
}

/// A binary little-endian PLY of `mesh` (float vertices, uchar-count int-index faces).
pub fn binary_ply(mesh: &Mesh) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
         property float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    for p in &mesh.positions {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    out
}

/// A binary you can run: `oavm-pack`, `oavm-trace`, `oavm-inspect`, `oavm-update` (`oavm-bench`
/// is `oavm-compare`'s, tested there).
pub fn bin(name: &str) -> Command {
    let path = match name {
        "oavm-pack" => env!("CARGO_BIN_EXE_oavm-pack"),
        "oavm-trace" => env!("CARGO_BIN_EXE_oavm-trace"),
        "oavm-inspect" => env!("CARGO_BIN_EXE_oavm-inspect"),
        "oavm-update" => env!("CARGO_BIN_EXE_oavm-update"),
        _ => panic!("no binary {name}"),
    };
    Command::new(path)
}

/// Runs `cmd`, returning its output; its stdout and stderr as text.
pub fn run(cmd: &mut Command) -> (Output, String, String) {
    let out = cmd.output().expect("run");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, stdout, stderr)
}

/// Packs `mesh` (a path) into `out` with `oavm-pack` and extra arguments; panics on failure.
pub fn pack(mesh: &Path, out: &Path, extra: &[&str]) {
    let (o, _, err) = run(bin("oavm-pack").arg(mesh).arg(out).args(extra));
    assert!(o.status.success(), "oavm-pack failed: {err}");
}
