//! Writing an `.oavm` file in one pass (spec §2-§3, §8): blocks encoded and stored as they
//! come ([`store_block`], [`FileWriter::push`]), then the directory, the top tree and its link
//! bounds, then the header. Where the bytes go is a [`Sink`]: a buffer or a file (which the
//! caller makes safe and atomic, `crate::output`).

use std::io::Write;

use bytemuck::Zeroable;

use super::BlockView;
use super::format::*;
use crate::error::Error;

/// The records of one unit: the top tree, or the subtrees of one block (spec §8.1, §8.3).
#[derive(Clone, Debug, Default)]
pub struct UnitParts {
    pub levels: Vec<LevelEntry>,
    pub nodes: Vec<NodeRecord>,
    pub ranks: Vec<RankWord>,
    pub volumes: Vec<VolumeRecord>,
    pub refs: Vec<u32>,
    pub triangles: Vec<TriRecord>,
    /// Clusters (spec §7.1, §7.2): empty in a unit of leaf lists and in the top tree.
    pub cluster_nodes: Vec<ClusterNode>,
    pub groups: Vec<TriGroup>,
    /// Ropes (spec §8.4): one record per node, or none (a file without ropes).
    pub ropes: Vec<RopeRecord>,
    /// Occluders (spec §8.5): the internal nodes holding some, and their triangles.
    pub occluder_nodes: Vec<OccluderNode>,
    pub occluders: Vec<TriRecord>,
}

impl UnitParts {
    pub fn as_ref(&self) -> UnitRef<'_> {
        UnitRef {
            levels: &self.levels,
            nodes: &self.nodes,
            ranks: &self.ranks,
            volumes: &self.volumes,
            refs: &self.refs,
            triangles: &self.triangles,
            cluster_nodes: &self.cluster_nodes,
            groups: &self.groups,
            ropes: &self.ropes,
            occluder_nodes: &self.occluder_nodes,
            occluders: &self.occluders,
        }
    }
}

/// A borrowed unit.
#[derive(Clone, Copy, Debug)]
pub struct UnitRef<'a> {
    pub levels: &'a [LevelEntry],
    pub nodes: &'a [NodeRecord],
    pub ranks: &'a [RankWord],
    pub volumes: &'a [VolumeRecord],
    pub refs: &'a [u32],
    pub triangles: &'a [TriRecord],
    pub cluster_nodes: &'a [ClusterNode],
    pub groups: &'a [TriGroup],
    pub ropes: &'a [RopeRecord],
    pub occluder_nodes: &'a [OccluderNode],
    pub occluders: &'a [TriRecord],
}

impl<'a> From<&BlockView<'a>> for UnitRef<'a> {
    /// A decoded block's parts, as they are (the passes that add ropes or occluders replace
    /// theirs).
    fn from(v: &BlockView<'a>) -> UnitRef<'a> {
        UnitRef {
            levels: v.levels,
            nodes: v.nodes,
            ranks: v.ranks,
            volumes: v.volumes,
            refs: v.refs,
            triangles: v.triangles,
            cluster_nodes: v.cluster_nodes,
            groups: v.groups,
            ropes: v.ropes,
            occluder_nodes: v.occluder_nodes,
            occluders: v.occluders,
        }
    }
}

impl UnitRef<'_> {
    /// Triangles stored in the unit (spec §8.2, the directory's `triangles`): its triangle
    /// records, or its groups' lanes in use.
    pub fn stored_triangles(&self) -> u64 {
        self.triangles.len() as u64 + self.groups.iter().map(|g| g.count as u64).sum::<u64>()
    }
}

/// How blocks are made and stored.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BlockOptions {
    /// Target raw size of a block, bytes: subtrees are grouped into blocks of about this size
    /// (a single leaf larger than it gets a block of its own).
    pub block_size: u64,
    /// zstd level for blocks (`None`: raw). A block that does not shrink is stored raw.
    pub compress: Option<i32>,
    /// Triangle groups per chunk (spec §8.3): the unit in which a block's groups are checked,
    /// compressed and read on their own.
    pub chunk_groups: u32,
    /// Store groups in the lean encoding (spec §7.3, [`CODEC_LEAN`]): about two thirds of the
    /// bytes, decoded far faster than zstd. Not with `compress`.
    pub lean: bool,
}

/// Default target block size: 256 KiB, a few dozen disk pages and a few thousand triangles;
/// small enough that a tight memory budget holds many blocks, large enough that the directory
/// and top tree stay small (about 1/5000 of the file).
pub const DEFAULT_BLOCK_SIZE: u64 = 256 * 1024;
/// Default zstd level of `--compress`.
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;
/// Default groups per chunk: 128 groups, 20 KiB, whole pages.
pub const DEFAULT_CHUNK_GROUPS: u32 = 128;

impl BlockOptions {
    pub fn validate(&self) -> Result<(), Error> {
        if !(4096..=MAX_BLOCK_RAW_LEN / 4).contains(&self.block_size) {
            return Err(Error::Invalid(format!(
                "--block-size {} must be between 4 KiB and {} MiB",
                self.block_size,
                (MAX_BLOCK_RAW_LEN / 4) >> 20
            )));
        }
        if !(1..=MAX_CHUNK_GROUPS).contains(&self.chunk_groups) {
            return Err(Error::Invalid(format!(
                "--chunk-groups {} must be between 1 and {MAX_CHUNK_GROUPS}",
                self.chunk_groups
            )));
        }
        if self.lean && self.compress.is_some() {
            return Err(Error::Invalid(
                "--lean and --compress: a file's groups are stored lean or zstd, not both \
                 (choose --lean for speed, --compress for size)"
                    .into(),
            ));
        }
        if let Some(level) = self.compress
            && !zstd::compression_level_range().contains(&level)
        {
            return Err(Error::Invalid(format!(
                "--compress={level}: zstd levels are {:?}",
                zstd::compression_level_range()
            )));
        }
        Ok(())
    }
}

