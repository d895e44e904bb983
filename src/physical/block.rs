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
    /// The header's flag `LEAN`: blocks may be [`CODEC_LEAN`].
    lean: bool,
    /// Groups per chunk (the header's `chunk_groups`; 0 in a file of lists).
    chunk_groups: u32,
}

impl BlockReader {
    pub fn new<D: AsRef<[u8]>>(file: &OavmFile<D>) -> BlockReader {
        let s = file.section(SectionKind::Blocks);
        let h = file.header();
        BlockReader {
            section: (s.offset, s.offset + s.length),
            max_raw_len: h.max_block_raw_len,
            compressed: h.flags & FLAG_COMPRESSED != 0,
            lean: h.flags & FLAG_LEAN != 0,
            chunk_groups: h.chunk_groups,
        }
    }

    /// A reader for a file whose blocks section is `section` (`start..end`), for tests that
    /// build block files of their own.
    #[cfg(test)]
    pub(crate) fn for_section(
        section: (u64, u64),
        max_raw_len: u64,
        compressed: bool,
        chunk_groups: u32,
    ) -> Self {
        BlockReader {
            section,
            max_raw_len,
            compressed,
            lean: false,
            chunk_groups,
        }
    }

    /// Groups per chunk (the header's `chunk_groups`).
    pub fn chunk_groups(&self) -> u32 {
        self.chunk_groups
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
    /// `COMPRESSED`); `raw_len <= max_block_raw_len`; its head within its bytes (a head that
    /// ends before the block ends is followed by whole groups, from a multiple of
    /// [`GROUPS_ALIGN`]); a raw block starts on a page ([`RAW_BLOCK_ALIGN`]) and has
    /// `raw_len == stored_len` and `head_raw_len == head_stored_len`; a zstd head decodes to at
    /// most [`MAX_ZSTD_RATIO`] times what it stores.
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
                if e.raw_len != e.stored_len || e.head_raw_len != e.head_stored_len {
                    return Err(format!(
                        "raw block with raw_len {} != stored_len {} or a head of {} raw bytes \
                         stored in {}",
                        e.raw_len, e.stored_len, e.head_raw_len, e.head_stored_len
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
            CODEC_ZSTD if !zstd_head_fits(e.head_raw_len, e.head_stored_len) => Err(format!(
                "a zstd head of {} bytes claims to decode to {} bytes, more than \
                     {MAX_ZSTD_RATIO} times its size and a page",
                e.head_stored_len, e.head_raw_len
            )),
            CODEC_ZSTD => Ok(()),
            CODEC_LEAN if !self.lean || !self.compressed => Err(
                "a lean block in a file whose header does not say blocks may be lean and coded"
                    .into(),
            ),
            CODEC_LEAN if e.head_raw_len != e.head_stored_len || e.head_raw_len == e.raw_len => {
                Err(format!(
                    "a lean block with a head of {} raw bytes stored in {}, of {} raw bytes: \
                     its head is stored raw, and it has groups",
                    e.head_raw_len, e.head_stored_len, e.raw_len
                ))
            }
            CODEC_LEAN if !e.offset.is_multiple_of(RAW_BLOCK_ALIGN) => Err(format!(
                "lean block at offset {}, not a multiple of {RAW_BLOCK_ALIGN}",
                e.offset
            )),
            CODEC_LEAN => Ok(()),
            codec => Err(format!("unknown codec {codec}")),
        }?;
        if e.head_stored_len > e.stored_len || e.head_raw_len > e.raw_len {
            return Err(format!(
                "a head of {} stored / {} raw bytes in a block of {} / {}",
                e.head_stored_len, e.head_raw_len, e.stored_len, e.raw_len
            ));
        }
        let groups = e.raw_len - e.head_raw_len;
        if groups > 0
            && (!e.head_raw_len.is_multiple_of(GROUPS_ALIGN)
                || !groups.is_multiple_of(std::mem::size_of::<TriGroup>() as u64)
                || self.chunk_groups == 0)
        {
            return Err(format!(
                "groups of {groups} bytes from {}: not whole groups from a multiple of \
                 {GROUPS_ALIGN}, or in a file without chunks",
                e.head_raw_len
            ));
        }
        Ok(())
    }

    /// The stored bytes of a block whose entry [`Self::check_entry`] accepted (empty if it
    /// did not).
    pub fn stored<'a>(&self, bytes: &'a [u8], e: &BlockEntry) -> &'a [u8] {
        let off = e.offset as usize;
        bytes
            .get(off..off.saturating_add(e.stored_len as usize))
            .unwrap_or(&[])
    }

