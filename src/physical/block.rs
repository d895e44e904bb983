//! Reading a block (format-spec §8.2-§8.3, §11 "Paging"): the checks of its directory entry,
//! its checksum, its decoding, and the typed view of its records. This is the one way a block
//! is read: the pager uses it on every admission and `verify` on every block, so both accept
//! and refuse exactly the same blocks.

use std::ops::Deref;

use super::file::{AlignedBytes, OavmFile};
use super::format::*;

/// A block that cannot be read: a bad directory entry, a checksum mismatch, a frame that does
/// not decode to its block, records that break the layout. Names the block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlockError {
    pub block: u32,
    pub what: String,
}

impl std::fmt::Display for BlockError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "block {}: {}", self.block, self.what)
    }
}

impl std::error::Error for BlockError {}

/// How the blocks of one opened file are read: what the checks of spec §11 ("Paging") need to
/// know of the file. Plain data (the file's bytes are passed to each call), so its owner can
/// keep it beside the file.
#[derive(Clone, Copy, Debug)]
pub struct BlockReader {
    /// The blocks section, `start..end`.
    section: (u64, u64),
    max_raw_len: u64,
    compressed: bool,
}

impl BlockReader {
    pub fn new<D: AsRef<[u8]>>(file: &OavmFile<D>) -> BlockReader {
        let s = file.section(SectionKind::Blocks);
        let h = file.header();
        BlockReader {
            section: (s.offset, s.offset + s.length),
            max_raw_len: h.max_block_raw_len,
            compressed: h.flags & FLAG_COMPRESSED != 0,
        }
    }

    /// A reader for a file whose blocks section is `section` (`start..end`), for tests that
    /// build block files of their own.
    #[cfg(test)]
    pub(crate) fn for_section(section: (u64, u64), max_raw_len: u64, compressed: bool) -> Self {
        BlockReader {
            section,
            max_raw_len,
            compressed,
        }
    }

    /// The largest `raw_len` a block may have (the header's `max_block_raw_len`).
    pub fn max_raw_len(&self) -> u64 {
        self.max_raw_len
    }

    /// Whether the file may hold zstd blocks (its `COMPRESSED` flag).
    pub fn compressed(&self) -> bool {
        self.compressed
    }

    /// Spec §11, paging: the entry of a block, checked without reading the block. Its stored
    /// bytes lie inside the blocks section; its codec is known (zstd only in a file flagged
    /// `COMPRESSED`); `raw_len <= max_block_raw_len`; a raw block starts on a page
    /// ([`RAW_BLOCK_ALIGN`]) and has `raw_len == stored_len`; a zstd block decodes to at most
    /// [`MAX_ZSTD_RATIO`] times what it stores.
    pub fn check_entry(&self, e: &BlockEntry) -> Result<(), String> {
        if e.is_free() {
            return Err("a free entry (spec §8.2): no block is stored there".into());
        }
        let (start, end) = self.section;
        match e.offset.checked_add(e.stored_len) {
            Some(stop) if e.offset >= start && stop <= end => {}
            _ => {
                return Err(format!(
                    "stored bytes {}..{}+{} lie outside the blocks section ({start}..{end})",
                    e.offset, e.offset, e.stored_len
                ));
            }
        }
        if e.raw_len > self.max_raw_len {
            return Err(format!(
                "raw_len {} exceeds the header's largest block, {} bytes",
                e.raw_len, self.max_raw_len
            ));
        }
        match e.codec {
            CODEC_RAW => {
                if e.raw_len != e.stored_len {
                    return Err(format!(
                        "raw block with raw_len {} != stored_len {}",
                        e.raw_len, e.stored_len
                    ));
                }
                if !e.offset.is_multiple_of(RAW_BLOCK_ALIGN) {
                    return Err(format!(
                        "raw block at offset {}, not a multiple of {RAW_BLOCK_ALIGN}",
                        e.offset
                    ));
                }
                Ok(())
            }
            CODEC_ZSTD if !self.compressed => {
                Err("a zstd block in a file whose header says no block is compressed".into())
            }
            CODEC_ZSTD if e.raw_len > e.stored_len.saturating_mul(MAX_ZSTD_RATIO) => Err(format!(
                "a zstd block of {} bytes claims to decode to {} bytes, more than \
                 {MAX_ZSTD_RATIO} times its size",
                e.stored_len, e.raw_len
            )),
            CODEC_ZSTD => Ok(()),
            codec => Err(format!("unknown codec {codec}")),
        }
    }