impl Default for BlockOptions {
    fn default() -> Self {
        BlockOptions {
            block_size: DEFAULT_BLOCK_SIZE,
            compress: None,
            chunk_groups: DEFAULT_CHUNK_GROUPS,
            lean: false,
        }
    }
}

/// A block ready to be written: its stored bytes and its directory entry (offset not yet set).
pub struct StoredBlock {
    pub bytes: Vec<u8>,
    pub entry: BlockEntry,
    /// The id the block was encoded with (its header says it): where it must be written.
    pub entry_id: u32,
    /// The bounds of each of its roots (spec §8.1), for the links to them.
    pub root_bounds: Vec<LinkBounds>,
    /// Whether it carries ropes (spec §8.4; all blocks of a file do, or none).
    pub ropes: bool,
    /// The box of each of its roots' wide nodes (spec §8.7; empty in a file of lists), for the
    /// top tree's wide links.
    pub root_boxes: Vec<super::wide::WorldBox>,
    /// Groups per chunk it was made with (the file's `chunk_groups`).
    pub chunk_groups: u32,
}

/// Whether a block of `raw_len` bytes whose zstd frame is `z_len` bytes is stored compressed:
/// when that is smaller, and within [`MAX_ZSTD_RATIO`] (which a reader enforces).
fn worth_compressing(raw_len: u64, z_len: u64) -> bool {
    z_len < raw_len && raw_len <= z_len.saturating_mul(MAX_ZSTD_RATIO)
}

/// The local level and reference count of the leaf with the most references in `unit`.
fn largest_leaf(unit: UnitRef<'_>) -> (usize, usize) {
    let mut best = (0, 0);
    for (l, e) in unit.levels.iter().enumerate() {
        let recs = unit
            .nodes
            .get(e.node_start as usize..(e.node_start + e.node_count) as usize)
            .unwrap_or(&[]);
        for rec in recs {
            if let Some(NodeKind::Solid {
                first,
                inline_count,
                ..
            }) = rec.kind()
                && let Some((refs, _)) = leaf_refs(unit.refs, first, inline_count)
                && refs.len() > best.1
            {
                best = (l, refs.len());
            }
        }
    }
    best
}

/// The header of the block `unit` would make (spec §8.3).
fn block_header(unit: UnitRef<'_>, root_level: u32, id: u32, chunk_groups: u32) -> BlockHeader {
    BlockHeader {
        tag: BLOCK_TAG,
        level_count: unit.levels.len() as u32,
        root_level,
        root_count: unit.levels.first().map_or(0, |l| l.node_count as u32),
        node_count: unit.nodes.len() as u64,
        rank_count: unit.ranks.len() as u64,
        volume_count: unit.volumes.len() as u64,
        ref_count: unit.refs.len() as u64,
        triangle_count: unit.triangles.len() as u64,
        cluster_node_count: unit.cluster_nodes.len() as u64,
        group_count: unit.groups.len() as u64,
        block_id: id as u64,
        rope_count: unit.ropes.len() as u64,
        occluder_node_count: unit.occluder_nodes.len() as u64,
        occluder_count: unit.occluders.len() as u64,
        chunk_count: (unit.groups.len() as u64).div_ceil(chunk_groups.max(1) as u64),
    }
}

/// The raw bytes of a block (spec §8.3): header, then each part where [`block_layout`] puts
/// it; the chunk table is left zero (see [`store_block`]). The caller has checked its size.
pub fn encode_block(unit: UnitRef<'_>, root_level: u32, id: u32, chunk_groups: u32) -> Vec<u8> {
    let header = block_header(unit, root_level, id, chunk_groups);
    let (ranges, len) = block_layout(&header).expect("block counts fit in memory");
    let mut out = vec![0u8; len as usize];
    out[..std::mem::size_of::<BlockHeader>()].copy_from_slice(bytemuck::bytes_of(&header));
    let parts: [(usize, &[u8]); BLOCK_PARTS - 1] = [
        (PART_LEVELS, bytemuck::cast_slice(unit.levels)),
        (PART_NODES, bytemuck::cast_slice(unit.nodes)),
        (PART_RANKS, bytemuck::cast_slice(unit.ranks)),
        (PART_VOLUMES, bytemuck::cast_slice(unit.volumes)),
        (PART_REFS, bytemuck::cast_slice(unit.refs)),
        (PART_TRIANGLES, bytemuck::cast_slice(unit.triangles)),
        (PART_WIDE, bytemuck::cast_slice(unit.cluster_nodes)),
        (PART_ROPES, bytemuck::cast_slice(unit.ropes)),
        (
            PART_OCCLUDER_NODES,
            bytemuck::cast_slice(unit.occluder_nodes),
        ),
        (PART_OCCLUDERS, bytemuck::cast_slice(unit.occluders)),
        (PART_GROUPS, bytemuck::cast_slice(unit.groups)),
    ];
    for (i, bytes) in parts {
        out[ranges[i].start as usize..ranges[i].end as usize].copy_from_slice(bytes);
    }
    out
}

