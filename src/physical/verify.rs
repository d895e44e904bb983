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

/// Checks every section's checksum (but the blocks', which carry their own), the zero
/// padding before each section, and the buffer's alignment. Returns the sections checked.
pub fn check_sections<D: AsRef<[u8]>>(file: &OavmFile<D>, d: &mut Defects) -> u32 {
    let bytes = file.bytes();
    let count = SectionKind::count_for(file.header().flags);
    let mut covered =
        (std::mem::size_of::<Header>() + count * std::mem::size_of::<SectionEntry>()) as u64;
    let mut checked = 0;
    for kind in SectionKind::ALL.into_iter().take(count) {
        let s = file.section(kind);
        if let Some(pad) = bytes.get(covered as usize..s.offset as usize)
            && pad.iter().any(|&b| b != 0)
        {
            d.push(format!(
                "padding before the {} section (bytes {covered}..{}) is not zero",
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
        }
        checked += 1;
        covered = s.offset + s.length;
    }
    if !file.is_aligned() {
        d.push("the buffer holding the file is not 8-byte aligned; records cannot be read".into());
    }
    checked
}

/// Checks that the blocks lie one after another inside the blocks section, each aligned for
/// its codec, with zero padding between them, and that `max_block_raw_len` is the largest
/// block's. Returns, per block, whether it is well placed (a misplaced block is not read).
pub fn check_block_placement<D: AsRef<[u8]>>(file: &OavmFile<D>, d: &mut Defects) -> Vec<bool> {
    let bytes = file.bytes();
    let section = *file.section(SectionKind::Blocks);
    let directory = file.directory();
    let mut placed = Vec::with_capacity(directory.len());
    let mut prev_end = section.offset;
    let mut max_raw = 0u64;
    for (b, e) in directory.iter().enumerate() {
        let align = if e.codec == CODEC_RAW {
            RAW_BLOCK_ALIGN
        } else {
            SECTION_ALIGN
        };
        let end = e.offset.checked_add(e.stored_len);
        if e.offset < prev_end
            || !e.offset.is_multiple_of(align)
            || end.is_none_or(|x| x > section.offset + section.length)
        {
            d.push(format!(
                "block {b}: {} bytes at offset {} are misplaced (after {prev_end}, {align}-aligned, inside the blocks section)",
                e.stored_len, e.offset
            ));
            placed.push(false);
            continue;
        }
        if let Some(pad) = bytes.get(prev_end as usize..e.offset as usize)
            && pad.iter().any(|&x| x != 0)
        {
            d.push(format!("padding before block {b} is not zero"));
        }
        prev_end = end.unwrap_or(prev_end);
        max_raw = max_raw.max(e.raw_len);
        placed.push(true);
    }
    if prev_end != section.offset + section.length && directory.is_empty() == (section.length == 0)
    {
        d.push(format!(
            "the blocks section ends at {}, its last block at {prev_end}",
            section.offset + section.length
        ));
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
