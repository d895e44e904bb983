//! Tracing through the pager under memory budgets (the pager of `src/logical/pager`) on a real
//! file: the bunny packed into 4 KiB blocks, raw and zstd. Whatever the budget (unlimited, or a
//! few blocks: the smallest a file allows), the thread count (1, 4) and the order of the rays
//! (as given, Morton, by block), every answer is bit for bit the one of an unlimited
//! single-threaded run; the pager's counters add up and its resident bytes never exceed the
//! budget. Then the binaries end to end: `oavm-pack
//! --compress` and `oavm-trace --mem-budget` write the same answers as an unlimited run, and a
//! file with one damaged block fails `--verify` and any trace that reaches the block with an
//! error naming the file and the block, writing nothing, never panicking.
//!
//! (A solid leaf is one cluster of up to 512 triangles, and a block holds whole leaves, so 4 KiB
//! blocks make the bunny's 614 clusters 595 blocks, most of them one cluster each: budgets of a
//! few blocks make the pager evict and read again all the time.)

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;

use oavm::logical::{BlockReads, BlockSource, FrameOptions, Order, SceneOptions, Walk};
use oavm::pack::encode_with;
use oavm::physical::BlockOptions;
use oavm::physical::format::CODEC_RAW;
use oavm::physical::{AlignedBytes, BlockView};
use oavm::rays::{self, Bounds, Camera};
use oavm::render::RenderOptions;
use oavm::{BuildOptions, Counters, Hit, Mesh, Ray, Scene};
use serde_json::Value;
use tempfile::TempDir;

fn bunny_ply() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/bunny.ply")
}

fn bunny() -> &'static Mesh {
    static MESH: OnceLock<Mesh> = OnceLock::new();
    MESH.get_or_init(|| oavm::mesh::load(&bunny_ply()).expect("load the bunny"))
}

/// How the bunny's blocks are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Coding {
    Raw,
    Zstd,
    /// Groups in the lean encoding (format-spec §7.3).
    Lean,
}

/// The bunny packed with 4 KiB blocks: raw (`compress: None`) or zstd level 3.
fn packed(compress: Option<i32>) -> &'static AlignedBytes {
    packed_as(match compress {
        None => Coding::Raw,
        Some(_) => Coding::Zstd,
    })
}

/// The bunny packed with 4 KiB blocks and chunks of 8 groups, stored as `coding` says.
fn packed_as(coding: Coding) -> &'static AlignedBytes {
    static CELLS: [OnceLock<AlignedBytes>; 3] = [const { OnceLock::new() }; 3];
    let compress = (coding == Coding::Zstd).then_some(3);
    CELLS[coding as usize].get_or_init(|| {
        let (parts, _) = oavm::pack::build(bunny(), &BuildOptions::default(), &oavm::pack::Quiet)
            .expect("build");
        let bytes = encode_with(
            &parts,
            &BlockOptions {
                block_size: 4096,
                compress,
                chunk_groups: 8,
                lean: coding == Coding::Lean,
            },
        )
        .expect("encode");
        let scene = Scene::from_bytes(bytes.clone(), "bunny.oavm").expect("open");
        let report = scene.verify().expect("verify");
        assert!(report.is_ok(), "verify: {:?}", report.defects);
        let dir = scene.file().directory();
        assert!(dir.len() > 500, "only {} blocks", dir.len());
        let coded = dir.iter().filter(|e| e.codec != CODEC_RAW).count();
        match coding {
            Coding::Raw => assert_eq!(coded, 0),
            _ => assert!(
                coded > dir.len() / 2,
                "{coded} of {} blocks {coding:?}",
                dir.len()
            ),
        }
        bytes
    })
}

fn bounds() -> Bounds {
    Bounds::of_points(bunny().positions.iter().copied())
}

/// 10^5 random rays, then the 320x240 primary rays of the framing camera.
fn ray_set() -> &'static [Ray] {
    static RAYS: OnceLock<Vec<Ray>> = OnceLock::new();
    RAYS.get_or_init(|| {
        let b = bounds();
        let mut rays = rays::random_rays(&b, 100_000, 5);
        rays.extend(Camera::framing(&b).primary_rays(320, 240));
        rays
    })
}

/// Closest-hit answers as bits (`t` and `prim`), and any-hit answers.
#[derive(Debug, PartialEq, Eq)]
struct Answers {
    closest: Vec<(u32, u32)>,
    any: Vec<u8>,
}

struct Run {
    answers: Answers,
    closest: Counters,
    any: Counters,
    budget: u64,
    /// Threads the scene allowed.
    threads: usize,
    peak: u64,
    max_raw_len: u64,
    blocks: u64,
}

/// Traces the ray set through a fresh scene (a fresh pager) on a pool of `threads`; `checks`:
/// raw blocks are paged in with their checksums checked (off, only the pages walks touch are
/// read: the answers must not change).
fn trace(bytes: &AlignedBytes, budget: u64, threads: usize, order: Order, checks: bool) -> Run {
    trace_with(bytes, budget, threads, order, checks, false, Walk::Auto)
}

/// [`trace`], reading blocks through the map (`map_blocks`) or into the pager's memory.
fn trace_with(
    bytes: &AlignedBytes,
    budget: u64,
    threads: usize,
    order: Order,
    checks: bool,
    map_blocks: bool,
    walk: Walk,
) -> Run {
    let scene = Scene::from_bytes_with(
        bytes.clone(),
        "bunny.oavm",
        &SceneOptions {
            walk,
            mem_budget: Some(budget),
            threads,
            check_blocks: checks,
            block_reads: if map_blocks {
                BlockReads::Map
            } else {
                BlockReads::Read
            },
            chunks: false,
        },
    )
    .expect("open");
    run_scene(&scene, threads, order)
}

