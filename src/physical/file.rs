//! Reading an `.oavm` file: O(1) checks at open, typed zero-copy views of the sections after.
//!
//! [`OavmFile`] is generic over its bytes (`D: AsRef<[u8]>`): tests run it on an
//! [`AlignedBytes`] buffer, production on a [`crate::os::MappedFile`], through the same code.
//! Opening checks the header, the section table and the level table (at most 22 entries), so its
//! cost does not depend on the size of the file; the contents of the other sections are checked
//! by [`super::verify`] on demand and bounds-checked by every reader as it goes.

use std::ops::Range;

use bytemuck::{Pod, Zeroable};

use super::format::*;
use crate::error::FormatError;

/// An opened `.oavm` file whose header, section table and level table have been validated.
pub struct OavmFile<D> {
    data: D,
    /// The header of the slot read (spec §2.1), copied at open: a later update may overwrite
    /// the other slot, and two updates later this one, while this reader still reads its
    /// generation.
    header: Header,
    /// Which header slot holds `header` (0 or 1), and what the other one held at open.
    slot: usize,
    other_slot: SlotState,
    /// Section entries indexed by `SectionKind as usize - 1`.
    sections: [SectionEntry; SectionKind::ALL.len()],
    levels: Vec<LevelEntry>,
}

impl<D: AsRef<[u8]>> OavmFile<D> {
    /// Opens `data` as an `.oavm` file, checking only what the size of the file does not scale:
    /// header, section table and level table (spec §2–§4.1).
    pub fn open(data: D) -> Result<OavmFile<D>, FormatError> {
        if cfg!(target_endian = "big") {
            return Err(FormatError::BigEndianHost);
        }
        let bytes = data.as_ref();
        // A slot is valid when its header and section table are (spec §2.1: what an
        // interrupted update can leave wrong); the chosen generation's level table is then
        // checked, and damage there is an error, not a reason to read an older generation.
        let read = |slot: usize| -> Result<_, FormatError> {
            let header = read_header(bytes, slot, bytes.len() as u64)?;
            let sections = read_section_table(bytes, &header, slot)?;
            Ok((header, sections))
        };
        let first = read(0);
        let second_at = HEADER_SLOTS[1] as usize;
        let second_used = bytes
            .get(second_at..second_at + std::mem::size_of::<Header>())
            .is_some_and(|b| b.iter().any(|&x| x != 0));
        let second = second_used.then(|| read(1));
        // The valid slot of the highest generation (spec §2.1); a file whose slot 0 is broken
        // and whose slot 1 was never written reports slot 0's defect.
        let (slot, (header, sections), other_slot) = match (first, second) {
            (Ok(a), None) => (0, a, SlotState::Unused),
            (Err(e), None) => return Err(e),
            (Ok(a), Some(Ok(b))) => {
                // Generation g is valid only in slot (g - 1) mod 2 (read_header), so two
                // valid slots never hold the same generation.
                if a.0.generation > b.0.generation {
                    (0, a, SlotState::Older(b.0.generation))
                } else {
                    (1, b, SlotState::Older(a.0.generation))
                }
            }
            (Ok(a), Some(Err(e))) => (0, a, SlotState::Invalid(e.to_string())),
            (Err(e), Some(Ok(b))) => (1, b, SlotState::Invalid(e.to_string())),
            (Err(e), Some(Err(_))) => return Err(e),
        };
        let levels = read_levels(bytes, &header, &sections)?;
        Ok(OavmFile {
            data,
            header,
            slot,
            other_slot,
            sections,
            levels,
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The header slot this generation was read from (spec §2.1).
    pub fn slot(&self) -> usize {
        self.slot
    }

    /// What the other header slot held at open.
    pub fn other_slot(&self) -> &SlotState {
        &self.other_slot
    }

    pub fn levels(&self) -> &[LevelEntry] {
        &self.levels
    }

    pub fn section(&self, kind: SectionKind) -> &SectionEntry {
        &self.sections[kind as usize - 1]
    }

    /// The buffer holding the file.
    pub fn data(&self) -> &D {
        &self.data
    }

    pub fn bytes(&self) -> &[u8] {
        self.data.as_ref()
    }

    /// The raw bytes of a section (its range was validated at open).
    pub fn section_bytes(&self, kind: SectionKind) -> &[u8] {
        let s = self.section(kind);
        self.data
            .as_ref()
            .get(s.offset as usize..(s.offset + s.length) as usize)
            .unwrap_or(&[])
    }

    /// The block directory (spec §8), cast in place; entries are untrusted until checked
    /// ([`block_view`] and the pager check each one they use).
    pub fn directory(&self) -> &[BlockEntry] {
        self.records(SectionKind::Directory)
    }

    /// A section's records, cast in place. Open checked the section's length, alignment in the
    /// file and record size; the buffer's own alignment is checked here, and a misaligned buffer
    /// (not a map, not an [`AlignedBytes`]) yields an empty slice, which every reader treats as
    /// out-of-bounds, never as a panic.
    pub fn records<T: Pod>(&self, kind: SectionKind) -> &[T] {
        bytemuck::try_cast_slice(self.section_bytes(kind)).unwrap_or(&[])
    }

    /// Whether the buffer holding the file is aligned well enough to cast records in place.
    pub fn is_aligned(&self) -> bool {
        (self.data.as_ref().as_ptr() as usize).is_multiple_of(std::mem::align_of::<u64>())
    }

    pub fn into_inner(self) -> D {
        self.data
    }
}

/// What a header slot other than the one read held at open (spec §2.1).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SlotState {
    /// All zero: the file was never updated (slot 1 of a file as packed).
    Unused,
    /// A valid header of an older generation.
    Older(u64),
    /// Bytes that are not a valid header: an update was interrupted while writing it (the next
    /// update overwrites it), or damage; the reason is the reader's.
    Invalid(String),
}

fn header_err(what: impl Into<String>) -> FormatError {
    FormatError::Header(what.into())
}

fn table_err(what: impl Into<String>) -> FormatError {
    FormatError::SectionTable(what.into())
}

/// Whether the file `f`, whose size or change time moved since a reader read `header` from
/// slot `slot`, still holds that generation as it was (spec §2.1): its slot holds the same
/// header (an update since wrote the other slot, or was interrupted), or a slot holds a later
/// generation (an update wrote it; two updates wrote over the reader's slot). An update only
/// appends and writes a slot, so the bytes the reader uses are then as they were.
pub fn generation_intact(f: &std::fs::File, slot: usize, header: &Header) -> bool {
    use std::os::unix::fs::FileExt;
    let Ok(len) = f.metadata().map(|m| m.len()) else {
        return false;
    };
    let mut first = vec![0u8; DATA_START.min(len) as usize];
    if f.read_exact_at(&mut first, 0).is_err() {
        return false;
    }
    let at = HEADER_SLOTS.get(slot).copied().unwrap_or(0) as usize;
    let mine = bytemuck::bytes_of(header);
    if first.get(at..at + mine.len()) == Some(mine) {
        return true;
    }
    (0..HEADER_SLOTS.len())
        .any(|s| read_header(&first, s, len).is_ok_and(|h| h.generation > header.generation))
}

/// Reads and checks the header in slot `slot` (spec §2, §2.1) of a file whose first bytes
/// are `file` (all of it, or at least its header slots) and whose length is `file_len`.
fn read_header(file: &[u8], slot: usize, file_len: u64) -> Result<Header, FormatError> {
    let at = HEADER_SLOTS[slot] as usize;
    let bytes = file.get(at..).unwrap_or(&[]);
    let need = std::mem::size_of::<Header>();
    if bytes.len() < need {
        if bytes.len() >= MAGIC.len() && bytes[..MAGIC.len()] != MAGIC {
            return Err(FormatError::BadMagic {
                found: bytes[..8].try_into().unwrap_or([0; 8]),
            });
        }
        return Err(FormatError::TooShort {
            len: bytes.len() as u64,
            need: need as u64,
        });
    }
    let header: Header = bytemuck::pod_read_unaligned(&bytes[..need]);
    if header.magic != MAGIC {
        return Err(FormatError::BadMagic {
            found: header.magic,
        });
    }
    // The version is checked before anything else a later version might have changed.
    if header.version != VERSION {
        return Err(FormatError::Version {
            expected: VERSION,
            found: header.version,
        });
    }
    let section_count = check_header_frame(&header, slot, file_len)?;
    let table_end = need + section_count * std::mem::size_of::<SectionEntry>();
    if bytes.len() < table_end {
        return Err(header_err(format!(
            "the file ends inside the section table ({table_end} bytes needed)"
        )));
    }
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    hasher.update(&bytes[..HEADER_CHECKED_LEN]);
    hasher.update(&bytes[need..table_end]);
    let computed = hasher.digest();
    if computed != header.checksum {
        return Err(FormatError::Checksum {
            section: "header and section table",
            stored: header.checksum,
            computed,
        });
    }
    check_header_fields(&header)?;
    Ok(header)
}

/// The header fields that say where things are and how many, checked before the checksum
/// (which covers the section table they locate): block size limit, header size, the slot of
/// the generation, file size, flags, section count and table offset. Returns the section
/// count.
fn check_header_frame(header: &Header, slot: usize, file_len: u64) -> Result<usize, FormatError> {
    let at = HEADER_SLOTS[slot] as usize;
    let need = std::mem::size_of::<Header>();
    if header.max_block_raw_len > MAX_BLOCK_RAW_LEN {
        return Err(header_err(format!(
            "max_block_raw_len {} is above the limit of {MAX_BLOCK_RAW_LEN} bytes",
            header.max_block_raw_len
        )));
    }
    if header.header_size as usize != need {
        return Err(header_err(format!(
            "header_size is {}, version {VERSION} headers are {need} bytes",
            header.header_size
        )));
    }
    if header.generation < FIRST_GENERATION
        || (header.generation - FIRST_GENERATION) % 2 != slot as u64
    {
        return Err(header_err(format!(
            "generation {} in header slot {slot}: generation g is written to slot (g - 1) mod 2",
            header.generation
        )));
    }
    if header.file_size > file_len {
        return Err(header_err(format!(
            "the header records a file of at least {} bytes but the file has {file_len} bytes \
             (truncated)",
            header.file_size,
        )));
    }
    if header.flags & !KNOWN_FLAGS != 0 {
        return Err(header_err(format!(
            "unknown flags {:#x}",
            header.flags & !KNOWN_FLAGS
        )));
    }
    let section_count = SectionKind::count_for(header.flags);
    if header.section_count as usize != section_count {
        return Err(header_err(format!(
            "{} sections, version {VERSION} files {} ropes have {section_count}",
            header.section_count,
            if header.flags & FLAG_ROPES != 0 {
                "with"
            } else {
                "without"
            }
        )));
    }
    if header.section_table_offset != (at + need) as u64 {
        return Err(header_err(format!(
            "section table at offset {}, expected {}",
            header.section_table_offset,
            at + need
        )));
    }
    Ok(section_count)
}

/// The header fields checked after the checksum: reserved bytes, the lattice, level count and
/// depth, the root cube and the mesh bounds.
fn check_header_fields(header: &Header) -> Result<(), FormatError> {
    if header.reserved.iter().any(|&r| r != 0) || header.reserved_u32 != 0 {
        return Err(header_err("reserved fields are not zero"));
    }
    if header.chunk_groups > MAX_CHUNK_GROUPS
        || (header.chunk_groups != 0 && header.flags & FLAG_CLUSTERS == 0)
    {
        return Err(header_err(format!(
            "chunk_groups is {}: at most {MAX_CHUNK_GROUPS}, and 0 in a file without clusters",
            header.chunk_groups
        )));
    }
    if header.lattice_bits != LATTICE_BITS {
        return Err(header_err(format!(
            "lattice_bits is {}, this version uses {LATTICE_BITS}",
            header.lattice_bits
        )));
    }
    if header.level_count == 0 || header.level_count > MAX_LEVEL + 1 {
        return Err(header_err(format!(
            "level_count is {}, must be 1..={}",
            header.level_count,
            MAX_LEVEL + 1
        )));
    }
    if header.max_depth > MAX_LEVEL || header.level_count > header.max_depth + 1 {
        return Err(header_err(format!(
            "max_depth {} is above {MAX_LEVEL} or below the tree's depth {}",
            header.max_depth,
            header.level_count - 1
        )));
    }
    let root_ok = header.root_min.iter().all(|c| c.is_finite())
        && header.root_size.is_finite()
        && header.root_size > 0.0;
    if !root_ok {
        return Err(header_err(format!(
            "root cube (min {:?}, size {}) is not finite and positive",
            header.root_min, header.root_size
        )));
    }
    if !(MIN_ROOT_SIZE..=MAX_ROOT_SIZE).contains(&header.root_size) {
        return Err(header_err(format!(
            "root cube edge {:e} is outside {MIN_ROOT_SIZE:e}..{MAX_ROOT_SIZE:e}, the scales \
             this version traces correctly: rescale the mesh and repack it",
            header.root_size
        )));
    }
    let mesh_ok = (0..3).all(|k| {
        header.mesh_min[k].is_finite()
            && header.mesh_max[k].is_finite()
            && header.mesh_min[k] <= header.mesh_max[k]
    });
    if !mesh_ok {
        return Err(header_err("mesh bounds are not finite or min > max"));
    }
    Ok(())
}

fn read_section_table(
    bytes: &[u8],
    header: &Header,
    slot: usize,
) -> Result<[SectionEntry; SectionKind::ALL.len()], FormatError> {
    let start = header.section_table_offset as usize;
    let entry = std::mem::size_of::<SectionEntry>();
    let mut sections = [SectionEntry::zeroed(); SectionKind::ALL.len()];
    // `read_header` checked the count against the flags and that the table is in the file.
    // Sections start in the data region, after both header slots (spec §2.1).
    let mut prev_end = DATA_START;
    for (i, kind) in SectionKind::for_flags(header.flags).enumerate() {
        let at = start + i * entry;
        let s: SectionEntry = bytemuck::pod_read_unaligned(&bytes[at..at + entry]);
        let name = kind.name();
        if s.kind != kind as u32 {
            return Err(table_err(format!(
                "slot {slot}: entry {i} has kind {}, expected {} ({name}): sections are stored \
                 in a fixed order",
                s.kind, kind as u32
            )));
        }
        if kind == SectionKind::Blocks && s.offset != DATA_START {
            return Err(table_err(format!(
                "{name}: starts at {}, the data region at {DATA_START}",
                s.offset
            )));
        }
        if s.codec != 0 || s.block_directory != 0 {
            return Err(table_err(format!(
                "{name}: codec {} / block directory {} are reserved and must be 0 in version {VERSION}",
                s.codec, s.block_directory
            )));
        }
        if !s.offset.is_multiple_of(SECTION_ALIGN) || s.offset < prev_end {
            return Err(table_err(format!(
                "{name}: offset {} is not {SECTION_ALIGN}-aligned or overlaps what precedes it (ends at {prev_end})",
                s.offset
            )));
        }
        let end = s
            .offset
            .checked_add(s.length)
            .filter(|&e| e <= header.file_size);
        let Some(end) = end else {
            return Err(table_err(format!(
                "{name}: {} bytes at offset {} run past the end of the {}-byte file",
                s.length, s.offset, header.file_size
            )));
        };
        match kind.record_size() {
            Some(size) if s.count.checked_mul(size) != Some(s.length) => {
                return Err(table_err(format!(
                    "{name}: {} records of {size} bytes do not make {} bytes",
                    s.count, s.length
                )));
            }
            Some(_) => {}
            None => {
                if s.checksum != 0 || s.count != header.block_count {
                    return Err(table_err(format!(
                        "{name}: {} blocks and checksum {:#x}, the header says {} blocks and \
                         blocks carry their own checksums (0 here)",
                        s.count, s.checksum, header.block_count
                    )));
                }
            }
        }
        if kind == SectionKind::Directory && s.count != header.block_count {
            return Err(table_err(format!(
                "{name}: {} entries, the header says {} blocks",
                s.count, header.block_count
            )));
        }
        if kind == SectionKind::WideNodes || kind == SectionKind::WideLinks {
            // At most one wide node per internal node, one wide link per link (spec §8.7).
            let nodes = sections[SectionKind::Nodes as usize - 1].count;
            if s.count > nodes {
                return Err(table_err(format!(
                    "{name}: {} records, more than the top tree's {nodes} nodes",
                    s.count
                )));
            }
        }
        if kind == SectionKind::LinkBounds || kind == SectionKind::Ropes {
            let nodes = sections[SectionKind::Nodes as usize - 1].count;
            if s.count != nodes {
                return Err(table_err(format!(
                    "{name}: {} records, one per top-tree node ({nodes}) expected",
                    s.count
                )));
            }
        }
        if kind == SectionKind::Directory && s.offset != prev_end.next_multiple_of(SECTION_ALIGN) {
            return Err(table_err(format!(
                "{name}: starts at {}, not where the data region ends ({prev_end})",
                s.offset
            )));
        }
        if kind == SectionKind::Prims && s.count != header.input_triangles.div_ceil(PRIM_CHUNK) {
            return Err(table_err(format!(
                "{name}: {} chunks for {} primitives ({PRIM_CHUNK} a chunk)",
                s.count, header.input_triangles
            )));
        }
        prev_end = end;
        sections[kind as usize - 1] = s;
    }
    if prev_end != header.file_size {
        return Err(table_err(format!(
            "the last section ends at {prev_end}, the file at {}",
            header.file_size
        )));
    }
    Ok(sections)
}

/// Checks the level table against itself and the section sizes (spec §4.1 invariants).
fn read_levels(
    bytes: &[u8],
    header: &Header,
    sections: &[SectionEntry; SectionKind::ALL.len()],
) -> Result<Vec<LevelEntry>, FormatError> {
    let err = |what: String| FormatError::Section {
        section: "levels",
        what,
    };
    let s = &sections[SectionKind::Levels as usize - 1];
    // The top tree holds the levels down to its deepest link or empty leaf: at least the root,
    // at most the whole tree's.
    if s.count == 0 || s.count > header.level_count as u64 {
        return Err(err(format!(
            "{} top-tree levels for a tree of {} levels",
            s.count, header.level_count
        )));
    }
    let range: Range<usize> = s.offset as usize..(s.offset + s.length) as usize;
    let levels: Vec<LevelEntry> = bytes[range]
        .chunks_exact(std::mem::size_of::<LevelEntry>())
        .map(bytemuck::pod_read_unaligned)
        .collect();
    let mut node_start = 0u64;
    let mut rank_start = 0u64;
    let mut expected_nodes = 1u64;
    for (l, e) in levels.iter().enumerate() {
        if e.node_count != expected_nodes {
            return Err(err(format!(
                "level {l} has {} nodes, expected {expected_nodes} (8 per internal node above)",
                e.node_count
            )));
        }
        if e.internal_count > e.node_count {
            return Err(err(format!(
                "level {l} has {} internal nodes among {} nodes",
                e.internal_count, e.node_count
            )));
        }
        if e.node_start != node_start || e.rank_start != rank_start {
            return Err(err(format!(
                "level {l} starts at node {} and rank word {}, expected {node_start} and {rank_start}",
                e.node_start, e.rank_start
            )));
        }
        // Counts are bounded by the section sizes checked below, so these cannot overflow.
        node_start = node_start.saturating_add(e.node_count);
        rank_start = rank_start.saturating_add(e.node_count.div_ceil(64));
        expected_nodes = e.internal_count.saturating_mul(8);
        if node_start > sections[SectionKind::Nodes as usize - 1].count {
            return Err(err(format!("level {l} runs past the nodes section")));
        }
    }
    if expected_nodes != 0 {
        return Err(err("the deepest level has internal nodes".to_string()));
    }
    let nodes = sections[SectionKind::Nodes as usize - 1].count;
    let ranks = sections[SectionKind::Ranks as usize - 1].count;
    if node_start != nodes || rank_start != ranks {
        return Err(err(format!(
            "levels hold {node_start} nodes and {rank_start} rank words, the sections {nodes} and {ranks}"
        )));
    }
    Ok(levels)
}

/// A byte buffer aligned for casting records in place (backed by `u64`s), for files held in
/// memory: tests, and files produced by the builder before they are written.
#[derive(Clone, Default)]
pub struct AlignedBytes {
    words: Vec<u64>,
    len: usize,
}

impl AlignedBytes {
    /// `len` zero bytes.
    pub fn zeroed(len: usize) -> AlignedBytes {
        AlignedBytes {
            words: vec![0u64; len.div_ceil(8)],
            len,
        }
    }

    pub fn from_slice(bytes: &[u8]) -> AlignedBytes {
        let mut words = vec![0u64; bytes.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        AlignedBytes {
            words,
            len: bytes.len(),
        }
    }

    pub fn as_mut_slice(&mut self) -> &mut [u8] {
        &mut bytemuck::cast_slice_mut::<u64, u8>(&mut self.words)[..self.len]
    }

    pub fn truncate(&mut self, len: usize) {
        self.len = self.len.min(len);
    }
}

impl AsRef<[u8]> for AlignedBytes {
    fn as_ref(&self) -> &[u8] {
        &bytemuck::cast_slice::<u64, u8>(&self.words)[..self.len]
    }
}