    /// Checks the xxh3 of a block's head against its entry and, for a raw block, every
    /// chunk's against the head's chunk table ([`Self::check_chunks`]), so that every stored
    /// byte is checked. A zstd block's chunks are checked as [`Self::decode`] decodes them.
    pub fn check_sum(&self, e: &BlockEntry, stored: &[u8]) -> Result<(), String> {
        let head = stored.get(..e.head_stored_len as usize).unwrap_or(&[]);
        let computed = checksum(head);
        if computed != e.checksum {
            return Err(format!(
                "checksum mismatch (stored {:#018x}, computed {computed:#018x}): the file is \
                 corrupt",
                e.checksum
            ));
        }
        if e.codec == CODEC_RAW && e.head_raw_len < e.raw_len {
            let table = self.chunk_table(e, head)?;
            for (c, ce) in table.iter().enumerate() {
                let bytes = chunk_bytes(e, stored, ce);
                check_chunk_sum(c, ce, bytes)?;
            }
        }
        Ok(())
    }

    /// The chunk table of a block from its decoded head (spec §8.3), checked against the
    /// entry: `ceil(groups / chunk_groups)` chunks, each stored right after the one before
    /// (the first right after the head), the last ending where the block does, each as long
    /// as its groups (raw) or shorter and within [`MAX_ZSTD_RATIO`] of them (zstd; only in a
    /// zstd block).
    pub fn chunk_table<'h>(
        &self,
        e: &BlockEntry,
        head: &'h [u8],
    ) -> Result<&'h [ChunkEntry], String> {
        let groups = (e.raw_len - e.head_raw_len) / std::mem::size_of::<TriGroup>() as u64;
        let hsize = std::mem::size_of::<BlockHeader>();
        if head.len() < hsize {
            return Err("a head shorter than its header".into());
        }
        let header: BlockHeader = bytemuck::pod_read_unaligned(&head[..hsize]);
        let expected = match self.chunk_groups {
            0 => 0,
            n => groups.div_ceil(n as u64),
        };
        if header.group_count != groups || header.chunk_count != expected {
            return Err(format!(
                "a head with {} groups in {} chunks, where the entry says {groups} groups in {expected}",
                header.group_count, header.chunk_count
            ));
        }
        let ranges = block_layout(&header).ok_or("block counts overflow")?.0;
        let r = &ranges[PART_CHUNKS];
        let table: &[ChunkEntry] = head
            .get(r.start as usize..r.end as usize)
            .and_then(|b| bytemuck::try_cast_slice(b).ok())
            .ok_or("the chunk table lies outside the head, or is not aligned")?;
        let mut next = 0u64;
        let size = std::mem::size_of::<TriGroup>() as u64;
        for (c, ce) in table.iter().enumerate() {
            let first = c as u64 * self.chunk_groups as u64;
            let raw = (groups - first).min(self.chunk_groups as u64) * size;
            let stored = ce.stored_len as u64;
            let fits = match e.codec {
                CODEC_LEAN => stored > 0 && stored <= raw,
                _ if stored == raw => true,
                _ => e.codec == CODEC_ZSTD && stored < raw && raw <= stored * MAX_ZSTD_RATIO,
            };
            if ce.offset as u64 != next || !fits {
                return Err(format!(
                    "chunk {c}: {stored} bytes stored at {} after the head, for {raw} raw bytes \
                     (expected at {next})",
                    ce.offset
                ));
            }
            next += stored;
        }
        if e.head_stored_len + next != e.stored_len {
            return Err(format!(
                "chunks end {} bytes after the head, the block {}",
                next,
                e.stored_len - e.head_stored_len
            ));
        }
        Ok(table)
    }

    /// Decodes a zstd or lean block's stored bytes into `out`, which must be `raw_len` bytes
    /// long: the head's frame, or its raw bytes (a lean block; the caller has checked its
    /// checksum, [`Self::check_sum`]), then each chunk (a lean block's: lean groups, §7.3),
    /// checked against the head's chunk table and decoded (or copied, a raw chunk) into its
    /// place. Each frame must record no content size or exactly its length, and decode to
    /// exactly that: a frame that claims more cannot make the caller allocate or write more.
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
        let (head, groups) = out.split_at_mut(e.head_raw_len as usize);
        let head_stored = stored.get(..e.head_stored_len as usize).unwrap_or(&[]);
        if e.codec == CODEC_LEAN {
            // Checked by `check_entry`: a lean head is stored raw.
            head.copy_from_slice(head_stored.get(..head.len()).ok_or("a head cut short")?);
        } else {
            decode_frame(head_stored, head, dctx, "the directory says head_raw_len")
                .map_err(|w| format!("head: {w}"))?;
        }
        if groups.is_empty() {
            return Ok(());
        }
        let table = self.chunk_table(e, head)?;
        let size = std::mem::size_of::<TriGroup>();
        let per = self.chunk_groups as usize * size;
        for (c, ce) in table.iter().enumerate() {
            let bytes = chunk_bytes(e, stored, ce);
            check_chunk_sum(c, ce, bytes)?;
            let at = c * per;
            let dst = &mut groups[at..(at + per).min(raw_len - e.head_raw_len as usize)];
            if e.codec == CODEC_LEAN {
                super::lean::decode_chunk(bytes, dst).map_err(|w| format!("chunk {c}: {w}"))?;
            } else if bytes.len() == dst.len() {
                dst.copy_from_slice(bytes);
            } else {
                decode_frame(bytes, dst, dctx, "its groups take")
                    .map_err(|w| format!("chunk {c}: {w}"))?;
            }
        }
        Ok(())
    }

    /// Reads block `id` of the file `bytes` whole, as the pager admits it with every check
    /// on: its entry, its checksums, its decoding. The raw bytes are borrowed from `bytes` for
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