/// Stores the raw bytes of a block (`raw`, laid out by `header`): its groups cut into chunks of
/// `chunk_groups`, each compressed on its own when `compress` says so and that pays (else
/// raw), their entries written into the head's chunk table, then the head, compressed in a
/// block whose codec is zstd. A block is zstd when its head or a chunk shrinks, and its head's
/// frame stays within what a reader accepts ([`zstd_head_fits`]); else raw. With `lean`, a
/// block with groups is lean: its head raw, each chunk in the lean encoding (spec §7.3).
/// Returns the codec, the stored bytes and the head's stored and raw lengths.
fn store_raw(
    mut raw: Vec<u8>,
    header: &BlockHeader,
    chunk_groups: u32,
    compress: Option<i32>,
    lean: bool,
) -> std::io::Result<(u32, Vec<u8>, u64, u64)> {
    let (ranges, len) = block_layout(header).expect("block counts fit in memory");
    let head_len = match header.group_count {
        0 => len,
        _ => ranges[PART_GROUPS].start,
    } as usize;
    let per = chunk_groups.max(1) as usize * std::mem::size_of::<TriGroup>();
    let chunk = |c: &[u8], level: Option<i32>| -> std::io::Result<Vec<u8>> {
        if let Some(level) = level {
            let z = zstd::bulk::compress(c, level)?;
            if worth_compressing(c.len() as u64, z.len() as u64) {
                return Ok(z);
            }
        }
        Ok(c.to_vec())
    };
    let table_at = ranges[PART_CHUNKS].start as usize;
    let write_table = |raw: &mut [u8], chunks: &[Vec<u8>]| {
        let mut at = 0u64;
        for (i, c) in chunks.iter().enumerate() {
            let e = ChunkEntry {
                offset: at as u32,
                stored_len: c.len() as u32,
                checksum: checksum(c),
            };
            let p = table_at + i * std::mem::size_of::<ChunkEntry>();
            raw[p..p + std::mem::size_of::<ChunkEntry>()].copy_from_slice(bytemuck::bytes_of(&e));
            at += c.len() as u64;
        }
    };
    if lean && header.group_count > 0 {
        let chunks: Vec<Vec<u8>> = raw[head_len..]
            .chunks(per)
            .map(|c| super::lean::encode_chunk(c).map_err(std::io::Error::other))
            .collect::<std::io::Result<_>>()?;
        write_table(&mut raw, &chunks);
        raw.truncate(head_len);
        for c in &chunks {
            raw.extend_from_slice(c);
        }
        return Ok((CODEC_LEAN, raw, head_len as u64, head_len as u64));
    }
    if let Some(level) = compress {
        let chunks: Vec<Vec<u8>> = raw[head_len..]
            .chunks(per)
            .map(|c| chunk(c, Some(level)))
            .collect::<std::io::Result<_>>()?;
        write_table(&mut raw, &chunks);
        let z = zstd::bulk::compress(&raw[..head_len], level)?;
        let shrank = z.len() < head_len
            || chunks.iter().map(Vec::len).sum::<usize>() < len as usize - head_len;
        if shrank && zstd_head_fits(head_len as u64, z.len() as u64) {
            let head_stored = z.len() as u64;
            let mut out = z;
            for c in &chunks {
                out.extend_from_slice(c);
            }
            return Ok((CODEC_ZSTD, out, head_stored, head_len as u64));
        }
    }
    // Raw: the bytes as laid out, every chunk raw.
    let chunks: Vec<Vec<u8>> = raw[head_len..].chunks(per).map(<[u8]>::to_vec).collect();
    write_table(&mut raw, &chunks);
    Ok((CODEC_RAW, raw, head_len as u64, head_len as u64))
}

/// Encodes block `id` and stores it as `opts` say: zstd-compressed if that makes it smaller
/// and the ratio stays within [`MAX_ZSTD_RATIO`] (else raw). Refuses a block a reader would
/// refuse: one larger than [`MAX_BLOCK_RAW_LEN`] (a leaf whose triangles cannot be separated,
/// such as many copies of one triangle).
pub fn store_block(
    unit: UnitRef<'_>,
    root_level: u32,
    id: u32,
    opts: &BlockOptions,
) -> Result<StoredBlock, Error> {
    store_block_within(unit, root_level, id, opts, MAX_BLOCK_RAW_LEN)
}

