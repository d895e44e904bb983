//! The byte-level part of full verification (spec §11, "Verify"): every section's checksum,
//! zero padding between sections, between blocks and between a block's parts, blocks in order
//! inside the blocks section. With the header checksum (checked at open) and each block's own
//! checksum (checked when the block is read, [`super::block::BlockReader::read`]) they cover
//! every byte of the file. The structural invariants are checked above this layer
//! (`crate::logical::verify`), which drives the whole verification.

use super::file::OavmFile;
use super::format::*;

/// Defects found, in order; at most [`Defects::MAX_LISTED`] are listed, the rest counted.
#[derive(Debug, Default)]
pub struct Defects {
    list: Vec<String>,
    more: usize,
}

impl Defects {
    /// Defects listed before the rest are only counted.
    pub const MAX_LISTED: usize = 50;

    pub fn push(&mut self, d: String) {
        if self.list.len() < Self::MAX_LISTED {
            self.list.push(d);
        } else {
            self.more += 1;
        }
    }

    /// Appends `other`'s defects (listed ones first, as far as room is left).
    pub fn append(&mut self, other: Defects) {
        for d in other.list {
            self.push(d);
        }
        self.more += other.more;
    }

    /// The list, ending with a count of those not listed.
    pub fn into_list(self) -> Vec<String> {
        let mut list = self.list;
        if self.more > 0 {
            list.push(format!("... and {} more defects", self.more));
        }
        list
    }
}

/// Checks the zero bytes after the slot's section table (spec §2.1), every section's checksum (but the blocks',
/// which carry their own), the zero padding between sections, and the buffer's alignment.
/// Returns the sections checked.
pub fn check_sections<D: AsRef<[u8]>>(file: &OavmFile<D>, d: &mut Defects) -> u32 {
    let bytes = file.bytes();
    let header = file.header();
    let slot = file.slot();
    let table_end = header.section_table_offset
        + (SectionKind::count_for(header.flags) * std::mem::size_of::<SectionEntry>()) as u64;
    // The other slot is not this generation's: the previous generation's header, or what an
    // interrupted update left there (in a file as packed, zero, or a torn first update).
    let slot_end = HEADER_SLOTS.get(slot + 1).copied().unwrap_or(DATA_START);
    if let Some(pad) = bytes.get(table_end as usize..slot_end as usize)
        && pad.iter().any(|&b| b != 0)
    {
        d.push(format!(
            "header slot {slot}: bytes {table_end}..{slot_end} after the section table are not zero"
        ));
    }
    let mut covered = None::<u64>;
    let mut checked = 0;
    for kind in SectionKind::for_flags(header.flags) {
        let s = file.section(kind);
        // The data region's own padding is checked with its blocks; the directory starts
        // where it ends.
        if let Some(from) = covered
            && let Some(pad) = bytes.get(from as usize..s.offset as usize)
            && pad.iter().any(|&b| b != 0)
        {
            d.push(format!(
                "padding before the {} section (bytes {from}..{}) is not zero",
                kind.name(),
                s.offset
            ));
        }
        if kind != SectionKind::Blocks {
            let computed = checksum(file.section_bytes(kind));
            if computed != s.checksum {
                d.push(format!(
                    "{} section: checksum mismatch (stored {:#018x}, computed {computed:#018x})",
                    kind.name(),
                    s.checksum
                ));
            }
            covered = Some(s.offset + s.length);
        }
        checked += 1;
    }
    if !file.is_aligned() {
        d.push("the buffer holding the file is not 8-byte aligned; records cannot be read".into());
    }
    checked
}