/// The stored bytes of chunk `ce` of a block whose stored bytes are `stored` (empty if they
/// lie outside: [`BlockReader::chunk_table`] has checked they do not).
fn chunk_bytes<'s>(e: &BlockEntry, stored: &'s [u8], ce: &ChunkEntry) -> &'s [u8] {
    let at = e.head_stored_len as usize + ce.offset as usize;
    stored.get(at..at + ce.stored_len as usize).unwrap_or(&[])
}

/// Checks the xxh3 of chunk `c`'s stored bytes against its entry.
fn check_chunk_sum(c: usize, ce: &ChunkEntry, bytes: &[u8]) -> Result<(), String> {
    let computed = checksum(bytes);
    if computed != ce.checksum {
        return Err(format!(
            "chunk {c}: checksum mismatch (stored {:#018x}, computed {computed:#018x}): the file \
             is corrupt",
            ce.checksum
        ));
    }
    Ok(())
}

/// Decodes one zstd frame into `out`, exactly filling it (`what` names `out`'s length in an
/// error: "its groups take").
pub(crate) fn decode_frame(
    stored: &[u8],
    out: &mut [u8],
    dctx: &mut zstd::bulk::Decompressor<'_>,
    what: &str,
) -> Result<(), String> {
    let raw_len = out.len();
    match zstd::zstd_safe::get_frame_content_size(stored) {
        Ok(Some(n)) if n != raw_len as u64 => {
            return Err(format!(
                "the zstd frame's content size is {n} bytes, {what} {raw_len}"
            ));
        }
        Ok(_) => {}
        Err(_) => return Err("not a zstd frame (bad frame header)".into()),
    }
    let n = dctx
        .decompress_to_buffer(stored, out)
        .map_err(|err| format!("zstd: {err} ({raw_len} bytes)"))?;
    if n != raw_len {
        return Err(format!(
            "the zstd frame decodes to {n} bytes, {what} {raw_len}"
        ));
    }
    Ok(())
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
    /// The chunk table (spec §8.3): where each chunk of the groups is stored.
    pub chunks: &'a [ChunkEntry],
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
        Self::parse_as(raw, id, entry, false)
    }

    /// [`Self::parse`] of a block's head alone (spec §8.3: its bytes before the groups), whose
    /// entry gives the head's lengths as the block's (`raw_len = head_raw_len`): the same
    /// checks, and no groups.
    pub fn parse_head(
        raw: &'a [u8],
        id: u32,
        entry: &BlockEntry,
    ) -> Result<BlockView<'a>, &'static str> {
        Self::parse_as(raw, id, entry, true)
    }

    fn parse_as(
        raw: &'a [u8],
        id: u32,
        entry: &BlockEntry,
        head_only: bool,
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
        let head_end = match header.group_count {
            0 => len,
            _ => ranges[PART_GROUPS].start,
        };
        if (if head_only { head_end } else { len }) != raw.len() as u64 {
            return Err("block counts do not match its length");
        }
        if head_end != entry.head_raw_len {
            return Err("block head length differs from its directory entry");
        }
        let cast = |i: usize| match head_only && i == PART_GROUPS {
            true => &raw[..0],
            false => &raw[ranges[i].start as usize..ranges[i].end as usize],
        };
        let (
            Ok(levels),
            Ok(nodes),
            Ok(ranks),
            Ok(volumes),
            Ok(refs),
            Ok(triangles),
            Ok(cluster_nodes),
            Ok(ropes),
            Ok(occluder_nodes),
            Ok(occluders),
            Ok(chunks),
            Ok(groups),
        ) = (
            bytemuck::try_cast_slice::<u8, LevelEntry>(cast(PART_LEVELS)),
            bytemuck::try_cast_slice::<u8, NodeRecord>(cast(PART_NODES)),
            bytemuck::try_cast_slice::<u8, RankWord>(cast(PART_RANKS)),
            bytemuck::try_cast_slice::<u8, VolumeRecord>(cast(PART_VOLUMES)),
            bytemuck::try_cast_slice::<u8, u32>(cast(PART_REFS)),
            bytemuck::try_cast_slice::<u8, TriRecord>(cast(PART_TRIANGLES)),
            bytemuck::try_cast_slice::<u8, ClusterNode>(cast(PART_WIDE)),
            bytemuck::try_cast_slice::<u8, RopeRecord>(cast(PART_ROPES)),
            bytemuck::try_cast_slice::<u8, OccluderNode>(cast(PART_OCCLUDER_NODES)),
            bytemuck::try_cast_slice::<u8, TriRecord>(cast(PART_OCCLUDERS)),
            bytemuck::try_cast_slice::<u8, ChunkEntry>(cast(PART_CHUNKS)),
            bytemuck::try_cast_slice::<u8, TriGroup>(cast(PART_GROUPS)),
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
            chunks,
        })
    }
}
