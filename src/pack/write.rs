//! From the builder's tree to the bytes of a file: split into blocks ([`super::blocks`]), the
//! blocks encoded in parallel and written in order ([`crate::physical::writer`]), then the top
//! tree and the header.

use rayon::prelude::*;

use super::blocks::{self, BlockParts};
use crate::error::Error;
use crate::mapping::ClusterGeometry;
use crate::output::Output;
use crate::physical::AlignedBytes;
use crate::physical::format::{FLAG_CLUSTERS, Header, PrimRecord};
use crate::physical::writer::{
    BlockOptions, FileSink, FileWriter, Sink, StoredBlock, UnitParts, UnitRef, store_block,
};

/// A whole tree as the in-memory builder lays it out: every level, node, volume, reference and
/// triangle in one unit (spec §4-§7), and the header fields the builder knows (see
/// [`FileWriter::finish`]). Written, it is split into blocks.
#[derive(Clone, Debug)]
pub struct TreeParts {
    pub header: Header,
    pub tree: UnitParts,
}

impl TreeParts {
    /// The tree as one unit (its arrays, borrowed).
    pub fn unit(&self) -> UnitRef<'_> {
        self.tree.as_ref()
    }

    /// Where the lattice lies, if the header asks for clusters.
    pub fn cluster_geometry(&self) -> Option<ClusterGeometry> {
        (self.header.flags & FLAG_CLUSTERS != 0).then_some(ClusterGeometry {
            root_min: self.header.root_min,
            root_size: self.header.root_size,
        })
    }
}

/// Blocks encoded (and compressed) at a time, in parallel, before they are written in order:
/// bounds what is held.
const BATCH: usize = 64;

/// Encodes `blocks` in parallel, a batch at a time, and appends them to `w` in order.
pub(crate) fn write_blocks<S: Sink>(
    blocks: &[BlockParts],
    opts: &BlockOptions,
    w: &mut FileWriter<S>,
    io: &impl Fn(std::io::Error) -> Error,
) -> Result<(), Error> {
    for batch in blocks.chunks(BATCH) {
        let stored: Vec<StoredBlock> = batch
            .par_iter()
            .map(|b| store_block(b.unit.as_ref(), b.root_level, b.id, opts))
            .collect::<Result<_, _>>()?;
        for s in stored {
            w.push(s).map_err(io)?;
        }
    }
    Ok(())
}

/// Splits `parts` into blocks, writes them to `w` and returns the top tree.
fn write_tree<S: Sink>(
    parts: &TreeParts,
    opts: &BlockOptions,
    w: &mut FileWriter<S>,
    io: &impl Fn(std::io::Error) -> Error,
) -> Result<UnitParts, Error> {
    let split = blocks::partition(
        parts.unit(),
        0,
        &[0],
        opts.block_size,
        w.block_count(),
        parts.cluster_geometry().as_ref(),
    )?;
    write_blocks(&split.blocks, opts, w, io)?;
    blocks::assemble_top(split.top)
}

/// Lays a whole in-memory tree out as the bytes of a file, split into blocks as `opts` say.
pub fn encode_with(parts: &TreeParts, opts: &BlockOptions) -> Result<AlignedBytes, Error> {
    let io = |e: std::io::Error| Error::Build(format!("encoding in memory: {e}"));
    let mut w = FileWriter::new(Vec::new()).map_err(io)?;
    let top = write_tree(parts, opts, &mut w, &io)?;
    let (bytes, _) = w.finish(&parts.header, top.as_ref()).map_err(io)?;
    Ok(AlignedBytes::from_slice(&bytes))
}

/// [`encode_with`] with the default block options.
pub fn encode(parts: &TreeParts) -> Result<AlignedBytes, Error> {
    encode_with(parts, &BlockOptions::default())
}

/// Writes the file of `parts` into `out` (created before the build, so that a bad output path
/// fails before the work) and commits it; returns its size and block count. Only one batch of
/// encoded blocks is held at a time.
/// With `prims`, the primitive table (spec §8.6) follows the blocks; with `geometries`, the
/// geometry table (spec §8.8) ends the file.
pub fn write_file(
    mut out: Output,
    parts: &TreeParts,
    opts: &BlockOptions,
    prims: Option<&[PrimRecord]>,
    geometries: Vec<crate::mesh::Geometry>,
) -> Result<(u64, u32), Error> {
    let path = out.path().to_owned();
    let io = |e: std::io::Error| Error::io(&path, e);
    let file = out.file().try_clone().map_err(io)?;
    let mut w = FileWriter::new(FileSink::new(file)).map_err(io)?;
    let top = write_tree(parts, opts, &mut w, &io)?;
    if let Some(p) = prims {
        w.push_prims(p).map_err(io)?;
    }
    w.set_geometries(geometries);
    let blocks = w.block_count();
    let (sink, size) = w.finish(&parts.header, top.as_ref()).map_err(io)?;
    sink.into_file().map_err(io)?;
    out.commit()?;
    Ok((size, blocks))
}