    /// The stored bytes of a block whose entry [`Self::check_entry`] accepted (empty if it
    /// did not).
    pub fn stored<'a>(&self, bytes: &'a [u8], e: &BlockEntry) -> &'a [u8] {
        let off = e.offset as usize;
        bytes
            .get(off..off.saturating_add(e.stored_len as usize))
            .unwrap_or(&[])
    }

    /// Checks the xxh3 of a block's stored bytes against its entry.
    pub fn check_sum(&self, e: &BlockEntry, stored: &[u8]) -> Result<(), String> {
        let computed = checksum(stored);
        if computed != e.checksum {
            return Err(format!(
                "checksum mismatch (stored {:#018x}, computed {computed:#018x}): the file is \
                 corrupt",
                e.checksum
            ));
        }
        Ok(())
    }

    /// Decodes a zstd block's stored bytes into `out`, which must be `raw_len` bytes long. The
    /// frame must record no content size or exactly `raw_len`, and decode to exactly `raw_len`
    /// bytes: a frame that claims more cannot make the caller allocate or write more.
    pub fn decode(
        &self,
        e: &BlockEntry,
        stored: &[u8],
        out: &mut [u8],
        dctx: &mut zstd::bulk::Decompressor<'_>,
    ) -> Result<(), String> {
        let raw_len = e.raw_len as usize;
        if out.len() != raw_len {
            return Err(format!(
                "a buffer of {} bytes for a block of {raw_len}",
                out.len()
            ));
        }
        match zstd::zstd_safe::get_frame_content_size(stored) {
            Ok(Some(n)) if n != e.raw_len => {
                return Err(format!(
                    "the zstd frame's content size is {n} bytes, the directory says raw_len {}",
                    e.raw_len
                ));
            }
            Ok(_) => {}
            Err(_) => return Err("not a zstd frame (bad frame header)".into()),
        }
        let n = dctx
            .decompress_to_buffer(stored, out)
            .map_err(|err| format!("zstd: {err} (raw_len {raw_len})"))?;
        if n != raw_len {
            return Err(format!(
                "the zstd frame decodes to {n} bytes, the directory says raw_len {raw_len}"
            ));
        }
        Ok(())
    }

    /// Reads block `id` of the file `bytes` whole, as the pager admits it with every check
    /// on: its entry, its checksum, its decoding. The raw bytes are borrowed from `bytes` for
    /// a raw block and decoded into an aligned buffer for a zstd block.
    pub fn read<'a>(
        &self,
        bytes: &'a [u8],
        id: u32,
        e: &BlockEntry,
    ) -> Result<ReadBlock<'a>, BlockError> {
        let fail = |what: String| BlockError { block: id, what };
        self.check_entry(e).map_err(fail)?;
        let stored = self.stored(bytes, e);
        self.check_sum(e, stored).map_err(fail)?;
        if e.codec == CODEC_RAW {
            if !(bytes.as_ptr() as usize).is_multiple_of(std::mem::align_of::<u64>()) {
                return Err(fail("the file's buffer is not 8-aligned".into()));
            }
            return Ok(ReadBlock::Stored(stored));
        }
        let mut out = AlignedBytes::zeroed(e.raw_len as usize);
        let mut dctx = zstd::bulk::Decompressor::new()
            .map_err(|err| fail(format!("cannot create a zstd decompressor: {err}")))?;
        self.decode(e, stored, out.as_mut_slice(), &mut dctx)
            .map_err(fail)?;
        Ok(ReadBlock::Decoded(out))
    }
}

/// A block's raw bytes, 8-aligned, as [`BlockReader::read`] gives them.
pub enum ReadBlock<'a> {
    /// A raw block: its stored bytes, in the file.
    Stored(&'a [u8]),
    /// A zstd block, decoded.
    Decoded(AlignedBytes),
}

impl Deref for ReadBlock<'_> {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            ReadBlock::Stored(bytes) => bytes,
            ReadBlock::Decoded(buf) => buf.as_ref(),
        }
    }
}

/// A block's records, cast in place from its raw bytes (spec §8).
#[derive(Clone, Copy, Debug)]
pub struct BlockView<'a> {
    pub header: BlockHeader,
    pub levels: &'a [LevelEntry],
    pub nodes: &'a [NodeRecord],
    pub ranks: &'a [RankWord],
    pub volumes: &'a [VolumeRecord],
    pub refs: &'a [u32],
    pub triangles: &'a [TriRecord],
    pub cluster_nodes: &'a [ClusterNode],
    pub groups: &'a [TriGroup],
    /// Ropes (spec §8.4): one per node, or none.
    pub ropes: &'a [RopeRecord],
    /// Occluders (spec §8.5): the internal nodes holding some, and their triangles.
    pub occluder_nodes: &'a [OccluderNode],
    pub occluders: &'a [TriRecord],
}