/// [`store_block`] with `limit` for [`MAX_BLOCK_RAW_LEN`] (tests try it with a small one).
fn store_block_within(
    unit: UnitRef<'_>,
    root_level: u32,
    id: u32,
    opts: &BlockOptions,
    limit: u64,
) -> Result<StoredBlock, Error> {
    if !unit.ropes.is_empty() && unit.ropes.len() != unit.nodes.len() {
        return Err(Error::Build(format!(
            "block {id}: {} rope records for {} nodes",
            unit.ropes.len(),
            unit.nodes.len()
        )));
    }
    // A block of clusters gets its wide nodes (spec §8.7): the octree's, the clusters' roots
    // among them, renumbered.
    let wide = if unit.cluster_nodes.is_empty() {
        None
    } else {
        Some(
            super::wide::lay_block(unit.levels, unit.nodes, unit.cluster_nodes)
                .map_err(|e| Error::Build(format!("block {id}: wide nodes: {e}")))?,
        )
    };
    let unit = match &wide {
        Some(w) => UnitRef {
            nodes: &w.records,
            cluster_nodes: &w.nodes,
            ..unit
        },
        None => unit,
    };
    let root_boxes = wide.as_ref().map_or(Vec::new(), |w| w.roots.clone());
    let chunk_groups = opts.chunk_groups;
    let header = block_header(unit, root_level, id, chunk_groups);
    let raw_len = block_layout(&header).map_or(u64::MAX, |(_, n)| n);
    if raw_len > limit {
        let largest = largest_leaf(unit);
        return Err(Error::Build(format!(
            "block {id} would be {raw_len} bytes, more than the {limit} bytes a \
             reader accepts (format-spec §2): a leaf at level {} holds {} triangle references \
             that subdivision cannot separate (many triangles at one place, or the depth limit); \
             raise --max-depth, or remove the duplicate triangles",
            root_level as usize + largest.0,
            largest.1
        )));
    }
    let root_bounds = super::bounds::root_bounds(unit.levels, unit.nodes)
        .map_err(|e| Error::Build(format!("block {id}: {e}")))?;
    let raw = encode_block(unit, root_level, id, chunk_groups);
    let (codec, bytes, head_stored_len, head_raw_len) =
        store_raw(raw, &header, chunk_groups, opts.compress, opts.lean)
            .map_err(|e| Error::Build(format!("compressing block {id}: {e}")))?;
    Ok(StoredBlock {
        entry: BlockEntry {
            offset: 0,
            stored_len: bytes.len() as u64,
            raw_len,
            codec,
            root_level,
            root_count: unit.levels.first().map_or(0, |l| l.node_count as u32),
            triangles: unit.stored_triangles() as u32,
            checksum: checksum(&bytes[..head_stored_len as usize]),
            head_stored_len,
            head_raw_len,
        },
        bytes,
        entry_id: id,
        root_bounds,
        ropes: !unit.ropes.is_empty(),
        root_boxes,
        chunk_groups,
    })
}

