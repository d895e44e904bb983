//! Instructions a ray costs in one tracer, for callgrind: OAVM (packed in memory, as the
//! benchmark builds it), obvhs or (with the `embree` feature) Embree, on the same RAYS file, traced
//! ray by ray on this thread, `--passes` times. Run it under callgrind with 1 and with 2 passes:
//! the difference of the two totals is what one pass of the rays costs, with loading, building
//! and everything else outside the trace cancelled out.
//!
//! ```text
//! tools/embree.sh cargo build --release --features tools,embree --example ray_cost
//! valgrind --tool=callgrind --callgrind-out-file=/dev/null \
//!     target/release/examples/ray_cost MESH RAYS --tracer embree [--any] --passes 1
//! ```
//!
//! `tools/ray_cost.sh` does the two runs per tracer and ray set and prints instructions a ray.
//! OAVM traces through [`oavm::logical::Tree::intersect_each`] (`occluded_each` with `--any`),
//! the batch call a render's waves use, on this thread: no rayon, no reordering. Prints the
//! answers' count of hits so that a run that answered nothing is seen.

use std::process::ExitCode;

#[path = "peers/mod.rs"]
mod peers;

use oavm::pack::LeafKind;
use oavm::{BuildOptions, Counters, Ray};
use peers::{ObvhsScene, Tracer};

const USAGE: &str = "usage: ray_cost MESH RAYS [--tracer oavm|obvhs|embree] [--any] [--passes N]";

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("ray_cost: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let (mut mesh, mut rays) = (None, None);
    let (mut tracer, mut any, mut passes) = ("oavm".to_string(), false, 1usize);
    // As the benchmark builds it.
    let opts = BuildOptions::with_leaf(LeafKind::Cluster);
    while let Some(a) = args.next() {
        let mut value = |what: &str| args.next().ok_or(format!("{what} needs a value\n{USAGE}"));
        match a.as_str() {
            "--tracer" => tracer = value("--tracer")?,
            "--any" => any = true,
            "--passes" => {
                passes = value("--passes")?
                    .parse()
                    .map_err(|e| format!("--passes: {e}"))?
            }
            _ if a.starts_with("--") => return Err(format!("unknown option {a}\n{USAGE}")),
            _ if mesh.is_none() => mesh = Some(a),
            _ if rays.is_none() => rays = Some(a),
            _ => return Err(format!("unexpected argument {a}\n{USAGE}")),
        }
    }
    let (Some(mesh), Some(rays)) = (mesh, rays) else {
        return Err(USAGE.into());
    };
    let rays = oavm::rays::read_rays(rays.as_ref(), u64::MAX).map_err(|e| e.to_string())?;
    let m = oavm::mesh::load(mesh.as_ref()).map_err(|e| format!("{mesh}: {e}"))?;
    let hits = match tracer.as_str() {
        "oavm" => {
            let (parts, _) = oavm::pack::build(&m, &opts, &oavm::pack::Quiet)
                .map_err(|e| format!("{mesh}: build: {e}"))?;
            let bytes = oavm::pack::encode(&parts).map_err(|e| format!("{mesh}: encode: {e}"))?;
            drop((parts, m));
            let scene = oavm::Scene::from_bytes(bytes, mesh.as_str())
                .map_err(|e| format!("{mesh}: open: {e}"))?;
            trace_oavm(&scene, &rays, any, passes)?
        }
        "obvhs" => trace_peer(
            &ObvhsScene::build(&m.positions, &m.triangles),
            &rays,
            any,
            passes,
        ),
        #[cfg(feature = "embree")]
        "embree" => trace_peer(
            &peers::EmbreeScene::build(&m.positions, &m.triangles),
            &rays,
            any,
            passes,
        ),
        other => return Err(format!("unknown tracer {other} (embree needs the feature)")),
    };
    println!("{tracer}: {} rays, {hits} hit, {passes} passes", rays.len());
    Ok(())
}

/// Hits of the last of `passes` passes over `rays` through OAVM's batch call.
#[inline(never)]
fn trace_oavm<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    scene: &oavm::Scene<D>,
    rays: &[Ray],
    any: bool,
    passes: usize,
) -> Result<usize, String> {
    let tree = scene.tree();
    let mut c = Counters::default();
    let (mut hits, mut occluded) = (Vec::new(), Vec::new());
    let mut n = 0;
    for _ in 0..passes {
        if any {
            tree.occluded_each(rays, &mut c, &mut occluded)
                .map_err(|e| e.to_string())?;
            n = occluded.iter().filter(|&&o| o).count();
        } else {
            tree.intersect_each(rays, &mut c, &mut hits)
                .map_err(|e| e.to_string())?;
            n = hits.iter().filter(|h| h.is_some()).count();
        }
    }
    Ok(n)
}

/// Hits of the last of `passes` passes over `rays` through a peer, ray by ray.
#[inline(never)]
fn trace_peer(t: &impl Tracer, rays: &[Ray], any: bool, passes: usize) -> usize {
    let mut n = 0;
    for _ in 0..passes {
        n = if any {
            rays.iter().filter(|r| t.occluded(r)).count()
        } else {
            rays.iter()
                .filter(|r| t.intersect(r).prim != u32::MAX)
                .count()
        };
    }
    n
}
