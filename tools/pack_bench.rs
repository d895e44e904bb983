//! Where `oavm-pack`'s time goes, phase by phase, timed in one process so that the phases after
//! parsing can be repeated: parsing, the tree (`pack::build`: preparing, subdividing, merging,
//! laying out) and encoding in memory (`pack::encode`: splitting into blocks, which builds
//! every cluster, and encoding the blocks). Each phase runs `--runs` times; the best and the
//! median run are printed. Short runs, the best counts: on a machine shared with builds and
//! benchmarks, some run goes uninterrupted.
//!
//! `cargo run --release --features tools --example pack_bench -- MESH [--runs N] [--threads T] [--list]`.
//! Numbers for us, not for the docs.

use std::path::PathBuf;
use std::time::Instant;

use oavm::pack::{BuildOptions, LeafKind, Quiet, build, encode};

fn main() {
    let mut args = std::env::args().skip(1);
    let mut mesh: Option<PathBuf> = None;
    let mut runs = 5usize;
    let mut threads = 0usize;
    let mut leaf = LeafKind::Cluster;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|s| s.parse().ok()).unwrap_or(runs),
            "--threads" => threads = args.next().and_then(|s| s.parse().ok()).unwrap_or(0),
            "--list" => leaf = LeafKind::List,
            _ => mesh = Some(PathBuf::from(a)),
        }
    }
    let Some(mesh) = mesh else {
        eprintln!("usage: pack_bench MESH [--runs N] [--threads T] [--list]");
        std::process::exit(2);
    };
    let pool = match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("pack_bench: {e}");
            std::process::exit(1);
        }
    };
    pool.install(|| run(&mesh, runs.max(1), leaf));
}

fn report(name: &str, mut t: Vec<f64>) {
    t.sort_by(f64::total_cmp);
    println!(
        "{name:>8}: best {:.3} s, median {:.3} s ({} runs)",
        t[0],
        t[t.len() / 2],
        t.len()
    );
}

fn run(mesh: &std::path::Path, runs: usize, leaf: LeafKind) {
    let mut parse = Vec::new();
    let mut m = None;
    for _ in 0..runs {
        let t = Instant::now();
        m = Some(oavm::mesh::load(mesh).unwrap_or_else(|e| {
            eprintln!("pack_bench: {e}");
            std::process::exit(1);
        }));
        parse.push(t.elapsed().as_secs_f64());
    }
    let Some(m) = m else { return };
    let opts = BuildOptions::with_leaf(leaf);
    let mut tree = Vec::new();
    let mut parts = None;
    for _ in 0..runs {
        let t = Instant::now();
        parts = Some(build(&m, &opts, &Quiet).unwrap_or_else(|e| {
            eprintln!("pack_bench: {e}");
            std::process::exit(1);
        }));
        tree.push(t.elapsed().as_secs_f64());
    }
    let Some((parts, _)) = parts else { return };
    let mut enc = Vec::new();
    let mut bytes = 0;
    for _ in 0..runs {
        let t = Instant::now();
        let b = encode(&parts).unwrap_or_else(|e| {
            eprintln!("pack_bench: {e}");
            std::process::exit(1);
        });
        enc.push(t.elapsed().as_secs_f64());
        bytes = b.as_ref().len();
    }
    report("parse", parse);
    report("tree", tree);
    report("encode", enc);
    println!(
        "   bytes: {bytes} ({:.2} per input triangle)",
        bytes as f64 / m.triangles.len().max(1) as f64
    );
}
