//! A fixture: a built file, its blocks decoded, where its regions are, and the answers of the
//! intact file to a set of rays; and what it takes to make one (opening from memory, the top
//! tree's links).

use std::ops::Range;
use std::sync::OnceLock;

use oavm::logical::{SceneOptions, Walk};
use oavm::pack::LeafKind;
use oavm::pack::encode_with;
use oavm::physical::AlignedBytes;
use oavm::physical::BlockOptions;
use oavm::rays::{Bounds, SplitMix64};
use oavm::{BuildOptions, Error, FormatError, Hit, Mesh, Ray, Scene};

use super::*;

pub fn open(bytes: &[u8]) -> Result<Scene<AlignedBytes>, Error> {
    Scene::from_bytes(AlignedBytes::from_slice(bytes), "corrupt.oavm")
}

/// Opens `bytes` to be traced by `walk` (the default options otherwise): [`Walk::Auto`] for
/// the files without ropes, as [`open`] does; [`Walk::Ropes`] for the files with them, so that
/// their ropes (§8.4) are followed.
pub fn open_walking(bytes: &[u8], walk: Walk) -> Result<Scene<AlignedBytes>, Error> {
    let opts = SceneOptions {
        walk,
        ..SceneOptions::default()
    };
    Scene::from_bytes_with(AlignedBytes::from_slice(bytes), "corrupt.oavm", &opts)
}

/// The format error that opening `bytes` must give.
pub fn open_error(bytes: &[u8], what: &str) -> FormatError {
    match open(bytes) {
        Ok(_) => panic!("{what}: the file opened"),
        Err(Error::Format { source, .. }) => source,
        Err(e) => panic!("{what}: not a format error: {e}"),
    }
}

pub fn dragon() -> &'static Mesh {
    static MESH: OnceLock<Mesh> = OnceLock::new();
    MESH.get_or_init(|| {
        oavm::mesh::load(&crate::common::shared_scene("dragon/dragon_vrip_res4.ply"))
            .expect("dragon")
    })
}

/// The first `n` triangles of the dragon (all its vertices stay; unused ones are ignored).
pub fn dragon_part(n: usize) -> Mesh {
    let mut m = dragon().clone();
    m.triangles.truncate(n);
    m
}

/// A link of the top tree (§8.1), found from the spec's mapping rule (§4).
#[derive(Clone, Copy, Debug)]
pub struct Link {
    /// Index of the link's record in the nodes section.
    pub node: usize,
    pub level: u32,
    pub code: u64,
    pub block: u32,
    pub root: u32,
}

/// The top tree's links: its levels walked from the root, each internal node's children being
/// the next 8 nodes of the next level (§4), codes `code << 3 | octant`.
pub fn top_links(b: &[u8]) -> Vec<Link> {
    let (lv, lv_len) = section(b, LEVELS);
    let (nodes, _) = section(b, NODES);
    let mut codes = vec![0u64];
    let mut links = Vec::new();
    for l in 0..lv_len / 32 {
        let n = read_u64(b, lv + 32 * l) as usize;
        let start = read_u64(b, lv + 32 * l + 16) as usize;
        assert_eq!(codes.len(), n, "level {l} of the top tree");
        let mut next = Vec::new();
        for (i, &code) in codes.iter().enumerate() {
            let at = nodes + 8 * (start + i);
            let (payload, meta) = (read_u32(b, at), read_u32(b, at + 4));
            match meta >> 30 {
                KIND_INTERNAL => next.extend((0..8).map(|o| code << 3 | o)),
                KIND_LINK => links.push(Link {
                    node: start + i,
                    level: l as u32,
                    code,
                    block: payload,
                    root: meta & LINK_ROOT_MASK,
                }),
                _ => {}
            }
        }
        codes = next;
    }
    links
}

/// The centre of the cell of node `code` at `level`, in world units (§1: lattice and Morton
/// codes, x lowest).
/// The centre of the link bounds (§8.1) of the link record `node` at `level`, `code`: a ray
/// from there cannot pass the link by, since it starts inside its bounds.
pub fn link_bounds_centre(b: &[u8], node: usize, level: u32, code: u64) -> [f32; 3] {
    let at = section(b, LINK_BOUNDS).0 + 8 * node;
    let (lo, hi) = (&b[at..at + 3], &b[at + 3..at + 6]);
    // 256ths of the cell, as an offset from its centre in cells.
    let frac: [f64; 3] =
        std::array::from_fn(|k| (lo[k] as f64 + hi[k] as f64 + 1.0) / 2.0 / 256.0 - 0.5);
    cell_point(b, level, code, frac)
}