impl<'a> BlockView<'a> {
    /// Spec §8.3, §11 ("every time a walk enters it"): reads the raw bytes of block `id`
    /// (described by `entry`): checks its header against the entry, its layout against its
    /// length and its level table against its counts, all in `O(levels)`, and casts its records
    /// in place. Errors say what is wrong.
    pub fn parse(
        raw: &'a [u8],
        id: u32,
        entry: &BlockEntry,
    ) -> Result<BlockView<'a>, &'static str> {
        let hsize = std::mem::size_of::<BlockHeader>();
        if raw.len() as u64 != entry.raw_len || raw.len() < hsize {
            return Err("block length differs from its directory entry");
        }
        let header: BlockHeader = bytemuck::pod_read_unaligned(&raw[..hsize]);
        if header.tag != BLOCK_TAG {
            return Err("block does not start with its tag");
        }
        if header.block_id != id as u64 {
            return Err("block holds another block's id");
        }
        // A block of clusters counts its groups' lanes in the directory, which only a walk
        // over the groups can check (`verify` does).
        if header.root_level != entry.root_level
            || header.root_count != entry.root_count
            || (header.group_count == 0 && header.triangle_count != entry.triangles as u64)
        {
            return Err("block header differs from its directory entry");
        }
        if header.level_count == 0
            || header.root_count == 0
            || header.root_level as u64 + header.level_count as u64 > MAX_LEVEL as u64 + 1
        {
            return Err("block level count or root level out of range");
        }
        if header.rope_count != 0 && header.rope_count != header.node_count {
            return Err("block rope count is neither 0 nor its node count");
        }
        if (header.occluder_node_count == 0) != (header.occluder_count == 0)
            || header.occluder_node_count > header.node_count
            || header.occluder_count > u32::MAX as u64
        {
            return Err("block occluder counts are inconsistent");
        }
        let Some((ranges, len)) = block_layout(&header) else {
            return Err("block counts overflow");
        };
        if len != raw.len() as u64 {
            return Err("block counts do not match its length");
        }
        let cast = |i: usize| &raw[ranges[i].start as usize..ranges[i].end as usize];
        let (
            Ok(levels),
            Ok(nodes),
            Ok(ranks),
            Ok(volumes),
            Ok(refs),
            Ok(triangles),
            Ok(cluster_nodes),
            Ok(groups),
            Ok(ropes),
            Ok(occluder_nodes),
            Ok(occluders),
        ) = (
            bytemuck::try_cast_slice::<u8, LevelEntry>(cast(0)),
            bytemuck::try_cast_slice::<u8, NodeRecord>(cast(1)),
            bytemuck::try_cast_slice::<u8, RankWord>(cast(2)),
            bytemuck::try_cast_slice::<u8, VolumeRecord>(cast(3)),
            bytemuck::try_cast_slice::<u8, u32>(cast(4)),
            bytemuck::try_cast_slice::<u8, TriRecord>(cast(5)),
            bytemuck::try_cast_slice::<u8, ClusterNode>(cast(6)),
            bytemuck::try_cast_slice::<u8, TriGroup>(cast(7)),
            bytemuck::try_cast_slice::<u8, RopeRecord>(cast(8)),
            bytemuck::try_cast_slice::<u8, OccluderNode>(cast(9)),
            bytemuck::try_cast_slice::<u8, TriRecord>(cast(10)),
        )
        else {
            return Err("block bytes are not aligned");
        };
        let (mut node_start, mut rank_start) = (0u64, 0u64);
        let mut expected = header.root_count as u64;
        for e in levels {
            if e.node_count != expected
                || e.internal_count > e.node_count
                || e.node_start != node_start
                || e.rank_start != rank_start
            {
                return Err("block level table is inconsistent");
            }
            node_start = node_start.saturating_add(e.node_count);
            rank_start = rank_start.saturating_add(e.node_count.div_ceil(64));
            expected = e.internal_count.saturating_mul(8);
            if node_start > header.node_count {
                return Err("block level table is inconsistent");
            }
        }
        if expected != 0 || node_start != header.node_count || rank_start != header.rank_count {
            return Err("block level table is inconsistent");
        }
        Ok(BlockView {
            header,
            levels,
            nodes,
            ranks,
            volumes,
            refs,
            triangles,
            cluster_nodes,
            groups,
            ropes,
            occluder_nodes,
            occluders,
        })
    }
}