/// Traces the ray set through `scene` on a pool of `threads`.
fn run_scene<D: AsRef<[u8]> + BlockSource>(scene: &Scene<D>, threads: usize, order: Order) -> Run {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let rays = ray_set();
    let (hits, closest, occ, any) = pool.install(|| {
        let mut hits = vec![Hit::MISS; rays.len()];
        let closest = scene
            .intersect_batch_ordered(rays, &mut hits, order)
            .expect("closest hits");
        let mut occ = vec![0u8; rays.len()];
        let any = scene
            .occluded_batch_ordered(rays, &mut occ, order)
            .expect("any hits");
        (hits, closest, occ, any)
    });
    Run {
        answers: Answers {
            closest: hits.iter().map(|h| (h.t.to_bits(), h.prim)).collect(),
            any: occ,
        },
        closest,
        any,
        budget: scene.budget(),
        threads: scene.threads(),
        peak: scene.peak_resident_bytes(),
        max_raw_len: scene.held_block_bytes(),
        blocks: scene.file().directory().len() as u64,
    }
}

/// Checks that the counters add up; `misses`: the pass must have read blocks (the first pass
/// through a fresh pager, or any pass under a budget of a few blocks).
#[track_caller]
fn check_counters(what: &str, c: &Counters, raw: bool, rays: u64, misses: bool) {
    let p = &c.page;
    assert_eq!(c.rays, rays, "{what}");
    assert_eq!(p.requested, p.hits + p.misses, "{what}: {p:?}");
    // Rays reach blocks: each asks the pager for every block it moves into, or (streamed) is
    // parked at it, and each block served is asked for once; a streamed walk goes wide
    // through the blocks that are resident while it can, asking for them (and parks at the
    // first that is not).
    if c.blocks_served > 0 {
        assert!(c.walks_parked >= rays / 10, "{what}: {c:?}");
        assert!(c.walks_unparked > 0, "{what}: {c:?}");
        assert!(p.requested >= c.blocks_served, "{what}: {c:?}");
    } else {
        assert!(p.requested >= rays / 10, "{what}: {p:?}");
    }
    assert_eq!(p.misses > 0, p.bytes_read > 0, "{what}: {p:?}");
    if misses {
        assert!(p.misses > 0, "{what}: {p:?}");
    }
    if raw {
        assert_eq!(p.bytes_decompressed, 0, "{what}: {p:?}");
    } else if p.misses > 0 {
        assert!(p.bytes_decompressed > p.bytes_read, "{what}: {p:?}");
    }
}

/// Every budget, thread count and order against the unlimited single-threaded run in the
/// order given, for one codec.
fn budgets_do_not_change_answers(coding: Coding) {
    let bytes = packed_as(coding);
    let raw = coding == Coding::Raw;
    let rays = ray_set().len() as u64;
    let reference = trace(bytes, u64::MAX, 1, Order::None, true);
    let hits = reference
        .answers
        .closest
        .iter()
        .filter(|h| h.1 != u32::MAX)
        .count();
    assert!(hits > 30_000, "only {hits} hits: the rays miss the bunny");
    check_counters("unlimited closest", &reference.closest, raw, rays, true);
    // The any-hit pass finds every block it needs resident.
    check_counters("unlimited any", &reference.any, raw, rays, false);
    assert_eq!(reference.any.page.misses, 0);
    for (what, c) in [("closest", &reference.closest), ("any", &reference.any)] {
        // With no budget nothing is evicted: each block is read once at most.
        assert!(c.page.misses <= reference.blocks, "{what}: {:?}", c.page);
    }
    let max = reference.max_raw_len;
    let mut misses = Vec::new();
    // Unlimited; three blocks, the least any file allows (one thread: a block read, a block
    // admitted, one to evict), without block checks; nine, four threads' worth.
    for budget in [u64::MAX, 3 * max, 9 * max] {
        for threads in [1, 4] {
            // Blocks read into the pager's memory (the default), and at nine blocks on four
            // threads also through the map.
            let orders = [Order::None, Order::Morton, Order::Blocks, Order::Stream];
            for (order, map) in orders.into_iter().flat_map(|o| [(o, false), (o, true)]) {
                if (budget == u64::MAX && threads == 1 && order == Order::None)
                    || (map && (budget != 9 * max || threads != 4))
                {
                    continue;
                }
                let what = format!("budget {budget}, {threads} threads, order {order}, map {map}");
                let r = trace_with(
                    bytes,
                    budget,
                    threads,
                    order,
                    budget != 3 * max,
                    map,
                    Walk::Auto,
                );
                if r.answers != reference.answers {
                    let first = (0..rays as usize).find(|&i| {
                        r.answers.closest[i] != reference.answers.closest[i]
                            || r.answers.any[i] != reference.answers.any[i]
                    });
                    panic!("{what}: answers differ, first at ray {first:?}");
                }
                let tight = budget != u64::MAX;
                // A stream parks walks and serves blocks; a direct walk does neither, and nor
                // does a stream under a budget that holds every block (it is the direct walk).
                for c in [&r.closest, &r.any] {
                    let streamed = c.walks_parked > 0 && c.blocks_served > 0;
                    assert_eq!(streamed, order == Order::Stream && tight, "{what}: {c:?}");
                }
                check_counters(&format!("{what}, closest"), &r.closest, raw, rays, true);
                check_counters(&format!("{what}, any"), &r.any, raw, rays, tight);
                // The work of the walks does not depend on paging, but for a stream's: its
                // walks go wide while their blocks are resident, and one stopped at a block
                // that is not is walked again top-down, parked at the blocks it needs.
                let work = |c: &Counters| (c.nodes_visited, c.leaves_visited, c.triangles_tested);
                if !(order == Order::Stream && tight) {
                    assert_eq!(work(&r.closest), work(&reference.closest), "{what}");
                    assert_eq!(work(&r.any), work(&reference.any), "{what}");
                }
                // The budget is never raised; threads are lowered to what it holds (two blocks
                // a thread and one more).
                assert_eq!(r.budget, budget, "{what}");
                let allowed = ((budget / max - 1) / 2).min(threads as u64) as usize;
                assert_eq!(r.threads, allowed.max(1), "{what}");
                if budget != u64::MAX {
                    // The decoded blocks resident never exceed the budget.
                    assert!(r.peak <= budget, "{what}: peak {} over budget", r.peak);
                    // A few blocks' room for thousands of blocks: blocks are read again.
                    assert!(
                        r.closest.page.misses > r.blocks,
                        "{what}: {:?}",
                        r.closest.page
                    );
                }
                if threads == 1 && budget == 3 * max && order != Order::Stream {
                    misses.push((order, r.closest.page.misses + r.any.page.misses));
                }
            }
        }
    }
    // Single-threaded with a budget of three blocks, the Morton order reads fewer blocks again,
    // and binning by first block fewer still (it is deterministic; this checks that ordering
    // happens at all, and that the bins do what they are for).
    assert!(
        matches!(misses[..], [(Order::None, none), (Order::Morton, morton), (Order::Blocks, blocks)]
            if morton < none && blocks < morton),
        "{misses:?}"
    );
}