/// The point `offset` cells (per axis) from the centre of the cell `level`, `code`, in world
/// units.
pub fn cell_point(b: &[u8], level: u32, code: u64, offset: [f64; 3]) -> [f32; 3] {
    let mut c = [0u64; 3];
    for i in 0..level {
        let g = code >> (3 * i);
        for (k, ck) in c.iter_mut().enumerate() {
            *ck |= ((g >> k) & 1) << i;
        }
    }
    let size = 1u64 << (21 - level);
    let root_size = f64::from_bits(read_u64(b, ROOT_SIZE_AT));
    std::array::from_fn(|k| {
        let min = f64::from_bits(read_u64(b, ROOT_MIN_AT + 8 * k));
        let cells = (c[k] * size) as f64 + size as f64 * (0.5 + offset[k]);
        (min + cells * root_size / (1u64 << 21) as f64) as f32
    })
}

/// A built file, its blocks decoded, where its regions are, and the answers of the intact file
/// to a set of rays.
pub struct Fixture {
    pub name: String,
    pub bytes: Vec<u8>,
    /// The header's `CLUSTERS` flag (§2): solid leaves are clusters, not lists.
    pub clusters: bool,
    /// The header's `ROPES` flag (§2, §8.4): the file holds ropes.
    pub ropes: bool,
    /// The header's `OCCLUDERS` flag (§2, §8.5): blocks may hold occluders.
    pub occluders: bool,
    /// The header's `PRIMS` flag (§2, §8.6): the file holds its primitive table.
    pub prims: bool,
    /// The generation the file holds (§2.1) and the offset of its header slot.
    pub generation: u64,
    pub slot: usize,
    /// How the file is traced: [`Walk::Ropes`] for a file with ropes, else [`Walk::Auto`].
    pub walk: Walk,
    pub dir: Vec<Entry>,
    /// Each block's decoded bytes (none for a free entry).
    pub decoded: Vec<Vec<u8>>,
    pub links: Vec<Link>,
    /// The blocks whose parts are regions of their own: the first, the largest and the last,
    /// the one holding the most occluders, and those the caller asks for.
    pub detailed: Vec<usize>,
    /// The block holding the most occluders (§8.5), if any does.
    pub occluder_block: Option<usize>,
    /// The block with the largest `raw_len`.
    pub largest: usize,
    /// The primitive chunks (§8.6) of the generation.
    pub chunks: Vec<Chunk>,
    pub regions: Vec<Region>,
    pub rays: Vec<Ray>,
    pub hits: Vec<Hit>,
    pub occluded: Vec<u8>,
    /// In a generation after the first, the previous generation's answers to the same rays:
    /// what the file answers when its newest header slot is damaged (§2.1).
    pub previous: Option<Answers>,
    /// The header's `max_block_raw_len`.
    pub max_raw: u64,
    /// What one of the largest blocks takes when held, in whole pages: budgets count these.
    pub held: u64,
}

/// A generation's answers to a fixture's rays.
pub struct Answers {
    pub generation: u64,
    pub hits: Vec<Hit>,
    pub occluded: Vec<u8>,
}

/// What a fixture's file must be, beyond what it holds.
pub struct Expect {
    pub leaf: LeafKind,
    pub compressed: bool,
    pub ropes: bool,
    pub occluders: bool,
    pub prims: bool,
    pub generation: u64,
    /// The file before occluders were added, whose answers the file must give (§8.5), and
    /// what `add_occluders` reported.
    pub without_occluders: Option<Vec<u8>>,
    pub occluder_report: Option<oavm::pack::occluders::OccluderReport>,
    /// The file as its previous generation was (a generation after the first).
    pub previous: Option<Vec<u8>>,
    /// Blocks to detail besides the first, the largest and the last.
    pub detail: Vec<usize>,
    /// Primitives an update removed: their records are absent (§8.6); every other record is
    /// the mesh's triangle.
    pub removed: Vec<u32>,
}

impl Expect {
    /// A file as packed (generation 1) with leaves of `leaf`, raw, and nothing optional.
    pub fn new(leaf: LeafKind) -> Expect {
        Expect {
            leaf,
            compressed: false,
            ropes: false,
            occluders: false,
            prims: false,
            generation: 1,
            without_occluders: None,
            occluder_report: None,
            previous: None,
            detail: Vec::new(),
            removed: Vec::new(),
        }
    }
}

impl Fixture {
    pub fn new(name: &str, mesh: &Mesh, opts: BuildOptions, blocks: BlockOptions) -> Fixture {
        Fixture::build(name, mesh, opts, blocks, false, false)
    }

