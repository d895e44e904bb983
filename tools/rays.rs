//! Writes the ray sets we measure with as RAYS files (`../shared/RAYS.md`), so any tracer can be
//! given exactly the same rays:
//!
//!     cargo run --release --features tools --example rays -- MESH OUT_PREFIX [--random N] [--seed S] [--width W --height H]
//!
//! writes `OUT_PREFIX.random.rays` (N random rays, default 10^6), `OUT_PREFIX.primary.rays`
//! (the default camera of `oavm-trace`, W x H, default 1024x768) and `OUT_PREFIX.shadow.rays`
//! (toward the default light from every primary ray's closest hit, found by brute force-checked
//! OAVM tracing of the mesh packed in memory with default options). MESH may be a packed
//! `.oavm` file instead (a mesh too large to pack in memory): then the model's bounds come from
//! its header, as `oavm-trace --random` and `--primary` take them, and the primary hits from
//! tracing it within the default memory budget.

use std::path::PathBuf;

use oavm::rays::{self, Bounds, Camera};
use oavm::{BuildOptions, Hit, Ray, Scene};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// Bad arguments or inputs end with a message and exit status 1, never a panic.
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rays: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The random rays, the primary rays and their hits (traced in the scene's default order).
fn sets<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    scene: &Scene<D>,
    b: &Bounds,
    n: usize,
    seed: u64,
    w: u32,
    h: u32,
) -> Result<(Vec<Ray>, Vec<Ray>, Vec<Hit>)> {
    let random = rays::random_rays(b, n, seed);
    let primary = Camera::framing(b).primary_rays(w, h);
    let mut hits = vec![Hit::MISS; primary.len()];
    scene.intersect_batch_ordered(&primary, &mut hits, scene.default_order())?;
    Ok((random, primary, hits))
}

fn run() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: rays MESH OUT_PREFIX [--random N] [--seed S] [--width W --height H]";
    let (Some(mesh_path), Some(prefix)) = (args.next().map(PathBuf::from), args.next()) else {
        return Err(usage.into());
    };
    let (mut n, mut seed, mut w, mut h) = (1_000_000usize, 1u64, 1024u32, 768u32);
    while let Some(a) = args.next() {
        let v = args.next().ok_or(usage)?;
        let bad = |e: std::num::ParseIntError| format!("{a} {v}: {e}");
        match a.as_str() {
            "--random" => n = v.parse().map_err(bad)?,
            "--seed" => seed = v.parse().map_err(bad)?,
            "--width" => w = v.parse().map_err(bad)?,
            "--height" => h = v.parse().map_err(bad)?,
            _ => return Err(usage.into()),
        }
    }
    // As oavm-trace: what half of the available memory holds.
    let avail = oavm::os::available_memory().unwrap_or(oavm::logical::FALLBACK_MEM_BUDGET);
    let max = oavm::logical::max_rays(avail / 2) as usize;
    if n > max || (w as u64) * (h as u64) > max as u64 {
        return Err(format!("at most {max} rays a set").into());
    }
    // A mesh is packed in memory; a packed file (too large a mesh for that) is opened, with
    // the model's bounds from its header, as oavm-trace takes them.
    let (b, random, primary, hits) = if mesh_path.extension().is_some_and(|e| e == "oavm") {
        let scene = Scene::open(&mesh_path)?;
        let hd = scene.file().header();
        let b = Bounds {
            min: hd.mesh_min,
            max: hd.mesh_max,
        };
        let (random, primary, hits) = sets(&scene, &b, n, seed, w, h)?;
        (b, random, primary, hits)
    } else {
        let mesh = oavm::mesh::load(&mesh_path)?;
        let b = Bounds::of_points(mesh.positions.iter().copied());
        let (parts, _) = oavm::pack::build(&mesh, &BuildOptions::default(), &oavm::pack::Quiet)?;
        let scene = Scene::from_bytes(oavm::pack::encode(&parts)?, "memory")?;
        let (random, primary, hits) = sets(&scene, &b, n, seed, w, h)?;
        (b, random, primary, hits)
    };
    let shadow = rays::shadow_rays(&primary, &hits, rays::default_light(&b));
    for (name, set) in [
        ("random", &random),
        ("primary", &primary),
        ("shadow", &shadow),
    ] {
        let path = PathBuf::from(format!("{prefix}.{name}.rays"));
        rays::write_rays(&path, set)?;
        println!("{}: {} rays", path.display(), set.len());
    }
    Ok(())
}