/// Chunked reading (format-spec §8.3, [`SceneOptions::chunks`]): the pager holds blocks' heads
/// and the walks read chunks of 8 groups. Under budgets of a twentieth and a quarter of the
/// decoded blocks, on 1 and 2 threads, in the order given and in Morton order (the walks do the
/// direct walk's work) and streamed (groups put off until their chunks are read together,
/// `logical::chunked`), every answer is the unlimited run's, chunks are read (and read again
/// under the small budget), and the counters add up.
fn chunked_reads_do_not_change_answers(compress: Coding) {
    let bytes = packed_as(compress);
    let rays = ray_set().len() as u64;
    let reference = trace(bytes, u64::MAX, 1, Order::None, true);
    let decoded = Scene::from_bytes(bytes.clone(), "bunny.oavm")
        .expect("open")
        .decoded_bytes();
    let chunk_reads = |budget: u64| -> (u64, u64) {
        let scene = open_chunked(bytes, budget, 1);
        let r = run_scene(&scene, 1, Order::Morton);
        (scene.chunks_read(), r.closest.page.chunk_misses)
    };
    for budget in [decoded / 20, decoded / 4] {
        for threads in [1, 2] {
            for order in [Order::None, Order::Morton, Order::Stream] {
                let what = format!("{compress:?}: budget {budget}, {threads} threads, {order}");
                let scene = open_chunked(bytes, budget, threads);
                assert!(scene.chunked(), "{what}: not chunked");
                let r = run_scene(&scene, threads, order);
                if r.answers != reference.answers {
                    let first = (0..rays as usize).find(|&i| {
                        r.answers.closest[i] != reference.answers.closest[i]
                            || r.answers.any[i] != reference.answers.any[i]
                    });
                    panic!("{what}: answers differ, first at ray {first:?}");
                }
                let work = |c: &Counters| (c.nodes_visited, c.leaves_visited, c.triangles_tested);
                for (c, base) in [(&r.closest, &reference.closest), (&r.any, &reference.any)] {
                    // Ray by ray, the walks read chunks as they reach them and do the direct
                    // walk's work; a stream puts groups off until their chunks are read.
                    if order != Order::Stream {
                        assert_eq!(work(c), work(base), "{what}");
                        assert_eq!(c.groups_deferred, 0, "{what}: {c:?}");
                    }
                    assert_eq!(c.rays, rays, "{what}");
                    let p = &c.page;
                    assert_eq!(
                        p.chunk_requests,
                        p.chunk_hits + p.chunk_misses,
                        "{what}: {p:?}"
                    );
                    assert_eq!(c.walks_parked, 0, "{what}: streamed: {c:?}");
                }
                if order == Order::Stream {
                    assert!(r.closest.groups_deferred > 0, "{what}: {:?}", r.closest);
                }
                assert!(
                    r.closest.page.chunk_misses > 0,
                    "{what}: {:?}",
                    r.closest.page
                );
                assert_eq!(
                    scene.chunks_read(),
                    r.closest.page.chunk_misses + r.any.page.chunk_misses,
                    "{what}"
                );
                assert!(r.peak <= budget, "{what}: peak {} over {budget}", r.peak);
            }
        }
    }
    // The file on disk, its chunks read directly (past the page cache, rounded out to the
    // device's block rather than the page: raw chunks of 8 groups do not start on pages).
    let dir = TempDir::new().unwrap();
    let path = dir.path().join("bunny.oavm");
    std::fs::write(&path, bytes.as_ref()).unwrap();
    for order in [Order::Morton, Order::Stream] {
        let scene = Scene::open_with(&path, &chunked_options(decoded / 20, 2)).expect("open");
        assert!(scene.chunked());
        let r = run_scene(&scene, 2, order);
        assert!(
            r.answers == reference.answers,
            "{compress:?}, {order}, from the file: answers differ"
        );
        assert!(r.closest.page.chunk_misses > 0, "{:?}", r.closest.page);
    }
    // The small budget reads chunks again; the larger one fewer times.
    let (small, large) = (chunk_reads(decoded / 20), chunk_reads(decoded / 4));
    assert!(small.0 > large.0 && large.0 > 0, "{small:?} {large:?}");
    // A scene of the whole file, or one not asked for chunks, is not chunked.
    assert!(!open_chunked(bytes, u64::MAX, 1).chunked());
}

/// The bunny opened under `budget` on `threads`, chunks asked for.
fn open_chunked(bytes: &AlignedBytes, budget: u64, threads: usize) -> Scene<AlignedBytes> {
    Scene::from_bytes_with(
        bytes.clone(),
        "bunny.oavm",
        &chunked_options(budget, threads),
    )
    .expect("open")
}

/// Options of a scene read chunk by chunk under `budget` on `threads`, blocks read directly.
fn chunked_options(budget: u64, threads: usize) -> SceneOptions {
    SceneOptions {
        walk: Walk::Auto,
        mem_budget: Some(budget),
        threads,
        check_blocks: true,
        block_reads: BlockReads::Read,
        chunks: true,
    }
}

#[test]
fn raw_chunks_give_the_same_answers_under_any_budget() {
    chunked_reads_do_not_change_answers(Coding::Raw);
}

#[test]
fn zstd_chunks_give_the_same_answers_under_any_budget() {
    chunked_reads_do_not_change_answers(Coding::Zstd);
}

