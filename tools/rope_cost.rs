//! What ropes cost to build and store, for the KD-tree's rope walks and for OAVM (issue 14):
//!
//! ```text
//! cargo run --release -p oavm-compare --example rope_cost -- [MESH]   # default: the dragon
//! ```
//!
//! For the KD-tree: the tree's build, then each rope walk's ropes built on a fresh tree
//! (`KdTree::with_traversal`), timed apart, with the bytes and pointers they add. For OAVM: the
//! file built in memory (clusters and leaf lists), then `pack::ropes::add_ropes` over it: the
//! time finding the ropes, the whole pass (decode, find, encode), the ropes and bytes added, and
//! bytes per triangle before and after. One run each: these are costs, not speeds.

use std::time::Instant;

use oavm::pack::{BuildOptions, LeafKind};
use oavm::physical::OavmFile;
use oavm_compare::kdtree::{KdTraversal, KdTree};
use oavm_compare::{Accelerator, Triangles};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).unwrap_or_else(|| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/scenes/dragon/dragon_vrip.ply"
        )
        .into()
    });
    let mesh = oavm::mesh::load(std::path::Path::new(&path))?;
    let tris = Triangles::from_mesh(&mesh)?;
    let n = mesh.triangles.len() as f64;
    println!("{path}: {} triangles", mesh.triangles.len());
    for t in [
        KdTraversal::SplitStack,
        KdTraversal::Ropes,
        KdTraversal::Popov,
    ] {
        let start = Instant::now();
        let kd = KdTree::build(&tris);
        let tree_s = start.elapsed().as_secs_f64();
        let (bytes, pointers) = (kd.stats().bytes, kd.stats().pointers);
        let start = Instant::now();
        let kd = kd.with_traversal(t);
        let ropes_s = start.elapsed().as_secs_f64();
        let s = kd.stats();
        println!(
            "kdtree:{:<11} tree {tree_s:.3} s, ropes {ropes_s:.3} s; {bytes} -> {} bytes (+{}), \
             {pointers} -> {} pointers (+{}), {:.1} -> {:.1} bytes/triangle",
            s.name.trim_start_matches("kdtree:"),
            s.bytes,
            s.bytes - bytes,
            s.pointers,
            s.pointers - pointers,
            bytes as f64 / n,
            s.bytes as f64 / n,
        );
    }
    for leaf in [LeafKind::Cluster, LeafKind::List] {
        let opts = BuildOptions::with_leaf(leaf);
        let start = Instant::now();
        let (parts, stats) = oavm::pack::build(&mesh, &opts, &oavm::pack::Quiet)?;
        let bytes = oavm::pack::encode(&parts)?;
        let build_s = start.elapsed().as_secs_f64();
        let file = OavmFile::open(bytes)?;
        let (_, _, r) = oavm::pack::ropes::add_ropes(&file, Vec::new())?;
        println!(
            "oavm {leaf:?}: build {build_s:.3} s, ropes {:.3} s finding, {:.3} s the pass; \
             {} -> {} bytes (+{:.1} %), {} -> {} pointers (+{} ropes), {:.1} -> {:.1} \
             bytes/triangle",
            r.compute_seconds,
            r.seconds,
            r.bytes_before,
            r.bytes_after,
            100.0 * (r.bytes_after as f64 / r.bytes_before as f64 - 1.0),
            stats.pointers.total,
            stats.pointers.total + r.ropes,
            r.ropes,
            r.bytes_before as f64 / n,
            r.bytes_after as f64 / n,
        );
    }
    Ok(())
}