    /// Built as [`Fixture::new`]; with `ropes`, given ropes afterwards as `oavm-pack --ropes`
    /// gives them (§8.4: `add_ropes` on the finished file) and traced by the walk that follows
    /// them; with `occluders`, given occluders afterwards as `oavm-pack --occluders` gives them
    /// (§8.5: `add_occluders` with the default parameters on the finished file), traced by the
    /// default walk (in a file of clusters the top-down walk, whose any-hit queries test them).
    pub fn build(
        name: &str,
        mesh: &Mesh,
        opts: BuildOptions,
        blocks: BlockOptions,
        ropes: bool,
        occluders: bool,
    ) -> Fixture {
        let (parts, _) = oavm::pack::build(mesh, &opts, &oavm::pack::Quiet).expect("build");
        let mut bytes = encode_with(&parts, &blocks)
            .expect("encode")
            .as_ref()
            .to_vec();
        // The file before occluders, whose answers the file with them must give.
        let mut without_occluders = None;
        let mut occluder_report = None;
        if occluders {
            let plain = open(&bytes).expect("the file without occluders opens");
            let (with, size, report) = oavm::pack::occluders::add_occluders(
                plain.file(),
                &oavm::pack::occluders::ShadowParams::default(),
                Vec::new(),
            )
            .expect("add occluders");
            assert_eq!(
                size,
                with.len() as u64,
                "{name}: the size add_occluders reports"
            );
            assert!(
                report.occluders > 0 && report.occluder_nodes > 0,
                "{name}: add_occluders chose none: {report:?}"
            );
            without_occluders = Some(std::mem::replace(&mut bytes, with));
            occluder_report = Some(report);
        }
        if ropes {
            let plain = open(&bytes).expect("the file without ropes opens");
            let (roped, size, _) =
                oavm::pack::ropes::add_ropes(plain.file(), Vec::new()).expect("add ropes");
            assert_eq!(
                size,
                roped.len() as u64,
                "{name}: the size add_ropes reports"
            );
            bytes = roped;
        }
        let expect = Expect {
            leaf: opts.leaf,
            compressed: blocks.compress.is_some(),
            ropes,
            occluders,
            without_occluders,
            occluder_report,
            ..Expect::new(opts.leaf)
        };
        Fixture::examine(name, mesh, bytes, expect)
    }