#[test]
fn lean_chunks_give_the_same_answers_under_any_budget() {
    chunked_reads_do_not_change_answers(Coding::Lean);
}

#[test]
fn raw_blocks_give_the_same_answers_under_any_budget() {
    budgets_do_not_change_answers(Coding::Raw);
}

#[test]
fn zstd_blocks_give_the_same_answers_under_any_budget() {
    budgets_do_not_change_answers(Coding::Zstd);
}

#[test]
fn lean_blocks_give_the_same_answers_under_any_budget() {
    budgets_do_not_change_answers(Coding::Lean);
}

/// The file with every link's bounds (format-spec §8.1) widened to its whole cell, the
/// section's checksum recomputed: a tracer can then pass no block by.
/// A frame (primary rays and their shadow rays) streamed in one stream, where a shadow walk
/// begins in the block its primary walk ends in, against the same frame traced directly with
/// the batch calls (unlimited, one thread): the same hits and shadow answers, for raw and zstd
/// blocks, under budgets of a few blocks, on one and four threads; and under a budget of a
/// few blocks the one stream reads fewer blocks than the two direct batches.
#[test]
fn streamed_frames_give_the_direct_answers() {
    let b = bounds();
    let rays = Camera::framing(&b).primary_rays(320, 240);
    let light = rays::default_light(&b);
    for compress in [None, Some(3)] {
        let bytes = packed(compress);
        let open = |budget: u64, threads: usize| {
            Scene::from_bytes_with(
                bytes.clone(),
                "bunny.oavm",
                &SceneOptions {
                    walk: oavm::logical::Walk::Auto,
                    mem_budget: Some(budget),
                    threads,
                    check_blocks: true,
                    block_reads: BlockReads::Read,
                    chunks: false,
                },
            )
            .expect("open")
        };
        // The reference: the batch calls, ray by ray.
        let reference = open(u64::MAX, 1);
        let mut hits = vec![Hit::MISS; rays.len()];
        reference.intersect_batch(&rays, &mut hits).unwrap();
        let shadow = rays::shadow_rays(&rays, &hits, light);
        let mut occluded = vec![0u8; shadow.len()];
        reference.occluded_batch(&shadow, &mut occluded).unwrap();
        let lit = occluded.iter().filter(|&&o| o == 0).count();
        assert!(
            shadow.len() > 20_000 && lit > 1_000 && lit < shadow.len() - 1_000,
            "{} hits, {lit} lit: the frame must have hits, lit points and shadows",
            shadow.len()
        );
        let max = reference.held_block_bytes();
        for budget in [u64::MAX, 3 * max, 9 * max, 64 * max] {
            for threads in [1, 4] {
                let what = format!("{compress:?}, budget {budget}, {threads} threads");
                let scene = open(budget, threads);
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let frame = |order| {
                    pool.install(|| {
                        scene.trace_frame(
                            &rays,
                            &FrameOptions {
                                light: Some(light),
                                wave: 0,
                                order,
                            },
                        )
                    })
                    .unwrap()
                };
                let f = frame(Order::Stream);
                assert!(f.hits == hits, "{what}: hits differ");
                assert!(f.occluded == occluded, "{what}: shadow answers differ");
                assert_eq!(f.primary.counters.rays, rays.len() as u64, "{what}");
                assert_eq!(f.shadow.counters.rays, shadow.len() as u64, "{what}");
                // Streamed under a budget; the direct walk under one that holds the file.
                let parked = f.primary.counters.walks_parked;
                assert_eq!(
                    parked > 0,
                    budget != u64::MAX,
                    "{what}: {parked} walks parked"
                );
                assert!(f.primary.seconds > 0.0 && f.shadow.seconds > 0.0, "{what}");
                if budget == 64 * max && threads == 1 {
                    // A shadow walk starts in the block held: one stream reads fewer blocks
                    // than a batch of primary rays then one of shadow rays.
                    let direct = frame(Order::Blocks);
                    let misses = |f: &oavm::logical::Frame| {
                        f.primary.counters.page.misses + f.shadow.counters.page.misses
                    };
                    assert!(
                        misses(&f) < misses(&direct),
                        "{what}: streamed {} misses, direct {}",
                        misses(&f),
                        misses(&direct)
                    );
                }
                if budget != u64::MAX {
                    assert!(scene.peak_resident_bytes() <= budget, "{what}");
                }
            }
        }
    }
}

/// A frame traced chunk by chunk (the primary rays, then the shadow rays, each with groups put
/// off until their chunks are read) gives the answers of the batch calls without a budget.
#[test]
fn chunked_frames_give_the_direct_answers() {
    let b = bounds();
    let rays = Camera::framing(&b).primary_rays(320, 240);
    let light = rays::default_light(&b);
    for compress in [None, Some(3)] {
        let bytes = packed(compress);
        let reference = Scene::from_bytes(bytes.clone(), "bunny.oavm").expect("open");
        let mut hits = vec![Hit::MISS; rays.len()];
        reference.intersect_batch(&rays, &mut hits).unwrap();
        let shadow = rays::shadow_rays(&rays, &hits, light);
        let mut occluded = vec![0u8; shadow.len()];
        reference.occluded_batch(&shadow, &mut occluded).unwrap();
        assert!(occluded.contains(&1) && occluded.contains(&0));
        let budget = reference.decoded_bytes() / 20;
        let scene = open_chunked(bytes, budget, 2);
        assert!(scene.chunked());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let opts = FrameOptions {
            light: Some(light),
            wave: 0,
            order: scene.default_order(),
        };
        assert_eq!(opts.order, Order::Stream);
        let f = pool.install(|| scene.trace_frame(&rays, &opts)).unwrap();
        let what = format!("{compress:?}");
        assert!(f.hits == hits, "{what}: hits differ");
        assert!(f.occluded == occluded, "{what}: shadow answers differ");
        assert!(f.primary.counters.groups_deferred > 0, "{what}");
        assert_eq!(f.shadow.counters.rays, shadow.len() as u64, "{what}");
    }
}

