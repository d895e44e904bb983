//! The figures that choose the cluster size: the octree of a mesh built as the pack builds it
//! (`pack::build`), at several leaf sizes `K`, and every solid leaf clustered as the pack
//! clusters it (its triangles, clipped to its widened cell), by one reused builder on one
//! thread. Per `K` and builder variant: clusters, mean triangle references per cluster, lanes
//! per group, groups and nodes per reference, bytes per reference (80-byte nodes and 160-byte
//! groups), depth (max and mean), the SAH's expected node visits and group tests for a ray that
//! meets a cluster's root box (slot areas over the root box's area), and the build's CPU
//! seconds per million references. The module documentation of the cluster builder
//! (src/pack/cluster/mod.rs) quotes these figures.
//!
//! ```text
//! cargo run --release --features tools --example cluster_stats -- [MESH] [--k 64,128] [--variants default,window 32] [--passes N]
//! ```
//!
//! MESH defaults to the bunny (`../shared/scenes/bunny/bun_zipper.ply`), `--k` to 64, 128,
//! 256, 512 and 1024; the full dragon (`../shared/scenes/dragon/dragon_vrip.ply --k
//! 128,256,512,1024`) takes a minute. `--variants` picks builder variants: `default` and
//! `window N` (`ClusterBuilder::with_window`, N from 1 to 64; all of 1, 16, 32 and 64 by
//! default). `--passes N` times the fastest of N builds of every cluster. Times are this
//! thread's CPU seconds, so other processes on the machine inflate them less than wall time,
//! but do not leave them alone (shared caches and cores): take the least of several runs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use oavm::pack::{BuildOptions, ClusterBuilder, ClusterTri, LeafKind, Quiet, TreeParts, build};
use oavm::physical::check_cluster;
use oavm::physical::format::{NodeKind, leaf_refs};

const USAGE: &str = "usage: cluster_stats [MESH] [--k K,K,...] [--variants default,window N,...] \
                     [--passes N]";

/// A clip box: a leaf's cell widened by the cell margin, in world units.
type Clip = ([f64; 3], [f64; 3]);

fn main() {
    if let Err(e) = run() {
        eprintln!("cluster_stats: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let mut mesh_path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/bunny/bun_zipper.ply");
    let mut ks = vec![64u32, 128, 256, 512, 1024];
    let mut pick: Option<String> = None;
    let mut passes = 1usize;
    let mut args = std::env::args().skip(1);
    let mut mesh_given = false;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--k" => {
                let v = args.next().ok_or(USAGE)?;
                ks = v
                    .split(',')
                    .map(|k| k.trim().parse::<u32>().ok().filter(|&k| k > 0))
                    .collect::<Option<Vec<u32>>>()
                    .ok_or_else(|| format!("--k {v:?}: leaf sizes, positive, by commas"))?;
            }
            "--variants" => pick = Some(args.next().ok_or(USAGE)?),
            "--passes" => {
                passes = args
                    .next()
                    .and_then(|s| s.parse().ok())
                    .filter(|&n| n > 0)
                    .ok_or("--passes takes a positive number")?
            }
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            _ if !mesh_given && !a.starts_with('-') => {
                mesh_path = PathBuf::from(a);
                mesh_given = true;
            }
            _ => return Err(format!("unexpected argument {a:?}\n{USAGE}")),
        }
    }
    let variants = variants(pick.as_deref())?;
    let mesh = oavm::mesh::load(&mesh_path).map_err(|e| e.to_string())?;
    for (i, &k) in ks.iter().enumerate() {
        let opts = BuildOptions {
            max_depth: 16,
            leaf_size: k,
            ..BuildOptions::with_leaf(LeafKind::Cluster)
        };
        let (parts, _) = build(&mesh, &opts, &Quiet).map_err(|e| e.to_string())?;
        if i == 0 {
            println!(
                "{}: {} triangles; octree leaf size K, then per variant: clusters, mean refs per \
                 cluster, lanes per group, groups and nodes per ref, bytes per ref (80 B nodes + \
                 160 B groups), depth max / mean, node visits and group tests per ray meeting the \
                 root box, build CPU seconds per million refs (one thread)",
                mesh_path.display(),
                parts.tree.triangles.len()
            );
        }
        let leaves = leaves(&parts)?;
        for (name, make) in &variants {
            let s = measure(&leaves, make, passes)?;
            let r = s.refs as f64;
            let c = s.clusters as f64;
            println!(
                "K {k:5} {name:>12}: {:6} clusters, {:7.1} refs, {:.2} lanes/group, {:.4} \
                 groups/ref, {:.4} nodes/ref, {:6.2} B/ref, depth {} / {:.2}, {:.2} visits {:.2} \
                 tests, {:.3} s/M refs",
                s.clusters,
                r / c,
                r / s.groups as f64,
                s.groups as f64 / r,
                s.nodes as f64 / r,
                (80 * s.nodes + 160 * s.groups) as f64 / r,
                s.depth_max,
                s.depth_sum as f64 / c,
                s.visits / c,
                s.tests / c,
                s.seconds / r * 1e6,
            );
        }
    }
    Ok(())
}

/// A builder variant: its name and how to make the builder.
type Variant = (String, Box<dyn Fn() -> ClusterBuilder>);

