//! Writes a large real mesh for the out-of-core figures: `N` randomly rotated, scaled and placed
//! copies of a real mesh (by default the Stanford dragon), as one binary little-endian PLY.
//!
//!     cargo run --release --features tools --example make_copies -- OUT.ply --copies 150 [--seed 1]
//!         [--mesh ../shared/scenes/dragon/dragon_vrip.ply]
//!
//! The same arguments give the same bytes on any machine. The copies sit in the cells of an
//! `n x n x n` lattice (`n = ceil(cbrt(N))`, filled in order), each cell the size of the source
//! mesh's bounding sphere's diameter; a copy gets a uniformly random rotation (Shoemake's
//! quaternion method), a scale in [0.5, 1.0] and a random offset that keeps it inside its cell,
//! so copies do not overlap and the scene has the empty space between objects that real large
//! scenes have. 150 dragons give 130,712,100 triangles (2.5 GB of PLY).
//!
//! Output layout: a header declaring `vertex` (`float x, y, z`) and `face`
//! (`list uchar int vertex_indices`), all vertices of copy 0, 1, ... then all faces of copy 0,
//! 1, ... (indices offset by the copy's first vertex). Memory use is the source mesh plus a few
//! copies' worth of output buffers: the output is streamed.

use std::io::Write;
use std::path::PathBuf;

use clap::Parser;
use oavm::Error;
#[path = "../src/bin/cli/mod.rs"]
mod cli;

use cli::main_with;
use oavm::rays::SplitMix64;
use rayon::prelude::*;

#[derive(Parser, Debug)]
struct Args {
    /// Output binary PLY.
    out: PathBuf,
    /// Number of copies.
    #[arg(long)]
    copies: u64,
    /// Seed of the placement.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Source mesh.
    #[arg(long, default_value = "../shared/scenes/dragon/dragon_vrip.ply")]
    mesh: PathBuf,
}

/// A copy's transform: `p -> scale * R p + offset`.
struct Placement {
    rot: [[f64; 3]; 3],
    scale: f64,
    offset: [f64; 3],
}

fn placements(n: u64, seed: u64, centre: [f64; 3], radius: f64) -> Vec<Placement> {
    let side = (n as f64).cbrt().ceil().max(1.0) as u64;
    let mut rng = SplitMix64::new(seed);
    (0..n)
        .map(|i| {
            // Shoemake (1992): a uniform random unit quaternion from three uniforms.
            let (u1, u2, u3) = (rng.next_f64(), rng.next_f64(), rng.next_f64());
            let tau = std::f64::consts::TAU;
            let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
            let q = [
                a * (tau * u2).sin(),
                a * (tau * u2).cos(),
                b * (tau * u3).sin(),
                b * (tau * u3).cos(),
            ];
            let [x, y, z, w] = q;
            let rot = [
                [
                    1.0 - 2.0 * (y * y + z * z),
                    2.0 * (x * y - z * w),
                    2.0 * (x * z + y * w),
                ],
                [
                    2.0 * (x * y + z * w),
                    1.0 - 2.0 * (x * x + z * z),
                    2.0 * (y * z - x * w),
                ],
                [
                    2.0 * (x * z - y * w),
                    2.0 * (y * z + x * w),
                    1.0 - 2.0 * (x * x + y * y),
                ],
            ];
            let scale = 0.5 + 0.5 * rng.next_f64();
            // Cell of copy i; the rotated, scaled copy fits in a sphere of radius scale*radius,
            // placed anywhere that keeps that sphere in the cell (cell edge 2*radius).
            let cell = [i % side, (i / side) % side, i / (side * side)];
            let slack = 2.0 * radius * (1.0 - scale);
            let offset = std::array::from_fn(|k| {
                let lo = cell[k] as f64 * 2.0 * radius + scale * radius;
                let c = lo + slack * rng.next_f64();
                // Rotate about the source's centre: p -> s R (p - centre) + c.
                c - scale * (0..3).map(|j| rot[k][j] * centre[j]).sum::<f64>()
            });
            Placement { rot, scale, offset }
        })
        .collect()
}

fn run(args: &Args) -> Result<(), Error> {
    let mesh = oavm::mesh::load(&args.mesh)?;
    let nv = mesh.positions.len() as u64;
    let nf = mesh.triangles.len() as u64;
    let total_v = nv
        .checked_mul(args.copies)
        .filter(|&v| v <= i32::MAX as u64)
        .ok_or_else(|| Error::Invalid("too many vertices for 32-bit PLY indices".into()))?;
    let total_f = nf * args.copies;
    let b = oavm::rays::Bounds::of_points(mesh.positions.iter().copied());
    let centre = b.centre();
    let radius = 0.5 * b.diagonal();
    let places = placements(args.copies, args.seed, centre, radius);

    let tmp = args.out.with_extension("ply.partial");
    let file = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let written = write_copies(args, &mesh, &places, file, &tmp, total_v, total_f);
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written?;
    std::fs::rename(&tmp, &args.out).map_err(|e| Error::io(&args.out, e))?;
    Ok(())
}

fn write_copies(
    args: &Args,
    mesh: &oavm::mesh::Mesh,
    places: &[Placement],
    file: std::fs::File,
    tmp: &std::path::Path,
    total_v: u64,
    total_f: u64,
) -> Result<(), Error> {
    let nv = mesh.positions.len() as u64;
    let mut w = std::io::BufWriter::with_capacity(1 << 22, file);
    let io = |e| Error::io(tmp, e);
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment {} copies of {}, seed {} (tools/make_copies.rs)\n\
         element vertex {total_v}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {total_f}\nproperty list uchar int vertex_indices\nend_header\n",
        args.copies,
        args.mesh.display(),
        args.seed
    )
    .map_err(io)?;
    let started = std::time::Instant::now();
    let chunk = 8;
    for (ci, group) in places.chunks(chunk).enumerate() {
        let bufs: Vec<Vec<u8>> = group
            .par_iter()
            .map(|p| {
                let mut buf = Vec::with_capacity(mesh.positions.len() * 12);
                for v in &mesh.positions {
                    for k in 0..3 {
                        let r = (0..3).map(|j| p.rot[k][j] * v[j] as f64).sum::<f64>();
                        buf.extend_from_slice(&((p.scale * r + p.offset[k]) as f32).to_le_bytes());
                    }
                }
                buf
            })
            .collect();
        for b in bufs {
            w.write_all(&b).map_err(io)?;
        }
        eprint!(
            "\rvertices of copy {} of {}",
            (ci * chunk + group.len()),
            args.copies
        );
    }
    for c in 0..args.copies {
        let base = (c * nv) as u32;
        let mut buf = Vec::with_capacity(mesh.triangles.len() * 13);
        for t in &mesh.triangles {
            buf.push(3u8);
            for &i in t {
                buf.extend_from_slice(&(base + i).to_le_bytes());
            }
        }
        w.write_all(&buf).map_err(io)?;
        if c % 8 == 7 || c + 1 == args.copies {
            eprint!("\rfaces of copy {} of {}   ", c + 1, args.copies);
        }
    }
    w.flush().map_err(io)?;
    eprintln!(
        "\nwrote {}: {} copies, {total_v} vertices, {total_f} triangles in {:.1} s",
        args.out.display(),
        args.copies,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    main_with("make_copies", || run(&args))
}
