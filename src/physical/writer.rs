//! Writing an `.oavm` file: laying the sections out (spec §2–§3) and replacing the destination
//! atomically.

use std::io::Write;
use std::path::Path;

use bytemuck::Zeroable;

use super::file::AlignedBytes;
use super::format::*;
use crate::error::Error;
use crate::mapping::morton::LATTICE_BITS;

/// A whole tree as the in-memory builder lays it out: every level, node, volume, reference and
/// triangle in one flat set of arrays (the layout of a single unit, spec §4–§6), plus what the
/// header says about it. The writer splits it into blocks ([`super::blocks`]).
#[derive(Clone, Debug, Default)]
pub struct TreeParts {
    pub root_min: [f64; 3],
    pub root_size: f64,
    pub mesh_min: [f32; 3],
    pub mesh_max: [f32; 3],
    pub input_triangles: u64,
    pub empty_leaves: u64,
    pub solid_leaves: u64,
    pub max_depth: u32,
    pub leaf_size: u32,
    pub merged: bool,
    pub levels: Vec<LevelEntry>,
    pub nodes: Vec<NodeRecord>,
    pub ranks: Vec<RankWord>,
    pub volumes: Vec<VolumeRecord>,
    pub refs: Vec<u32>,
    pub triangles: Vec<TriRecord>,
}

impl TreeParts {
    /// The header fields of the tree.
    pub fn meta(&self) -> FileMeta {
        FileMeta {
            root_min: self.root_min,
            root_size: self.root_size,
            mesh_min: self.mesh_min,
            mesh_max: self.mesh_max,
            input_triangles: self.input_triangles,
            stored_triangles: self.triangles.len() as u64,
            empty_leaves: self.empty_leaves,
            solid_leaves: self.solid_leaves,
            level_count: self.levels.len() as u32,
            max_depth: self.max_depth,
            leaf_size: self.leaf_size,
            merged: self.merged,
        }
    }

    /// The tree as one unit (its arrays, borrowed).
    pub fn unit(&self) -> UnitRef<'_> {
        UnitRef {
            levels: &self.levels,
            nodes: &self.nodes,
            ranks: &self.ranks,
            volumes: &self.volumes,
            refs: &self.refs,
            triangles: &self.triangles,
        }
    }
}

/// What the header records about the tree (spec §2).
#[derive(Clone, Copy, Debug, Default)]
pub struct FileMeta {
    pub root_min: [f64; 3],
    pub root_size: f64,
    pub mesh_min: [f32; 3],
    pub mesh_max: [f32; 3],
    pub input_triangles: u64,
    pub stored_triangles: u64,
    pub empty_leaves: u64,
    pub solid_leaves: u64,
    /// Levels of the whole tree (top and blocks).
    pub level_count: u32,
    pub max_depth: u32,
    pub leaf_size: u32,
    pub merged: bool,
}

/// The records of one unit: the top tree, or the subtrees of one block (spec §7, §8).
#[derive(Clone, Debug, Default)]
pub struct UnitParts {
    pub levels: Vec<LevelEntry>,
    pub nodes: Vec<NodeRecord>,
    pub ranks: Vec<RankWord>,
    pub volumes: Vec<VolumeRecord>,
    pub refs: Vec<u32>,
    pub triangles: Vec<TriRecord>,
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
}

/// How blocks are made and stored.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BlockOptions {
    /// Target raw size of a block, bytes: subtrees are grouped into blocks of about this size
    /// (a single leaf larger than it gets a block of its own).
    pub block_size: u64,
    /// zstd level for blocks (`None`: raw). A block that does not shrink is stored raw.
    pub compress: Option<i32>,
}

/// Default target block size: 256 KiB, a few dozen disk pages and a few thousand triangles;
/// small enough that a tight memory budget holds many blocks, large enough that the directory
/// and top tree stay small (about 1/5000 of the file).
pub const DEFAULT_BLOCK_SIZE: u64 = 256 * 1024;
/// Default zstd level of `--compress`.
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;