    /// The fixture of the file `bytes`, whose triangles are `mesh`'s: checked against `expect`
    /// and against the spec's layout, its blocks decoded, its regions found, its answers to a
    /// set of rays taken.
    pub fn examine(name: &str, mesh: &Mesh, bytes: Vec<u8>, expect: Expect) -> Fixture {
        let Expect {
            ropes, occluders, ..
        } = expect;
        let walk = if ropes { Walk::Ropes } else { Walk::Auto };
        let scene = open_walking(&bytes, walk).expect("the intact file opens");
        let report = scene.verify().expect("verify");
        assert!(report.is_ok(), "{name}: intact file: {:?}", report.defects);
        // §2.1: the generation, in the slot `(g - 1) mod 2`, which is the slot a reader takes.
        let slot = slot_of(&bytes);
        let generation = read_u64(&bytes, slot + GENERATION_AT);
        assert_eq!(generation, expect.generation, "{name}: the generation");
        assert_eq!(
            slot,
            HEADER_SLOTS[((generation - 1) % 2) as usize],
            "{name}: generation {generation}'s slot"
        );
        assert_eq!(
            scene.file().header().generation,
            generation,
            "{name}: the generation read"
        );
        // A file as packed leaves slot 1 all zero (§2.1); an updated one holds the previous
        // generation in the other slot.
        let other = HEADER_SLOTS[1] - slot;
        match generation {
            1 => assert!(
                bytes[other..other + SLOT_LEN].iter().all(|&x| x == 0),
                "{name}: slot 1 of a file as packed"
            ),
            g => assert_eq!(
                slot_generation(&bytes, other),
                Some(g - 1),
                "{name}: the other slot"
            ),
        }
        let flags = flags_at(&bytes, slot);
        assert_eq!(flags & FLAG_ROPES != 0, ropes, "{name}: the ROPES flag");
        assert_eq!(
            flags & FLAG_OCCLUDERS != 0,
            occluders,
            "{name}: the OCCLUDERS flag"
        );
        let prims = flags & FLAG_PRIMS != 0;
        assert_eq!(prims, expect.prims, "{name}: the PRIMS flag");
        assert_eq!(
            read_u32(&bytes, slot + SECTION_COUNT_AT) as usize,
            section_count(&bytes),
            "{name}: section_count (§2)"
        );
        // The generation ends the file: no bytes past its `file_size` in these fixtures.
        assert_eq!(
            read_u64(&bytes, slot + FILE_SIZE_AT),
            bytes.len() as u64,
            "{name}: file_size"
        );
        let dir = directory(&bytes);
        let live: Vec<usize> = (0..dir.len()).filter(|&b| !dir[b].free).collect();
        assert!(live.len() >= 8, "{name}: {} blocks, want many", live.len());
        if generation == 1 {
            assert_eq!(
                live.len(),
                dir.len(),
                "{name}: a free entry as packed (§8.2)"
            );
        }
        let decoded: Vec<Vec<u8>> = dir
            .iter()
            .map(|e| match (e.free, e.codec) {
                (true, _) => Vec::new(),
                (false, CODEC_RAW) => bytes[e.stored()].to_vec(),
                _ => zstd::bulk::decompress(&bytes[e.stored()], e.raw_len).expect("decode"),
            })
            .collect();
        if expect.compressed {
            assert!(
                live.iter().all(|&b| dir[b].codec == CODEC_ZSTD),
                "{name}: every block compressed"
            );
        }
        let clusters = flags & FLAG_CLUSTERS != 0;
        assert_eq!(
            clusters,
            expect.leaf == LeafKind::Cluster,
            "{name}: the CLUSTERS flag"
        );
        // §8.3: a block of a file of clusters has cluster nodes and groups and no references
        // or triangle records; a block of a file of lists the other way round.
        for &b in &live {
            let raw = &decoded[b];
            let parts = block_parts(raw);
            let (has, lacks) = match clusters {
                true => (
                    [PART_CLUSTER_NODES, PART_GROUPS],
                    [PART_REFS, PART_TRIANGLES],
                ),
                false => (
                    [PART_REFS, PART_TRIANGLES],
                    [PART_CLUSTER_NODES, PART_GROUPS],
                ),
            };
            assert!(
                has.iter().all(|&i| !parts[i].is_empty())
                    && lacks.iter().all(|&i| parts[i].is_empty()),
                "{name}: block {b}'s parts {parts:?}"
            );
            // §8.4: a block of a file with ropes has one rope record per node record, and
            // one of a file without none.
            let nodes = parts[PART_NODES].len() / 8;
            assert_eq!(
                parts[PART_ROPES].len(),
                if ropes { nodes * ROPE_LEN } else { 0 },
                "{name}: block {b}'s ropes {parts:?}"
            );
            // §8.5: occluder entries and occluders together, or neither (none without the
            // flag); every occluder is one of the block's triangles, corners and id.
            let (entries, occ) = (
                parts[PART_OCCLUDER_NODES].len() / OCCLUDER_NODE_LEN,
                parts[PART_OCCLUDERS].len() / TRI_LEN,
            );
            assert!(
                (entries == 0) == (occ == 0) && (occluders || occ == 0) && entries <= nodes,
                "{name}: block {b}'s occluders {parts:?}"
            );
            if occ > 0 {
                let tris = block_triangles(raw);
                for o in parts[PART_OCCLUDERS].clone().step_by(TRI_LEN) {
                    assert!(
                        tris.iter().any(|t| t[..] == raw[o..o + TRI_LEN]),
                        "{name}: block {b}: the occluder at byte {o} is not a triangle of the block"
                    );
                }
            }
        }
        // §8.6: one chunk per 4096 primitives, the last one shorter, each record the
        // primitive's corners as the mesh gives them; every triangle a block stores is its
        // primitive's record, bit for bit.
        let chunks = prim_chunks(&bytes);
        if prims {
            let n = mesh.triangles.len();
            assert_eq!(
                read_u64(&bytes, slot + INPUT_TRIANGLES_AT) as usize,
                n,
                "{name}: input_triangles"
            );
            assert_eq!(chunks.len(), n.div_ceil(PRIMS_PER_CHUNK), "{name}: chunks");
            for (c, ch) in chunks.iter().enumerate() {
                assert_eq!(
                    ch.count,
                    (n - c * PRIMS_PER_CHUNK).min(PRIMS_PER_CHUNK),
                    "{name}: chunk {c}"
                );
            }
            let record = |p: usize| {
                let at = prim_record_at(&bytes, p);
                bytes[at..at + PRIM_RECORD_LEN].to_vec()
            };
            for (p, t) in mesh.triangles.iter().enumerate() {
                let want: Vec<u8> = t
                    .iter()
                    .flat_map(|&v| mesh.positions[v as usize])
                    .flat_map(f32::to_le_bytes)
                    .collect();
                let absent = record(p).chunks(4).all(|w| w == PRIM_ABSENT.to_le_bytes());
                match expect.removed.binary_search(&(p as u32)).is_ok() {
                    true => assert!(absent, "{name}: removed primitive {p}'s record"),
                    false => assert!(record(p) == want, "{name}: primitive {p}'s record"),
                }
            }
            for &b in &live {
                for t in block_triangles(&decoded[b]) {
                    let prim = read_u32(&t, 36) as usize;
                    assert!(
                        record(prim) == t[..36],
                        "{name}: block {b} stores primitive {prim} other than its record"
                    );
                }
            }
        } else {
            assert!(chunks.is_empty(), "{name}: chunks without the flag");
        }
        let occluder_counts: Vec<(usize, usize)> = decoded
            .iter()
            .map(|raw| match raw.is_empty() {
                true => (0, 0),
                false => {
                    let parts = block_parts(raw);
                    (
                        parts[PART_OCCLUDER_NODES].len() / OCCLUDER_NODE_LEN,
                        parts[PART_OCCLUDERS].len() / TRI_LEN,
                    )
                }
            })
            .collect();
        if let Some(report) = &expect.occluder_report {
            // The blocks hold what add_occluders reports: some blocks hold occluders.
            let entries: usize = occluder_counts.iter().map(|c| c.0).sum();
            let occ: usize = occluder_counts.iter().map(|c| c.1).sum();
            assert_eq!(
                (entries as u64, occ as u64),
                (report.occluder_nodes, report.occluders),
                "{name}: the blocks' occluder counts"
            );
            let holding = occluder_counts.iter().filter(|c| c.1 > 0).count();
            assert!(holding > 0, "{name}: no block holds occluders");
            eprintln!(
                "{name}: {occ} occluders at {entries} nodes in {holding} of {} blocks",
                dir.len()
            );
        }
        let links = top_links(&bytes);
        let largest = *live
            .iter()
            .max_by_key(|&&b| dir[b].raw_len)
            .expect("blocks");
        let mut detailed = vec![live[0], largest, live[live.len() - 1]];
        // With occluders, also the block holding the most (§8.5), so that its two occluder
        // parts are regions.
        let occluder_block = (0..dir.len())
            .filter(|&b| occluder_counts[b].1 > 0)
            .max_by_key(|&b| (occluder_counts[b].1, occluder_counts[b].0));
        detailed.extend(occluder_block);
        detailed.extend(expect.detail.iter().filter(|&&b| !dir[b].free));
        detailed.sort_unstable();
        detailed.dedup();

        let used = mesh.triangles.iter().flatten();
        let bounds = Bounds::of_points(used.map(|&v| mesh.positions[v as usize]));
        let mut rays = ray_set(mesh, &bounds);
        // One ray from inside the link bounds of each block's first root: its walk needs that
        // block first, so a block the pager refuses fails the batch.
        let mut rng = SplitMix64::new(0xb10c);
        for &b in &live {
            let link = links
                .iter()
                .find(|l| l.block == b as u32 && l.root == 0)
                .expect("every block's first root is linked");
            rays.push(Ray::new(
                link_bounds_centre(&bytes, link.node, link.level, link.code),
                random_dir(&mut rng),
                0.0,
                f32::INFINITY,
            ));
        }
        // No link to a free entry (§8.2).
        for (b, e) in dir.iter().enumerate() {
            assert!(
                !e.free || links.iter().all(|l| l.block != b as u32),
                "{name}: a link to free entry {b}"
            );
        }
        // With occluders, one ray through each occluder of the block holding the most, from
        // just before its centroid: its any-hit walk enters the nodes around it, so that the
        // occluders rewritten in that block are tested by the tracer, not only by verify.
        let aimed = rays.len();
        if let Some(ob) = occluder_block {
            let raw = &decoded[ob];
            let back = bounds.diagonal() as f32 * 1e-3;
            for o in block_parts(raw)[PART_OCCLUDERS].clone().step_by(TRI_LEN) {
                let v = |c: usize, k: usize| f32::from_bits(read_u32(raw, o + 12 * c + 4 * k));
                let d = random_dir(&mut rng);
                let origin =
                    std::array::from_fn(|k| (v(0, k) + v(1, k) + v(2, k)) / 3.0 - d[k] * back);
                rays.push(Ray::new(origin, d, 0.0, f32::INFINITY));
            }
        }
        let mut hits = vec![Hit::MISS; rays.len()];
        scene.intersect_batch(&rays, &mut hits).expect("trace");
        let mut occluded = vec![0u8; rays.len()];
        let counters = scene.occluded_batch(&rays, &mut occluded).expect("trace");
        let same = |a: &Hit, b: &Hit| a.t.to_bits() == b.t.to_bits() && a.prim == b.prim;
        if let Some(plain) = &expect.without_occluders {
            // Occluders change no answer (§8.5): the file before them gives the same, bit for
            // bit; and the walk of a file of clusters tests them, so that damaged occluders are
            // traced as well as verified.
            let plain = open_walking(plain, walk).expect("opens");
            let mut h = vec![Hit::MISS; rays.len()];
            plain.intersect_batch(&rays, &mut h).expect("trace");
            let mut o = vec![0u8; rays.len()];
            plain.occluded_batch(&rays, &mut o).expect("trace");
            let differ = (0..rays.len()).find(|&i| !same(&h[i], &hits[i]) || o[i] != occluded[i]);
            assert!(
                differ.is_none(),
                "{name}: ray {differ:?}: the answers with and without occluders differ"
            );
            assert!(
                counters.promoted_tested > 0,
                "{name}: the any-hit walk tested no occluder: {counters:?}"
            );
            let mut o = vec![0u8; rays.len() - aimed];
            let c = scene.occluded_batch(&rays[aimed..], &mut o).expect("trace");
            assert!(
                c.promoted_tested > 0,
                "{name}: the rays through block {occluder_block:?}'s occluders tested none: {c:?}"
            );
            eprintln!(
                "{name}: the any-hit walk tested {} occluders, {} on the {} rays through block \
                 {occluder_block:?}'s",
                counters.promoted_tested,
                c.promoted_tested,
                rays.len() - aimed
            );
        }
        if ropes {
            // The walk that follows ropes gives the answers of the same walk finding each next
            // leaf from Morton codes (§8.4, §10), bit for bit.
            let neighbours = open_walking(&bytes, Walk::Neighbours).expect("opens");
            let mut h = vec![Hit::MISS; rays.len()];
            neighbours.intersect_batch(&rays, &mut h).expect("trace");
            let mut o = vec![0u8; rays.len()];
            neighbours.occluded_batch(&rays, &mut o).expect("trace");
            let differ = (0..rays.len()).find(|&i| !same(&h[i], &hits[i]) || o[i] != occluded[i]);
            assert!(
                differ.is_none(),
                "{name}: ray {differ:?}: the walks by ropes and by neighbours differ"
            );
        }
        let n_hit = hits.iter().filter(|h| h.is_hit()).count();
        assert!(
            n_hit > rays.len() / 4 && n_hit < rays.len(),
            "{name}: the rays should both hit and miss ({n_hit} of {} hit)",
            rays.len()
        );
        // The previous generation's answers, from the file as it was before the update: the
        // answers a reader of it kept getting, and those of this file if its newest header
        // slot is damaged (§2.1). The update changed some.
        let previous = expect.previous.as_ref().map(|before| {
            let old = open_walking(before, walk).expect("the previous generation opens");
            let mut h = vec![Hit::MISS; rays.len()];
            old.intersect_batch(&rays, &mut h).expect("trace");
            let mut o = vec![0u8; rays.len()];
            old.occluded_batch(&rays, &mut o).expect("trace");
            let changed = (0..rays.len())
                .filter(|&i| !same(&h[i], &hits[i]) || o[i] != occluded[i])
                .count();
            assert!(changed > 0, "{name}: the update changed no answer");
            eprintln!(
                "{name}: the update changed the answers to {changed} of {} rays",
                rays.len()
            );
            Answers {
                generation: old.file().header().generation,
                hits: h,
                occluded: o,
            }
        });
        let max_raw = scene.file().header().max_block_raw_len;
        let held = scene.held_block_bytes();
        let mut fix = Fixture {
            name: format!(
                "{name} ({} levels, {} top levels, {} blocks, {} bytes)",
                scene.file().header().level_count,
                scene.file().levels().len(),
                dir.len(),
                bytes.len()
            ),
            bytes,
            clusters,
            ropes,
            occluders,
            prims,
            generation,
            slot,
            walk,
            dir,
            decoded,
            links,
            detailed,
            occluder_block,
            largest,
            chunks,
            regions: Vec::new(),
            rays,
            hits,
            occluded,
            previous,
            max_raw,
            held,
        };
        fix.regions = fix.make_regions();
        fix
    }