/// Checks where the blocks and the primitive chunks lie in the data region (spec §2.1, §8.2,
/// §8.6): each inside it, aligned for its kind, none overlapping another; in a file as packed
/// (generation 1) the blocks one after another in directory order, then the chunks in order,
/// with zero bytes between and after them and no free directory entry. Also that
/// `max_block_raw_len` is the largest block's. Returns, per block, whether it is well placed (a
/// misplaced or free entry is not read).
pub fn check_block_placement<D: AsRef<[u8]>>(file: &OavmFile<D>, d: &mut Defects) -> Vec<bool> {
    let bytes = file.bytes();
    let section = *file.section(SectionKind::Blocks);
    let region_end = section.offset + section.length;
    let first_generation = file.header().generation == FIRST_GENERATION;
    let directory = file.directory();
    let chunks: &[PrimChunk] = file.records(SectionKind::Prims);
    let mut placed = Vec::with_capacity(directory.len());
    // (start, end, what) of everything this generation refers to in the region.
    let mut items: Vec<(u64, u64, String)> = Vec::new();
    let mut max_raw = 0u64;
    for (b, e) in directory.iter().enumerate() {
        if e.is_free() {
            if first_generation {
                d.push(format!(
                    "block {b}: a free entry in a generation-1 file (only updates free entries)"
                ));
            }
            placed.push(false);
            continue;
        }
        let align = if e.codec != CODEC_ZSTD {
            RAW_BLOCK_ALIGN
        } else {
            SECTION_ALIGN
        };
        let end = e.offset.checked_add(e.stored_len);
        if e.offset < section.offset
            || !e.offset.is_multiple_of(align)
            || end.is_none_or(|x| x > region_end)
        {
            d.push(format!(
                "block {b}: {} bytes at offset {} are misplaced ({align}-aligned, inside the data region {}..{region_end})",
                e.stored_len, e.offset, section.offset
            ));
            placed.push(false);
            continue;
        }
        items.push((e.offset, end.unwrap_or(e.offset), format!("block {b}")));
        max_raw = max_raw.max(e.raw_len);
        placed.push(true);
    }
    for (c, ch) in chunks.iter().enumerate() {
        let end = ch
            .count
            .checked_mul(std::mem::size_of::<PrimRecord>() as u64)
            .and_then(|n| ch.offset.checked_add(n));
        if ch.offset < section.offset
            || !ch.offset.is_multiple_of(SECTION_ALIGN)
            || end.is_none_or(|x| x > region_end)
        {
            d.push(format!(
                "primitive chunk {c}: {} records at offset {} are misplaced ({SECTION_ALIGN}-aligned, inside the data region)",
                ch.count, ch.offset
            ));
            continue;
        }
        items.push((
            ch.offset,
            end.unwrap_or(ch.offset),
            format!("primitive chunk {c}"),
        ));
    }
    if first_generation {
        // Already in file order: blocks by directory order, then chunks.
        let mut prev = (section.offset, "the data region's start".to_string());
        for (start, end, what) in &items {
            if *start < prev.0 {
                d.push(format!(
                    "{what} at offset {start} is not after {} (ending at {}): a packed file \
                     stores blocks in directory order, then the primitive chunks",
                    prev.1, prev.0
                ));
                continue;
            }
            if let Some(pad) = bytes.get(prev.0 as usize..*start as usize)
                && pad.iter().any(|&x| x != 0)
            {
                d.push(format!("padding before {what} is not zero"));
            }
            prev = (*end, what.clone());
        }
        if let Some(pad) = bytes.get(prev.0 as usize..region_end as usize)
            && pad.iter().any(|&x| x != 0)
        {
            d.push(format!(
                "padding after {} to the end of the data region is not zero",
                prev.1
            ));
        }
        if region_end.saturating_sub(prev.0) >= SECTION_ALIGN {
            d.push(format!(
                "the data region ends at {region_end}, {} (its last item) at {}",
                prev.1, prev.0
            ));
        }
    } else {
        items.sort_by_key(|i| i.0);
        for w in items.windows(2) {
            if w[1].0 < w[0].1 {
                d.push(format!(
                    "{} (bytes {}..{}) overlaps {} (bytes {}..{})",
                    w[1].2, w[1].0, w[1].1, w[0].2, w[0].0, w[0].1
                ));
            }
        }
    }
    let header = file.header();
    if max_raw != header.max_block_raw_len {
        d.push(format!(
            "header: max_block_raw_len {} but the largest block is {max_raw} bytes",
            header.max_block_raw_len
        ));
    }
    placed
}

/// Checks every primitive chunk's checksum (spec §8.6), for chunks that
/// [`check_block_placement`] found in place; returns the table's records by chunk (empty where
/// a chunk is misplaced or damaged).
pub fn check_prim_chunks<'a, D: AsRef<[u8]>>(
    file: &'a OavmFile<D>,
    d: &mut Defects,
) -> Vec<&'a [PrimRecord]> {
    let bytes = file.bytes();
    let chunks: &[PrimChunk] = file.records(SectionKind::Prims);
    let n = file.header().input_triangles;
    let mut out = Vec::with_capacity(chunks.len());
    for (c, ch) in chunks.iter().enumerate() {
        let expected = (n - (c as u64 * PRIM_CHUNK).min(n)).min(PRIM_CHUNK);
        if ch.count != expected || ch.reserved != 0 {
            d.push(format!(
                "primitive chunk {c}: {} records (expected {expected}) or reserved bytes set",
                ch.count
            ));
            out.push(&[][..]);
            continue;
        }
        let len = (ch.count * std::mem::size_of::<PrimRecord>() as u64) as usize;
        let Some(stored) = bytes.get(ch.offset as usize..(ch.offset as usize).saturating_add(len))
        else {
            out.push(&[][..]);
            continue;
        };
        let computed = checksum(stored);
        if computed != ch.checksum {
            d.push(format!(
                "primitive chunk {c}: checksum mismatch (stored {:#018x}, computed {computed:#018x})",
                ch.checksum
            ));
            out.push(&[][..]);
            continue;
        }
        out.push(bytemuck::try_cast_slice(stored).unwrap_or(&[]));
    }
    out
}

/// Checks the zero padding between the parts of block `b`'s raw bytes (spec §8.3), whose
/// layout `header` gives (already checked against its length).
pub fn check_block_padding(raw: &[u8], header: &BlockHeader, b: u32, d: &mut Defects) {
    let Some((ranges, _)) = block_layout(header) else {
        return;
    };
    let mut at = std::mem::size_of::<BlockHeader>() as u64;
    for r in ranges {
        if raw
            .get(at as usize..r.start as usize)
            .is_some_and(|pad| pad.iter().any(|&x| x != 0))
        {
            d.push(format!(
                "block {b}: padding at bytes {at}..{} is not zero",
                r.start
            ));
        }
        at = r.end;
    }
}
