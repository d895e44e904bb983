//! Writing an `.oavm` file: laying the sections out (spec §2–§3) and replacing the destination
//! atomically.

use std::io::Write;
use std::path::Path;

use bytemuck::Zeroable;

use super::file::AlignedBytes;
use super::format::*;
use crate::error::Error;
use crate::mapping::morton::LATTICE_BITS;

/// Everything a file holds, as the builder produces it. The writer only lays it out; the
/// invariants of the contents are the builder's (and `verify` checks them).
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
    fn section_bytes(&self, kind: SectionKind) -> (&[u8], u64) {
        match kind {
            SectionKind::Levels => (bytemuck::cast_slice(&self.levels), self.levels.len() as u64),
            SectionKind::Nodes => (bytemuck::cast_slice(&self.nodes), self.nodes.len() as u64),
            SectionKind::Ranks => (bytemuck::cast_slice(&self.ranks), self.ranks.len() as u64),
            SectionKind::Volumes => (
                bytemuck::cast_slice(&self.volumes),
                self.volumes.len() as u64,
            ),
            SectionKind::Refs => (bytemuck::cast_slice(&self.refs), self.refs.len() as u64),
            SectionKind::Triangles => (
                bytemuck::cast_slice(&self.triangles),
                self.triangles.len() as u64,
            ),
        }
    }
}

/// Lays `parts` out as the bytes of an `.oavm` file (spec §2: header, section table, then the
/// sections in [`SectionKind::ALL`] order, each at a multiple of [`SECTION_ALIGN`], zero padding
/// between them).
pub fn encode(parts: &TreeParts) -> AlignedBytes {
    let header_size = std::mem::size_of::<Header>() as u64;
    let table_size = (SectionKind::ALL.len() * std::mem::size_of::<SectionEntry>()) as u64;
    let mut entries = [SectionEntry::zeroed(); SectionKind::ALL.len()];
    let mut at = header_size + table_size;
    for (i, kind) in SectionKind::ALL.into_iter().enumerate() {
        let (bytes, count) = parts.section_bytes(kind);
        at = align_up(at);
        entries[i] = SectionEntry {
            kind: kind as u32,
            codec: 0,
            offset: at,
            length: bytes.len() as u64,
            count,
            block_directory: 0,
            checksum: checksum(bytes),
        };
        at += bytes.len() as u64;
    }
    let file_size = at;

    let mut header = Header {
        magic: MAGIC,
        version: VERSION,
        flags: if parts.merged { FLAG_MERGED } else { 0 },
        header_size: header_size as u32,
        section_count: SectionKind::ALL.len() as u32,
        section_table_offset: header_size,
        file_size,
        root_min: parts.root_min,
        root_size: parts.root_size,
        mesh_min: parts.mesh_min,
        mesh_max: parts.mesh_max,
        input_triangles: parts.input_triangles,
        empty_leaves: parts.empty_leaves,
        solid_leaves: parts.solid_leaves,
        level_count: parts.levels.len() as u32,
        lattice_bits: LATTICE_BITS,
        max_depth: parts.max_depth,
        leaf_size: parts.leaf_size,
        reserved: [0; 14],
        checksum: 0,
    };
    let table: &[u8] = bytemuck::cast_slice(&entries);
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    hasher.update(&bytemuck::bytes_of(&header)[..HEADER_CHECKED_LEN]);
    hasher.update(table);
    header.checksum = hasher.digest();

    // Zero-filled buffer: all padding is zero by construction.
    let mut out = AlignedBytes::from_slice(&vec![0u8; file_size as usize]);
    let buf = out.as_mut_slice();
    buf[..header_size as usize].copy_from_slice(bytemuck::bytes_of(&header));
    buf[header_size as usize..(header_size + table_size) as usize].copy_from_slice(table);
    for (i, kind) in SectionKind::ALL.into_iter().enumerate() {
        let (bytes, _) = parts.section_bytes(kind);
        let off = entries[i].offset as usize;
        buf[off..off + bytes.len()].copy_from_slice(bytes);
    }
    out
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
    tmp.write_all(bytes).map_err(err)?;
    tmp.as_file().sync_all().map_err(err)?;
    tmp.persist(path).map_err(|e| err(e.error))?;
    Ok(())
}