fn without_link_culling(bytes: &AlignedBytes) -> AlignedBytes {
    use oavm::physical::format::{LinkBounds, NodeKind, NodeRecord, SectionKind, checksum};
    let scene = Scene::from_bytes(bytes.clone(), "bunny.oavm").expect("open");
    let f = scene.file();
    let nodes: &[NodeRecord] = f.records(SectionKind::Nodes);
    let s = *f.section(SectionKind::LinkBounds);
    let mut b = bytes.as_ref().to_vec();
    let mut links = 0;
    for (i, rec) in nodes.iter().enumerate() {
        if let Some(NodeKind::Link { .. }) = rec.kind() {
            let at = s.offset as usize + 8 * i;
            b[at..at + 8].copy_from_slice(bytemuck::bytes_of(&LinkBounds::FULL));
            links += 1;
        }
    }
    assert!(links > 100, "only {links} links");
    let sum = checksum(&b[s.offset as usize..(s.offset + s.length) as usize]);
    // The section's checksum is the last field of its entry in the table (§3), which the
    // header's checksum covers (§2): both are recomputed.
    let table = 256 + 48 * (SectionKind::LinkBounds as usize - 1);
    b[table + 40..table + 48].copy_from_slice(&sum.to_le_bytes());
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(&b[..248]);
    h.update(&b[256..256 + 48 * SectionKind::count_for(f.header().flags)]);
    b[248..256].copy_from_slice(&h.digest().to_le_bytes());
    AlignedBytes::from_slice(&b)
}

/// Link bounds let rays pass blocks they cannot hit without paging them in, and change no
/// answer: the same file with every link's bounds widened to its cell gives the same answers
/// bit for bit, asks the pager for more blocks, and culls no link. The widened file is still
/// structurally sound but no longer what its leaves give, and `--verify` says so. The link
/// bounds (format-spec §8.1) are what the top-down walk culls links by (the wide walk culls
/// them by the top tree's wide nodes, §8.7): it is the walk traced here.
#[test]
fn link_bounds_save_block_reads_and_change_no_answer() {
    for compress in [None, Some(3)] {
        let bytes = packed(compress);
        let wide = without_link_culling(bytes);
        let defects = Scene::from_bytes(wide.clone(), "wide.oavm")
            .expect("open")
            .verify()
            .expect("verify")
            .defects;
        assert!(
            defects.iter().any(|d| d.contains("bounds")),
            "verify misses widened link bounds: {defects:?}"
        );
        let culled = trace_with(
            bytes,
            u64::MAX,
            2,
            Order::Morton,
            true,
            false,
            Walk::TopDown,
        );
        let full = trace_with(
            &wide,
            u64::MAX,
            2,
            Order::Morton,
            true,
            false,
            Walk::TopDown,
        );
        assert_eq!(culled.answers, full.answers, "{compress:?}");
        for (a, b) in [(&culled.closest, &full.closest), (&culled.any, &full.any)] {
            assert!(a.links_culled > 0, "{compress:?}: {a:?}");
            assert_eq!(b.links_culled, 0, "{compress:?}: {b:?}");
            assert!(
                a.page.requested < b.page.requested,
                "{compress:?}: {} blocks asked for with link bounds, {} without",
                a.page.requested,
                b.page.requested
            );
        }
    }
}

#[test]
fn renders_are_the_same_in_rows_and_in_morton_tiles_under_any_budget() {
    let b = bounds();
    let bytes = packed(Some(3));
    let max = Scene::from_bytes(bytes.clone(), "bunny.oavm")
        .unwrap()
        .held_block_bytes();
    let tight = 3 * max;
    let image = |budget: u64, order: Order| {
        let scene = Scene::from_bytes_with(
            bytes.clone(),
            "bunny.oavm",
            &SceneOptions {
                walk: oavm::logical::Walk::Auto,
                mem_budget: Some(budget),
                threads: 0,
                check_blocks: true,
                block_reads: BlockReads::Read,
                chunks: false,
            },
        )
        .unwrap();
        let opts = RenderOptions {
            width: 203, // not a multiple of the tile size
            height: 150,
            camera: Camera::framing(&b),
            light: rays::default_light(&b),
            order,
        };
        let (image, stats) = oavm::render::render(&scene, &opts).expect("render");
        (image.rgb, stats.primary.rays, stats.hits, stats.shadow.rays)
    };
    let reference = image(u64::MAX, Order::None);
    assert_eq!(reference.1, 203 * 150);
    assert!(reference.2 > 1000, "{} hits", reference.2);
    // Shadow rays from the hits facing the light only (a streamed render must pick the same).
    assert!(
        reference.3 > 1000 && reference.3 < reference.2,
        "{reference:?}"
    );
    for budget in [u64::MAX, tight, 9 * max] {
        assert!(image(budget, Order::Morton) == reference, "budget {budget}");
        // Streamed: bands of rows, each pixel's shadow walk beginning where its hit is.
        assert!(
            image(budget, Order::Stream) == reference,
            "budget {budget}, stream"
        );
    }
    assert!(image(tight, Order::None) == reference);
}

#[test]
fn morton_order_is_a_permutation_and_keeps_misses_last() {
    let scene = Scene::from_bytes(packed(None).clone(), "bunny.oavm").unwrap();
    let mut rays = ray_set()[..1000].to_vec();
    // A ray that misses the model's box and an invalid one: they need no block, and go last.
    let b = bounds();
    let far = [b.max[0] + 10.0, b.max[1] + 10.0, b.max[2] + 10.0];
    rays.push(Ray::new(far, [1.0, 0.0, 0.0], 0.0, f32::INFINITY));
    rays.push(Ray::new([0.0; 3], [0.0; 3], 0.0, 1.0));
    let order = scene.morton_order(&rays);
    let mut seen = order.clone();
    seen.sort_unstable();
    assert_eq!(seen, (0..rays.len() as u32).collect::<Vec<_>>());
    let last: Vec<u32> = order[order.len() - 2..].to_vec();
    assert_eq!(last, [1000, 1001]);
    // Empty batches and length mismatches.
    let mut none: Vec<Hit> = Vec::new();
    scene
        .intersect_batch_ordered(&[], &mut none, Order::Morton)
        .unwrap();
    let mut short = vec![Hit::MISS; 3];
    assert!(
        scene
            .intersect_batch_ordered(&rays, &mut short, Order::Morton)
            .is_err()
    );
}

