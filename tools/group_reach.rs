//! How many bytes of a file's blocks rays need, read whole or in chunks of their triangle groups:
//! the lower bound an out-of-core trace that keeps every wide node resident and reads only the
//! groups rays reach could get to, at each chunk size.
//!
//! ```text
//! cargo run --release --features tools,group-trace --example group_reach -- FILE.oavm \
//!     [--any] RAYS [[--any] RAYS ...] [--chunks 16k,32k,64k]
//! ```
//!
//! Traces each RAYS file (closest hit, or any hit after `--any`) with the wide walk on this
//! thread, the file mapped whole, and records every triangle group a ray tests (the
//! `group-trace` feature). Per set, and for all sets together (a frame's primary and shadow
//! rays, say), prints bytes a ray for each way of reading what was reached once:
//!
//! - whole blocks (their stored length, as format 6 reads them);
//! - chunks of C bytes of a block's groups (160 bytes each, stored one after another), chunk
//!   `160 g / C` holding group `g`, each chunk counted whole (the last of a block as long as
//!   what is left of its groups);
//! - the groups alone (160 bytes each): what no chunking can beat.
//!
//! Each block or chunk is counted once however many rays need it: a trace within a budget
//! smaller than what the rays need reads some of them again. The wide nodes, which such a trace
//! keeps resident, are not counted; their total (the top tree's and the blocks') is printed, as
//! are the blocks' groups. Every block is read and checked once first (raw or zstd).

use std::collections::HashSet;
use std::process::ExitCode;

use oavm::logical::group_trace;
use oavm::physical::format::{BlockEntry, SectionKind};
use oavm::physical::{BlockReader, BlockView};
use oavm::{Counters, Scene};

const USAGE: &str =
    "usage: group_reach FILE.oavm [--any] RAYS [[--any] RAYS ...] [--chunks 16k,32k,64k]";
/// Bytes of a triangle group (spec: eight lanes of three corners, ids and flags).
const GROUP_BYTES: u64 = 160;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("group_reach: {e}");
            ExitCode::FAILURE
        }
    }
}

/// A size such as `32k` or `65536`, in bytes.
fn size(s: &str) -> Result<u64, String> {
    let (n, unit) = match s.strip_suffix(['k', 'K']) {
        Some(n) => (n, 1024),
        None => (s, 1),
    };
    n.parse::<u64>()
        .ok()
        .filter(|&n| n > 0)
        .map(|n| n * unit)
        .ok_or(format!("bad size {s:?}"))
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let file = args.next().ok_or(USAGE)?;
    let mut sets: Vec<(String, bool)> = Vec::new();
    let mut chunks = vec![16 * 1024, 32 * 1024, 64 * 1024];
    let mut any = false;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--any" => any = true,
            "--chunks" => {
                let v = args
                    .next()
                    .ok_or(format!("--chunks needs a value\n{USAGE}"))?;
                chunks = v.split(',').map(size).collect::<Result<_, _>>()?;
            }
            _ if a.starts_with("--") => return Err(format!("unknown option {a}\n{USAGE}")),
            _ => {
                sets.push((a, any));
                any = false;
            }
        }
    }
    if sets.is_empty() {
        return Err(USAGE.into());
    }
    let scene = Scene::open(&file).map_err(|e| e.to_string())?;
    let directory = scene.file().directory();
    // Each block's groups, in bytes, and the wide nodes every block holds.
    let reader = BlockReader::new(scene.file());
    let (mut groups, mut block_nodes) = (Vec::with_capacity(directory.len()), 0u64);
    for (i, e) in directory.iter().enumerate() {
        let raw = reader
            .read(scene.file().bytes(), i as u32, e)
            .map_err(|e| format!("{file}: {e}"))?;
        let view =
            BlockView::parse(&raw, i as u32, e).map_err(|w| format!("{file}: block {i}: {w}"))?;
        groups.push(view.groups.len() as u64 * GROUP_BYTES);
        block_nodes += std::mem::size_of_val(view.cluster_nodes) as u64;
    }
    let top = scene.file().section(SectionKind::WideNodes).length;
    let tree = scene.tree();
    println!(
        "{file}: {} blocks, {} bytes of blocks of which {} of triangle groups; wide nodes {} bytes ({top} of the top tree)",
        directory.len(),
        directory.iter().map(|e| e.raw_len).sum::<u64>(),
        groups.iter().sum::<u64>(),
        top + block_nodes,
    );
    print!(
        "{:<28} {:>9} {:>8} {:>12}",
        "set", "rays", "blocks", "whole B/ray"
    );
    for c in &chunks {
        print!(" {:>11}", format!("{}k B/ray", c / 1024));
    }
    println!(" {:>11}", "groups B/ray");
    let mut all: HashSet<(u32, u32)> = HashSet::new();
    let mut all_rays = 0;
    let mut c = Counters::default();
    for (path, any) in &sets {
        let rays = oavm::rays::read_rays(path.as_ref(), u64::MAX).map_err(|e| e.to_string())?;
        group_trace::take();
        if *any {
            tree.occluded_each(&rays, &mut c, &mut Vec::new())
        } else {
            tree.intersect_each(&rays, &mut c, &mut Vec::new())
        }
        .map_err(|e| format!("{path}: {e}"))?;
        let seen: HashSet<(u32, u32)> = group_trace::take().into_iter().collect();
        report(path, rays.len(), &seen, directory, &groups, &chunks)?;
        all.extend(&seen);
        all_rays += rays.len();
    }
    if sets.len() > 1 {
        report("all sets", all_rays, &all, directory, &groups, &chunks)?;
    }
    Ok(())
}

/// Prints bytes a ray for `rays` rays that reached the groups `seen`.
fn report(
    name: &str,
    rays: usize,
    seen: &HashSet<(u32, u32)>,
    directory: &[BlockEntry],
    groups: &[u64],
    chunks: &[u64],
) -> Result<(), String> {
    let per_ray = |bytes: u64| bytes as f64 / rays.max(1) as f64;
    let blocks: HashSet<u32> = seen.iter().map(|&(b, _)| b).collect();
    let mut whole = 0;
    for &b in &blocks {
        let e = directory
            .get(b as usize)
            .ok_or(format!("block {b} is not in the directory"))?;
        whole += e.raw_len;
    }
    let name = std::path::Path::new(name)
        .file_name()
        .map_or(name.into(), |n| n.to_string_lossy().into_owned());
    print!(
        "{name:<28} {rays:>9} {:>8} {:>12.0}",
        blocks.len(),
        per_ray(whole)
    );
    for &c in chunks {
        let touched: HashSet<(u32, u64)> = seen
            .iter()
            .map(|&(b, g)| (b, u64::from(g) * GROUP_BYTES / c))
            .collect();
        let mut bytes = 0;
        for &(b, k) in &touched {
            let len = groups.get(b as usize).copied().unwrap_or(0);
            bytes += c.min(len.saturating_sub(k * c));
        }
        print!(" {:>11.0}", per_ray(bytes));
    }
    println!(" {:>11.0}", per_ray(seen.len() as u64 * GROUP_BYTES));
    Ok(())
}