/// The variants `pick` names (`default`, `window N`, by commas), or all of them.
fn variants(pick: Option<&str>) -> Result<Vec<Variant>, String> {
    let named = |name: &str| -> Result<Variant, String> {
        if name == "default" {
            return Ok((name.into(), Box::new(ClusterBuilder::new)));
        }
        let window = name
            .strip_prefix("window ")
            .and_then(|w| w.trim().parse::<usize>().ok())
            .filter(|w| (1..=64).contains(w))
            .ok_or_else(|| {
                format!("variant {name:?}: `default` or `window N`, N from 1 to 64\n{USAGE}")
            })?;
        Ok((
            name.into(),
            Box::new(move || ClusterBuilder::with_window(window)),
        ))
    };
    match pick {
        Some(p) => p.split(',').map(|n| named(n.trim())).collect(),
        None => ["default", "window 1", "window 16", "window 32", "window 64"]
            .into_iter()
            .map(named)
            .collect(),
    }
}

/// Every solid leaf of the tree: its triangles and its widened cell, as the pack gives them to
/// the cluster builder. The levels are walked from the root, each internal node's children
/// being the next 8 nodes of the next level (spec §4), codes `code << 3 | octant`.
fn leaves(parts: &TreeParts) -> Result<Vec<(Vec<ClusterTri>, Clip)>, String> {
    let geometry = parts
        .cluster_geometry()
        .ok_or("the tree is not one of clusters")?;
    let t = &parts.tree;
    let bad = |what: &str| format!("the tree built is not sound: {what}");
    let mut codes = vec![0u64];
    let mut out = Vec::new();
    for (l, lv) in t.levels.iter().enumerate() {
        if codes.len() as u64 != lv.node_count {
            return Err(bad(&format!("level {l} has {} nodes", lv.node_count)));
        }
        let mut next = Vec::new();
        for (i, &code) in codes.iter().enumerate() {
            let node = t
                .nodes
                .get(lv.node_start as usize + i)
                .ok_or_else(|| bad("a node past the nodes"))?;
            match node.kind() {
                Some(NodeKind::Internal) => next.extend((0..8).map(|o| code << 3 | o)),
                Some(NodeKind::Solid {
                    first,
                    inline_count,
                    ..
                }) => {
                    let (ids, _) = leaf_refs(&t.refs, first, inline_count)
                        .ok_or_else(|| bad("a leaf's references"))?;
                    let tris = ids
                        .iter()
                        .map(|&id| {
                            let r = t
                                .triangles
                                .get(id as usize)
                                .ok_or_else(|| bad("a reference past the triangles"))?;
                            Ok(ClusterTri {
                                v: r.v,
                                prim: r.prim,
                            })
                        })
                        .collect::<Result<Vec<_>, String>>()?;
                    out.push((tris, geometry.widened_cell(l as u32, code)));
                }
                _ => {}
            }
        }
        codes = next;
    }
    Ok(out)
}

/// Per-cluster figures, summed.
#[derive(Default)]
struct Sums {
    clusters: u64,
    refs: u64,
    nodes: u64,
    groups: u64,
    depth_max: u32,
    depth_sum: u64,
    /// Expected node visits and group tests of a ray that meets the root's box (the sum of
    /// slot areas over the root box's area, as the SAH counts them).
    visits: f64,
    tests: f64,
    seconds: f64,
}

/// Clusters every leaf with one builder made by `make`, `passes` times (the fastest pass is
/// timed), checks each cluster and sums its figures.
fn measure(
    leaves: &[(Vec<ClusterTri>, Clip)],
    make: &dyn Fn() -> ClusterBuilder,
    passes: usize,
) -> Result<Sums, String> {
    let mut s = Sums::default();
    let mut builder = make();
    let mut built = Vec::with_capacity(leaves.len());
    s.seconds = f64::INFINITY;
    for _ in 0..passes {
        built.clear();
        let wall = Instant::now();
        let t0 = cpu_seconds(wall);
        for (tris, clip) in leaves {
            built.push(
                builder
                    .build(tris, *clip, 0, 0)
                    .map_err(|e| format!("building a cluster: {e}"))?,
            );
        }
        s.seconds = s.seconds.min(cpu_seconds(wall) - t0);
    }
    for ((tris, clip), b) in leaves.iter().zip(&built) {
        let shape = check_cluster(&b.nodes, &b.groups, 0, *clip)
            .map_err(|e| format!("a cluster built is not sound: {e}"))?;
        s.clusters += 1;
        s.refs += tris.len() as u64;
        s.nodes += b.nodes.len() as u64;
        s.groups += b.groups.len() as u64;
        s.depth_max = s.depth_max.max(shape.depth);
        s.depth_sum += shape.depth as u64;
        let root = &b.nodes[0];
        let mut rb = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for i in 0..root.child_count as usize {
            let c = root.child_box(i);
            for a in 0..3 {
                rb.0[a] = rb.0[a].min(c.0[a]);
                rb.1[a] = rb.1[a].max(c.1[a]);
            }
        }
        let ra = area(rb);
        if ra > 0.0 {
            let (mut v, mut t) = (1.0, 0.0);
            for n in &b.nodes {
                for i in 0..n.child_count as usize {
                    let f = area(n.child_box(i)) / ra;
                    if i < n.inner_count as usize {
                        v += f;
                    } else {
                        t += f;
                    }
                }
            }
            s.visits += v;
            s.tests += t;
        }
    }
    Ok(s)
}

/// This thread's CPU time in seconds (`/proc/thread-self/schedstat`: nanoseconds on a CPU), so
/// that builds timed on a busy machine are not charged for other processes; wall time where
/// that file is missing.
fn cpu_seconds(wall: Instant) -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map_or_else(|| wall.elapsed().as_secs_f64(), |ns| ns as f64 * 1e-9)
}

fn area(b: ([f32; 3], [f32; 3])) -> f64 {
    let d: [f64; 3] = std::array::from_fn(|k| (b.1[k] - b.0[k]) as f64);
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}
