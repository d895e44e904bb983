//! What a file holds, as `oavm-inspect` shows it: the header, the section table, the top
//! tree's levels, the wide nodes of a file of clusters (spec §8.7), the block directory (a
//! summary and, on request, every block) and, on request, the whole tree's nodes per level
//! and the blocks' wide nodes (which read every block).

use serde::Serialize;

use super::block::{BlockReader, BlockView};
use super::cluster_check::wide_region;
use super::file::OavmFile;
use super::format::*;

/// A file's structure. See the module documentation.
#[derive(Clone, Debug, Serialize)]
pub struct Inspection {
    pub header: Header,
    /// The flags by name.
    pub flags: Vec<&'static str>,
    pub sections: Vec<Section>,
    /// The top tree, level by level (spec §8.1).
    pub top_levels: Vec<TopLevel>,
    pub directory: DirectorySummary,
    /// Every block's directory entry, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blocks: Option<Vec<BlockEntry>>,
    /// Nodes per level of the whole tree (top tree and blocks), when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tree_levels: Option<Vec<TreeLevel>>,
    /// The wide nodes (spec §8.7), in a file of clusters.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wide: Option<WideSummary>,
    /// The geometry table (spec §8.8), in a file that has one; or why it cannot be read.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometries: Option<Result<Vec<crate::mesh::Geometry>, String>>,
}

/// A file of clusters' wide nodes (spec §8.7).
#[derive(Clone, Debug, Default, Serialize)]
pub struct WideSummary {
    /// The top tree's wide nodes and wide links (the records of their sections).
    pub top_nodes: u64,
    pub links: u64,
    /// Over every readable block, when the whole tree is counted (it reads every block).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blocks: Option<BlockWideCounts>,
}

/// The wide nodes of the blocks, by what they are: the octree's internal nodes, and the
/// clusters' (their roots among the octree's, spec §8.7; the nodes below them after).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BlockWideCounts {
    pub octree_nodes: u64,
    pub cluster_roots: u64,
    /// All the clusters' nodes, their roots included.
    pub cluster_nodes: u64,
}

/// One section of the table (spec §3).
#[derive(Clone, Debug, Serialize)]
pub struct Section {
    pub name: &'static str,
    #[serde(flatten)]
    pub entry: SectionEntry,
}

/// One level of the top tree: its nodes by kind.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TopLevel {
    pub level: u32,
    pub nodes: u64,
    pub internal: u64,
    pub empty: u64,
    pub links: u64,
    /// Records no writer produces (reported by `--verify`).
    pub invalid: u64,
}

/// The block directory in brief (spec §8.2).
#[derive(Clone, Debug, Default, Serialize)]
pub struct DirectorySummary {
    pub blocks: u64,
    pub raw_blocks: u64,
    pub zstd_blocks: u64,
    /// Lean blocks (spec §7.3).
    pub lean_blocks: u64,
    pub stored_bytes: u64,
    pub decoded_bytes: u64,
    pub smallest_decoded: u64,
    pub largest_decoded: u64,
    /// The heads' bytes (spec §8.2: everything but the groups), stored and decoded.
    pub head_stored_bytes: u64,
    pub head_decoded_bytes: u64,
    /// Groups per chunk (the header's `chunk_groups`), and the chunks of all blocks.
    pub chunk_groups: u32,
    pub chunks: u64,
    /// The entries' `triangles` summed (spec §8.2): triangle records in a file of lists, group
    /// lanes in use in a file of clusters.
    pub triangle_records: u64,
    /// Blocks per level of their roots: `(level, blocks)`.
    pub root_levels: Vec<(u32, u64)>,
}

/// One level of the whole tree.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TreeLevel {
    pub level: u32,
    pub nodes: u64,
    pub internal: u64,
    pub empty: u64,
    pub solid: u64,
}

/// What to include beyond the summary.
#[derive(Clone, Copy, Debug, Default)]
pub struct InspectOptions {
    /// Every block's directory entry.
    pub blocks: bool,
    /// The whole tree's nodes per level: reads (and decodes) every block.
    pub levels: bool,
}

