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
    let mesh = oavm::mesh::load(&mesh_path)?;
    let b = Bounds::of_points(mesh.positions.iter().copied());
    let random = rays::random_rays(&b, n, seed);
    let primary = Camera::framing(&b).primary_rays(w, h);
    let (parts, _) = oavm::build::build(&mesh, &BuildOptions::default(), &oavm::build::Quiet)?;
    let scene = Scene::from_bytes(oavm::build::encode(&parts)?, "memory")?;
    let mut hits = vec![Hit::MISS; primary.len()];
    scene.intersect_batch(&primary, &mut hits)?;
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