/// Where the writer's bytes go: a growing buffer (files built in memory) or a file.
pub trait Sink {
    fn append(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Overwrites bytes already appended, at `offset` (the header, written last).
    fn patch(&mut self, offset: u64, bytes: &[u8]) -> std::io::Result<()>;
    /// Makes everything written so far durable (a file: flushed and `fdatasync`ed).
    fn sync(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Sink for Vec<u8> {
    fn append(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.extend_from_slice(bytes);
        Ok(())
    }

    fn patch(&mut self, offset: u64, bytes: &[u8]) -> std::io::Result<()> {
        let at = offset as usize;
        self.get_mut(at..at + bytes.len())
            .ok_or_else(|| std::io::Error::other("patch past the end"))?
            .copy_from_slice(bytes);
        Ok(())
    }
}

/// A file sink: buffered appends, the header patched in place at the end.
pub struct FileSink {
    out: std::io::BufWriter<std::fs::File>,
}

impl FileSink {
    /// Appends to `file`, from its current position, through a 1 MiB buffer.
    pub fn new(file: std::fs::File) -> FileSink {
        FileSink {
            out: std::io::BufWriter::with_capacity(1 << 20, file),
        }
    }

    /// Flushes the buffer and gives the file back.
    pub fn into_file(self) -> std::io::Result<std::fs::File> {
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

impl Sink for FileSink {
    fn append(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.out.write_all(bytes)
    }

    fn patch(&mut self, offset: u64, bytes: &[u8]) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        self.out.flush()?;
        self.out.get_ref().write_all_at(bytes, offset)
    }

    fn sync(&mut self) -> std::io::Result<()> {
        self.out.flush()?;
        self.out.get_ref().sync_data()
    }
}

/// Writes a file in one pass (spec §2): a placeholder header and section table, the blocks as
/// they come, then the block directory and the top tree, then the real header. Nothing but the
/// blocks is held, and those only until they are written.
///
/// [`FileWriter::resume`] writes the next generation of an existing file instead (spec
/// §2.1): new blocks and primitive chunks appended after everything the file holds, then the
/// sections, synced, then the header in the other slot, synced.
pub struct FileWriter<S: Sink> {
    sink: S,
    at: u64,
    blocks_start: u64,
    directory: Vec<BlockEntry>,
    /// The roots' bounds of every block, by block id (a free entry has none).
    bounds: Vec<Vec<LinkBounds>>,
    /// The boxes of every block's roots' wide nodes (spec §8.7), by block id (empty in a file
    /// of lists and for a free entry).
    boxes: Vec<Vec<super::wide::WorldBox>>,
    /// Whether the blocks written carry ropes (`None` before the first).
    ropes: Option<bool>,
    /// Groups per chunk of the blocks written (0 before the first block with groups; an
    /// update's, the file's).
    chunk_groups: u32,
    /// The primitive table's chunks (spec §8.6), if any.
    prims: Option<Vec<PrimChunk>>,
    /// The geometry table (spec §8.8); empty: none.
    geometries: Vec<crate::mesh::Geometry>,
    /// The generation written and its header slot (spec §2.1).
    generation: u64,
    /// Sync the data before the header and the header after it (a new generation).
    durable: bool,
}

const ZEROS: [u8; 4096] = [0; 4096];

impl<S: Sink> FileWriter<S> {
    pub fn new(mut sink: S) -> std::io::Result<FileWriter<S>> {
        let blocks_start = RAW_BLOCK_ALIGN;
        sink.append(&ZEROS[..blocks_start as usize])?;
        Ok(FileWriter {
            sink,
            at: blocks_start,
            blocks_start,
            directory: Vec::new(),
            bounds: Vec::new(),
            boxes: Vec::new(),
            ropes: None,
            chunk_groups: 0,
            prims: None,
            geometries: Vec::new(),
            generation: FIRST_GENERATION,
            durable: false,
        })
    }

    /// Writes generation `generation` of a file whose bytes end at `at` (a multiple of
    /// [`RAW_BLOCK_ALIGN`]; the sink appends there): `directory` is the previous generation's
    /// (free entries where blocks were removed, spec §8.2) with `bounds`, each live block's
    /// roots' link bounds, and `boxes`, their wide nodes' boxes (spec §8.7); `prims` its primitive chunks (changed ones are replaced with
    /// [`Self::replace_prim_chunk`]). Ropes are not carried over (a file that has them is not
    /// updated).
    #[allow(clippy::too_many_arguments)]
    pub fn resume(
        sink: S,
        at: u64,
        generation: u64,
        chunk_groups: u32,
        directory: Vec<BlockEntry>,
        bounds: Vec<Vec<LinkBounds>>,
        boxes: Vec<Vec<super::wide::WorldBox>>,
        prims: Option<Vec<PrimChunk>>,
    ) -> std::io::Result<FileWriter<S>> {
        if !at.is_multiple_of(RAW_BLOCK_ALIGN) || at < DATA_START || generation <= FIRST_GENERATION
        {
            return Err(std::io::Error::other(format!(
                "generation {generation} cannot start at offset {at}"
            )));
        }
        if bounds.len() != directory.len() || boxes.len() != directory.len() {
            return Err(std::io::Error::other(
                "one bounds list and one box list per directory entry expected",
            ));
        }
        Ok(FileWriter {
            sink,
            at,
            blocks_start: DATA_START,
            directory,
            bounds,
            boxes,
            ropes: Some(false),
            chunk_groups,
            prims,
            geometries: Vec::new(),
            generation,
            durable: true,
        })
    }

    fn pad_to(&mut self, align: u64) -> std::io::Result<()> {
        while !self.at.is_multiple_of(align) {
            let n = (self.at.next_multiple_of(align) - self.at).min(ZEROS.len() as u64);
            self.sink.append(&ZEROS[..n as usize])?;
            self.at += n;
        }
        Ok(())
    }

    /// Sets the geometry table the file will hold (spec §8.8; empty: none). [`Self::finish`]
    /// checks that it covers the file's primitives.
    pub fn set_geometries(&mut self, geometries: Vec<crate::mesh::Geometry>) {
        self.geometries = geometries;
    }

    /// Blocks written so far (the id the next one gets).
    pub fn block_count(&self) -> u32 {
        self.directory.len() as u32
    }

    /// Appends the next block (its id is [`Self::block_count`] before the call).
    pub fn push(&mut self, block: StoredBlock) -> std::io::Result<u32> {
        if block.entry_id != self.block_count() {
            return Err(std::io::Error::other(format!(
                "block {} written as block {}",
                block.entry_id,
                self.block_count()
            )));
        }
        self.directory.push(BlockEntry::zeroed());
        self.bounds.push(Vec::new());
        self.boxes.push(Vec::new());
        self.store(block)
    }

    /// Writes a block into a free entry of the directory (its id, which its header says), or
    /// as the next one: what an update does with the blocks it makes.
    pub fn place(&mut self, block: StoredBlock) -> std::io::Result<u32> {
        let id = block.entry_id as usize;
        if id == self.directory.len() {
            return self.push(block);
        }
        if self.directory.get(id).is_none_or(|e| !e.is_free()) {
            return Err(std::io::Error::other(format!(
                "block {id} written where the directory has no free entry"
            )));
        }
        self.store(block)
    }

    /// Stores `block` at the end of what is written, into its directory entry.
    fn store(&mut self, block: StoredBlock) -> std::io::Result<u32> {
        let align = if block.entry.codec != CODEC_ZSTD {
            RAW_BLOCK_ALIGN
        } else {
            SECTION_ALIGN
        };
        self.pad_to(align)?;
        if *self.ropes.get_or_insert(block.ropes) != block.ropes {
            return Err(std::io::Error::other(format!(
                "block {} {} ropes, the blocks before it {}",
                block.entry_id,
                if block.ropes { "has" } else { "has no" },
                if block.ropes {
                    "have none"
                } else {
                    "have them"
                },
            )));
        }
        if block.entry.head_raw_len < block.entry.raw_len {
            if self.chunk_groups == 0 {
                self.chunk_groups = block.chunk_groups;
            }
            if self.chunk_groups != block.chunk_groups {
                return Err(std::io::Error::other(format!(
                    "block {} has chunks of {} groups, the file {}",
                    block.entry_id, block.chunk_groups, self.chunk_groups
                )));
            }
        }
        let mut entry = block.entry;
        entry.offset = self.at;
        self.sink.append(&block.bytes)?;
        self.at += block.bytes.len() as u64;
        let id = block.entry_id as usize;
        self.directory[id] = entry;
        self.bounds[id] = block.root_bounds;
        self.boxes[id] = block.root_boxes;
        Ok(block.entry_id)
    }

    /// Writes chunk `c` of the primitive table (spec §8.6): the next one, or one written before
    /// again (an update's changed primitives).
    pub fn write_prim_chunk(&mut self, c: usize, records: &[PrimRecord]) -> std::io::Result<()> {
        self.pad_to(SECTION_ALIGN)?;
        let bytes: &[u8] = bytemuck::cast_slice(records);
        let entry = PrimChunk {
            offset: self.at,
            count: records.len() as u64,
            checksum: checksum(bytes),
            reserved: 0,
        };
        let chunks = self.prims.get_or_insert_with(Vec::new);
        if c > chunks.len() {
            return Err(std::io::Error::other(format!(
                "primitive chunk {c} written after {} chunks",
                chunks.len()
            )));
        }
        if c == chunks.len() {
            chunks.push(entry);
        } else {
            chunks[c] = entry;
        }
        self.sink.append(bytes)?;
        self.at += bytes.len() as u64;
        Ok(())
    }

    /// Drops the primitive chunks from `count` on (an update that leaves fewer primitives).
    pub fn truncate_prim_chunks(&mut self, count: usize) {
        if let Some(p) = &mut self.prims {
            p.truncate(count);
        }
    }

    /// Drops free entries at the end of the directory.
    pub fn trim_free(&mut self) {
        while self.directory.last().is_some_and(|e| e.is_free()) {
            self.directory.pop();
            self.bounds.pop();
            self.boxes.pop();
        }
    }

    /// Writes the primitive table's chunks (spec §8.6) after the blocks: `records` holds one
    /// record per input triangle, in primitive-id order. Call once, after the last block.
    pub fn push_prims(&mut self, records: &[PrimRecord]) -> std::io::Result<()> {
        if self.prims.is_some() {
            return Err(std::io::Error::other(
                "the primitive table was written twice",
            ));
        }
        let mut chunks = Vec::with_capacity(records.len().div_ceil(PRIM_CHUNK as usize));
        for chunk in records.chunks(PRIM_CHUNK as usize) {
            self.pad_to(SECTION_ALIGN)?;
            let bytes: &[u8] = bytemuck::cast_slice(chunk);
            chunks.push(PrimChunk {
                offset: self.at,
                count: chunk.len() as u64,
                checksum: checksum(bytes),
                reserved: 0,
            });
            self.sink.append(bytes)?;
            self.at += bytes.len() as u64;
        }
        self.prims = Some(chunks);
        Ok(())
    }

    /// The link bounds section (spec §8.1): for each top-tree node, its root's bounds if it is a
    /// link, else zero.
    fn link_bounds(&self, nodes: &[NodeRecord]) -> std::io::Result<Vec<LinkBounds>> {
        nodes
            .iter()
            .map(|rec| match rec.kind() {
                Some(NodeKind::Link { block, root }) => self
                    .bounds
                    .get(block as usize)
                    .and_then(|b| b.get(root as usize))
                    .copied()
                    .ok_or_else(|| {
                        std::io::Error::other(format!(
                            "the top tree links to root {root} of block {block}, which was not written"
                        ))
                    }),
                _ => Ok(LinkBounds::default()),
            })
            .collect()
    }

    /// Writes the directory, the top tree and the header; returns the sink and the file size.
    /// `meta` holds the header fields the builder knows (root cube, mesh bounds, triangle,
    /// leaf and level counts, build options, the `MERGED` flag); the writer sets the rest.
    pub fn finish(mut self, meta: &Header, top: UnitRef<'_>) -> std::io::Result<(S, u64)> {
        let directory = std::mem::take(&mut self.directory);
        let link_bounds = self.link_bounds(top.nodes)?;
        let ropes = self.top_ropes(&top)?;
        let prims = self.prims.take();
        if let Some(p) = &prims
            && p.len() as u64 != meta.input_triangles.div_ceil(PRIM_CHUNK)
        {
            return Err(std::io::Error::other(format!(
                "{} primitive chunks for {} input triangles",
                p.len(),
                meta.input_triangles
            )));
        }
        crate::mesh::check_geometries(&self.geometries, meta.input_triangles)
            .map_err(|e| std::io::Error::other(format!("the geometry table: {e}")))?;
        let geometries = super::geometry_records(&self.geometries);
        let mut flags = file_flags(meta, &directory, ropes, prims.is_some());
        if !geometries.is_empty() {
            flags |= FLAG_GEOMETRIES;
        }
        let (wide_nodes, wide_links) = if flags & FLAG_CLUSTERS != 0 {
            super::wide::lay_top(top.levels, top.nodes, |b, r| {
                self.boxes.get(b as usize)?.get(r as usize).copied()
            })
            .map_err(|e| std::io::Error::other(format!("the top tree's wide nodes: {e}")))?
        } else {
            (Vec::new(), Vec::new())
        };
        let mut entries = [SectionEntry::zeroed(); SectionKind::ALL.len()];
        entries[0] = SectionEntry {
            kind: SectionKind::Blocks as u32,
            codec: 0,
            offset: self.blocks_start,
            // The data region (the blocks section) ends where the directory begins (spec §2.1).
            length: self.at.next_multiple_of(SECTION_ALIGN) - self.blocks_start,
            count: directory.len() as u64,
            block_directory: 0,
            checksum: 0,
        };
        let wide = (&wide_nodes[..], &wide_links[..]);
        let sections = top_sections(
            &directory,
            &top,
            &link_bounds,
            wide,
            prims.as_deref(),
            &geometries,
        );
        let section_count = self.write_sections(sections, flags, &mut entries)?;
        let file_size = self.at;
        let header = self.header(meta, flags, &directory, section_count);
        self.write_header(header, &entries[..section_count])?;
        Ok((self.sink, file_size))
    }

    /// Whether the file has ropes (spec §8.4), which are all or nothing: the top tree's (one
    /// per node) and every block's.
    fn top_ropes(&self, top: &UnitRef<'_>) -> std::io::Result<bool> {
        let ropes = !top.ropes.is_empty();
        if ropes && top.ropes.len() != top.nodes.len() {
            return Err(std::io::Error::other(format!(
                "{} top-tree rope records for {} nodes",
                top.ropes.len(),
                top.nodes.len()
            )));
        }
        if ropes != self.ropes.unwrap_or(ropes) {
            return Err(std::io::Error::other(
                "the top tree and the blocks disagree on whether the file has ropes",
            ));
        }
        Ok(ropes)
    }

    /// Writes the sections present with `flags`, each aligned, and their entries in the
    /// section table after the blocks' (`entries[0]`); returns how many entries there are.
    fn write_sections(
        &mut self,
        sections: [(SectionKind, &[u8], u64); 11],
        flags: u32,
        entries: &mut [SectionEntry],
    ) -> std::io::Result<usize> {
        let mut section_count = 1;
        for (kind, bytes, count) in sections {
            if !kind.present(flags) {
                continue;
            }
            self.pad_to(SECTION_ALIGN)?;
            entries[section_count] = SectionEntry {
                kind: kind as u32,
                codec: 0,
                offset: self.at,
                length: bytes.len() as u64,
                count,
                block_directory: 0,
                checksum: checksum(bytes),
            };
            section_count += 1;
            self.sink.append(bytes)?;
            self.at += bytes.len() as u64;
        }
        Ok(section_count)
    }

    /// The header slot of the generation written: generation g goes to slot (g - 1) mod 2
    /// (spec §2.1).
    fn slot(&self) -> u64 {
        HEADER_SLOTS[((self.generation - FIRST_GENERATION) % 2) as usize]
    }

    /// The header of the file written (its checksum not yet set), once every section is: the
    /// fields of `meta` the builder knows, and the rest from what was written.
    fn header(
        &self,
        meta: &Header,
        flags: u32,
        directory: &[BlockEntry],
        section_count: usize,
    ) -> Header {
        let live = || directory.iter().filter(|e| !e.is_free());
        let max_raw = live().map(|e| e.raw_len).max().unwrap_or(0);
        let block_triangles: u64 = live().map(|e| e.triangles as u64).sum();
        let header_size = std::mem::size_of::<Header>() as u64;
        Header {
            magic: MAGIC,
            version: VERSION,
            flags,
            header_size: header_size as u32,
            section_count: section_count as u32,
            section_table_offset: self.slot() + header_size,
            file_size: self.at,
            root_min: meta.root_min,
            root_size: meta.root_size,
            mesh_min: meta.mesh_min,
            mesh_max: meta.mesh_max,
            input_triangles: meta.input_triangles,
            empty_leaves: meta.empty_leaves,
            solid_leaves: meta.solid_leaves,
            level_count: meta.level_count,
            lattice_bits: LATTICE_BITS,
            max_depth: meta.max_depth,
            leaf_size: meta.leaf_size,
            block_count: directory.len() as u64,
            max_block_raw_len: max_raw,
            block_triangles,
            stored_triangles: meta.stored_triangles,
            generation: self.generation,
            chunk_groups: self.chunk_groups,
            reserved_u32: 0,
            reserved: [0; 8],
            checksum: 0,
        }
    }

    /// Writes `header`, its checksum set over it and the section `table`, and the table into
    /// the generation's header slot; for a new generation, its sections are made durable
    /// before the header that makes them the file's, and the header after.
    fn write_header(&mut self, mut header: Header, table: &[SectionEntry]) -> std::io::Result<()> {
        let table: &[u8] = bytemuck::cast_slice(table);
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        hasher.update(&bytemuck::bytes_of(&header)[..HEADER_CHECKED_LEN]);
        hasher.update(table);
        header.checksum = hasher.digest();
        if self.durable {
            self.sink.sync()?;
        }
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        bytes.extend_from_slice(table);
        self.sink.patch(self.slot(), &bytes)?;
        if self.durable {
            self.sink.sync()?;
        }
        Ok(())
    }
}

/// The header's flags: those of `meta` the builder sets (merged, clusters, occluders: a pass
/// that adds occluders, which some blocks may lack, says so in `meta`), and those of what was
/// written: compressed blocks among the live ones, ropes, the primitive table.
fn file_flags(meta: &Header, directory: &[BlockEntry], ropes: bool, prims: bool) -> u32 {
    let mut flags = meta.flags & (FLAG_MERGED | FLAG_CLUSTERS | FLAG_OCCLUDERS);
    if directory
        .iter()
        .filter(|e| !e.is_free())
        .any(|e| e.codec != CODEC_RAW)
    {
        flags |= FLAG_COMPRESSED;
    }
    if directory
        .iter()
        .filter(|e| !e.is_free())
        .any(|e| e.codec == CODEC_LEAN)
    {
        flags |= FLAG_LEAN;
    }
    if ropes {
        flags |= FLAG_ROPES;
    }
    if prims {
        flags |= FLAG_PRIMS;
    }
    flags
}

/// The sections after the blocks, in file order, with their bytes and record counts: the
/// directory, the top tree's levels, nodes, ranks, volumes, link bounds, wide nodes and links,
/// and ropes, the primitive chunk directory and the geometry table (empty when absent).
fn top_sections<'a>(
    directory: &'a [BlockEntry],
    top: &UnitRef<'a>,
    link_bounds: &'a [LinkBounds],
    wide: (&'a [ClusterNode], &'a [WideLink]),
    prims: Option<&'a [PrimChunk]>,
    geometries: &'a [GeometryRecord],
) -> [(SectionKind, &'a [u8], u64); 11] {
    [
        (
            SectionKind::Directory,
            bytemuck::cast_slice(directory),
            directory.len() as u64,
        ),
        (
            SectionKind::Levels,
            bytemuck::cast_slice(top.levels),
            top.levels.len() as u64,
        ),
        (
            SectionKind::Nodes,
            bytemuck::cast_slice(top.nodes),
            top.nodes.len() as u64,
        ),
        (
            SectionKind::Ranks,
            bytemuck::cast_slice(top.ranks),
            top.ranks.len() as u64,
        ),
        (
            SectionKind::Volumes,
            bytemuck::cast_slice(top.volumes),
            top.volumes.len() as u64,
        ),
        (
            SectionKind::LinkBounds,
            bytemuck::cast_slice(link_bounds),
            link_bounds.len() as u64,
        ),
        (
            SectionKind::WideNodes,
            bytemuck::cast_slice(wide.0),
            wide.0.len() as u64,
        ),
        (
            SectionKind::WideLinks,
            bytemuck::cast_slice(wide.1),
            wide.1.len() as u64,
        ),
        (
            SectionKind::Ropes,
            bytemuck::cast_slice(top.ropes),
            top.ropes.len() as u64,
        ),
        (
            SectionKind::Prims,
            bytemuck::cast_slice(prims.unwrap_or(&[])),
            prims.map_or(0, |p| p.len() as u64),
        ),
        (
            SectionKind::Geometries,
            bytemuck::cast_slice(geometries),
            geometries.len() as u64,
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit of one solid leaf holding `n` copies of one triangle (all with primitive id 0:
    /// the most compressible block there is).
    fn one_leaf(n: u32) -> UnitParts {
        let tri = TriRecord {
            v: [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            prim: 0,
        };
        let mut refs: Vec<u32> = Vec::new();
        if n > MAX_INLINE_REFS {
            refs.push(n);
        }
        refs.extend(0..n);
        UnitParts {
            levels: vec![LevelEntry {
                node_count: 1,
                internal_count: 0,
                node_start: 0,
                rank_start: 0,
            }],
            nodes: vec![NodeRecord::solid(0, n, LeafBounds::FULL)],
            ranks: vec![RankWord {
                internal: 0,
                rank: 0,
            }],
            volumes: Vec::new(),
            refs,
            triangles: vec![tri; n as usize],
            cluster_nodes: Vec::new(),
            groups: Vec::new(),
            ropes: Vec::new(),
            occluder_nodes: Vec::new(),
            occluders: Vec::new(),
        }
    }

    /// The writer refuses a block a reader would refuse, naming the leaf that made it so, rather
    /// than writing a file the tracer rejects (before, a leaf of millions of copies of one
    /// triangle gave a file with a 1.1 GB block).
    #[test]
    fn a_block_past_the_limit_is_refused_at_write() {
        let unit = one_leaf(500);
        let opts = BlockOptions::default();
        let size = store_block(unit.as_ref(), 3, 0, &opts)
            .unwrap()
            .entry
            .raw_len;
        assert!(store_block_within(unit.as_ref(), 3, 0, &opts, size).is_ok());
        let e = store_block_within(unit.as_ref(), 3, 0, &opts, size - 1)
            .err()
            .expect("refused")
            .to_string();
        assert!(
            e.contains("a leaf at level 3 holds 500 triangle references"),
            "{e}"
        );
    }

    /// A block is stored compressed when that is smaller and within [`MAX_ZSTD_RATIO`], which
    /// a reader enforces; else raw, which every reader reads.
    #[test]
    fn blocks_are_compressed_within_the_ratio_only() {
        assert!(worth_compressing(1000, 999));
        assert!(!worth_compressing(1000, 1000));
        assert!(worth_compressing(64 * 100, 100));
        assert!(!worth_compressing(64 * 100 + 1, 100));
        assert!(!worth_compressing(u64::MAX, 0));
        // A real block: copies of one triangle compress well, and within the ratio (its
        // references, distinct and increasing, keep it there).
        let opts = BlockOptions {
            compress: Some(3),
            ..BlockOptions::default()
        };
        let b = store_block(one_leaf(20_000).as_ref(), 0, 0, &opts).unwrap();
        assert_eq!(b.entry.codec, CODEC_ZSTD);
        assert!(b.entry.raw_len > 8 * b.entry.stored_len, "{:?}", b.entry);
        assert!(b.entry.raw_len <= b.entry.stored_len * MAX_ZSTD_RATIO);
    }
}
