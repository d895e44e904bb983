//! The regions of a file that the tests damage, named as errors and defects name them.

use std::ops::Range;

use super::*;

/// What a region's offsets are relative to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Space {
    /// The file.
    File,
    /// Block `b`'s decoded bytes (for a raw block, its stored bytes).
    Block(usize),
}

/// A part of a file, named as errors and defects name it.
#[derive(Clone, Debug)]
pub struct Region {
    pub name: String,
    pub kind: RegionKind,
    pub space: Space,
    pub range: Range<usize>,
    /// What verify reports about a byte of a region of zero padding: the region's own words
    /// (its name is not what the defect says).
    pub defect: Option<String>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RegionKind {
    /// The header and the section table of the slot of the file's generation (§2, §2.1).
    Header,
    Table,
    /// The zero bytes after that section table, to the slot's end (§2.1).
    SlotPadding,
    /// The other header slot (§2.1): not this generation's, not checked (all zero in a file as
    /// packed; the previous generation's header in an updated file).
    OtherSlot,
    /// Zero padding before a section (§1).
    Padding,
    /// Index into [`SECTIONS`].
    Section(usize),
    /// The stored bytes of block `b`, whole (a zstd frame, or a raw block not cut into parts).
    Stored(usize),
    /// Zero padding in the data region of a file as packed (§2, §8.2): before a block or a
    /// primitive chunk, or after the last of them to the directory.
    Gap,
    /// Bytes of the data region that a generation after the first does not refer to (§2.1:
    /// older generations' blocks, chunks and sections, not checked).
    Dead,
    /// The records of primitive chunk `c` (§8.6).
    Chunk(usize),
    /// Block `b`'s header (§8.3).
    BlockHeader(usize),
    /// Block `b`'s part (index into [`BLOCK_PARTS`]).
    BlockPart(usize, usize),
    /// The zero padding between two parts of block `b`.
    BlockPadding(usize),
}

impl Region {
    /// Size of the region's records, and their fields.
    pub fn records(&self) -> (usize, Fields) {
        match self.kind {
            RegionKind::Header => (HEADER_LEN, HEADER_FIELDS),
            RegionKind::Table => (ENTRY_LEN, ENTRY_FIELDS),
            RegionKind::Padding
            | RegionKind::SlotPadding
            | RegionKind::OtherSlot
            | RegionKind::Gap
            | RegionKind::Dead
            | RegionKind::BlockPadding(_)
            | RegionKind::Stored(_) => (1, &[(0, "byte")]),
            RegionKind::Section(i) => (SECTIONS[i].1, SECTIONS[i].2),
            RegionKind::Chunk(_) => (PRIM_RECORD_LEN, PRIM_RECORD_FIELDS),
            RegionKind::BlockHeader(_) => (BLOCK_HEADER_LEN, BLOCK_HEADER_FIELDS),
            RegionKind::BlockPart(_, i) => (BLOCK_PARTS[i].1, BLOCK_PARTS[i].2),
        }
    }

    /// The block whose stored bytes the region is part of.
    pub fn block(&self) -> Option<usize> {
        match self.kind {
            RegionKind::Stored(b)
            | RegionKind::BlockHeader(b)
            | RegionKind::BlockPart(b, _)
            | RegionKind::BlockPadding(b) => Some(b),
            _ => None,
        }
    }

    pub fn is_padding(&self) -> bool {
        matches!(
            self.kind,
            RegionKind::Padding
                | RegionKind::SlotPadding
                | RegionKind::OtherSlot
                | RegionKind::Gap
                | RegionKind::Dead
                | RegionKind::BlockPadding(_)
        )
    }

    /// Whether the generation the file holds does not cover the region (§2.1): its bytes may
    /// be anything, and a reader of the generation neither reads nor checks them.
    pub fn not_covered(&self) -> bool {
        matches!(self.kind, RegionKind::OtherSlot | RegionKind::Dead)
    }

    /// The field that byte `at` (in the region's space) belongs to.
    pub fn field(&self, at: usize) -> &'static str {
        let (size, fields) = self.records();
        let rel = (at - self.range.start) % size;
        fields
            .iter()
            .rev()
            .find(|(o, _)| *o <= rel)
            .map_or("?", |f| f.1)
    }

    /// Where byte `at` is: the record, field and byte within the region.
    pub fn place(&self, at: usize) -> String {
        let rel = at - self.range.start;
        let (size, _) = self.records();
        let field = self.field(at);
        match self.kind {
            RegionKind::Header => format!("header field {field} (byte {rel})"),
            _ if size == 1 => format!("{} byte {rel}", self.name),
            _ => format!(
                "{} record {} field {field} (byte {} of the record)",
                self.name,
                rel / size,
                rel % size
            ),
        }
    }
}

/// `text` names block `b` ("block 3" not followed by another digit).
pub fn names_block(text: &str, b: usize) -> bool {
    let pat = format!("block {b}");
    text.match_indices(&pat).any(|(i, _)| {
        !text[i + pat.len()..]
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_digit())
    })
}