/// Inspects an opened file. Entries and blocks are untrusted: a block that cannot be read is
/// counted in no level (`--verify` says why).
pub fn inspect<D: AsRef<[u8]>>(file: &OavmFile<D>, opts: InspectOptions) -> Inspection {
    let header = *file.header();
    let names = [
        (FLAG_MERGED, "merged"),
        (FLAG_COMPRESSED, "compressed"),
        (FLAG_CLUSTERS, "clusters"),
        (FLAG_ROPES, "ropes"),
        (FLAG_OCCLUDERS, "occluders"),
        (FLAG_PRIMS, "prims"),
        (FLAG_LEAN, "lean"),
        (FLAG_GEOMETRIES, "geometries"),
    ];
    let flags = names
        .iter()
        .filter(|(bit, _)| header.flags & bit != 0)
        .map(|&(_, name)| name)
        .collect();
    let sections = SectionKind::for_flags(file.header().flags)
        .map(|k| Section {
            name: k.name(),
            entry: *file.section(k),
        })
        .collect();

    let nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    let top_levels = file
        .levels()
        .iter()
        .enumerate()
        .map(|(l, e)| {
            let mut t = TopLevel {
                level: l as u32,
                nodes: e.node_count,
                ..TopLevel::default()
            };
            let recs = nodes
                .get(e.node_start as usize..(e.node_start + e.node_count) as usize)
                .unwrap_or(&[]);
            for r in recs {
                match r.kind() {
                    Some(NodeKind::Internal) => t.internal += 1,
                    Some(NodeKind::Empty { .. }) => t.empty += 1,
                    Some(NodeKind::Link { .. }) => t.links += 1,
                    _ => t.invalid += 1,
                }
            }
            t
        })
        .collect();

    let directory = file.directory();
    let mut d = DirectorySummary {
        blocks: directory.len() as u64,
        smallest_decoded: directory.iter().map(|e| e.raw_len).min().unwrap_or(0),
        chunk_groups: file.header().chunk_groups,
        ..DirectorySummary::default()
    };
    let mut root_levels = [0u64; MAX_LEVEL as usize + 1];
    for e in directory {
        match e.codec {
            CODEC_RAW => d.raw_blocks += 1,
            CODEC_LEAN => d.lean_blocks += 1,
            _ => d.zstd_blocks += 1,
        }
        d.stored_bytes = d.stored_bytes.saturating_add(e.stored_len);
        d.decoded_bytes = d.decoded_bytes.saturating_add(e.raw_len);
        d.largest_decoded = d.largest_decoded.max(e.raw_len);
        d.head_stored_bytes = d.head_stored_bytes.saturating_add(e.head_stored_len);
        d.head_decoded_bytes = d.head_decoded_bytes.saturating_add(e.head_raw_len);
        if let Some(per) = (file.header().chunk_groups as u64)
            .checked_mul(160)
            .filter(|&p| p > 0)
        {
            d.chunks += e.raw_len.saturating_sub(e.head_raw_len).div_ceil(per);
        }
        d.triangle_records += e.triangles as u64;
        if let Some(n) = root_levels.get_mut(e.root_level as usize) {
            *n += 1;
        }
    }
    d.root_levels = (0..).zip(root_levels).filter(|&(_, n)| n > 0).collect();

    let (tree_levels, block_wide) = match opts.levels {
        true => {
            let (t, w) = tree_levels(file);
            (Some(t), Some(w))
        }
        false => (None, None),
    };
    let wide = (header.flags & FLAG_CLUSTERS != 0).then(|| WideSummary {
        top_nodes: file.section(SectionKind::WideNodes).count,
        links: file.section(SectionKind::WideLinks).count,
        blocks: block_wide,
    });
    Inspection {
        header,
        flags,
        sections,
        top_levels,
        directory: d,
        blocks: opts.blocks.then(|| directory.to_vec()),
        tree_levels,
        wide,
        geometries: (header.flags & FLAG_GEOMETRIES != 0)
            .then(|| super::read_geometries(file).map_err(|e| e.to_string())),
    }
}

/// Nodes per level over the top tree and every readable block, and the blocks' wide nodes.
fn tree_levels<D: AsRef<[u8]>>(file: &OavmFile<D>) -> (Vec<TreeLevel>, BlockWideCounts) {
    let mut wide = BlockWideCounts::default();
    let mut levels: Vec<TreeLevel> = (0..=MAX_LEVEL)
        .map(|level| TreeLevel {
            level,
            ..TreeLevel::default()
        })
        .collect();
    let mut count = |level: usize, rec: &NodeRecord| {
        if let Some(t) = levels.get_mut(level) {
            t.nodes += 1;
            match rec.kind() {
                Some(NodeKind::Internal) => t.internal += 1,
                Some(NodeKind::Empty { .. }) => t.empty += 1,
                Some(NodeKind::Solid { .. }) => t.solid += 1,
                // A link is its block's root, counted with the block.
                _ => t.nodes -= 1,
            }
        }
    };
    let nodes: &[NodeRecord] = file.records(SectionKind::Nodes);
    for (l, e) in file.levels().iter().enumerate() {
        for r in nodes
            .get(e.node_start as usize..(e.node_start + e.node_count) as usize)
            .unwrap_or(&[])
        {
            count(l, r);
        }
    }
    let reader = BlockReader::new(file);
    for (b, e) in file.directory().iter().enumerate() {
        let Ok(raw) = reader.read(file.bytes(), b as u32, e) else {
            continue;
        };
        let Ok(view) = BlockView::parse(&raw, b as u32, e) else {
            continue;
        };
        if let (false, Some((_, roots))) = (
            view.cluster_nodes.is_empty(),
            wide_region(view.levels, view.nodes),
        ) {
            // The region as laid out (spec §8.7: adoption leaves out some internal nodes).
            let all = view.cluster_nodes.len() as u64;
            let region = super::wide::lay_block(view.levels, view.nodes, view.cluster_nodes)
                .map_or(roots, |w| w.region as u64);
            let octree = region.saturating_sub(roots);
            wide.octree_nodes += octree.min(all);
            wide.cluster_roots += roots;
            wide.cluster_nodes += all.saturating_sub(octree);
        }
        for (ll, le) in view.levels.iter().enumerate() {
            let l = view.header.root_level as usize + ll;
            for r in view
                .nodes
                .get(le.node_start as usize..(le.node_start + le.node_count) as usize)
                .unwrap_or(&[])
            {
                count(l, r);
            }
        }
    }
    while levels.last().is_some_and(|t| t.nodes == 0) {
        levels.pop();
    }
    (levels, wide)
}