// ---------------------------------------------------------------------------------------------
// The binaries

fn run(cmd: &mut Command) -> Output {
    cmd.stdin(Stdio::null())
        .output()
        .expect("cannot spawn the binary")
}

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}--- stderr\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[track_caller]
fn assert_success(o: &Output) {
    assert!(o.status.success(), "expected success, got {}", describe(o));
}

/// A clean failure (an exit code other than 0 and a panic's 101, no panic message); stderr.
#[track_caller]
fn assert_failure(o: &Output) -> String {
    assert!(
        matches!(o.status.code(), Some(c) if c != 0 && c != 101),
        "expected a clean failure, got {}",
        describe(o)
    );
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!err.contains("panicked"), "{}", describe(o));
    err
}

fn pack(dir: &Path, name: &str, extra: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let o = run(Command::new(env!("CARGO_BIN_EXE_oavm-pack"))
        .arg(bunny_ply())
        .arg(&out)
        .args(["--block-size", "4K"])
        .args(extra));
    assert_success(&o);
    out
}

fn trace_cmd(file: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_oavm-trace"));
    c.arg(file);
    c
}

#[test]
fn cli_budget_and_order_do_not_change_the_output_files() {
    let dir = TempDir::new().unwrap();
    let file = pack(dir.path(), "bunny.oavm", &["--compress"]);
    let rays_path = dir.path().join("rays.bin");
    let b = bounds();
    let mut rays = rays::random_rays(&b, 20_000, 9);
    rays.extend(Camera::framing(&b).primary_rays(128, 96));
    rays::write_rays(&rays_path, &rays).unwrap();

    let out = |name: &str| dir.path().join(name);
    let reference = [("--hits", out("ref.hits")), ("--occluded", out("ref.occl"))];
    for (flag, path) in &reference {
        let o = run(trace_cmd(&file)
            .args(["--order", "none", "--threads", "1", "--rays"])
            .arg(&rays_path)
            .arg(flag)
            .arg(path));
        assert_success(&o);
    }
    // Budgets of three and five of the file's largest blocks: on two threads, the first is
    // traced on one (the budget holds two blocks a thread and one more), the second on two.
    let scene = Scene::open(&file).unwrap();
    let (max, largest) = (
        scene.held_block_bytes(),
        scene.file().header().max_block_raw_len,
    );
    drop(scene);
    let (three, five) = ((3 * max).to_string(), (5 * max).to_string());
    for budget in [three.as_str(), five.as_str()] {
        for order in ["none", "morton"] {
            for (flag, ref_path) in &reference {
                let path = out(&format!("{budget}-{order}{flag}"));
                let o = run(trace_cmd(&file)
                    .args(["--mem-budget", budget, "--order", order, "--threads", "2"])
                    .arg("--rays")
                    .arg(&rays_path)
                    .arg(flag)
                    .arg(&path)
                    .arg("--json"));
                assert_success(&o);
                assert!(
                    fs::read(&path).unwrap() == fs::read(ref_path).unwrap(),
                    "{budget} {order} {flag}: the output differs from the unlimited run's"
                );
                let v: Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
                let p = &v["page"];
                let n = |v: &Value, k: &str| {
                    v[k].as_u64()
                        .unwrap_or_else(|| panic!("`{k}` is not a count in {v:#}"))
                };
                assert_eq!(n(&v, "rays"), rays.len() as u64);
                assert_eq!(n(p, "requested"), n(p, "hits") + n(p, "misses"), "{v:#}");
                assert!(
                    n(p, "misses") > 0 && n(p, "bytes_decompressed") > 0,
                    "{v:#}"
                );
                assert_eq!(v["order"], order);
                let asked: u64 = budget.parse().unwrap();
                assert_eq!(n(&v, "mem_budget"), asked);
                assert_eq!(n(&v, "pager_budget"), asked, "never raised: {v:#}");
                assert_eq!(n(&v, "max_block_raw_len"), largest);
                assert!(n(&v, "pager_peak_resident_bytes") <= asked, "{v:#}");
                let threads = if asked == 3 * max { 1 } else { 2 };
                assert_eq!(n(&v, "threads"), threads, "{v:#}");
                if threads == 1 {
                    let err = String::from_utf8_lossy(&o.stderr);
                    assert!(err.contains("--threads 2 lowered to 1"), "{err}");
                }
                for k in ["mrays_per_s", "open_ms", "start_to_first_ray_ms"] {
                    assert!(v[k].as_f64().is_some(), "`{k}` in {v:#}");
                }
                assert!(
                    p["hit_rate"]
                        .as_f64()
                        .is_some_and(|r| (0.0..=1.0).contains(&r))
                );
                assert!(p["bytes_read_per_ray"].as_f64().is_some_and(|r| r > 0.0));
                // Linux: peak RSS and the disk reads are there.
                assert!(n(&v, "peak_rss_bytes") > 0, "{v:#}");
                n(&v, "disk_read_bytes_trace");
            }
        }
    }

    // The benchmark mode: the same figures, per set and in total.
    let o = run(trace_cmd(&file).args([
        "--random",
        "5000",
        "--shadow",
        "--mem-budget",
        five.as_str(),
        "--json",
    ]));
    assert_success(&o);
    let v: Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let sets = v["sets"].as_array().expect("sets");
    assert_eq!(sets.len(), 2, "{v:#}");
    assert_eq!(
        (sets[0]["set"].as_str(), sets[1]["set"].as_str()),
        (Some("random"), Some("shadow"))
    );
    assert_eq!(sets[0]["rays"], 5000);
    assert_eq!(sets[1]["rays"], sets[0]["hits"]);
    let total = v["rays"].as_u64().unwrap();
    assert_eq!(total, 5000 + sets[1]["rays"].as_u64().unwrap());

    // Bad sizes and orders are usage errors.
    for args in [
        &["--mem-budget", "12X"][..],
        &["--order", "hilbert"][..],
        &["--primary", "640"][..],
    ] {
        let o = run(trace_cmd(&file).args(args));
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", describe(&o));
    }
    let o = run(trace_cmd(&file).arg("--shadow"));
    assert_eq!(o.status.code(), Some(2), "{}", describe(&o));
    assert!(
        assert_failure(&o).contains("--shadow/--wave needs --random N or --primary WxH"),
        "{}",
        describe(&o)
    );
}

