//! Writes the ray sets we measure with as RAYS files (`../shared/RAYS.md`), so any tracer can be
//! given exactly the same rays:
//!
//!     cargo run --release --example rays -- MESH OUT_PREFIX [--random N] [--seed S] [--width W --height H]
//!
//! writes `OUT_PREFIX.random.rays` (N random rays, default 10^6), `OUT_PREFIX.primary.rays`
//! (the default camera of `oavm-trace`, W x H, default 1024x768) and `OUT_PREFIX.shadow.rays`
//! (toward the default light from every primary ray's closest hit, found by brute force-checked
//! OAVM tracing of the mesh packed in memory with default options).

use std::path::PathBuf;

use oavm::rays::{self, Bounds, Camera};
use oavm::{BuildOptions, Hit, Scene};

fn main() {
    let mut args = std::env::args().skip(1);
    let usage = "usage: rays MESH OUT_PREFIX [--random N] [--seed S] [--width W --height H]";
    let mesh_path = PathBuf::from(args.next().expect(usage));
    let prefix = args.next().expect(usage);
    let (mut n, mut seed, mut w, mut h) = (1_000_000usize, 1u64, 1024u32, 768u32);
    while let Some(a) = args.next() {
        let v = args.next().expect(usage);
        match a.as_str() {
            "--random" => n = v.parse().expect("--random N"),
            "--seed" => seed = v.parse().expect("--seed S"),
            "--width" => w = v.parse().expect("--width W"),
            "--height" => h = v.parse().expect("--height H"),
            _ => panic!("{usage}"),
        }
    }
    let mesh = oavm::mesh::load(&mesh_path).unwrap_or_else(|e| panic!("{e}"));
    let b = Bounds::of_points(mesh.positions.iter().copied());
    let random = rays::random_rays(&b, n, seed);
    let primary = Camera::framing(&b).primary_rays(w, h);
    let (parts, _) =
        oavm::build::build(&mesh, &BuildOptions::default(), &oavm::build::Quiet).expect("build");
    let scene =
        Scene::from_bytes(oavm::build::encode(&parts).expect("encode"), "memory").expect("open");
    let mut hits = vec![Hit::MISS; primary.len()];
    scene.intersect_batch(&primary, &mut hits).expect("trace");
    let shadow = rays::shadow_rays(&primary, &hits, rays::default_light(&b));
    for (name, set) in [
        ("random", &random),
        ("primary", &primary),
        ("shadow", &shadow),
    ] {
        let path = PathBuf::from(format!("{prefix}.{name}.rays"));
        rays::write_rays(&path, set).unwrap_or_else(|e| panic!("{e}"));
        println!("{}: {} rays", path.display(), set.len());
    }
}