    /// The generation's header slot: the header, the section table, the zero bytes after it;
    /// the other header slot, whole. The data region: for each detailed block the padding (a
    /// file as packed) or the bytes no longer referred to (a later generation) before it, its
    /// stored bytes if compressed, and its header, parts and the padding between them; the
    /// stored bytes of 8 other blocks; every primitive chunk and what lies before it; what lies
    /// after the last block or chunk. Then the directory and the other sections, each with the
    /// padding before it (§2, §2.1, §3, §8).
    pub fn make_regions(&self) -> Vec<Region> {
        let b = &self.bytes;
        let file = |name: String, kind, range| Region {
            name,
            kind,
            space: Space::File,
            range,
            defect: None,
        };
        let slot = self.slot;
        let table = table_range(slot, flags_at(b, slot));
        let slot_index = slot / SLOT_LEN;
        let other = HEADER_SLOTS[1] - slot;
        let mut out = vec![
            file("header".into(), RegionKind::Header, slot..slot + HEADER_LEN),
            file("section table".into(), RegionKind::Table, table.clone()),
            Region {
                defect: Some(format!(
                    "header slot {slot_index}: bytes {}..{} after the section table are not zero",
                    table.end,
                    slot + SLOT_LEN
                )),
                ..file(
                    format!("header slot {slot_index} after the section table"),
                    RegionKind::SlotPadding,
                    table.end..slot + SLOT_LEN,
                )
            },
            file(
                format!("header slot {} (not this generation's)", other / SLOT_LEN),
                RegionKind::OtherSlot,
                other..other + SLOT_LEN,
            ),
        ];
        out.sort_by_key(|r| r.range.start);
        // The data region's items, in file order: blocks (a free entry has none) and chunks.
        #[derive(Clone, Copy)]
        enum Item {
            Block(usize),
            Chunk(usize),
        }
        let mut items: Vec<(Range<usize>, Item)> = (0..self.dir.len())
            .filter(|&blk| !self.dir[blk].free)
            .map(|blk| (self.dir[blk].stored(), Item::Block(blk)))
            .chain(
                self.chunks
                    .iter()
                    .enumerate()
                    .map(|(c, ch)| (ch.records(), Item::Chunk(c))),
            )
            .collect();
        items.sort_by_key(|i| i.0.start);
        let what = |item: Item| match item {
            Item::Block(blk) => format!("block {blk}"),
            Item::Chunk(c) => format!("primitive chunk {c}"),
        };
        let live: Vec<usize> = (0..self.dir.len()).filter(|&i| !self.dir[i].free).collect();
        let mut others: Vec<usize> = live
            .iter()
            .copied()
            .filter(|i| !self.detailed.contains(i))
            .collect();
        let step = others.len().div_ceil(8).max(1);
        others = others.into_iter().step_by(step).collect();
        let (region_start, region_len) = section(b, BLOCKS);
        assert_eq!(region_start, BLOCKS_START, "the data region's start (§3)");
        let region_end = region_start + region_len;
        let mut prev_end = BLOCKS_START;
        for (range, item) in items.iter().cloned() {
            let shown = match item {
                Item::Block(blk) => self.detailed.contains(&blk) || others.contains(&blk),
                Item::Chunk(_) => true,
            };
            let detailed = matches!(item, Item::Block(blk) if self.detailed.contains(&blk));
            assert!(
                range.start >= prev_end,
                "{}: {} overlaps",
                self.name,
                what(item)
            );
            // What lies before the item: zero padding in a file as packed, every gap checked
            // by verify (§8.2); in a later generation, bytes of older generations, not checked
            // (§2.1), all of them regions.
            if range.start > prev_end && self.generation == 1 && (detailed || shown) {
                out.push(Region {
                    defect: Some(format!("padding before {} is not zero", what(item))),
                    ..file(
                        format!("padding before {}", what(item)),
                        RegionKind::Gap,
                        prev_end..range.start,
                    )
                });
            }
            if range.start > prev_end && self.generation > 1 {
                out.push(file(
                    format!("older generations' bytes before {}", what(item)),
                    RegionKind::Dead,
                    prev_end..range.start,
                ));
            }
            prev_end = range.end;
            let blk = match item {
                Item::Chunk(c) => {
                    out.push(file(
                        format!("primitive chunk {c} records"),
                        RegionKind::Chunk(c),
                        range,
                    ));
                    continue;
                }
                Item::Block(blk) => blk,
            };
            if !shown {
                continue;
            }
            let e = self.dir[blk];
            if !detailed || e.codec != CODEC_RAW {
                let what = if e.codec == CODEC_RAW {
                    "raw bytes"
                } else {
                    "zstd frame"
                };
                out.push(file(
                    format!("block {blk} {what}"),
                    RegionKind::Stored(blk),
                    e.stored(),
                ));
            }
            if !detailed {
                continue;
            }
            let raw = &self.decoded[blk];
            let in_block = |name: String, kind, range| Region {
                name,
                kind,
                space: Space::Block(blk),
                range,
                defect: None,
            };
            out.push(in_block(
                format!("block {blk} header"),
                RegionKind::BlockHeader(blk),
                0..BLOCK_HEADER_LEN,
            ));
            let mut end = BLOCK_HEADER_LEN;
            // An empty part (the refs and triangles of a file of clusters, the cluster nodes
            // and groups of a file of lists) has no bytes but its place, at the next multiple
            // of 64: the padding before it is there all the same (so a block of lists ends
            // with the padding before its empty cluster nodes). Absent ropes take no place.
            for (i, r) in block_parts(raw).into_iter().enumerate() {
                let part = BLOCK_PARTS[i].0;
                if r.start > end {
                    out.push(in_block(
                        format!("block {blk} padding before its {part}"),
                        RegionKind::BlockPadding(blk),
                        end..r.start,
                    ));
                }
                end = r.end;
                if !r.is_empty() {
                    out.push(in_block(
                        format!("block {blk} {part}"),
                        RegionKind::BlockPart(blk, i),
                        r,
                    ));
                }
            }
            assert_eq!(end, raw.len(), "block {blk} ends with its last part (§8.3)");
        }
        // After the last item, to the directory: less than 64 bytes of zero padding in a file
        // as packed (§3), older generations' bytes in a later one.
        assert!(
            region_end >= prev_end,
            "{}: the data region's end",
            self.name
        );
        if self.generation == 1 {
            assert!(
                region_end - prev_end < ALIGN,
                "{}: the data region ends at the next multiple of 64 after its last item (§3)",
                self.name
            );
        }
        if region_end > prev_end {
            let last = items.last().expect("items").1;
            out.push(match self.generation {
                1 => Region {
                    defect: Some(format!(
                        "padding after {} to the end of the data region is not zero",
                        what(last)
                    )),
                    ..file(
                        format!("padding after {}", what(last)),
                        RegionKind::Gap,
                        prev_end..region_end,
                    )
                },
                _ => file(
                    format!("older generations' bytes after {}", what(last)),
                    RegionKind::Dead,
                    prev_end..region_end,
                ),
            });
        }
        let mut end = region_end;
        let kinds = section_kinds(flags_at(b, slot));
        for (i, &kind) in kinds.iter().enumerate().skip(DIRECTORY) {
            let (offset, length) = section(b, i);
            let (name, ..) = SECTIONS[kind as usize - 2];
            if i == DIRECTORY {
                assert_eq!(
                    offset, region_end,
                    "the directory starts where the data region ends (§3)"
                );
            }
            if offset > end {
                out.push(file(
                    format!("padding before the {name} section"),
                    RegionKind::Padding,
                    end..offset,
                ));
            }
            out.push(file(
                format!("{name} section"),
                RegionKind::Section(kind as usize - 2),
                offset..offset + length,
            ));
            end = offset + length;
        }
        assert_eq!(end, b.len(), "the last section ends the file (§3)");
        out
    }

