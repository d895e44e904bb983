//! The smallest whole use of the library: pack a mesh into a file, open the file, trace a batch
//! of rays, read the answers.
//!
//!     cargo run --release --example minimal [MESH] [OUT.oavm]
//!
//! MESH defaults to the bundled bunny (`data/bunny.ply`); OUT.oavm to `bunny.oavm` in the
//! system's temporary directory. A second run could skip the pack: the file is the structure.

use oavm::pack::{PackOptions, Quiet, pack};
use oavm::rays::{Bounds, Camera};
use oavm::{Hit, Scene};

fn main() -> Result<(), oavm::Error> {
    let mut args = std::env::args_os().skip(1);
    let mesh = args.next().unwrap_or_else(|| "data/bunny.ply".into());
    let out = args
        .next()
        .map_or_else(|| std::env::temp_dir().join("bunny.oavm"), Into::into);

    // Pack: build the octree over the mesh and write it as one file.
    let report = pack(mesh.as_ref(), &out, &PackOptions::default(), &Quiet)?;
    println!(
        "packed {} triangles into {} bytes",
        report.stats.input_triangles, report.file_bytes
    );

    // Open: map the file and check its header; no block is read until a ray needs it.
    let scene = Scene::open(&out)?;

    // Trace: the 640x480 rays of a camera framing the mesh, closest hit, on every core.
    let header = scene.file().header();
    let bounds = Bounds {
        min: header.mesh_min,
        max: header.mesh_max,
    };
    let rays = Camera::framing(&bounds).primary_rays(640, 480);
    let mut hits = vec![Hit::MISS; rays.len()];
    let counters = scene.intersect_batch(&rays, &mut hits)?;

    // Read the answers: `t` along each ray and the primitive (input triangle) hit.
    let hit = hits.iter().filter(|h| h.is_hit()).count();
    let nearest = hits
        .iter()
        .filter(|h| h.is_hit())
        .min_by(|a, b| a.t.total_cmp(&b.t));
    println!("{hit} of {} rays hit; nearest: {nearest:?}", rays.len());
    println!(
        "{:.2} triangle tests a ray",
        counters.triangles_tested as f64 / rays.len() as f64
    );
    Ok(())
}
