//! How fast the in-memory mesh readers parse (`oavm::mesh::parse_ply`, `parse_obj`): the bunny's
//! ascii PLY and its OBJ, the dragon's ascii PLY, and the dragon written again as binary little-
//! and big-endian PLY (float x y z, `list uchar int vertex_indices`). Each file is read into
//! memory once and parsed `--runs` times (default 5); the best run is printed, in MB/s of file.
//! Each binary PLY must read back as the mesh of the ascii one. They are left in the temporary
//! directory (`oavm-dragon-binary_little_endian.ply`, `...big_endian.ply`): binary PLYs for
//! `stream_bench`.
//!
//! `cargo run --release --features tools --example parse_bench -- [--scenes DIR] [--runs N]`, DIR defaulting to
//! `../shared/scenes` beside the checkout. Numbers for us, not for the docs.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use oavm::mesh::{Mesh, MeshError, parse_obj, parse_ply};

const USAGE: &str = "usage: parse_bench [--scenes DIR] [--runs N]";

fn main() {
    if let Err(e) = run() {
        eprintln!("parse_bench: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let mut scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    let mut runs = 5usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--scenes" => scenes = PathBuf::from(args.next().ok_or(USAGE)?),
            "--runs" => {
                runs = args
                    .next()
                    .and_then(|s| s.parse().ok())
                    .filter(|&n| n > 0)
                    .ok_or("--runs takes a positive number")?
            }
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            _ => return Err(format!("unknown argument {a:?}\n{USAGE}")),
        }
    }
    let read = |rel: &str| {
        let p = scenes.join(rel);
        std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))
    };
    measure(
        "bunny/bun_zipper.ply",
        &read("bunny/bun_zipper.ply")?,
        parse_ply,
        runs,
    )?;
    measure(
        "bunny/stanford-bunny.obj",
        &read("bunny/stanford-bunny.obj")?,
        parse_obj,
        runs,
    )?;
    let dragon = read("dragon/dragon_vrip.ply")?;
    measure("dragon/dragon_vrip.ply", &dragon, parse_ply, runs)?;
    let mesh = parse_ply(&dragon, "dragon").map_err(|e| e.to_string())?;
    for big_endian in [false, true] {
        let bytes = binary_ply(&mesh, big_endian);
        let format = ply_format(big_endian);
        let path = std::env::temp_dir().join(format!("oavm-dragon-{format}.ply"));
        std::fs::write(&path, &bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        if parse_ply(&bytes, "dragon").map_err(|e| e.to_string())? != mesh {
            return Err(format!(
                "{}: does not read back as the dragon",
                path.display()
            ));
        }
        measure(&path.display().to_string(), &bytes, parse_ply, runs)?;
    }
    Ok(())
}

/// Parses `bytes` `runs` times and prints the best run.
fn measure(
    name: &str,
    bytes: &[u8],
    parse: fn(&[u8], &str) -> Result<Mesh, MeshError>,
    runs: usize,
) -> Result<(), String> {
    let mut best = f64::INFINITY;
    let mut triangles = 0;
    for _ in 0..runs {
        let t = Instant::now();
        let mesh = parse(bytes, name).map_err(|e| format!("{name}: {e}"))?;
        best = best.min(t.elapsed().as_secs_f64());
        triangles = mesh.triangles.len();
    }
    println!(
        "{name:40} {:8.1} MB  {:8.1} ms  {:8.0} MB/s  {triangles} triangles",
        bytes.len() as f64 / 1e6,
        best * 1e3,
        bytes.len() as f64 / 1e6 / best
    );
    Ok(())
}

fn ply_format(big_endian: bool) -> &'static str {
    match big_endian {
        false => "binary_little_endian",
        true => "binary_big_endian",
    }
}

/// `mesh` as a binary PLY: float x y z, then `list uchar int vertex_indices`.
fn binary_ply(mesh: &Mesh, big_endian: bool) -> Vec<u8> {
    let mut out = Vec::new();
    write!(
        out,
        "ply\nformat {} 1.0\ncomment written by tools/parse_bench.rs\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        ply_format(big_endian),
        mesh.positions.len(),
        mesh.triangles.len()
    )
    .expect("writing to a Vec");
    let word = |out: &mut Vec<u8>, b: [u8; 4]| match big_endian {
        false => out.extend_from_slice(&b),
        true => out.extend(b.iter().rev()),
    };
    for p in &mesh.positions {
        for c in p {
            word(&mut out, c.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for &i in t {
            word(&mut out, (i as i32).to_le_bytes());
        }
    }
    out
}