#[test]
fn cli_a_damaged_block_is_named_by_verify_and_by_a_trace_that_reaches_it() {
    let dir = TempDir::new().unwrap();
    let file = pack(dir.path(), "bunny.oavm", &[]);
    let good = fs::read(&file).unwrap();

    // The block to damage: the one that most rays of a small image from the framing camera
    // (the renderer's) need first, so that a render reaches it: with link bounds (§8.1) a ray
    // pages in only the blocks whose solid leaves it may meet, and with clusters the bunny's
    // 595 blocks are small, so a block picked at random (as the middle of the directory was
    // when blocks were lists) may lie behind the surface every primary ray stops at. Rays start
    // at the centres of its triangles (its groups' lanes, in a file of clusters; its triangle
    // records in a file of lists), one way, then the other, so they walk it first.
    let scene = Scene::from_bytes(AlignedBytes::from_slice(&good), &file).unwrap();
    let smallest_budget = (3 * scene.held_block_bytes()).to_string();
    let dir_entries = scene.file().directory();
    let mut first = vec![0usize; dir_entries.len()];
    for r in Camera::framing(&bounds()).primary_rays(64, 48) {
        if let Some(b) = scene.tree().first_block(&r).expect("the intact file") {
            first[b as usize] += 1;
        }
    }
    let id = (0..first.len()).max_by_key(|&b| first[b]).unwrap();
    assert!(first[id] > 0, "no ray needs a block");
    let e = dir_entries[id];
    assert_eq!(e.codec, CODEC_RAW);
    let (off, len) = (e.offset as usize, e.stored_len as usize);
    let view = BlockView::parse(&good[off..off + len], id as u32, &e).expect("the block reads");
    let lanes = view
        .groups
        .iter()
        .flat_map(|g| (0..g.count.min(8) as usize).map(|l| g.triangle(l)));
    let mut rays = Vec::new();
    for v in view.triangles.iter().map(|t| t.v).chain(lanes) {
        let c: [f32; 3] = std::array::from_fn(|k| (v[0][k] + v[1][k] + v[2][k]) / 3.0);
        for d in [[0.3, 0.5, 0.8], [-0.3, -0.5, -0.8]] {
            rays.push(Ray::new(c, d, 0.0, f32::INFINITY));
        }
    }
    assert!(!rays.is_empty());
    let rays_path = dir.path().join("rays.bin");
    rays::write_rays(&rays_path, &rays).unwrap();

    let mut bad = good.clone();
    bad[off + len / 2] ^= 0x20;
    fs::write(&file, &bad).unwrap();

    // --verify names the block.
    let o = run(trace_cmd(&file).arg("--verify"));
    let err = assert_failure(&o);
    assert!(err.contains(&format!("block {id}")), "{}", describe(&o));
    assert!(
        err.contains(&file.display().to_string()),
        "{}",
        describe(&o)
    );

    // A trace reaching it fails naming the file and the block, and writes nothing; with any
    // budget (none, or the smallest the file allows) and order, either query.
    for budget in [None, Some(smallest_budget.as_str())] {
        for (flag, name) in [("--hits", "out.hits"), ("--occluded", "out.occl")] {
            let out = dir.path().join(name);
            let mut cmd = trace_cmd(&file);
            cmd.arg("--rays").arg(&rays_path).arg(flag).arg(&out);
            if let Some(b) = budget {
                cmd.args(["--mem-budget", b]);
            }
            let o = run(&mut cmd);
            let err = assert_failure(&o);
            assert!(err.starts_with("oavm-trace: error: "), "{}", describe(&o));
            assert!(
                err.contains(&file.display().to_string()),
                "{}",
                describe(&o)
            );
            assert!(err.contains(&format!("block {id}")), "{}", describe(&o));
            assert!(!out.exists(), "{flag}: an output was written");
        }
    }
    // Rendering and the benchmark mode fail the same way when they reach it (the whole model
    // is seen, and random rays cross every block's region sooner or later).
    let png = dir.path().join("b.png");
    let o = run(trace_cmd(&file).arg("-o").arg(&png));
    let err = assert_failure(&o);
    assert!(err.contains(&format!("block {id}")), "{}", describe(&o));
    assert!(!png.exists());

    // The file restored: the same rays trace.
    fs::write(&file, &good).unwrap();
    let out = dir.path().join("out.hits");
    let o = run(trace_cmd(&file)
        .arg("--rays")
        .arg(&rays_path)
        .arg("--hits")
        .arg(&out));
    assert_success(&o);
    assert!(out.exists());
}

/// The default threads under a budget smaller than the file: eight per core, but no more than
/// leave three quarters of the budget to the cache (each thread keeps one block's room), never
/// fewer than one per core, never more than the budget holds; one per core when the file fits.
#[test]
fn default_threads_leave_the_cache_most_of_the_budget() {
    let bytes = packed(None);
    let open = |budget: u64| {
        Scene::from_bytes_with(
            bytes.clone(),
            "bunny.oavm",
            &SceneOptions {
                walk: oavm::logical::Walk::Auto,
                mem_budget: Some(budget),
                threads: 64,
                check_blocks: true,
                block_reads: BlockReads::Read,
                chunks: false,
            },
        )
        .expect("open")
    };
    let largest = open(u64::MAX).held_block_bytes();
    let decoded = open(u64::MAX).decoded_bytes();
    assert!(
        decoded > 150 * largest,
        "{decoded} bytes in blocks of up to {largest}"
    );
    // Room for 150 blocks: the quarter rule allows 37 threads, eight per core of 2 cores is 16.
    assert_eq!(open(150 * largest).default_threads(2), 16);
    // Room for 40: 10 threads, not 16.
    assert_eq!(open(40 * largest).default_threads(2), 10);
    // Room for 12: 3 by the quarter rule, but at least one per core (4).
    assert_eq!(open(12 * largest).default_threads(4), 4);
    // Room for 5: the budget holds 2 threads ((5 - 1) / 2), whatever the cores.
    assert_eq!(open(5 * largest).default_threads(4), 2);
    // The whole file fits: one per core.
    assert_eq!(open(decoded).default_threads(2), 2);
}