    /// The part of a block that holds the triangles themselves: its triangle records (lists)
    /// or its groups (clusters).
    pub fn mesh_part(&self) -> &'static str {
        match self.clusters {
            true => BLOCK_PARTS[PART_GROUPS].0,
            false => BLOCK_PARTS[PART_TRIANGLES].0,
        }
    }

    pub fn region(&self, name: &str) -> &Region {
        self.regions
            .iter()
            .find(|r| r.name == name)
            .unwrap_or_else(|| panic!("{}: no region {name}", self.name))
    }

    /// The bytes a region's offsets refer to.
    pub fn space(&self, space: Space) -> &[u8] {
        match space {
            Space::File => &self.bytes,
            Space::Block(b) => &self.decoded[b],
        }
    }

    /// The file offset of byte `at` of `space`, if the bytes are stored as they are decoded.
    pub fn file_at(&self, space: Space, at: usize) -> Option<usize> {
        match space {
            Space::File => Some(at),
            Space::Block(b) => (self.dir[b].codec == CODEC_RAW).then(|| self.dir[b].offset + at),
        }
    }

    /// The file with `new` written at `at` of `space`, checksums recomputed (those of the
    /// fixture's generation): a compressed block is decoded, changed, compressed again and the
    /// file laid out again (§8; a file as packed only).
    pub fn rewrite(&self, space: Space, at: usize, new: &[u8]) -> Vec<u8> {
        match (space, self.file_at(space, at)) {
            (_, Some(at)) => {
                let mut b = self.bytes.clone();
                b[at..at + new.len()].copy_from_slice(new);
                fix_checksums_at(&mut b, self.slot);
                b
            }
            (Space::Block(blk), None) => {
                let mut raw = self.decoded[blk].clone();
                raw[at..at + new.len()].copy_from_slice(new);
                relayout(&self.bytes, blk, &zstd_frame(&raw), raw.len())
            }
            (Space::File, None) => unreachable!(),
        }
    }

    /// The answers the file must give when it opens as `generation`: the previous
    /// generation's if that is the previous generation of an updated file, else the file's
    /// (a header rewritten to another generation number holds the same file).
    pub fn answers(&self, generation: u64) -> (&[Hit], &[u8]) {
        match &self.previous {
            Some(p) if p.generation == generation && generation != self.generation => {
                (&p.hits, &p.occluded)
            }
            _ => (&self.hits, &self.occluded),
        }
    }

    /// Whether `generation` is the previous generation of an updated file.
    pub fn is_previous(&self, generation: u64) -> bool {
        self.previous
            .as_ref()
            .is_some_and(|p| p.generation == generation && generation != self.generation)
    }

    /// A name for field `at` of `region`, telling link records of the top tree (and their
    /// ropes) apart.
    pub fn field(&self, region: &Region, at: usize) -> String {
        let field = region.field(at);
        let record = match region.kind {
            RegionKind::Section(i) if i == NODES - 1 => Some(8),
            RegionKind::Section(SECTION_ROPES) => Some(ROPE_LEN),
            _ => None,
        };
        if let Some(size) = record {
            let node = (at - region.range.start) / size;
            if self.links.iter().any(|l| l.node == node) {
                return format!("{field} (of a link)");
            }
        }
        field.to_string()
    }
}