impl BlockOptions {
    pub fn validate(&self) -> Result<(), Error> {
        if !(4096..=MAX_BLOCK_RAW_LEN / 4).contains(&self.block_size) {
            return Err(Error::Invalid(format!(
                "--block-size {} must be between 4 KiB and {} MiB",
                self.block_size,
                (MAX_BLOCK_RAW_LEN / 4) >> 20
            )));
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
}

/// The raw bytes of a block (spec §8): header, level table, nodes, ranks, volumes, refs,
/// triangles, each part at a multiple of 64 bytes from the start.
pub fn encode_block(unit: UnitRef<'_>, root_level: u32, id: u32) -> Vec<u8> {
    let header = BlockHeader {
        tag: BLOCK_TAG,
        level_count: unit.levels.len() as u32,
        root_level,
        root_count: unit.levels.first().map_or(0, |l| l.node_count as u32),
        node_count: unit.nodes.len() as u64,
        rank_count: unit.ranks.len() as u64,
        volume_count: unit.volumes.len() as u64,
        ref_count: unit.refs.len() as u64,
        triangle_count: unit.triangles.len() as u64,
        block_id: id as u64,
    };
    let (ranges, len) = block_layout(&header).expect("block counts fit in memory");
    let mut out = vec![0u8; len as usize];
    out[..std::mem::size_of::<BlockHeader>()].copy_from_slice(bytemuck::bytes_of(&header));
    let parts: [&[u8]; 6] = [
        bytemuck::cast_slice(unit.levels),
        bytemuck::cast_slice(unit.nodes),
        bytemuck::cast_slice(unit.ranks),
        bytemuck::cast_slice(unit.volumes),
        bytemuck::cast_slice(unit.refs),
        bytemuck::cast_slice(unit.triangles),
    ];
    for (r, bytes) in ranges.iter().zip(parts) {
        out[r.start as usize..r.end as usize].copy_from_slice(bytes);
    }
    out
}

/// Encodes block `id` and stores it as `opts` say: zstd-compressed if that makes it smaller.
pub fn store_block(
    unit: UnitRef<'_>,
    root_level: u32,
    id: u32,
    opts: &BlockOptions,
) -> Result<StoredBlock, Error> {
    let root_bounds = super::bounds::root_bounds(unit.levels, unit.nodes)
        .map_err(|e| Error::Build(format!("block {id}: {e}")))?;
    let raw = encode_block(unit, root_level, id);
    let raw_len = raw.len() as u64;
    let (codec, bytes) = match opts.compress {
        Some(level) => {
            let z = zstd::bulk::compress(&raw, level)
                .map_err(|e| Error::Build(format!("compressing block {id}: {e}")))?;
            if z.len() < raw.len() {
                (CODEC_ZSTD, z)
            } else {
                (CODEC_RAW, raw)
            }
        }
        None => (CODEC_RAW, raw),
    };
    Ok(StoredBlock {
        entry: BlockEntry {
            offset: 0,
            stored_len: bytes.len() as u64,
            raw_len,
            codec,
            root_level,
            root_count: unit.levels.first().map_or(0, |l| l.node_count as u32),
            triangles: unit.triangles.len() as u32,
            checksum: checksum(&bytes),
        },
        bytes,
        entry_id: id,
        root_bounds,
    })
}

/// Where the writer's bytes go: a growing buffer (files built in memory) or a file.
pub trait Sink {
    fn append(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Overwrites bytes already appended, at `offset` (the header, written last).
    fn patch(&mut self, offset: u64, bytes: &[u8]) -> std::io::Result<()>;
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
}

/// Writes a version-2 file in one pass (spec §2): a placeholder header and section table, the
/// blocks as they come, then the block directory and the top tree, then the real header.
/// Nothing but the blocks is held, and those only until they are written.
pub struct FileWriter<S: Sink> {
    sink: S,
    at: u64,
    blocks_start: u64,
    directory: Vec<BlockEntry>,
    max_raw: u64,
    block_triangles: u64,
    compressed: bool,
    /// The roots' bounds of every block written, block after block; `bounds_start[b]` is where
    /// block `b`'s begin.
    bounds: Vec<LinkBounds>,
    bounds_start: Vec<usize>,
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
            max_raw: 0,
            block_triangles: 0,
            compressed: false,
            bounds: Vec::new(),
            bounds_start: Vec::new(),
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

    /// Blocks written so far (the id the next one gets).
    pub fn block_count(&self) -> u32 {
        self.directory.len() as u32
    }

    /// Bytes written so far.
    pub fn bytes_written(&self) -> u64 {
        self.at
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
        let align = if block.entry.codec == CODEC_RAW {
            RAW_BLOCK_ALIGN
        } else {
            SECTION_ALIGN
        };
        self.pad_to(align)?;
        let mut entry = block.entry;
        entry.offset = self.at;
        self.sink.append(&block.bytes)?;
        self.at += block.bytes.len() as u64;
        self.max_raw = self.max_raw.max(entry.raw_len);
        self.block_triangles += entry.triangles as u64;
        self.compressed |= entry.codec != CODEC_RAW;
        self.directory.push(entry);
        self.bounds_start.push(self.bounds.len());
        self.bounds.extend_from_slice(&block.root_bounds);
        Ok(self.directory.len() as u32 - 1)
    }

    /// The link bounds section (spec §8.1): for each top-tree node, its root's bounds if it is a
    /// link, else zero.
    fn link_bounds(&self, nodes: &[NodeRecord]) -> std::io::Result<Vec<LinkBounds>> {
        nodes
            .iter()
            .map(|rec| match rec.kind() {
                Some(NodeKind::Link { block, root }) => self
                    .bounds_start
                    .get(block as usize)
                    .and_then(|&s| {
                        let end = self
                            .bounds_start
                            .get(block as usize + 1)
                            .copied()
                            .unwrap_or(self.bounds.len());
                        self.bounds[s..end].get(root as usize)
                    })
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
    pub fn finish(mut self, meta: &FileMeta, top: UnitRef<'_>) -> std::io::Result<(S, u64)> {
        let mut entries = [SectionEntry::zeroed(); SectionKind::ALL.len()];
        entries[0] = SectionEntry {
            kind: SectionKind::Blocks as u32,
            codec: 0,
            offset: self.blocks_start,
            length: self.at - self.blocks_start,
            count: self.directory.len() as u64,
            block_directory: 0,
            checksum: 0,
        };
        let directory = std::mem::take(&mut self.directory);
        let link_bounds = self.link_bounds(top.nodes)?;
        let sections: [(SectionKind, &[u8], u64); 6] = [
            (
                SectionKind::Directory,
                bytemuck::cast_slice(&directory),
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
                bytemuck::cast_slice(&link_bounds),
                link_bounds.len() as u64,
            ),
        ];
        for (i, (kind, bytes, count)) in sections.into_iter().enumerate() {
            self.pad_to(SECTION_ALIGN)?;
            entries[i + 1] = SectionEntry {
                kind: kind as u32,
                codec: 0,
                offset: self.at,
                length: bytes.len() as u64,
                count,
                block_directory: 0,
                checksum: checksum(bytes),
            };
            self.sink.append(bytes)?;
            self.at += bytes.len() as u64;
        }
        let file_size = self.at;
        let mut flags = if meta.merged { FLAG_MERGED } else { 0 };
        if self.compressed {
            flags |= FLAG_COMPRESSED;
        }
        let header_size = std::mem::size_of::<Header>() as u64;
        let mut header = Header {
            magic: MAGIC,
            version: VERSION,
            flags,
            header_size: header_size as u32,
            section_count: SectionKind::ALL.len() as u32,
            section_table_offset: header_size,
            file_size,
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
            max_block_raw_len: self.max_raw,
            block_triangles: self.block_triangles,
            stored_triangles: meta.stored_triangles,
            reserved: [0; 10],
            checksum: 0,
        };
        let table: &[u8] = bytemuck::cast_slice(&entries);
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        hasher.update(&bytemuck::bytes_of(&header)[..HEADER_CHECKED_LEN]);
        hasher.update(table);
        header.checksum = hasher.digest();
        self.sink.patch(0, bytemuck::bytes_of(&header))?;
        self.sink.patch(header_size, table)?;
        Ok((self.sink, file_size))
    }
}

/// Lays a whole in-memory tree out as the bytes of a file: split into blocks as `opts` say
/// ([`super::blocks::partition`]), blocks encoded in parallel.
pub fn encode_with(parts: &TreeParts, opts: &BlockOptions) -> Result<AlignedBytes, Error> {
    let mut w = FileWriter::new(Vec::new()).map_err(|e| Error::Build(e.to_string()))?;
    let top = write_tree(parts, opts, &mut w)?;
    let (bytes, _) = w
        .finish(&parts.meta(), top.as_ref())
        .map_err(|e| Error::Build(e.to_string()))?;
    Ok(AlignedBytes::from_slice(&bytes))
}

/// [`encode_with`] with the default block options; panics only if the tree's own indices are
/// inconsistent (a builder bug), which `encode_with` reports as an error.
pub fn encode(parts: &TreeParts) -> AlignedBytes {
    encode_with(parts, &BlockOptions::default()).expect("a consistent tree encodes")
}

/// Splits `parts` into blocks, writes them to `w` and returns the top tree.
pub fn write_tree<S: Sink>(
    parts: &TreeParts,
    opts: &BlockOptions,
    w: &mut FileWriter<S>,
) -> Result<UnitParts, Error> {
    use rayon::prelude::*;
    let first = w.block_count();
    let split = super::blocks::partition(parts.unit(), 0, &[0], opts.block_size, first)?;
    // Encode (and compress) in parallel, a bounded batch at a time, writing in order.
    for batch in split.blocks.chunks(64) {
        let stored: Vec<StoredBlock> = batch
            .par_iter()
            .map(|b| store_block(b.unit.as_ref(), b.root_level, b.id, opts))
            .collect::<Result<_, _>>()?;
        for s in stored {
            let expected = s.entry_id;
            let id = w.push(s).map_err(|e| Error::Build(e.to_string()))?;
            debug_assert_eq!(id, expected);
        }
    }
    super::blocks::assemble_top(split.top)
}

/// `e` without the temporary file's path that `tempfile` appends to its errors (as
/// ` at path "..."`, in a wrapper that exposes neither the inner error nor the OS code).
fn os_error(e: std::io::Error) -> std::io::Error {
    if e.raw_os_error().is_some() {
        return e;
    }
    let text = e.to_string();
    match text.split_once(" at path ") {
        Some((msg, _)) => std::io::Error::new(e.kind(), msg.to_string()),
        None => e,
    }
}

/// Writes `bytes` to `path` atomically: into a temporary file in the same directory, flushed to
/// disk, then renamed over `path`. On any error the temporary file is removed and `path` is left
/// as it was, so no partial output is ever visible.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    write_atomic_with(path, |file| file.write_all(bytes))
}

/// Creates `path` atomically from what `fill` writes into a fresh temporary file in the same
/// directory: flushed to disk, then renamed over `path`. On any error (of `fill` too) the
/// temporary file is removed and `path` is left as it was.
pub fn write_atomic_with<T>(
    path: &Path,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<T>,
) -> Result<T, Error> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // Errors name the file asked for, never the temporary one (whose name means nothing to the
    // user); the OS error alone says what went wrong.
    let err = |e: std::io::Error| Error::io(path, os_error(e));
    let mut builder = tempfile::Builder::new();
    builder.prefix(".oavm-pack-").suffix(".tmp");
    // A temporary file is private (0600); the output should get the permissions of any new
    // file (0666 less the umask), which the rename keeps.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir).map_err(err)?;
    let out = fill(tmp.as_file_mut()).map_err(err)?;
    tmp.as_file().sync_all().map_err(err)?;
    tmp.persist(path).map_err(|e| err(e.error))?;
    Ok(out)
}

/// Writes the file of `parts` to `path` atomically, split into blocks as `opts` say; returns
/// its size and block count. Only one batch of encoded blocks is held at a time.
pub fn write_file(
    path: &Path,
    parts: &TreeParts,
    opts: &BlockOptions,
) -> Result<(u64, u32), Error> {
    let mut build_error = None;
    let result = write_atomic_with(path, |file| {
        let sink = FileSink {
            out: std::io::BufWriter::with_capacity(1 << 20, file.try_clone()?),
        };
        let mut w = FileWriter::new(sink)?;
        let top = match write_tree(parts, opts, &mut w) {
            Ok(top) => top,
            Err(e) => {
                build_error = Some(e);
                return Err(std::io::Error::other("build failed"));
            }
        };
        let blocks = w.block_count();
        let (mut sink, size) = w.finish(&parts.meta(), top.as_ref())?;
        sink.out.flush()?;
        Ok((size, blocks))
    });
    match (build_error, result) {
        (Some(e), _) => Err(e),
        (None, r) => r,
    }
}