/// Which way blocks are read: `Read` reads them into the pager's memory under a budget smaller
/// than the file (raw and zstd), `Map` never does, `Auto` does only for a file larger than the
/// memory available (not this one); a budget that holds a raw file whole maps it in any case.
#[test]
fn block_reads_follow_the_option_and_the_file_size() {
    for compress in [None, Some(3)] {
        let bytes = packed(compress);
        let open = |budget: u64, block_reads: BlockReads| {
            Scene::from_bytes_with(
                bytes.clone(),
                "bunny.oavm",
                &SceneOptions {
                    walk: oavm::logical::Walk::Auto,
                    mem_budget: Some(budget),
                    threads: 2,
                    check_blocks: true,
                    block_reads,
                    chunks: false,
                },
            )
            .expect("open")
        };
        let small = 9 * open(u64::MAX, BlockReads::Map).held_block_bytes();
        for (budget, how, reads) in [
            (small, BlockReads::Read, true),
            (small, BlockReads::Map, false),
            (small, BlockReads::Auto, false),
            // Raw and held whole: read from the map; zstd: still decoded into slots.
            (u64::MAX, BlockReads::Read, compress.is_some()),
        ] {
            let scene = open(budget, how);
            assert_eq!(
                scene.info().reads_blocks,
                reads,
                "{compress:?}, budget {budget}, {how:?}"
            );
            // And the blocks read back either way.
            let rays = ray_set();
            let mut hits = vec![Hit::MISS; rays.len()];
            scene.intersect_batch(rays, &mut hits).unwrap();
            assert!(hits.iter().filter(|h| h.is_hit()).count() > 30_000);
        }
    }
}

/// Every hit along each ray (`Scene::list_intersections`) is the same whether the file is held
/// whole, paged in 4 KiB blocks under a twentieth of its decoded size, or read chunk by chunk
/// (raw, zstd and lean groups); blocks are read again under the small budget, and the rays do
/// meet the bunny several times.
#[test]
fn every_hit_is_the_same_paged_and_chunked() {
    let rays = &ray_set()[..20_000];
    for coding in [Coding::Raw, Coding::Zstd, Coding::Lean] {
        let bytes = packed_as(coding);
        let whole = Scene::from_bytes(bytes.clone(), "bunny.oavm").expect("open");
        let (want, _) = whole.list_intersections(rays).expect("list");
        let several = (0..rays.len()).filter(|&i| want.of(i).len() >= 2).count();
        assert!(
            several > 2000,
            "{coding:?}: only {several} rays hit twice or more"
        );
        let budget = whole.decoded_bytes() / 20;
        for chunks in [false, true] {
            let opts = SceneOptions {
                chunks,
                ..chunked_options(budget, 2)
            };
            let scene = Scene::from_bytes_with(bytes.clone(), "bunny.oavm", &opts).expect("open");
            assert_eq!(scene.chunked(), chunks);
            let (got, c) = scene.list_intersections(rays).expect("list");
            assert!(got == want, "{coding:?}, chunks {chunks}: the hits differ");
            assert!(
                c.page.misses > c.page.requested / 100,
                "{coding:?}: {:?}",
                c.page
            );
        }
    }
}

/// Closest points and occupancy are the same whether the file is held whole, paged under a
/// twentieth of its decoded size, or read chunk by chunk; blocks are read again.
#[test]
fn closest_points_are_the_same_paged_and_chunked() {
    use oavm::logical::ClosestPoint;
    let b = bounds();
    let mut rng = oavm::rays::SplitMix64::new(9);
    let pts: Vec<[f32; 3]> = (0..5000)
        .map(|_| {
            std::array::from_fn(|k| {
                (b.min[k] as f64 + (b.max[k] - b.min[k]) as f64 * (1.4 * rng.next_f64() - 0.2))
                    as f32
            })
        })
        .collect();
    for coding in [Coding::Raw, Coding::Zstd, Coding::Lean] {
        let bytes = packed_as(coding);
        let whole = Scene::from_bytes(bytes.clone(), "bunny.oavm").expect("open");
        let mut want = vec![ClosestPoint::NONE; pts.len()];
        whole
            .closest_points(&pts, f32::INFINITY, &mut want)
            .expect("closest");
        let mut want_occ = vec![0u8; pts.len()];
        whole.occupancy(&pts, &mut want_occ).expect("occupancy");
        assert!(want_occ.iter().filter(|&&o| o == 1).count() > 100);
        let budget = whole.decoded_bytes() / 20;
        for chunks in [false, true] {
            let opts = SceneOptions {
                chunks,
                ..chunked_options(budget, 2)
            };
            let scene = Scene::from_bytes_with(bytes.clone(), "bunny.oavm", &opts).expect("open");
            let mut got = vec![ClosestPoint::NONE; pts.len()];
            let c = scene
                .closest_points(&pts, f32::INFINITY, &mut got)
                .expect("closest");
            assert!(
                got == want,
                "{coding:?}, chunks {chunks}: the closest points differ"
            );
            assert!(
                c.page.misses > c.page.requested / 100,
                "{coding:?}: {:?}",
                c.page
            );
            let mut occ = vec![0u8; pts.len()];
            scene.occupancy(&pts, &mut occ).expect("occupancy");
            assert!(
                occ == want_occ,
                "{coding:?}, chunks {chunks}: occupancy differs"
            );
        }
    }
}
